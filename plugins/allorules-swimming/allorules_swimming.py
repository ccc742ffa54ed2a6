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
    direction (its principal axis when the body has no frame), diameter the geometric mean
    of the extents across it; points are face centroids weighted by area, so F does not
    depend on the mesh's size, orientation or tessellation. ``streamlining`` = 0 drops it.

Use: ``pip install plugins/allorules-swimming`` (entry point ``swimming``), or
``--plugin path/to/allorules_swimming.py``, or ``plugins: [allorules_swimming.py]`` in a
ruleset (see ``otter.yaml`` next to this file).
"""
from __future__ import annotations

import numpy as np

from allorules.errors import MeasurementError
from allorules.hookspecs import hookimpl
from allorules.specs import ConstraintSpec, ParameterSpec


def fineness_ratio(body) -> float:
    """Body length over body diameter (see the module docstring): dimensionless."""
    corners = body.vertices[body.faces]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    total = areas.sum()
    if not np.isfinite(total) or total <= 0:
        raise MeasurementError("aquatic-locomotion: the surface has no area (degenerate or NaN vertices)")
    weights = areas / total
    points = corners.mean(axis=1)
    centred = points - weights @ points
    covariance = (centred * weights[:, None]).T @ centred
    _, axes = np.linalg.eigh(covariance)          # columns by increasing variance
    if body.frame is not None:                    # length along the anatomical forward axis
        forward = np.asarray(body.frame.forward, dtype=float)
        forward = forward / np.linalg.norm(forward)
        across = axes - np.outer(forward, forward @ axes)
        # the two principal directions most orthogonal to forward, made orthonormal
        order = np.argsort(-np.linalg.norm(across, axis=0))[:2]
        side, _ = np.linalg.qr(across[:, order])
        axes = np.column_stack([side, forward])
    projected = centred @ axes
    extents = projected.max(axis=0) - projected.min(axis=0)
    length, diameter = extents[2], np.sqrt(extents[0] * extents[1])
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
