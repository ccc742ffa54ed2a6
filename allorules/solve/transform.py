"""The step's transform (paper Eq. 9, dimensionless per METHOD §5/§6): from the variables
(s, α_0, α_j) to the trial mesh, in the animal's own axes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from allorules.body import Body
from allorules.measure.frame import regions_frame
from allorules.measure.parts import TORSO_REGIONS
from allorules.rules.model import TRANSFORM_FORMS
from allorules.solve.held_regions import HeldRegions
from allorules.solve.limb_thickness import thickening_field
from allorules.solve.posture import FootContact, LimbFolds
from allorules.spectral.basis import HarmonicBasis, transform
from allorules.spectral.power_laws import (
    DetailLayer,
    apply_to_mesh,
    detail_taper,
    dimensionless,
    from_mode_magnitudes,
    geometric_mean_gate,
    mode_magnitudes,
    mode_shares,
    multi_region_power_law,
    stretch_first_axis,
)


def anatomical_axes(body: Body) -> np.ndarray:
    """The animal's own axes as rows (forward, up, side), orthonormal and right-handed, in mesh
    coordinates: from ``body.frame`` (the labeller's, a labels file's, or read off the regions by
    the run pipeline); else read off the regions here (:func:`allorules.measure.frame.regions_frame`);
    else the mesh's own axes."""
    frame = body.frame if body.frame is not None else regions_frame(body)
    forward = up = None
    if frame is not None:
        forward, up = np.asarray(frame.forward, dtype=float), np.asarray(frame.up, dtype=float)
    if forward is None or up is None or np.linalg.norm(np.cross(forward, up)) < 1e-9 * np.linalg.norm(forward) * np.linalg.norm(up):
        return np.eye(3)
    forward = forward / np.linalg.norm(forward)
    up = up - (up @ forward) * forward
    up = up / np.linalg.norm(up)
    return np.array([forward, up, np.cross(forward, up)])


@dataclass(frozen=True)
class StepVariables:
    """One point of a step's variables by name (:meth:`StepTransform.unpack`)."""

    scale: float                      # s
    alpha0: float                     # α_0
    alphas: tuple[float, ...]         # α_j, in the order of StepTransform.regions
    trunk_stretch: float | None       # δ, when the trunk's stretch is on
    limb_thickness: float | None      # κ, when the limbs' thickness is on
    sizes: dict[str, float]           # σ (size − 1) of each region held at its rule's size


@dataclass
class StepTransform:
    """Everything Eq. 9 needs on the step's start body: coefficients, c, the regions' u_j.

    ``form`` is how coefficients are made dimensionless (:mod:`allorules.spectral.power_laws`): ``"per-axis"``
    (METHOD §5: u = x̃ / c per axis, the power law on each axis) or ``"per-mode"`` (ρ_i = ‖x̃_i‖ / c,
    the power law on each mode's vector length, its direction kept; u_j = the region's share of
    the mode). ``u`` and each ``region_us[j]`` are (m, 3) per axis and (m,) per mode.
    """

    body: Body
    basis: HarmonicBasis
    regions: tuple[str, ...]
    coefficients: np.ndarray
    u: np.ndarray
    c: np.ndarray | float
    region_us: list[np.ndarray]
    form: str = "per-axis"
    axes: np.ndarray | None = None     # per-axis: rows forward, up, side of the animal (mesh coordinates)
    feet: FootContact | None = None    # posture keep: the feet put back after Eq. 9 (allorules.solve.posture)
    folds: LimbFolds | None = None     # posture keep: folded legs given their folds back after Eq. 9 (the same)
    detail: DetailLayer | None = None  # solver.detail_cutoff: Eq. 9 on the base, the detail following it
    held: HeldRegions | None = None    # open regions held as a similarity of their input shape (solve/held_regions.py)
    held_scale: float = 1.0            # ... at this isometric factor from the run's input
    trunk_gate: np.ndarray | None = None   # solver.trunk_stretch: G of the trunk's forward coefficients, per mode
    limb_field: np.ndarray | None = None   # solver.limb_thickness: D̃, the limbs' thickening in the basis (m, 3)

    @classmethod
    def of(cls, body: Body, basis: HarmonicBasis, regions: tuple[str, ...], form: str = "per-axis",
           keep_stance: bool = False, detail_cutoff: float | None = None, held: HeldRegions | None = None,
           held_scale: float = 1.0, trunk_stretch: bool = False, limb_thickness: bool = False) -> "StepTransform":
        if form not in TRANSFORM_FORMS:
            raise ValueError(f"unknown transform form {form!r}; use one of {', '.join(TRANSFORM_FORMS)}")
        if trunk_stretch and form != "per-axis":
            raise ValueError("the trunk's stretch acts along the animal's forward axis: it needs the per-axis transform")
        # Eq. 5 about the body's area-weighted centroid (what mode 0 holds), see module docstring.
        centred = body.vertices - (basis.mass @ body.vertices) / basis.mass.sum()
        masks = [body.region_mask(region).astype(float) if body.has_region(region) else np.zeros(len(body.vertices))
                 for region in regions]
        # x̃ and every region's x̃_seg in one pass over the basis (it is read once, not 1 + k times)
        together = transform(basis, np.hstack([body.vertices] + [centred * mask[:, None] for mask in masks]))
        coefficients = together[:, :3]
        axes = anatomical_axes(body) if form == "per-axis" else None
        # per axis: the axes are the animal's own (forward, up, side), so that the result does not
        # depend on how the mesh is turned; the coefficients of those coordinates are x̃ Aᵀ.
        u, c = dimensionless(coefficients @ axes.T) if form == "per-axis" else mode_magnitudes(coefficients)
        region_us = []
        for number in range(len(regions)):
            region_coefficients = together[:, 3 + 3 * number:6 + 3 * number]            # x̃_seg
            region_us.append(region_coefficients @ axes.T / c if form == "per-axis"
                             else mode_shares(region_coefficients, coefficients, c))
        trunk_gate = None
        trunk = [region_u for region, region_u in zip(regions, region_us) if region in TORSO_REGIONS]
        if trunk_stretch and trunk:
            trunk_gate = geometric_mean_gate(u[:, 0], sum(trunk)[:, 0])
        limb_field = transform(basis, thickening_field(body)) if limb_thickness else None
        feet = FootContact.of(body) if keep_stance else None
        folds = LimbFolds.of(body) if keep_stance else None
        detail = None
        if detail_cutoff is not None:
            taper = detail_taper(basis.eigenvalues, float(basis.mass.sum()), detail_cutoff)
            detail = DetailLayer(basis, body.vertices, coefficients, taper)
        return cls(body, basis, tuple(regions), coefficients, u, c, region_us, form, axes, feet, folds, detail,
                   held, float(held_scale), trunk_gate, limb_field)

    @property
    def sized(self) -> tuple[str, ...]:
        """The regions held at their rule's size, each with a size variable (solve/held_regions.py)."""
        return self.held.ruled if self.held is not None else ()

    @property
    def variable_count(self) -> int:
        """(s, α_0, one α_j per region[, δ the trunk's stretch][, κ the limbs' thickness], one size
        per region held at its rule's size)."""
        return 2 + len(self.regions) + (self.trunk_gate is not None) + (self.limb_field is not None) + len(self.sized)

    def unpack(self, variables: np.ndarray) -> "StepVariables":
        """The variable vector by name: ``(s, α_0, α_1 … α_k[, δ][, κ][, σ per ruled region])``, δ
        and κ only when switched on, one σ per region held at its rule's size (:attr:`sized`)."""
        values = [float(value) for value in variables]
        count = len(self.regions)
        extra = iter(values[2 + count:])
        stretch = next(extra) if self.trunk_gate is not None else None
        thickness = next(extra) if self.limb_field is not None else None
        return StepVariables(values[0], values[1], tuple(values[2:2 + count]), stretch, thickness,
                             dict(zip(self.sized, extra)))

    def vertices(self, variables: np.ndarray) -> np.ndarray:
        """Vertices for the variables (:meth:`unpack`): Eq. 9 with detail kept, the trunk
        stretched by δ, the limbs thickened by κ; then the folded legs' folds given back and the
        feet put back; then the held regions given their input shape, a ruled one at its size × (1 + σ)."""
        named = self.unpack(variables)
        scale = named.scale
        u_new = multi_region_power_law(self.u, self.region_us, list(named.alphas), named.alpha0, scale)
        if named.trunk_stretch is not None:
            u_new = stretch_first_axis(u_new, self.trunk_gate, named.trunk_stretch)
        if self.form == "per-axis":
            # x̃' = x̃ + c·(u' − u), the change taken in the animal's axes and turned back to the
            # mesh's; exactly x̃ where u' = u
            new_coefficients = self.coefficients + (self.c * (u_new - self.u)) @ self.axes
        else:
            new_coefficients = from_mode_magnitudes(self.coefficients, self.u, u_new)
        if named.limb_thickness is not None:   # x̃' += κ·s·D̃ (solve/limb_thickness.py)
            new_coefficients = new_coefficients + named.limb_thickness * scale * self.limb_field
        if self.detail is not None:
            vertices = self.detail.apply(new_coefficients)
        else:
            vertices = apply_to_mesh(self.basis, self.body.vertices, new_coefficients, scale, coefficients=self.coefficients)
        if self.folds is not None:     # no rule asks for a fold to open or close: the solver measures it kept
            vertices = self.folds.apply(vertices)
        if self.feet is not None:
            vertices = self.feet.apply(vertices, scale)
        # last: the feet's shift is harmonic over the whole body and would shear a held part
        if self.held is None:
            return vertices
        return self.held.apply(vertices, self.held_scale, {region: 1.0 + size for region, size in named.sizes.items()})

    def body_at(self, variables: np.ndarray) -> Body:
        from allorules.measure.parts import carry_fields

        return carry_fields(self.body, self.body.with_vertices(self.vertices(variables)))
