"""Mesh preparation: from whatever file the user has to a body the method can work on (METHOD §1).

:func:`load_mesh` reads any format trimesh reads. :func:`prepare_mesh` repairs it in one reusable
step and says what it changed: merge duplicate (seam) vertices, weld open seams (boundary
vertices that nearly touch), drop unreferenced vertices, degenerate, duplicate and non-manifold
faces, orient faces consistently and outward, keep the largest connected part as the body and
carry the small detached parts (eyes, teeth) along by the displacement of their nearest body
vertex. An animal modelled in pieces (its largest part under JOIN_BELOW of the surface) gets as
its body the surface its pieces enclose together (:mod:`allorules.mesh.join`), every piece's
vertices bound to it.
:func:`cap_holes` closes boundary loops for volume measurement only; output meshes keep their holes.

The :class:`PreparedMesh` remembers how every vertex of the input maps to the body, so that a
scaled body can be written back in the input's own topology (with its UVs and materials).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.csgraph as csgraph
from scipy.spatial import cKDTree

from allorules.errors import MeshError
from allorules.mesh.geometry import enclosed_volume, face_areas, face_normals
from allorules.mesh.join import JOIN_BELOW, buried_faces, join_parts
from allorules.mesh.load import load_mesh
from allorules.mesh.topology import (
    boundary_edges,
    cap_holes,
    corner_edges,
    count_boundary_loops,
    directed_edges,
    face_components,
    unique_edges,
)
from allorules.mesh.transfer import Binding, bind, carry_deformation, carry_labels

log = logging.getLogger(__name__)

MINIMUM_BODY_VERTICES = 100
# Vertices closer than this fraction of the bounding-box diagonal are the same point (seams).
MERGE_TOLERANCE = 1e-7


@dataclass
class DetachedPart:
    """A small part carried along with the body: ``source_vertices`` move with ``anchors``."""

    source_vertices: np.ndarray   # indices into the input's vertices
    anchors: np.ndarray           # for each, the nearest body vertex


@dataclass(frozen=True)
class JoinedPieces:
    """An animal modelled in pieces, its body the surface they enclose together
    (:mod:`allorules.mesh.join`): ``source_vertices`` are bound to that surface by ``binding`` and
    move, turn and scale with it (:func:`allorules.mesh.transfer.carry_deformation`)."""

    source_vertices: np.ndarray   # indices into the input's vertices (every vertex a face uses)
    binding: Binding              # each one's place on the body and offset from it
    buried: np.ndarray            # per input face: deep inside the body, unseen (a leg's top in the trunk)


@dataclass
class PreparedMesh:
    """The repaired body and how it relates to the input.

    ``source_vertex_index[k]`` is the body vertex that input vertex ``k`` became, or -1 when the
    input vertex is not part of the body (a detached part's vertex, or an unreferenced one).
    """

    vertices: np.ndarray
    faces: np.ndarray
    repairs: list[str]
    source: "object | None" = None          # the trimesh.Trimesh as loaded, for export
    source_path: Path | None = None
    source_vertex_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    detached: list[DetachedPart] = field(default_factory=list)
    boundary_loops: int = 0
    pieces: JoinedPieces | None = None      # the body joined from pieces, not the input's own vertices

    def source_positions(self, body_vertices: np.ndarray) -> np.ndarray:
        """Positions for every input vertex after the body moved to ``body_vertices``.

        Body vertices take their new place; detached parts move rigidly with the displacement of
        their nearest body vertex; on a body joined from pieces every piece's vertex moves with the
        surface under it; unreferenced input vertices stay where they were.
        """
        if self.source is None:
            return np.asarray(body_vertices, dtype=float).copy()
        original = np.asarray(self.source.vertices, dtype=float)
        positions = original.copy()
        in_body = self.source_vertex_index >= 0
        positions[in_body] = body_vertices[self.source_vertex_index[in_body]]
        displacement = np.asarray(body_vertices, dtype=float) - self.vertices
        for part in self.detached:
            positions[part.source_vertices] = original[part.source_vertices] + displacement[part.anchors]
        if self.pieces is not None:
            bound = self.pieces.source_vertices
            positions[bound] = carry_deformation(self.pieces.binding, self.vertices, body_vertices, original[bound])
        return positions

    @property
    def source_vertex_count(self) -> int:
        """How many vertices the input had (the body's own count when it came as a body)."""
        return len(self.source.vertices) if self.source is not None else len(self.vertices)

    def source_labels(self, body_labels: np.ndarray, unlabelled: int = -1) -> np.ndarray:
        """A label for every input vertex from the body's: a detached part's vertex takes its
        anchor's (an eye shell, the head's), an unreferenced one ``unlabelled``."""
        body_labels = np.asarray(body_labels)
        if self.source is None:
            return body_labels.copy()
        labels = np.full(self.source_vertex_count, unlabelled, dtype=body_labels.dtype)
        in_body = self.source_vertex_index >= 0
        labels[in_body] = body_labels[self.source_vertex_index[in_body]]
        for part in self.detached:
            labels[part.source_vertices] = body_labels[part.anchors]
        if self.pieces is not None:
            labels[self.pieces.source_vertices] = carry_labels(self.pieces.binding, body_labels)
        return labels

    def body_labels(self, source_labels: np.ndarray, unlabelled: int = -1) -> np.ndarray:
        """A label for every body vertex from the input's (``source_labels``, one per input vertex):
        where repair merged input vertices into one, the last of them; on a body joined from pieces,
        the nearest piece vertex's; a body vertex no input vertex became (none today) ``unlabelled``."""
        source_labels = np.asarray(source_labels)
        if self.source is None:
            return source_labels.copy()
        if self.pieces is not None:
            bound = self.pieces.source_vertices
            _, nearest = cKDTree(np.asarray(self.source.vertices, dtype=np.float64)[bound]).query(self.vertices)
            return source_labels[bound[nearest]]
        labels = np.full(len(self.vertices), unlabelled, dtype=source_labels.dtype)
        in_body = self.source_vertex_index >= 0
        labels[self.source_vertex_index[in_body]] = source_labels[in_body]
        return labels


def prepare_mesh(mesh) -> PreparedMesh:
    """Repair a mesh (a path or a ``trimesh.Trimesh``) into a body; see the module docstring.

    Raises :class:`MeshError` for an empty mesh, one without faces, non-finite coordinates or a
    body too small to work with.
    """
    source_path = None
    if isinstance(mesh, (str, Path)):
        source_path = Path(mesh)
        mesh = load_mesh(source_path)
    name = str(source_path) if source_path else "mesh"
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3) if len(mesh.faces) else np.zeros((0, 3), np.int64)
    if len(vertices) == 0:
        raise MeshError(f"{name}: the mesh is empty (no vertices)")
    if len(faces) == 0:
        raise MeshError(f"{name}: the mesh has no faces (a point cloud?); export it as a triangle mesh")
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        raise MeshError(
            f"{name}: {int(bad.sum())} vertices have NaN or infinite coordinates; "
            "remove or fix them in your modelling tool"
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{name}: faces refer to vertices that do not exist")

    repairs: list[str] = []
    source_count = len(vertices)

    # 1. Merge duplicate vertices (UV and normal seams split one surface into many parts).
    merged_index, vertices = _merge_close_vertices(vertices)
    faces = merged_index[faces]
    if len(vertices) < source_count:
        repairs.append(f"merged {source_count - len(vertices)} duplicate vertices (seams)")

    # 1b. Close open seams: boundary vertices that nearly touch (a mirrored half not welded to
    # its other half) are one point; over the slit, the body's left and right would be far apart.
    seam_index, vertices = _weld_open_seams(vertices, faces)
    if len(seam_index) > len(vertices):
        repairs.append(f"welded {len(seam_index) - len(vertices)} vertices along open seams (edges of holes that touch)")
    merged_index, faces = seam_index[merged_index], seam_index[faces]

    # 2. Drop degenerate, duplicate and non-manifold faces.
    faces, dropped = _drop_degenerate_faces(vertices, faces)
    if dropped:
        repairs.append(f"dropped {dropped} degenerate faces")
    faces, dropped = _drop_duplicate_faces(faces)
    if dropped:
        repairs.append(f"dropped {dropped} duplicate faces")
    faces, dropped = _drop_non_manifold_faces(faces)
    if dropped:
        repairs.append(f"dropped {dropped} faces on non-manifold edges")
    if len(faces) == 0:
        raise MeshError(f"{name}: no usable faces remain after removing degenerate ones")

    unreferenced = len(vertices) - len(np.unique(faces))

    # 3. Keep the largest connected part (by area) as the body; where it holds too little of the
    # surface the animal is modelled in pieces (legs pushed into a trunk): join them into one.
    component = face_components(faces)
    areas = face_areas(vertices, faces)
    part_area = np.bincount(component, weights=areas)
    body_part = int(np.argmax(part_area))
    share = part_area[body_part] / part_area.sum()
    joined = len(part_area) > 1 and share < JOIN_BELOW
    if joined:
        try:
            joined_surface = join_parts(vertices, faces)
        except MeshError as error:
            raise MeshError(f"{name}: {error}") from None
        vertices, faces = joined_surface.vertices, joined_surface.faces
        repairs.append(
            f"joined its {len(part_area)} pieces into one surface of {len(vertices)} vertices (the largest "
            f"held only {share:.0%} of the surface); every piece's vertices move with it"
        )
        component = face_components(faces)
        part_area = np.bincount(component, weights=face_areas(vertices, faces))
        body_part = int(np.argmax(part_area))
    elif len(part_area) > 1:
        repairs.append(
            f"kept the largest of {len(part_area)} parts as the body ({share:.0%} of the surface); "
            f"{len(part_area) - 1} small parts are carried along"
        )
    body_faces = faces[component == body_part]

    # 4. Drop unreferenced vertices (renumber the body's vertices).
    used = np.unique(body_faces)
    renumber = -np.ones(len(vertices), dtype=np.int64)
    renumber[used] = np.arange(len(used))
    if unreferenced:
        repairs.append(f"dropped {unreferenced} unreferenced vertices")
    body_vertices = vertices[used]
    body_faces = renumber[body_faces]
    if len(body_vertices) < MINIMUM_BODY_VERTICES:
        raise MeshError(
            f"{name}: the body has only {len(body_vertices)} vertices; allorules needs at least "
            f"{MINIMUM_BODY_VERTICES}: subdivide the mesh (e.g. Blender's Subdivision Surface) and try again"
        )

    # 5. Orient faces consistently, then outward (positive enclosed volume after capping).
    body_faces, flipped = _orient_consistently(body_faces)
    if flipped:
        repairs.append(f"flipped {flipped} faces to make the winding consistent")
    capped_vertices, capped_faces = cap_holes(body_vertices, body_faces)
    if enclosed_volume(capped_vertices, capped_faces) < 0:
        body_faces = body_faces[:, ::-1].copy()
        repairs.append("reversed all faces so that normals point outward")
    loops = count_boundary_loops(body_faces)
    if loops:
        repairs.append(f"found {loops} holes; they are capped for volume measurement only, never in the output")

    # Map input vertices to body vertices; every other vertex a face of the input uses (a detached
    # part's, or one left only on a face dropped above) follows its nearest body vertex, or, on a
    # body joined from pieces, the surface under it. (A large body keeps its own vertices: runs work
    # on a working mesh made from it, allorules.mesh.working.)
    source = mesh
    detached: list[DetachedPart] = []
    pieces = None
    if joined:
        source_vertex_index = np.full(source_count, -1, dtype=np.int64)
        pieces = _bound_pieces(mesh, body_vertices, body_faces, joined_surface.cell)
    else:
        source_vertex_index = renumber[merged_index]
        other = np.unique(merged_index[np.asarray(mesh.faces, dtype=np.int64)])
        other = other[renumber[other] < 0]
        if len(other):
            detached_source = np.flatnonzero(np.isin(merged_index, other))
            _, anchors = cKDTree(body_vertices).query(np.asarray(mesh.vertices)[detached_source])
            detached.append(DetachedPart(detached_source, np.asarray(anchors, dtype=np.int64)))
    for line in repairs:
        log.debug("prepare: %s", line)
    return PreparedMesh(
        vertices=body_vertices,
        faces=body_faces,
        repairs=repairs,
        source=source,
        source_path=source_path,
        source_vertex_index=source_vertex_index,
        detached=detached,
        boundary_loops=loops,
        pieces=pieces,
    )


def _bound_pieces(mesh, body_vertices: np.ndarray, body_faces: np.ndarray, cell: float) -> JoinedPieces:
    """Every vertex a face of the input uses, bound to the body joined from its pieces, and which
    of its faces lie buried in the body (each vertex's depth along the surface's outward normal)."""
    source_faces = np.asarray(mesh.faces, dtype=np.int64)
    on_pieces = np.unique(source_faces)
    binding = bind(np.asarray(mesh.vertices, dtype=np.float64)[on_pieces], body_vertices, body_faces)
    outward = face_normals(body_vertices, body_faces)[binding.triangle]
    outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-300)
    depth = np.zeros(len(mesh.vertices))
    depth[on_pieces] = -np.einsum("ij,ij->i", binding.offset, outward)
    return JoinedPieces(on_pieces, binding, buried_faces(source_faces, depth, cell))


# --- geometry helpers (plain numpy) ---------------------------------------------------------


def _merge_close_vertices(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Union vertices closer than MERGE_TOLERANCE × bounding-box diagonal; returns (index, unique)."""
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    pairs = cKDTree(vertices).query_pairs(max(diagonal, np.finfo(float).tiny) * MERGE_TOLERANCE, output_type="ndarray")
    return _union(vertices, pairs)


def _union(vertices: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices joined in groups by ``pairs`` (index pairs); returns (index, unique), each group
    kept as its first vertex."""
    n = len(vertices)
    if len(pairs) == 0:
        return np.arange(n), vertices
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, group = csgraph.connected_components(graph, directed=False)
    # Keep the first vertex of each group, in input order, so numbering stays stable.
    first = np.full(group.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, group, np.arange(n))
    order = np.argsort(first)
    new_id = np.empty_like(order)
    new_id[order] = np.arange(len(order))
    return new_id[group], vertices[first[order]]


SEAM_TOLERANCE = 0.05   # of the median boundary edge: boundary vertices this near are one point


def _weld_open_seams(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Union boundary vertices closer than SEAM_TOLERANCE × the median boundary edge to another
    boundary vertex they share no edge with; returns (index, unique) as
    :func:`_merge_close_vertices`. A mirrored half exported without its seam welded (the
    vertices along the cut 0.2 % of an edge apart) is one surface again."""
    n = len(vertices)
    boundary = boundary_edges(faces)
    if len(boundary) == 0:
        return np.arange(n), vertices
    tolerance = SEAM_TOLERANCE * float(np.median(np.linalg.norm(vertices[boundary[:, 0]] - vertices[boundary[:, 1]], axis=1)))
    rim = np.unique(boundary)
    pairs = rim[cKDTree(vertices[rim]).query_pairs(tolerance, output_type="ndarray")]
    if len(pairs) == 0:
        return np.arange(n), vertices
    pairs = np.sort(pairs, axis=1)
    pairs = pairs[~_rows_in(pairs, unique_edges(faces))]
    return _union(vertices, pairs)


def _rows_in(rows: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Which of ``rows`` (sorted pairs) are rows of ``table`` (sorted pairs)."""
    key = lambda a: a[:, 0] * (int(max(rows.max(initial=0), table.max(initial=0))) + 1) + a[:, 1]   # noqa: E731
    return np.isin(key(rows), key(table))


def _drop_degenerate_faces(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    areas = face_areas(vertices, faces)
    scale = float(np.median(areas[~repeated])) if (~repeated).any() else 0.0
    flat = areas <= 1e-12 * scale
    keep = ~(repeated | flat)
    return faces[keep], int((~keep).sum())


def _drop_duplicate_faces(faces: np.ndarray) -> tuple[np.ndarray, int]:
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    first.sort()
    return faces[first], len(faces) - len(first)


def _drop_non_manifold_faces(faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Remove faces beyond the first two on any edge shared by more than two faces."""
    dropped_total = 0
    while True:
        edges = corner_edges(faces)
        _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.ravel()
        if counts.max(initial=0) <= 2:
            return faces, dropped_total
        face_of = np.tile(np.arange(len(faces)), 3)
        order = np.lexsort((face_of, inverse))
        rank = np.empty(len(order), dtype=np.int64)
        sorted_edges = inverse[order]
        starts = np.r_[0, np.flatnonzero(np.diff(sorted_edges)) + 1]
        run_start = np.repeat(starts, np.diff(np.r_[starts, len(order)]))
        rank[order] = np.arange(len(order)) - run_start
        drop = np.unique(face_of[rank >= 2])
        keep = np.ones(len(faces), dtype=bool)
        keep[drop] = False
        faces = faces[keep]
        dropped_total += len(drop)


def _orient_consistently(faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Flip faces so that every interior edge is traversed in opposite directions by its two faces.

    Breadth-first over face adjacency from face 0 of each component. Non-orientable surfaces
    (Möbius-like) keep whatever orientation the traversal reached.
    """
    faces = faces.copy()
    edges = corner_edges(faces)
    _, inverse = np.unique(edges, axis=0, return_inverse=True)
    inverse = inverse.ravel()
    f = len(faces)
    directed = directed_edges(faces)
    forward = directed[:, 0] < directed[:, 1]   # is the face's traversal the sorted direction?
    face_of = np.tile(np.arange(f), 3)
    order = np.argsort(inverse, kind="stable")
    sorted_edge = inverse[order]
    pair_start = np.flatnonzero(np.r_[True, np.diff(sorted_edge) != 0])
    pair_len = np.diff(np.r_[pair_start, len(order)])
    two = pair_start[pair_len == 2]
    a, b = order[two], order[two + 1]
    # Faces a and b agree when they traverse the shared edge in opposite directions.
    disagree = forward[a] == forward[b]
    graph = sparse.coo_matrix((np.where(disagree, 2.0, 1.0), (face_of[a], face_of[b])), shape=(f, f))
    graph = (graph + graph.T).tocsr()
    flip = np.zeros(f, dtype=bool)
    visited = np.zeros(f, dtype=bool)
    for start in range(f):
        if visited[start]:
            continue
        nodes, predecessors = csgraph.breadth_first_order(graph, start, directed=False, return_predecessors=True)
        visited[nodes] = True
        children = nodes[1:]
        parents = predecessors[children]
        disagrees = (np.asarray(graph[children, parents]).ravel() == 2.0).tolist()
        # Breadth-first order: a parent's flip is settled before its children's.
        flip_list = flip.tolist()
        for child, parent, disagrees_with_parent in zip(children.tolist(), parents.tolist(), disagrees):
            flip_list[child] = flip_list[parent] ^ disagrees_with_parent
        flip = np.asarray(flip_list, dtype=bool)
    faces[flip] = faces[flip][:, ::-1]
    return faces, int(min(flip.sum(), f - flip.sum()))


