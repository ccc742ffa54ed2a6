"""YAML read safely with the location of every value, for ``file:line`` errors (rulesets, merge
files, batch manifests). Duplicate and non-text keys are refused.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from allorules.errors import RulesetError, RulesetProblems, SourceLocation

if TYPE_CHECKING:  # pragma: no cover
    pass


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
