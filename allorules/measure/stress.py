"""Peak limb stress σ = M / A (paper §3.1, METHOD §3): the smallest load-bearing limb
cross-section, chosen automatically away from the junction and the tip (or by the user), and the
gauge that follows those sections as material through a run.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from allorules.body import Body
from allorules.errors import MeasurementError
from allorules.measure.cache import measured
from allorules.measure.limbs import Section, limb_sections
from allorules.measure.mass import body_mass
from allorules.measure.parts import LIMB_REGIONS
from allorules.measure.sections import JoinedLoops


@dataclass(frozen=True)
class MaterialBand:
    """One limb cross-section fixed to the material.

    Chosen as a closed isocontour of a limb field on one body; kept as the mesh edges it crosses
    (``edge_start``, ``edge_end``: body vertex indices, in loop order) and where it crosses them
    (``t``). On a deformed body with the same connectivity, the same contour of the same frozen
    field crosses the same edges at the same parameters, so the band follows the same place on
    the limb: its points are p_k = v[edge_start_k] + t_k (v[edge_end_k] − v[edge_start_k]).
    """

    region: str
    part: int
    fraction: float               # along the limb when chosen (0 junction, 1 tip)
    edge_start: np.ndarray
    edge_end: np.ndarray
    t: np.ndarray

    @classmethod
    def from_loop(cls, region: str, part: int, fraction: float, loop, part_faces: np.ndarray,
                  part_vertex_index: np.ndarray, field: np.ndarray, part_vertices: np.ndarray) -> "MaterialBand":
        """Freeze a closed isocontour ``loop`` (of ``field`` at ``loop.level``) of a limb part."""
        faces = np.asarray(part_faces)[np.asarray(loop.faces)]
        starts, ends = [], []
        # Point k ends the segment through face k−1 and starts the one through face k: it lies on
        # the edge those two faces share.
        for previous, current in zip(np.roll(faces, 1, axis=0), faces):
            shared = np.intersect1d(previous, current)
            if len(shared) != 2:
                raise MeasurementError(f"a cross-section of {region!r} is not a simple loop; cannot follow it")
            starts.append(shared[0])
            ends.append(shared[1])
        starts, ends = np.asarray(starts), np.asarray(ends)
        t = (loop.level - field[starts]) / (field[ends] - field[starts])
        points = part_vertices[starts] + t[:, None] * (part_vertices[ends] - part_vertices[starts])
        scale = np.ptp(part_vertices, axis=0).max()
        if not np.allclose(points, loop.points, atol=1e-9 * scale, rtol=0):
            raise MeasurementError(f"a cross-section of {region!r} could not be frozen to the mesh edges")
        index = np.asarray(part_vertex_index)
        return cls(region, part, float(fraction), index[starts], index[ends], t)

    def points(self, vertices: np.ndarray) -> np.ndarray:
        start, end = vertices[self.edge_start], vertices[self.edge_end]
        return start + self.t[:, None] * (end - start)

    def area(self, vertices: np.ndarray) -> float:
        """‖½ Σ p_k × p_{k+1}‖ (METHOD §3), about the loop's mean point for round-off."""
        points = self.points(np.asarray(vertices))
        centred = points - points.mean(axis=0)
        return float(np.linalg.norm(0.5 * np.cross(centred, np.roll(centred, -1, axis=0)).sum(axis=0)))


@dataclass(frozen=True)
class StressGauge:
    """Peak stress σ = M / A measured at cross-sections frozen to the material.

    Without an override, the bands are every candidate of the automatic rule of
    :func:`allorules.measure.stress.load_bearing_section` on the body it was chosen on (all limb
    sections between the junction and tip margins) and A is the smallest of their areas, so the
    peak moves along the limb if the scaling moves it, while every band stays the same material
    ring (a min of smooth functions of α, which the root find can bracket). With an override
    (:class:`allorules.measure.stress.SectionChoice`) the single chosen section is followed.
    """

    bands: tuple[MaterialBand, ...]

    @classmethod
    def choose(cls, body: Body, override=None) -> "StressGauge":
        def band(region, limb, section) -> MaterialBand:
            return MaterialBand.from_loop(region, limb.part, section.fraction, section.loop, limb.mesh.faces,
                                          limb.mesh.vertex_index, np.asarray(limb.field, dtype=float), limb.mesh.vertices)

        chosen = load_bearing_section(body, override=override)   # raises the clear errors
        if override is not None:
            limb = limb_sections(body, chosen.region)[chosen.part]
            return cls((band(chosen.region, limb, chosen.section),))
        bands = []
        for region in LIMB_REGIONS:
            if not body.has_region(region) or not body.region_face_mask(region).any():
                continue
            for limb in limb_sections(body, region):
                for section in limb.sections:
                    if JUNCTION_SKIP <= section.fraction <= 1.0 - TIP_SKIP:
                        bands.append(band(region, limb, section))
        return cls(tuple(bands))

    @cached_property
    def _joined(self) -> JoinedLoops:
        return JoinedLoops.of([(band.edge_start, band.edge_end, band.t) for band in self.bands], [True] * len(self.bands))

    def areas(self, vertices: np.ndarray) -> np.ndarray:
        """Every band's area (:meth:`MaterialBand.area`), all bands at once: a run measures them on
        every trial."""
        return self._joined.areas(self._joined.points(np.asarray(vertices)))

    def area(self, vertices: np.ndarray) -> float:
        return float(np.min(self.areas(vertices)))

    def stress(self, body: Body) -> float:
        """σ = M / A (density cancels; only ratios are used)."""
        from allorules.measure.mass import body_mass

        area = self.area(body.vertices)
        if not area > 0:
            raise MeasurementError("a load-bearing limb section collapsed to zero area")
        return body_mass(body) / area

    def describe(self, vertices: np.ndarray | None = None) -> dict:
        """Which band carries the peak (on ``vertices``, if given) and how many are followed."""
        index = int(np.argmin(self.areas(vertices))) if vertices is not None else 0
        band = self.bands[index]
        return {"region": band.region, "part": int(band.part), "fraction": round(band.fraction, 4),
                "bands_followed": len(self.bands)}


# Share of a limb's length left out at the junction and at the tip when the load-bearing
# section is chosen automatically (the cut distorts the first loops; areas go to zero at the tip).
JUNCTION_SKIP = 0.15


TIP_SKIP = 0.20


@dataclass(frozen=True)
class SectionChoice:
    """A user's choice of the load-bearing section: ``fraction`` of the way from junction to tip
    along ``region``; ``part`` picks one limb of a paired region (None: the smaller section)."""

    region: str
    fraction: float
    part: int | None = None


@dataclass
class LoadBearingSection:
    """The cross-section that carries the peak stress."""

    region: str
    part: int
    section: Section

    @property
    def area(self) -> float:
        return self.section.area


def load_bearing_section(body: Body, *, override: SectionChoice | None = None) -> LoadBearingSection:
    """The limb cross-section of peak stress.

    Automatic rule: the smallest-area section of all limbs (forelimbs and hindlimbs, every
    part) between ``JUNCTION_SKIP`` and ``1 − TIP_SKIP`` of the limb's length from its junction.
    ``override`` takes the section at a given fraction of a given region instead.
    """
    if override is not None:
        if not 0.0 <= override.fraction <= 1.0:
            raise MeasurementError(f"section fraction must be between 0 (junction) and 1 (tip), got {override.fraction}")
        limbs = limb_sections(body, override.region)
        if override.part is not None:
            if not 0 <= override.part < len(limbs):
                raise MeasurementError(f"region {override.region!r} has {len(limbs)} part(s); part {override.part} does not exist")
            limbs = [limbs[override.part]]
        candidates = [LoadBearingSection(limb.region, limb.part, limb.section_at(override.fraction)) for limb in limbs]
        return min(candidates, key=lambda choice: choice.area)

    present = [region for region in LIMB_REGIONS if body.has_region(region) and body.labels is not None
               and body.region_face_mask(region).any()]
    if not present:
        raise MeasurementError(
            "peak stress needs a limb region ('forelimbs' or 'hindlimbs') but the body has none "
            f"(regions: {', '.join(body.region_names) or 'none'}); label the body or pick the section yourself"
        )
    candidates = []
    for region in present:
        for limb in limb_sections(body, region):
            for section in limb.sections:
                if JUNCTION_SKIP <= section.fraction <= 1.0 - TIP_SKIP:
                    candidates.append(LoadBearingSection(region, limb.part, section))
    if not candidates:
        raise MeasurementError(
            f"no closed cross-section found in the limbs ({', '.join(present)}); the limb labels may "
            "not cover whole legs: check the segmentation or pick the section yourself"
        )
    return min(candidates, key=lambda choice: choice.area)


def peak_stress(body: Body, *, override: SectionChoice | None = None) -> float:
    """Peak stress σ = M / A (body mass over load-bearing cross-section area); only ratios matter."""
    cache = measured(body).peak_stress
    if override not in cache:
        area = load_bearing_section(body, override=override).area
        if not area > 0:
            raise MeasurementError("the load-bearing cross-section has zero area; pick another section")
        cache[override] = body_mass(body) / area
    return cache[override]
