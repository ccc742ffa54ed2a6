"""The package reads as the pipeline: no module imports a later stage, and no imports go round in a
circle (docs/architecture.md)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

import allorules

PACKAGE = Path(allorules.__file__).parent

# The stages in the order a mesh goes through them; a module may import its own stage and
# earlier ones only. The core (errors, body, files) comes before every stage.
STAGES = ["core", "mesh", "spectral", "segment", "measure", "plugins", "rules", "solve", "output", "runs",
          "cli", "front"]
CORE = {"errors", "body", "files"}   # and the root package itself, which holds only __version__
FRONT = {"api", "blender", "hookspecs", "specs"}   # the public API, the Blender add-on, old plugin paths


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def stage(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "allorules":
        return None
    if len(parts) == 1:
        return "core"
    head = parts[1]
    if head in CORE:
        return "core"
    if head in FRONT:
        return "front"
    return head if head in STAGES else None


def imports(path: Path, *, annotations: bool = True) -> set[str]:
    """Every allorules module ``path`` imports, at module level or inside functions; without
    ``annotations``, leaving out ``if TYPE_CHECKING:`` blocks (names for type hints only)."""
    module = module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    hints_only = set()
    if not annotations:
        for node in ast.walk(tree):
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                hints_only.update(id(child) for statement in node.body for child in ast.walk(statement))
    found = set()
    for node in ast.walk(tree):
        if id(node) in hints_only:
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            found.add(base)
            for alias in node.names:   # "from allorules.spectral import cache" imports a module
                if (PACKAGE.parent / base.replace(".", "/") / f"{alias.name}.py").exists():
                    found.add(f"{base}.{alias.name}")
    return {name for name in found if name.split(".")[0] == "allorules" and name != module}


MODULES = {module_name(path): imports(path) for path in sorted(PACKAGE.rglob("*.py"))}
RUNTIME = {module_name(path): imports(path, annotations=False) for path in sorted(PACKAGE.rglob("*.py"))}


def test_every_module_belongs_to_a_stage():
    assert [module for module in MODULES if stage(module) is None] == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_imports_a_later_stage(module):
    mine = STAGES.index(stage(module))
    later = sorted(name for name in MODULES[module] if stage(name) and STAGES.index(stage(name)) > mine)
    assert later == [], f"{module} ({stage(module)}) imports later stages: {later}"


def test_no_import_cycles():
    """At run time (type-hint-only imports cannot loop)."""
    graph = {module: {name for name in names if name in MODULES} for module, names in RUNTIME.items()}
    # a package's __init__ re-exporting its modules is not a cycle with them
    graph = {module: {name for name in names if not module.startswith(name + ".")} for module, names in graph.items()}
    cycles, state = [], {}

    def visit(module: str, trail: list[str]) -> None:
        state[module] = "open"
        for name in sorted(graph[module]):
            if state.get(name) == "open":
                cycles.append(trail[trail.index(name):] + [name] if name in trail else [module, name])
            elif name not in state:
                visit(name, trail + [name])
        state[module] = "done"

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert cycles == []


def test_the_layout_is_what_the_architecture_page_describes():
    page = (PACKAGE.parent / "docs" / "architecture.md")
    if not page.exists():
        pytest.skip("docs/ is not beside the package (installed copy)")
    text = page.read_text(encoding="utf-8")
    missing = [module for module in MODULES if module.count(".") == 2 and f"{module.split('.', 1)[1].replace('.', '/')}.py" not in text]
    assert missing == [], f"modules docs/architecture.md does not mention: {missing}"
