"""Measurements of a body and its regions (METHOD §3): masses, lengths, girths, peak stress.

All quantities are used only as ratios (before/after a scaling step), so density cancels and a
mass is a volume. The public names the rules engine calls are :func:`body_mass`,
:func:`region_mass`, :func:`region_length`, :func:`region_girth` and :func:`peak_stress`.

- Volumes: divergence theorem on the surface with every open boundary loop capped by a fan
  around its centroid (caps exist for measuring only).
- Cross-sections: closed isocontour loops of a field that runs along the part
  (:mod:`allorules.sections`): the part's own Fiedler vector for limbs and other regions, planes
  across the torso axis for the chest and abdomen.
- Lengths: diameter of the region's skeleton; mean over the parts of a paired region (a pair
  that comes out as one piece with two feet is split into its legs). Fields and skeletons are
  taken with the part's holes (holes of the body's surface, not cuts) capped.
- Peak stress σ = M / A with A the smallest limb cross-section away from the junction and the tip.

Expensive derived things (region parts, fields, sections) are kept in ``body.cache``, which is
valid only for the body's exact vertices. See docs/measurements.md for the definitions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.csgraph as csgraph

from .body import Body
from .errors import MeasurementError
from .laplacian import face_areas, lumped_mass
from .sections import (
    Loop,
    Skeleton,
    area_quantile_levels,
    area_quantiles,
    boundary_loops,
    connected_parts,
    fiedler_vector,
    harmonic_field,
    isocontour_loops,
    skeleton,
    submesh,
)

from .patches import vertex_graph
from .preparation import HoleCaps, boundary_edge_loops, boundary_edges, cap_holes, hole_caps

LIMB_REGIONS = ("forelimbs", "hindlimbs")
CHEST_LIMIT_MARGIN = 0.01   # heart girth's last candidate: this share of the chest's length behind the forelimbs
PAIRED_REGIONS = LIMB_REGIONS
TORSO_REGIONS = ("chest", "abdomen")
# Share of a limb's length left out at the junction and at the tip when the load-bearing
# section is chosen automatically (the cut distorts the first loops; areas go to zero at the tip).
JUNCTION_SKIP = 0.15
TIP_SKIP = 0.20
# Loops per part for sections and skeletons.
SECTION_COUNT = 40
# Share of a limb's area at its far end (the foot: a hoof, a wide sole) that a limb's skeleton
# does not cut into sections: the field along the leg flattens across a sole, where its
# isocontours wander and split. The skeleton's tip reaches the foot's far end from the last
# section before it (sections.end_point).
FOOT_SHARE = 0.1
# A part whose second-largest opening has at least this share of the largest one's girth is a
# tube between two openings (a neck): it is cut by the harmonic field between them.
SECOND_OPENING_SHARE = 0.25
# Parts of a region smaller than this share of its largest part's area are label noise.
MINIMUM_PART_SHARE = 0.2
# A piece of a paired region has two feet (two legs touching: a camel's knees) when a vertex lies
# at least this share of the farthest foot's distance (along the surface) from both that foot
# and the junction; on one leg nothing is much more than half a leg from both.
SECOND_FOOT_SHARE = 0.75


# ---------------------------------------------------------------------------------------------
# Volumes


def enclosed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed, outward-oriented triangle surface.

    Divergence theorem (Mirtich 1996): V = Σ_faces a · (b × c) / 6, taken about the vertex
    mean so that round-off does not grow with the distance from the origin.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return 0.0
    centred = vertices - vertices[faces.ravel()].mean(axis=0)     # any centre: the surface is closed
    a, b, c = (centred[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def capped(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with every boundary loop closed by a fan around its centroid (measuring only)."""
    return cap_holes(vertices, faces)


def _capped_volume(body: Body, name: str, faces: np.ndarray) -> float:
    """Volume of ``faces`` capped; the capping plan is topology, kept in the cache under ``name``
    (and carried to trial meshes by :func:`carry_fields`)."""
    key = f"measures.caps:{name}"
    if key not in body.cache:
        body.cache[key] = hole_caps(faces, len(body.vertices))
    return enclosed_volume(*body.cache[key].apply(body.vertices))


def body_mass(body: Body) -> float:
    """Body mass M (as a volume): enclosed volume of the capped body surface."""
    key = "measures.body_mass"
    if key not in body.cache:
        volume = _capped_volume(body, "body", body.faces)
        if not np.isfinite(volume) or volume <= 0:
            raise MeasurementError(
                f"volume cannot be determined even after capping: got {volume:.6g}; the surface is "
                "probably inside out or badly broken, run it through allorules.preparation.prepare_mesh"
            )
        body.cache[key] = volume
    return body.cache[key]


def region_mass(body: Body, region: str) -> float:
    """Mass of a region (as a volume): its faces with every open boundary loop capped."""
    key = f"measures.region_mass:{region}"
    if key not in body.cache:
        volume = _capped_volume(body, f"region:{region}", body.faces[_region_faces(body, region)])
        if not np.isfinite(volume) or volume <= 0:
            raise MeasurementError(
                f"volume of region {region!r} cannot be determined even after capping (got "
                f"{volume:.6g}); check its labels cover a piece of surface, not scattered faces"
            )
        body.cache[key] = volume
    return body.cache[key]


# ---------------------------------------------------------------------------------------------
# Region parts


@dataclass
class RegionPart:
    """One connected piece of a region as a mesh of its own (e.g. one leg of ``forelimbs``).

    ``caps`` closes the part's *holes*, the boundary loops that are holes of the body's own
    surface (an open hoof sole), as opposed to its *openings*, where it was cut from the rest of
    the body: fields and skeletons are taken on the part so closed (:meth:`closed`), as volumes
    are; a hole is not where a limb joins the body, and a limb does not end at it.
    """

    region: str
    vertices: np.ndarray
    faces: np.ndarray
    vertex_index: np.ndarray   # body vertex of each part vertex
    area: float                # of the part's own faces (caps not included)
    caps: HoleCaps | None = None

    def closed(self) -> tuple[np.ndarray, np.ndarray]:
        """The part with its holes capped: its vertices and then one per hole (the hole's
        centroid), its faces and then the caps' fans."""
        return (self.vertices, self.faces) if self.caps is None else self.caps.apply(self.vertices)

    def moved(self, body_vertices: np.ndarray) -> "RegionPart":
        """The same part (same faces, same caps) cut from a moved copy of its body."""
        vertices = np.asarray(body_vertices)[self.vertex_index]
        return RegionPart(self.region, vertices, self.faces, self.vertex_index,
                          float(face_areas(vertices, self.faces).sum()), self.caps)


def _region_faces(body: Body, region: str) -> np.ndarray:
    if body.labels is None or region not in body.region_names:
        raise MeasurementError(
            f"body has no region {region!r} (regions: {', '.join(body.region_names) or 'none'}); "
            "label the body first (allorules.segmentation) or drop the rule that needs it"
        )
    selection = body.region_face_mask(region)
    if not selection.any():
        raise MeasurementError(f"region {region!r} has no faces; check the segmentation of this body")
    return selection


def _edge_keys(edges: np.ndarray, vertex_count: int) -> np.ndarray:
    """One integer per undirected edge (a, b)."""
    return np.minimum(edges[:, 0], edges[:, 1]) * vertex_count + np.maximum(edges[:, 0], edges[:, 1])


def _body_hole_edges(body: Body) -> np.ndarray:
    """Sorted keys (:func:`_edge_keys`) of the body surface's own boundary edges (its holes)."""
    key = "measures.body-hole-edges"
    if key not in body.cache:
        body.cache[key] = np.unique(_edge_keys(boundary_edges(body.faces), len(body.vertices)))
    return body.cache[key]


def part_hole_caps(faces: np.ndarray, vertex_index: np.ndarray, body_hole_edges: np.ndarray, body_vertex_count: int) -> HoleCaps:
    """The plan that caps those boundary loops of a part (local ``faces``) whose every edge is a
    boundary edge of the body too (``body_hole_edges``, :func:`_edge_keys` of body vertices):
    holes of the surface, not openings cut by the labels. A loop that is partly a cut stays open,
    and so does every loop of a part that has no cut at all (a whole open tube labelled as one
    region: its holes are where it ends)."""
    edges, edge_loop, loop_count = boundary_edge_loops(faces)
    on_body_boundary = np.isin(_edge_keys(np.asarray(vertex_index)[edges], body_vertex_count), body_hole_edges)
    is_hole = np.ones(loop_count, dtype=bool)
    np.logical_and.at(is_hole, edge_loop, on_body_boundary)
    if is_hole.all():   # no cut at all (the part is a whole piece of the body): its holes are its ends
        is_hole[:] = False
    return hole_caps(faces, len(vertex_index), capped=is_hole)


def region_parts(body: Body, region: str) -> list[RegionPart]:
    """Connected parts of a region, largest first, without label noise.

    Parts smaller than ``MINIMUM_PART_SHARE`` of the largest one's area are dropped. A paired
    region (forelimbs, hindlimbs) keeps all remaining parts; any other region its largest part.
    Each part knows how to cap its holes (:class:`RegionPart`).
    """
    key = f"measures.parts:{region}"
    if key in body.cache:
        return body.cache[key]
    faces = body.faces[_region_faces(body, region)]
    hole_edges = _body_hole_edges(body)
    parts = []
    for face_index in connected_parts(faces):
        vertices, local_faces, vertex_index = submesh(body.vertices, faces, face_index)
        caps = part_hole_caps(local_faces, vertex_index, hole_edges, len(body.vertices))
        parts.append(RegionPart(region, vertices, local_faces, vertex_index,
                                float(face_areas(vertices, local_faces).sum()), caps if caps.loop_count else None))
    parts.sort(key=lambda part: -part.area)
    parts = [part for part in parts if part.area >= MINIMUM_PART_SHARE * parts[0].area]
    if region not in PAIRED_REGIONS:
        parts = parts[:1]
    elif len(parts) == 1:   # a pair that touches (a camel's knees): one piece with two feet
        split = _split_at_two_feet(parts[0])
        if split is not None:
            parts = sorted((_sub_part(body, region, leg, hole_edges) for leg in split), key=lambda part: -part.area)
    body.cache[key] = parts
    return parts


def _surface_distances(vertices: np.ndarray, faces: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Shortest distance along the mesh edges from the nearest of ``sources`` to every vertex."""
    return csgraph.dijkstra(vertex_graph(vertices, faces), directed=False, indices=np.asarray(sources), min_only=True)


def _split_at_two_feet(part: RegionPart) -> list[np.ndarray] | None:
    """The body faces of each leg when one piece of a paired region holds two legs, else None.

    Foot a: the vertex farthest (along the surface) from the junction (the part's largest cut
    opening). Foot b: the vertex farthest from both a and the junction (largest of the smaller of
    its two distances); it is a second foot when that is at least ``SECOND_FOOT_SHARE`` of a's
    distance from the junction (on one leg, no vertex is much more than half a leg from both
    its foot and its top). Each face goes to the foot it is nearer along the surface.
    """
    vertices, faces = part.closed()
    openings = boundary_loops(vertices, faces)
    if not openings:
        return None
    junction = max(openings, key=lambda loop: loop.girth).vertex_ids
    from_junction = _surface_distances(vertices, faces, junction)
    if not np.all(np.isfinite(from_junction)):
        return None
    foot_a = int(np.argmax(from_junction))
    from_a = _surface_distances(vertices, faces, [foot_a])
    foot_b = int(np.argmax(np.minimum(from_a, from_junction)))
    if min(from_a[foot_b], from_junction[foot_b]) < SECOND_FOOT_SHARE * from_junction[foot_a]:
        return None
    from_b = _surface_distances(vertices, faces, [foot_b])
    nearer_a = (from_a - from_b)[part.faces].sum(axis=1) < 0
    legs = []
    for side in (nearer_a, ~nearer_a):
        pieces = connected_parts(part.faces[side])
        if not pieces:
            return None
        legs.append(np.flatnonzero(side)[pieces[0]])   # the leg itself, without stray bits across the seam
    return [part.vertex_index[part.faces[leg]] for leg in legs]


def _sub_part(body: Body, region: str, faces: np.ndarray, hole_edges: np.ndarray) -> RegionPart:
    """A part of ``region`` made of the body faces ``faces`` (vertex ids of the body)."""
    vertices, local_faces, vertex_index = submesh(body.vertices, faces, np.arange(len(faces)))
    caps = part_hole_caps(local_faces, vertex_index, hole_edges, len(body.vertices))
    return RegionPart(region, vertices, local_faces, vertex_index, float(face_areas(vertices, local_faces).sum()),
                      caps if caps.loop_count else None)


def _part_field(part: RegionPart) -> np.ndarray:
    """The field that runs along a part, from where it joins the body to its far end.

    A limb, or any part with one opening: its own Fiedler vector, oriented to grow away from its
    largest open boundary (the junction). A part with two openings of comparable size (a neck:
    to the chest and to the head; the second at least ``SECOND_OPENING_SHARE`` of the first's
    girth): the harmonic function from 0 on the larger opening to 1 on the other, which runs
    along a tube whatever its proportions.
    """
    if len(part.vertices) < 4:
        raise MeasurementError(f"a part of region {part.region!r} has only {len(part.vertices)} vertices; it is too small to measure")
    vertices, faces = part.closed()
    openings = sorted(boundary_loops(vertices, faces), key=lambda loop: -loop.girth)
    if (part.region not in LIMB_REGIONS and len(openings) >= 2
            and openings[1].girth >= SECOND_OPENING_SHARE * openings[0].girth):
        return harmonic_field(vertices, faces, openings[0].vertex_ids, openings[1].vertex_ids)
    field = fiedler_vector(vertices, faces)
    if openings and field[openings[0].vertex_ids].mean() > np.median(field):
        field = -field
    return field


def _closed_fields(body: Body, region: str) -> list[np.ndarray]:
    """The field along each part on the part with its holes capped (one value per vertex of
    :meth:`RegionPart.closed`), cached; topology, so :func:`carry_fields` carries it."""
    key = f"measures.fields:{region}"
    if key not in body.cache:
        body.cache[key] = [_part_field(part) for part in region_parts(body, region)]
    return body.cache[key]


def part_fields(body: Body, region: str) -> list[np.ndarray]:
    """The field along each part of a region (its own Fiedler vector, junction → tip), one value
    per part vertex (taken on the part with its holes capped)."""
    return [field[:len(part.vertices)] for field, part in zip(_closed_fields(body, region), region_parts(body, region))]


def carry_fields(reference: Body, body: Body) -> Body:
    """Measure ``body`` along the fields of ``reference`` (same faces and labels, moved vertices).

    Copies the reference's region parts (connectivity) and part fields, and the skeletons and
    limbs measured on it, as far as they have been computed, into ``body.cache``: ``body``'s
    sections, skeletons, lengths and limb girths are then taken on the same material curves as on
    the reference. Those loops cross the same mesh edges at the same place along them, so they are
    re-measured by interpolation (:meth:`Loop.moved`) with no re-extraction; the skeletons keep
    their nodes and joins. The torso stays cut by planes across its axis (a tape measure, not a
    material curve) but the chest keeps the reference's candidate sections (by their area
    quantile), and the section at the forelimbs' limit follows the limit (see :func:`chest_girth`).
    Every measure is then a continuous function of the vertices. Meant for an optimiser that
    measures many trial deformations of one body. Returns ``body``.
    """
    if reference.faces.shape != body.faces.shape or not np.array_equal(reference.faces, body.faces):
        raise ValueError("carry_fields needs two bodies with the same faces")
    if (reference.labels is None) != (body.labels is None) or (
        reference.labels is not None and not np.array_equal(reference.labels, body.labels)
    ):
        raise ValueError("carry_fields needs two bodies with the same labels")
    for key, value in reference.cache.items():
        if key.startswith("measures.parts:"):
            body.cache[key] = [part.moved(body.vertices) for part in value]
        elif key.startswith(("measures.fields:", "measures.caps:")):   # topology: the same for both
            body.cache[key] = value
        elif key.startswith(("measures.skeleton:", "measures.limbs:", "measures.chest-candidates")):
            body.cache["measures.carried." + key[len("measures."):]] = value
        elif key.startswith("measures.carried."):   # a carried body passed on as a reference
            body.cache[key] = value
    return body


# ---------------------------------------------------------------------------------------------
# Limbs and cross-sections


@dataclass
class Section:
    """A cross-section of a limb: a loop, how far along the limb it is, and where it was taken."""

    loop: Loop
    distance: float   # along the limb's skeleton from the junction
    fraction: float   # distance / limb length: 0 at the junction, 1 at the tip

    @property
    def area(self) -> float:
        return self.loop.area

    @property
    def girth(self) -> float:
        return self.loop.girth


@dataclass
class Limb:
    """One limb (a part of a limb region) cut across from its junction with the body to its tip."""

    region: str
    part: int
    sections: list[Section]   # ordered junction → tip
    junction: np.ndarray      # centroid of the junction (the part's largest open boundary)
    tip: np.ndarray           # vertex where the field is largest (the foot's tip)
    length: float             # junction → section centroids → tip
    field: np.ndarray         # per part vertex, grows from junction to tip
    levels: np.ndarray        # field level of each section
    mesh: RegionPart
    junction_loop: Loop | None = None   # the junction's open boundary (None: the field's lowest vertex)

    @property
    def centroids(self) -> np.ndarray:
        """The centroids of the cross-sections, junction to tip, (sections, 3): the leg's centre line."""
        return np.array([section.loop.centroid for section in self.sections])

    def moved(self, part: RegionPart) -> "Limb":
        """The same limb (same loops, junction and tip) on a moved copy ``part`` of its mesh."""
        loops = [section.loop.moved(part.vertices) for section in self.sections]
        junction_loop = None if self.junction_loop is None else self.junction_loop.moved(part.vertices)
        junction = part.vertices[int(np.argmin(self.field))] if junction_loop is None else junction_loop.centroid
        tip = part.vertices[int(np.argmax(self.field))]
        sections, length = _chain_sections(junction, loops, tip)
        return Limb(self.region, self.part, sections, junction, tip, length, self.field, self.levels, part, junction_loop)

    def section_at(self, fraction: float) -> Section:
        """The cross-section at ``fraction`` of the limb's length (0 junction, 1 tip), recomputed exactly."""
        if not self.sections:
            raise MeasurementError(f"no closed cross-section found on {self.region!r} part {self.part}")
        fractions = np.asarray([section.fraction for section in self.sections])
        fraction = float(np.clip(fraction, fractions[0], fractions[-1]))
        level = float(np.interp(fraction, fractions, self.levels))
        loops = isocontour_loops(self.mesh.vertices, self.mesh.faces, self.field, level)
        if not loops:
            nearest = int(np.argmin(np.abs(fractions - fraction)))
            return self.sections[nearest]
        return Section(loops[0], fraction * self.length, fraction)


def _limb(part: RegionPart, index: int, field: np.ndarray) -> Limb:
    levels = area_quantile_levels(part.vertices, part.faces, field, SECTION_COUNT)
    loops, kept_levels = [], []
    for level in levels:
        found = isocontour_loops(part.vertices, part.faces, field, level)
        if found:
            loops.append(found[0])   # the main cross-section (longest loop) at this level
            kept_levels.append(level)
    boundaries = boundary_loops(part.vertices, part.faces)
    tip = part.vertices[int(np.argmax(field))]
    junction_loop = max(boundaries, key=lambda loop: loop.girth) if boundaries else None
    junction = part.vertices[int(np.argmin(field))] if junction_loop is None else junction_loop.centroid
    sections, length = _chain_sections(junction, loops, tip)
    return Limb(part.region, index, sections, junction, tip, length, field, np.asarray(kept_levels), part, junction_loop)


def _chain_sections(junction: np.ndarray, loops: list[Loop], tip: np.ndarray) -> tuple[list[Section], float]:
    """Sections along the chain junction → loop centroids → tip, and the chain's length."""
    chain = [junction] + [loop.centroid for loop in loops] + [tip]
    steps = np.linalg.norm(np.diff(np.asarray(chain), axis=0), axis=1)
    distances = np.cumsum(steps)
    length = float(distances[-1])
    sections = [Section(loop, float(d), float(d / length) if length > 0 else 0.0) for loop, d in zip(loops, distances[:-1])]
    return sections, length


def limb_sections(body: Body, region: str) -> list[Limb]:
    """The limbs of a region (one per part), each cut into cross-sections from junction to tip.

    The field is the limb's own Fiedler vector (METHOD §3: a global Fiedler vector does not cut
    legs across), oriented to grow from the junction (the part's largest open boundary) to the
    tip. One loop per level, the longest where a level has several.
    """
    key = f"measures.limbs:{region}"
    if key not in body.cache:
        parts = region_parts(body, region)
        carried = body.cache.get(f"measures.carried.limbs:{region}")
        if carried is not None:   # the reference's limbs, re-measured on the moved parts
            body.cache[key] = [limb.moved(part) for limb, part in zip(carried, parts)]
        else:
            fields = part_fields(body, region)
            body.cache[key] = [_limb(part, index, field) for index, (part, field) in enumerate(zip(parts, fields))]
    return body.cache[key]


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
    key = f"measures.peak_stress:{override}"
    if key not in body.cache:
        area = load_bearing_section(body, override=override).area
        if not area > 0:
            raise MeasurementError("the load-bearing cross-section has zero area; pick another section")
        body.cache[key] = body_mass(body) / area
    return body.cache[key]


# ---------------------------------------------------------------------------------------------
# Posture: how the limbs stand


def stance_down(limbs: list[Limb], frame=None) -> np.ndarray:
    """'Down' for an animal standing on its legs, whatever the mesh's orientation: −``frame.up``
    when the body has a frame (the labeller's is the normal of the plane the feet stand on),
    else the direction the legs point, shoulders to feet (the sum of their junction → tip axes;
    tilted where the legs slant, as a dog's hind legs do)."""
    down = -np.asarray(frame.up, dtype=float) if frame is not None else np.sum([limb.tip - limb.junction for limb in limbs], axis=0)
    return down / np.linalg.norm(down)


def limb_bend(limb: Limb) -> float:
    """How far a limb's centre line strays from straight: the largest distance of a section
    centroid from the line junction → last section's centroid, as a share of that line's length
    (0 for a straight leg; a uniform scaling or a turn leaves it as it is). The foot tip is left
    out: it is one vertex, at the toe, and a hoof's toe sits off the leg's line."""
    if len(limb.sections) < 2:
        return 0.0
    centroids = limb.centroids
    chord = centroids[-1] - limb.junction
    reach = float(np.linalg.norm(chord))
    if reach == 0.0:
        return 0.0
    offsets = centroids - limb.junction
    across = offsets - np.outer(offsets @ chord / reach ** 2, chord)
    return float(np.linalg.norm(across, axis=1).max() / reach)


def posture_change(before: Body, after: Body) -> dict[str, dict[str, float]]:
    """How the limbs' stance and shape changed from ``before`` to ``after`` (same faces and labels).

    Per limb part (``"forelimbs[0]"`` …): ``tilt_degrees``, the angle between its axis (junction
    centroid → foot tip) before and after; ``foot_lift``, the change of the foot's height above the
    lowest foot, as a share of the leg's length; ``bend``, the change of :func:`limb_bend` (a leg
    that bows). Heights are taken along :func:`stance_down` of ``before``. Nothing rules ask for;
    the report shows it because an allometric edit can meet every rule yet leave the animal
    leaning or its legs bent.
    """
    limbs_before = [limb for region in LIMB_REGIONS if before.has_region(region) for limb in limb_sections(before, region)]
    if not limbs_before:
        return {}
    carried = carry_fields(before, after.with_vertices(after.vertices))
    limbs_after = [limb for region in LIMB_REGIONS if carried.has_region(region) for limb in limb_sections(carried, region)]

    down = stance_down(limbs_before, before.frame)

    def stance(limbs: list[Limb]) -> tuple[np.ndarray, np.ndarray]:
        axes = np.array([limb.tip - limb.junction for limb in limbs])
        heights = -np.array([limb.tip @ down for limb in limbs])
        lengths = np.array([limb.length for limb in limbs])
        return axes, (heights - heights.min()) / lengths

    axes_before, lift_before = stance(limbs_before)
    axes_after, lift_after = stance(limbs_after)
    change = {}
    for index, limb in enumerate(limbs_before):
        cosine = axes_before[index] @ axes_after[index] / (np.linalg.norm(axes_before[index]) * np.linalg.norm(axes_after[index]))
        change[f"{limb.region}[{limb.part}]"] = {
            "tilt_degrees": float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))),
            "foot_lift": float(lift_after[index] - lift_before[index]),
            "bend": limb_bend(limbs_after[index]) - limb_bend(limb),
        }
    return change


# ---------------------------------------------------------------------------------------------
# Lengths and girths


def region_skeleton(body: Body, region: str) -> list[Skeleton]:
    """Skeleton of each part of a region, from the part's own Fiedler vector."""
    key = f"measures.skeleton:{region}"
    carried = body.cache.get(f"measures.carried.skeleton:{region}")
    if key not in body.cache and carried is not None:   # the reference's skeletons, re-measured
        body.cache[key] = [part_skeleton.moved(part.closed()[0]) for part_skeleton, part in zip(carried, region_parts(body, region))]
    if key not in body.cache:
        skeletons = []
        for part, field in zip(region_parts(body, region), _closed_fields(body, region)):
            vertices, faces = part.closed()
            levels = None
            if region in LIMB_REGIONS:   # no sections in the foot: its end is the tip's end point
                targets = (np.arange(SECTION_COUNT) + 0.5) / SECTION_COUNT
                levels = np.unique(area_quantiles(vertices, faces, field, targets[targets <= 1.0 - FOOT_SHARE]))
                levels = levels[(levels > field.min()) & (levels < field.max())]
            skeletons.append(skeleton(vertices, faces, field, levels, count=SECTION_COUNT, by_level=region in LIMB_REGIONS))
        body.cache[key] = skeletons
    return body.cache[key]


def region_length(body: Body, region: str) -> float:
    """Length of a region: diameter of its skeleton; the mean over the parts of a paired region."""
    key = f"measures.region_length:{region}"
    if key not in body.cache:
        lengths = [part_skeleton.diameter for part_skeleton in region_skeleton(body, region)]
        length = float(np.mean(lengths))
        if not length > 0:
            raise MeasurementError(f"region {region!r} has no measurable length (its skeleton is a point)")
        body.cache[key] = length
    return body.cache[key]


def torso_axis(body: Body) -> np.ndarray:
    """Unit vector from the back of the torso to its front.

    ``body.frame.forward`` when the body has a frame; otherwise the torso's (chest and abdomen)
    area-weighted principal axis, pointing from the abdomen's centroid to the chest's.
    """
    if body.frame is not None:
        forward = np.asarray(body.frame.forward, dtype=float)
        return forward / np.linalg.norm(forward)
    if not all(body.has_region(region) for region in TORSO_REGIONS):
        raise MeasurementError(
            "the torso's direction is unknown: the body needs both 'chest' and 'abdomen' regions or a "
            "frame (up/forward) to measure chest girth"
        )
    mass = lumped_mass(body.vertices, body.faces)
    centroids = {}
    for region in TORSO_REGIONS:
        mask = body.region_mask(region)
        centroids[region] = (body.vertices[mask] * mass[mask, None]).sum(axis=0) / mass[mask].sum()
    mask = body.region_mask("chest") | body.region_mask("abdomen")
    weights = mass[mask] / mass[mask].sum()
    centred = body.vertices[mask] - (body.vertices[mask] * weights[:, None]).sum(axis=0)
    covariance = (centred * weights[:, None]).T @ centred
    axis = np.linalg.eigh(covariance)[1][:, -1]
    return axis if axis @ (centroids["chest"] - centroids["abdomen"]) >= 0 else -axis


def _torso_loops(body: Body, region: str, axis: np.ndarray, targets: np.ndarray | None = None,
                 around_torso: bool = False) -> tuple[list[Loop], np.ndarray]:
    """Closed plane sections of a region's largest part across ``axis`` (largest loop per level).

    Levels at the part's area quantiles ``targets`` (default: ``(k + ½)/SECTION_COUNT``).
    ``around_torso``: cut the loops at those levels from the whole torso piece around the part
    (:func:`_torso_piece`) rather than from the part alone. Returns the loops and the quantile of
    each (levels without a closed loop are left out).
    """
    part = region_parts(body, region)[0]
    field = part.vertices @ axis
    if targets is None:
        targets = (np.arange(SECTION_COUNT) + 0.5) / SECTION_COUNT
    levels = area_quantiles(part.vertices, part.faces, field, targets)
    cut = _torso_piece(body, region) if around_torso else part
    cut_field = cut.vertices @ axis
    loops, kept = [], []
    for target, level in zip(np.asarray(targets).tolist(), levels.tolist()):
        if not field.min() < level < field.max():   # not a cross-section (see area_quantile_levels)
            continue
        found = isocontour_loops(cut.vertices, cut.faces, cut_field, level)
        if found:
            loops.append(found[0])
            kept.append(target)
    return loops, np.asarray(kept)


def _torso_piece(body: Body, region: str) -> RegionPart:
    """The connected piece of the torso (faces mostly chest or abdomen) that holds ``region``'s
    largest part: what a tape measure goes around when the region's own sections do not close."""
    key = "measures.parts:torso"
    if key not in body.cache:
        in_torso = np.zeros(len(body.vertices), dtype=bool)
        for name in TORSO_REGIONS:
            if body.has_region(name):
                in_torso |= body.region_mask(name)
        faces = body.faces[in_torso[body.faces].sum(axis=1) >= 2]
        pieces = []
        for face_index in connected_parts(faces):
            vertices, local_faces, vertex_index = submesh(body.vertices, faces, face_index)
            pieces.append(RegionPart("torso", vertices, local_faces, vertex_index, float(face_areas(vertices, local_faces).sum())))
        body.cache[key] = pieces
    first = region_parts(body, region)[0].vertex_index[0]
    return next(piece for piece in body.cache[key] if np.isin(first, piece.vertex_index))


def _forelimb_limit(body: Body, axis: np.ndarray) -> float | None:
    """Position along ``axis`` of the rearmost point where the forelimbs meet the chest (``None``
    without forelimbs): the front end of where heart girth may be taken."""
    if not (body.has_region("forelimbs") and body.region_mask("forelimbs").any()):
        return None
    forelimb_faces = body.faces[body.region_face_mask("forelimbs")]
    junction = body.vertices[np.intersect1d(np.unique(forelimb_faces), np.flatnonzero(body.region_mask("chest")))]
    return float((junction @ axis).min() if len(junction) else (body.vertices[body.region_mask("forelimbs")] @ axis).min())


def chest_girth(body: Body) -> float:
    """Heart girth: the largest closed section of the chest across the torso axis behind the forelimbs.

    "Behind the forelimbs" means every point of the section lies at least ``CHEST_LIMIT_MARGIN`` of
    the chest's length behind (along the torso axis) the rearmost point where the forelimbs meet
    the body; without forelimbs, any section. The candidates are the sections at fixed area
    quantiles of the chest that lie behind that limit, plus the section at the limit: where the
    chest widens towards the forelimbs (real horses) the largest is that last one, and it moves
    with the forelimbs continuously instead of jumping from one quantile to the next. When no
    section of the chest alone closes there (its boundary with the abdomen zigzags across the
    large faces of a low-poly mesh), the same levels are cut around the whole torso. On a carried
    body (:func:`carry_fields`) the quantile levels, and which of the two, are the reference's.
    """
    axis = torso_axis(body)
    part = region_parts(body, "chest")[0]
    field = part.vertices @ axis
    limit = _forelimb_limit(body, axis)
    if limit is not None:
        limit -= CHEST_LIMIT_MARGIN * (field.max() - field.min())

    def candidates(targets: np.ndarray | None, around_torso: bool) -> tuple[list[Loop], np.ndarray]:
        loops, kept = _torso_loops(body, "chest", axis, targets, around_torso)
        if limit is not None:
            # every candidate behind the limit, and the section at the limit itself: so a candidate
            # crossing the limit leaves or joins where it equals that last section (no jump)
            loops = [loop for loop in loops if (loop.points @ axis).max() <= limit]
            if field.min() < limit < field.max():
                cut = _torso_piece(body, "chest") if around_torso else part
                loops += isocontour_loops(cut.vertices, cut.faces, cut.vertices @ axis, limit)[:1]
        return loops, kept

    carried = body.cache.get("measures.carried.chest-candidates")
    if carried is not None:
        loops, _ = candidates(*carried)
    else:
        for around_torso in (False, True):
            loops, kept = candidates(None, around_torso)
            if loops:
                body.cache["measures.chest-candidates"] = (kept, around_torso)
                break
    if not loops:
        raise MeasurementError(
            "no closed section of the chest behind the forelimbs: the chest region does not go all "
            "around the body there; check the segmentation"
        )
    return max(loop.girth for loop in loops)


def region_girth(body: Body, region: str) -> float:
    """Girth of a region, taken where docs/measurements.md says.

    chest: heart girth (:func:`chest_girth`); abdomen: its largest section across the torso
    axis; limbs: the section at mid-length, mean over the limbs; any other region: the longest
    closed isocontour of its own Fiedler vector (the base of a neck, the widest part of a head).
    """
    key = f"measures.region_girth:{region}"
    if key in body.cache:
        return body.cache[key]
    if region == "chest":
        girth = chest_girth(body)
    elif region == "abdomen":
        axis = torso_axis(body)
        loops = _torso_loops(body, region, axis)[0] or _torso_loops(body, region, axis, around_torso=True)[0]
        if not loops:
            raise MeasurementError("no closed section across the abdomen; check the segmentation")
        girth = max(loop.girth for loop in loops)
    elif region in LIMB_REGIONS:
        girth = float(np.mean([limb.section_at(0.5).girth for limb in limb_sections(body, region)]))
    else:
        girths = []
        for part_skeleton in region_skeleton(body, region):
            section_loops = [loop for loop, kind in zip(part_skeleton.loops, part_skeleton.kinds) if kind == "section"]
            if section_loops:
                girths.append(max(loop.girth for loop in section_loops))
        if not girths:
            raise MeasurementError(f"no closed cross-section found on region {region!r}; check the segmentation")
        girth = float(np.mean(girths))
    body.cache[key] = girth
    return girth
