"""allorules plugin: the constraint ``aquatic-locomotion`` for swimming and wading animals.

Two residuals, both dimensionless and 0 when met, for a step with body-mass ratio r:

``limb-stress`` = (1 − b) · (σ(candidate) / σ(initial) − 1)
    Water carries the fraction ``buoyancy`` = b of the body's weight (b ≈ 1 for an animal
    as dense as water and fully submerged, 0 on land), so the limbs carry (1 − b) M g. Their
    peak stress then matters in proportion to the share of the weight they bear: b = 0 is the
    built-in ``terrestrial-limb-stress`` (keep σ = M/A, Biewener 1990), b = 1 removes the
    limb-stress requirement altogether. (The factor enters the energy squared.) Use this
    constraint *instead of* ``terrestrial-limb-stress`` (remove that one in the ruleset).

``fineness`` = streamlining · (F(candidate) / F(initial) − 1)
    F is the fineness ratio, body length over body diameter; the drag of a swimmer depends
    on it (lowest near 4.5 for streamlined bodies, Webb 1975), and keeping F keeps the
    original's streamlining at the new size. Length is the extent along the body's forward
    direction (its principal axis when the body has no frame), diameter 2√2 (λ_a λ_b)^(1/4)
    from the variances across it (2R for a round body of radius R); points are face
    centroids weighted by area, so F depends neither on the mesh's size and orientation nor
    (much) on its tessellation. ``streamlining`` = 0 drops it.

Use: ``pip install plugins/allorules-swimming`` (entry point ``swimming``), or
``--plugin path/to/allorules_swimming.py``, or ``plugins: [allorules_swimming.py]`` in a
ruleset (see ``otter.yaml`` next to this file).
"""
from __future__ import annotations

import numpy as np

from allorules.errors import MeasurementError
from allorules.plugins import ConstraintSpec, ParameterSpec, hookimpl


def fineness_ratio(body) -> float:
    """Body length over body diameter (see the module docstring): dimensionless.

    Length: the extent of the surface along the body's forward direction (its frame) or, without
    a frame, along the principal axis of largest spread. Diameter: 2√2 (λ_a λ_b)^(1/4), with
    λ_a, λ_b the variances of the surface across that axis; exactly 2R for a circular
    cross-section of radius R, and unchanged by any rotation about the axis.
    """
    corners = body.vertices[body.faces]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    total = areas.sum()
    if not np.isfinite(total) or total <= 0:
        raise MeasurementError("aquatic-locomotion: the surface has no area (degenerate or NaN vertices)")
    weights = areas / total
    points = corners.mean(axis=1)                 # face centroids, weighted by area
    centred = points - weights @ points
    covariance = (centred * weights[:, None]).T @ centred
    if body.frame is not None:
        forward = np.asarray(body.frame.forward, dtype=float)
        forward = forward / np.linalg.norm(forward)
    else:
        forward = np.linalg.eigh(covariance)[1][:, -1]
    # an orthonormal basis of the plane across the body (any one: the determinant below is invariant)
    helper = np.eye(3)[np.argmin(np.abs(forward))]
    side = np.cross(forward, helper)
    side /= np.linalg.norm(side)
    across = np.column_stack([side, np.cross(forward, side)])
    cross_section = across.T @ covariance @ across
    along = centred @ forward
    length = along.max() - along.min()
    diameter = 2.0 * np.sqrt(2.0) * max(np.linalg.det(cross_section), 0.0) ** 0.25
    if not diameter > 0:
        raise MeasurementError("aquatic-locomotion: the body is flat; its fineness ratio is undefined")
    return float(length / diameter)


def aquatic_residuals(context, parameters) -> dict[str, float]:
    buoyancy = float(parameters["buoyancy"])
    streamlining = float(parameters["streamlining"])
    residuals = {}
    if buoyancy < 1.0:
        stress_ratio = (context.measure("stress", context.candidate, None)
                        / context.measure("stress", context.initial, None))
        residuals["limb-stress"] = (1.0 - buoyancy) * (stress_ratio - 1.0)
    if streamlining > 0.0:
        residuals["fineness"] = streamlining * (fineness_ratio(context.candidate) / fineness_ratio(context.initial) - 1.0)
    return residuals


@hookimpl
def allorules_constraints():
    return [ConstraintSpec(
        name="aquatic-locomotion",
        description="buoyancy b relieves limb stress (residual scaled by 1 − b); fineness ratio kept",
        residuals=aquatic_residuals,
        parameters={
            "buoyancy": ParameterSpec(0.5, "fraction of the body weight carried by water (0 land, 1 floating)",
                                      minimum=0.0, maximum=1.0),
            "streamlining": ParameterSpec(1.0, "factor on the fineness residual (0 ignores streamlining)",
                                          minimum=0.0, maximum=10.0),
        },
    )]
