"""The limbs' thickness as one more variable of a step (an extension of Eq. 9; docs/method.md,
"the limbs' thickness").

A heavier animal keeps its peak limb stress σ = M/A only with legs thicker than isometric (A ∝ M,
girth ∝ M^(1/2)). Eq. 9 has no lever for that: a leg's girth is carried by coefficients far
below the largest (|u| ≪ 1), where the gate G(u, u_j) = √(u u_j) of Eq. 7 makes the leg's α_j
about a hundred times weaker than α_0, so the solver thickens the legs through α_0 (which
reshapes every region) and puts the rest back with the regions' α at their bounds: swollen,
lumpy legs on the Princeton pig 383 at ×2, no solution at all for the donkey 385 at ×0.5
(docs/biology-scaling.md).

κ thickens every limb across its own centre line, faded in from its junction with the body, and
grows its foot with it as a whole:

    D(x) = w(f(x)) · [(1 − b(f(x))) (x − p(x))_⊥ + b(f(x)) (x − c)],
    x̃' = (Eq. 9)(x̃) + κ · s · D̃,   D̃ = Hᵀ M D,

with p(x) the point of the limb's centre line at the vertex's level of the limb's field
(:meth:`allorules.measure.limbs.Limb.offsets_across`, the line's direction taken out), w a
smoothstep from 0 at the junction to 1 at ``JUNCTION_FADE`` of the limb's length, b one from 0 to
1 over ``FOOT``, c the sole's centre (:func:`_sole_centre`), and D̃ the field's coefficients in the
step's basis (so the change is as smooth as the basis and zero outside the limbs). κ = 0 is Eq. 9;
κ = 0.1 makes the legs' girth 10 % larger than Eq. 9 made them, and each foot 10 % larger, the
same shape on the same sole. Kept still instead (b = 0, w back to 0 over ``FOOT``), a foot stayed
at Eq. 9's size while κ swelled the shin above it: the cow 381 at ×2 had hooves ×0.83-0.92 under
legs whose girth changed unevenly by 65-75 % (docs/method.md, "the limbs' thickness").
"""
from __future__ import annotations

import numpy as np

from allorules.body import Body
from allorules.measure.limbs import Limb, limb_sections
from allorules.measure.parts import LIMB_REGIONS
from allorules.mesh.geometry import smoothstep

LIMB_THICKNESS_BOUNDS = (-0.3, 0.3)   # κ per step; the real horse at ×2 used 0.07-0.21, the pig 383 0.08-0.13
JUNCTION_FADE = 0.3                   # share of the limb's length over which the thickening fades in
FOOT = (0.75, 0.9)                    # ... and the foot, below, grows as a whole (a similarity)


def thickening_field(body: Body) -> np.ndarray:
    """D of the module docstring: per vertex of ``body`` (n, 3), each limb vertex's offset across
    its limb's centre line, turning over ``FOOT`` into its offset from the sole's centre (a hoof
    or paw grows with the leg and keeps its shape; thinned across the line with the leg, the cow
    381's hoof changed shape by 37 % of its size at ×0.5), all of it rising from 0 at the junction
    over ``JUNCTION_FADE``; zero off the limbs and on a limb too short to have a centre line."""
    field = np.zeros_like(np.asarray(body.vertices, dtype=float))
    for region in LIMB_REGIONS:
        if not body.has_region(region):
            continue
        for limb in limb_sections(body, region):
            offsets, along = limb.offsets_across()
            foot = smoothstep((along - FOOT[0]) / (FOOT[1] - FOOT[0]))[:, None]
            field[limb.mesh.vertex_index] = smoothstep(along / JUNCTION_FADE)[:, None] * (
                (1.0 - foot) * offsets + foot * (limb.mesh.vertices - _sole_centre(limb)))
    return field


def _sole_centre(limb: Limb) -> np.ndarray:
    """The point of the limb's axis level with its tip: its last section's centroid moved along the
    centre line's last direction to the tip's height. The foot grows about it, so its sole spreads
    evenly about its middle and stays at its height (the tip, at a hoof's front rim, would push the
    foot back)."""
    centroids = limb.centroids
    if len(centroids) < 2:
        return np.asarray(limb.tip, dtype=float)
    direction = centroids[-1] - centroids[-2]
    length = np.linalg.norm(direction)
    if not length > 0:
        return centroids[-1]
    direction = direction / length
    return centroids[-1] + float((limb.tip - centroids[-1]) @ direction) * direction
