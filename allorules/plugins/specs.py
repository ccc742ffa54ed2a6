"""What plugins provide: small dataclasses describing measures, segmenters and constraints.

These are the values the hooks in :mod:`allorules.plugins.hookspecs` return. They hold plain
callables, so a plugin needs nothing from allorules but these classes and ``hookimpl`` (all
importable from :mod:`allorules.plugins`).
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Mapping

if TYPE_CHECKING:  # pragma: no cover
    from allorules.body import Body

# How far a rule's exponent may lie from its measure's isometric exponent (see
# ``docs/rulesets.md``, "Exponent range"): |exponent - isometric| <= EXPONENT_RANGE.
# Observed allometric exponents differ from isometric ones by well under 0.5; a difference
# of 1 (a length growing like mass itself, a mass not growing at all) is surely a typo.
EXPONENT_RANGE = 1.0

MEASURE_KINDS = ("mass", "length", "girth", "area", "stress", "ratio", "other")


@dataclass(frozen=True)
class MeasureSpec:
    """A quantity measured on a body, optionally restricted to one region.

    ``compute(body, region)`` returns a positive float (arbitrary units; only ratios are used).
    ``isometric_exponent`` is the exponent of the quantity against body mass under uniform
    scaling: mass or volume 1, length and girth 1/3, area 2/3, stress M/A 1/3, a ratio 0.
    ``needs_region``: a rule using it must name a region. ``accepts_region``: whether a region
    may be named at all (``False`` for whole-body quantities such as peak limb stress).
    """

    name: str
    kind: str
    isometric_exponent: float
    compute: Callable[["Body", "str | None"], float]
    description: str
    needs_region: bool = True
    accepts_region: bool = True

    def exponent_range(self) -> tuple[float, float]:
        """The sane range of rule exponents for this measure: isometric ± EXPONENT_RANGE."""
        return (self.isometric_exponent - EXPONENT_RANGE, self.isometric_exponent + EXPONENT_RANGE)


@dataclass(frozen=True)
class SegmenterSpec:
    """Something that labels a body's vertices with regions: ``segment(body, **options) -> Body``.

    It receives the prepared, unlabelled :class:`~allorules.body.Body` (one connected, outward
    oriented surface) and returns the same surface labelled: ``Body(body.vertices, body.faces,
    labels, region_names)`` with ``labels[i]`` the index into ``region_names`` of vertex i (or
    ``UNLABELLED``), optionally with a ``frame`` and a ``labelling`` (its confidence). Options
    come from the ruleset's ``segmenter: {name, options}``, checked against ``parameters`` (as a
    constraint's are); ``up``/``forward`` from the command line are passed to a segmenter that
    declares parameters of those names. Regions the ruleset does not list are folded into their
    neighbour afterwards (docs/segmentation.md), so a segmenter may return more.
    """

    name: str
    description: str
    segment: Callable[..., "Body"]
    parameters: Mapping[str, Any] = field(default_factory=dict)

    def parameter_specs(self) -> dict[str, ParameterSpec]:
        return parameter_specs(self.parameters)

    def complete_parameters(self, given: Mapping[str, Any]) -> dict[str, Any]:
        return complete_parameters(self.parameters, given)


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of a constraint or a segmenter: its default, meaning and allowed range.

    ``kind`` is ``float``, ``int``, ``str``, ``bool``, ``Path`` (a file, given relative to the
    ruleset that names it and passed on as an absolute :class:`~pathlib.Path`) or ``tuple`` (a
    direction: three numbers, not all zero). Numbers given for a float parameter are accepted.
    ``minimum``/``maximum`` are inclusive bounds for numbers, ``choices`` the allowed values for
    text. ``required``: the ruleset must give it (its default is then ``None``); an optional
    parameter whose default is ``None`` may be left unset.
    """

    default: Any
    description: str = ""
    kind: type = float
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] | None = None
    required: bool = False

    def check(self, value: Any) -> str | None:
        """Return what is wrong with ``value`` (one phrase), or ``None`` when it is fine."""
        if value is None and self.default is None and not self.required:
            return None
        if self.kind is float:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return f"must be a number, not {type(value).__name__}"
            if not math.isfinite(value):
                return "must be a finite number"
        elif self.kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                return f"must be an integer, not {type(value).__name__}"
        elif self.kind is bool:
            if not isinstance(value, bool):
                return f"must be true or false, not {type(value).__name__}"
        elif self.kind is str:
            if not isinstance(value, str):
                return f"must be text, not {type(value).__name__}"
            if self.choices is not None and value not in self.choices:
                return f"must be one of {', '.join(self.choices)}"
        elif self.kind is Path:
            if not isinstance(value, (str, Path)) or not str(value).strip():
                return "must be a file path (text)"
        elif self.kind is tuple:
            numbers = list(value) if isinstance(value, (list, tuple)) else []
            if (len(numbers) != 3 or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x)
                                         for x in numbers) or not any(numbers)):
                return "must be a direction: three numbers, not all zero, e.g. [0, 1, 0]"
            return None
        if self.minimum is not None and value < self.minimum:
            return f"must be at least {self.minimum}"
        if self.maximum is not None and value > self.maximum:
            return f"must be at most {self.maximum}"
        return None


def parameter_specs(parameters: Mapping[str, Any]) -> dict[str, ParameterSpec]:
    """Every parameter as a :class:`ParameterSpec` (plain defaults wrapped)."""
    specs: dict[str, ParameterSpec] = {}
    for name, value in parameters.items():
        if isinstance(value, ParameterSpec):
            specs[name] = value
        else:
            kind = type(value) if isinstance(value, (bool, str)) else float if isinstance(value, (int, float)) else object
            specs[name] = ParameterSpec(default=value, kind=kind)
    return specs


def parameter_problems(given: Mapping[str, Any], specs: Mapping[str, ParameterSpec],
                       word: str = "parameter") -> list[tuple[str, str]]:
    """``(name, what is wrong)`` for each given value that is unknown (with a did-you-mean) or
    fails its spec's check, and for each required one not given; empty when all is well."""
    problems = []
    for name, value in given.items():
        if name not in specs:
            close = difflib.get_close_matches(str(name), list(specs), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            problems.append((name, f"unknown {word} {name!r}; {hint}its {word}s: {', '.join(specs) or 'none'}"))
            continue
        problem = specs[name].check(value)
        if problem:
            problems.append((name, f"{word} {name!r} {problem}"))
    for name, spec in specs.items():
        if spec.required and name not in given:
            problems.append((name, f"needs {word} {name!r} ({spec.description})"))
    return problems


def complete_parameters(parameters: Mapping[str, Any], given: Mapping[str, Any]) -> dict[str, Any]:
    """The defaults of ``parameters`` overridden by ``given`` (assumed already validated)."""
    values = {name: spec.default for name, spec in parameter_specs(parameters).items()}
    values.update(given)
    return values


@dataclass(frozen=True)
class ConstraintContext:
    """What a constraint sees during one scaling step.

    ``initial`` is the run's input mesh, ``candidate`` the trial mesh, ``mass_ratio`` the
    body-mass ratio the run will have reached after this step (R at the last step), so a residual
    is the whole run's so far and misses of earlier steps do not add up; ``measure(name, body,
    region)`` evaluates any registered measure (cached by the solver). ``solver.solve_step`` used
    alone passes the step's start mesh and r.
    """

    initial: "Body"
    candidate: "Body"
    mass_ratio: float
    measure: Callable[[str, "Body", "str | None"], float]


Residuals = Mapping[str, float]


@dataclass(frozen=True)
class ConstraintSpec:
    """An energy term: ``residuals(context, parameters) -> {name: relative residual}``.

    Each residual is dimensionless and 0 when the constraint is satisfied, typically
    ``quantity(candidate) / target - 1``. ``parameters`` maps each parameter name to a
    :class:`ParameterSpec` or simply to its default value; the ruleset's values, checked
    and completed with defaults, are passed to ``residuals``.
    """

    name: str
    description: str
    residuals: Callable[[ConstraintContext, Mapping[str, Any]], Residuals]
    parameters: Mapping[str, Any] = field(default_factory=dict)

    def parameter_specs(self) -> dict[str, ParameterSpec]:
        return parameter_specs(self.parameters)

    def complete_parameters(self, given: Mapping[str, Any]) -> dict[str, Any]:
        return complete_parameters(self.parameters, given)
