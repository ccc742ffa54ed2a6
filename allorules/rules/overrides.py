"""Exponents changed from the command line (``--rule ID=EXPONENT``), range-checked like the file.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import replace
from typing import TYPE_CHECKING, Iterable, Mapping

from allorules.errors import PluginError, RulesetError
from allorules.rules.find import _registry
from allorules.rules.model import Ruleset
from allorules.rules.resolve import exponent_problem

if TYPE_CHECKING:  # pragma: no cover
    from allorules.plugins.registry import PluginRegistry


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
