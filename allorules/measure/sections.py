"""Cross-sections and skeletons of a mesh from the isocontours of a scalar field (METHOD §3).

A *loop* is a closed polyline where a piecewise-linear per-vertex field crosses a level
(marching triangles). Its length is a girth, ‖½ Σ p_k × p_{k+1}‖ its cross-sectional area and
its centroid a skeleton node. Sweeping the level gives a stack of loops; loops at neighbouring
levels that touch the same connected band of surface between the two levels are joined, which
makes the *skeleton* graph, whose diameter (longest shortest path) is a length.

Everything here is a plain function of vertex, face and field arrays; :mod:`allorules.measure`
applies them to the regions of a :class:`~allorules.body.Body`. The usual field is the Fiedler
vector h₁ of the harmonic basis (:func:`fiedler_vector`), which runs along elongated shapes.
"""
from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dataclass_field

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg

from allorules.mesh.geometry import nearest_rotations, vertex_areas
from allorules.mesh.topology import boundary_edge_loops, directed_edges, face_adjacency
from allorules.spectral.eigen import few_smallest_eigenpairs
from allorules.spectral.laplacian import cotangent_laplacian

# Meshes up to this many vertices use the reference (dense) eigensolver for h₁.

# ---------------------------------------------------------------------------------------------
# Loops


@dataclass
class Loop:
    """A polyline on the surface, closed unless ``closed`` is False.

    ``points[k]`` lies on an edge of the mesh; the segment from ``points[k]`` to
    ``points[k+1]`` (and, when closed, from the last back to the first) crosses ``faces[k]``.
    """

    points: np.ndarray            # (k, 3)
    faces: np.ndarray             # (k,) for a closed loop, (k-1,) for an open chain
    level: float = float("nan")   # the field value it is an isocontour of (nan: a mesh boundary)
    closed: bool = True
    vertex_ids: np.ndarray | None = None   # for a mesh boundary: the mesh vertex of each point
    # For an isocontour: the mesh edge (two vertex ids) each point lies on and where along it,
    # points[k] = v[edges[k, 0]] + weights[k] · (v[edges[k, 1]] − v[edges[k, 0]]).
    edges: np.ndarray | None = None
    weights: np.ndarray | None = None

    def moved(self, vertices: np.ndarray) -> "Loop":
        """The same material loop on the mesh with new ``vertices`` (same faces, same edges).

        An isocontour of a field carried unchanged to the moved mesh crosses the same edges at
        the same place along them, so its points are a linear interpolation, no re-extraction.
        """
        if self.vertex_ids is not None:
            points = vertices[self.vertex_ids]
        elif self.edges is not None:
            start = vertices[self.edges[:, 0]]
            points = start + self.weights[:, None] * (vertices[self.edges[:, 1]] - start)
        else:
            raise ValueError("this loop does not know the mesh edges it lies on")
        return Loop(points, self.faces, self.level, self.closed, self.vertex_ids, self.edges, self.weights)

    def _segments(self) -> tuple[np.ndarray, np.ndarray]:
        following = np.roll(self.points, -1, axis=0) if self.closed else self.points[1:]
        start = self.points if self.closed else self.points[:-1]
        return start, following

    @property
    def girth(self) -> float:
        """Length of the polyline (the closing segment included when closed)."""
        start, following = self._segments()
        return float(np.linalg.norm(following - start, axis=1).sum())

    @property
    def vector_area(self) -> np.ndarray:
        """½ Σ p_k × p_{k+1}: normal times enclosed area; independent of the origin when closed."""
        start, following = self._segments()
        origin = self.points.mean(axis=0)   # exact for a closed loop, steadier in floating point
        return 0.5 * np.cross(start - origin, following - origin).sum(axis=0)

    @property
    def area(self) -> float:
        """Cross-sectional area ‖½ Σ p_k × p_{k+1}‖ (METHOD §3)."""
        return float(np.linalg.norm(self.vector_area))

    @property
    def centroid(self) -> np.ndarray:
        """Length-weighted centroid of the polyline (does not depend on how densely it is sampled)."""
        start, following = self._segments()
        lengths = np.linalg.norm(following - start, axis=1)
        if lengths.sum() <= 0:
            return self.points.mean(axis=0)
        return ((start + following) * 0.5 * lengths[:, None]).sum(axis=0) / lengths.sum()

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the loop's plane of best fit (direction of the vector area)."""
        vector = self.vector_area
        norm = np.linalg.norm(vector)
        return vector / norm if norm > 0 else vector


@dataclass(frozen=True)
class JoinedLoops:
    """Many closed loops or open chains of one mesh end to end, each point on a mesh edge, so that
    their points, centroids and areas on new vertices take one pass over numpy arrays: what a run
    does on every trial (skeletons moved, limb-stress bands measured).

    Loop k's points are ``starts[k]`` … ``starts[k] + counts[k] − 1``; a point is
    v[edge_start] + weight (v[edge_end] − v[edge_start]) (a boundary's vertex: both ends that
    vertex, weight 0); ``following`` is each point's successor in its loop and ``segment`` whether
    the segment to it counts (not the closing one of an open chain).
    """

    edge_start: np.ndarray
    edge_end: np.ndarray
    weights: np.ndarray
    starts: np.ndarray
    counts: np.ndarray
    following: np.ndarray
    segment: np.ndarray

    @classmethod
    def of(cls, edges: list[tuple[np.ndarray, np.ndarray, np.ndarray]], closed: list[bool]) -> "JoinedLoops":
        """From each loop's (edge starts, edge ends, weights) and whether it is closed."""
        counts = np.asarray([len(weights) for _, _, weights in edges], dtype=np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64) if len(edges) else counts
        following = np.arange(int(counts.sum()), dtype=np.int64) + 1
        segment = np.ones(len(following), dtype=bool)
        ends = starts + counts - 1
        present = counts > 0
        following[ends[present]] = starts[present]
        segment[ends[present & ~np.asarray(closed, dtype=bool)]] = False
        join = (lambda k, kind: np.concatenate([piece[k] for piece in edges]).astype(kind)) if edges else \
            (lambda k, kind: np.zeros(0, dtype=kind))
        return cls(join(0, np.int64), join(1, np.int64), join(2, np.float64), starts, counts, following, segment)

    def points(self, vertices: np.ndarray) -> np.ndarray:
        """Every loop's points on the mesh with ``vertices``, end to end."""
        start = vertices[self.edge_start]
        return start + self.weights[:, None] * (vertices[self.edge_end] - start)

    def _sums(self, values: np.ndarray) -> np.ndarray:
        """Per loop, the sum of ``values`` (one row per point); 0 for a loop without points."""
        sums = np.zeros((len(self.counts),) + values.shape[1:])
        present = self.counts > 0
        if present.any():
            sums[present] = np.add.reduceat(values, self.starts[present], axis=0)
        return sums

    def centroids(self, points: np.ndarray) -> np.ndarray:
        """Each loop's :attr:`Loop.centroid`: its segments' midpoints weighted by their lengths (a
        loop without length: its points' mean)."""
        following = points[self.following]
        lengths = np.where(self.segment, np.linalg.norm(following - points, axis=1), 0.0)
        total = self._sums(lengths)
        centroids = self._sums((points + following) * 0.5 * lengths[:, None]) / np.where(total > 0, total, 1.0)[:, None]
        for index in np.flatnonzero(~(total > 0)):
            first = self.starts[index]
            centroids[index] = points[first:first + self.counts[index]].mean(axis=0)
        return centroids

    def rotations(self, start: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Each loop's best rotation (n, 3, 3) from its points ``start`` to its points ``points``
        (both end to end, as :meth:`points` gives them), about the points' means
        (:func:`allorules.mesh.geometry.nearest_rotations`): how each cross-section turned."""
        counts = np.maximum(self.counts, 1)[:, None]
        start = start - np.repeat(self._sums(start) / counts, self.counts, axis=0)
        points = points - np.repeat(self._sums(points) / counts, self.counts, axis=0)
        covariances = self._sums(np.einsum("ij,ik->ijk", points, start).reshape(-1, 9)).reshape(-1, 3, 3)
        return nearest_rotations(covariances)[0]

    def areas(self, points: np.ndarray) -> np.ndarray:
        """Each loop's :attr:`Loop.area`, ‖½ Σ (p_k − m) × (p_{k+1} − m)‖ about its points' mean m."""
        counts = np.maximum(self.counts, 1)
        centred = points - np.repeat(self._sums(points) / counts[:, None], self.counts, axis=0)
        crossed = np.where(self.segment[:, None], np.cross(centred, centred[self.following]), 0.0)
        return np.linalg.norm(0.5 * self._sums(crossed), axis=1)


def join_loops(loops: list[Loop]) -> JoinedLoops:
    """``loops`` (isocontours on mesh edges, or mesh boundaries on vertices) as :class:`JoinedLoops`."""
    edges = []
    for loop in loops:
        if loop.vertex_ids is not None:
            ids = np.asarray(loop.vertex_ids, dtype=np.int64)
            edges.append((ids, ids, np.zeros(len(ids))))
        elif loop.edges is not None:
            edges.append((loop.edges[:, 0], loop.edges[:, 1], np.asarray(loop.weights, dtype=np.float64)))
        else:
            raise ValueError("this loop does not know the mesh edges it lies on")
    return JoinedLoops.of(edges, [loop.closed for loop in loops])


def _chain(neighbours: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Order the nodes of a graph of maximum degree two into chains.

    ``neighbours[i]`` holds node i's (at most two) neighbours, -1 for none. Returns one
    ``(node order, closed)`` per connected component.
    """
    count = len(neighbours)
    visited = np.zeros(count, dtype=bool)
    degree = (neighbours >= 0).sum(axis=1)
    table = neighbours.tolist()
    chains = []
    # Open chains first, from an end (degree ≤ 1); then what is left is closed cycles.
    starts = list(np.flatnonzero(degree <= 1)) + list(range(count))
    for start in starts:
        if visited[start]:
            continue
        order = [start]
        visited[start] = True
        previous, current = -1, start
        closed = False
        while True:
            a, b = table[current]
            step = a if a != previous and a >= 0 else (b if b != previous and b >= 0 else -1)
            if step == a and a == b and a >= 0:   # two-node cycle walked both ways
                step = -1
            if step < 0:
                break
            if visited[step]:
                closed = step == start and len(order) > 2
                break
            order.append(step)
            visited[step] = True
            previous, current = current, step
        chains.append((np.asarray(order, dtype=np.int64), closed))
    return chains


def isocontour_loops(
    vertices: np.ndarray,
    faces: np.ndarray,
    field: np.ndarray,
    level: float,
    *,
    keep_open: bool = False,
) -> list[Loop]:
    """The polylines where the piecewise-linear ``field`` equals ``level`` (marching triangles).

    A vertex counts as above the level when ``field ≥ level`` (so a level through a vertex is
    handled consistently). Each face with vertices on both sides contributes one segment between
    the crossing points on its two crossed edges; segments sharing an edge are chained. Chains
    that end at the mesh boundary (or at a non-manifold edge) are open: they are dropped unless
    ``keep_open``. Returns loops longest first.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    field = np.asarray(field, dtype=np.float64)
    return _loops_at(vertices, faces, field, level, *_face_extents(field, faces), keep_open)


def isocontour_stack(vertices: np.ndarray, faces: np.ndarray, field: np.ndarray, levels, *,
                     keep_open: bool = False) -> list[list[Loop]]:
    """:func:`isocontour_loops` at each of ``levels`` (the same loops), the faces' extent in the
    field found once for all of them: what a stack of sections of one mesh costs."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    field = np.asarray(field, dtype=np.float64)
    lowest, highest = _face_extents(field, faces)
    return [_loops_at(vertices, faces, field, float(level), lowest, highest, keep_open) for level in levels]


def _face_extents(field: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each face's lowest and highest corner value (column by column: min(axis=1) over three
    columns is several times slower)."""
    a, b, c = field[faces[:, 0]], field[faces[:, 1]], field[faces[:, 2]]
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)


def _loops_at(vertices: np.ndarray, faces: np.ndarray, field: np.ndarray, level: float, lowest: np.ndarray,
              highest: np.ndarray, keep_open: bool) -> list[Loop]:
    """The loops of :func:`isocontour_loops`, given each face's lowest and highest corner value."""
    # a face is crossed where some corner is above the level (≥) and some below
    crossing = np.flatnonzero((highest >= level) & (lowest < level))
    if len(crossing) == 0:
        return []
    corners = faces[crossing]
    side = field[corners] >= level
    # Edge k of a face joins corner k and corner k+1; exactly two of the three are crossed.
    edge_a = corners
    edge_b = np.roll(corners, -1, axis=1)
    crossed = side != np.roll(side, -1, axis=1)          # (c, 3), two True per row
    rows, edge_slot = np.nonzero(crossed)
    a = edge_a[rows, edge_slot]
    b = edge_b[rows, edge_slot]
    low, high = np.minimum(a, b), np.maximum(a, b)
    keys = low * len(vertices) + high
    unique_keys, node_of = np.unique(keys, return_inverse=True)
    node_of = node_of.reshape(-1, 2)                     # the two crossing nodes of each face
    node_low = unique_keys // len(vertices)
    node_high = unique_keys % len(vertices)
    # Crossing point on edge (p, q): p + t (q − p), t = (level − f_p) / (f_q − f_p).
    f_low, f_high = field[node_low], field[node_high]
    t = np.clip((level - f_low) / (f_high - f_low), 0.0, 1.0)
    points = vertices[node_low] + t[:, None] * (vertices[node_high] - vertices[node_low])

    # Each node (a mesh edge) touches at most two crossing faces on a manifold mesh.
    node_count = len(unique_keys)
    incidence_node = node_of.ravel()
    uses = np.bincount(incidence_node, minlength=node_count)
    usable = uses[incidence_node] <= 2                   # a non-manifold edge breaks the chain
    segment_ok = usable.reshape(-1, 2).all(axis=1)
    # each node's (at most two) neighbours, in the order of the segments, and the face of each
    segments = node_of[segment_ok]
    ends = segments.ravel()                              # p₀ q₀ p₁ q₁ ...: each segment's two ends
    sort = np.argsort(ends, kind="stable")
    node = ends[sort]
    slot = np.arange(len(node)) - np.searchsorted(node, node)   # 0 for a node's first segment, 1 for its second
    neighbours = np.full((node_count, 2), -1, dtype=np.int64)
    neighbour_face = np.full((node_count, 2), -1, dtype=np.int64)
    neighbours[node, slot] = segments[:, ::-1].ravel()[sort]
    neighbour_face[node, slot] = np.repeat(crossing[segment_ok], 2)[sort]
    loops = []
    for order, closed in _chain(neighbours):
        if len(order) < 2 or (not closed and not keep_open):
            continue
        following = np.roll(order, -1) if closed else order[1:]
        start = order if closed else order[:-1]
        crossed_faces = np.where(neighbours[start, 0] == following, neighbour_face[start, 0], neighbour_face[start, 1])
        edges = np.column_stack([node_low[order], node_high[order]])
        loops.append(Loop(points[order], crossed_faces, float(level), closed, None, edges, t[order]))
    loops.sort(key=lambda loop: -loop.girth)
    return loops


def boundary_loops(vertices: np.ndarray, faces: np.ndarray) -> list[Loop]:
    """The open boundary of a mesh as closed loops, one per connected component of its boundary
    edges (the loops of :func:`~allorules.mesh.topology.boundary_edge_loops`); ``faces`` = the
    face of each edge.

    A loop is a closed walk over its component's edges in the faces' winding (an Euler circuit):
    where a boundary passes through a vertex twice (a pinch, as a jagged region border on a fine
    mesh or a painted label has: two faces of the region meeting at one vertex only), the walk
    passes through it twice and the opening stays one loop, whose girth and centroid are the
    whole opening's. (Kept to two neighbours per vertex, the chains of such a border broke into
    pieces: the 382's foreleg at 200k vertices measured 0.83 for 0.53, its junction in six.) A
    component the winding cannot walk (faces oriented inconsistently) is chained as before.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    edges, edge_loop, loop_count = boundary_edge_loops(faces)
    if loop_count == 0:
        return []
    # the face of each boundary edge: its row among the faces' directed edges (row k: face k mod F)
    directed = directed_edges(faces)
    size = int(directed.max()) + 1
    keys = directed[:, 0] * size + directed[:, 1]
    order = np.argsort(keys)
    rows = order[np.searchsorted(keys[order], edges[:, 0] * size + edges[:, 1])]
    face_of = dict(zip(map(tuple, edges.tolist()), (rows % len(faces)).tolist()))
    loops = []
    for loop in range(loop_count):
        own = edges[edge_loop == loop]
        walk = _euler_circuit(own)
        if walk is None:
            loops.extend(_chained_loops(vertices, own, face_of))
            continue
        following = np.roll(walk, -1)
        crossed = np.asarray([face_of[(p, q)] for p, q in zip(walk.tolist(), following.tolist())], dtype=np.int64)
        loops.append(Loop(vertices[walk], crossed, float("nan"), True, walk))
    return [loop for loop in loops if len(loop.points) >= 3]


def _euler_circuit(edges: np.ndarray) -> np.ndarray | None:
    """The vertices of a closed walk through every directed edge once (Hierholzer), or None when
    there is none (a vertex with more edges in than out)."""
    outgoing: dict[int, list[int]] = {}
    balance: dict[int, int] = {}
    for p, q in edges.tolist():
        outgoing.setdefault(p, []).append(q)
        balance[p] = balance.get(p, 0) + 1
        balance[q] = balance.get(q, 0) - 1
    if any(balance.values()):
        return None
    stack, walk = [int(edges[0, 0])], []
    while stack:
        vertex = stack[-1]
        if outgoing.get(vertex):
            stack.append(outgoing[vertex].pop())
        else:
            walk.append(stack.pop())
    walk = walk[::-1][:-1]                     # the circuit, without repeating its start at the end
    return np.asarray(walk, dtype=np.int64) if len(walk) == len(edges) else None


def _chained_loops(vertices: np.ndarray, edges: np.ndarray, face_of: dict) -> list[Loop]:
    """Loops of boundary edges chained through vertices of at most two of them (the fallback for a
    boundary the faces' winding cannot walk)."""
    nodes, local = np.unique(edges, return_inverse=True)
    local = local.reshape(-1, 2)
    neighbours = np.full((len(nodes), 2), -1, dtype=np.int64)
    fill = np.zeros(len(nodes), dtype=np.int64)
    for p, q in local.tolist():
        for x, y in ((p, q), (q, p)):
            if fill[x] < 2:
                neighbours[x, fill[x]] = y
                fill[x] += 1
    loops = []
    for order, closed in _chain(neighbours):
        if len(order) < 3:
            continue
        ids = nodes[order]
        following = np.roll(ids, -1) if closed else ids[1:]
        crossed = [face_of.get((p, q), face_of.get((q, p), -1)) for p, q in zip(ids.tolist(), following.tolist())]
        loops.append(Loop(vertices[ids], np.asarray(crossed, dtype=np.int64), float("nan"), closed, ids))
    return loops


# ---------------------------------------------------------------------------------------------
# Fields and mesh parts


def fiedler_vector(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """h₁, the first non-constant eigenvector of L h = λ D h (METHOD §2), on a connected mesh.

    Its sign is fixed by the eigensolver (largest-magnitude entry positive); callers that need a
    direction (junction → tip) orient it themselves.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    _, vectors = few_smallest_eigenpairs(cotangent_laplacian(vertices, faces), vertex_areas(vertices, faces), 2)
    return vectors[:, 1]


def harmonic_field(vertices: np.ndarray, faces: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The harmonic function (L u = 0) that is 0 on the vertices ``low`` and 1 on ``high``.

    With the two openings of a tube as ``low`` and ``high``, its isocontours are cross-sections
    of the tube whatever its proportions (a Fiedler vector runs around a tube shorter than about
    π × its radius). Other boundaries keep the natural (Neumann) condition.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    stiffness = cotangent_laplacian(vertices, np.asarray(faces, dtype=np.int64)).tocsr()
    values = np.full(len(vertices), np.nan)
    values[np.asarray(low)] = 0.0
    values[np.asarray(high)] = 1.0
    fixed = ~np.isnan(values)
    free = np.flatnonzero(~fixed)
    if len(free):
        # L_ff u_f = −L_fc u_c
        right = -stiffness[free][:, np.flatnonzero(fixed)] @ values[fixed]
        values[free] = scipy.sparse.linalg.spsolve(stiffness[free][:, free].tocsc(), right)
    # Maximum principle: a harmonic function lies between its boundary values. Round-off (which
    # depends on where the mesh sits in space) can put a free vertex a few ulps outside [0, 1];
    # clipping keeps the openings the field's exact extremes (see area_quantile_levels).
    return np.clip(values, 0.0, 1.0)


def area_quantiles(vertices: np.ndarray, faces: np.ndarray, field: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """The field's values below which the given shares ``targets`` (0…1) of the area lie (vertex-area weights)."""
    mass = vertex_areas(vertices, faces)
    order = np.argsort(field)
    cumulative = np.cumsum(mass[order])
    cumulative /= cumulative[-1]
    return np.interp(np.asarray(targets, dtype=np.float64), cumulative, field[order])


def area_quantile_levels(vertices: np.ndarray, faces: np.ndarray, field: np.ndarray, count: int) -> np.ndarray:
    """``count`` levels at the (k + ½)/count quantiles of the field, weighted by vertex area.

    On a tube of constant radius, area is proportional to length, so the levels are about evenly
    spaced along it whatever the shape of the field's profile (a Fiedler vector is flat near the
    ends of a tube; evenly spaced *values* would crowd the middle).
    """
    targets = (np.arange(count) + 0.5) / count
    levels = np.unique(area_quantiles(vertices, faces, field, targets))
    # A level at the field's minimum or maximum is not a cross-section: at the minimum nothing
    # is below it, at the maximum its "contour" is the set where the maximum is attained. For a
    # harmonic field that set is a whole opening (a plateau of vertices at exactly 0 or 1, which
    # the quantiles land on when the opening holds more than 1/(2·count) of the area), and which
    # spurious loops round-off then draws around it depended on the mesh's place in space.
    return levels[(levels > field.min()) & (levels < field.max())]


# ---------------------------------------------------------------------------------------------
# Skeleton


@dataclass
class Skeleton:
    """Skeleton graph: nodes are points, edges weighted by the distance between them.

    ``kinds[i]`` is ``"section"`` (centroid of ``loops[i]``, an isocontour), ``"boundary"``
    (centroid of ``loops[i]``, an open boundary of the mesh) or ``"tip"`` (the end of a limb,
    where isocontours shrink to a point: :func:`end_point` beyond the last loop, ``tip_anchors[i]``,
    as far as the surface beyond it, ``tip_regions[i]``, reaches along the part (from the loop at
    a quarter of the levels back, ``tip_bases[i]``); without such a loop, the vertex
    ``tip_vertices[i]`` where the field is extreme).
    """

    points: np.ndarray                   # (N, 3)
    graph: sparse.csr_matrix             # (N, N) symmetric, weights = distances
    kinds: list[str]
    loops: list[Loop | None]
    levels: np.ndarray = dataclass_field(default_factory=lambda: np.zeros(0))
    tip_vertices: np.ndarray = dataclass_field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # mesh vertex per node, −1 if not a tip
    tip_anchors: np.ndarray = dataclass_field(default_factory=lambda: np.zeros(0, dtype=np.int64))   # per node: the loop node a tip lies beyond, −1 if none
    tip_regions: list[np.ndarray | None] = dataclass_field(default_factory=list)                    # per node: a tip's end-band vertices
    tip_bases: np.ndarray = dataclass_field(default_factory=lambda: np.zeros(0, dtype=np.int64))     # per node: the loop a tip's direction is taken from, −1 if none
    moving: JoinedLoops | None = dataclass_field(default=None, repr=False, compare=False)              # the loops joined for :meth:`moved`, made on the first move

    @property
    def diameter(self) -> float:
        return skeleton_diameter(self.graph)

    def moved(self, vertices: np.ndarray) -> "Skeleton":
        """The same skeleton (same loops, tips and joins) on the mesh with new ``vertices``.

        For a field carried unchanged to a moved mesh: every loop crosses the same edges
        (:meth:`Loop.moved`), tips are the same vertices, and the graph keeps its edges with
        weights re-measured, so the diameter is a continuous function of the vertices.
        """
        vertices = np.asarray(vertices, dtype=np.float64)
        if self.moving is None:
            self.moving = join_loops([loop for loop in self.loops if loop is not None])
        joined = self.moving
        moved_points = joined.points(vertices)
        centroids = iter(joined.centroids(moved_points))
        firsts = iter(zip(joined.starts.tolist(), joined.counts.tolist()))
        loops = []
        for loop in self.loops:      # (the loop on the new vertices, its centroid), None for a tip
            if loop is None:
                loops.append(None)
                continue
            first, count = next(firsts)
            loops.append((Loop(moved_points[first:first + count], loop.faces, loop.level, loop.closed, loop.vertex_ids,
                               loop.edges, loop.weights), next(centroids)))
        points = []
        for node, section in enumerate(loops):
            if section is not None:
                points.append(section[1])
            elif self.tip_anchors[node] >= 0:
                base = self.tip_bases[node]
                points.append(end_point(vertices, loops[self.tip_anchors[node]][0], self.tip_regions[node],
                                        None if base < 0 else loops[base][0]))
            else:
                points.append(vertices[self.tip_vertices[node]])
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        # the same graph, its edges' weights re-measured: the CSR pattern is the input's
        pattern = self.graph.tocsr()
        rows = np.repeat(np.arange(pattern.shape[0]), np.diff(pattern.indptr))
        weights = np.maximum(np.linalg.norm(points[rows] - points[pattern.indices], axis=1), 1e-300)
        graph = sparse.csr_matrix((weights, pattern.indices, pattern.indptr), shape=pattern.shape)
        return Skeleton(points, graph, self.kinds, [None if section is None else section[0] for section in loops],
                        self.levels, self.tip_vertices, self.tip_anchors, self.tip_regions, self.tip_bases, self.moving)


def end_point(vertices: np.ndarray, anchor: Loop, end_vertices: np.ndarray, base: Loop | None = None) -> np.ndarray:
    """Where a part ends beyond its last cross-section ``anchor``: as far out as the surface beyond
    it (``end_vertices``) reaches along the part.

    p = c + n · max_v (v − c)·n, with c the loop's centroid and n the end's direction: from the
    centroid of ``base`` (a loop some way back from the end) to c, or without one the loop's unit
    normal; either way pointing to the end (to the side where the end vertices lie on the whole).
    A maximum of continuous functions of the vertices, so it does not jump when a neighbouring
    vertex becomes the extreme one (the field's extreme vertex, on a blunt toe or a flat sole,
    does); and it measures how far the end reaches along the part, not across it (the extreme
    vertex may sit on the rim of a wide sole). A chord over several loops rather than the last
    loop's normal: the tilt of one loop across an angled hoof moved the end by a few per cent of
    its width.
    """
    centre, normal = anchor.centroid, anchor.normal
    if base is not None:
        direction = centre - base.centroid
        if np.linalg.norm(direction) > 0:
            normal = direction / np.linalg.norm(direction)
    offsets = (np.asarray(vertices)[np.asarray(end_vertices)] - centre) @ normal
    if offsets.sum() < 0:
        normal, offsets = -normal, -offsets
    return centre + max(float(offsets.max(initial=0.0)), 0.0) * normal


def skeleton_longest_path(graph: sparse.spmatrix) -> tuple[float, list[int]]:
    """The longest of all shortest paths in a weighted undirected graph: (length, node path)."""
    if graph.shape[0] == 0:
        return 0.0, []
    distances, predecessors = csgraph.shortest_path(graph, directed=False, return_predecessors=True)
    distances[~np.isfinite(distances)] = -1.0
    start, end = np.unravel_index(int(np.argmax(distances)), distances.shape)
    length = float(max(distances[start, end], 0.0))
    path = [int(end)]
    while path[-1] != start and predecessors[start, path[-1]] >= 0:
        path.append(int(predecessors[start, path[-1]]))
    return length, path[::-1]


def skeleton_diameter(graph: sparse.spmatrix) -> float:
    """Diameter of a skeleton graph: its longest shortest path (METHOD §3)."""
    return skeleton_longest_path(graph)[0]


def skeleton(
    vertices: np.ndarray,
    faces: np.ndarray,
    field: np.ndarray,
    levels: np.ndarray | None = None,
    *,
    count: int = 40,
    by_level: bool = False,
) -> Skeleton:
    """Skeleton of a mesh from the isocontours of ``field`` at ``levels``.

    Levels default to ``count`` area quantiles of the field (:func:`area_quantile_levels`). The
    surface between two consecutive levels (and below the first, above the last) is a set of
    *bands*: connected components of the faces whose field range meets that interval. Nodes:
    every closed isocontour loop (its centroid); every open boundary loop of the mesh (its
    centroid); in each band below the first or above the last level that holds no boundary, the
    end point beyond the outermost loop (a tip, :func:`end_point`). Nodes that touch the same band
    part are joined: every two of them, or with ``by_level`` in the order of their field value (a
    loop's level, a boundary's mean value, a tip beyond every loop), each level's nodes to the
    next level's, so that the skeleton runs through every loop rather than skipping some where a
    face happens to span two levels. By level is steadier where the loops are well sampled (a
    limb); on a coarse part the path through every loop zigzags and every-two is steadier.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    field = np.asarray(field, dtype=np.float64)
    if levels is None:
        levels = area_quantile_levels(vertices, faces, field, count)
    levels = np.sort(np.asarray(levels, dtype=np.float64))
    adjacency = face_adjacency(faces)
    face_low, face_high = _face_extents(field, faces)

    points: list[np.ndarray] = []
    kinds: list[str] = []
    node_loops: list[Loop | None] = []
    tip_vertices: list[int] = []
    tip_anchors: list[int] = []
    tip_regions: list[np.ndarray | None] = []
    tip_bases: list[int] = []
    node_faces: list[np.ndarray] = []    # faces each node touches, to find its bands
    for level, found in zip(levels, isocontour_stack(vertices, faces, field, levels)):
        for loop in found:
            points.append(loop.centroid)
            kinds.append("section")
            node_loops.append(loop)
            node_faces.append(loop.faces)
            tip_vertices.append(-1)
            tip_anchors.append(-1)
            tip_regions.append(None)
            tip_bases.append(-1)
    for loop in boundary_loops(vertices, faces):
        points.append(loop.centroid)
        kinds.append("boundary")
        node_loops.append(loop)
        node_faces.append(loop.faces[loop.faces >= 0])
        tip_vertices.append(-1)
        tip_anchors.append(-1)
        tip_regions.append(None)
        tip_bases.append(-1)

    # Field value of each node so far: a loop's level; an open boundary's mean value. A tip lies
    # beyond every loop of its end band (tip_value).
    node_values = [loop.level if kind == "section" else float(field[loop.vertex_ids].mean())
                   for loop, kind in zip(node_loops, kinds)]

    def tip_value(band: int) -> float:
        return -np.inf if band == 0 else np.inf

    edges: set[tuple[int, int]] = set()
    bounds = np.concatenate([[-np.inf], levels, [np.inf]])
    face_nodes: dict[int, list[int]] = {}
    for node, touched in enumerate(node_faces):
        for face in touched.tolist():
            face_nodes.setdefault(face, []).append(node)
    for band in range(len(bounds) - 1):
        lower, upper = bounds[band], bounds[band + 1]
        # Faces whose field range [low, high] meets [lower, upper] (upper excluded: field ≥ level is above).
        in_band = np.flatnonzero((face_high >= lower) & (face_low < upper))
        if len(in_band) == 0:
            continue
        sub = adjacency[in_band][:, in_band]
        component_count, component = csgraph.connected_components(sub, directed=False)
        members: dict[int, set[int]] = {}
        for local, face in enumerate(in_band.tolist()):
            for node in face_nodes.get(face, ()):
                members.setdefault(int(component[local]), set()).add(node)
        end_band = band == 0 or band == len(bounds) - 2
        if end_band:
            # A tip in each end band part that is not closed off by a boundary: the end point
            # beyond the part's outermost loop (the longest, if the end level has several), or,
            # without one, the vertex where the field is extreme.
            end_level = levels[0] if band == 0 else levels[-1]
            for part in range(component_count):
                part_nodes = members.get(part, set())
                if any(kinds[node] == "boundary" for node in part_nodes):
                    continue
                part_vertices = np.unique(faces[in_band[component == part]])
                values = field[part_vertices]
                tip = part_vertices[np.argmin(values) if band == 0 else np.argmax(values)]
                outermost = [node for node in part_nodes if node_loops[node] is not None and kinds[node] == "section"
                             and node_loops[node].level == end_level]
                if outermost:
                    anchor = max(outermost, key=lambda node: node_loops[node].girth)
                    beyond = part_vertices[values <= end_level] if band == 0 else part_vertices[values >= end_level]
                    # the loop a quarter of the levels back from this end (the nearest closed one
                    # towards it; the longest where a level has several): the end's direction
                    back = max(1, len(levels) // 4)
                    base_level = levels[back] if band == 0 else levels[-1 - back]
                    sections = [node for node, kind in enumerate(kinds) if kind == "section"
                                and (base_level <= node_loops[node].level <= end_level if band else
                                     end_level <= node_loops[node].level <= base_level)]
                    nearest = (max if band == 0 else min)(node_loops[node].level for node in sections)
                    base = max((node for node in sections if node_loops[node].level == nearest),
                               key=lambda node: node_loops[node].girth)
                    base = -1 if base == anchor else base
                    points.append(end_point(vertices, node_loops[anchor], beyond, None if base < 0 else node_loops[base]))
                    tip_anchors.append(anchor)
                    tip_regions.append(beyond)
                    tip_bases.append(base)
                else:
                    points.append(vertices[tip])
                    tip_anchors.append(-1)
                    tip_regions.append(None)
                    tip_bases.append(-1)
                kinds.append("tip")
                node_loops.append(None)
                tip_vertices.append(int(tip))
                members.setdefault(part, set()).add(len(points) - 1)
        for part_nodes in members.values():
            # by_level: join the nodes of a band part in the order of their field value, each
            # group (one level) to the next, so that a loop touching the band only through a
            # face spanning two levels is not a shortcut past the loops between them (such faces
            # come and go as the levels slide over the vertices' values, and the shortcuts with
            # them). Otherwise every two nodes of a band part are joined.
            if not by_level:
                ordered = sorted(part_nodes)
                for i, p in enumerate(ordered):
                    for q in ordered[i + 1:]:
                        edges.add((p, q))
                continue
            groups: dict[float, list[int]] = {}
            for node in part_nodes:
                groups.setdefault(node_values[node] if node < len(node_values) else tip_value(band), []).append(node)
            ordered_groups = [groups[value] for value in sorted(groups)]
            for lower_group, upper_group in zip(ordered_groups, ordered_groups[1:]):
                for p in lower_group:
                    for q in upper_group:
                        edges.add((min(p, q), max(p, q)))

    point_array = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if edges:
        pairs = np.asarray(sorted(edges), dtype=np.int64)
        weights = np.linalg.norm(point_array[pairs[:, 0]] - point_array[pairs[:, 1]], axis=1)
        # A zero-length edge would vanish from a sparse matrix; keep it as a tiny positive weight.
        weights = np.maximum(weights, 1e-300)
        graph = sparse.coo_matrix((weights, (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
        graph = (graph + graph.T).tocsr()
    else:
        graph = sparse.csr_matrix((len(points), len(points)))
    return Skeleton(point_array, graph, kinds, node_loops, levels, np.asarray(tip_vertices, dtype=np.int64),
                    np.asarray(tip_anchors, dtype=np.int64), tip_regions, np.asarray(tip_bases, dtype=np.int64))
