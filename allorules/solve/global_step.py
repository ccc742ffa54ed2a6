"""One step of global allometric scaling (paper §3.1, METHOD §4): the 1-D root find for α (and s)
that changes the mass by the step's ratio at unchanged peak stress.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import brentq

from allorules.body import Body
from allorules.errors import AllorulesError, MeasurementError, ScalingError
from allorules.mesh.geometry import count_flipped_faces
from allorules.spectral.basis import HarmonicBasis, transform
from allorules.spectral.power_laws import apply_to_mesh, global_allometric

# The bracket search for α widens by doubling from ALPHA_LIMIT / 256 up to ALPHA_LIMIT either way.
ALPHA_LIMIT = 1.0


ALPHA_DOUBLINGS = 8


# A step whose solution folds more than this share of the faces over is refused, not returned.
MAXIMUM_FLIPPED_SHARE = 0.001


# Solve each step's mass ratio to this relative accuracy.
RATIO_TOLERANCE = 1e-7


StressMeasure = Callable[[Body], float]


@dataclass
class _Trial:
    alpha: float
    scale: float
    mass_ratio: float
    stress_ratio: float


def _solve_step(
    body: Body,
    basis: HarmonicBasis,
    target: float,
    mass: Callable[[Body], float],
    stress: StressMeasure,
    alpha_limit: float,
    on_trial: Callable[[int, float], None] | None = None,
) -> tuple[np.ndarray, _Trial, int]:
    """Find α (and s) with ρ(α) = target; returns the new vertices, the solution, evaluations.
    ``on_trial(count, misfit)`` is told of every trial mesh (misfit: best log(ρ/r)² so far)."""
    vertices = body.vertices
    coefficients = transform(basis, vertices)
    mass_0, stress_0 = mass(body), stress(body)
    trials: list[_Trial] = []

    def trial(alpha: float) -> _Trial:
        shaped = body.with_vertices(apply_to_mesh(basis, vertices, global_allometric(coefficients, basis.eigenvalues, alpha, 1.0), 1.0,
                                                  coefficients=coefficients))
        mass_1, stress_1 = mass(shaped), stress(shaped)
        if not (np.isfinite(mass_1) and np.isfinite(stress_1) and mass_1 > 0 and stress_1 > 0):
            raise MeasurementError(f"α = {alpha:g} gives a mesh whose mass or stress cannot be measured")
        scale = stress_0 / stress_1                                  # σ(s, α) = s·σ(1, α) = σ_0
        result = _Trial(alpha, scale, scale ** 3 * mass_1 / mass_0, 1.0)  # M(s, α) = s³·M(1, α)
        trials.append(result)
        if on_trial is not None:
            on_trial(len(trials), min(math.log(t.mass_ratio / target) ** 2 for t in trials))
        return result

    def residual(alpha: float) -> float:
        return math.log(trial(alpha).mass_ratio / target)

    # Widening search for a sign change of log(ρ(α)/r), both sides of α = 0 in turn (ρ(0) = 1), so
    # that the root nearest to isometric scaling is the one found.
    zero = residual(0.0)
    bracket = None
    failures = []
    last = {1.0: (0.0, zero), -1.0: (0.0, zero)}
    alpha = alpha_limit / 2 ** ALPHA_DOUBLINGS
    while bracket is None and last and alpha <= alpha_limit * (1 + 1e-12):
        for direction in [d for d in (1.0, -1.0) if d in last]:
            previous_alpha, previous_value = last[direction]
            try:
                value = residual(direction * alpha)
            except AllorulesError as error:
                failures.append(f"α = {direction * alpha:g}: {error}")
                del last[direction]
                continue
            if np.sign(value) != np.sign(previous_value):
                bracket = sorted([(previous_alpha, previous_value), (direction * alpha, value)])
                break
            last[direction] = (direction * alpha, value)
        alpha *= 2.0
    if bracket is None:
        closest = min(trials, key=lambda t: abs(math.log(t.mass_ratio / target)))
        searched = f"[{-alpha_limit:g}, {alpha_limit:g}]"
        why = f" ({'; '.join(failures)})" if failures else ""
        raise ScalingError(
            f"no α in {searched} reaches a mass ratio of {target:.4g} at unchanged peak stress: the closest "
            f"was {closest.mass_ratio:.4g} at α = {closest.alpha:.4g}, s = {closest.scale:.4g}{why}; "
            "the load-bearing section may not respond to α (check the limb labels) — try a smaller ratio",
            closest=closest,
        )
    (low, _), (high, _) = bracket
    alpha = brentq(residual, low, high, xtol=1e-12, rtol=1e-10, maxiter=200)
    solution = trial(alpha)
    if abs(math.log(solution.mass_ratio / target)) > RATIO_TOLERANCE * 10:
        raise ScalingError(f"the root find for α did not converge (mass ratio {solution.mass_ratio:.6g} for {target:.6g})",
                           closest=solution)
    new_vertices = apply_to_mesh(basis, vertices, global_allometric(coefficients, basis.eigenvalues, alpha, solution.scale),
                                 solution.scale, coefficients=coefficients)
    flipped = count_flipped_faces(vertices, new_vertices, body.faces)
    if flipped > MAXIMUM_FLIPPED_SHARE * len(body.faces):
        raise ScalingError(
            f"the only α found ({alpha:.4g}, s = {solution.scale:.4g}) folds {flipped} of {len(body.faces)} faces over; "
            "refusing a broken mesh — use more harmonic modes (--modes) or a smaller ratio",
            closest=solution,
        )
    return new_vertices, solution, len(trials)
