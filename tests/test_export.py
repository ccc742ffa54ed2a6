"""Tests of allorules.output.export: formats, carried-over UVs/materials, atomic and safe writing."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

from allorules import files
from allorules.errors import MeshError, OutputError
from allorules.files import atomic_write, default_output_path
from allorules.mesh.geometry import vertex_normals
from allorules.output.export import save_mesh

SHARED_MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"

# A 1×1×1 cube as an artist would export it: 8 positions, 14 UV coordinates (seams), two
# materials, a material library with a texture, and one normal per side (hard edges).
CUBE_OBJ = """\
# test cube
mtllib cube.mtl
o Cube
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
vt 0.00 0.00
vt 0.25 0.00
vt 0.25 0.25
vt 0.00 0.25
vt 0.50 0.00
vt 0.50 0.25
vt 0.75 0.00
vt 0.75 0.25
vt 1.00 0.00
vt 1.00 0.25
vt 0.25 0.50
vt 0.50 0.50
vt 0.25 0.75
vt 0.50 0.75
vn 0 0 -1
vn 0 0 1
vn 0 -1 0
vn 0 1 0
vn 1 0 0
vn -1 0 0
s off
usemtl Skin
f 1/1/1 4/4/1 3/3/1
f 1/1/1 3/3/1 2/2/1
f 5/5/2 6/7/2 7/8/2
f 5/5/2 7/8/2 8/6/2
f 1/1/3 2/2/3 6/5/3
f 1/1/3 6/5/3 5/4/3
usemtl Hooves
f 4/11/4 8/12/4 7/14/4
f 4/11/4 7/14/4 3/13/4
f 2/9/5 3/10/5 7/8/5
f 2/9/5 7/8/5 6/7/5
f 1/1/6 5/2/6 8/3/6
f 1/1/6 8/3/6 4/4/6
"""

CUBE_MTL = """\
newmtl Skin
Kd 0.8 0.6 0.5
map_Kd skin.png
newmtl Hooves
Kd 0.2 0.2 0.2
"""


def _tiny_png() -> bytes:
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.new("RGB", (4, 4), (200, 150, 120)).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.fixture
def textured_cube(tmp_path: Path) -> Path:
    folder = tmp_path / "input"
    folder.mkdir()
    (folder / "cube.obj").write_text(CUBE_OBJ)
    (folder / "cube.mtl").write_text(CUBE_MTL)
    (folder / "skin.png").write_bytes(_tiny_png())
    return folder / "cube.obj"


def _load(path: Path) -> trimesh.Trimesh:
    return trimesh.load(path, force="mesh", process=False)


def _no_temporaries(folder: Path) -> bool:
    return not any(name.name.endswith(".tmp") for name in folder.iterdir())


# ------------------------------------------------------------------------------------------
# OBJ with UVs and materials


def test_obj_round_trip_keeps_uvs_faces_and_material_library(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    assert len(source.vertices) > 8  # trimesh split the cube at its UV seams
    scaled = source.vertices * np.array([2.0, 0.5, 3.0]) + 7.0
    output = tmp_path / "out" / "cube_scaled.obj"

    result = save_mesh(output, scaled, source.faces, source=source, input_path=textured_cube)

    back = _load(output)
    np.testing.assert_array_equal(back.faces, source.faces)
    np.testing.assert_array_equal(back.visual.uv, source.visual.uv)
    np.testing.assert_allclose(back.vertices, scaled, rtol=1e-8, atol=1e-8)
    text = output.read_text()
    assert "mtllib cube.mtl" in text
    assert "usemtl Skin" in text and "usemtl Hooves" in text  # both material groups survive
    assert "UVs" in result.carried
    assert any("mtllib cube.mtl" in item for item in result.carried)
    # the material library and its texture are referenced from the new folder: copied there
    assert (output.parent / "cube.mtl").read_text() == CUBE_MTL
    assert (output.parent / "skin.png").is_file()
    assert set(result.extra_files) == {output.parent / "cube.mtl", output.parent / "skin.png"}
    assert _no_temporaries(output.parent)


def test_obj_normals_are_recomputed_for_the_new_shape(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    output = tmp_path / "cube_sheared.obj"
    sheared = source.vertices.copy()
    sheared[:, 0] += sheared[:, 1]          # x += y: the ±x sides tilt, the others stay
    save_mesh(output, sheared, source.faces, source=source, input_path=textured_cube)
    lines = output.read_text().splitlines()
    normals = np.array([[float(x) for x in line.split()[1:]] for line in lines if line.startswith("vn ")])
    expected = np.array([[0, 0, -1], [0, 0, 1], [0, -1, 0], [0, 1, 0], [1, -1, 0], [-1, 1, 0]], dtype=float)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(normals, expected, atol=1e-9)  # hard edges stay hard, one per side
    # face lines are the input's, verbatim
    face_lines = [line for line in lines if line.startswith("f ")]
    assert face_lines == [line for line in CUBE_OBJ.splitlines() if line.startswith("f ")]


def test_smooth_normals_stay_smooth_and_point_outward(tmp_path: Path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    lines = [f"v {x} {y} {z}" for x, y, z in sphere.vertices]
    lines += ["vn 0 0 1"] * len(sphere.vertices)            # stale normals, one per vertex
    lines += [f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}" for a, b, c in sphere.faces]
    path = tmp_path / "ball.obj"
    path.write_text("\n".join(lines) + "\n")
    source = _load(path)
    output = tmp_path / "ball_big.obj"
    save_mesh(output, source.vertices * np.array([3.0, 1.0, 1.0]), source.faces, source=source, input_path=path)
    normals = np.array([[float(x) for x in line.split()[1:]] for line in output.read_text().splitlines()
                        if line.startswith("vn ")])
    ellipsoid_gradient = sphere.vertices * np.array([3.0, 1.0, 1.0]) / np.array([9.0, 1.0, 1.0])
    ellipsoid_gradient /= np.linalg.norm(ellipsoid_gradient, axis=1, keepdims=True)
    assert np.min((normals * ellipsoid_gradient).sum(axis=1)) > 0.98


def test_obj_in_the_same_folder_references_the_library_without_copying(textured_cube: Path) -> None:
    source = _load(textured_cube)
    output = textured_cube.with_name("cube_big.obj")
    result = save_mesh(output, source.vertices * 2, source.faces, source=source, input_path=textured_cube)
    assert result.extra_files == []
    assert "mtllib cube.mtl" in output.read_text()
    assert sorted(path.name for path in output.parent.iterdir()) == ["cube.mtl", "cube.obj", "cube_big.obj", "skin.png"]


def test_existing_library_beside_the_output_is_not_overwritten(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "cube.mtl").write_text("newmtl Mine\n")
    save_mesh(folder / "cube.obj", source.vertices, source.faces, source=source, input_path=textured_cube)
    assert (folder / "cube.mtl").read_text() == "newmtl Mine\n"


def test_missing_material_library_is_reported_not_fatal(textured_cube: Path, tmp_path: Path, caplog) -> None:
    (textured_cube.parent / "cube.mtl").unlink()
    source = _load(textured_cube)
    output = tmp_path / "cube.obj"
    with caplog.at_level("WARNING", logger="allorules.output.export"):
        result = save_mesh(output, source.vertices, source.faces, source=source, input_path=textured_cube)
    assert any("cube.mtl" in note and "missing" in note for note in result.notes)
    assert any("cube.mtl" in record.getMessage() for record in caplog.records)
    assert "mtllib cube.mtl" in output.read_text()  # still referenced, as the input did
    np.testing.assert_array_equal(_load(output).visual.uv, source.visual.uv)


def test_positions_from_prepared_mesh_keep_the_input_layout(tmp_path: Path) -> None:
    from allorules.mesh.repair import prepare_mesh
    # A ball whose every face corner has its own UV (seams everywhere), as game assets often do.
    sphere = trimesh.creation.icosphere(subdivisions=2)
    corners = sphere.vertices[sphere.faces.reshape(-1)]
    uv = np.column_stack([np.arctan2(corners[:, 1], corners[:, 0]) / (2 * np.pi) + 0.5, corners[:, 2] / 2 + 0.5])
    lines = ["mtllib ball.mtl", "usemtl Fur"] + [f"v {x} {y} {z}" for x, y, z in sphere.vertices]
    lines += [f"vt {u} {v}" for u, v in uv]
    lines += [f"f {a + 1}/{3 * k + 1} {b + 1}/{3 * k + 2} {c + 1}/{3 * k + 3}" for k, (a, b, c) in enumerate(sphere.faces)]
    path = tmp_path / "ball.obj"
    path.write_text("\n".join(lines) + "\n")
    (tmp_path / "ball.mtl").write_text("newmtl Fur\nKd 0.5 0.4 0.3\n")

    prepared = prepare_mesh(path)
    assert len(prepared.vertices) == len(sphere.vertices) < len(prepared.source.vertices)  # seams merged
    moved = prepared.vertices * 1.5
    positions = prepared.source_positions(moved)
    output = tmp_path / "out" / "ball.obj"
    result = save_mesh(output, positions, prepared.source.faces, source=prepared.source, input_path=path)
    assert "UVs" in result.carried
    back = _load(output)
    np.testing.assert_array_equal(back.faces, prepared.source.faces)
    np.testing.assert_array_equal(back.visual.uv, prepared.source.visual.uv)
    np.testing.assert_allclose(back.vertices, prepared.source.vertices * 1.5, atol=1e-9)
    assert (output.parent / "ball.mtl").is_file()


def test_other_layout_is_written_without_uvs_and_says_why(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    box = trimesh.creation.box()
    result = save_mesh(tmp_path / "box.obj", box.vertices, box.faces, source=source, input_path=textured_cube)
    assert any("layout" in note for note in result.notes)
    assert "UVs" not in result.carried
    assert "vt " not in (tmp_path / "box.obj").read_text()


# ------------------------------------------------------------------------------------------
# Other formats


def test_glb_loads_back_with_uvs(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    output = tmp_path / "cube.glb"
    result = save_mesh(output, source.vertices * 3, source.faces, source=source, input_path=textured_cube)
    back = _load(output)
    np.testing.assert_array_equal(back.faces, source.faces)
    np.testing.assert_allclose(back.visual.uv, source.visual.uv, atol=1e-6)  # float32 in glTF
    np.testing.assert_allclose(back.vertices, source.vertices * 3, atol=1e-5)
    assert "UVs" in result.carried


def test_ply_keeps_uvs(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    output = tmp_path / "cube.ply"
    save_mesh(output, source.vertices, source.faces, source=source)
    back = _load(output)
    np.testing.assert_array_equal(back.faces, source.faces)
    np.testing.assert_allclose(back.visual.uv, source.visual.uv, atol=1e-6)


@pytest.mark.parametrize("extension", [".stl", ".off", ".ply", ".obj", ".glb"])
def test_every_format_round_trips_geometry(tmp_path: Path, extension: str) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    vertices = sphere.vertices * 5 + 1
    output = tmp_path / f"sphere{extension}"
    result = save_mesh(output, vertices, sphere.faces)
    assert result.format == extension[1:]
    back = trimesh.load(output, force="mesh")  # processed: STL's unmerged corners merged again
    assert len(back.faces) == len(sphere.faces)
    assert back.is_watertight
    np.testing.assert_allclose(back.volume, trimesh.Trimesh(vertices, sphere.faces).volume, rtol=1e-5)


def test_geometry_only_formats_say_uvs_are_dropped(textured_cube: Path, tmp_path: Path) -> None:
    source = _load(textured_cube)
    result = save_mesh(tmp_path / "cube.stl", source.vertices, source.faces, source=source)
    assert any("UVs" in note for note in result.notes)


# ------------------------------------------------------------------------------------------
# Safety


def test_nan_positions_are_refused_and_nothing_is_written(tmp_path: Path) -> None:
    box = trimesh.creation.box()
    vertices = box.vertices.copy()
    vertices[3, 1] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        save_mesh(tmp_path / "box.obj", vertices, box.faces)
    vertices[3, 1] = np.inf
    with pytest.raises(MeshError, match="NaN or infinite"):
        save_mesh(tmp_path / "box.ply", vertices, box.faces)
    assert list(tmp_path.iterdir()) == []


def test_input_is_never_overwritten_unless_asked(textured_cube: Path) -> None:
    source = _load(textured_cube)
    before = textured_cube.read_bytes()
    with pytest.raises(MeshError, match="input"):
        save_mesh(textured_cube, source.vertices * 2, source.faces, source=source, input_path=textured_cube)
    # also through another spelling of the same path
    other_spelling = textured_cube.parent / ".." / textured_cube.parent.name / textured_cube.name
    with pytest.raises(MeshError, match="input"):
        save_mesh(other_spelling, source.vertices * 2, source.faces, source=source, input_path=textured_cube)
    assert textured_cube.read_bytes() == before
    save_mesh(textured_cube, source.vertices * 2, source.faces, source=source, input_path=textured_cube, overwrite=True)
    np.testing.assert_allclose(_load(textured_cube).vertices, source.vertices * 2)


def test_existing_output_is_refused_unless_overwrite(tmp_path: Path) -> None:
    box = trimesh.creation.box()
    output = tmp_path / "box.off"
    output.write_text("precious")
    with pytest.raises(MeshError, match="already exists"):
        save_mesh(output, box.vertices, box.faces)
    assert output.read_text() == "precious"
    save_mesh(output, box.vertices, box.faces, overwrite=True)
    assert output.read_text().startswith("OFF")


def test_unsupported_extension_is_a_clear_error(tmp_path: Path) -> None:
    box = trimesh.creation.box()
    with pytest.raises(MeshError, match=r"\.obj"):
        save_mesh(tmp_path / "box.fbx", box.vertices, box.faces)


def test_bad_faces_are_refused(tmp_path: Path) -> None:
    box = trimesh.creation.box()
    with pytest.raises(MeshError, match="do not exist"):
        save_mesh(tmp_path / "box.obj", box.vertices, box.faces + 100)


def test_failure_mid_way_leaves_no_partial_file(tmp_path: Path, monkeypatch) -> None:
    box = trimesh.creation.box()
    output = tmp_path / "box.obj"

    def failing_fsync(descriptor: int) -> None:  # the data is in the temporary file by now
        raise OSError("disk full")

    monkeypatch.setattr(files.os, "fsync", failing_fsync)
    with pytest.raises(OutputError, match="disk full"):   # one line for the user, not a traceback
        save_mesh(output, box.vertices, box.faces)
    assert not output.exists()
    assert list(tmp_path.iterdir()) == []


def test_failure_mid_way_keeps_the_previous_file(tmp_path: Path) -> None:
    output = tmp_path / "old.obj"
    output.write_text("old content")

    def half_then_fail(stream) -> None:
        stream.write(b"v 0 0 0\n")
        raise RuntimeError("writer crashed")

    with pytest.raises(RuntimeError):
        atomic_write(output, half_then_fail)
    assert output.read_text() == "old content"
    assert _no_temporaries(tmp_path)


def test_default_output_path_never_names_an_existing_file(tmp_path: Path) -> None:
    source = tmp_path / "horse.obj"
    source.write_text("")
    first = default_output_path(source)
    assert first == tmp_path / "horse_scaled.obj"
    first.write_text("")
    assert default_output_path(source) == tmp_path / "horse_scaled-2.obj"
    assert default_output_path(source, extension=".glb") == tmp_path / "horse_scaled.glb"


def test_vertex_normals_of_a_sphere_point_outward() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3)
    normals = vertex_normals(sphere.vertices * 10 + 3, sphere.faces)
    radial = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    assert np.min((normals * radial).sum(axis=1)) > 0.99
    lonely = vertex_normals(np.vstack([sphere.vertices, [[5.0, 5.0, 5.0]]]), sphere.faces)
    assert np.isfinite(lonely).all()


# ------------------------------------------------------------------------------------------
# Real input


@pytest.mark.shared_meshes
def test_dog_with_missing_material_library_exports_and_says_so(tmp_path: Path) -> None:
    path = SHARED_MESHES / "dog-lowpoly.obj"
    if not path.is_file():
        pytest.skip("shared meshes not available")
    source = _load(path)
    output = tmp_path / "dog.obj"
    result = save_mesh(output, source.vertices * 0.5, source.faces, source=source, input_path=path)
    assert any("dog_reference.mtl" in note for note in result.notes)
    back = _load(output)
    np.testing.assert_array_equal(back.faces, source.faces)
    np.testing.assert_array_equal(back.visual.uv, source.visual.uv)
    assert output.read_text().count("usemtl") == path.read_text().count("usemtl")
    assert os.path.getsize(path) > 0  # input untouched


def test_quads_and_relative_indices_are_kept_verbatim(tmp_path: Path) -> None:
    text = "\n".join([
        "v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0", "v 0 0 1", "v 1 0 1", "v 1 1 1", "v 0 1 1",
        "vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1",
        "vn 0 0 1", "vn 0 0 1", "vn 0 0 1", "vn 0 0 1", "vn 0 0 1", "vn 0 0 1",
        "f 1/1/1 4/4/1 3/3/1 2/2/1",          # z = 0 side, outward -z
        "f -4/1/-5 -3/2/-5 -2/3/-5 -1/4/-5",  # z = 1 side (relative indices), outward +z
        "f 1/1/3 2/2/3 6/3/3 5/4/3",
        "f 4/1/4 8/2/4 7/3/4 3/4/4",
        "f 2/1/5 3/2/5 7/3/5 6/4/5",
        "f 1/1/6 5/2/6 8/3/6 4/4/6",
    ]) + "\n"
    path = tmp_path / "quads.obj"
    path.write_text(text)
    source = _load(path)
    output = tmp_path / "quads_tall.obj"
    save_mesh(output, source.vertices * np.array([1.0, 3.0, 1.0]), source.faces, source=source, input_path=path)
    lines = output.read_text().splitlines()
    assert [line for line in lines if line.startswith("f ")] == [line for line in text.splitlines() if line.startswith("f ")]
    normals = np.array([[float(x) for x in line.split()[1:]] for line in lines if line.startswith("vn ")])
    expected = [[0, 0, -1], [0, 0, 1], [0, -1, 0], [0, 1, 0], [1, 0, 0], [-1, 0, 0]]
    np.testing.assert_allclose(normals, expected, atol=1e-9)
    back = _load(output)
    np.testing.assert_array_equal(back.faces, source.faces)
    np.testing.assert_allclose(back.vertices, source.vertices * np.array([1.0, 3.0, 1.0]))
