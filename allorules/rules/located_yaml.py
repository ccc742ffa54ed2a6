"""YAML read safely with the location of every value, for ``file:line`` errors (rulesets, merge
files, batch manifests). Duplicate and non-text keys are refused.

**Bounded.** A file larger than :data:`MAX_BYTES`, or whose values, counted with every alias
(``*name``) expanded, number more than :data:`MAX_VALUES`, is refused with one line before
anything walks it: a "billion laughs" document of nine levels of nine aliases is 500 bytes that
expand to 387 million values. Counting and indexing visit each node once (an alias is the node
it names, already visited), so reading is linear in the file's size. The limits can be raised
with ``ALLORULES_YAML_MAX_BYTES`` and ``ALLORULES_YAML_MAX_VALUES`` for unusual files.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from allorules.errors import RulesetError, RulesetProblems, SourceLocation
from allorules.files import MAX_TEXT_BYTES, text_size_problem

# A ruleset is a few kilobytes and a few hundred values; a manifest of 10,000 meshes is under
# 1 MB and 40,000 values. Checking a ruleset at the limits takes seconds, not minutes
# (docs/benchmarks.md, benchmarks/bench_yaml_limits.py).
MAX_BYTES = MAX_TEXT_BYTES
MAX_VALUES = 100_000

_FLOAT = re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                    |\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?
                    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.X)


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e-6`` (no dot) as a number, as YAML 1.2 and JSON do."""


_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))

if getattr(yaml, "__with_libyaml__", False):
    class _FastLoader(yaml.CSafeLoader):
        """The same loader with libyaml's parser (eight times faster); its error messages say less,
        so a document it refuses is read again with :class:`_Loader` for the message."""

    _FastLoader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))
else:  # pragma: no cover - PyYAML built without libyaml
    _FastLoader = _Loader


def values_limit() -> int:
    """The most values a YAML file may expand to: :data:`MAX_VALUES`, or ``ALLORULES_YAML_MAX_VALUES``."""
    text = os.environ.get("ALLORULES_YAML_MAX_VALUES")
    try:
        return max(1, int(text)) if text else MAX_VALUES
    except ValueError:
        return MAX_VALUES


def check_size(path: Path, size: int, kind: str, error: type[RulesetError] = RulesetError) -> None:
    """Refuse a YAML file larger than the limit, before reading it."""
    problem = text_size_problem(size, kind)
    if problem:
        raise error(problem, SourceLocation(path))


def expanded_size(root: yaml.Node, path: Path, kind: str, error: type[RulesetError] = RulesetError) -> int:
    """The number of values in the document (keys not counted) with every alias expanded, counted
    visiting each node once; more than the limit, or a node that contains itself, raises ``error``."""
    largest = values_limit()
    sizes: dict[int, int] = {}
    active: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            total = 1 + sum(sizes[id(child)] for child in _values(node))
            active.discard(key)
            sizes[key] = total
            if total > largest:
                through = "through its aliases (*name) " if len(sizes) <= largest else ""
                raise error(f"the {kind} holds more than {largest:,} values {through}(a {kind} is usually a few hundred); "
                            + ("write the values out, or use fewer aliases" if through else "is it the right file?")
                            + " (ALLORULES_YAML_MAX_VALUES raises the limit)", _location(path, node))
            continue
        if key in sizes:
            continue
        if key in active:
            raise error("an alias (*name) refers to a value that contains it; YAML that contains itself has no end",
                        _location(path, node))
        active.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in _values(node) if id(child) not in sizes)
    return sizes[id(root)]


def _values(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [value for _key, value in node.value]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


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
        if path.is_file():
            check_size(path, path.stat().st_size, kind, error)
        raw = path.read_bytes()
    except IsADirectoryError:
        raise error(f"{path} is a folder; give the {kind} .yaml file") from None
    except FileNotFoundError:
        raise error(f"{kind} file {path} does not exist; check the path") from None
    except OSError as problem:
        raise error(f"cannot read {kind} {path}: {problem.strerror or problem}") from None
    check_size(path, len(raw), kind, error)   # a file that grew, or a special file
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as problem:
        raise error(f"{path} is not UTF-8 text (byte {problem.start}); save it as UTF-8") from None
    loader, composed = None, False
    try:
        loader = _FastLoader(text)
        node, composed = loader.get_single_node(), True
    except Exception:   # read it again with the loader whose messages say more (and without libyaml's
        # own failures, such as a document of comments only)
        if loader is not None:
            loader.dispose()
        try:
            loader = _Loader(text)
        except yaml.YAMLError as problem:   # characters YAML does not allow (control characters, ...)
            raise error(f"not readable as YAML: {' '.join(str(problem).split())}; remove that character",
                        SourceLocation(path, text.count(chr(10), 0, getattr(problem, "position", 0)) + 1)) from None
    try:
        if not composed:
            node = loader.get_single_node()
        if node is None:
            raise error(empty, SourceLocation(path, 1))
        expanded_size(node, path, kind, error)
        problems: list[RulesetError] = []
        where: dict[tuple, SourceLocation] = {}
        key_where: dict[tuple, SourceLocation] = {}
        _index_nodes(path, node, (), where, key_where, problems, depth=0, visited=set())
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
                 problems: list[RulesetError], depth: int, visited: set[int]) -> None:
    """Record each value's location; reject duplicate and non-text keys (YAML keeps the last).

    A node met again through an alias is located where its anchor is and not walked again: its
    keys were checked the first time, and walking it once per alias is what made an alias bomb
    take minutes and gigabytes."""
    where[keys] = _location(path, node)
    if id(node) in visited:
        return
    visited.add(id(node))
    if depth > 50:
        problems.append(RulesetError("the YAML nests too deeply", _location(path, node)))
        return
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                _index_nodes(path, value_node, keys + ("<<",), where, key_where, problems, depth + 1, visited)
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
            _index_nodes(path, value_node, keys + (key,), where, key_where, problems, depth + 1, visited)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            _index_nodes(path, item, keys + (index,), where, key_where, problems, depth + 1, visited)


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
