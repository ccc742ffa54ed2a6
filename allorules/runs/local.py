"""Local allometric scaling of one region (paper Eq. 5-7) and the paper's arithmetic variant for
comparison, with the seam strain that tells them apart.
"""
from __future__ import annotations

import math

import numpy as np

from allorules.body import Body
from allorules.errors import ScalingError, SegmentationError
from allorules.mesh.topology import unique_edges
from allorules.runs.steps import step_basis
from allorules.solve.transform import StepTransform
from allorules.spectral.basis import HarmonicBasis


def scale_region(
    body: Body,
    region: str,
    alpha: float,
    *,
    modes: int | None = None,
    basis: HarmonicBasis | None = None,
    arithmetic_factor: float | None = None,
    use_cache: bool = True,
    form: str = "per-axis",
) -> Body:
    """Local allometric scaling of one region (paper Eq. 5–7, dimensionless per METHOD §5).

    u'_i = sgn(u_i)|u_i|^(1 + α·G(u_i, u_seg,i)); α > 0 shrinks what the region shares with the
    body, α < 0 grows it, smoothly, without a seam. ``form``: ``"per-axis"`` (default, METHOD §5, in
    the animal's own axes) or ``"per-mode"`` (on each mode's coefficient vector length), see
    :class:`allorules.solve.transform.StepTransform`. ``arithmetic_factor`` = f instead applies the
    paper's bad example x̃' = x̃ + (f − 1)·x̃_seg (the region's vertices scaled by f about the
    body's centroid): for comparison only, it tears the region's boundary open.
    """
    if not body.has_region(region) or body.labels is None or not body.region_mask(region).any():
        raise SegmentationError(f"body has no region {region!r} (regions: {', '.join(body.region_names) or 'none'}); "
                                "label it first (allorules segment) or give --segmentation FILE")
    if not math.isfinite(alpha):
        raise ScalingError(f"alpha must be a finite number, got {alpha}")
    basis = basis or step_basis(body, modes, None, use_cache)
    if arithmetic_factor is not None:
        if not (math.isfinite(arithmetic_factor) and arithmetic_factor > 0):
            raise ScalingError(f"the arithmetic factor must be a positive number, got {arithmetic_factor}")
        # x̃' = x̃ + (f − 1)·x̃_seg (arithmetic_region_scaling) reconstructed with the COMPLETE basis,
        # which by linearity is x' = x + (f − 1)·I_seg ⊙ (x − centre). With a truncated basis the
        # edit would be low-passed and its tear blurred into ripples; the paper's point (Fig. 14) is
        # the tear itself.
        centre = (basis.mass @ body.vertices) / basis.mass.sum()
        mask = body.region_mask(region).astype(float)[:, None]
        return body.with_vertices(body.vertices + (arithmetic_factor - 1.0) * mask * (body.vertices - centre))
    step = StepTransform.of(body, basis, (region,), form)
    try:
        return body.with_vertices(step.vertices(np.array([1.0, 0.0, float(alpha)])))   # Eq. 6: s = 1, α_0 = 0
    except ValueError as error:
        raise ScalingError(f"alpha {alpha:g} is too large for region {region!r}: {error}") from None


def seam_strain(before: np.ndarray, after: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    """How much an edit stretches the edges across a region's boundary compared with both sides.

    Edge strain = |ℓ'/ℓ − 1|. Returns the largest strain of the edges joining a region vertex to a
    non-region vertex (``boundary``), the 99th percentile of strain over edges inside the region
    (``inside``) and outside it (``outside``), and ``seam`` = boundary / max(inside, outside): about
    1 for a seamless edit (the boundary stretches like its neighbourhood), large when it tears
    (the arithmetic variant: the region's vertices move away from their neighbours).
    """
    faces = np.asarray(faces)
    edges = unique_edges(faces)
    length_before = np.linalg.norm(before[edges[:, 0]] - before[edges[:, 1]], axis=1)
    length_after = np.linalg.norm(after[edges[:, 0]] - after[edges[:, 1]], axis=1)
    strain = np.abs(length_after / np.maximum(length_before, np.finfo(float).tiny) - 1.0)
    mask = np.asarray(mask, dtype=bool)
    first, second = mask[edges[:, 0]], mask[edges[:, 1]]

    def high(selection: np.ndarray) -> float:
        return float(np.percentile(strain[selection], 99)) if selection.any() else 0.0

    crossing = first != second
    boundary = float(strain[crossing].max()) if crossing.any() else 0.0
    inside, outside = high(first & second), high(~first & ~second)
    reference = max(inside, outside)
    return {"boundary": boundary, "inside": inside, "outside": outside,
            "seam": boundary / reference if reference > 0 else (0.0 if boundary == 0 else math.inf)}
