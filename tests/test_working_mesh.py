"""Tests of allorules.working_mesh: size, quality, the body kept as it is, and clear refusals."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from allorules.errors import MeshError
from allorules.mesh.geometry import face_areas
from allorules.mesh.transfer import bind
from allorules.mesh.working import (
    MAX_WORKING_VERTICES,
    MIN_WORKING_VERTICES,
    SPLIT_BELOW,
    WORKING_VERTICES,
    check_working_vertices,
    flip_flat_triangles,
    make_working_mesh,
    split_working_mesh,
    triangle_quality,
)


def test_a_body_at_or_below_the_working_size_is_used_as_it_is() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=4)          # 2,562 vertices
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    working = make_working_mesh(vertices, faces, 2562)
    assert working.is_source and working.vertices is vertices and working.faces is faces
    assert make_working_mesh(vertices, faces).is_source       # the default is larger


def test_a_coarse_body_split_finer_is_the_same_surface_with_its_own_vertices_first() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=2)          # 162 vertices: split twice, 2,562
    mesh.vertices *= [2.0, 1.0, 0.7]
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    assert make_working_mesh(vertices, faces).is_coarse_source  # used as it is first
    working = split_working_mesh(vertices, faces)
    assert working.method == "split" and not working.is_source and working.source_vertices == 162
    assert len(working.vertices) == 2562 >= SPLIT_BELOW and len(working.faces) == 16 * len(faces)
    assert np.array_equal(working.vertices[:len(vertices)], vertices)       # unmoved, in their order
    assert np.abs(bind(working.vertices, vertices, faces).offset).max() < 1e-12   # every vertex on the body
    assert np.isclose(face_areas(working.vertices, working.faces).sum(), face_areas(vertices, faces).sum())
    assert trimesh.Trimesh(working.vertices, working.faces, process=False).is_volume
    assert not make_working_mesh(working.vertices, working.faces).is_coarse_source


def test_a_larger_body_is_remeshed_to_the_size_with_good_triangles(generated_horse) -> None:
    body = generated_horse.body()
    working = make_working_mesh(body.vertices, body.faces, 2000)
    assert working.method == "remeshed" and working.source_vertices == len(body.vertices)
    assert abs(len(working.vertices) / 2000 - 1) < 0.05
    quality = triangle_quality(working.vertices, working.faces)
    before = triangle_quality(body.vertices, body.faces)
    assert quality["min_angle_median"] > 50 and quality["below_10"] < 0.001
    assert quality["min_angle_median"] > before["min_angle_median"]
    # the same surface: every working vertex lies on the body
    distance = np.linalg.norm(bind(working.vertices, body.vertices, body.faces).offset, axis=1)
    size = np.linalg.norm(np.ptp(body.vertices, axis=0))
    assert distance.max() < 2e-3 * size
    # one closed, outward body; its volume a little smaller (the chords of a coarser mesh cut
    # inside a curved surface: 1.4 % at 2,000 vertices of the 3,000-vertex horse)
    from allorules.body import Body
    from allorules.measure.mass import body_mass

    assert -0.03 < body_mass(Body(working.vertices, working.faces)) / body_mass(body) - 1 < 0


def test_a_fine_body_is_decimated_first_then_remeshed() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=5)          # 10,242 vertices > 4 × 2,000
    mesh.vertices *= [2.0, 1.0, 0.7]
    working = make_working_mesh(mesh.vertices, mesh.faces, 2000)
    assert working.method == "decimated+remeshed" and abs(len(working.vertices) / 2000 - 1) < 0.05
    assert working.quality["min_angle_median"] > 50


def test_a_body_pinched_at_a_vertex_is_remeshed_with_the_pinch_split(monkeypatch) -> None:
    """Two sheets of one surface touching at a vertex (a held-out cow's pinch) crashed the remesher
    with a segmentation fault once decimated; it is given the surface with that vertex split, and
    the working mesh is the same surface."""
    import gpytoolbox
    import igl

    sphere = trimesh.creation.icosphere(subdivisions=5)                 # 10,242 vertices
    vertices, faces = np.array(sphere.vertices), np.array(sphere.faces)
    north, south = int(np.argmax(vertices[:, 2])), int(np.argmin(vertices[:, 2]))
    vertices[[north, south]] = 0.0                                      # both poles pulled to the centre
    faces = np.where(faces == south, north, faces)                      # and made one vertex: a pinch
    assert not igl.is_vertex_manifold(faces)[north]
    given = []
    remesh = gpytoolbox.remesh_botsch

    def watched(v, f, **options):
        given.append(bool(igl.is_vertex_manifold(np.asarray(f, dtype=np.int64)).all()))
        return remesh(v, f, **options)

    monkeypatch.setattr(gpytoolbox, "remesh_botsch", watched)
    working = make_working_mesh(vertices, faces, 2000)
    assert given and all(given)
    assert abs(len(working.vertices) / 2000 - 1) < 0.1
    area = face_areas(vertices, faces).sum()
    assert face_areas(working.vertices, working.faces).sum() == pytest.approx(area, rel=0.03)


def test_an_open_body_with_holes_keeps_its_holes() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=5)
    keep = ~((mesh.triangles_center[:, 2] > 0.9) | (np.abs(mesh.triangles_center[:, 0]) > 0.95))  # three holes
    vertices, faces = mesh.vertices, mesh.faces[keep]
    working = make_working_mesh(vertices, faces, 2000)
    from allorules.mesh.topology import count_boundary_loops

    assert count_boundary_loops(working.faces) == 3


def test_a_flat_triangle_has_its_long_edge_flipped_and_one_on_a_rim_stays() -> None:
    """A remeshed vertex projected onto a rim's edge makes a triangle with an angle of 180° (a
    held-out donkey's working mesh: its basis took 11× as long). Its long edge is flipped where
    another triangle lies across it; the surface keeps its orientation and its edges unique."""
    from allorules.mesh.geometry import corner_angles, face_normals

    vertices = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1e-7, 0.0], [1.0, -1.0, 0.0],
                         [3.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    # (2, 0, 1) is flat at corner 2; (1, 0, 3) lies across its long edge (0, 1); (2, 1, 4) and
    # (2, 5, 0) close the fan above it
    faces = np.array([[2, 0, 1], [1, 0, 3], [2, 1, 4], [2, 5, 0]])
    flipped = flip_flat_triangles(vertices, faces)
    assert corner_angles(vertices, faces).max() > 179.99
    assert corner_angles(vertices, flipped).max() < 170 and corner_angles(vertices, flipped[:2]).min() > 44
    assert np.all(np.sign(face_normals(vertices, flipped)[:, 2]) == np.sign(face_normals(vertices, faces[1:2])[0, 2]))
    edges = np.sort(np.vstack([flipped[:, [0, 1]], flipped[:, [1, 2]], flipped[:, [2, 0]]]), axis=1)
    assert len(np.unique(edges, axis=0)) == len(edges) - 3     # the three inner edges, each used twice
    # with nothing across its long edge (a rim), the flat triangle stays
    assert np.array_equal(flip_flat_triangles(vertices, faces[[0, 2, 3]]), faces[[0, 2, 3]])
    # a remesh with no such triangle is left exactly as it is
    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert np.array_equal(flip_flat_triangles(sphere.vertices, sphere.faces), sphere.faces)


@pytest.mark.parametrize("count", [MIN_WORKING_VERTICES - 1, MAX_WORKING_VERTICES + 1, 0, -5, 2500.5])
def test_a_working_size_out_of_range_is_refused_before_any_work(count) -> None:
    with pytest.raises(MeshError, match="working-vertices"):
        check_working_vertices(count)
    with pytest.raises(MeshError, match="working-vertices"):
        make_working_mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int), count)   # refused before looking at the mesh


def test_the_default_and_a_valid_size() -> None:
    assert check_working_vertices(None) == WORKING_VERTICES
    assert check_working_vertices(12000) == 12000


def test_a_single_sheet_is_refused_with_what_to_do() -> None:
    sheet = trimesh.creation.icosphere(subdivisions=5)
    sheet = sheet.submesh([np.flatnonzero(sheet.triangles_center[:, 2] > 0.1)], append=True)   # a bowl
    with pytest.raises(MeshError, match="single open sheet.*close it"):
        make_working_mesh(sheet.vertices, sheet.faces, 2000)


def test_a_flat_plate_is_refused_as_too_thin() -> None:
    plate = trimesh.creation.box(extents=[100.0, 100.0, 0.2]).subdivide_to_size(2.0)
    with pytest.raises(MeshError, match="too thin"):
        make_working_mesh(plate.vertices, plate.faces, 2000)


def test_the_command_lines_help_gives_the_working_sizes():
    import argparse

    from allorules.cli.arguments import add_working_vertices_argument
    from allorules.mesh.working import (
        MAX_WORKING_VERTICES,
        MIN_WORKING_VERTICES,
        WORKING_VERTICES,
    )

    parser = argparse.ArgumentParser()
    add_working_vertices_argument(parser)
    text = parser.format_help().replace("\n", " ")
    assert f"default {WORKING_VERTICES}, from {MIN_WORKING_VERTICES} to {MAX_WORKING_VERTICES}" in " ".join(text.split())
