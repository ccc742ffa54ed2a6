"""The spectral algebra of allometric scaling (paper §3.1–3.3, METHOD §4–6).

Pure functions on coefficient arrays ``x̃`` of shape (m, 3) (or (m,) for one axis) and on the
basis eigenvalues. Nothing here measures a mesh or solves for parameters; the runs that do live
in :mod:`allorules.runs.global_run` (and the biology-aware solver).

Conventions, fixed here once for every caller:

* **Mode 0 (the constant mode) is never scaled.** On a connected mesh ``h_0`` is constant, so
  ``H_0 x̃_0`` is the area-weighted centroid of the surface; leaving it alone keeps that centroid
  in place. Every other mode is multiplied by the isometric factor ``s`` (and the power law).
* **The detail residual** ``d = x − H x̃`` (what lies beyond the m-th mode, METHOD §2) is added
  back scaled by ``s``: ``x' = H x̃' + s·d``. :func:`apply_to_mesh` evaluates this as
  ``x' = s·x + H (x̃' − s·x̃)``, which is algebraically the same and makes the identity edit
  (``x̃' = x̃``, ``s = 1``) return the input bit for bit.
* **Dimensionless forms.** Eigenvalues enter as ``λ_i / λ_1`` (λ scales as 1/length², so the
  ratio does not depend on the mesh's units); coefficients enter the local power laws as
  ``u = x̃ / c`` with ``c = max_{i≥1} |x̃_i|`` per axis (METHOD §5, :func:`dimensionless`), or —
  the *per-mode* form, which does not depend on the mesh's orientation — as the length of each
  mode's coefficient vector, ``ρ_i = ‖x̃_i‖ / max_{k≥1} ‖x̃_k‖``, with the region's share of the
  mode its signed projection on that vector (:func:`mode_magnitudes`, :func:`mode_shares`,
  :func:`from_mode_magnitudes`; docs/method.md says when each is used and why).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from allorules.spectral.basis import HarmonicBasis, reconstruct, transform

__all__ = [
    "relative_eigenvalues",
    "global_allometric",
    "dimensionless",
    "from_dimensionless",
    "edited_coefficients",
    "mode_magnitudes",
    "mode_shares",
    "from_mode_magnitudes",
    "geometric_mean_gate",
    "local_power_law",
    "multi_region_power_law",
    "arithmetic_region_scaling",
    "apply_to_mesh",
    "detail_taper",
    "DetailLayer",
]


def relative_eigenvalues(eigenvalues: np.ndarray) -> np.ndarray:
    """λ_i / λ_1 for every mode (entry 0 is λ_0/λ_1 ≈ 0 and is never used as a factor).

    Raises ``ValueError`` when λ_1 is not clearly positive: then the mesh has more than one
    connected part (or the basis is broken) and λ/λ_1 means nothing.
    """
    eigenvalues = np.asarray(eigenvalues, dtype=float)
    if eigenvalues.ndim != 1 or len(eigenvalues) < 2:
        raise ValueError("need at least two eigenvalues (λ_0 and λ_1)")
    first = float(eigenvalues[1])
    if not np.isfinite(first) or first <= 1e-10 * max(float(np.max(np.abs(eigenvalues))), np.finfo(float).tiny):
        raise ValueError(
            f"λ_1 = {first:.3g} is not positive: the mesh is not one connected surface "
            "(scale the largest connected part, carry small parts along)"
        )
    return eigenvalues / first


def _broadcast_modes(factors: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    return factors[:, None] if coefficients.ndim == 2 else factors


def global_allometric(coefficients: np.ndarray, eigenvalues: np.ndarray, alpha: float, scale: float) -> np.ndarray:
    """Global allometric scaling (paper Eq. 4, made unit-free by λ_1; METHOD §4).

    x̃'_i = s · x̃_i · (λ_i / λ_1)^α   for i ≥ 1,
    x̃'_0 = x̃_0                        (the constant mode: the centroid stays in place).

    Since λ_i/λ_1 ≥ 1 and grows with frequency, α > 0 amplifies the fine (high-frequency)
    modes relative to the coarse ones and α < 0 damps them; α = 0 is isometric scaling by s.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    if len(coefficients) != len(eigenvalues):
        raise ValueError(f"{len(coefficients)} coefficients but {len(eigenvalues)} eigenvalues")
    if not np.isfinite(alpha) or not np.isfinite(scale):
        raise ValueError(f"alpha and scale must be finite, got alpha={alpha}, scale={scale}")
    if alpha == 0.0 and scale == 1.0:
        return coefficients.copy()
    factors = np.empty(len(eigenvalues))
    factors[0] = 1.0
    ratio = relative_eigenvalues(eigenvalues)[1:]
    # Eigenvalues of a PSD problem are ≥ 0; round-off may leave a tiny negative λ_i, i ≥ 1, only on
    # a broken basis, which relative_eigenvalues already refused (λ_i ≥ λ_1 > 0 for i ≥ 1).
    factors[1:] = scale * np.power(ratio, alpha)
    return coefficients * _broadcast_modes(factors, coefficients)


def dimensionless(coefficients: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(u, c)`` with ``u = x̃ / c`` and ``c = max_{i≥1} |x̃_i|`` per axis (METHOD §5).

    After this, |u_i| ≤ 1 for every i ≥ 1 and u does not depend on the mesh's units. An axis
    whose non-constant coefficients are all zero (a flat mesh seen edge-on) gets c = 1, so that
    u stays finite and the power laws leave it unchanged.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    if len(coefficients) < 2:
        raise ValueError("need at least two modes")
    c = np.max(np.abs(coefficients[1:]), axis=0)
    c = np.where(c > 0, c, 1.0)
    return coefficients / c, np.asarray(c, dtype=float)


def from_dimensionless(u: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Back from the dimensionless form: x̃ = c · u (per axis)."""
    return np.asarray(u, dtype=float) * np.asarray(c, dtype=float)


def edited_coefficients(coefficients: np.ndarray, u: np.ndarray, u_new: np.ndarray, c: np.ndarray) -> np.ndarray:
    """x̃' = x̃ + c·(u' − u): the same as ``from_dimensionless(u', c)`` up to round-off, but exactly
    ``coefficients`` where the edit left u unchanged — so an identity edit stays bit-exact
    (c·(x̃/c) is not always x̃ in floating point). Use this to hand edits to :func:`apply_to_mesh`.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    return coefficients + np.asarray(c, dtype=float) * (np.asarray(u_new, dtype=float) - np.asarray(u, dtype=float))


def mode_magnitudes(coefficients: np.ndarray) -> tuple[np.ndarray, float]:
    """``(ρ, c)``: each mode's coefficient vector length over the largest, ρ_i = ‖x̃_i‖ / c with
    c = max_{i≥1} ‖x̃_i‖ (the per-mode dimensionless form).

    Lengths and their ratios do not change when the mesh is rotated or its units change, so power
    laws on ρ do not depend on the mesh's orientation (per-axis u = x̃ / c does: a rotation mixes
    the axes, and each axis is raised to its own power). For a 1-D signal ρ = |u|.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    if coefficients.ndim != 2 or len(coefficients) < 2:
        raise ValueError("need (m, 3) coefficients with at least two modes")
    lengths = np.linalg.norm(coefficients, axis=1)
    c = float(np.max(lengths[1:]))
    c = c if c > 0 else 1.0
    return lengths / c, c


def mode_shares(region_coefficients: np.ndarray, coefficients: np.ndarray, c: float) -> np.ndarray:
    """A region's signed share of each mode, p_i = (x̃_seg,i · x̃_i) / (‖x̃_i‖ c): the projection of
    the region's coefficient vector (Eq. 5) on the body's, in the units of :func:`mode_magnitudes`.

    It plays u_seg's part in the gate G(ρ_i, p_i) of Eq. 7: positive where the region pulls the
    mode the way the body does (then G = √(ρ_i p_i)), 0 or negative where it does not (G = 0).
    For a 1-D signal it is sgn(u_i)·u_seg,i, and G is the paper's.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    region_coefficients = np.asarray(region_coefficients, dtype=float)
    lengths = np.linalg.norm(coefficients, axis=1)
    projection = np.einsum("ij,ij->i", region_coefficients, coefficients)
    return np.where(lengths > 0, projection / np.where(lengths > 0, lengths, 1.0), 0.0) / c


def from_mode_magnitudes(coefficients: np.ndarray, rho: np.ndarray, rho_new: np.ndarray) -> np.ndarray:
    """x̃'_i = x̃_i · ρ'_i / ρ_i: each mode's vector keeps its direction and takes its new length.
    Exactly ``coefficients`` where ρ' = ρ (the identity edit stays bit-exact)."""
    coefficients = np.asarray(coefficients, dtype=float)
    rho, rho_new = np.asarray(rho, dtype=float), np.asarray(rho_new, dtype=float)
    unchanged = rho_new == rho
    factor = np.where(unchanged | (rho == 0), 1.0, rho_new / np.where(rho > 0, rho, 1.0))
    return np.where(unchanged[:, None], coefficients, coefficients * factor[:, None])


def geometric_mean_gate(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """G(a, b) of paper Eq. 7: √(ab) if ab > 0, else 0 (elementwise).

    Signed inputs: for two negative numbers G is √(ab) > 0 as well (same sign ⇒ scale,
    opposite signs or a zero ⇒ leave alone).
    """
    product = np.asarray(a, dtype=float) * np.asarray(b, dtype=float)
    return np.where(product > 0, np.sqrt(np.where(product > 0, product, 0.0)), 0.0)


def _signed_power(u: np.ndarray, exponent: np.ndarray) -> np.ndarray:
    """sgn(u)|u|^p, with 0 ↦ 0 for any p > 0; refuses exponents ≤ 0 (they blow up small u)."""
    exponent = np.broadcast_to(np.asarray(exponent, dtype=float), np.shape(u))
    if np.any(exponent <= 0) or not np.all(np.isfinite(exponent)):
        raise ValueError(
            f"power-law exponent 1 + α·G must stay positive (smallest is {float(np.min(exponent)):.3g}); "
            "use smaller α"
        )
    magnitude = np.abs(u)
    safe = magnitude > 0
    result = np.zeros_like(u, dtype=float)
    result[safe] = np.sign(u[safe]) * np.power(magnitude[safe], exponent[safe])
    return result


def local_power_law(u: np.ndarray, u_region: np.ndarray, alpha: float) -> np.ndarray:
    """Local allometric scaling (paper Eq. 6 on the dimensionless form, METHOD §5).

    u'_i = sgn(u_i) |u_i|^(1 + α·G(u_i, u_region,i))   for i ≥ 1;   u'_0 = u_0.

    ``u_region`` is the transform of the region's vertices alone (Eq. 5) divided by the SAME c as
    ``u``. Since |u_i| ≤ 1, α > 0 shrinks the modes the region shares with the body, α < 0 grows them.
    """
    return multi_region_power_law(u, [u_region], [alpha], 0.0, 1.0)


def multi_region_power_law(
    u: np.ndarray,
    region_us: Sequence[np.ndarray],
    alphas: Sequence[float],
    alpha0: float,
    scale: float,
) -> np.ndarray:
    """Biology-aware scaling (paper Eq. 9, METHOD §6), dimensionless.

    u'_i = s · sgn(u_i) |u_i|^(1 + α_0 + Σ_j α_j G(u_i, u_j,i))   for i ≥ 1;   u'_0 = u_0.

    Returns u'; the new coefficients are ``edited_coefficients(x̃, u, u', c)`` (= c·u') and the
    mesh is ``apply_to_mesh(basis, vertices, those, detail_scale=s)``. With α_0 = 0, all α_j = 0 and
    s = 1 the input is returned exactly.
    """
    u = np.asarray(u, dtype=float)
    if len(region_us) != len(alphas):
        raise ValueError(f"{len(region_us)} regions but {len(alphas)} alphas")
    if not np.isfinite(scale) or not np.isfinite(alpha0) or not all(np.isfinite(a) for a in alphas):
        raise ValueError("scale and alphas must be finite")
    if alpha0 == 0.0 and scale == 1.0 and all(a == 0.0 for a in alphas):
        return u.copy()
    exponent = np.full(u.shape, 1.0 + alpha0)
    for region_u, alpha in zip(region_us, alphas):
        region_u = np.asarray(region_u, dtype=float)
        if region_u.shape != u.shape:
            raise ValueError(f"region coefficients have shape {region_u.shape}, expected {u.shape}")
        if alpha != 0.0:
            exponent = exponent + alpha * geometric_mean_gate(u, region_u)
    result = u.copy()
    result[1:] = scale * _signed_power(u[1:], exponent[1:])
    return result


def stretch_first_axis(u: np.ndarray, gate: np.ndarray, stretch: float) -> np.ndarray:
    """The trunk's stretch (docs/method.md, "the trunk's length"; an extension of Eq. 9), per axis:

        u'_i,0 = u_i,0 · (1 + δ · g_i)   for i ≥ 1;   the other axes and mode 0 untouched,

    with axis 0 the animal's forward axis and g_i = G(u_i,0, u_T,i,0) the gate of Eq. 7 between the
    body's and the trunk's forward coefficients. Eq. 9's power law barely moves coefficients near
    |u| = 1, which carry a region's extent; this factor does, so the trunk can grow longer without
    growing round. δ = 0 returns ``u`` unchanged."""
    result = np.array(u, dtype=float, copy=True)
    if stretch != 0.0:
        result[1:, 0] *= 1.0 + stretch * np.asarray(gate, dtype=float)[1:]
    return result


def arithmetic_region_scaling(coefficients: np.ndarray, region_coefficients: np.ndarray, factor: float) -> np.ndarray:
    """The paper's bad example (§3.2, Fig. 14), for comparison only.

    x̃' = x̃ + (f − 1)·x̃_seg, i.e. the transform of "multiply the region's vertices by f": by
    linearity of the MHT it is exactly scaling the segmented vertex set, so the region's
    boundary tears open (a jump of (f − 1)·x at the edge). Mode 0 included, like the paper.
    """
    coefficients = np.asarray(coefficients, dtype=float)
    region_coefficients = np.asarray(region_coefficients, dtype=float)
    return coefficients + (factor - 1.0) * region_coefficients


def apply_to_mesh(
    basis: HarmonicBasis,
    vertices: np.ndarray,
    new_coefficients: np.ndarray,
    detail_scale: float,
    *,
    coefficients: np.ndarray | None = None,
) -> np.ndarray:
    """New vertex positions from edited coefficients, keeping the detail beyond the m-th mode.

    x' = H x̃' + s·d  with  d = x − H x̃   (METHOD §2), evaluated as  x' = s·x + H (x̃' − s·x̃)
    so that the identity edit returns ``vertices`` exactly. ``coefficients`` (= Hᵀ D x) may be
    passed when already known. Raises ``ValueError`` rather than returning NaN.
    """
    vertices = np.asarray(vertices, dtype=float)
    if coefficients is None:
        coefficients = transform(basis, vertices)
    new_coefficients = np.asarray(new_coefficients, dtype=float)
    if new_coefficients.shape != coefficients.shape:
        raise ValueError(f"new coefficients have shape {new_coefficients.shape}, expected {coefficients.shape}")
    if not np.all(np.isfinite(new_coefficients)) or not np.isfinite(detail_scale):
        raise ValueError("edited coefficients are not finite")
    change = new_coefficients - detail_scale * coefficients
    if detail_scale == 1.0 and not np.any(change):
        return vertices.copy()
    result = detail_scale * vertices + reconstruct(basis, change)
    if not np.all(np.isfinite(result)):
        raise ValueError("scaled vertices are not finite")
    return result


def detail_taper(eigenvalues: np.ndarray, area: float, cutoff_modes: float | None) -> np.ndarray:
    """Per mode, how much of an edit of the coefficients reaches the mesh: 1 for the coarse modes
    that carry the body's proportions, 0 for the fine modes that carry its small features.

    The cutoff is a wavelength, not a mode number, so that it does not depend on the mesh's
    tessellation or units: λ_c = 4π·K / A (A the surface area), the eigenvalue of mode K of a
    surface of area A by Weyl's law (λ_k ≈ 4πk/A), i.e. wavelengths about √(πA/K). Modes with
    λ ≤ λ_c get 1; between λ_c and 4λ_c (wavelength halved) the weight falls smoothly,
    w = cos²(π/2 · log(λ/λ_c)/log 4); beyond it, 0. ``cutoff_modes=None``: every mode gets 1
    (the paper's Eq. 4/9 on the whole spectrum). Mode 0 always gets 1.
    """
    eigenvalues = np.asarray(eigenvalues, dtype=float)
    weights = np.ones(len(eigenvalues))
    if cutoff_modes is None:
        return weights
    if not (np.isfinite(cutoff_modes) and cutoff_modes > 0 and area > 0):
        raise ValueError(f"the detail cutoff must be a positive number of modes, got {cutoff_modes}")
    cutoff = 4.0 * np.pi * float(cutoff_modes) / float(area)
    ratio = np.maximum(eigenvalues, 0.0) / cutoff
    above = ratio > 1.0
    position = np.log(np.where(above, ratio, 1.0)) / np.log(4.0)
    weights = np.where(above, np.cos(0.5 * np.pi * np.clip(position, 0.0, 1.0)) ** 2, 1.0)
    weights[0] = 1.0
    return weights


class DetailLayer:
    """The surface split into a smooth base and the detail on it, so that an edit of the
    coefficients reshapes the body and leaves its small features their shape (METHOD §10).

    ``x = b + d`` with the base b = H (w ⊙ x̃) (the coarse modes, weighted by the
    :func:`detail_taper` w) and the detail d = x − b (the fine modes and everything beyond the
    m-th mode: horns, ears, eyes, hooves, the tail's tip). An edit x̃ → x̃' moves the base by
    Δb = H (w ⊙ (x̃' − x̃)) and scales the detail by the base's own change of size σ:

        x' = b + Δb + σ · d,    σ² = Σ_i D_i |b'_i − c|² / Σ_i D_i |b_i − c|²

    (c the area-weighted centroid, which mode 0 keeps; σ is the ratio of the base's RMS radius
    after and before). Uniform scaling by s gives σ = s and x' = c + s (x − c) exactly; the
    identity edit gives x exactly. The paper's Eq. 9 instead changes every mode by its own factor
    s·|u_i|^(α_0 + Σ α_j G) and METHOD §2 adds the detail back × s: the fine modes of one small
    feature then change by different factors (it stretches, thins or curls) and, where the power
    laws shrink the body below s (at ×2 the product of the steps' s is 1.37 while the body grows
    by 1.26), the detail outgrows the body (horns, ears and eyes bulge). See docs/method.md (solver.detail_cutoff; off by default).
    """

    def __init__(self, basis: HarmonicBasis, vertices: np.ndarray, coefficients: np.ndarray, taper: np.ndarray):
        self.basis = basis
        self.vertices = np.asarray(vertices, dtype=float)
        self.coefficients = np.asarray(coefficients, dtype=float)
        self.taper = np.asarray(taper, dtype=float)
        self.base = reconstruct(basis, self.taper[:, None] * self.coefficients)
        self.detail = self.vertices - self.base
        self._weights = basis.mass / basis.mass.sum()
        self._centre = self._weights @ self.vertices
        self._spread = self._rms_radius(self.base)

    def _rms_radius(self, points: np.ndarray) -> float:
        offset = points - self._centre
        return float(np.sqrt(self._weights @ np.einsum("ij,ij->i", offset, offset)))

    def apply(self, new_coefficients: np.ndarray) -> np.ndarray:
        """Vertices for edited coefficients x̃' (the whole edit, isometric factor included)."""
        change = self.taper[:, None] * (np.asarray(new_coefficients, dtype=float) - self.coefficients)
        if not np.any(change):
            return self.vertices.copy()
        moved = self.base + reconstruct(self.basis, change)
        scale = self._rms_radius(moved) / self._spread if self._spread > 0 else 1.0
        result = moved + scale * self.detail
        if not np.all(np.isfinite(result)):
            raise ValueError("scaled vertices are not finite")
        return result
