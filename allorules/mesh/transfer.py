"""Carrying a working mesh's result back to the user's mesh (METHOD §9, issue 16).

:func:`bind` ties every vertex p of the user's body to the working surface once, before any
edit: its closest point (``triangle`` and barycentric ``weights`` b, the *foot*
f = Σ_k b_k w_k over the triangle's corners w_k) and its *offset* d = p − f, the user's detail
relative to the working surface.

:func:`carry_deformation` moves the user's body with the working mesh. Each working vertex k gets
the similarity that its neighbourhood underwent, A_k = σ_k R_k: R_k the rotation that best maps
its one-ring edges and normal before onto after (Kabsch / orthogonal Procrustes), σ_k = √(a'_k / a_k) its change of area (lumped mass) as an isotropic scale. A user vertex
then goes to

    p' = Σ_k b_k w'_k + (Σ_k b_k A_k) d

the moved foot plus the offset turned and scaled with the surface around it. The frame is
interpolated across the triangle with the same weights as the foot, so it is continuous over the
working surface and neighbouring user vertices do not crack apart; nothing is smoothed (the
offset is kept whole, so sharp features stay sharp); a uniform scale by s gives s·p (to
round-off), a rigid motion moves p rigidly. Working vertices that did not move give back the
input exactly (short-circuited, bit for bit).

:func:`carry_labels` gives each user vertex the region with the largest summed weight among its
working triangle's corners. The user's vertices, their order and faces are never changed, so the output is
written in the input's own layout by :mod:`allorules.export` (UVs, materials and groups kept).

Everything is vectorised and goes by chunks of ``CHUNK`` user vertices (memory at 1-2M vertices).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CHUNK = 200_000


@dataclass(frozen=True)
class Binding:
    """Where every user vertex sits on the working surface, and its offset from there."""

    triangle: np.ndarray     # (n,) index into the working faces
    weights: np.ndarray      # (n, 3) barycentric coordinates of the foot in that triangle
    offset: np.ndarray       # (n, 3) user vertex minus its foot, in the working mesh's coordinates
    working_faces: np.ndarray

    @property
    def vertex_count(self) -> int:
        return len(self.triangle)

    def corners(self) -> np.ndarray:
        """(n, 3) the working vertices of each user vertex's triangle."""
        return self.working_faces[self.triangle]


def bind(user_vertices: np.ndarray, working_vertices: np.ndarray, working_faces: np.ndarray) -> Binding:
    """Bind every user vertex to its closest point on the working surface (libigl's AABB tree,
    through gpytoolbox), with barycentric weights and the offset from it."""
    import gpytoolbox

    user_vertices = np.asarray(user_vertices, dtype=np.float64)
    working_vertices = np.ascontiguousarray(working_vertices, dtype=np.float64)
    working_faces = np.ascontiguousarray(working_faces, dtype=np.int64)
    count = len(user_vertices)
    triangle = np.empty(count, dtype=np.int64)
    weights = np.empty((count, 3))
    offset = np.empty((count, 3))
    tree = gpytoolbox.squared_distance_precompute(working_vertices, working_faces.astype(np.int32))
    for start in range(0, count, CHUNK):
        points = np.ascontiguousarray(user_vertices[start:start + CHUNK])
        # libigl's AABB tree finds the closest triangle; the point on it is found here (the third
        # value it returns is closest points or barycentric coordinates depending on the call)
        _, nearest, _ = tree.squared_distance(points)
        nearest = np.asarray(nearest, dtype=np.int64).ravel()
        block = closest_point_weights(points, working_vertices[working_faces[nearest]])
        foot = np.einsum("ij,ijk->ik", block, working_vertices[working_faces[nearest]])
        triangle[start:start + CHUNK] = nearest
        weights[start:start + CHUNK] = block
        offset[start:start + CHUNK] = points - foot
    return Binding(triangle, weights, offset, working_faces)


def closest_point_weights(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (n, 3) of the point of triangle ``corners[i]`` (n, 3, 3) closest
    to ``points[i]`` (Ericson, Real-Time Collision Detection §5.1.5: the Voronoi region of a
    corner, an edge or the face, vectorised)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    ab, ac, ap = b - a, c - a, points - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = points - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = points - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    tiny = np.finfo(float).tiny

    def ratio(top, bottom):
        return np.clip(top / np.where(np.abs(bottom) > tiny, bottom, tiny), 0.0, 1.0)

    denominator = va + vb + vc
    safe = np.where(np.abs(denominator) > tiny, denominator, 1.0)
    weights = np.column_stack([va / safe, vb / safe, vc / safe])                 # inside the face
    on_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    t = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    weights[on_bc] = np.column_stack([np.zeros_like(t), 1 - t, t])[on_bc]
    on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    t = ratio(d2, d2 - d6)
    weights[on_ac] = np.column_stack([1 - t, np.zeros_like(t), t])[on_ac]
    on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    t = ratio(d1, d1 - d3)
    weights[on_ab] = np.column_stack([1 - t, t, np.zeros_like(t)])[on_ab]
    weights[(d6 >= 0) & (d5 <= d6)] = (0.0, 0.0, 1.0)
    weights[(d3 >= 0) & (d4 <= d3)] = (0.0, 1.0, 0.0)
    weights[(d1 <= 0) & (d2 <= 0)] = (1.0, 0.0, 0.0)
    weights = np.clip(np.nan_to_num(weights, nan=1.0 / 3.0), 0.0, 1.0)
    return weights / np.maximum(weights.sum(axis=1, keepdims=True), tiny)


def vertex_similarities(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3, 3) per working vertex, the similarity σ_k R_k its neighbourhood underwent.

    R_k maximises Σ_j ⟨e'_kj, R e_kj⟩ + 2 ℓ² ⟨n'_k, R n_k⟩ over its one-ring edges e and its unit
    normal n, ℓ² the mean squared edge length (Kabsch: R = U diag(1, 1, det) Vᵀ from the SVD of the
    covariance C = Σ e' eᵀ + 2 ℓ² n' nᵀ); σ_k = √(a'_k / a_k), the change of its lumped area."""
    from allorules.mesh.geometry import vertex_areas, vertex_normals

    before = np.asarray(before, dtype=np.float64)
    after = np.asarray(after, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    vector = before[edges[:, 1]] - before[edges[:, 0]]
    moved = after[edges[:, 1]] - after[edges[:, 0]]
    outer = moved[:, :, None] * vector[:, None, :]
    covariance = np.zeros((len(before), 3, 3))
    np.add.at(covariance, edges[:, 0], outer)
    np.add.at(covariance, edges[:, 1], outer)           # (−e')(−e)ᵀ = e' eᵀ
    # The normal weighs like two mean edges: it fixes the turn about a flat one-ring's tangent axes.
    normal, moved_normal = vertex_normals(before, faces), vertex_normals(after, faces)
    covariance += 2.0 * np.einsum("ij,ij->", vector, vector) / len(vector) * moved_normal[:, :, None] * normal[:, None, :]
    left, _, right = np.linalg.svd(covariance)
    sign = np.sign(np.linalg.det(left @ right))
    sign[sign == 0] = 1.0
    left[:, :, 2] *= sign[:, None]
    rotation = left @ right
    area_before, area_after = vertex_areas(before, faces), vertex_areas(after, faces)
    scale = np.sqrt(np.where(area_before > 0, area_after / np.where(area_before > 0, area_before, 1.0), 1.0))
    return scale[:, None, None] * rotation


def carry_deformation(binding: Binding, working_before: np.ndarray, working_after: np.ndarray,
                      user_before: np.ndarray | None = None) -> np.ndarray:
    """The user's vertices after the working mesh moved from ``working_before`` to
    ``working_after``: p' = Σ b_k w'_k + (Σ b_k σ_k R_k) d (module docstring). When the working
    mesh did not move, ``user_before`` (if given) is returned as it is, bit for bit."""
    working_before = np.asarray(working_before, dtype=np.float64)
    working_after = np.asarray(working_after, dtype=np.float64)
    if np.array_equal(working_before, working_after):
        if user_before is not None:
            return np.array(user_before, dtype=np.float64, copy=True)
    similarities = vertex_similarities(working_before, working_after, binding.working_faces)
    result = np.empty((binding.vertex_count, 3))
    for start in range(0, binding.vertex_count, CHUNK):
        rows = slice(start, start + CHUNK)
        corners = binding.working_faces[binding.triangle[rows]]
        weights = binding.weights[rows]
        foot = np.einsum("ij,ijk->ik", weights, working_after[corners])
        frame = np.einsum("ij,ijkl->ikl", weights, similarities[corners])
        result[rows] = foot + np.einsum("ikl,il->ik", frame, binding.offset[rows])
    return result


def carry_labels(binding: Binding, working_labels: np.ndarray) -> np.ndarray:
    """Per user vertex, the label with the largest summed weight among its working triangle's
    corners (ties: the first corner's). Where the corners disagree the boundary runs straight
    across the triangle (half-way between its labelled corners), not along the working mesh's
    zigzag of edges."""
    working_labels = np.asarray(working_labels)
    corners = binding.corners()
    corner_labels = working_labels[corners]                                   # (n, 3)
    # summed weight of each corner's label: corner k gets the weights of every corner labelled like it
    same = corner_labels[:, :, None] == corner_labels[:, None, :]            # (n, 3, 3)
    support = np.einsum("ikj,ij->ik", same, binding.weights)
    return corner_labels[np.arange(binding.vertex_count), np.argmax(support, axis=1)]


def carry_values(binding: Binding, working_values: np.ndarray) -> np.ndarray:
    """A smooth per-vertex field (n_working, ...) interpolated at every user vertex's foot."""
    working_values = np.asarray(working_values, dtype=np.float64)
    corners = binding.corners()
    return np.einsum("ij,ij...->i...", binding.weights, working_values[corners])
