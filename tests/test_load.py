"""Reading mesh files (issue 19): any byte encoding in an OBJ's comments, a binary file or a
point cloud refused with a true one-line message, 0-based and out-of-range OBJ indices refused
instead of read silently wrong."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from allorules.cli import main
from allorules.errors import MeshError
from allorules.mesh.load import load_mesh

# A closed tetrahedron, 1-based as OBJ wants it
VERTICES = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
FACES = "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
TETRAHEDRON_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def write(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8"))
    return path


def test_a_latin1_byte_in_a_comment_is_read_like_utf8(tmp_path):
    plain = load_mesh(write(tmp_path, "plain.obj", "# cafe\n" + VERTICES + FACES))
    latin = load_mesh(write(tmp_path, "latin.obj", b"# caf\xe9 \xa9 Ren\xe9\n" + (VERTICES + FACES).encode()))
    assert np.array_equal(latin.vertices, plain.vertices) and np.array_equal(latin.faces, plain.faces)
    assert np.array_equal(latin.faces, TETRAHEDRON_FACES)


def test_a_latin1_material_library_is_read(tmp_path):
    write(tmp_path, "skin.mtl", b"# peau d'\xe9l\xe9phant\nnewmtl skin\nKd 0.8 0.7 0.6\n")
    mesh = load_mesh(write(tmp_path, "textured.obj", b"mtllib skin.mtl\n# \xe9\n" + VERTICES.encode() + b"usemtl skin\n"
                           + FACES.encode()))
    assert len(mesh.faces) == 4


def test_a_utf8_comment_and_crlf_lines_are_read(tmp_path):
    text = ("# éléphant 象\r\n" + VERTICES + FACES).replace("\n", "\r\n")
    assert np.array_equal(load_mesh(write(tmp_path, "crlf.obj", text)).faces, TETRAHEDRON_FACES)


@pytest.mark.parametrize("name", ["binary.obj", "binary.off"])
def test_a_binary_file_is_refused_as_not_text(tmp_path, name):
    rng = np.random.default_rng(0)
    path = write(tmp_path, name, rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(MeshError, match="holds binary data, not (OBJ|OFF) text") as caught:
        load_mesh(path)
    assert "charset_normalizer" not in str(caught.value)


def test_vertices_without_faces_are_a_point_cloud(tmp_path):
    with pytest.raises(MeshError, match="holds 4 vertices but no faces"):
        load_mesh(write(tmp_path, "points.obj", VERTICES))


def test_an_empty_file_says_so(tmp_path):
    with pytest.raises(MeshError, match="the file is empty"):
        load_mesh(write(tmp_path, "empty.obj", "\n  \n"))


@pytest.mark.parametrize("faces", [
    "f 0 2 1\nf 0 1 3\nf 0 3 2\nf 1 2 3\n",                          # counted from 0
    "f 1/1 3/3 2/2\nf 1/1 2/2 4/0\nf 1 4 3\nf 2 3 4\n",              # a texture index 0
    "f 1//1 3//1 2//1\nf 1 2 4\nf 1 4 3\nf 2 3 0\n",                 # 0 at the end of the file
])
def test_zero_based_indices_are_refused(tmp_path, faces):
    text = VERTICES + "vt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n" + faces
    with pytest.raises(MeshError, match="vertex index 0, but OBJ counts vertices from 1"):
        load_mesh(write(tmp_path, "zero.obj", text))


def test_coordinates_equal_to_zero_are_not_mistaken_for_indices(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 3 2\nv 0 0 1\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"   # interleaved
    assert np.array_equal(load_mesh(write(tmp_path, "interleaved.obj", text)).faces, TETRAHEDRON_FACES)


@pytest.mark.parametrize("last, shown", [("f 2 3 9\n", "vertex 9"), ("f 2 3 -7\n", "vertex -7")])
def test_indices_past_the_vertices_are_refused(tmp_path, last, shown):
    text = VERTICES + FACES.rsplit("f", 1)[0] + last
    with pytest.raises(MeshError, match=f"refers to {shown}, but the file has 4 vertices"):
        load_mesh(write(tmp_path, "damaged.obj", text))


def test_negative_indices_within_range_are_read(tmp_path):
    text = VERTICES + "f -4 -2 -3\nf -4 -3 -1\nf -4 -1 -2\nf -3 -2 -1\n"
    assert np.array_equal(load_mesh(write(tmp_path, "relative.obj", text)).faces, TETRAHEDRON_FACES)


def test_a_real_obj_reads_as_trimesh_reads_it(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=3)
    path = tmp_path / "sphere.obj"
    mesh.export(path)
    direct = trimesh.load(path, force="mesh", process=False)
    ours = load_mesh(path)
    assert np.array_equal(ours.vertices, direct.vertices) and np.array_equal(ours.faces, direct.faces)


@pytest.mark.parametrize("name, data, message", [
    ("binary.obj", bytes(range(256)) * 20, "holds binary data"),
    ("points.obj", VERTICES, "no faces"),
    ("zero.obj", VERTICES + "f 0 2 1\nf 0 1 3\nf 0 3 2\nf 1 2 3\n", "counts vertices from 1"),
])
def test_the_command_line_says_it_in_one_line(tmp_path, capsys, name, data, message):
    path = write(tmp_path, name, data)
    assert main(["spectrum", str(path), "--modes", "3"]) != 0
    error = capsys.readouterr().err.strip()
    assert message in error and len(error.splitlines()) == 1 and "No module" not in error


@pytest.mark.parametrize("vertices, message", [
    ("v 1e308 0 0\nv -1e308 0 0\nv 0 1e308 0\nv 0 0 1e308\n", "coordinates as large as 1e\\+308"),
    ("v 1e-40 0 0\nv 0 0 0\nv 0 1e-40 0\nv 0 0 1e-40\n", "1e-40 units across"),
    ("v 0 0\nv 1 0\nv 0 1\nv 1 1\n", "vertices have 2 coordinates, a 3-D mesh needs three"),
])
def test_coordinates_that_cannot_be_measured_are_refused(tmp_path, capsys, vertices, message):
    path = write(tmp_path, "odd.obj", vertices + FACES)
    with pytest.raises(MeshError, match=message):
        load_mesh(path)
    assert main(["spectrum", str(path), "--modes", "3"]) != 0
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "Warning" not in error   # no NumPy overflow warning either


def test_library_messages_do_not_reach_the_user(tmp_path, capsys):
    """trimesh logs 'triangulating faces' at INFO; only allorules' own messages are shown."""
    path = write(tmp_path, "quads.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
                 "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n")
    main(["spectrum", str(path), "--modes", "3"])
    assert "triangulating" not in capsys.readouterr().err
