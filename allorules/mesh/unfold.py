"""Unfolding: faces a deformation turned inside out, smoothed back into the surface (issue 18 §4).

Owns :func:`unfold_faces` and its outcome, :class:`Unfolding`. Eq. 9 can fold a few triangles
where the power law of one region meets another's (the real horse galloping at ×2: one face in
the fore limbs, a spike 0.5 % of the body's size): a face whose normal turned by more than 90°
(:func:`allorules.mesh.geometry.flipped_face_mask`) renders as a dark speck and breaks shading
and subdivision in Blender. The written mesh should have none.

Over the vertices of the folded faces and a ring of neighbours around them (the patch), the
deformation is rebuilt from the vertices just outside it: the similarity (scale, rotation, shift)
that best maps the outside ring from before to after (:func:`allorules.mesh.geometry.similarity_fit`),
plus what it leaves, r = after − similarity(before), filled in harmonically from the ring (the
uniform graph Laplacian, L_pp r_p = −L_po r_o). The input's own detail in the patch rides along
with the similarity, exactly where the deformation around the fold is one (uniform scaling,
turning), and the fold's spike is gone. Where faces are still folded the patch grows by one more
ring, up to ``MAX_RINGS``. Every vertex outside the patch keeps its position exactly.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.linalg import spsolve

from allorules.mesh.geometry import flipped_face_mask, similarity_fit
from allorules.mesh.topology import vertex_adjacency

MAX_RINGS = 6            # rings of neighbours the patch may grow by around the folded faces
# keeps a part wholly inside the patch (a detached eye) solvable: it follows the ring's similarity
_ANCHOR = 1e-6


@dataclass(frozen=True)
class Unfolding:
    """What :func:`unfold_faces` did: the new positions, how many faces were folded before and
    still are after, how many vertices moved, and the largest distance one moved."""

    vertices: np.ndarray
    folded: int
    left: int
    moved: int
    largest_move: float

    @property
    def unfolded(self) -> int:
        return self.folded - self.left


def unfold_faces(before: np.ndarray, after: np.ndarray, faces: np.ndarray, *, max_rings: int = MAX_RINGS) -> Unfolding:
    """``after`` (a deformation of ``before``, same faces) with every folded face smoothed back, as
    far as ``max_rings`` rings of neighbours allow; ``after`` itself (not a copy) when none is
    folded. Where some stay folded, the patch that left the fewest is kept."""
    before, after = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    flipped = flipped_face_mask(before, after, faces)
    folded = int(flipped.sum())
    if folded == 0:
        return Unfolding(after, 0, 0, 0, 0.0)
    count = len(before)
    # face × vertex incidence: the rings grow through it, and only the faces about the patch are
    # looked at again (a 2.6M-vertex sphere with one fold: no whole-mesh adjacency or Laplacian)
    incidence = sparse.csr_matrix((np.ones(faces.size), (np.repeat(np.arange(len(faces)), 3), faces.ravel())),
                                  shape=(len(faces), count))
    patch = np.zeros(count, dtype=bool)
    patch[faces[flipped].ravel()] = True
    best: tuple[int, np.ndarray, np.ndarray] = (folded, np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    touching = np.flatnonzero(incidence @ patch.astype(float))      # the faces with a vertex in the patch
    for _ in range(max_rings):
        patch[faces[touching].ravel()] = True                          # one ring more
        touching = np.flatnonzero(incidence @ patch.astype(float))
        local = faces[touching]                                        # every face about the patch
        about = np.unique(local)                             # the patch and the ring just outside it
        inner, ring = about[patch[about]], about[~patch[about]]
        if len(ring) < 3:                                    # the patch took a whole part: nothing to rebuild it from
            break
        scale, rotation, shift = similarity_fit(before[ring], after[ring])
        fitted_inner = scale * before[inner] @ rotation.T + shift
        left_over_ring = after[ring] - (scale * before[ring] @ rotation.T + shift)
        index = np.full(count, -1, dtype=np.int64)
        index[inner] = np.arange(len(inner))
        index[ring] = len(inner) + np.arange(len(ring))
        laplacian = _uniform_laplacian(index[local], len(about))
        system = laplacian[: len(inner), : len(inner)] + _ANCHOR * sparse.identity(len(inner))
        right = -(laplacian[: len(inner), len(inner):] @ left_over_ring)
        positions = fitted_inner + np.asarray(spsolve(system.tocsc(), right)).reshape(-1, 3)
        # only the faces about the patch moved; the others keep their (unfolded) turn
        left = _folded(before[local], np.vstack([positions, after[ring]])[index[local]])
        if left < best[0]:
            best = (left, inner, positions)
        if left == 0:
            break
    left, inner, positions = best
    vertices = after.copy()
    vertices[inner] = positions
    moves = np.linalg.norm(positions - after[inner], axis=1)
    return Unfolding(vertices, folded, left, int(np.count_nonzero(moves)), float(moves.max(initial=0.0)))


def _uniform_laplacian(faces: np.ndarray, count: int) -> sparse.csr_matrix:
    """Degree minus adjacency of the vertices joined by the edges of ``faces`` (local indices)."""
    adjacency = vertex_adjacency(faces, count)
    return (sparse.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()


def _folded(corners_before: np.ndarray, corners_after: np.ndarray) -> int:
    """How many of the faces given by their corners (k × 3 × 3) are folded (flipped_face_mask's test)."""
    triangles = np.arange(3 * len(corners_before)).reshape(-1, 3)
    return int(flipped_face_mask(corners_before.reshape(-1, 3), corners_after.reshape(-1, 3), triangles).sum())

