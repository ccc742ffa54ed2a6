"""Automatic labelling of a standing quadruped into head, neck, chest, abdomen, forelimbs, hindlimbs.

The rules (documented with their limits in ``docs/segmentation.md``):

1. **Extremities.** The average geodesic distance (AGD, from a farthest-point sample of sources)
   is largest at the tips of protrusions. Its local maxima, ranked by topological persistence
   (how far the AGD falls before the tip's super-level component meets a more prominent one),
   are the candidate tips: feet, muzzle, tail, ears, horns, trunk.
2. **Feet and up.** Four candidates are the feet if a plane through them is a supporting plane
   of the whole mesh (nothing lies clearly below it), they are nearly coplanar, and the
   surface's centroid projects inside their quadrilateral; of the valid sets the most
   persistent wins. Up is the plane's normal, towards the body. ``up`` overrides the normal.
3. **Legs.** Sweeping a plane upwards from the ground, each foot's connected part of the
   surface below the plane grows as a tube until it meets another substantial part (the belly,
   the other leg of the pair): the leg is cut there, by that horizontal plane (the armpit or
   groin). Two legs that only touch (knees) are not the body: the sweep goes on past them.
4. **Forward.** The feet pair into fore and hind (the pairing with the shorter in-pair
   distances); the head end of the body axis is the end with more surface beyond its pair of
   feet (head and neck outweigh a tail). ``forward`` overrides the sign (and the axis).
5. **Head, neck, chest, abdomen.** See :func:`_split_torso` and :func:`_neck_cuts`: from where
   the skeleton of the front part bends, the neck is followed down as a tube; the head ends at
   its throat (its narrowest section, in the head's half of the neck) and the neck where the
   tube flares into the chest (the knee of its section radius).

Everything is measured in units of the mesh's own size (√area), along its own detected axes,
so the labels do not change under rotation, mirroring or uniform scaling.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse
from scipy.sparse.csgraph import connected_components, dijkstra

from allorules.body import UNLABELLED, Body, Frame
from allorules.errors import SegmentationError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.topology import (
    corner_edges,
    directed_edges,
    vertex_components,
    vertex_graph,
)
from allorules.segment.regions import QUADRUPED_REGIONS

REGIONS = QUADRUPED_REGIONS
HEAD, NECK, CHEST, ABDOMEN, FORELIMBS, HINDLIMBS = range(6)

AGD_SOURCES = 24            # farthest-point sources for the average geodesic distance
CANDIDATE_TIPS = 12         # most persistent extremities considered as feet
MIN_PERSISTENCE = 0.03      # of the AGD range: smaller maxima are surface noise
PLANARITY_TOLERANCE = 0.12  # foot heights off their plane, relative to the feet's spread
SUPPORT_TOLERANCE = 0.06    # how far (relative to body height) the mesh may dip below the foot plane
SUPPORT_RESOLUTION = 0.01  # misfits of the ground plane closer than this (of the feet's spread) tie
SUBSTANTIAL_PART = 0.01     # of the surface area: smaller sublevel parts are bumps, not the body


@dataclass
class Extremities:
    """Tips of protrusions: vertex ids and their persistence (in units of √area)."""

    vertices: np.ndarray
    persistence: np.ndarray


def label_quadruped(body: Body, *, up=None, forward=None, complete: bool = True) -> Body:
    """Label a standing quadruped's vertices with the six regions of :data:`REGIONS`.

    Returns a new :class:`Body` with ``labels``, ``region_names = REGIONS`` and ``frame`` set to
    the detected (or given) ``Frame(up, forward)``. Raises :class:`SegmentationError` with a
    one-line reason when the mesh does not look like a standing quadruped, and (with
    ``complete``, the default) when any region was not found. ``complete=False`` returns the
    partial labelling instead, for diagnosis only.
    """
    vertices, faces = body.vertices, body.faces
    if len(vertices) < 50 or len(faces) < 50:
        raise SegmentationError(f"the mesh has only {len(vertices)} vertices; too coarse to find a quadruped's regions")
    if not np.isfinite(vertices).all():
        raise SegmentationError("the mesh has NaN or infinite vertex coordinates; prepare it first")
    up = _unit_or_none(up, "up")
    forward = _unit_or_none(forward, "forward")
    graph = vertex_graph(vertices, faces)
    mass = vertex_areas(vertices, faces)
    parts = vertex_components(graph)
    main_part = int(np.argmax(np.bincount(parts, weights=mass)))
    main = parts == main_part
    index = np.flatnonzero(main)
    sub_graph = graph[index][:, index]
    sub_vertices = vertices[index]
    sub_mass = mass[index]
    scale = float(np.sqrt(sub_mass.sum()))
    if not scale > 0:
        raise SegmentationError("the mesh has no surface area")
    # Work in units of the mesh's own size: nothing below depends on its absolute scale.
    sub_vertices = (sub_vertices - np.average(sub_vertices, axis=0, weights=sub_mass)) / scale
    sub_graph = sub_graph / scale
    local = np.full(len(vertices), -1, dtype=np.int64)
    local[index] = np.arange(len(index))
    sub_faces = local[faces[main[faces].all(axis=1)]]
    labels_main, frame = _label_connected(sub_vertices, sub_faces, sub_graph, sub_mass, up, forward)
    labels = np.full(len(vertices), UNLABELLED, dtype=np.int64)
    labels[index] = labels_main
    if not main.all():  # small separate parts (eyes, teeth) take the label of the nearest body vertex
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(vertices[index]).query(vertices[~main])
        labels[~main] = labels_main[nearest]
    # Never hand on a body with a region missing: every later measurement would fail on it, or worse.
    missing = [name for index_of, name in enumerate(REGIONS) if not np.any(labels == index_of)]
    if missing and complete:
        raise SegmentationError(
            f"found no {' and no '.join(missing)} on this mesh; give the regions with --segmentation FILE "
            "(allorules segment --patches 24 and a merge file), or try --up/--forward"
        )
    return Body(vertices, faces, labels, REGIONS, frame)


def _unit_or_none(direction, name: str) -> np.ndarray | None:
    if direction is None:
        return None
    direction = np.asarray(direction, dtype=float).reshape(-1)
    if direction.shape != (3,) or not np.isfinite(direction).all() or np.linalg.norm(direction) == 0:
        raise SegmentationError(f"--{name} must be a non-zero direction like 0,1,0 or +y")
    return direction / np.linalg.norm(direction)


def _label_connected(vertices, faces, graph, mass, up, forward):
    extremities = find_extremities(vertices, graph, mass)
    feet, up = _find_feet(vertices, mass, extremities, up)
    height = vertices @ up
    legs = _cut_legs(vertices, faces, graph, mass, height, feet, up)
    fore, hind, forward = _pair_feet(vertices, mass, up, feet, legs, forward)
    labels = np.full(len(vertices), UNLABELLED, dtype=np.int64)
    for foot in fore:
        labels[legs == foot] = FORELIMBS
    for foot in hind:
        labels[legs == foot] = HINDLIMBS
    _split_torso(vertices, faces, graph, mass, up, forward, labels, fore, hind)
    return labels, Frame(up=up, forward=forward)


# ---------------------------------------------------------------- extremities

def average_geodesic_distance(graph: sparse.csr_matrix, mass: np.ndarray, sources: int = AGD_SOURCES) -> np.ndarray:
    """Mean graph-geodesic distance from a farthest-point sample of ``sources`` vertices."""
    n = graph.shape[0]
    start = int(np.argmax(mass))  # deterministic, independent of vertex order only up to ties
    chosen = [start]
    distance = dijkstra(graph, indices=start)
    rows = [distance]
    nearest = distance.copy()
    for _ in range(min(sources, n) - 1):
        nxt = int(np.argmax(nearest))
        chosen.append(nxt)
        distance = dijkstra(graph, indices=nxt)
        rows.append(distance)
        nearest = np.minimum(nearest, distance)
    return np.mean(rows, axis=0)


def persistent_maxima(values: np.ndarray, graph: sparse.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of a vertex function and their persistence (super-level-set union–find).

    Sweeping downwards, each maximum starts a component; when two components meet at a
    vertex, the one born lower dies there and its persistence is birth − that value (elder rule).
    The global maximum's persistence is its value minus the global minimum.
    """
    order = np.argsort(-values, kind="stable")
    parent = np.full(len(values), -1, dtype=np.int64)
    birth_vertex = {}
    persistence = {}
    indptr, indices = graph.indptr, graph.indices

    for v in order:
        roots = {_find(parent, u) for u in indices[indptr[v]:indptr[v + 1]] if parent[u] >= 0}
        if not roots:
            parent[v] = v
            birth_vertex[v] = v
            continue
        roots = sorted(roots, key=lambda r: -values[birth_vertex[r]])
        survivor = roots[0]
        parent[v] = survivor
        for other in roots[1:]:
            tip = birth_vertex[other]
            persistence[tip] = values[tip] - values[v]
            parent[other] = survivor
    for root in {_find(parent, v) for v in range(len(values))}:
        tip = birth_vertex[root]
        persistence[tip] = values[tip] - values.min()
    tips = np.array(sorted(persistence, key=lambda t: -persistence[t]), dtype=np.int64)
    return tips, np.array([persistence[t] for t in tips])


def find_extremities(vertices, graph, mass) -> Extremities:
    """Tips of the mesh's protrusions, most persistent first (AGD maxima above a noise floor)."""
    agd = average_geodesic_distance(graph, mass)
    tips, persistence = persistent_maxima(agd, graph)
    keep = persistence >= MIN_PERSISTENCE * (agd.max() - agd.min())
    return Extremities(tips[keep], persistence[keep])


# ---------------------------------------------------------------- feet and up

def _find_feet(vertices, mass, extremities: Extremities, up):
    tips = extremities.vertices[:CANDIDATE_TIPS]
    strength = extremities.persistence[:CANDIDATE_TIPS]
    if len(tips) < 4:
        raise SegmentationError(
            f"found only {len(tips)} limb-like extremities, a standing quadruped has at least four feet; "
            "this mesh does not look like a quadruped (segment it by hand: allorules segment --patches)"
        )
    centroid = np.average(vertices, axis=0, weights=mass)
    best, best_score = None, -np.inf
    for combination in itertools.combinations(range(len(tips)), 4):
        points = vertices[tips[list(combination)]]
        normal = _support_normal(points, centroid, up)
        if normal is None:
            continue
        heights = (vertices - points.mean(axis=0)) @ normal
        body_height = heights.max()
        foot_heights = heights[tips[list(combination)]]
        spread = np.max(np.linalg.norm(points[:, None] - points[None], axis=2))
        if np.ptp(foot_heights) > PLANARITY_TOLERANCE * spread:
            continue
        if heights.min() < foot_heights.min() - SUPPORT_TOLERANCE * body_height:
            continue
        if not _inside_quad(points, centroid, normal):
            continue
        # Standing on the ground: the four feet are the lowest points and level with each other.
        # The better support (less of the mesh below the lowest foot, feet more level) wins; a
        # hanging trunk or tail tip with three feet makes a tilted plane the fourth foot dips
        # below. Persistence only breaks ties between equally good supports.
        misfit = (max(foot_heights.min() - heights.min(), 0.0) + np.ptp(foot_heights)) / spread
        score = -round(misfit / SUPPORT_RESOLUTION) + strength[list(combination)].sum() / strength.sum()
        if score > best_score:
            best, best_score = (tips[list(combination)], normal), score
    if best is None:
        raise SegmentationError(
            "four feet standing on a common ground plane were not found; the mesh does not look like a "
            "standing quadruped (if it is one, give --up; otherwise segment it by hand with allorules segment)"
        )
    return best


def _support_normal(points, centroid, up):
    if up is not None:
        return up if (centroid - points.mean(axis=0)) @ up > 0 else None
    centred = points - points.mean(axis=0)
    _, singular, axes = np.linalg.svd(centred)
    if singular[1] < 1e-9:
        return None
    normal = axes[2]
    return normal if (centroid - points.mean(axis=0)) @ normal > 0 else -normal


def _inside_quad(points, centroid, normal) -> bool:
    """Whether the centroid projects inside the convex hull of the four feet (on their plane)."""
    basis_u = np.cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(basis_u) < 0.1:
        basis_u = np.cross(normal, [0.0, 1.0, 0.0])
    basis_u /= np.linalg.norm(basis_u)
    basis_v = np.cross(normal, basis_u)
    flat = np.column_stack([points @ basis_u, points @ basis_v])
    target = np.array([centroid @ basis_u, centroid @ basis_v])
    hull = flat[_convex_hull_2d(flat)]
    signs = []
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        edge, offset = b - a, target - a
        signs.append(edge[0] * offset[1] - edge[1] * offset[0])
    signs = np.array(signs)
    return bool(np.all(signs >= 0) or np.all(signs <= 0))


def _convex_hull_2d(points):
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))

    def cross(o, a, b):
        return (points[a][0] - points[o][0]) * (points[b][1] - points[o][1]) - (points[a][1] - points[o][1]) * (points[b][0] - points[o][0])

    lower, upper = [], []
    for i in order:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], i) <= 0:
            lower.pop()
        lower.append(i)
    for i in reversed(order):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], i) <= 0:
            upper.pop()
        upper.append(i)
    return lower[:-1] + upper[:-1]


# ---------------------------------------------------------------- legs

def _cut_legs(vertices, faces, graph, mass, height, feet, up) -> np.ndarray:
    """Per-vertex foot id (−1 off the legs): each foot's part of the surface below its cut plane.

    Sweep upwards (sub-level sets of height, union–find). A foot's part stops growing at the
    first height where it meets another substantial part (area ≥ SUBSTANTIAL_PART of the
    surface, or holding another foot): that height is the leg's horizontal cut. Two legs that
    only touch (knees, hocks) are not the body: when two feet's parts meet and, just above the
    meeting, the horizontal section still shows them as two separate loops, the sweep goes on
    with them together; their shared part is split between the feet by geodesic distance.
    """
    n = len(height)
    order = np.argsort(height, kind="stable")
    parent = np.full(n, -1, dtype=np.int64)
    area = np.zeros(n)
    holds_foot = np.zeros(n, dtype=bool)
    cut = {int(foot): None for foot in feet}
    substantial = SUBSTANTIAL_PART * mass.sum()
    indptr, indices = graph.indptr, graph.indices
    is_foot = np.zeros(n, dtype=bool)
    is_foot[feet] = True
    members: dict[int, list[int]] = {}
    touching = []   # pairs of feet whose legs touch below their cuts
    pairs = None
    for v in order:
        roots = list({_find(parent, u) for u in indices[indptr[v]:indptr[v + 1]] if parent[u] >= 0})
        big = [r for r in roots if holds_foot[r] or area[r] >= substantial]
        foot_roots = [r for r in roots if holds_foot[r]]
        if len(big) >= 2:
            if len(big) == len(foot_roots) and all(cut[f] is None for r in foot_roots for f in members[r]):
                if pairs is None:
                    pairs = _face_pairs(faces)
                if _legs_touch(vertices, faces, pairs, height, up, parent, foot_roots, v):
                    touching.append([f for r in foot_roots for f in members[r]])
                    big = []
            for r in foot_roots if big else []:
                for foot in members[r]:
                    if cut[foot] is None:
                        cut[foot] = height[v]
        parent[v] = v
        area[v] = mass[v]
        holds_foot[v] = is_foot[v]
        members[v] = [int(v)] if is_foot[v] else []
        for r in roots:
            parent[r] = v
            area[v] += area[r]
            holds_foot[v] |= holds_foot[r]
            members[v] += members.pop(r)
        if all(value is not None for value in cut.values()):
            break
    legs = np.full(n, -1, dtype=np.int64)
    for foot, level in cut.items():
        if level is None:
            raise SegmentationError("a leg could not be separated from the body; the mesh does not look like a standing quadruped")
        parts = vertex_components(graph, height < level)
        legs[(parts == parts[foot]) & (height < level)] = foot
    for group in touching:   # legs that touch: the shared part goes to the geodesically nearest foot
        shared = np.isin(legs, group)
        if not shared.any():
            continue
        index = np.flatnonzero(shared)
        local = {int(v): i for i, v in enumerate(index)}
        distance = dijkstra(graph[index][:, index], indices=[local[f] for f in group if f in local])
        legs[index] = np.array([f for f in group if f in local])[np.argmin(distance, axis=0)]
    return legs


def _find(parent: np.ndarray, x: int) -> int:
    """Root of x in a union–find forest stored in ``parent`` (path compression on the way)."""
    root = x
    while parent[root] != root:
        root = parent[root]
    while parent[x] != root:
        parent[x], x = root, parent[x]
    return root


def _legs_touch(vertices, faces, pairs, height, up, parent, foot_roots, v) -> bool:
    """Whether the feet's parts meeting at vertex v only touch: in horizontal sections a little
    (two typical edge heights) and one leg radius above v, the loops nearest each part's top are
    different loops (legs that go on separately), not one (the body that joins them)."""
    step = 2 * float(np.median(np.abs(height[faces[:, 0]] - height[faces[:, 1]])))
    processed = np.flatnonzero(parent >= 0)
    root_of = np.array([_find(parent, u) for u in processed])
    tops = []
    for root in foot_roots:
        mine = processed[root_of == root]
        band = mine[height[mine] >= min(height[v] - step, height[mine].max())]   # never empty
        tops.append(vertices[band].mean(axis=0))
    rise = step
    for _ in range(2):
        loops, radius = set(), 0.0
        for top in tops:
            point = top + (height[v] + rise - top @ up) * up
            section = _section_loop(vertices, faces, pairs, point, up)
            if section is None:
                return False
            loops.add(int(section[2].min()))   # loops are disjoint sets of faces: the smallest names one
            radius = max(radius, float(np.sqrt(section[0] / np.pi)))
        if len(loops) < len(tops):
            return False
        rise = max(radius, step)
    return True


def _pair_feet(vertices, mass, up, feet, legs, forward):
    """Split the feet into fore and hind pairs and fix the forward direction."""
    points = vertices[feet]
    pairings = [((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2))]

    def in_pair_distance(pairing):
        return sum(np.linalg.norm(points[a] - points[b]) for a, b in pairing)

    pair_a, pair_b = min(pairings, key=in_pair_distance)
    middle_a = points[list(pair_a)].mean(axis=0)
    middle_b = points[list(pair_b)].mean(axis=0)
    axis = middle_b - middle_a
    axis -= (axis @ up) * up
    axis /= np.linalg.norm(axis)
    if forward is not None:
        flat = forward - (forward @ up) * up
        if np.linalg.norm(flat) < 1e-6:
            raise SegmentationError("--forward must not be parallel to up")
        flat /= np.linalg.norm(flat)
        if flat @ axis < 0:
            axis = -axis
            pair_a, pair_b = pair_b, pair_a
        forward_axis = flat
    else:
        torso = legs < 0
        along = vertices @ axis
        beyond_b = mass[torso & (along > middle_b @ axis)].sum()
        beyond_a = mass[torso & (along < middle_a @ axis)].sum()
        if beyond_a > beyond_b:
            axis = -axis
            pair_a, pair_b = pair_b, pair_a
        forward_axis = axis
    fore = [int(feet[i]) for i in pair_b]
    hind = [int(feet[i]) for i in pair_a]
    return fore, hind, forward_axis


# ---------------------------------------------------------------- torso

def _split_torso(vertices, faces, graph, mass, up, forward, labels, fore, hind) -> None:
    """Label the rest (not legs): head, neck, chest, abdomen. Fills ``labels`` in place.

    Head and neck: the section loops of :func:`_neck_cuts` cut them off the front (each the part
    connected to the head tip beyond its loop, see :func:`_beyond_loop`). Chest/abdomen: the
    vertical plane half way between the fore and hind feet. The tail (behind the hind legs)
    stays with the abdomen.
    """
    rest = np.flatnonzero(labels == UNLABELLED)
    along = vertices @ forward
    fore_along = vertices[fore].mean(axis=0) @ forward
    hind_along = vertices[hind].mean(axis=0) @ forward
    middle = 0.5 * (fore_along + hind_along)
    in_rest = np.zeros(len(vertices), dtype=bool)
    in_rest[rest] = True
    labels[in_rest & (along >= middle)] = CHEST
    labels[in_rest & (along < middle)] = ABDOMEN
    head_cut, neck_cut = _neck_cuts(vertices, faces, graph, rest, along, np.flatnonzero(labels == FORELIMBS))
    if head_cut is None:
        return
    tip = rest[np.argmax(along[rest])]
    pairs = _face_pairs(faces)
    for (point, normal), region in ((neck_cut, NECK), (head_cut, HEAD)):
        beyond = _beyond_loop(vertices, faces, graph, pairs, point, normal, in_rest, tip)
        if beyond is None or (along[beyond] < middle).any():
            continue   # the loop does not cut the front off (or leaks into the body): leave it
        labels[beyond] = region


def _beyond_loop(vertices, faces, graph, pairs, point, normal, allowed, tip):
    """Vertices on the tip's side of the section loop through ``point`` (⟂ ``normal``).

    Only the loop around ``point`` cuts, not the whole plane: the graph loses the edges that
    cross the plane inside that loop's faces, and the tip's connected part (within
    ``allowed``) is returned as a boolean mask, or None if the loop is not found.
    """
    section = _section_loop(vertices, faces, pairs, point, normal)
    if section is None:
        return None
    side = (vertices - point) @ normal > 0
    loop_faces = faces[section[2]]
    edges = directed_edges(loop_faces)
    edges = edges[side[edges[:, 0]] != side[edges[:, 1]]]
    cut = sparse.coo_matrix((np.ones(2 * len(edges)), (np.concatenate([edges[:, 0], edges[:, 1]]),
                                                        np.concatenate([edges[:, 1], edges[:, 0]]))),
                            shape=graph.shape).tocsr()
    kept = (graph - graph.multiply(cut > 0)).tocsr()
    kept.eliminate_zeros()
    # On the plane's tip side only: where the loop does not close (a hole in the mesh), the cut
    # is the plane near it; a bulge in front of the plane elsewhere (a horse's breast) is only
    # reached across the plane, so it stays with the body.
    allowed = allowed & side
    if not allowed[tip]:
        return None
    parts = vertex_components(kept, allowed)
    return allowed & (parts == parts[tip])


def isocontour_profile(vertices, faces, field, levels):
    """Length and centroid of the isocontour of a per-vertex field at each level (marching triangles)."""
    values = field[faces]
    corners = vertices[faces]
    lengths = np.zeros(len(levels))
    centroids = np.zeros((len(levels), 3))
    for k, level in enumerate(levels):
        above = values > level
        count = above.sum(axis=1)
        crossing = (count == 1) | (count == 2)
        if not crossing.any():
            continue
        v, c, a = values[crossing], corners[crossing], above[crossing]
        # The lone corner (the one on the other side from the other two) and its two edges.
        lone = np.where(a.sum(axis=1) == 1, np.argmax(a, axis=1), np.argmin(a, axis=1))
        rows = np.arange(len(v))
        points = []
        for step in (1, 2):
            other = (lone + step) % 3
            t = (level - v[rows, lone]) / (v[rows, other] - v[rows, lone])
            points.append(c[rows, lone] + t[:, None] * (c[rows, other] - c[rows, lone]))
        segment = np.linalg.norm(points[1] - points[0], axis=1)
        lengths[k] = segment.sum()
        if lengths[k] > 0:
            centroids[k] = (0.5 * (points[0] + points[1]) * segment[:, None]).sum(axis=0) / lengths[k]
    return lengths, centroids


PROFILE_LEVELS = 160
BEND_SHARE = 6             # the bend is measured between chords of 1/BEND_SHARE of the profile
MIN_NECK_LENGTH = 1.0      # a neck runs at least one of its radii from the bend to its base


def _neck_cuts(vertices, faces, graph, rest, along, forelimb):
    """(head cut, neck cut) as (point, normal) planes, normals towards the head tip, or
    (None, None) if no neck is found.

    1. The skeleton of the front part: centroids C(s) of the isocontours of the geodesic
       distance s from the head tip (the most forward non-leg vertex), up to where the
       isocontours reach the forelimbs.
    2. Head/neck: where that skeleton bends (the head's axis meets the neck's); the turn at s
       is the angle between the chords C(s) − C(s − w) and C(s + w) − C(s), w a fixed share
       (1/BEND_SHARE) of the profile; candidates are checked for a neck behind them.
    3. Neck base: the neck is followed as a tube from the bend (:func:`_follow_neck`); its
       section radius r(t) grows slowly (the taper) until the sections enter the chest. The
       base is the knee of r(t). The neck cut is the tube's section there.
    4. The head cut is the tube's section at the throat: its narrowest section when that lies
       in the head's half of the neck (the throatlatch), else at the bend.
    Only the section loops cut (see :func:`_beyond_loop`), so a bulge of the chest in front of
    a plane stays chest.
    """
    tip_local = int(np.argmax(along[rest]))
    sub = graph[rest][:, rest]
    distance_local = dijkstra(sub, indices=tip_local)
    distance = np.full(len(vertices), np.inf)
    distance[rest] = distance_local
    finite = np.isfinite(distance)
    faces = faces[finite[faces].all(axis=1)]
    near_forelimb = np.unique(graph[forelimb].indices)
    near_forelimb = near_forelimb[finite[near_forelimb]]
    span = float(distance[near_forelimb].min()) if len(near_forelimb) else float(distance[finite].max())
    levels = np.linspace(0, span, PROFILE_LEVELS + 2)[1:-1]
    step = levels[1] - levels[0]
    field = np.where(finite, distance, np.inf)
    perimeter, centroids = isocontour_profile(vertices, faces, field, levels)
    if not perimeter.max() > 0:
        return None, None
    perimeter = _moving_average(perimeter, 5)
    centroids = _moving_average(centroids, 5)
    # The bend is measured between chords of a fixed share of the profile: the head and the
    # neck each span a good part of it, while the muzzle's stop or an ear bends the skeleton
    # only over a short stretch.
    w = max(2, len(levels) // BEND_SHARE)
    turn = np.zeros(len(levels))
    for k in range(w, len(levels) - w):
        before = centroids[k] - centroids[k - w]
        after = centroids[k + w] - centroids[k]
        norms = np.linalg.norm(before) * np.linalg.norm(after)
        if norms > 0:
            turn[k] = np.arccos(np.clip(before @ after / norms, -1.0, 1.0))
    # Candidate bends: the local maxima of the turn at least half as sharp as the sharpest, the
    # sharpest first. The head/neck bend is followed by a neck (see _follow_neck): the sections
    # first narrow (from the back of the head into the neck) and the tube then runs at least
    # MIN_NECK_LENGTH of its radii before flaring into the chest. The first candidate that
    # shows both wins (a camel's S-shaped neck bends sharply again where it enters the chest,
    # and from there the sections only grow); if none does, the sharpest bend with a tube.
    peaks = [k for k in range(1, len(levels) - 1)
             if turn[k] >= turn[k - 1] and turn[k] > turn[k + 1] and turn[k] >= 0.5 * turn.max()]
    peaks.sort(key=lambda k: -turn[k])
    pairs = _face_pairs(faces)
    found = []
    for bend in peaks:
        neck_direction = centroids[bend + w] - centroids[bend]
        if not np.linalg.norm(neck_direction) > 0:
            continue
        neck_direction = neck_direction / np.linalg.norm(neck_direction)
        neck = _follow_neck(vertices, faces, pairs, centroids[bend], neck_direction, step, span)
        if neck is None:
            continue
        found.append((bend, neck_direction, neck))
        if neck[3] > 0 and neck[2] >= MIN_NECK_LENGTH:
            break
    if not found:
        return None, None
    bend, neck_direction, (base_point, base_direction, _, _, throat) = next(
        (candidate for candidate in found if candidate[2][3] > 0 and candidate[2][2] >= MIN_NECK_LENGTH), found[0])
    # The head cut: at the throat (the neck's narrowest section in its head half, else the bend;
    # see _follow_neck), across the neck's axis as the tube-following found it (the chord from
    # the bend to the base), not the first chord after the bend, which still leans into the head.
    axis = base_point - centroids[bend]
    if np.linalg.norm(axis) > 0:
        neck_direction = axis / np.linalg.norm(axis)
    return (throat, -neck_direction), (base_point, -base_direction)


def _follow_neck(vertices, faces, pairs, start, direction, step, span):
    """Follow a tube from ``start`` along ``direction``: (base point, base direction, length,
    narrowing) of the neck it finds, or None; length and narrowing (the distance to the
    narrowest section) in radii of the narrowest section.

    Each step cuts the surface with the plane through the current axis point perpendicular to
    the current direction, takes the loop around the point (its equivalent radius r and its
    centre), and steps on from that centre; the direction is the chord from the first centre to
    the current one (beyond two radii), so the axis follows a gently bent neck without turning
    into the chest. r changes slowly along the neck (its taper) and fast where the sections
    enter the chest: the base is the knee of r(t), past the narrowest section, of r's running
    maximum: the point farthest below the chord to its top (no threshold).
    """
    point = start
    travelled, radii, centres, directions = [], [], [], []
    distance_so_far = 0.0
    for _ in range(4 * PROFILE_LEVELS):
        section = _section_loop(vertices, faces, pairs, point, direction)
        if section is None:
            break
        area, centre, _ = section
        r = float(np.sqrt(area / np.pi))
        travelled.append(distance_so_far)
        radii.append(r)
        centres.append(centre)
        directions.append(direction)
        if distance_so_far > span:
            break
        chord = centre - centres[0]
        if np.linalg.norm(chord) > 2 * r:
            direction = chord / np.linalg.norm(chord)
        point = centre + step * direction
        distance_so_far += step
    if len(radii) < 3:
        return None
    radii, travelled = np.array(radii), np.array(travelled)
    narrowest = int(np.argmin(radii[:int(np.argmax(radii)) + 1]))   # the neck: before the widest (chest)
    # Past the narrowest section, r's running maximum (a dip where a plane slips between two
    # bulges is not the neck again); its knee up to where it first reaches its top.
    grown = np.maximum.accumulate(radii[narrowest:])
    top = int(np.argmax(grown))
    if top < 2:
        return None
    along_track = travelled[narrowest:] - travelled[narrowest]
    chord = grown[0] + along_track * ((grown[top] - grown[0]) / along_track[top])
    base = narrowest + int(np.argmax((chord - grown)[:top + 1]))
    if radii[narrowest] <= 0:
        return None
    # The throat: the narrowest section, when it lies in the head's half of the neck (a neck
    # narrowest just before the chest, like a lion's under its mane, has no throat: the bend
    # itself is then the head's end).
    throat = centres[narrowest] if 2 * travelled[narrowest] <= travelled[base] else centres[0]
    return (centres[base], directions[base], travelled[base] / radii[narrowest],
            travelled[narrowest] / radii[narrowest], throat)


def _face_pairs(faces):
    """Pairs of faces sharing an edge (rows of two face ids)."""
    edges = corner_edges(faces)
    face_of = np.tile(np.arange(len(faces)), 3)
    key = edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1]
    order = np.argsort(key, kind="stable")
    key, face_of = key[order], face_of[order]
    same = key[1:] == key[:-1]
    return np.column_stack([face_of[:-1][same], face_of[1:][same]])


def _section_loop(vertices, faces, pairs, point, normal):
    """(area, centre, faces) of the loop of the plane section through ``point`` (⟂ ``normal``)
    nearest ``point``, or None where the plane misses the surface.

    The faces the plane crosses form one ring per loop (joined through shared edges); the loop
    whose length-weighted centre is nearest ``point`` is taken. Area = |½ Σ (p_k − o) × (q_k − o) · n|
    over its oriented segments p_k → q_k (o any point of the plane: ``point``).
    """
    side = (vertices - point) @ normal
    above = side[faces] > 0
    crossing = above.any(axis=1) & ~above.all(axis=1)
    crossed = np.flatnonzero(crossing)
    if len(crossed) < 3:
        return None
    local = np.full(len(faces), -1)
    local[crossed] = np.arange(len(crossed))
    joined = pairs[crossing[pairs[:, 0]] & crossing[pairs[:, 1]]]
    ring = sparse.coo_matrix((np.ones(len(joined)), (local[joined[:, 0]], local[joined[:, 1]])),
                             shape=(len(crossed), len(crossed)))
    _, loop_of = connected_components(ring, directed=False)
    corners, values = vertices[faces[crossed]], side[faces[crossed]]
    ends = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        crosses = (values[:, a] > 0) != (values[:, b] > 0)
        t = np.where(crosses, values[:, a] / np.where(crosses, values[:, a] - values[:, b], 1.0), np.nan)
        ends.append(corners[:, a] + (corners[:, b] - corners[:, a]) * t[:, None])
    ends = np.stack(ends, axis=1)
    order = np.argsort(~np.isfinite(ends[:, :, 0]), axis=1, kind="stable")[:, :2]
    pair = ends[np.arange(len(ends))[:, None], order]
    start, end = pair[:, 0], pair[:, 1]
    face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    flip = np.einsum("ij,ij->i", end - start, np.cross(normal, face_normal)) < 0
    start, end = np.where(flip[:, None], end, start), np.where(flip[:, None], start, end)
    length = np.linalg.norm(end - start, axis=1)
    middle = 0.5 * (start + end)
    loops = loop_of.max() + 1
    weight = np.bincount(loop_of, weights=length, minlength=loops)
    centre = np.column_stack([np.bincount(loop_of, weights=middle[:, i] * length, minlength=loops)
                              for i in range(3)]) / np.maximum(weight, 1e-300)[:, None]
    nearest = int(np.argmin(np.linalg.norm(centre - point, axis=1)))
    mine = loop_of == nearest
    area = float(abs(0.5 * np.cross(start[mine] - point, end[mine] - point).sum(axis=0) @ normal))
    return area, centre[nearest], crossed[mine]


def _moving_average(values, width):
    """Centred moving average along the first axis, the ends padded with the end values."""
    values = np.asarray(values, dtype=float)
    pad = width // 2
    padded = np.concatenate([np.repeat(values[:1], pad, axis=0), values, np.repeat(values[-1:], pad, axis=0)])
    kernel = np.ones(width) / width
    if values.ndim == 1:
        return np.convolve(padded, kernel, mode="valid")
    return np.column_stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(values.shape[1])])
