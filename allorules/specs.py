"""What plugins provide: small dataclasses describing measures, segmenters and constraints.

These are the values the hooks in :mod:`allorules.hookspecs` return. They hold plain
callables, so a plugin needs nothing from allorules but these classes and ``hookimpl``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping

if TYPE_CHECKING:  # pragma: no cover
    from .body import Body

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
    """Something that labels a body's vertices with regions: ``segment(body, **options)``."""

    name: str
    description: str
    segment: Callable[..., "Body"]


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of a constraint: its default, meaning and allowed range.

    ``kind`` is ``float``, ``int``, ``str`` or ``bool``; numbers given for a float parameter
    are accepted. ``minimum``/``maximum`` are inclusive bounds for numbers, ``choices`` the
    allowed values for strings.
    """

    default: Any
    description: str = ""
    kind: type = float
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] | None = None

    def check(self, value: Any) -> str | None:
        """Return what is wrong with ``value`` (one phrase), or ``None`` when it is fine."""
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
        if self.minimum is not None and value < self.minimum:
            return f"must be at least {self.minimum}"
        if self.maximum is not None and value > self.maximum:
            return f"must be at most {self.maximum}"
        return None


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
        """Every parameter as a :class:`ParameterSpec` (plain defaults wrapped)."""
        specs: dict[str, ParameterSpec] = {}
        for name, value in self.parameters.items():
            if isinstance(value, ParameterSpec):
                specs[name] = value
            else:
                kind = type(value) if isinstance(value, (bool, str)) else float if isinstance(value, (int, float)) else object
                specs[name] = ParameterSpec(default=value, kind=kind)
        return specs

    def complete_parameters(self, given: Mapping[str, Any]) -> dict[str, Any]:
        """The defaults overridden by ``given`` (assumed already validated)."""
        values = {name: spec.default for name, spec in self.parameter_specs().items()}
        values.update(given)
        return values
