"""Rulesets: the YAML documents that say how a body scales, and their validated model.

A ruleset names its regions, its allometric rules (``measure(region) ∝ M^exponent``), how
body mass is measured, the constraints (energy terms from plugins) and the solver settings.
This module reads rulesets (by built-in name, by a name a plugin's search path provides, or
by file path), resolves ``extends`` (overriding or removing single rules and constraints),
validates them against the published JSON Schema (``allorules/schema/ruleset.schema.json``)
and against the registered plugins, and reports every problem as a
:class:`~allorules.errors.RulesetError` naming file and line.

YAML is read with safe loading only. The format is documented in ``docs/rulesets.md``.
"""
from __future__ import annotations

import difflib
import json
import math
import re
from dataclasses import dataclass, field, replace
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping

import yaml

from .errors import PluginError, RulesetError, SourceLocation

if TYPE_CHECKING:  # pragma: no cover
    from .plugins import PluginRegistry

RULESET_SUFFIXES = (".yaml", ".yml")
MAX_EXTENDS_DEPTH = 32


# ---------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Rule:
    """``measure(region)`` follows ``q' = q · r^exponent`` for a body-mass ratio r (paper Eq. 10)."""

    id: str
    region: str | None
    measure: str
    exponent: float
    weight: float = 1.0
    source: str = ""


@dataclass(frozen=True)
class BodyMassTerm:
    """How body mass M is measured; the energy term (M(x')/(r·M_0) − 1)² gets ``weight``."""

    measure: str = "mass"
    region: str | None = None
    weight: float = 1.0
    source: str = ""


@dataclass(frozen=True)
class ConstraintUse:
    """A constraint a plugin provides, with its (complete, checked) parameters and weight."""

    name: str
    parameters: Mapping[str, Any] = field(default_factory=dict)
    weight: float = 1.0
    source: str = ""


@dataclass(frozen=True)
class SolverSettings:
    """nlopt settings and stepping (METHOD §6).

    LN_BOBYQA is the default: derivative-free (the energy is measured on meshes, no
    gradients), respects the bounds, and builds a quadratic model, which suits a smooth sum
    of squares in a handful of variables (s, α_0 and one α per region).
    """

    step_ratio_up: float = 1.1
    step_ratio_down: float = 0.9
    algorithm: str = "LN_BOBYQA"
    relative_tolerance: float = 1e-6
    parameter_tolerance: float = 1e-4
    max_evaluations: int = 400
    scale_bounds: tuple[float, float] = (0.5, 2.0)
    alpha_bounds: tuple[float, float] = (-1.0, 1.0)
    transform: str = "per-axis"     # METHOD §5, in the animal's own axes; or "per-mode" (docs/biology-scaling.md)
    posture: str = "keep"           # legs upright, feet on the ground; "upright": legs only; "free" (allorules.posture)


@dataclass(frozen=True)
class Ruleset:
    """A resolved, validated ruleset (``extends`` already applied)."""

    name: str
    description: str
    path: Path | None
    regions: tuple[str, ...]
    rules: tuple[Rule, ...]
    body_mass: BodyMassTerm = BodyMassTerm()
    constraints: tuple[ConstraintUse, ...] = ()
    solver: SolverSettings = SolverSettings()
    plugins: tuple[Path, ...] = ()
    segmenter: str = "auto-quadruped"
    extends: tuple[str, ...] = ()   # the chain of rulesets this one was built on, nearest first

    def rule(self, rule_id: str) -> Rule:
        for rule in self.rules:
            if rule.id == rule_id:
                return rule
        raise RulesetError(f"ruleset {self.name!r} has no rule {rule_id!r}; its rules: "
                           f"{', '.join(r.id for r in self.rules) or 'none'}")


@dataclass(frozen=True)
class RulesetSummary:
    """One line of ``allorules rulesets``."""

    name: str
    description: str
    path: Path
    origin: str          # "built-in" or the plugin that provides the search path
    shadowed: tuple[Path, ...] = ()


class RulesetProblems(RulesetError):
    """Several problems in one ruleset; ``problems`` holds each as a :class:`RulesetError`.

    Its message is the first problem (and how many more there are), so it still reads as one
    line; ``allorules ruleset check`` prints them all.
    """

    def __init__(self, problems: list[RulesetError]):
        self.problems = list(problems)
        first = self.problems[0]
        more = len(self.problems) - 1
        message = str(first) + (f" (and {more} more problem{'s' if more > 1 else ''}: run 'allorules ruleset check')" if more else "")
        super().__init__(message)
        self.location = first.location


# ---------------------------------------------------------------------------------------------
# Reading YAML with line numbers
# ---------------------------------------------------------------------------------------------
class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e-6`` (no dot) as a number, as YAML 1.2 and JSON do."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                    |\.[0-9_]+(?:[eE][-+][0-9]+)?
                    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


@dataclass
class LocatedDocument:
    """One YAML file: its data and where each value was written (for file:line errors)."""

    path: Path
    data: Any
    where: dict[tuple, SourceLocation]      # path of keys/indices -> location of the value
    key_where: dict[tuple, SourceLocation]  # path -> location of the mapping key itself

    def at(self, *keys: Any) -> SourceLocation:
        """Location of the value at ``keys``, or of the nearest enclosing value written."""
        keys = tuple(keys)
        while keys and keys not in self.where:
            keys = keys[:-1]
        return self.where.get(keys, SourceLocation(self.path, 1))

    def key_at(self, *keys: Any) -> SourceLocation:
        return self.key_where.get(tuple(keys)) or self.at(*keys)


def _location(path: Path, node: yaml.Node) -> SourceLocation:
    return SourceLocation(path, node.start_mark.line + 1, node.start_mark.column + 1)


def read_located_yaml(path: Path, *, kind: str = "ruleset", error: type[RulesetError] = RulesetError,
                      empty: str = "the ruleset is empty; it needs at least 'regions' and 'rules' or 'extends'",
                      ) -> LocatedDocument:
    """Read one YAML file safely, remembering where every value was written.

    ``kind`` names the file in messages ("ruleset", "manifest"); every problem raises ``error``
    with the file and line. Duplicate keys and non-text keys are refused (YAML would silently keep
    the last); several such problems in a ruleset are raised together as :class:`RulesetProblems`.
    """
    try:
        raw = path.read_bytes()
    except IsADirectoryError:
        raise error(f"{path} is a folder; give the {kind} .yaml file") from None
    except FileNotFoundError:
        raise error(f"{kind} file {path} does not exist; check the path") from None
    except OSError as problem:
        raise error(f"cannot read {kind} {path}: {problem.strerror or problem}") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as problem:
        raise error(f"{path} is not UTF-8 text (byte {problem.start}); save it as UTF-8") from None
    try:
        loader = _Loader(text)
    except yaml.YAMLError as problem:   # characters YAML does not allow (control characters, ...)
        raise error(f"not readable as YAML: {' '.join(str(problem).split())}; remove that character",
                    SourceLocation(path, text.count(chr(10), 0, getattr(problem, "position", 0)) + 1)) from None
    try:
        node = loader.get_single_node()
        if node is None:
            raise error(empty, SourceLocation(path, 1))
        problems: list[RulesetError] = []
        where: dict[tuple, SourceLocation] = {}
        key_where: dict[tuple, SourceLocation] = {}
        _index_nodes(path, node, (), where, key_where, problems, depth=0)
        if problems and error is RulesetError:
            raise RulesetProblems(problems)
        if problems:
            raise error(problems[0].problem, problems[0].location)
        data = loader.construct_document(node)
    except yaml.MarkedYAMLError as problem:
        mark = problem.problem_mark or problem.context_mark
        location = SourceLocation(path, mark.line + 1, mark.column + 1) if mark else SourceLocation(path)
        described = " ".join(str(part) for part in (problem.context, problem.problem) if part)
        raise error(f"YAML syntax error: {described}; fix the YAML there", location) from None
    except yaml.YAMLError as problem:
        raise error(f"YAML error: {str(problem).splitlines()[0]}", SourceLocation(path)) from None
    except RecursionError:
        raise error("the YAML nests too deeply", SourceLocation(path)) from None
    finally:
        loader.dispose()
    return LocatedDocument(path, data, where, key_where)


def _read_document(path: Path) -> LocatedDocument:
    document = read_located_yaml(path)
    if not isinstance(document.data, dict):
        raise RulesetError(f"a ruleset is a mapping of keys (name, regions, rules, ...), not {_kind(document.data)}",
                           document.at())
    return document


def _index_nodes(path: Path, node: yaml.Node, keys: tuple, where: dict, key_where: dict,
                 problems: list[RulesetError], depth: int) -> None:
    """Record each value's location; reject duplicate and non-text keys (YAML keeps the last)."""
    where[keys] = _location(path, node)
    if depth > 50:
        problems.append(RulesetError("the YAML nests too deeply", _location(path, node)))
        return
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                _index_nodes(path, value_node, keys + ("<<",), where, key_where, problems, depth + 1)
                continue
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag != "tag:yaml.org,2002:str":
                problems.append(RulesetError(f"keys must be text, not {_node_kind(key_node)}; quote it or fix the indentation",
                                             _location(path, key_node)))
                continue
            key = key_node.value
            if key in seen:
                problems.append(RulesetError(f"key {key!r} is given twice (first at line {seen[key]}); keep one",
                                             _location(path, key_node)))
                continue
            seen[key] = key_node.start_mark.line + 1
            key_where[keys + (key,)] = _location(path, key_node)
            _index_nodes(path, value_node, keys + (key,), where, key_where, problems, depth + 1)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            _index_nodes(path, item, keys + (index,), where, key_where, problems, depth + 1)


def _node_kind(node: yaml.Node) -> str:
    if isinstance(node, yaml.MappingNode):
        return "a mapping"
    if isinstance(node, yaml.SequenceNode):
        return "a list"
    return f"{node.tag.rsplit(':', 1)[-1]} {node.value!r}"


def _kind(value: Any) -> str:
    """A value's type in the words of a YAML user."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"true/false ({str(value).lower()})"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})"
    if isinstance(value, str):
        shown = value if len(value) <= 40 else value[:37] + "..."
        return f"text ({shown!r})"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return type(value).__name__


# ---------------------------------------------------------------------------------------------
# Schema validation
# ---------------------------------------------------------------------------------------------
@lru_cache(maxsize=1)
def ruleset_schema() -> dict[str, Any]:
    """The published JSON Schema of a ruleset document (one file, before ``extends``)."""
    text = resources.files("allorules").joinpath("schema/ruleset.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


@lru_cache(maxsize=1)
def _validator():
    import jsonschema

    return jsonschema.Draft7Validator(ruleset_schema())


def _schema_problems(document: LocatedDocument) -> list[RulesetError]:
    problems = []
    errors = sorted(_validator().iter_errors(document.data), key=lambda e: (list(map(str, e.absolute_path)), e.validator))
    for error in errors:
        problems.append(_schema_error(document, error))
    # One problem per place: a value failing anyOf also fails its branches.
    unique: dict[str, RulesetError] = {}
    for problem in problems:
        unique.setdefault(str(problem), problem)
    return sorted(unique.values(), key=lambda p: (p.location.line or 0) if p.location else 0)


def _schema_error(document: LocatedDocument, error) -> RulesetError:
    keys = tuple(error.absolute_path)
    what = _describe_place(document.data, keys)
    value = error.instance
    validator = error.validator
    schema = error.schema if isinstance(error.schema, dict) else {}
    if validator == "additionalProperties":
        allowed = sorted(schema.get("properties", {}))
        extra = [key for key in value if key not in allowed] if isinstance(value, dict) else []
        key = str(extra[0]) if extra else "?"
        close = difflib.get_close_matches(key, allowed, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        return RulesetError(f"unknown key {key!r} in {what}; {hint}allowed keys: {', '.join(allowed)}",
                            document.key_at(*keys, key))
    location = document.at(*keys)
    if validator == "required":
        missing = [key for key in error.validator_value if not isinstance(value, dict) or key not in value]
        return RulesetError(f"{what} is missing {', '.join(repr(m) for m in missing)}; add it", location)
    if validator == "anyOf":   # only optional regions use anyOf
        return RulesetError(f"{what} must be a region name or null, not {_kind(value)}", location)
    if validator == "type":
        wanted = {"number": "a number", "integer": "a whole number", "string": "text", "array": "a list",
                  "object": "a mapping", "boolean": "true or false", "null": "null"}
        expected = error.validator_value
        expected = [expected] if isinstance(expected, str) else list(expected)
        hint = ""
        if "number" in expected and isinstance(value, str) and re.fullmatch(r"\s*[-+]?\d+\s*/\s*\d+\s*", value):
            hint = " (write the fraction as a decimal, e.g. 0.3333)"
        return RulesetError(f"{what} must be {' or '.join(wanted.get(t, t) for t in expected)}, not {_kind(value)}{hint}",
                            location)
    if validator == "pattern":
        if isinstance(value, str) and keys and keys[-1] == "algorithm":
            return RulesetError(f"{what} {value!r} is not a derivative-free nlopt algorithm name; use LN_BOBYQA, "
                                "LN_COBYLA, LN_NELDERMEAD, LN_SBPLX or another LN_*/GN_* name", location)
        return RulesetError(f"{what} {value!r} is not a valid name: start with a letter, then letters, digits, "
                            "'-', '_' or '.' (at most 80)", location)
    if validator == "maxLength":
        return RulesetError(f"{what} is longer than {error.validator_value} characters; shorten it", location)
    if validator == "minLength":
        return RulesetError(f"{what} must not be empty", location)
    if validator in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        relation = {"minimum": "at least", "exclusiveMinimum": "greater than", "maximum": "at most",
                    "exclusiveMaximum": "less than"}[validator]
        return RulesetError(f"{what} must be {relation} {error.validator_value}, not {value!r}", location)
    if validator in ("minItems", "maxItems"):
        return RulesetError(f"{what} must be a list of exactly two numbers [lower, upper], not {len(value)} items",
                            location)
    if validator == "uniqueItems":
        duplicates = sorted({str(item) for item in value if value.count(item) > 1})
        return RulesetError(f"{what} lists {', '.join(duplicates)} more than once; list each once", location)
    return RulesetError(f"{what}: {error.message}", location)


def _describe_place(data: Any, keys: tuple) -> str:
    """Words for a place in a document: ``rule 'foreleg-length' key 'exponent'``, ``solver.algorithm``."""
    if not keys:
        return "the ruleset"
    if keys[0] in ("rules", "constraints") and len(keys) >= 2 and isinstance(keys[1], int):
        kind = "rule" if keys[0] == "rules" else "constraint"
        label_key = "id" if keys[0] == "rules" else "name"
        try:
            entry = data[keys[0]][keys[1]]
            label = entry.get(label_key) if isinstance(entry, dict) else None
        except (IndexError, KeyError, TypeError):
            label = None
        name = f"{kind} {label!r}" if isinstance(label, str) else f"{kind} number {keys[1] + 1}"
        if len(keys) == 2:
            return name
        rest = ".".join(str(k) for k in keys[2:])
        return f"{name} key {rest!r}"
    if len(keys) >= 2 and isinstance(keys[-1], int):
        return f"{'.'.join(str(k) for k in keys[:-1])} item {keys[-1] + 1}"
    return ".".join(str(k) for k in keys)


# ---------------------------------------------------------------------------------------------
# Finding rulesets
# ---------------------------------------------------------------------------------------------
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
        data = yaml.load(path.read_text(encoding="utf-8-sig"), Loader=_Loader)
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
    from .plugins import PluginRegistry, registry_for

    if plugin_manager is None:
        return registry_for([])
    if not isinstance(plugin_manager, PluginRegistry):
        raise TypeError("plugin_manager must be an allorules.plugins.PluginRegistry (see registry_for)")
    return plugin_manager


# ---------------------------------------------------------------------------------------------
# Resolving extends
# ---------------------------------------------------------------------------------------------
@dataclass
class _Entry:
    """A rule or constraint while ``extends`` is resolved: its keys and where each was written."""

    fields: dict[str, Any]
    where: dict[str, SourceLocation]
    location: SourceLocation


@dataclass
class _Merged:
    """A ruleset document with its ``extends`` chain applied, locations kept for later errors."""

    path: Path
    name: str
    values: dict[str, Any] = field(default_factory=dict)        # description, regions, segmenter
    where: dict[str, SourceLocation] = field(default_factory=dict)
    body_mass: dict[str, Any] = field(default_factory=dict)
    body_mass_where: dict[str, SourceLocation] = field(default_factory=dict)
    solver: dict[str, Any] = field(default_factory=dict)
    solver_where: dict[str, SourceLocation] = field(default_factory=dict)
    rules: dict[str, _Entry] = field(default_factory=dict)
    constraints: dict[str, _Entry] = field(default_factory=dict)
    plugins: list[tuple[Path, SourceLocation]] = field(default_factory=list)
    chain: list[str] = field(default_factory=list)


def _resolve(path: Path, registry: "PluginRegistry", visiting: tuple[Path, ...]) -> _Merged:
    path = path.resolve()
    document = _read_document(path)
    problems = _schema_problems(document)
    if problems:
        raise RulesetProblems(problems)
    data = document.data
    if "extends" in data:
        parent_name = data["extends"]
        at = document.at("extends")
        parent_path = _extends_target(parent_name, path, registry, at)
        chain = visiting + (path,)
        if parent_path.resolve() in chain:
            cycle = " → ".join(p.name for p in chain + (parent_path.resolve(),))
            raise RulesetError(f"circular extends: {cycle}; remove one of these extends", at)
        if len(chain) > MAX_EXTENDS_DEPTH:
            raise RulesetError(f"extends goes more than {MAX_EXTENDS_DEPTH} rulesets deep; flatten the chain", at)
        try:
            merged = _resolve(parent_path, registry, chain)
        except RulesetProblems:
            raise
        except RulesetError as error:
            if error.location is None:   # say which extends led there
                raise RulesetError(str(error), at) from None
            raise
        merged.chain = [merged.name] + merged.chain
        merged.path = path
    else:
        merged = _Merged(path=path, name="")
    merged.name = data.get("name", path.stem)
    _apply(document, merged)
    return merged


def _extends_target(value: str, path: Path, registry: "PluginRegistry", at: SourceLocation) -> Path:
    if looks_like_path(value):
        target = (path.parent / Path(value).expanduser()).resolve()
        if not target.is_file():
            raise RulesetError(f"extends {value!r}: no such file {target}; paths are relative to this ruleset's folder", at)
        return target
    return find_ruleset(value, registry, at)


def _apply(document: LocatedDocument, merged: _Merged) -> None:
    """Lay one document over what it extends (``merged``), in place."""
    data = document.data
    for key in ("description", "regions", "segmenter"):
        if key in data:
            merged.values[key] = data[key]
            merged.where[key] = document.at(key)
    for section, target, target_where in (("body_mass", merged.body_mass, merged.body_mass_where),
                                          ("solver", merged.solver, merged.solver_where)):
        for key, value in data.get(section, {}).items():
            target[key] = value
            target_where[key] = document.at(section, key)
    for entry_path in data.get("plugins", []):
        location = document.at("plugins", data["plugins"].index(entry_path))
        plugin_path = (document.path.parent / Path(entry_path).expanduser()).resolve()
        if plugin_path not in [p for p, _ in merged.plugins]:
            merged.plugins.append((plugin_path, location))
    is_child = "extends" in data
    for section, label, table in (("rules", "id", merged.rules), ("constraints", "name", merged.constraints)):
        kind = "rule" if section == "rules" else "constraint"
        problems: list[RulesetError] = []
        seen: set[str] = set()
        for index, entry in enumerate(data.get(section, [])):
            key = entry[label]
            location = document.at(section, index)
            if key in seen:
                problems.append(RulesetError(f"{kind} {key!r} is given twice in this file; keep one "
                                             f"(to change an inherited {kind}, give only the keys that change)",
                                             document.at(section, index, label)))
                continue
            seen.add(key)
            if entry.get("remove"):
                others = sorted(set(entry) - {label, "remove"})
                if others:
                    problems.append(RulesetError(f"{kind} {key!r} has remove: true and also {', '.join(others)}; "
                                                 f"a removed {kind} takes only {label} and remove", location))
                elif key not in table:
                    what = "the ruleset it extends" if is_child else "anything: this ruleset extends nothing"
                    problems.append(RulesetError(f"cannot remove {kind} {key!r}: it is not in {what}; "
                                                 f"known: {', '.join(table) or 'none'}", location))
                else:
                    del table[key]
                continue
            where = {name: document.at(section, index, name) for name in entry}
            if key in table:   # override only the keys given
                inherited = table[key]
                fields = dict(inherited.fields)
                merged_where = dict(inherited.where)
                for name, value in entry.items():
                    if name == "parameters" and isinstance(fields.get("parameters"), dict):
                        fields["parameters"] = {**fields["parameters"], **value}
                    else:
                        fields[name] = value
                    merged_where[name] = where[name]
                for name in entry.get("parameters", {}):
                    merged_where[f"parameters.{name}"] = document.at(section, index, "parameters", name)
                changed = [name for name in ("exponent", "region", "measure", "parameters") if name in entry]
                if changed and "source" not in entry:   # an inherited source no longer vouches for the value
                    old = " ".join(str(inherited.fields.get("source", "")).split())
                    fields["source"] = (f"{', '.join(changed)} overridden in {document.path.name}"
                                        + (f"; before: {old}" if old else ""))
                    merged_where["source"] = location
                table[key] = _Entry(fields, merged_where, location)
            else:
                for name in entry.get("parameters", {}):
                    where[f"parameters.{name}"] = document.at(section, index, "parameters", name)
                table[key] = _Entry(dict(entry), where, location)
        if problems:
            raise RulesetProblems(problems)


# ---------------------------------------------------------------------------------------------
# Checking the resolved ruleset against the registered plugins
# ---------------------------------------------------------------------------------------------
def _build(merged: _Merged, registry: "PluginRegistry") -> Ruleset:
    problems: list[RulesetError] = []
    plugin_failures_before = len(registry.failures)
    for plugin_path, location in merged.plugins:
        if registry.load_path(plugin_path) is None:
            message = registry.failures[-1].message if len(registry.failures) > plugin_failures_before else "failed to load"
            problems.append(RulesetError(f"plugin {plugin_path.name}: {message}", location))
    measures = registry.measures()
    constraints = registry.constraints()
    segmenters = registry.segmenters()
    failed_note = _failed_plugins_note(registry)
    whole = SourceLocation(merged.path, 1)

    regions = merged.values.get("regions")
    if regions is None:
        problems.append(RulesetError("the ruleset names no regions; add 'regions: [head, neck, ...]' "
                                     "(or extend a ruleset that has them)", whole))
        regions = []
    regions = tuple(regions)
    regions_text = ", ".join(regions) or "none"

    def check_region(region: Any, spec: Any, what: str, location: SourceLocation) -> None:
        if region is None:
            if spec is not None and spec.needs_region:
                problems.append(RulesetError(f"{what}: measure {spec.name!r} needs a region; add 'region:' "
                                             f"(one of {regions_text})", location))
            return
        if spec is not None and not spec.accepts_region:
            problems.append(RulesetError(f"{what}: measure {spec.name!r} is taken on the whole body; "
                                         "remove 'region' (or set it to null)", location))
        elif region not in regions:
            close = difflib.get_close_matches(region, regions, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            regions_at = merged.where.get("regions")
            set_at = f" (regions set at {regions_at})" if regions_at and regions_at.path != location.path else ""
            problems.append(RulesetError(f"{what}: unknown region {region!r}; {hint}the ruleset's regions are "
                                         f"{regions_text}{set_at} (add it to 'regions' if it is new)", location))

    def check_measure(name: str, what: str, location: SourceLocation):
        if name in measures:
            return measures[name]
        close = difflib.get_close_matches(name, list(measures), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        problems.append(RulesetError(f"{what}: unknown measure {name!r}; {hint}known measures: "
                                     f"{', '.join(sorted(measures))}{failed_note} (plugins add more: 'allorules plugins')",
                                     location))
        return None

    # body mass
    body_fields = {"measure": "mass", "region": None, "weight": 1.0, "source": "", **merged.body_mass}
    body_where = merged.body_mass_where
    body_spec = check_measure(body_fields["measure"], "body_mass", body_where.get("measure", whole))
    if body_spec is not None and body_spec.kind != "mass":
        problems.append(RulesetError(f"body_mass: measure {body_spec.name!r} measures {body_spec.kind}, not mass; "
                                     "use a mass measure (mass)", body_where.get("measure", whole)))
    if body_fields["region"] is not None:
        check_region(body_fields["region"], body_spec, "body_mass", body_where.get("region", whole))
    _check_finite(body_fields["weight"], "body_mass weight", body_where.get("weight", whole), problems)
    body_mass = BodyMassTerm(body_fields["measure"], body_fields["region"], float(body_fields["weight"]),
                             _text(body_fields["source"]))

    # rules
    rules = []
    for rule_id, entry in merged.rules.items():
        what = f"rule {rule_id!r}"
        missing = [key for key in ("measure", "exponent") if key not in entry.fields]
        if missing:
            problems.append(RulesetError(f"{what} is missing {', '.join(repr(m) for m in missing)}; a new rule needs "
                                         "measure and exponent (and region for a regional measure)", entry.location))
            continue
        spec = check_measure(entry.fields["measure"], what, entry.where.get("measure", entry.location))
        region = entry.fields.get("region")
        check_region(region, spec, what, entry.where.get("region", entry.location))
        exponent = entry.fields["exponent"]
        exponent_at = entry.where.get("exponent", entry.location)
        if _check_finite(exponent, f"{what} exponent", exponent_at, problems) and spec is not None:
            problem = exponent_problem(exponent, spec)
            if problem:
                problems.append(RulesetError(f"{what}: {problem}", exponent_at))
        weight = entry.fields.get("weight", 1.0)
        _check_finite(weight, f"{what} weight", entry.where.get("weight", entry.location), problems)
        rules.append(Rule(rule_id, region, entry.fields["measure"], float(exponent), float(weight),
                          _text(entry.fields.get("source", ""))))

    # constraints
    uses = []
    for name, entry in merged.constraints.items():
        what = f"constraint {name!r}"
        spec = constraints.get(name)
        if spec is None:
            close = difflib.get_close_matches(name, list(constraints), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            problems.append(RulesetError(f"{what} is not provided by any plugin; {hint}known constraints: "
                                         f"{', '.join(sorted(constraints)) or 'none'}{failed_note} "
                                         "(name the plugin under 'plugins:' or install it)", entry.location))
            continue
        given = entry.fields.get("parameters", {}) or {}
        specs = spec.parameter_specs()
        ok = True
        for parameter, value in given.items():
            at = entry.where.get(f"parameters.{parameter}", entry.where.get("parameters", entry.location))
            if parameter not in specs:
                close = difflib.get_close_matches(str(parameter), list(specs), n=1)
                hint = f"did you mean {close[0]!r}? " if close else ""
                problems.append(RulesetError(f"{what}: unknown parameter {parameter!r}; {hint}its parameters: "
                                             f"{', '.join(specs) or 'none'}", at))
                ok = False
                continue
            problem = specs[parameter].check(value)
            if problem:
                problems.append(RulesetError(f"{what}: parameter {parameter!r} {problem} (got {_kind(value)})", at))
                ok = False
        weight = entry.fields.get("weight", 1.0)
        _check_finite(weight, f"{what} weight", entry.where.get("weight", entry.location), problems)
        if ok:
            uses.append(ConstraintUse(name, spec.complete_parameters(given), float(weight),
                                      _text(entry.fields.get("source", ""))))

    # solver
    solver = _build_solver(merged, problems)

    segmenter = merged.values.get("segmenter", "auto-quadruped")
    if segmenter not in segmenters:
        problems.append(RulesetError(f"unknown segmenter {segmenter!r}; known: {', '.join(sorted(segmenters))}{failed_note}",
                                     merged.where.get("segmenter", whole)))
    if problems:
        problems.sort(key=lambda p: (str(p.location.path), p.location.line or 0) if p.location else ("", 0))
        raise RulesetProblems(problems)
    return Ruleset(
        name=merged.name,
        description=" ".join(str(merged.values.get("description", "")).split()),
        path=merged.path,
        regions=regions,
        rules=tuple(rules),
        body_mass=body_mass,
        constraints=tuple(uses),
        solver=solver,
        plugins=tuple(p for p, _ in merged.plugins),
        segmenter=segmenter,
        extends=tuple(merged.chain),
    )


def _text(value: Any) -> str:
    """Folded YAML text as one line (sources and descriptions)."""
    return " ".join(str(value or "").split())


def exponent_problem(exponent: float, spec: Any) -> str | None:
    """Why ``exponent`` is not sane for the measure ``spec`` (None when it is).

    Sane means within ±1 of the measure's isometric exponent (``specs.EXPONENT_RANGE``):
    length in [-2/3, 4/3], mass in [0, 2], area in [-1/3, 5/3].
    """
    low, high = spec.exponent_range()
    if low - 1e-12 <= exponent <= high + 1e-12:
        return None
    return (f"exponent {exponent:g} is outside the sane range [{low:.3g}, {high:.3g}] for measure {spec.name!r} "
            f"(isometric {spec.isometric_exponent:.4g} ± 1); check for a typo")


def _check_finite(value: Any, what: str, location: SourceLocation, problems: list[RulesetError]) -> bool:
    try:
        ok = math.isfinite(float(value))
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        problems.append(RulesetError(f"{what} must be a finite number, not {_kind(value)}", location))
    return ok


def _failed_plugins_note(registry: "PluginRegistry") -> str:
    failed = sorted({failure.plugin for failure in registry.failures})
    return f"; plugins that failed to load: {', '.join(failed)}" if failed else ""


def _build_solver(merged: _Merged, problems: list[RulesetError]) -> SolverSettings:
    defaults = SolverSettings()
    values = dict(merged.solver)
    where = merged.solver_where
    whole = SourceLocation(merged.path, 1)
    settings: dict[str, Any] = {}
    for key in ("step_ratio_up", "step_ratio_down", "relative_tolerance", "parameter_tolerance"):
        if key in values and _check_finite(values[key], f"solver.{key}", where.get(key, whole), problems):
            settings[key] = float(values[key])
    if "max_evaluations" in values:
        settings["max_evaluations"] = int(values["max_evaluations"])
    for key in ("scale_bounds", "alpha_bounds"):
        if key not in values:
            continue
        at = where.get(key, whole)
        low, high = values[key]
        if not (_check_finite(low, f"solver.{key} lower", at, problems)
                and _check_finite(high, f"solver.{key} upper", at, problems)):
            continue
        if not low < high:
            problems.append(RulesetError(f"solver.{key} must be [lower, upper] with lower < upper, not {values[key]}", at))
            continue
        if key == "scale_bounds" and not (0 < low <= 1 <= high):
            problems.append(RulesetError(f"solver.scale_bounds must satisfy 0 < lower <= 1 <= upper (s = 1 is no "
                                         f"change), not {values[key]}", at))
            continue
        if key == "alpha_bounds" and not (low <= 0 <= high):
            problems.append(RulesetError(f"solver.alpha_bounds must contain 0 (α = 0 is no change), not {values[key]}", at))
            continue
        settings[key] = (float(low), float(high))
    if "transform" in values:
        from .solver import TRANSFORM_FORMS

        if values["transform"] in TRANSFORM_FORMS:
            settings["transform"] = values["transform"]
        else:
            problems.append(RulesetError(f"solver.transform {values['transform']!r} is not a transform form; use "
                                         f"{' or '.join(TRANSFORM_FORMS)}", where.get("transform", whole)))
    if "posture" in values:
        from .posture import POSTURES

        if values["posture"] in POSTURES:
            settings["posture"] = values["posture"]
        else:
            problems.append(RulesetError(f"solver.posture {values['posture']!r} is not one of 'keep' (legs upright and "
                                         "feet on the ground), 'upright' (legs upright) or 'free' (as Eq. 9 leaves them)",
                                         where.get("posture", whole)))
    if "algorithm" in values:
        algorithm = values["algorithm"]
        try:
            import nlopt

            valid = isinstance(getattr(nlopt, algorithm, None), int)
        except ImportError:  # pragma: no cover - nlopt is a dependency
            valid = True
        if not valid:
            problems.append(RulesetError(f"solver.algorithm {algorithm!r} is not an nlopt algorithm; use LN_BOBYQA, "
                                         "LN_COBYLA, LN_NELDERMEAD or LN_SBPLX", where.get("algorithm", whole)))
        else:
            settings["algorithm"] = algorithm
    return replace(defaults, **settings)


# ---------------------------------------------------------------------------------------------
# Public functions
# ---------------------------------------------------------------------------------------------
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


def load_ruleset(name_or_path: str | Path, plugin_manager: "PluginRegistry | None" = None) -> Ruleset:
    """Read, resolve (``extends``) and validate a ruleset given by name or by file path.

    Plugins the ruleset names under ``plugins:`` are loaded into ``plugin_manager`` (a
    :class:`~allorules.plugins.PluginRegistry`; a fresh one with the built-ins and the
    installed plugins when ``None``), so pass the registry the solver will use. Every problem
    raises :class:`RulesetError` (:class:`RulesetProblems` when there are several).
    """
    registry = _registry(plugin_manager)
    path = ruleset_path(name_or_path, registry)
    merged = _resolve(path, registry, ())
    return _build(merged, registry)


def check_ruleset(name_or_path: str | Path, plugin_manager: "PluginRegistry | None" = None) -> list[RulesetError]:
    """Every problem of a ruleset (empty when it is valid)."""
    try:
        load_ruleset(name_or_path, plugin_manager)
    except RulesetProblems as problems:
        return problems.problems
    except RulesetError as error:
        return [error]
    return []


def ruleset_to_dict(ruleset: Ruleset) -> dict[str, Any]:
    """The resolved ruleset as a document (no extends) that loads back into an equal ruleset."""
    document: dict[str, Any] = {"name": ruleset.name}
    if ruleset.description:
        document["description"] = ruleset.description
    if ruleset.plugins:
        document["plugins"] = [str(path) for path in ruleset.plugins]
    document["segmenter"] = ruleset.segmenter
    document["regions"] = list(ruleset.regions)
    document["body_mass"] = {"measure": ruleset.body_mass.measure, "region": ruleset.body_mass.region,
                             "weight": ruleset.body_mass.weight}
    if ruleset.body_mass.source:
        document["body_mass"]["source"] = ruleset.body_mass.source
    document["rules"] = []
    for rule in ruleset.rules:
        entry: dict[str, Any] = {"id": rule.id, "region": rule.region, "measure": rule.measure,
                                 "exponent": rule.exponent, "weight": rule.weight}
        if rule.source:
            entry["source"] = rule.source
        document["rules"].append(entry)
    document["constraints"] = []
    for use in ruleset.constraints:
        entry = {"name": use.name, "parameters": dict(use.parameters), "weight": use.weight}
        if use.source:
            entry["source"] = use.source
        document["constraints"].append(entry)
    solver = ruleset.solver
    document["solver"] = {
        "step_ratio_up": solver.step_ratio_up, "step_ratio_down": solver.step_ratio_down,
        "algorithm": solver.algorithm, "relative_tolerance": solver.relative_tolerance,
        "parameter_tolerance": solver.parameter_tolerance, "max_evaluations": solver.max_evaluations,
        "scale_bounds": list(solver.scale_bounds), "alpha_bounds": list(solver.alpha_bounds),
        "transform": solver.transform, "posture": solver.posture,
    }
    return document


def dump_ruleset(ruleset: Ruleset) -> str:
    """The resolved ruleset as YAML text (what ``allorules ruleset show`` prints)."""
    header = f"# ruleset {ruleset.name}"
    if ruleset.extends:
        header += f", resolved (extends {' → '.join(ruleset.extends)})"
    if ruleset.path:
        header += f"\n# from {ruleset.path}"
    return header + "\n" + yaml.safe_dump(ruleset_to_dict(ruleset), sort_keys=False, allow_unicode=True, width=100)


def override_exponents(ruleset: Ruleset, exponents: Mapping[str, float],
                       plugin_manager: "PluginRegistry | None" = None) -> Ruleset:
    """The ruleset with some rules' exponents replaced (``--rule ID=EXPONENT``), range-checked."""
    if not exponents:
        return ruleset
    registry = _registry(plugin_manager)
    registry.load_paths(ruleset.plugins)
    measures = registry.measures()
    by_id = {rule.id: rule for rule in ruleset.rules}
    rules = list(ruleset.rules)
    for rule_id, value in exponents.items():
        if rule_id not in by_id:
            close = difflib.get_close_matches(rule_id, list(by_id), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise RulesetError(f"--rule {rule_id}: ruleset {ruleset.name!r} has no rule {rule_id!r}; {hint}"
                               f"its rules: {', '.join(by_id) or 'none'}")
        try:
            exponent = float(value)
        except (TypeError, ValueError):
            raise RulesetError(f"--rule {rule_id}={value}: the exponent must be a number, e.g. {rule_id}=0.4") from None
        if not math.isfinite(exponent):
            raise RulesetError(f"--rule {rule_id}={value}: the exponent must be a finite number")
        spec = measures.get(by_id[rule_id].measure)
        if spec is None:
            raise PluginError(f"measure {by_id[rule_id].measure!r} of rule {rule_id!r} is not provided by any plugin")
        problem = exponent_problem(exponent, spec)
        if problem:
            raise RulesetError(f"--rule {rule_id}={value}: {problem}")
        index = rules.index(by_id[rule_id])
        rules[index] = replace(by_id[rule_id], exponent=exponent,
                               source=f"set on the command line (was {by_id[rule_id].exponent:g})")
        by_id[rule_id] = rules[index]
    return replace(ruleset, rules=tuple(rules))


def parse_rule_overrides(texts: Iterable[str]) -> dict[str, float]:
    """``["neck-length=0.45", ...]`` → ``{"neck-length": 0.45}`` for :func:`override_exponents`."""
    overrides: dict[str, float] = {}
    for text in texts:
        rule_id, sep, value = str(text).partition("=")
        if not sep or not rule_id.strip() or not value.strip():
            raise RulesetError(f"--rule {text!r}: write ID=EXPONENT, e.g. --rule neck-length=0.45")
        try:
            overrides[rule_id.strip()] = float(value)
        except ValueError:
            raise RulesetError(f"--rule {text}: {value.strip()!r} is not a number; write ID=EXPONENT, "
                               "e.g. --rule neck-length=0.45") from None
    return overrides
