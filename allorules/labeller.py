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
   the other leg of the pair): the leg is cut there, by that horizontal plane.
4. **Forward.** The feet pair into fore and hind (the pairing with the shorter in-pair
   distances); the head end of the body axis is the end with more surface beyond its pair of
   feet (head and neck outweigh a tail). ``forward`` overrides the sign (and the axis).
5. **Head, neck, chest, abdomen.** See :func:`_split_torso`.

Everything is measured in units of the mesh's own size (√area), along its own detected axes,
so the labels do not change under rotation, mirroring or uniform scaling.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse
from scipy.sparse.csgraph import dijkstra

from .body import UNLABELLED, Body, Frame
from .errors import SegmentationError
from .laplacian import lumped_mass
from .patches import connected_parts, vertex_graph

REGIONS = ("head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs")
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
    mass = lumped_mass(vertices, faces)
    parts = connected_parts(graph)
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
    legs = _cut_legs(graph, mass, height, feet)
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

    def find(x):
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for v in order:
        roots = {find(u) for u in indices[indptr[v]:indptr[v + 1]] if parent[u] >= 0}
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
    for root in {find(v) for v in range(len(values))}:
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

def _cut_legs(graph, mass, height, feet) -> np.ndarray:
    """Per-vertex foot id (−1 off the legs): each foot's part of the surface below its cut plane.

    Sweep upwards (sub-level sets of height, union–find). A foot's part stops growing at the
    first height where it meets another substantial part (area ≥ SUBSTANTIAL_PART of the
    surface, or holding another foot): that height is the leg's horizontal cut.
    """
    n = len(height)
    order = np.argsort(height, kind="stable")
    parent = np.full(n, -1, dtype=np.int64)
    area = np.zeros(n)
    foot_of = {}
    for foot in feet:
        foot_of[int(foot)] = int(foot)
    holds_foot = np.zeros(n, dtype=bool)
    cut = {int(foot): None for foot in feet}
    substantial = SUBSTANTIAL_PART * mass.sum()
    indptr, indices = graph.indptr, graph.indices
    is_foot = np.zeros(n, dtype=bool)
    is_foot[feet] = True
    members: dict[int, list[int]] = {}

    def find(x):
        root = x
        while parent[root] != root:
            root = parent[root]
        while parent[x] != root:
            parent[x], x = root, parent[x]
        return root

    for v in order:
        roots = list({find(u) for u in indices[indptr[v]:indptr[v + 1]] if parent[u] >= 0})
        big = [r for r in roots if holds_foot[r] or area[r] >= substantial]
        foot_roots = [r for r in roots if holds_foot[r]]
        if len(big) >= 2:
            for r in foot_roots:
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
        parts = connected_parts(graph, height < level)
        legs[(parts == parts[foot]) & (height < level)] = foot
    return legs


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

    From the head tip (the most forward non-leg vertex), the geodesic distance s runs down the
    head and neck into the torso. The perimeter P(s) of its isocontours has a peak in the head,
    a valley in the neck and grows large in the torso. Head/neck cut: at the valley (the throat);
    neck/chest cut: where P leaves the neck's trend and rises towards the torso. Both cuts are
    then made planar, perpendicular to the neck axis (the line through the isocontour centroids
    between the two levels). Chest/abdomen: the vertical plane half way between the fore and
    hind feet. The tail (behind the hind legs) stays with the abdomen.
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
    for (point, normal), region in ((neck_cut, NECK), (head_cut, HEAD)):
        beyond = in_rest & ((vertices - point) @ normal > 0)
        parts = connected_parts(graph, beyond)
        tip = rest[np.argmax(along[rest])]
        if beyond[tip]:
            labels[beyond & (parts == parts[tip])] = region


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
NECK_BASE_RISE = 1.15      # perimeter growth over NECK_RISE_WINDOW that marks the neck's base
NECK_RISE_WINDOW = 1.0     # in neck radii (valley perimeter / 2π)
MIN_VALLEY_DEPTH = 0.03    # of the largest perimeter: shallower dips are not a neck


def _neck_cuts(vertices, faces, graph, rest, along, forelimb):
    """(head cut, neck cut) as (point, normal) planes, or (None, None) if no neck is found.

    Profile P(s) of isocontour perimeters of the geodesic distance s from the head tip, up to
    where the isocontours reach the forelimbs. The neck is the deepest valley of P (depth =
    the smaller of the highest P before and after it, minus P there). Head cut: the level of the
    highest P before the valley (the back of the skull). Neck base: the first level after the
    valley where P grows by NECK_BASE_RISE within NECK_RISE_WINDOW (the flare into the chest),
    taken at the start of that window. Each cut is the plane that best fits its isocontour.
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
    field = np.where(finite, distance, np.inf)
    perimeter, _ = isocontour_profile(vertices, faces, field, levels)
    perimeter = np.convolve(perimeter, np.ones(5) / 5, mode="same")
    top = perimeter.max()
    if not top > 0:
        return None, None
    before = np.maximum.accumulate(perimeter)
    after = np.maximum.accumulate(perimeter[::-1])[::-1]
    depth = np.minimum(before, after) - perimeter
    valley = int(np.argmax(depth))
    if depth[valley] < MIN_VALLEY_DEPTH * top:
        return None, None
    head_level = int(np.argmax(perimeter[:valley + 1]))
    step = levels[1] - levels[0]
    window = max(1, int(round(NECK_RISE_WINDOW * perimeter[valley] / (2 * np.pi) / step)))
    base_level = None
    for sustained in (True, False):  # prefer a flare that keeps growing (the torso, not a bump)
        for k in range(valley + window, len(levels) - (window if sustained else 0)):
            rise = perimeter[k] > NECK_BASE_RISE * perimeter[k - window]
            if rise and (not sustained or perimeter[k + window] > NECK_BASE_RISE * perimeter[k]):
                base_level = k - window
                break
        if base_level is not None:
            break
    if base_level is None:
        return None, None
    tip = rest[tip_local]
    cuts = []
    for level in (levels[head_level], levels[base_level]):
        plane = _contour_plane(vertices, faces, field, level, vertices[tip])
        if plane is None:
            return None, None
        cuts.append(plane)
    return cuts[0], cuts[1]


def _contour_plane(vertices, faces, field, level, towards):
    """Best-fit plane (point, unit normal towards ``towards``) of the isocontour at ``level``."""
    values = field[faces]
    above = values > level
    crossing = (above.sum(axis=1) == 1) | (above.sum(axis=1) == 2)
    if crossing.sum() < 3:
        return None
    corners = vertices[faces[crossing]]
    v = values[crossing]
    points = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        crosses = (v[:, a] > level) != (v[:, b] > level)
        t = (level - v[crosses, a]) / (v[crosses, b] - v[crosses, a])
        points.append(corners[crosses, a] + t[:, None] * (corners[crosses, b] - corners[crosses, a]))
    points = np.concatenate(points)
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre)[2][2]
    if (towards - centre) @ normal < 0:
        normal = -normal
    return centre, normal


