"""Global allometric scaling runs (paper §3.1, METHOD §4): from a mass ratio to a mesh.

The user asks for a mass ratio R. Each step solves for the global allometric exponent α and the
isometric factor s of Eq. 4 (:func:`allorules.spectral.power_laws.global_allometric`) so that the body's mass
changes by the step's ratio r and its peak stress σ = M/A stays as it was:

* For a trial α the mesh is reconstructed with s = 1 and measured: M(1, α), σ(1, α).
* Isometric scaling multiplies mass by s³ and stress by s (σ = s³M / s²A), so s = σ_0 / σ(1, α)
  keeps the stress, and the mass ratio reached is ρ(α) = s³·M(1, α) / M_0.
* One equation in one unknown remains, ρ(α) = r: bracketed by a widening search around α = 0
  (ρ(0) = 1) and solved with Brent's method.

A ratio beyond 1.1 up (0.9 down) goes in n equal steps r = R^(1/n), the harmonic basis recomputed
on each step's mesh (warm-started from the previous one), as in the paper.

**Where stress is measured.** The candidate load-bearing cross-sections are chosen ONCE, on the
input body, by the rule of :func:`allorules.measure.stress.load_bearing_section` (every limb section
between the junction and tip margins; or only the user's
:class:`~allorules.measure.stress.SectionChoice`), and then followed as material bands: the same
isocontour level of the same limb field on the same vertices (:class:`MaterialBand`). The mesh
keeps its connectivity, so each contour crosses the same edges at the same parameters and only
moves with them. A is the smallest band's area (:class:`StressGauge`). Stress before and after
every trial, step and run is therefore measured at the same places on the limbs, never
re-chosen from new contours; the peak may still move from one band to another if the shape
change moves it. (Re-choosing from scratch on the output is reported separately, as an
independent check.)

Mass is the enclosed volume of the capped body (:func:`allorules.measure.mass.body_mass`).
"""
from __future__ import annotations

import logging
import math
from typing import Callable

import numpy as np

from allorules.body import Body
from allorules.errors import ScalingError
from allorules.measure.stress import StressGauge
from allorules.mesh.geometry import count_flipped_faces
from allorules.runs.progress import RunProgress
from allorules.runs.results import ScalingResult, ScalingStep
from allorules.runs.steps import (
    STEP_DOWN,
    STEP_UP,
    check_mass_ratio,
    step_basis,
    step_ratios,
)
from allorules.solve.global_step import ALPHA_LIMIT, StressMeasure, _solve_step
from allorules.spectral.basis import transform
from allorules.spectral.power_laws import apply_to_mesh, global_allometric

log = logging.getLogger("allorules")


# ---------------------------------------------------------------------------------------------
# Stress measured at a fixed material band


# ---------------------------------------------------------------------------------------------
# Results


# ---------------------------------------------------------------------------------------------
# Helpers


def _default_mass(body: Body) -> float:
    from allorules.measure.mass import body_mass

    return body_mass(body)


# ---------------------------------------------------------------------------------------------
# One step: the 1-D root find


# ---------------------------------------------------------------------------------------------
# Runs


def scale_globally(
    body: Body,
    mass_ratio: float,
    *,
    modes: int | None = None,
    stress: StressMeasure | None = None,
    mass: Callable[[Body], float] | None = None,
    section=None,
    step_up: float = STEP_UP,
    step_down: float = STEP_DOWN,
    alpha_limit: float = ALPHA_LIMIT,
    use_cache: bool = True,
    progress: RunProgress | None = None,
) -> ScalingResult:
    """Scale ``body`` so that its mass changes by ``mass_ratio`` with peak stress unchanged.

    ``stress`` (Body → σ) replaces the default, which freezes the load-bearing limb section of
    the input (``section``: an optional :class:`allorules.measure.stress.SectionChoice`) and follows it
    (:class:`StressGauge`); the default needs a labelled body with a limb region. ``mass``
    replaces :func:`allorules.measure.mass.body_mass`. ``progress`` is told of the steps, each basis
    and each trial (:class:`allorules.runs.progress.RunProgress`). Raises :class:`ScalingError` (with
    ``closest`` = the partial result) when a step's α cannot be found.
    """
    target = check_mass_ratio(mass_ratio)
    ratios = step_ratios(target, step_up, step_down)
    mass = mass or _default_mass
    gauge = None
    if stress is None:
        gauge = StressGauge.choose(body, override=section)
        stress = gauge.stress
    initial = body
    mass_initial, stress_initial = mass(initial), stress(initial)
    result = ScalingResult(body=initial, target_mass_ratio=target, section=gauge.describe(initial.vertices) if gauge else None)
    basis = None
    current = initial
    progress = progress or RunProgress()
    for index, ratio in enumerate(ratios):
        progress.step_started(index + 1, len(ratios))
        basis = step_basis(current, modes, basis, use_cache, progress.basis)
        try:
            new_vertices, solution, evaluations = _solve_step(current, basis, ratio, mass, stress, alpha_limit,
                                                              progress.trial)
        except ScalingError as error:
            result.body = current
            _finish(result, initial, mass_initial, stress_initial, mass, stress)
            result.messages.append(f"step {index + 1} of {len(ratios)}: {error}")
            raise ScalingError(
                f"step {index + 1} of {len(ratios)} failed after reaching a mass ratio of {result.mass_ratio:.4g} "
                f"of the requested {target:.4g}: {error}",
                closest=result,
            ) from None
        following = current.with_vertices(new_vertices)
        step = ScalingStep(
            alpha=solution.alpha,
            scale=solution.scale,
            target_mass_ratio=ratio,
            mass_ratio=mass(following) / mass(current),
            stress_ratio=stress(following) / stress(current),
            modes=basis.modes,
            flipped_faces=count_flipped_faces(current.vertices, following.vertices, current.faces),
            evaluations=evaluations,
        )
        result.steps.append(step)
        log.debug("step %d/%d: α = %.5f, s = %.5f, mass ×%.5f, stress ×%.5f", index + 1, len(ratios),
                  step.alpha, step.scale, step.mass_ratio, step.stress_ratio)
        current = following
        progress.step_finished(index + 1, len(ratios))
    result.body = current
    _finish(result, initial, mass_initial, stress_initial, mass, stress)
    result.converged = (abs(math.log(result.mass_ratio / target)) < 1e-4 and abs(math.log(result.stress_ratio)) < 1e-4)
    if not result.converged:
        result.messages.append(
            f"reached mass ratio {result.mass_ratio:.6g} (target {target:.6g}) and stress ratio {result.stress_ratio:.6g}"
        )
    return result


def _finish(result: ScalingResult, initial: Body, mass_initial: float, stress_initial: float, mass, stress) -> None:
    final = result.body
    result.mass_ratio = mass(final) / mass_initial
    result.stress_ratio = stress(final) / stress_initial
    result.flipped_faces = count_flipped_faces(initial.vertices, final.vertices, initial.faces)
    if not np.all(np.isfinite(final.vertices)):   # never hand back a NaN mesh as a result
        raise ScalingError("the scaled mesh has non-finite vertices; nothing was written")


def scale_globally_raw(
    body: Body,
    alpha: float,
    scale: float = 1.0,
    modes: int | None = None,
    *,
    use_cache: bool = True,
) -> Body:
    """Eq. 4 applied once with the user's α and s (no measuring, no stress constraint)."""
    if not (math.isfinite(alpha) and math.isfinite(scale)):
        raise ScalingError(f"alpha and scale must be finite numbers, got {alpha}, {scale}")
    if scale <= 0:
        raise ScalingError(f"scale must be positive, got {scale:g}")
    if abs(alpha) > ALPHA_LIMIT:
        raise ScalingError(f"|alpha| = {abs(alpha):g} is beyond {ALPHA_LIMIT:g}: the fine modes would be scaled "
                           "by absurd factors; typical values are within ±0.2")
    basis = step_basis(body, modes, None, use_cache)
    coefficients = transform(basis, body.vertices)
    vertices = apply_to_mesh(basis, body.vertices, global_allometric(coefficients, basis.eigenvalues, alpha, scale), scale,
                             coefficients=coefficients)
    return body.with_vertices(vertices)
