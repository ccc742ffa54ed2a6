"""Finding rulesets by name: the built-in folder (package ``allorules.rulesets``), folders plugins
provide, and file paths.
"""
from __future__ import annotations

import difflib
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import yaml

from allorules.errors import RulesetError, SourceLocation
from allorules.files import text_size_problem
from allorules.rules.located_yaml import _FastLoader
from allorules.rules.model import RulesetSummary

if TYPE_CHECKING:  # pragma: no cover
    from allorules.plugins.registry import PluginRegistry


RULESET_SUFFIXES = (".yaml", ".yml")


def builtin_ruleset_folder() -> Path:
    return Path(str(resources.files("allorules.rulesets")))


def looks_like_path(text: str | Path) -> bool:
    """A ruleset given as a path (has a folder separator or a .yaml suffix) rather than a name."""
    if isinstance(text, Path):
        return True
    return "/" in text or "\\" in text or text.lower().endswith(RULESET_SUFFIXES) or text.startswith(("~", "."))


def _search_folders(registry: "PluginRegistry | None") -> list[tuple[Path, str]]:
    folders = [(builtin_ruleset_folder(), "built-in")]
    if registry is not None:
        for path in registry.ruleset_paths():
            provider = _provider_of_path(registry, path)
            folders.append((Path(path), f"plugin {provider}" if provider else "plugin"))
    return folders


def _provider_of_path(registry: "PluginRegistry", path: Path) -> str | None:
    for info in registry.describe():
        if str(path) in info.provides.get("ruleset path", []):
            return info.name
    return None


def _candidates(folder: Path) -> list[Path]:
    if folder.is_file():
        return [folder] if folder.suffix.lower() in RULESET_SUFFIXES else []
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in RULESET_SUFFIXES and p.is_file())


def list_rulesets(plugin_manager: "PluginRegistry | None" = None) -> list[RulesetSummary]:
    """Every ruleset that can be named: built-ins first, then those of plugins' search paths."""
    registry = _registry(plugin_manager)
    found: dict[str, RulesetSummary] = {}
    for folder, origin in _search_folders(registry):
        for path in _candidates(folder):
            name = path.stem
            if name in found:
                first = found[name]
                found[name] = replace(first, shadowed=first.shadowed + (path,))
                continue
            found[name] = RulesetSummary(name, _peek_description(path), path, origin)
    return list(found.values())


def _peek_description(path: Path) -> str:
    try:
        too_large = text_size_problem(path.stat().st_size, "ruleset")
        if too_large:
            return f"(cannot be read: {too_large.split(';')[0]})"
        data = yaml.load(path.read_text(encoding="utf-8-sig"), Loader=_FastLoader)
    except Exception as error:  # a broken file still gets listed, flagged
        return f"(cannot be read: {str(error).splitlines()[0] if str(error) else type(error).__name__})"
    if isinstance(data, dict) and isinstance(data.get("description"), str):
        return " ".join(data["description"].split())
    return ""


def find_ruleset(name: str, plugin_manager: "PluginRegistry | None" = None,
                 location: SourceLocation | None = None) -> Path:
    """The file of the ruleset called ``name`` (built-in first, then plugins' search paths)."""
    registry = _registry(plugin_manager)
    known = []
    for folder, _origin in _search_folders(registry):
        for path in _candidates(folder):
            if path.stem == name:
                return path
            known.append(path.stem)
    close = difflib.get_close_matches(name, known, n=1)
    hint = f"did you mean {close[0]!r}? " if close else ""
    raise RulesetError(f"unknown ruleset {name!r}; {hint}known: {', '.join(sorted(set(known)))} "
                       f"(to use a file, give its path, e.g. ./{name}.yaml)", location)


def _registry(plugin_manager: "PluginRegistry | None") -> "PluginRegistry":
    from allorules.plugins.registry import PluginRegistry, registry_for

    if plugin_manager is None:
        return registry_for([])
    if not isinstance(plugin_manager, PluginRegistry):
        raise TypeError("plugin_manager must be an allorules.plugins.PluginRegistry (see registry_for)")
    return plugin_manager


def ruleset_path(name_or_path: str | Path, plugin_manager: "PluginRegistry | None" = None) -> Path:
    """The file a ruleset name or path refers to."""
    if looks_like_path(name_or_path):
        path = Path(name_or_path).expanduser()
        if not path.is_file():
            if path.is_dir():
                raise RulesetError(f"{path} is a folder; give a ruleset .yaml file")
            raise RulesetError(f"ruleset file {path} does not exist; check the path "
                               "(or give a built-in name: see 'allorules rulesets')")
        return path
    return find_ruleset(str(name_or_path), plugin_manager)
