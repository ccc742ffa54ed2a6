"""Open regions held as a similarity of themselves (METHOD §10: "nothing changes that nobody asked
to change"; issue 18).

A region that no rule measures (the neck of ``quadruped``; a tail, ears, horns or a trunk when
the labeller finds them) should scale isometrically: length ∝ M^(1/3), mass ∝ M. Soft terms on its
length and mass (:func:`allorules.solve.open_regions.open_region_terms`) cannot hold it without
costing the rules: Eq. 9 gives a region one α_j, and the neck shares its modes with the chest and
the head, so one α cannot meet the neck's length, its mass and the chest's girth at once (on the
generated horse at ×0.5 with weight 1 the chest girth reached 0.390 for 0.365). Here the open
region is taken out of Eq. 9's hands instead, after the transform of each trial:

* each connected part P of the region (its faces as the measures take them: most corners in it)
  is given its *input* shape scaled by the isometric factor k = R_reached^(1/3) and turned and
  placed where Eq. 9 put it: S(x) = k Q x + t, Q the rotation that best maps the input part onto
  Eq. 9's part (Kabsch, area-weighted; for an appendage, which carries nothing, the turn of the
  region it grows from: it keeps its set on the head or the rump), t such that the centre of the
  opening towards the torso (the *near* opening) stays where Eq. 9 put it;
* what hangs beyond the part (the head beyond the neck, with its ears and horns: the *children*)
  is moved rigidly by τ, the shift that takes Eq. 9's far opening onto S's;
* the small mismatch left at each opening (Eq. 9 made the chest and the head other than
  isometric; a step's worth, since each step starts from the part as the previous one held it)
  is spread over a *zone* of the neighbouring side, one opening radius wide along the surface:
  a zone vertex z moves by w(z)·Σ_o b_zo (S − E)(o), the opening vertices' mismatches blended
  by the inverse fourth power of their distance to z (:class:`BlendZone`), w falling smoothly
  from 1 at the opening to 0 (smoothstep). A zone never reaches an appendage held before it
  (it may blend the edge of the neck). An appendage is then exactly S, so its length and mass are
  isometric to the measures' precision (the neck to within what its edge shares with the zones);
  the zones lie in ruled regions, whose measures the solver meets on this very mesh.

Once a run is made, the neck (with all it carries) and the head are turned back to the direction
they had on the run's input (:meth:`HeldRegions.turned_back`), each bending at its own base: Eq.
9's per-axis power law tilts a slanted neck, and Q above takes that tilt.

A part that does not touch the torso's side of the body, or has fewer than ``MIN_VERTICES``
vertices, is not held so (a note says so; the soft terms then hold it).

A ruled region whose rules fix only its size (the head of ``quadruped``: mass exponent 0.70) is
held the same way at the size its rule asks instead of the isometric one
(:func:`rule_held_regions`), times a size the solver sets to meet the rule: its eyes, ears and
horns keep their shape. Its own base takes the difference in size from the isometric neck, over
a zone half as wide inside it, so that the neck stays isometric.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from allorules.body import Body
from allorules.mesh.geometry import similarity_fit, smoothstep, vertex_areas
from allorules.mesh.topology import (
    submesh,
    vertex_adjacency,
    vertex_components,
    vertex_graph,
)
from allorules.segment.regions import NEIGHBOUR_REGION

ZONE = 1.0              # width of a blend zone beyond an opening, in opening radii (along the surface)
RULED_ZONE = 0.5        # ... inside a ruled part's near opening (the head's base meets the isometric neck)
MIN_VERTICES = 8        # smaller parts carry no shape to keep
BLEND_POWER = 4         # a zone vertex's share of an opening vertex's correction falls as its distance to this power
ISLAND_SHARE = 0.05     # a side of the body beyond a part smaller than this share of the part's area is part of it
ROOT_REGIONS = ("chest", "abdomen")   # the torso: what a held part's near opening faces
ARAP_ITERATIONS = 20    # local-global iterations of a neck bent back along its length (turn_back_bending)

__all__ = ["BlendZone", "HeldPart", "HeldRegions", "hold_regions", "rule_held_regions"]



@dataclass(frozen=True)
class BlendZone:
    """Vertices beyond an opening that take part of the opening's correction: ``vertices`` (body
    ids), ``blend`` (for each, the share it takes of each opening vertex's correction: weights by
    the inverse BLEND_POWER of its distance to them, summing to 1) and ``weight`` (1 at the
    opening, falling to 0 one zone width away).

    Each zone vertex once took the correction of its nearest opening vertex alone, which copied
    every opening vertex's own mismatch into the patch of the zone nearest it: two neighbouring
    zone vertices nearest two different opening vertices moved apart by the difference, and the
    held-out bulldog's back grew a spike beside its neck at ×2 (a vertex 0.30 of its edges out of
    the surface beyond its input's offset, its neighbour 0.14 in; 0.05 and 0.02 blended). Blended
    from the opening vertices around it, the correction varies smoothly across the zone; one
    shared by the whole opening is carried whole. (The inverse square blended more, 0.01, but took
    the first vertices beside the opening away from it: the generated horse's worst stretch jump
    at an opening, 1.74, exceeded the body's own, 1.73; tests/test_held_regions.py.)"""

    vertices: np.ndarray
    blend: np.ndarray
    weight: np.ndarray

    @classmethod
    def beyond(cls, graph, opening: np.ndarray, side: np.ndarray, reference: np.ndarray,
               zone: float | None = None) -> "BlendZone":
        """The zone of ``side`` (a mask of body vertices) beyond ``opening`` (body ids): distances
        along the surface within the side and the opening, width ``zone`` opening radii (default
        ``ZONE``); the blend from the opening by distance in ``reference`` (the input's positions)."""
        allowed = side.copy()
        allowed[opening] = True
        index = np.flatnonzero(allowed)
        position = np.full(len(side), -1)
        position[index] = np.arange(len(index))
        sub = graph[index][:, index]
        distance = dijkstra(sub, directed=False, indices=position[opening], min_only=True)
        points = reference[opening]
        radius = float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))
        width = (ZONE if zone is None else zone) * radius
        inside = side[index] & np.isfinite(distance) & (distance < width)
        vertices = index[inside]
        gaps = cdist(reference[vertices], points)
        blend = 1.0 / np.maximum(gaps, 1e-12 * max(radius, 1e-300)) ** BLEND_POWER
        blend /= np.maximum(blend.sum(axis=1, keepdims=True), 1e-300)
        return cls(vertices, blend, 1.0 - smoothstep(distance[inside] / width))

    def without(self, kept: np.ndarray) -> "BlendZone":
        """The zone less the body vertices ``kept`` (another held part's, which must stay exact)."""
        stay = ~np.isin(self.vertices, kept)
        return BlendZone(self.vertices[stay], self.blend[stay], self.weight[stay])

    def apply(self, vertices: np.ndarray, correction: np.ndarray) -> None:
        """Move the zone (in place) by its share of the opening vertices' ``correction``."""
        if len(self.vertices):
            vertices[self.vertices] += self.weight[:, None] * (self.blend @ correction)


_EMPTY_ZONE = BlendZone(np.zeros(0, dtype=np.int64), np.zeros((0, 0)), np.zeros(0))


@dataclass(frozen=True)
class HeldPart:
    """One connected part of a held region and what moves with it.

    ``members``: its body vertices; ``reference``: their positions on the run's input (the shape
    kept); ``weights``: their area shares (for the fit); ``near`` / ``far``: indices into
    ``members`` of the opening towards the torso and of the opening beyond (empty for an appendage
    such as a tail); ``children``: body vertices beyond the far opening, moved rigidly by τ;
    ``parent``: for an appendage, the body vertices of the region it grows from (the head under an
    ear, the abdomen under a tail), whose turn it follows, and ``parent_reference`` /
    ``parent_weights`` their input positions and area shares;
    ``near_zone`` / ``far_zone``: where the openings' mismatch is spread; ``size_exponent``: the
    part is sized ``scale ** size_exponent`` for the isometric factor ``scale`` (1 for an open
    region; 3e/d for a region held by a rule of exponent e on a measure of dimension d);
    ``ruled``: such a part's near zone lies inside it (its base takes the opening where the region
    before it left it, so that an isometric neck stays isometric) and its size is a variable of
    the solver (the rule is met by the solver, the base's blend included); ``joined``: the other
    open appendage regions held in this part, which touch it (an ear's horn); ``base_zone``: for
    an open part that carries others (the neck), its own base, where it bends when turned back
    (:meth:`turn_back`)."""

    region: str
    members: np.ndarray
    reference: np.ndarray
    weights: np.ndarray
    near: np.ndarray
    far: np.ndarray
    children: np.ndarray
    near_zone: BlendZone
    far_zone: BlendZone | None
    parent: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    parent_reference: np.ndarray | None = None
    parent_weights: np.ndarray | None = None
    size_exponent: float = 1.0   # the part's size factor is scale ** this: 1 isometric, a ruled head its rule's
    ruled: bool = False          # held at its rule's size: its base blends to where its neighbour left the opening
    seam: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))   # ruled: members on the torso side's faces
    joined: tuple[str, ...] = ()  # other appendage regions held in this part (they touch it)
    base_zone: BlendZone = field(default_factory=lambda: _EMPTY_ZONE)

    def parent_turn(self, vertices: np.ndarray) -> np.ndarray | None:
        """How the region this appendage grows from turned (``vertices``: the whole body now)."""
        if len(self.parent) < 3:
            return None
        _, rotation, _ = similarity_fit(self.parent_reference, vertices[self.parent], self.parent_weights)
        return rotation

    def shape(self, moved: np.ndarray, scale: float, parent_turn: np.ndarray | None = None) -> np.ndarray:
        """S: the reference shape × ``scale``, turned as ``moved`` (the part's vertices after Eq. 9)
        is, its near opening's centre where ``moved`` has it.

        Q is the rotation that best maps the reference onto ``moved`` (Kabsch/Umeyama) over the
        whole part when it carries something (the neck: the head goes where Eq. 9 put it). An
        appendage (a tail, an ear, a horn: nothing beyond it) turns as the region it grows from
        turned (``parent_turn``, :meth:`parent_turn`; identity when not given): it keeps its set
        on the head or the rump. (Fitted over the whole tail, which Eq. 9 bends, Q swung a
        giraffe's tail out by about 40° at ×0.5; fitted over its near opening alone, a small ring
        that Eq. 9 distorts, it turned the camel's hanging tail up into its rump at ×2; taken as the
        whole body's turn, the cow's ears did not follow its head and a spike stood by its eye.)"""
        if len(self.far):
            _, rotation, _ = similarity_fit(self.reference, moved, self.weights)
        else:
            rotation = np.eye(3) if parent_turn is None else parent_turn
        shape = scale * self.reference @ rotation.T
        return shape + (moved[self.near].mean(axis=0) - shape[self.near].mean(axis=0))

    def apply(self, vertices: np.ndarray, scale: float, size: float = 1.0) -> None:
        """Give the part (in ``vertices``, in place) its reference shape × ``scale ** size_exponent``
        × ``size``; move its children with its far opening and spread the openings' mismatch over
        the zones (a ruled part's near zone: over its own base, after it has its shape)."""
        moved = vertices[self.members]
        shape = self.shape(moved, scale ** self.size_exponent * size, self.parent_turn(vertices))
        if not self.ruled:
            self.near_zone.apply(vertices, shape[self.near] - moved[self.near])
        if len(self.far):
            shift = shape[self.far].mean(axis=0) - moved[self.far].mean(axis=0)
            vertices[self.children] += shift
            if self.far_zone is not None:
                self.far_zone.apply(vertices, shape[self.far] - (moved[self.far] + shift))
        vertices[self.members] = shape
        if self.ruled:   # every vertex it shares with the side before it stays where that side has it
            self.near_zone.apply(vertices, moved[self.seam] - shape[self.seam])

    def turn_back(self, vertices: np.ndarray, carried: np.ndarray | None = None) -> None:
        """Turn the part and what it carries (in ``vertices``, in place) rigidly about its near
        opening's centre back to the direction it had on the run's input: by Qᵀ, Q the rotation
        of its best similarity from the input (Kabsch, area-weighted), as the legs are turned back
        (:func:`allorules.solve.posture.restore_limb_axes`). Its own base bends: each vertex there
        turns by its share of Qᵀ about the same centre, none at the opening (the body before it is
        left as it is) and all of it one zone width in (an open part's ``base_zone``, a ruled part's
        ``near_zone``). Bending the chest beside the neck instead moved the front of the trunk: the
        held-out elephant's trunk length then read exponent 0.216 at ×0.5, beyond the 0.333 ± 0.1
        that refuses a run, where it read 0.240.

        Only a part that carries something (the neck under the head) or is held at its rule's size
        (the head) is turned: an appendage (a tail, ears, horns; even one held at its rule's size)
        already turns with the region it grows from. ``carried``: more vertices that turn with it
        rigidly (the appendages that grow from it)."""
        if not len(self.far) and (not self.ruled or self.region in NEIGHBOUR_REGION):
            return
        zone = self.near_zone if self.ruled else self.base_zone
        back, pivot = self._turn_back_about(vertices, zone)
        back = back.as_rotvec()
        moving = np.union1d(self.members, self.children)
        if carried is not None:       # whole, also where the zone reaches them
            moving, zone = np.union1d(moving, carried), zone.without(carried)
        moving = np.setdiff1d(moving, zone.vertices)
        vertices[moving] = (vertices[moving] - pivot) @ Rotation.from_rotvec(back).as_matrix().T + pivot
        if len(zone.vertices):
            bends = Rotation.from_rotvec((1.0 - zone.weight)[:, None] * back[None, :])
            vertices[zone.vertices] = bends.apply(vertices[zone.vertices] - pivot) + pivot

    def turn_back_bending(self, vertices: np.ndarray, faces: np.ndarray, carried: np.ndarray | None = None) -> None:
        """As :meth:`turn_back` for a part that carries something (the neck), but what it carries
        turns rigidly and the part itself bends along its whole length, as rigid as possible
        (libigl's ARAP, the part's vertices free, every other vertex of its faces held where it is
        or turned), instead of at its base. A neck as short as it is wide, turned back 29° at its
        base, read 15 % heavier (the held-out donkey at ×0.5, docs/benchmarks.md); bent along its
        length each face turns a little. A part that carries nothing is left as it is."""
        import igl

        if not len(self.far):
            return
        back, pivot = self._turn_back_about(vertices, self.base_zone)
        rest = np.array(vertices, dtype=float, copy=True)
        moving = np.union1d(self.children, carried if carried is not None else np.zeros(0, dtype=np.int64))
        moving = np.setdiff1d(moving, self.members)
        vertices[moving] = back.apply(vertices[moving] - pivot) + pivot
        touching = np.isin(faces, self.members).any(axis=1)
        local_rest, local_faces, index = submesh(rest, faces, touching)
        free = np.isin(index, self.members)
        held = np.flatnonzero(~free).astype(np.int32)
        data = igl.ARAPData()
        data.max_iter = ARAP_ITERATIONS
        igl.arap_precomputation(local_rest, local_faces.astype(np.int64), 3, held, data)
        bent = igl.arap_solve(vertices[index[held]], data, local_rest)
        if np.all(np.isfinite(bent)):
            vertices[index[free]] = bent[free]
        else:       # never a neck left behind its turned head: bent at its base instead
            vertices[:] = rest
            self.turn_back(vertices, carried)

    def _turn_back_about(self, vertices: np.ndarray, zone: BlendZone) -> tuple[Rotation, np.ndarray]:
        """(Qᵀ, the centre of the near opening): the turn that takes the part back to the direction
        it had on the run's input, Q the rotation of the best similarity (Kabsch, area-weighted) of
        its shape beyond ``zone`` (its base, which bends; all of it where that leaves too few)."""
        fitted = ~np.isin(self.members, zone.vertices)
        fitted = fitted if fitted.sum() >= MIN_VERTICES else np.ones(len(self.members), bool)
        _, turn, _ = similarity_fit(self.reference[fitted], vertices[self.members[fitted]], self.weights[fitted])
        return Rotation.from_matrix(turn.T), vertices[self.members[self.near]].mean(axis=0)


@dataclass(frozen=True)
class HeldRegions:
    """The held parts of a body, in the order they are applied (those carrying others first)."""

    parts: tuple[HeldPart, ...]
    notes: tuple[str, ...] = ()

    @property
    def regions(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(name for part in self.parts for name in (part.region, *part.joined)))

    @property
    def ruled(self) -> tuple[str, ...]:
        """The regions held at their rule's size, whose size is a variable of the solver."""
        return tuple(dict.fromkeys(part.region for part in self.parts if part.ruled))

    def apply(self, vertices: np.ndarray, scale: float, sizes: Mapping[str, float] | None = None) -> np.ndarray:
        """``vertices`` with every held part given its input shape × ``scale`` (the isometric factor
        from the run's input; a ruled part × ``scale ** size_exponent`` × its entry in ``sizes``),
        placed where ``vertices`` have it (module docstring)."""
        if not self.parts:
            return vertices
        sizes = sizes or {}
        result = np.array(vertices, dtype=float, copy=True)
        for part in self.parts:
            part.apply(result, scale, float(sizes.get(part.region, 1.0)))
        return result

    def turned_back(self, vertices: np.ndarray, neck: bool = True, faces: np.ndarray | None = None) -> np.ndarray:
        """``vertices`` with the neck (with the head, its ears and horns) and the head turned back to
        the direction each had on the run's input
        (:meth:`HeldPart.turn_back`): Eq. 9's per-axis power law tilts a slanted neck, and the held
        neck takes that tilt as its turn (the demo horse's head nodded 8.6° at ×2; turned back, 0.1°).
        ``neck=False``: the head alone (the open parts that carry it stay as they are). ``faces``
        given: the neck bends along its whole length instead of at its base
        (:meth:`HeldPart.turn_back_bending`)."""
        result = np.array(vertices, dtype=float, copy=True)
        for part in self.parts:
            if not neck and not part.ruled:
                continue
            # the appendages that grow from it turn with it whole, also where they touch a region
            # before it (the cow 381's ears and horns touch its neck: only a third of them lay beyond
            # the head, and turning that third alone tore its horns)
            carried = [other.members for other in self.parts if other is not part and not len(other.far)
                       and not other.ruled and len(other.parent)
                       and np.isin(other.parent, part.members).mean() > 0.5]
            carried = np.concatenate(carried) if carried else None
            if faces is not None and len(part.far):
                part.turn_back_bending(result, faces, carried)
            else:
                part.turn_back(result, carried)
        return result


def _sides(adjacency, inside: np.ndarray, root: np.ndarray, areas: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
    """The rest of the body (``~inside``) in connected sides: each vertex's side (−1 inside), the
    side that holds the torso (``root``; without it, the largest), and the vertices of sides too
    small to be a body part (fewer than ``MIN_VERTICES`` vertices or under ``ISLAND_SHARE`` of the
    part's area): label islands the part encloses."""
    outside = ~inside
    _, side = connected_components(adjacency[outside][:, outside], directed=False)
    side_of = np.full(len(inside), -1)
    side_of[outside] = side
    sizes = np.bincount(side)
    side_areas = np.bincount(side, weights=areas[outside])
    if root.any() and (root & outside).any():
        root_side = int(np.bincount(side_of[root & outside]).argmax())
    else:
        root_side = int(np.argmax(side_areas)) if len(side_areas) else -1
    small = (sizes < MIN_VERTICES) | (side_areas < ISLAND_SHARE * areas[inside].sum())
    if root_side >= 0:
        small[root_side] = False
    return side_of, root_side, outside & small[np.maximum(side_of, 0)]


def _pieces(faces: np.ndarray, count: int) -> list[np.ndarray]:
    """The region's faces (``faces``, body vertex ids) in pieces that share no vertex, largest first:
    two parts held one after the other must not share a vertex, or the second moves the first (the
    wolf's tail had two pieces of 8 vertices, each touching the tail at one vertex)."""
    component = vertex_components(vertex_adjacency(faces, count), np.isin(np.arange(count), faces))[faces[:, 0]]
    return sorted((np.flatnonzero(component == k) for k in np.unique(component)), key=len, reverse=True)


def hold_regions(body: Body, regions: tuple[str, ...], size_exponents: Mapping[str, float] | None = None) -> HeldRegions:
    """The :class:`HeldRegions` of ``regions`` on ``body`` (the run's input, labelled).

    ``size_exponents``: regions held at another size than isometric (:func:`rule_held_regions`).
    Each connected part of a region is held; touching parts of open appendage regions (an ear and
    a horn) are one part, named after the region with most of its faces (``joined``: the others).
    Its near opening is where it meets the side of the body that holds the torso
    (``ROOT_REGIONS``; without them, the largest side); every other side (the head beyond the
    neck) is its children. A part that does not touch that side, or has fewer than
    ``MIN_VERTICES`` vertices, is not held (a note says so)."""
    if body.labels is None or not regions:
        return HeldRegions(())
    count = len(body.vertices)
    adjacency = vertex_adjacency(body.faces, count).tocsr()
    graph = vertex_graph(body.vertices, body.faces).tocsr()
    areas = vertex_areas(body.vertices, body.faces)
    root = np.zeros(count, dtype=bool)
    for name in ROOT_REGIONS:
        if body.has_region(name):
            root |= body.region_mask(name)
    found: list[HeldPart] = []
    notes: list[str] = []
    sizes = dict(size_exponents or {})
    present = [region for region in regions if body.has_region(region)]
    # Open appendages (ears, horns, a tail) are pieced together: an ear and a horn that share a
    # vertex are one part, else the one held second moves the first's shared vertices (the cow
    # 381's ears came out at 0.9039 for 0.9, a horn touching each).
    appendages = tuple(region for region in present if region in NEIGHBOUR_REGION and region not in sizes)
    groups = [(region,) for region in present if region not in appendages] + ([appendages] if appendages else [])
    for group in groups:
        # the regions' faces as the measures take them (most of their corners in it), so that what
        # is held is what its length and mass are measured on
        face_masks = [body.region_face_mask(region) for region in group]
        region_face_ids = np.flatnonzero(np.any(face_masks, axis=0))
        face_region = np.argmax(np.array(face_masks)[:, region_face_ids], axis=0)
        region_faces = body.faces[region_face_ids]
        for piece in _pieces(region_faces, count):
            faces = region_faces[piece]
            held_here = np.bincount(face_region[piece], minlength=len(group))
            region = group[int(np.argmax(held_here))]
            joined = tuple(group[k] for k in np.flatnonzero(held_here) if group[k] != region)
            inside = np.zeros(count, dtype=bool)
            inside[np.unique(faces)] = True
            if inside.sum() < MIN_VERTICES:
                continue
            side_of, root_side, islands = _sides(adjacency, inside, root, areas)
            if islands.any():
                inside |= islands
                side_of, root_side, _ = _sides(adjacency, inside, root, areas)
            members = np.flatnonzero(inside)
            touching = adjacency[members].tocoo()
            neighbour_side = side_of[touching.col]
            near_ids = np.unique(members[touching.row][neighbour_side == root_side])
            far_ids = np.setdiff1d(np.unique(members[touching.row][(neighbour_side >= 0) & (neighbour_side != root_side)]),
                                   near_ids)
            if root_side < 0 or not len(near_ids):
                notes.append(f"region {region}: a part of {len(members)} vertices does not join the torso's side of the "
                             "body; " + ("Eq. 9 reshapes it as its rule asks" if region in sizes
                                         else "it is held by soft terms"))
                continue
            child_side = (side_of >= 0) & (side_of != root_side)
            reference = body.vertices[members].copy()
            parent = np.zeros(0, dtype=np.int64)
            if not len(far_ids):
                # an appendage follows the region it grows from: the commonest region just outside its
                # near opening, less what is held
                outside = touching.col[(neighbour_side == root_side) & (body.labels[touching.col] >= 0)]
                if len(outside):
                    grows_from = np.bincount(body.labels[outside]).argmax()
                    parent = np.setdiff1d(np.flatnonzero(body.labels == grows_from), members)
            ruled = region in sizes
            seam_ids = near_ids
            if ruled:   # its vertices on faces of the torso's side (the neck's last faces), not only its opening's
                others = np.ones(len(body.faces), dtype=bool)
                others[region_face_ids[piece]] = False
                others &= ~np.any(child_side[body.faces], axis=1)
                seam_ids = np.intersect1d(members, body.faces[others])
            found.append(HeldPart(
                region, members, reference, areas[members] / areas[members].sum(),
                np.searchsorted(members, near_ids), np.searchsorted(members, far_ids), np.flatnonzero(child_side),
                # an open part blends the body beside its opening; a ruled one its own base (below)
                _EMPTY_ZONE if ruled else BlendZone.beyond(graph, near_ids, side_of == root_side, body.vertices),
                BlendZone.beyond(graph, far_ids, child_side, body.vertices) if len(far_ids) else None,
                parent, body.vertices[parent].copy(), areas[parent] / max(areas[parent].sum(), 1e-300),
                float(sizes.get(region, 1.0)), ruled, np.searchsorted(members, seam_ids), joined,
                # where an open part that carries others bends when turned back: its own base
                BlendZone.beyond(graph, near_ids, inside, body.vertices) if len(far_ids) and not ruled else _EMPTY_ZONE))
    # parts that carry others (the neck carries the head and its ears) first. A zone spreads its
    # opening's mismatch over the body beside it, never over an appendage (tail, ears, horns, trunk)
    # held before it (applied after the ears, the horns' zone moved the cow's small ears: ears
    # length 0.258 at ×0.5). It may reach the edge of a neck held before it (the wolf's ears sit at
    # its neck: kept out of their zones, the seam creased and 6 faces flipped at ×2), and a part held
    # after it takes the zone's share before it is given its shape where it then sits.
    ordered: list[HeldPart] = []
    held_before = np.zeros(0, dtype=np.int64)          # the appendages held so far
    shaped = np.zeros(0, dtype=np.int64)               # every part's vertices held so far
    for part in sorted(found, key=lambda part: -len(part.children)):
        if part.ruled:
            # its seam: its vertices on the torso side's faces, and those it shares with a part held
            # before it (a head vertex that only touches the neck's ring is one of the neck's), so
            # that the part before keeps its shape exactly
            seam = np.union1d(part.members[part.seam], np.intersect1d(part.members, shaped))
            inside = np.zeros(count, dtype=bool)
            inside[part.members] = True
            part = replace(part, seam=np.searchsorted(part.members, seam),
                           near_zone=BlendZone.beyond(graph, seam, inside, body.vertices, RULED_ZONE))
        ordered.append(replace(part, near_zone=part.near_zone.without(held_before),
                               far_zone=None if part.far_zone is None else part.far_zone.without(held_before)))
        if part.region in NEIGHBOUR_REGION:
            held_before = np.concatenate([held_before, part.members])
        shaped = np.union1d(shaped, part.members)
    return HeldRegions(tuple(ordered), tuple(notes))


# A ruled region's size from its rule: a measure of dimension d (mass 3, length and girth 1) with
# exponent e grows by R^e, so the region's size by R^(e/d) = scale^(3e/d), scale = R^(1/3).
MEASURE_DIMENSIONS = {"mass": 3.0, "length": 1.0, "girth": 1.0}


def rule_held_regions(ruleset, body: Body) -> dict[str, float]:
    """The ruled regions held by their shape (``solver.ruled_shape: hold``, the default), each with
    its size exponent (:class:`HeldPart`): a region of ``body`` that is neither torso nor limb (the
    head) whose rules all ask one size of it, on measures of known dimension (mass, length,
    girth). The solver meets its rule through its size, and its eyes, ears and horns keep their shape:
    reshaped by Eq. 9's α instead, the real horse's head came out a thin beak at ×2 once the legs
    could thicken (solver.limb_thickness) and the Princeton pig's ears crumpled (docs/method.md,
    "the head held by its rule")."""
    from allorules.measure.parts import LIMB_REGIONS, TORSO_REGIONS

    if ruleset.solver.ruled_shape != "hold":
        return {}
    held: dict[str, float] = {}
    for region in ruleset.regions:
        rules = [rule for rule in ruleset.rules if rule.region == region]
        if (region in TORSO_REGIONS or region in LIMB_REGIONS or not rules or not body.has_region(region)
                or any(rule.measure not in MEASURE_DIMENSIONS for rule in rules)):
            continue
        sizes = {round(3.0 * rule.exponent / MEASURE_DIMENSIONS[rule.measure], 9) for rule in rules}
        if len(sizes) == 1:
            held[region] = sizes.pop()
    return held
