"""Tests of allorules.transfer: binding a fine mesh to a working surface and carrying a deformation
and labels back (issue 16 §2). Known answers: identity, uniform scale, rigid motion, a smooth
analytic field whose interpolation error is known, bumps and horns whose height is measurable."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from allorules.mesh.transfer import (
    bind,
    carry_deformation,
    carry_labels,
    carry_values,
    closest_point_weights,
    vertex_similarities,
)
from allorules.mesh.working import make_working_mesh


def _sphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def _bumpy_sphere(subdivisions: int = 5, amplitude: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit sphere with sharp-ish bumps (a product of sines): (vertices, faces, bump height)."""
    vertices, faces = _sphere(subdivisions)
    x, y, z = vertices.T
    height = amplitude * np.sin(7 * x) * np.sin(7 * y) * np.sin(7 * z)
    return vertices * (1.0 + height)[:, None], faces, height


def _field(points: np.ndarray) -> np.ndarray:
    """A smooth deformation: a bend, a twist and a bulge."""
    x, y, z = points.T
    return np.column_stack([x + 0.2 * np.sin(1.3 * y), y + 0.15 * x * z, 1.2 * z + 0.1 * np.cos(2 * x)])


def _stretch(points: np.ndarray) -> np.ndarray:
    return points * np.array([1.6, 1.0, 0.8])


# ------------------------------------------------------------------------------------------
# Binding


def test_binding_reproduces_every_user_vertex() -> None:
    fine, _, _ = _bumpy_sphere(4)
    coarse_vertices, coarse_faces = _sphere(2)
    binding = bind(fine, coarse_vertices, coarse_faces)
    feet = np.einsum("ij,ijk->ik", binding.weights, coarse_vertices[coarse_faces[binding.triangle]])
    np.testing.assert_allclose(feet + binding.offset, fine, atol=1e-14)
    assert np.all(binding.weights >= 0) and np.allclose(binding.weights.sum(axis=1), 1.0)
    # the foot is the closest point: no triangle is nearer (brute force over every triangle)
    corners = coarse_vertices[coarse_faces]
    for point, offset in zip(fine[::50], binding.offset[::50]):
        weights = closest_point_weights(np.repeat(point[None], len(coarse_faces), axis=0), corners)
        nearest = np.linalg.norm(np.einsum("ij,ijk->ik", weights, corners) - point, axis=1).min()
        assert np.linalg.norm(offset) <= nearest + 1e-12


def test_closest_point_weights_in_every_voronoi_region() -> None:
    triangle = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0]])
    points = np.array([[0.5, 0.5, 3.0],     # above the face
                       [-1, -1, 0.2],       # beyond corner a
                       [3, -1, 0],          # beyond corner b
                       [-0.5, 3, 0],        # beyond corner c
                       [1, -1, 0],          # beyond edge ab
                       [-1, 1, 0],          # beyond edge ac
                       [2, 2, -1]])         # beyond edge bc
    expected = np.array([[0.5, 0.5, 0], [0, 0, 0], [2, 0, 0], [0, 2, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    weights = closest_point_weights(points, np.repeat(triangle[None], len(points), axis=0))
    np.testing.assert_allclose(weights @ triangle, expected, atol=1e-15)
    assert np.all(weights >= 0) and np.allclose(weights.sum(axis=1), 1)


# ------------------------------------------------------------------------------------------
# Deformation


def test_identity_returns_the_input_bit_for_bit() -> None:
    fine, _, _ = _bumpy_sphere(4)
    coarse_vertices, coarse_faces = _sphere(2)
    binding = bind(fine, coarse_vertices, coarse_faces)
    out = carry_deformation(binding, coarse_vertices, coarse_vertices.copy(), fine)
    assert np.array_equal(out, fine) and out is not fine


@pytest.mark.parametrize("factor", [1.7, 0.3, 250.0])
def test_uniform_scale_scales_the_detail_exactly(factor: float) -> None:
    fine, _, _ = _bumpy_sphere(5)
    coarse_vertices, coarse_faces = _sphere(2)
    binding = bind(fine, coarse_vertices, coarse_faces)
    out = carry_deformation(binding, coarse_vertices, factor * coarse_vertices)
    np.testing.assert_allclose(out, factor * fine, rtol=0, atol=1e-13 * factor)


def test_rigid_motion_moves_the_detail_rigidly() -> None:
    fine, faces, _ = _bumpy_sphere(4)
    working = make_working_mesh(fine, faces, 2000)
    assert not working.is_source
    binding = bind(fine, working.vertices, working.faces)
    rotation = trimesh.transformations.rotation_matrix(1.1, [1, -2, 0.5])[:3, :3]
    move = lambda points: points @ rotation.T + np.array([3.0, -1.0, 7.0])  # noqa: E731
    out = carry_deformation(binding, working.vertices, move(working.vertices))
    np.testing.assert_allclose(out, move(fine), atol=1e-12)


def test_smooth_deformation_of_a_coarse_proxy_is_reproduced_to_its_sampling_error() -> None:
    """A smooth field applied to a coarse sphere and carried to a fine one: the error is the
    proxy's sampling error (piecewise-linear interpolation, O(h²)), so it falls about 4× with
    every halving of the proxy's edges, and stays below the field's own interpolation error."""
    fine, _ = _sphere(5)
    target = _field(fine)
    errors = []
    for subdivisions in (2, 3, 4):
        coarse_vertices, coarse_faces = _sphere(subdivisions)
        binding = bind(fine, coarse_vertices, coarse_faces)
        out = carry_deformation(binding, coarse_vertices, _field(coarse_vertices))
        errors.append(np.abs(out - target).max())
        # the same field interpolated linearly over the proxy's triangles at the feet, plus the offset unmoved:
        feet = fine - binding.offset
        interpolation = np.abs(carry_values(binding, _field(coarse_vertices)) - _field(feet)).max()
        assert errors[-1] < 3.0 * interpolation + 1e-12
    assert errors[0] / errors[1] > 3.0 and errors[1] / errors[2] > 3.0, errors
    assert errors[-1] < 2e-3


def test_bumps_keep_their_height_when_the_surface_stretches() -> None:
    """Detail lives in the working surface's local frame: after a stretch of the smooth sphere
    the bumps sit on the stretched surface with the same height (× the local isotropic scale)
    along its normal, not squashed or sheared by the stretch."""
    fine, faces, height = _bumpy_sphere(5, amplitude=0.04)
    coarse_vertices, coarse_faces = _sphere(4)
    binding = bind(fine, coarse_vertices, coarse_faces)
    stretched = _stretch(coarse_vertices)
    out = carry_deformation(binding, coarse_vertices, stretched)
    # the smooth part of each user vertex (its foot on the sphere) goes where the stretch takes it
    feet_after = np.einsum("ij,ijk->ik", binding.weights, stretched[coarse_faces[binding.triangle]])
    offset_after = out - feet_after
    similarities = vertex_similarities(coarse_vertices, stretched, coarse_faces)
    scale = np.einsum("ij,ij->i", binding.weights,
                      np.cbrt(np.linalg.det(similarities))[coarse_faces[binding.triangle]])
    # the offset's length is kept up to the local scale (no smoothing, no loss of height; the
    # blend of the corners' nearly equal rotations is a rotation to 1e-3) ...
    np.testing.assert_allclose(np.linalg.norm(offset_after, axis=1),
                               scale * np.linalg.norm(binding.offset, axis=1), rtol=2e-3, atol=1e-12)
    # ... and it points along the stretched surface's normal as it did along the sphere's
    normal_after = trimesh.Trimesh(stretched, coarse_faces, process=False).face_normals[binding.triangle]
    tall = np.abs(height) > 0.02
    along = np.abs(np.einsum("ij,ij->i", offset_after[tall], normal_after[tall])) / np.linalg.norm(offset_after[tall], axis=1)
    assert np.median(along) > 0.99 and along.min() > 0.9
    # a plain stretch of the fine mesh would squash the bumps on the short axis; this keeps them
    squashed = np.linalg.norm(_stretch(fine) - feet_after, axis=1)
    assert np.max(np.abs(np.linalg.norm(offset_after, axis=1) - scale * np.linalg.norm(binding.offset, axis=1))) \
        < 0.1 * np.max(np.abs(squashed - scale * np.linalg.norm(binding.offset, axis=1)))


def _horned_head(subdivisions: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A head (ellipsoid) with two long thin horns, as one closed fine mesh."""
    head = trimesh.creation.icosphere(subdivisions=subdivisions)
    head.vertices *= [1.2, 1.0, 0.9]
    parts = [head]
    for side in (-1, 1):
        horn = trimesh.creation.cone(radius=0.15, height=1.2, sections=48)
        horn = horn.subdivide().subdivide()
        turn = trimesh.transformations.rotation_matrix(side * 0.5, [1, 0, 0])
        horn.apply_transform(turn)
        horn.apply_translation([0.3, side * 0.35, 0.7])
        parts.append(horn)
    union = trimesh.boolean.union(parts) if trimesh.boolean.engines_available else None
    mesh = union if union is not None else trimesh.util.concatenate(parts)
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def test_a_horned_head_keeps_its_horns_under_scale_and_a_turn() -> None:
    """The horns (sharp tips, far off a coarse working surface) scale exactly with a uniform
    scale and turn rigidly with the head: their tips are where the same similarity takes them."""
    vertices, faces = _horned_head()
    working = make_working_mesh(vertices, faces, 2000) if len(vertices) > 2000 else None
    working_vertices, working_faces = (working.vertices, working.faces) if working else (vertices, faces)
    binding = bind(vertices, working_vertices, working_faces)
    tips = np.argsort(vertices[:, 2])[-5:]
    out = carry_deformation(binding, working_vertices, 2.5 * working_vertices)
    np.testing.assert_allclose(out, 2.5 * vertices, atol=1e-12)
    rotation = trimesh.transformations.rotation_matrix(0.8, [0, 1, 1])[:3, :3]
    out = carry_deformation(binding, working_vertices, 1.3 * working_vertices @ rotation.T)
    np.testing.assert_allclose(out[tips], 1.3 * vertices[tips] @ rotation.T, atol=1e-9)


def test_neighbouring_vertices_do_not_crack_apart() -> None:
    """Under a strong smooth deformation, fine edges whose ends sit on different working triangles
    stretch like the edges inside one triangle: the carried frame is continuous across the
    working triangles' edges (a per-triangle frame would tear them apart)."""
    fine, faces, _ = _bumpy_sphere(5)
    coarse_vertices, coarse_faces = _sphere(3)
    binding = bind(fine, coarse_vertices, coarse_faces)
    out = carry_deformation(binding, coarse_vertices, _field(coarse_vertices))
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    before = np.linalg.norm(fine[edges[:, 0]] - fine[edges[:, 1]], axis=1)
    strain = np.linalg.norm(out[edges[:, 0]] - out[edges[:, 1]], axis=1) / before
    crossing = binding.triangle[edges[:, 0]] != binding.triangle[edges[:, 1]]
    assert 0.2 < crossing.mean() < 0.8
    for quantile in (50, 99, 100):
        assert np.percentile(strain[crossing], quantile) < 1.05 * np.percentile(strain[~crossing], quantile)
        assert np.percentile(strain[crossing], 100 - quantile) > 0.95 * np.percentile(strain[~crossing], 100 - quantile)


# ------------------------------------------------------------------------------------------
# Labels


def test_labels_follow_the_corners_with_the_most_weight() -> None:
    fine, _, _ = _bumpy_sphere(4)
    coarse_vertices, coarse_faces = _sphere(2)
    coarse_labels = (coarse_vertices[:, 2] > 0).astype(int) + 2 * (coarse_vertices[:, 0] > 0.5)
    binding = bind(fine, coarse_vertices, coarse_faces)
    labels = carry_labels(binding, coarse_labels)
    assert labels.shape == (len(fine),)
    # every fine vertex has the label of one of its triangle's corners, and away from the
    # label boundaries the label of the region it lies in
    corners = coarse_faces[binding.triangle]
    assert np.all((coarse_labels[corners] == labels[:, None]).any(axis=1))
    inside = np.all(coarse_labels[corners] == coarse_labels[corners][:, :1], axis=1)
    np.testing.assert_array_equal(labels[inside], coarse_labels[corners[inside, 0]])
    assert inside.mean() > 0.7
    # where two corners share a label their weights add: the boundary crosses the triangle half-way
    weights = binding.weights
    for row in np.flatnonzero(~inside)[:200]:
        support = {label: weights[row][coarse_labels[corners[row]] == label].sum() for label in set(coarse_labels[corners[row]])}
        assert support[labels[row]] == max(support.values())


# ------------------------------------------------------------------------------------------
# The user's file: UVs, face order and materials


def _uv_mapped_obj(folder: Path) -> Path:
    """A UV-mapped bumpy ball exported as an artist's OBJ: seams (each face corner its own UV),
    two materials in groups, normals, a material library."""
    vertices, faces, _ = _bumpy_sphere(4)
    corners = vertices[faces.reshape(-1)]
    uv = np.column_stack([np.arctan2(corners[:, 1], corners[:, 0]) / (2 * np.pi) + 0.5, corners[:, 2] / 2.2 + 0.5])
    lines = ["# ball", "mtllib ball.mtl", "o Ball"] + [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    normals = trimesh.Trimesh(vertices, faces, process=False).vertex_normals
    lines += [f"vn {a:.6f} {b:.6f} {c:.6f}" for a, b, c in normals]
    half = len(faces) // 2
    for k, (a, b, c) in enumerate(faces):
        if k == 0:
            lines += ["g skin", "usemtl Fur", "s 1"]
        if k == half:
            lines += ["g belly", "usemtl Belly"]
        lines.append(f"f {a + 1}/{3 * k + 1}/{a + 1} {b + 1}/{3 * k + 2}/{b + 1} {c + 1}/{3 * k + 3}/{c + 1}")
    path = folder / "ball.obj"
    path.write_text("\n".join(lines) + "\n")
    (folder / "ball.mtl").write_text("newmtl Fur\nKd 0.5 0.4 0.3\nnewmtl Belly\nKd 0.9 0.8 0.7\n")
    return path


def test_uvs_face_order_and_materials_survive_bit_for_bit(tmp_path: Path) -> None:
    from allorules.mesh.repair import prepare_mesh
    from allorules.output.export import save_mesh

    source = _uv_mapped_obj(tmp_path)
    prepared = prepare_mesh(source)
    working = make_working_mesh(prepared.vertices, prepared.faces, 2000)
    assert not working.is_source and len(working.vertices) < 0.8 * len(prepared.vertices)
    binding = bind(prepared.vertices, working.vertices, working.faces)
    body_after = carry_deformation(binding, working.vertices, _field(working.vertices))
    positions = prepared.source_positions(body_after)
    output = tmp_path / "out" / "ball.obj"
    result = save_mesh(output, positions, np.asarray(prepared.source.faces), source=prepared.source, input_path=source)
    assert "UVs" in result.carried
    before, after = source.read_text().splitlines(), output.read_text().splitlines()
    kept = lambda lines: [line for line in lines if not line.startswith(("v ", "vn ", "#"))]  # noqa: E731
    assert kept(after) == kept(before)           # faces (order, corners), UVs, groups, materials: verbatim
    assert sum(line.startswith("v ") for line in after) == sum(line.startswith("v ") for line in before)
    back = trimesh.load(output, force="mesh", process=False)
    np.testing.assert_array_equal(back.faces, prepared.source.faces)
    np.testing.assert_array_equal(back.visual.uv, prepared.source.visual.uv)
    np.testing.assert_allclose(back.vertices, positions, atol=1e-7)
    # and the identity edit writes the input's positions back
    same = carry_deformation(binding, working.vertices, working.vertices.copy(), prepared.vertices)
    np.testing.assert_array_equal(prepared.source_positions(same), np.asarray(prepared.source.vertices))
