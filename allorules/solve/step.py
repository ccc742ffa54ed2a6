"""One step of biology-aware scaling: the energy of paper Eq. 11 and its nlopt solve (METHOD §6).

Owns the step's variables, the energy assembled from a ruleset, and the minimisation.

**Transform** (paper Eq. 9, dimensionless as in METHOD §5/§6). With u = x̃ / c the body's
dimensionless coefficients and u_j those of region j's vertices alone (Eq. 5, same c),

    x̃'_i = s · c · sgn(u_i) |u_i|^(1 + α_0 + Σ_j α_j G(u_i, u_j,i)),   i ≥ 1,

mode 0 untouched, detail beyond the m-th mode added back × s
(:func:`allorules.spectral.power_laws.multi_region_power_law`, :func:`allorules.spectral.power_laws.apply_to_mesh`). The
axes of "per axis" are the animal's own (forward, up, side: :func:`anatomical_axes`), so a turned
mesh gives the same animal turned; ``solver.transform: per-mode`` is the alternative on each
mode's vector length (docs/biology-scaling.md).
With ``solver.posture: keep`` the transform then puts every foot back at its height above the
others (:class:`allorules.solve.posture.FootContact`: legs moved rigidly along the ground's normal), so the
solver measures, and meets its targets on, the animal standing.
Region coefficients are taken of the vertices *relative to the body's area-weighted centroid*
(the point mode 0 represents), so that the gate G, and with it the result, does not depend on
where the mesh sits in space (Eq. 5 on raw coordinates would).

**Variables**: ``(s, α_0, α_j for each ruleset region)``; start at s = r^(1/3), every α = 0
(isometric scaling to the step's mass), which is already close for allometric exponents. With
``solver.trunk_stretch`` on, one more: δ, the trunk's stretch along the animal's forward axis
(:func:`allorules.spectral.power_laws.stretch_first_axis`, bounds ``TRUNK_STRETCH_BOUNDS``, start 0);
with ``solver.limb_thickness`` on, one more after it: κ, the limbs' thickening across their centre
lines (:mod:`allorules.solve.limb_thickness`, bounds ``LIMB_THICKNESS_BOUNDS``, start 0). A region
held at its rule's size (the head, ``solver.ruled_shape: hold``) has no α_j; its size is a
variable instead, last (its held shape × (1 + σ), bounds ``HELD_SIZE_BOUNDS``, start 0).

**Energy** (Eq. 11 with relative residuals, METHOD §6): a weighted sum of squared relative
residuals, one term per active part of the ruleset:

* body mass:   w_M · (M(x')/(r·M_0) − 1)²
* each rule:   w   · (q(x')/(q_0·r^e) − 1)²        (q = the rule's measure of its region)
* constraints: w   · Σ residual²                     (residuals from the plugin's ConstraintSpec)
* a small ridge ``ALPHA_RIDGE · Σ α²`` (10⁻⁶) so that a region no term sees (the neck in
  ``quadruped``) keeps α near 0 instead of drifting; it moves no residual by more than ~10⁻⁵.
  The stopping test (``ENERGY_TARGET``) looks at the misfit, the energy without the ridge.

Every trial mesh is measured along the material curves of the step's start body
(:func:`allorules.measure.parts.carry_fields`), so the measures vary smoothly with the variables; every
measure is computed at most once per trial (``body.cache``).

**The solve.** Each trial costs a reconstruction and a full set of measurements (the skeleton
lengths dominate), so the step is solved in as few trials as the problem allows, in three stages:

1. *Jacobian* of the residual vector by forward differences (one trial per variable), or the
   previous step's Jacobian when the run passes it on (the steps are alike, so it stays good).
2. *Gauss–Newton* on the sum of squares with Broyden rank-one updates (one trial per iteration,
   step halved while the energy does not drop); if the carried-over Jacobian does not reach the
   target, it is recomputed once at the best point. Eq. 11 is a small, nearly linear least
   squares problem over one step, so this usually meets every target in 2–5 trials.
3. *nlopt* polish, only when stage 2 has not met the target: the ruleset's algorithm (default
   LN_BOBYQA: derivative-free, bounded, quadratic model of a small sum of squares) with
   ``ftol_rel`` = relative_tolerance, ``xtol_rel`` = parameter_tolerance, ``maxeval`` = what is
   left of max_evaluations, over variables preconditioned by the Jacobian's SVD (the raw variables
   differ in effect by two orders of magnitude: α_0 moves every mode, a limb's α only the modes the
   limb shares with the body), started at the best trial with a small trust region.

Bounds: ``scale_bounds`` on s and ``alpha_bounds`` on every α (stage 2 clips to them, stage 3
penalises leaving them). Gauss–Newton stops once the misfit is below ``ENERGY_TARGET`` (10⁻⁹:
every relative residual below ~3·10⁻⁵); the Jacobian is recomputed and nlopt called only while
some residual is above ``RESIDUAL_TOLERANCE`` (5·10⁻⁴, i.e. at most 0.005 of exponent per 10 %
step; a soft open-region term of weight w: 5·10⁻⁴/√w, see :func:`allorules.solve.energy.residual_tolerance`),
and nlopt stops as soon as none is, or once it has *stalled*: its best misfit fell by less than
``STALL_DROP`` (RESIDUAL_TOLERANCE², what one residual at its tolerance contributes) over its last
``STALL_TRIALS`` trials (at least 2n + 2 for n variables, BOBYQA's model needs 2n + 1). A step whose
targets cannot all be met together (a soft term against the rules: the real horse at ×2 with its
trunk held, whose trunk residual grows to 0.037) otherwise crawls to ``ftol_rel`` in ~200 trials for
misfit drops of 10⁻⁸; what it leaves is carried into the next step as every miss is. Some measures
are not smooth at the 10⁻³ level (the chest girth is the largest of several loops, filtered by
position, so it jumps when a loop enters or leaves); chasing residuals below that made nlopt wander
to large, opposing α that met the numbers with a bent body. Trials whose exponent turns
non-positive or whose mesh cannot be measured get ``FAILED_ENERGY``; the best trial seen is always
what is returned, with the solver's status.
"""
from __future__ import annotations

import logging
import math
import weakref
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from allorules.body import Body
from allorules.errors import ScalingError
from allorules.solve.energy import (
    OUT_OF_BOUNDS_PENALTY,
    RESIDUAL_TOLERANCE,
    Evaluation,
    Measure,
    StepEnergy,
    Term,
    cached_measure,
)
from allorules.solve.held_regions import HeldRegions
from allorules.solve.limb_thickness import LIMB_THICKNESS_BOUNDS
from allorules.solve.posture import FootContact
from allorules.solve.transform import StepTransform
from allorules.spectral.basis import HarmonicBasis

log = logging.getLogger("allorules")

JACOBIAN_STEP_SCALE = 1e-3     # relative to s
JACOBIAN_STEP_ALPHA = 1e-3
GAUSS_NEWTON_TRIALS = 6
TRUNK_STRETCH_BOUNDS = (-0.5, 0.5)   # δ per step (solver.trunk_stretch); the real horse at ×2 used 0.07-0.11
HELD_SIZE_BOUNDS = (-0.2, 0.2)      # a ruled held region's size − 1, from its rule's similarity (solver.ruled_shape)
STALL_TRIALS = 30                   # nlopt stops once its best misfit fell by less than STALL_DROP over this many trials
STALL_DROP = RESIDUAL_TOLERANCE ** 2


@dataclass
class StepSolution:
    """What one step's solve reached (measured on its best trial mesh)."""

    scale: float
    alpha0: float
    alphas: dict[str, float]
    energy: float
    residuals: dict[str, float]
    evaluations: int
    status: str
    body: Body
    failed_evaluations: int = 0
    jacobian: np.ndarray | None = field(default=None, repr=False)   # of the residual vector, for the next step
    feet: FootContact | None = field(default=None, repr=False)      # the step's foot contact (posture keep)
    trunk_stretch: float | None = None                              # δ, when solver.trunk_stretch is on
    limb_thickness: float | None = None                             # κ, when solver.limb_thickness is on
    sizes: dict[str, float] = field(default_factory=dict)           # each region held at its rule's size: its size − 1
    met: bool = False                                               # every residual within its tolerance (StepEnergy.met)

    @property
    def variables(self) -> np.ndarray:
        extra = [value for value in (self.trunk_stretch, self.limb_thickness) if value is not None]
        return np.array([self.scale, self.alpha0, *self.alphas.values(), *extra, *self.sizes.values()])

    def as_dict(self) -> dict:
        return {
            "scale": float(self.scale),
            "alpha0": float(self.alpha0),
            "alphas": {key: float(value) for key, value in self.alphas.items()},
            "trunk_stretch": None if self.trunk_stretch is None else float(self.trunk_stretch),
            "limb_thickness": None if self.limb_thickness is None else float(self.limb_thickness),
            "sizes": {key: float(value) for key, value in self.sizes.items()},
            "energy": float(self.energy),
            "residuals": {key: float(value) for key, value in self.residuals.items()},
            "evaluations": int(self.evaluations),
            "failed_evaluations": int(self.failed_evaluations),
            "status": self.status,
        }


_NLOPT_STATUS = {1: "success", 2: "energy target reached", 3: "ftol reached", 4: "xtol reached",
                 5: "maxeval reached", 6: "maxtime reached", -1: "failure", -2: "invalid arguments",
                 -3: "out of memory", -4: "roundoff limited", -5: "forced stop"}


def _finite_difference_jacobian(energy: StepEnergy, at: Evaluation, lower: np.ndarray, upper: np.ndarray) -> np.ndarray | None:
    """∂(residual vector)/∂(variables) by forward differences (one trial per variable)."""
    steps = np.full(len(at.variables), JACOBIAN_STEP_ALPHA)
    steps[0] = JACOBIAN_STEP_SCALE * at.variables[0]
    columns = []
    for index, step in enumerate(steps):
        moved = at.variables.copy()
        if moved[index] + step > upper[index]:
            step = -step
        moved[index] += step
        trial = energy.evaluate(moved)
        if trial.vector is None:
            return None
        columns.append((trial.vector - at.vector) / step)
    return np.column_stack(columns)


def _gauss_newton(energy: StepEnergy, jacobian: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                  budget: int) -> tuple[np.ndarray, int]:
    """Gauss–Newton steps on the residual vector with Broyden updates of the Jacobian.

    Each iteration solves the linearised least squares min ‖v + J Δx‖ (Eq. 11 is a sum of
    squares), clips to the bounds and halves the step while the energy does not drop; the Jacobian
    is corrected by the rank-one ("good") Broyden update from every trial. Stops at
    ENERGY_TARGET or after ``budget`` trials. Returns the Jacobian and the trials used.
    """
    used = 0
    while used < budget and not energy.done():
        current = energy.best
        delta = np.linalg.lstsq(jacobian, -current.vector, rcond=1e-10)[0]
        accepted = False
        for _ in range(3):
            target = np.clip(current.variables + delta, lower, upper)
            trial = energy.evaluate(target)
            used += 1
            if trial.vector is not None:
                step = trial.variables - current.variables
                if step @ step > 0:     # Broyden: J ← J + (Δv − J Δx) Δxᵀ / ΔxᵀΔx
                    jacobian = jacobian + np.outer(trial.vector - current.vector - jacobian @ step, step) / (step @ step)
                if trial.energy < current.energy:
                    accepted = True
                    break
            delta = 0.5 * delta
            if used >= budget:
                break
        if not accepted:
            break
    return jacobian, used


def solve_step(
    body: Body,
    basis: HarmonicBasis,
    ruleset,
    registry,
    mass_ratio: float,
    *,
    measure: Measure | None = None,
    start: np.ndarray | None = None,
    jacobian: np.ndarray | None = None,
    on_trial: Callable[[int, float], None] | None = None,
    corrections: Mapping[str, float] | None = None,
    constraint_reference: tuple[Body, float] | None = None,
    extra_terms: list[Term] | None = None,
    extra_regions: tuple[str, ...] = (),
    held: HeldRegions | None = None,
    held_scale: float = 1.0,
    trunk_stretch: bool = False,
    limb_thickness: bool = False,
) -> StepSolution:
    """Minimise the step's energy over (s, α_0, α_j) (paper Eq. 11, METHOD §6); the best trial wins.

    ``body`` is the step's start mesh (labelled with the ruleset's regions), ``basis`` its harmonic
    basis, ``mass_ratio`` the step's r. ``start`` overrides the starting point (default s = r^(1/3),
    α = 0); ``jacobian`` (from the previous step's solution) saves the finite differences.
    ``on_trial(count, misfit)`` is told of every trial mesh measured (misfit: the best so far).
    ``corrections`` multiplies terms' targets by id (the run's carried-forward misses, see
    :func:`allorules.runs.ruleset_run.scale_with_ruleset`); ``constraint_reference`` = (body, ratio)
    that constraints compare a trial with (default: the step's start and ``mass_ratio``).
    ``extra_terms`` (the open regions' soft isometric terms, :mod:`allorules.solve.open_regions`)
    join the energy; ``extra_regions`` (appendages the ruleset does not list) get an α_j each;
    ``held`` open regions are given their input shape × ``held_scale`` after Eq. 9
    (:mod:`allorules.solve.held_regions`). ``trunk_stretch`` adds δ, the trunk's stretch along the
    animal's forward axis, as one more variable (:func:`allorules.spectral.power_laws.stretch_first_axis`);
    ``limb_thickness`` adds κ, the limbs' thickening, after it (:mod:`allorules.solve.limb_thickness`).
    ``solver.detail_cutoff`` splits the surface into base and detail (:class:`allorules.spectral.power_laws.DetailLayer`).
    Raises :class:`ScalingError` only when no trial could be measured at all.
    """
    settings = ruleset.solver
    measure = measure or cached_measure(registry)
    # a region held at its rule's size has a size variable instead of its α_j (its shape is held)
    ruled = held.ruled if held is not None else ()
    regions = tuple(region for region in tuple(ruleset.regions) + tuple(extra_regions) if region not in ruled)
    step = StepTransform.of(body, basis, regions, settings.transform, keep_stance=settings.posture == "keep",
                            detail_cutoff=settings.detail_cutoff, held=held, held_scale=held_scale,
                            trunk_stretch=trunk_stretch, limb_thickness=limb_thickness)
    energy = StepEnergy(step, ruleset, registry, mass_ratio, measure, on_trial, corrections, constraint_reference,
                        extra_terms)

    count = step.variable_count
    stretched, thickened = step.trunk_gate is not None, step.limb_field is not None
    lower = np.array([settings.scale_bounds[0], *[settings.alpha_bounds[0]] * (1 + len(regions)),
                      *[TRUNK_STRETCH_BOUNDS[0]] * stretched, *[LIMB_THICKNESS_BOUNDS[0]] * thickened,
                      *[HELD_SIZE_BOUNDS[0]] * len(ruled)], dtype=float)
    upper = np.array([settings.scale_bounds[1], *[settings.alpha_bounds[1]] * (1 + len(regions)),
                      *[TRUNK_STRETCH_BOUNDS[1]] * stretched, *[LIMB_THICKNESS_BOUNDS[1]] * thickened,
                      *[HELD_SIZE_BOUNDS[1]] * len(ruled)], dtype=float)
    isometric = np.zeros(count)
    isometric[0] = mass_ratio ** (1.0 / 3.0)                          # isometric: M ∝ s³
    isometric = np.clip(isometric, lower, upper)
    if start is not None and len(start) != count:
        start = None                                                   # the previous step had other variables
    start = isometric if start is None else np.clip(np.asarray(start, dtype=float), lower, upper)
    budget = int(settings.max_evaluations)

    first = energy.evaluate(start)
    if first.vector is None and not np.array_equal(start, isometric):
        # the previous step's point does not fit this mesh (an exponent turns negative): start afresh
        log.debug("step r=%.4f: the given start cannot be measured (%s); starting from isometric scaling",
                  mass_ratio, first.failure)
        jacobian = None
        first = energy.evaluate(isometric)
    if first.vector is None:
        raise ScalingError(f"the starting mesh of this step cannot be measured: {first.failure}")
    status = "energy target reached"
    if not energy.done():
        if jacobian is None or jacobian.shape != (len(first.vector), count):
            jacobian = _finite_difference_jacobian(energy, first, lower, upper)
        if jacobian is not None:
            jacobian, _ = _gauss_newton(energy, jacobian, lower, upper, min(GAUSS_NEWTON_TRIALS, budget - len(energy.evaluations)))
            if not energy.within_tolerance() and len(energy.evaluations) < budget:
                # The Jacobian carried over may be stale: recompute it at the best point once.
                fresh = _finite_difference_jacobian(energy, energy.best, lower, upper)
                if fresh is not None:
                    jacobian, _ = _gauss_newton(energy, fresh, lower, upper,
                                                min(GAUSS_NEWTON_TRIALS, budget - len(energy.evaluations)))
        if energy.done():
            status = "energy target reached"
        elif energy.within_tolerance():
            status = "within tolerance"
        elif len(energy.evaluations) < budget:
            status = _nlopt_polish(energy, jacobian, lower, upper, budget - len(energy.evaluations))
        elif not energy.done():
            status = "maxeval reached"
    best = energy.best
    named = step.unpack(best.variables)
    failed = sum(1 for evaluation in energy.evaluations if evaluation.failure)
    log.debug("step r=%.4f: %s after %d evaluations, energy %.3g", mass_ratio, status, len(energy.evaluations), best.energy)
    return StepSolution(
        scale=named.scale,
        alpha0=named.alpha0,
        alphas=dict(zip(regions, named.alphas)),
        energy=float(best.energy),
        residuals=dict(best.residuals),
        evaluations=len(energy.evaluations),
        status=status,
        body=best.body,
        failed_evaluations=failed,
        jacobian=jacobian,
        feet=step.feet,
        trunk_stretch=named.trunk_stretch,
        limb_thickness=named.limb_thickness,
        sizes=named.sizes,
        met=energy.met(best.residuals),
    )


def _nlopt_polish(energy: StepEnergy, jacobian: np.ndarray | None, lower: np.ndarray, upper: np.ndarray,
                  budget: int) -> str:
    """Minimise the energy with the ruleset's nlopt algorithm from the best trial so far.

    The variables are preconditioned by the Jacobian's SVD, x = x_best + V diag(1/σ̃) z with
    σ̃ = max(σ, 10⁻³ σ_max), so that every direction of z moves the residuals about equally (the
    raw variables differ in effect by two orders of magnitude: α_0 moves every mode, a limb's α
    only the few modes the limb shares). Without a Jacobian, z = x − x_best. Points outside the
    ruleset's bounds are measured at the nearest point inside plus a quadratic penalty. Stops
    once every residual is within tolerance, or once stalled (STALL_TRIALS, STALL_DROP).
    """
    import nlopt

    settings = energy.ruleset.solver
    best = energy.best
    count = len(best.variables)
    if jacobian is not None and np.all(np.isfinite(jacobian)):
        _, singular, right = np.linalg.svd(jacobian, full_matrices=False)
        floor = max(float(singular[0]) * 1e-3, 1e-12)
        precondition = right.T / np.maximum(singular, floor)
    else:
        precondition = np.eye(count)
    origin = best.variables.copy()
    radius = max(4.0 * math.sqrt(best.misfit), 1e-4)
    window = max(STALL_TRIALS, 2 * count + 2)
    misfits: list[float] = []          # the best misfit after each of nlopt's trials
    stop: str | None = None            # why the polish stopped itself: "within tolerance" or "stalled"

    # The polish stops itself with force_stop(), not by raising nlopt.ForcedStop: BOBYQA (nlopt
    # 2.11) does not always check an objective's exception and returned with it still set (a
    # SystemError, found on the generated horse's last-step refit); calls after the stop are not measured.
    # The objective reaches its optimiser through a weak reference: the optimiser holds the objective
    # where the garbage collector cannot see it, so a strong one made a cycle that outlived the step
    # with every trial body the energy keeps (a whole run's memory grew by them, to 2-3 GB on the
    # real horse and on Spot, a held-out cartoon cow of 2,930 vertices).
    def objective(z, gradient):
        nonlocal stop
        if stop is not None:
            return float(energy.best.energy)
        x = origin + precondition @ np.asarray(z)
        inside = np.clip(x, lower, upper)
        excess = float(np.sum((x - inside) ** 2))
        value = energy(inside) + OUT_OF_BOUNDS_PENALTY * excess
        misfits.append(energy.best.misfit)
        if energy.done() or energy.within_tolerance():
            stop = "within tolerance"
        elif len(misfits) > window and misfits[-window - 1] - misfits[-1] < STALL_DROP:
            stop = "stalled"
        if stop is not None:
            stopper().force_stop()
        return value

    algorithm = getattr(nlopt, settings.algorithm, None)
    if algorithm is None:
        raise ScalingError(f"nlopt has no algorithm {settings.algorithm!r}; use LN_BOBYQA or LN_SBPLX")
    optimiser = nlopt.opt(algorithm, count)
    stopper = weakref.ref(optimiser)
    optimiser.set_lower_bounds(np.full(count, -25.0 * radius))
    optimiser.set_upper_bounds(np.full(count, 25.0 * radius))
    optimiser.set_min_objective(objective)
    optimiser.set_ftol_rel(settings.relative_tolerance)
    optimiser.set_xtol_rel(settings.parameter_tolerance)
    optimiser.set_maxeval(int(budget))
    optimiser.set_initial_step(np.full(count, radius))
    try:
        optimiser.optimize(np.zeros(count))
        result = optimiser.last_optimize_result()
        return stop or _NLOPT_STATUS.get(result, str(result))
    except nlopt.ForcedStop:
        return stop or _NLOPT_STATUS[-5]
    except nlopt.RoundoffLimited:
        return "roundoff limited"
    except (RuntimeError, ValueError) as error:   # nlopt failure: the best trial seen is kept
        return f"nlopt failure: {error}"
