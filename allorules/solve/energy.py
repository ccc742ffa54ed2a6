"""The energy of the paper's Eq. 11 (METHOD §6): one term per active part of a ruleset (body
mass, each rule, each constraint), as weighted squared relative residuals, and the measures
every trial mesh is evaluated with. A new energy term goes here (or in a plugin constraint).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from allorules.body import Body
from allorules.errors import AllorulesError, ScalingError
from allorules.measure.cache import measured
from allorules.plugins.specs import ConstraintContext
from allorules.solve.transform import StepTransform

ENERGY_TARGET = 1e-9


RESIDUAL_TOLERANCE = 5e-4     # a step whose every |residual| is below this needs no nlopt polish
# A soft term of weight w (an open region held isometric, w = 0.01 by default) is met once its
# *weighted* residual √w·|residual| is below RESIDUAL_TOLERANCE, i.e. |residual| ≤ RESIDUAL_TOLERANCE/√w:
# it trades against the rules, and where it cannot be met with them the solve stops with the rules
# met instead of searching its 400 trials for the last 0.1 % of it (the real horse at ×2, trunk held:
# steps 5–8 took 1,429 trials for trunk residuals of 0.2–0.5 %). The run carries the miss forward.
ALPHA_RIDGE = 1e-6


FAILED_ENERGY = 1e6


OUT_OF_BOUNDS_PENALTY = 1e3


Measure = Callable[[str, Body, "str | None"], float]


@dataclass(frozen=True)
class Term:
    """One target of the energy: ``measure(region)`` should become ``initial · r^exponent``."""

    id: str
    kind: str                   # "body-mass", "rule" or "open-region" (allorules/solve/open_regions.py)
    measure: str
    region: str | None
    exponent: float
    weight: float


def residual_tolerance(term: Term) -> float:
    """How far ``term``'s relative residual may be off for a step to count as met: RESIDUAL_TOLERANCE
    for the body mass and the rules, RESIDUAL_TOLERANCE / √weight for a soft open-region term."""
    if term.kind == "open-region" and 0.0 < term.weight < 1.0:
        return RESIDUAL_TOLERANCE / math.sqrt(term.weight)
    return RESIDUAL_TOLERANCE


def energy_terms(ruleset) -> list[Term]:
    """The body-mass term and one term per rule of ``ruleset`` (constraints are handled apart)."""
    terms = [Term("body-mass", "body-mass", ruleset.body_mass.measure, ruleset.body_mass.region, 1.0,
                  float(ruleset.body_mass.weight))]
    for rule in ruleset.rules:
        terms.append(Term(rule.id, "rule", rule.measure, rule.region, float(rule.exponent), float(rule.weight)))
    return terms


def cached_measure(registry, overrides: Mapping[str, Callable[[Body], float]] | None = None) -> Measure:
    """``measure(name, body, region)`` through the registry, computed once per body (``body.cache``).

    ``overrides`` replaces whole-body measures by name (the run passes the frozen stress gauge for
    ``stress``, so stress is measured at one material section throughout)."""
    overrides = dict(overrides or {})

    def measure(name: str, body: Body, region: str | None) -> float:
        values = measured(body).values
        if (name, region) not in values:
            if name in overrides and region is None:
                value = overrides[name](body)
            else:
                value = registry.measure(name).compute(body, region)
            value = float(value)
            if not (math.isfinite(value) and value > 0):
                from allorules.errors import MeasurementError

                raise MeasurementError(f"measure {name!r} of {region or 'the body'} gave {value!r}; it must be positive")
            values[name, region] = value
        return values[name, region]

    return measure


@dataclass
class Evaluation:
    """One trial: its variables, weighted residual vector, energy and every named residual."""

    variables: np.ndarray
    energy: float
    residuals: dict[str, float]
    vector: np.ndarray | None = None      # √w · residual per term, then √ridge · α; energy = ‖vector‖²
    misfit: float = math.inf              # the energy without the ridge
    body: Body | None = None
    failure: str | None = None


class StepEnergy:
    """The energy of Eq. 11 for one step, assembled from a ruleset (see the module docstring)."""

    def __init__(self, transform_: StepTransform, ruleset, registry, mass_ratio: float, measure: Measure,
                 on_trial: Callable[[int, float], None] | None = None,
                 corrections: Mapping[str, float] | None = None,
                 constraint_reference: tuple[Body, float] | None = None,
                 extra_terms: list[Term] | None = None):
        self.transform = transform_
        self.on_trial = on_trial
        self.ruleset = ruleset
        self.registry = registry
        self.mass_ratio = float(mass_ratio)
        self.measure = measure
        self.terms = energy_terms(ruleset) + list(extra_terms or [])   # + the open regions' soft terms
        self.constraints = [(use, registry.constraint(use.name)) for use in ruleset.constraints]
        start = transform_.body
        self.initial = {term.id: measure(term.measure, start, term.region) for term in self.terms}
        # q* = q_0 · r^e, times what the earlier steps of the run left over (``corrections``).
        corrections = corrections or {}
        self.targets = {term.id: self.initial[term.id] * self.mass_ratio ** term.exponent
                        * corrections.get(term.id, 1.0) for term in self.terms}
        # Constraints compare a trial with this body at this mass ratio: the step's start and r,
        # or the run's input and the ratio reached (see solve_step).
        self.constraint_reference = constraint_reference or (start, self.mass_ratio)
        self.evaluations: list[Evaluation] = []
        self.best: Evaluation | None = None
        # per residual: how far it may be off for the step to count as met (see RESIDUAL_TOLERANCE)
        self.tolerances = {term.id: residual_tolerance(term) for term in self.terms}

    def residuals(self, body: Body) -> tuple[dict[str, float], list[float]]:
        """Every relative residual of ``body`` by name, and the weighted residual vector."""
        residuals: dict[str, float] = {}
        vector: list[float] = []
        for term in self.terms:
            value = self.measure(term.measure, body, term.region)
            residual = value / self.targets[term.id] - 1.0            # (q(x') − q*) / q*
            residuals[term.id] = residual
            vector.append(math.sqrt(term.weight) * residual)
        reference, ratio = self.constraint_reference
        context = ConstraintContext(reference, body, ratio, self.measure)
        for use, spec in self.constraints:
            values = spec.residuals(context, spec.complete_parameters(use.parameters))
            for name, residual in values.items():
                residual = float(residual)
                if not math.isfinite(residual):
                    raise ScalingError(f"constraint {use.name!r} gave a non-finite residual {name!r}")
                key = use.name if len(values) == 1 else f"{use.name}:{name}"
                residuals[key] = residual
                vector.append(math.sqrt(use.weight) * residual)
        return residuals, vector

    def evaluate(self, variables: np.ndarray) -> Evaluation:
        variables = np.array(variables, dtype=float)
        try:
            body = self.transform.body_at(variables)
            residuals, vector = self.residuals(body)
            misfit = float(np.dot(vector, vector))
            vector = np.array(vector + list(math.sqrt(ALPHA_RIDGE) * variables[1:]))
            evaluation = Evaluation(variables, float(vector @ vector), residuals, vector, misfit, body)
        except (ValueError, AllorulesError) as error:
            evaluation = Evaluation(variables, FAILED_ENERGY, {}, None, math.inf, None, str(error))
        self.evaluations.append(evaluation)
        if evaluation.failure is None and (self.best is None or evaluation.energy < self.best.energy):
            self.best = evaluation
        if self.on_trial is not None:
            self.on_trial(len(self.evaluations), self.best.misfit if self.best is not None else math.inf)
        return evaluation

    def done(self) -> bool:
        """Whether the best trial's misfit is below ENERGY_TARGET (every residual ≲ 3·10⁻⁵)."""
        return self.best is not None and self.best.misfit <= ENERGY_TARGET

    def met(self, residuals: Mapping[str, float]) -> bool:
        """Whether every residual is within its tolerance (RESIDUAL_TOLERANCE; a soft term's, scaled by its weight)."""
        return all(abs(value) <= self.tolerances.get(key, RESIDUAL_TOLERANCE) for key, value in residuals.items())

    def within_tolerance(self) -> bool:
        """Whether the best trial meets every target within its tolerance (:meth:`met`)."""
        return self.best is not None and self.met(self.best.residuals)

    def __call__(self, variables: np.ndarray) -> float:
        return self.evaluate(variables).energy
