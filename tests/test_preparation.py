"""Mesh preparation repairs generated broken inputs and names every repair."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from allorules.errors import MeshError
from allorules.mesh.geometry import enclosed_volume
from allorules.mesh.load import load_mesh
from allorules.mesh.repair import prepare_mesh
from allorules.mesh.topology import cap_holes, count_boundary_loops


def sphere(subdivisions: int = 3, radius: float = 1.0) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)


def test_clean_mesh_needs_no_repair():
    prepared = prepare_mesh(sphere())
    assert prepared.repairs == []
    assert np.array_equal(prepared.faces, sphere().faces)


def test_split_seams_are_merged_and_reported():
    mesh = sphere()
    # Give every face its own three vertices, as a UV-seamed export would.
    split = trimesh.Trimesh(mesh.vertices[mesh.faces].reshape(-1, 3), np.arange(3 * len(mesh.faces)).reshape(-1, 3), process=False)
    prepared = prepare_mesh(split)
    assert len(prepared.vertices) == len(mesh.vertices)
    assert any("merged" in repair and "seam" in repair for repair in prepared.repairs)
    # Every input vertex maps onto the body vertex at the same place.
    assert np.allclose(prepared.vertices[prepared.source_vertex_index], split.vertices)


def test_flipped_faces_are_reoriented_outward():
    mesh = sphere()
    faces = mesh.faces.copy()
    rng = np.random.default_rng(1)
    flip = rng.random(len(faces)) < 0.3
    faces[flip] = faces[flip][:, ::-1]
    prepared = prepare_mesh(trimesh.Trimesh(mesh.vertices, faces, process=False))
    assert any("flipped" in repair for repair in prepared.repairs)
    repaired = trimesh.Trimesh(prepared.vertices, prepared.faces, process=False)
    assert repaired.is_winding_consistent
    assert enclosed_volume(prepared.vertices, prepared.faces) > 0


def test_inside_out_mesh_is_turned_outward():
    mesh = sphere()
    prepared = prepare_mesh(trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False))
    assert any("outward" in repair for repair in prepared.repairs)
    assert enclosed_volume(prepared.vertices, prepared.faces) > 0


def test_holes_are_reported_and_capped_for_volume_only():
    mesh = sphere(4)
    top = mesh.vertices[mesh.faces].mean(axis=1)[:, 2] > 0.95
    bottom = mesh.vertices[mesh.faces].mean(axis=1)[:, 2] < -0.95
    holed = trimesh.Trimesh(mesh.vertices, mesh.faces[~(top | bottom)], process=False)
    prepared = prepare_mesh(holed)
    assert prepared.boundary_loops == 2
    assert any("2 holes" in repair for repair in prepared.repairs)
    assert count_boundary_loops(prepared.faces) == 2          # the output keeps its holes
    capped_vertices, capped_faces = cap_holes(prepared.vertices, prepared.faces)
    assert count_boundary_loops(capped_faces) == 0
    assert enclosed_volume(capped_vertices, capped_faces) == pytest.approx(4 / 3 * np.pi, rel=0.02)


def _split_in_halves(mesh: trimesh.Trimesh, gap: float) -> trimesh.Trimesh:
    """The mesh cut in two along x = 0, the vertices of the cut copied for the left half and moved
    ``gap`` (of an edge) to the left: a mirrored half exported with its seam not welded."""
    left = mesh.vertices[mesh.faces].mean(axis=1)[:, 0] < 0
    shared = np.intersect1d(mesh.faces[left], mesh.faces[~left])
    copy = np.arange(len(mesh.vertices))
    copy[shared] = len(mesh.vertices) + np.arange(len(shared))
    moved = mesh.vertices[shared] - [gap * mesh.edges_unique_length.mean(), 0.0, 0.0]
    faces = np.where(left[:, None], copy[mesh.faces], mesh.faces)
    return trimesh.Trimesh(np.vstack([mesh.vertices, moved]), faces, process=False)


def test_an_open_seam_is_welded_and_every_input_vertex_kept():
    mesh = sphere()
    split = _split_in_halves(mesh, gap=0.002)
    assert count_boundary_loops(split.faces) >= 1
    prepared = prepare_mesh(split)
    assert prepared.boundary_loops == 0
    assert len(prepared.vertices) == len(mesh.vertices)
    assert any("open seam" in repair for repair in prepared.repairs)
    # every input vertex maps onto a body vertex, and moves with it
    assert (prepared.source_vertex_index >= 0).all()
    assert np.abs(prepared.vertices[prepared.source_vertex_index] - split.vertices).max() < 0.01 * mesh.edges_unique_length.mean()
    assert enclosed_volume(prepared.vertices, prepared.faces) == pytest.approx(enclosed_volume(mesh.vertices, mesh.faces), rel=1e-3)


def test_an_opening_wider_than_a_seam_is_not_welded():
    prepared = prepare_mesh(_split_in_halves(sphere(), gap=0.3))
    assert not any("open seam" in repair for repair in prepared.repairs)
    # two halves apart, each half the surface: pieces, joined into the one surface they enclose
    assert prepared.pieces is not None and prepared.boundary_loops == 0
    assert enclosed_volume(prepared.vertices, prepared.faces) == pytest.approx(4 / 3 * np.pi, rel=0.03)


def test_stray_parts_are_carried_along_with_the_body():
    body = sphere(3)
    eye = sphere(1, radius=0.05)
    eye.apply_translation([0.0, 0.0, 1.2])
    both = trimesh.util.concatenate([body, eye])
    prepared = prepare_mesh(both)
    assert len(prepared.vertices) == len(body.vertices)
    assert any("largest of 2 parts" in repair for repair in prepared.repairs)
    moved = prepared.vertices * 2.0
    positions = prepared.source_positions(moved)
    eye_vertices = np.arange(len(body.vertices), len(both.vertices))
    # The eye moved rigidly with its nearest body vertex: its shape is unchanged.
    assert np.allclose(np.ptp(positions[eye_vertices], axis=0), np.ptp(eye.vertices, axis=0))
    assert positions[eye_vertices, 2].mean() > 2.0


def test_duplicate_and_degenerate_faces_are_dropped():
    mesh = sphere()
    faces = np.vstack([mesh.faces, mesh.faces[:5], [[0, 0, 1]]])
    prepared = prepare_mesh(trimesh.Trimesh(mesh.vertices, faces, process=False))
    assert len(prepared.faces) == len(mesh.faces)
    assert any("degenerate" in repair for repair in prepared.repairs)
    assert any("duplicate faces" in repair for repair in prepared.repairs)


def test_stray_parts_are_carried_along_when_faces_were_dropped_too():
    # A held-out dog (an OFF file: two faces dropped on non-manifold edges, and stray parts) failed
    # with an index error: the parts were taken from the input's faces with a mask over the faces kept.
    body = sphere(3)
    eye = sphere(1, radius=0.05)
    eye.apply_translation([0.0, 0.0, 1.2])
    both = trimesh.util.concatenate([body, eye])
    fin_tip = len(both.vertices)
    vertices = np.vstack([both.vertices, [[0.0, 0.0, 1.0 + 1e-3]]])
    a, b = body.faces[0][:2]
    faces = np.vstack([both.faces, [[0, 0, 1]], [[a, b, fin_tip]], [[a, b, fin_tip]]])
    prepared = prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))
    assert any("degenerate" in repair for repair in prepared.repairs)
    positions = prepared.source_positions(prepared.vertices * 2.0)
    eye_vertices = np.arange(len(body.vertices), len(both.vertices))
    assert np.allclose(np.ptp(positions[eye_vertices], axis=0), np.ptp(eye.vertices, axis=0))
    # The vertex left only on dropped faces moves with the body instead of staying behind as a spike.
    assert np.linalg.norm(positions[fin_tip]) > 1.9


def test_non_manifold_fin_is_removed():
    mesh = sphere()
    a, b = mesh.faces[0][:2]
    extra = len(mesh.vertices)
    vertices = np.vstack([mesh.vertices, [[3.0, 3.0, 3.0]]])
    faces = np.vstack([mesh.faces, [[a, b, extra]]])
    prepared = prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))
    assert any("non-manifold" in repair for repair in prepared.repairs)
    assert trimesh.Trimesh(prepared.vertices, prepared.faces, process=False).is_watertight


@pytest.mark.parametrize(
    "vertices, faces, message",
    [
        (np.zeros((0, 3)), np.zeros((0, 3), int), "empty"),
        (np.random.default_rng(0).random((200, 3)), np.zeros((0, 3), int), "no faces"),
    ],
)
def test_unusable_meshes_are_refused_clearly(vertices, faces, message):
    with pytest.raises(MeshError, match=message):
        prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))


def test_nan_coordinates_are_refused():
    mesh = sphere()
    vertices = mesh.vertices.copy()
    vertices[3] = np.nan
    with pytest.raises(MeshError, match="NaN or infinite"):
        prepare_mesh(trimesh.Trimesh(vertices, mesh.faces, process=False))


def test_too_small_body_is_refused():
    with pytest.raises(MeshError, match="only 12 vertices"):
        prepare_mesh(trimesh.creation.icosphere(subdivisions=0))


def test_unreadable_and_unsupported_files(tmp_path):
    with pytest.raises(MeshError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(MeshError, match="unsupported format"):
        load_mesh(tmp_path / "notes.txt")
    (tmp_path / "broken.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    with pytest.raises(MeshError, match="broken.ply"):
        prepare_mesh(tmp_path / "broken.ply")


def test_preparation_is_independent_of_units():
    mesh = sphere()
    for factor in (1e-3, 1e3):
        scaled = trimesh.Trimesh(mesh.vertices * factor, mesh.faces, process=False)
        assert prepare_mesh(scaled).repairs == []


@pytest.mark.shared_meshes
@pytest.mark.parametrize("name", ["horse", "lion", "wolf", "elephant", "camel", "dog-lowpoly"])
def test_real_meshes_prepare(shared_meshes, name):
    prepared = prepare_mesh(shared_meshes / f"{name}.obj")
    capped = cap_holes(prepared.vertices, prepared.faces)
    assert enclosed_volume(*capped) > 0
    assert np.all(np.isfinite(prepared.vertices))


# ---------------------------------------------------------------- an animal in pieces


def test_overlapping_pieces_are_joined_into_the_solid_they_enclose():
    """Two unit spheres whose centres are 1 apart: the body is their union, whose volume is known
    (two balls less their lens, π(4r + d)(2r − d)²/12), with no wall left inside."""
    left, right = sphere(4), sphere(4)
    left.apply_translation([-0.5, 0.0, 0.0])
    right.apply_translation([0.5, 0.0, 0.0])
    pieces = trimesh.util.concatenate([left, right])
    prepared = prepare_mesh(pieces)
    assert prepared.pieces is not None and any("joined its 2 pieces" in repair for repair in prepared.repairs)
    union = 2 * 4 / 3 * np.pi - np.pi * (4 + 1) * (2 - 1) ** 2 / 12
    assert enclosed_volume(prepared.vertices, prepared.faces) == pytest.approx(union, rel=0.01)
    assert prepared.boundary_loops == 0 and len(prepared.faces) > len(pieces.faces)
    # no inside wall: the left sphere's surface inside the right one (down to its centre) is gone
    assert np.linalg.norm(prepared.vertices - [0.5, 0, 0], axis=1).min() > 0.8
    assert np.all(prepared.source_vertex_index == -1)
    np.testing.assert_array_equal(prepared.pieces.source_vertices, np.arange(len(pieces.vertices)))
    # a piece modelled inside out is turned outward first, not subtracted from its neighbour
    right.invert()
    inside_out = prepare_mesh(trimesh.util.concatenate([left, right]))
    assert enclosed_volume(inside_out.vertices, inside_out.faces) == pytest.approx(union, rel=0.01)


def test_every_piece_moves_with_the_joined_body():
    legs = [sphere(3, radius=0.5) for _ in range(2)]
    trunk = sphere(4)
    for leg, x in zip(legs, (-0.5, 0.5)):
        leg.apply_translation([x, 0.0, -0.9])
    pieces = trimesh.util.concatenate([trunk, *legs])
    prepared = prepare_mesh(pieces)
    assert prepared.pieces is not None
    # untouched, the input comes back bit for bit; scaled by 2, every piece is scaled by 2
    np.testing.assert_array_equal(prepared.source_positions(prepared.vertices.copy()), pieces.vertices)
    np.testing.assert_allclose(prepared.source_positions(2.0 * prepared.vertices), 2.0 * pieces.vertices, atol=1e-9)
    # regions go to every piece's vertex from the surface under it, and back
    body_labels = (prepared.vertices[:, 2] < -0.75).astype(np.int64)       # 1: the legs' lower halves
    labels = prepared.source_labels(body_labels)
    feet = pieces.vertices[:, 2] < -1.2
    assert (labels[feet] == 1).all() and (labels[pieces.vertices[:, 2] > 0.0] == 0).all()
    back = prepared.body_labels(labels)
    assert np.mean(back == body_labels) > 0.97
    # the faces buried in the other pieces (the legs' tops in the trunk, the trunk's bottom in the
    # legs) are told from those anyone sees
    centres = pieces.vertices[pieces.faces].mean(axis=1)
    inside_trunk = np.linalg.norm(centres, axis=1) < 0.95
    inside_leg = np.min([np.linalg.norm(centres - [x, 0.0, -0.9], axis=1) for x in (-0.5, 0.5)], axis=0) < 0.45
    buried = prepared.pieces.buried
    assert buried.sum() > 0.05 * len(buried)
    assert np.all(inside_trunk[buried] | inside_leg[buried])
    assert not buried[(centres[:, 2] > 0.5) | (centres[:, 2] < -1.2)].any()     # the back, the feet


def test_pieces_that_enclose_nothing_are_refused():
    square = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    other = square.copy()
    other.apply_translation([2.0, 0.0, 0.0])
    with pytest.raises(MeshError, match="enclose no volume"):
        prepare_mesh(trimesh.util.concatenate([square, other]))
