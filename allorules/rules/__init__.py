"""Rulesets: the YAML documents that say how a body scales (docs/rulesets.md).

``model`` (what a ruleset holds; an exponent lives in a ``Rule``), ``located_yaml`` (safe YAML with
the line of every value), ``schema`` (the JSON Schema), ``find`` (by name or path), ``resolve``
(``load_ruleset``: extends, validation against the plugins), ``overrides`` (``--rule ID=EXPONENT``).
"""
from allorules.rules.find import list_rulesets
from allorules.rules.model import (
           Rule,
           Ruleset,
           SegmenterUse,
           SolverSettings,
           dump_ruleset,
)
from allorules.rules.resolve import check_ruleset, load_ruleset

__all__ = ["load_ruleset", "check_ruleset", "list_rulesets", "dump_ruleset", "Ruleset", "Rule", "SegmenterUse",
           "SolverSettings"]
