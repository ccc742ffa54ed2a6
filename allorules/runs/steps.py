"""How a run is cut into steps (METHOD §4/§6): the mass ratio checked, the equal step ratios
r = R^(1/n), and each step's harmonic basis.
"""
from __future__ import annotations

import math
from typing import Callable

from allorules.body import Body
from allorules.errors import BasisError, ScalingError
from allorules.spectral.basis import HarmonicBasis, compute_basis
from allorules.spectral.power_laws import relative_eigenvalues

MAXIMUM_MASS_RATIO = 1000.0


MINIMUM_MASS_RATIO = 0.001


STEP_UP = 1.1


STEP_DOWN = 0.9


def check_mass_ratio(ratio: float) -> float:
    """Refuse mass ratios that are not positive, not finite or absurd (beyond 1000 or 1/1000)."""
    try:
        ratio = float(ratio)
    except (TypeError, ValueError):
        raise ScalingError(f"mass ratio must be a number, got {ratio!r}") from None
    if not math.isfinite(ratio) or ratio <= 0:
        raise ScalingError(f"mass ratio must be a positive number, got {ratio:g} (2 doubles the mass, 0.5 halves it)")
    if ratio > MAXIMUM_MASS_RATIO or ratio < MINIMUM_MASS_RATIO:
        raise ScalingError(
            f"mass ratio {ratio:g} is absurd for one character: give a ratio between "
            f"{MINIMUM_MASS_RATIO:g} and {MAXIMUM_MASS_RATIO:g}"
        )
    return ratio


def step_ratios(ratio: float, step_up: float = STEP_UP, step_down: float = STEP_DOWN) -> list[float]:
    """n equal steps r = R^(1/n), n the smallest with r ≤ step_up (up) or r ≥ step_down (down)."""
    if not step_up > 1.0 or not 0.0 < step_down < 1.0:
        raise ValueError(f"step_up must be > 1 and step_down in (0, 1), got {step_up}, {step_down}")
    if ratio == 1.0:
        return []
    limit = step_up if ratio > 1.0 else step_down
    count = max(1, math.ceil(math.log(ratio) / math.log(limit) - 1e-12))
    return [ratio ** (1.0 / count)] * count


def step_basis(body: Body, modes: int | None, warm_start: HarmonicBasis | None, use_cache: bool,
               progress: Callable[[int, int], None] | None = None) -> HarmonicBasis:
    """A scaling step's basis on its start mesh, warm-started from the previous step's; refuses a
    mesh whose spectrum cannot be made dimensionless (λ_1 = 0: more than one piece)."""
    basis = compute_basis(body.vertices, body.faces, modes, use_cache=use_cache, warm_start=warm_start,
                          progress=progress)
    try:
        relative_eigenvalues(basis.eigenvalues)
    except ValueError as error:
        raise BasisError(f"cannot scale this mesh: {error}") from None
    return basis
