"""The published JSON Schema of a ruleset document and its validation, with errors that name the
file and line and suggest the key meant.
"""
from __future__ import annotations

import difflib
import json
import re
from functools import lru_cache
from importlib import resources
from typing import TYPE_CHECKING, Any

from allorules.errors import RulesetError
from allorules.rules.located_yaml import LocatedDocument, _kind

if TYPE_CHECKING:  # pragma: no cover
    pass


@lru_cache(maxsize=1)
def ruleset_schema() -> dict[str, Any]:
    """The published JSON Schema of a ruleset document (one file, before ``extends``)."""
    text = resources.files("allorules.rules").joinpath("ruleset.schema.json").read_text(encoding="utf-8")
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
    if validator == "oneOf" and keys == ("segmenter",):   # a name, or {name, options}
        if isinstance(value, dict):
            inner = [sub for sub in error.context if sub.relative_schema_path and sub.relative_schema_path[0] == 1]
            if inner:
                return _schema_error(document, inner[0])
        return RulesetError(f"segmenter must be a segmenter's name or a mapping with 'name' and 'options', "
                            f"not {_kind(value)}", location)
    if validator == "anyOf" and keys and keys[0] == "open_regions":   # a word or a mapping
        if isinstance(value, dict):
            branch = [sub for sub in error.context if sub.schema_path and sub.schema_path[0] == 1]
            if branch:
                return _schema_error(document, min(branch, key=lambda sub: len(sub.absolute_path) * -1))
        return RulesetError(f"{what} must be 'isometric', 'free' or a mapping (default, weight, measures, regions, "
                            f"source), not {_kind(value)}", location)
    if validator == "anyOf" and keys and keys[-1] == "detail_cutoff":
        return RulesetError(f"{what} must be a positive number of modes or null, not {_kind(value)}", location)
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
    if validator == "enum":
        return RulesetError(f"{what} {value!r} is not one of {', '.join(repr(v) for v in error.validator_value)}", location)
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
