"""Faces a deformation turned inside out, smoothed back (allorules.mesh.unfold)."""
from __future__ import annotations

import numpy as np
import trimesh

from allorules.mesh.geometry import flipped_face_mask
from allorules.mesh.unfold import unfold_faces


def _bumpy_sphere():
    sphere = trimesh.creation.icosphere(4)
    vertices = sphere.vertices * (1 + 0.04 * np.sin(11 * sphere.vertices[:, :1]) * np.cos(7 * sphere.vertices[:, 1:2]))
    return np.asarray(vertices), np.asarray(sphere.faces)


def _spiked(vertices, faces, scale=2.0):
    """Uniform scaling with one vertex dragged sideways past its neighbour (the faces around it fold)."""
    after = scale * vertices
    tip = 0
    neighbour = faces[np.any(faces == tip, axis=1)][0]
    neighbour = neighbour[neighbour != tip][0]
    after[tip] = scale * (vertices[tip] + 2.5 * (vertices[neighbour] - vertices[tip]))
    return after, tip


def test_a_folded_fan_is_smoothed_back_and_nothing_else_moves():
    vertices, faces = _bumpy_sphere()
    after, tip = _spiked(vertices, faces)
    assert flipped_face_mask(vertices, after, faces).sum() >= 2
    unfolding = unfold_faces(vertices, after, faces)
    assert unfolding.folded >= 2 and unfolding.left == 0 and unfolding.unfolded == unfolding.folded
    assert not flipped_face_mask(vertices, unfolding.vertices, faces).any()
    moved = np.flatnonzero(np.any(unfolding.vertices != after, axis=1))
    assert unfolding.moved == len(moved) and tip in moved
    assert len(moved) < 0.02 * len(vertices)                           # a small patch around the fold
    # the patch is a few rings around the tip: every moved vertex is near it
    assert np.linalg.norm(after[moved] - 2 * vertices[tip], axis=1).max() < 0.5


def test_the_detail_of_the_input_rides_along():
    """The patch follows the similarity of the ring around it: where the deformation about the
    fold is a uniform scale, the unfolded patch is the bumpy surface scaled, exactly (smoothing the
    surface or its displacement would flatten the bumps)."""
    vertices, faces = _bumpy_sphere()
    after, tip = _spiked(vertices, faces)
    unfolding = unfold_faces(vertices, after, faces)
    assert unfolding.moved > 1
    assert np.abs(unfolding.vertices - 2 * vertices).max() < 1e-9
    # turned and shifted as well: the same
    c, s = np.cos(0.5), np.sin(0.5)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    turned = unfold_faces(vertices, after @ turn.T + 3.0, faces)
    assert turned.left == 0 and np.abs(turned.vertices - ((2 * vertices) @ turn.T + 3.0)).max() < 1e-9


def test_a_fold_on_a_smooth_bend_is_unfolded_close_to_the_bend():
    """A non-uniform deformation (a bend) with a fold: unfolded, the patch lies near the bent
    surface (within a small share of the patch's size), not at the fold."""
    vertices, faces = _bumpy_sphere()
    bent = vertices.copy()
    bent[:, 0] += 0.3 * vertices[:, 2] ** 2                         # a smooth bend
    after = bent.copy()
    tip = 0
    neighbour = faces[np.any(faces == tip, axis=1)][0]
    neighbour = neighbour[neighbour != tip][0]
    after[tip] = bent[tip] + 2.5 * (bent[neighbour] - bent[tip])
    unfolding = unfold_faces(vertices, after, faces)
    assert unfolding.left == 0
    moved = np.any(unfolding.vertices != after, axis=1)
    span = np.ptp(bent[moved], axis=0).max()
    assert np.linalg.norm(unfolding.vertices[moved] - bent[moved], axis=1).max() < 0.1 * span


def test_nothing_folded_is_returned_as_it_is():
    vertices, faces = _bumpy_sphere()
    after = 1.5 * vertices + 2.0
    unfolding = unfold_faces(vertices, after, faces)
    assert unfolding.vertices is after and (unfolding.folded, unfolding.left, unfolding.moved) == (0, 0, 0)


def test_a_degenerate_or_needle_input_face_is_not_folded():
    """A face of zero area, or a needle whose height is under 1 % of its length, has no normal worth
    turning: it is never counted folded (nor made to unfold); a thin but real face is."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [0.5, 0.005, 0], [0.5, 0.02, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4], [0, 1, 5]])    # a triangle, a line, a needle, a thin one
    moved = vertices * [1, -1, 1]
    assert flipped_face_mask(vertices, moved, faces).tolist() == [True, False, False, True]
