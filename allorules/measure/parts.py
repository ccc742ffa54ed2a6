"""Regions as meshes of their own: connected parts (a paired region split into its legs), their
holes capped, the field that runs along each part, and carrying all of that to a moved copy of
the body (so an optimiser measures trial meshes along the same material curves); and the torso's
axis, along which girths and the trunk's length are taken.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse.csgraph as csgraph

from allorules.body import Body
from allorules.errors import MeasurementError
from allorules.measure.cache import Carried, measured
from allorules.measure.sections import (
    boundary_loops,
    fiedler_vector,
    harmonic_field,
)
from allorules.mesh.geometry import face_areas, vertex_areas
from allorules.mesh.topology import (
    HoleCaps,
    boundary_edge_loops,
    boundary_edges,
    face_parts,
    hole_caps,
    submesh,
    vertex_graph,
)

LIMB_REGIONS = ("forelimbs", "hindlimbs")


PAIRED_REGIONS = LIMB_REGIONS


TORSO_REGIONS = ("chest", "abdomen")


# Loops per part for sections and skeletons.
SECTION_COUNT = 40


# A part whose second-largest opening has at least this share of the largest one's girth is a
# tube between two openings (a neck): it is cut by the harmonic field between them.
SECOND_OPENING_SHARE = 0.25


# A part's Fiedler vector whose values on its junction spread over more than this share of its
# range runs across the part (a leg about as wide as long), not along it. The shared animals' legs
# as they come: 0.01-0.21, the pig 383's hind leg 0.33; the camel's forelegs, long and touching at
# the knee, 0.54-0.57 in its run at ×0.5 (at 0.5 they were switched mid-run and the run moved:
# trunk 0.329 → 0.342, 6 → 13 faces folded as solved); a stubby leg turned across: 0.77-1.0.
ACROSS_SHARE = 0.7


# Parts of a region smaller than this share of its largest part's area are label noise.
MINIMUM_PART_SHARE = 0.2


# A piece of a paired region has two feet (two legs touching: a camel's knees) when a vertex lies
# at least this share of the farthest foot's distance (along the surface) from both that foot
# and the junction; on one leg nothing is much more than half a leg from both.
SECOND_FOOT_SHARE = 0.75


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
            "label the body first (allorules.segment) or drop the rule that needs it"
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
    cache = measured(body)
    if cache.hole_edges is None:
        cache.hole_edges = np.unique(_edge_keys(boundary_edges(body.faces), len(body.vertices)))
    return cache.hole_edges


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
    cache = measured(body).parts
    if region in cache:
        return cache[region]
    faces = body.faces[_region_faces(body, region)]
    hole_edges = _body_hole_edges(body)
    parts = []
    for face_index in face_parts(faces):
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
    cache[region] = parts
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
        pieces = face_parts(part.faces[side])
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
    largest open boundary (the junction), unless it runs across the part (``ACROSS_SHARE``): then
    the harmonic function from 0 on the junction to 1 at the vertex farthest from it. A part with
    two openings of comparable size (a neck: to the chest and to the head; the second at least
    ``SECOND_OPENING_SHARE`` of the first's girth): the harmonic function from 0 on the larger
    opening to 1 on the other, which runs along a tube whatever its proportions.
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
    if openings and np.ptp(field[openings[0].vertex_ids]) > ACROSS_SHARE * np.ptp(field):
        # The Fiedler vector runs across the part, not along it: a stubby leg thickened by a run
        # (a cartoon dog's, 1.8 diameters long, at ×2: its junction spread over 0.77 of the
        # field's range, 0.06-0.13 as it came; measured across, its length came out 0.308 for
        # 0.360). Then the harmonic function from the junction to the part's far end.
        junction = openings[0].vertex_ids
        reach = csgraph.dijkstra(vertex_graph(vertices, faces), indices=junction, min_only=True)
        field = harmonic_field(vertices, faces, junction, [int(np.argmax(np.where(np.isfinite(reach), reach, -1.0)))])
    return field


def _closed_fields(body: Body, region: str) -> list[np.ndarray]:
    """The field along each part on the part with its holes capped (one value per vertex of
    :meth:`RegionPart.closed`), cached; topology, so :func:`carry_fields` carries it."""
    cache = measured(body).fields
    if region not in cache:
        cache[region] = [_part_field(part) for part in region_parts(body, region)]
    return cache[region]


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
    source, target = measured(reference), measured(body)
    target.parts.update({region: [part.moved(body.vertices) for part in parts] for region, parts in source.parts.items()})
    target.fields.update(source.fields)        # topology: the same for both
    target.caps.update(source.caps)
    carried = target.carried = Carried()
    if source.carried is not None:             # a carried body passed on as a reference
        carried.limbs.update(source.carried.limbs)
        carried.skeletons.update(source.carried.skeletons)
    carried.limbs.update(source.limbs)
    carried.skeletons.update(source.skeletons)
    return carry_choices(reference, body)


def carry_choices(reference: Body, body: Body) -> Body:
    """Measure ``body`` afresh but with the discrete choices made on ``reference`` (a moved copy of
    the same mesh and labels): where heart girth is cut (the candidate levels' area quantiles, the
    piece: chest, torso or body, and the margin behind the forelimbs; see
    :func:`allorules.measure.girth.chest_girth`). Every curve is cut anew on ``body``; only what
    the tape goes round stays. Made afresh, that choice flipped within a run (the bull 386 at ×2:
    its chest's own sections at the input, the whole torso's after a few steps, 12 % longer), and
    the run then chased the jump (heart girth exponent 0.515, every other rule lost). Returns
    ``body``.
    """
    source = measured(reference)
    choice = source.chest_candidates if source.chest_candidates is not None else (
        source.carried.chest_candidates if source.carried is not None else None)
    if choice is not None:
        target = measured(body)
        target.carried = target.carried or Carried()
        target.carried.chest_candidates = choice
    return body


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
            "frame (up/forward) to measure along the torso (chest girth, the trunk's length)"
        )
    mass = vertex_areas(body.vertices, body.faces)
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
