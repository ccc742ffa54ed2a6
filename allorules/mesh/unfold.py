"""Unfolding: faces a deformation turned inside out, smoothed back into the surface (issue 18 §4).

Owns :func:`unfold_faces` and its outcome, :class:`Unfolding`. Eq. 9 can fold a few triangles
where the power law of one region meets another's (the real horse galloping at ×2: one face in
the fore limbs, a spike 0.7 % of the body's size): a face whose normal turned by more than 90°
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
    adjacency = vertex_adjacency(faces, count)
    laplacian = (sparse.diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
    patch = np.zeros(count, dtype=bool)
    patch[faces[flipped].ravel()] = True
    best = (folded, after)
    for _ in range(max_rings):
        patch |= adjacency @ patch.astype(float) > 0
        inner, outer = np.flatnonzero(patch), np.flatnonzero(~patch)
        ring = np.flatnonzero(~patch & (adjacency @ patch.astype(float) > 0))
        if len(ring) < 3:                                    # the patch took a whole part: nothing to rebuild it from
            break
        scale, rotation, shift = similarity_fit(before[ring], after[ring])
        fitted = scale * before @ rotation.T + shift
        left_over = after - fitted
        system = laplacian[inner][:, inner] + _ANCHOR * sparse.identity(len(inner))
        right = -(laplacian[inner][:, outer] @ left_over[outer])
        candidate = after.copy()                             # every vertex outside exactly as it was
        candidate[inner] = fitted[inner] + np.asarray(spsolve(system.tocsc(), right)).reshape(-1, 3)
        left = int(flipped_face_mask(before, candidate, faces).sum())
        if left < best[0]:
            best = (left, candidate)
        if left == 0:
            break
    left, vertices = best
    moves = np.linalg.norm(vertices - after, axis=1)
    return Unfolding(vertices, folded, left, int(np.count_nonzero(moves)), float(moves.max()))
