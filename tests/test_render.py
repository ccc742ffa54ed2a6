"""Tests of allorules.output.render: pictures exist, have the asked size, show what they should."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from matplotlib.image import imread

from allorules.body import Frame
from allorules.output.render import (
    REGION_PALETTE,
    _visible,
    camera_for,
    make_shot,
    plot_spectrum,
    region_color,
    region_colors,
    region_legend,
    render_closeups,
    render_comparison,
    render_gallery,
    render_views,
    resolve_frame,
)

SHARED_MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


def _image(path: Path) -> np.ndarray:
    image = imread(path)
    assert image.dtype == np.float32
    return image[:, :, :3]


def _ink(image: np.ndarray) -> np.ndarray:
    """Pixels that are clearly not white background."""
    return image.min(axis=2) < 0.9


def _without_lines(mask: np.ndarray) -> np.ndarray:
    """The mask without (ground) lines: rows inked across more than 90% of the width."""
    mask = mask.copy()
    mask[mask.sum(axis=1) > 0.9 * mask.shape[1]] = False
    return mask


def _above_ground(image: np.ndarray) -> np.ndarray:
    """The part of a picture above its ground line (the first row inked across the width)."""
    lines = np.flatnonzero(_ink(image).sum(axis=1) > 0.9 * image.shape[1])
    return image[: lines[0]]


def _ink_box(mask: np.ndarray) -> tuple[int, int]:
    """(width, height) in pixels of the inked area."""
    rows, columns = np.nonzero(mask)
    return columns.max() - columns.min() + 1, rows.max() - rows.min() + 1


def _long_box(length_axis: int = 0, length: float = 4.0):
    extents = np.ones(3)
    extents[length_axis] = length
    return trimesh.creation.box(extents=extents)


def _animal_like(forward: np.ndarray, up: np.ndarray) -> trimesh.Trimesh:
    """A long body with a raised 'head' at the +forward end, in the given frame."""
    body = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
    head = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    head.apply_translation((2.5, 1.5, 0.0))
    mesh = trimesh.util.concatenate([body, head])
    forward = forward / np.linalg.norm(forward)
    up = up / np.linalg.norm(up)
    rotation = np.column_stack([forward, up, np.cross(forward, up)])  # model x,y,z -> world
    mesh.vertices = mesh.vertices @ rotation.T
    return mesh


# ------------------------------------------------------------------------------------------
# render_views


def test_side_view_png_has_requested_size_and_is_not_blank(tmp_path: Path) -> None:
    box = _long_box()
    path = render_views(box.vertices, box.faces, path=tmp_path / "box.png", size=(400, 300))
    image = _image(path)
    assert image.shape[:2] == (300, 400)
    assert image.var() > 1e-3
    width, height = _ink_box(_ink(image))
    assert width > 2.5 * height  # a 4×1×1 box seen from the side is long and low


def test_default_frame_takes_the_longer_horizontal_axis_as_forward(tmp_path: Path) -> None:
    box = _long_box(length_axis=2)  # long along Z, as most of the shared meshes
    up, forward, lateral = resolve_frame(box.vertices)
    np.testing.assert_allclose(up, [0, 1, 0])
    np.testing.assert_allclose(forward, [0, 0, 1])
    np.testing.assert_allclose(lateral, np.cross(forward, up))
    path = render_views(box.vertices, box.faces, path=tmp_path / "z.png", size=(400, 300))
    width, height = _ink_box(_ink(_image(path)))
    assert width > 2.5 * height


def test_side_view_puts_the_head_to_the_right_in_any_orientation(tmp_path: Path) -> None:
    rotation = trimesh.transformations.random_rotation_matrix(np.random.default_rng(3).random(3))[:3, :3]
    for number, (forward, up) in enumerate([
        (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])),
        (np.array([0, 0, -1.0]), np.array([0, 1.0, 0])),
        (rotation[:, 0], rotation[:, 1]),        # arbitrary orientation, frame given
    ]):
        mesh = _animal_like(forward, up)
        path = render_views(mesh.vertices, mesh.faces, path=tmp_path / f"a{number}.png",
                            frame=Frame(up=up, forward=forward), size=(400, 300))
        ink = _ink(_image(path))
        rows, columns = np.nonzero(ink)
        top = rows < rows.min() + 0.3 * (rows.max() - rows.min())  # the raised head is the top
        middle = (columns.min() + columns.max()) / 2
        assert columns[top].mean() > middle, f"head not on the right for frame {number}"


def test_frame_with_reversed_forward_flips_the_picture(tmp_path: Path) -> None:
    mesh = _animal_like(np.array([1.0, 0, 0]), np.array([0, 1.0, 0]))
    path = render_views(mesh.vertices, mesh.faces, path=tmp_path / "flip.png",
                        frame=Frame(up=np.array([0, 1.0, 0]), forward=np.array([-1.0, 0, 0])), size=(400, 300))
    rows, columns = np.nonzero(_ink(_image(path)))
    top = rows < rows.min() + 0.3 * (rows.max() - rows.min())
    assert columns[top].mean() < (columns.min() + columns.max()) / 2


def test_every_view_renders_and_views_are_side_by_side(tmp_path: Path) -> None:
    box = _long_box()
    path = render_views(box.vertices, box.faces, path=tmp_path / "all.png",
                        views=("side", "three-quarter", "front", "top"), size=(800, 200), title="box")
    image = _image(path)
    assert image.shape[:2] == (200, 800)
    for quarter in range(4):
        panel = image[:, quarter * 200:(quarter + 1) * 200]
        assert _ink(panel).sum() > 500, f"panel {quarter} is empty"


def test_front_view_of_a_long_box_is_square(tmp_path: Path) -> None:
    box = _long_box()
    camera = camera_for("front", *resolve_frame(box.vertices))
    shot = make_shot(box.vertices, box.faces, camera)
    xmin, xmax, ymin, ymax = shot.bounds
    assert xmax - xmin == pytest.approx(1.0) and ymax - ymin == pytest.approx(1.0)
    top = make_shot(box.vertices, box.faces, camera_for("top", *resolve_frame(box.vertices)))
    assert top.bounds[1] - top.bounds[0] == pytest.approx(4.0)  # head to the right in the top view too


def test_nearer_faces_are_drawn_last_and_shading_is_finite() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    camera = camera_for("side", *resolve_frame(sphere.vertices))
    shot = make_shot(sphere.vertices, sphere.faces, camera)
    depth = shot.depth[shot.faces].mean(axis=1)
    assert np.all(np.diff(depth) >= 0)
    assert np.isfinite(shot.colors).all() and shot.colors.min() >= 0 and shot.colors.max() <= 1
    # the lit side is brighter than the side facing away from the key light (upper left)
    centres = shot.triangles.mean(axis=1)
    facing = depth > 0.5
    upper_left = facing & (centres[:, 0] < -0.3) & (centres[:, 1] > 0.3)
    lower_right = facing & (centres[:, 0] > 0.3) & (centres[:, 1] < -0.3)
    assert shot.colors[upper_left, :3].mean() > shot.colors[lower_right, :3].mean() + 0.1


def test_non_finite_vertices_are_refused(tmp_path: Path) -> None:
    box = _long_box()
    vertices = box.vertices.copy()
    vertices[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        render_views(vertices, box.faces, path=tmp_path / "nan.png")
    assert not (tmp_path / "nan.png").exists()


def test_unknown_view_is_refused(tmp_path: Path) -> None:
    box = _long_box()
    with pytest.raises(ValueError, match="three-quarter"):
        render_views(box.vertices, box.faces, path=tmp_path / "x.png", views=("back",))


# ------------------------------------------------------------------------------------------
# Regions and annotations


def test_region_colors_follow_the_fixed_palette() -> None:
    names = ("head", "forelimbs", "antlers")
    labels = np.array([0, 1, 2, -1, 7])
    colors = region_colors(labels, names)
    assert colors.shape == (5, 4)
    np.testing.assert_allclose(colors[0], region_color("head"))
    np.testing.assert_allclose(colors[0][:3], [0xD5 / 255, 0x5E / 255, 0x00 / 255])
    assert region_color("antlers") == region_color("antlers")  # stable for unknown names
    np.testing.assert_allclose(colors[3], colors[4])  # unlabelled and out of range: the same grey
    assert len({tuple(region_color(name)) for name in REGION_PALETTE}) == len(REGION_PALETTE)
    legend = region_legend(labels[:4], names)
    assert list(legend) == ["head", "forelimbs", "antlers", "unlabelled"]


def _hue_pixels(image: np.ndarray, rgb: tuple[float, float, float]) -> int:
    """Pixels whose chromaticity matches ``rgb`` (shading darkens but keeps the hue)."""
    target = np.asarray(rgb) / max(np.sum(rgb), 1e-9)
    total = image.sum(axis=2, keepdims=True)
    chroma = image / np.maximum(total, 1e-9)
    return int((np.abs(chroma - target).max(axis=2) < 0.04)[total[:, :, 0] > 0.3].sum())


def test_region_colours_appear_with_a_legend(tmp_path: Path) -> None:
    box = trimesh.creation.box(extents=(4.0, 1.0, 1.0)).subdivide().subdivide()
    names = ("head", "forelimbs")
    labels = np.where(box.vertices[:, 0] > 0, 0, 1)
    path = render_views(box.vertices, box.faces, path=tmp_path / "regions.png", size=(500, 300),
                        vertex_colors=region_colors(labels, names), legend=region_legend(labels, names))
    image = _image(path)
    head = _hue_pixels(image, region_color("head")[:3])
    forelimbs = _hue_pixels(image, region_color("forelimbs")[:3])
    assert head > 2000 and forelimbs > 2000
    # head (+x = forward) is on the right half of the picture
    red = np.abs(image - np.asarray(region_color("head")[:3])).max(axis=2) < 0.25
    assert np.nonzero(red)[1].mean() > 250


def test_annotations_are_drawn_and_hidden_ones_detected(tmp_path: Path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3)
    up, forward, lateral = resolve_frame(sphere.vertices)
    camera = camera_for("side", up, forward, lateral)
    shot = make_shot(sphere.vertices, sphere.faces, camera)
    near, far = lateral * 1.0, -lateral * 1.0  # side view looks from +lateral
    project = lambda point: np.array([point @ camera.right, point @ camera.up])  # noqa: E731
    assert _visible(shot, project(near), float(near @ camera.toward_viewer), 0.02)
    assert not _visible(shot, project(far), float(far @ camera.toward_viewer), 0.02)
    plain = render_views(sphere.vertices, sphere.faces, path=tmp_path / "plain.png", size=(300, 300))
    labelled = render_views(sphere.vertices, sphere.faces, path=tmp_path / "labels.png", size=(300, 300),
                            annotations=[(near, "1"), (far, "2"), (up * 1.0, "patch 17")])
    assert np.abs(_image(plain) - _image(labelled)).max() > 0.3  # the labels changed pixels


# ------------------------------------------------------------------------------------------
# Comparison and gallery


def _blobs(image: np.ndarray) -> list[tuple[int, int]]:
    """(width, height) of each separate inked column range, left to right (ignoring thin lines)."""
    ink = _without_lines(_ink(image))
    columns = ink.sum(axis=0) > 0
    blobs, start = [], None
    for x, on in enumerate(np.append(columns, False)):
        if on and start is None:
            start = x
        elif not on and start is not None:
            rows = np.nonzero(ink[:, start:x].any(axis=1))[0]
            blobs.append((x - start, rows.max() - rows.min() + 1))
            start = None
    return [blob for blob in blobs if blob[0] > 5]


def test_comparison_true_scale_and_normalised(tmp_path: Path) -> None:
    box = _long_box()
    meshes = [(box.vertices, box.faces, "before"), (box.vertices * 2.0 + 10.0, box.faces, "after")]
    true = _image(render_comparison(meshes, path=tmp_path / "true.png", normalise_size=False,
                                    size=(900, 400)))
    assert true.shape[:2] == (400, 900)
    small, big = _blobs(_above_ground(true))
    assert big[1] / small[1] == pytest.approx(2.0, rel=0.1)
    assert big[0] / small[0] == pytest.approx(2.0, rel=0.1)
    normalised = _image(render_comparison(meshes, path=tmp_path / "normalised.png", normalise_size=True,
                                          size=(900, 400)))
    first, second = _blobs(_above_ground(normalised))
    assert first[1] == pytest.approx(second[1], abs=2)


def test_comparison_on_a_common_ground_line(tmp_path: Path) -> None:
    box = _long_box()
    lifted = box.vertices + np.array([0.0, 5.0, 0.0])  # floating in the air: still grounded
    image = _image(render_comparison([(box.vertices, box.faces, "a"), (lifted * 0.5, box.faces, "b")],
                                     path=tmp_path / "ground.png", normalise_size=False, size=(800, 400)))
    ink = _without_lines(_ink(_above_ground(image)))
    left, right = ink[:, :400], ink[:, 400:]
    assert abs(np.nonzero(left)[0].max() - np.nonzero(right)[0].max()) <= 2  # same lowest row


def test_comparison_on_a_shared_ground_shows_a_floating_mesh_floating(tmp_path: Path) -> None:
    box = _long_box()
    lifted = box.vertices + np.array([0.0, 0.5, 0.0])   # half a box's height above the first one's floor
    meshes = [(box.vertices, box.faces, "a"), (lifted, box.faces, "b")]
    image = _image(render_comparison(meshes, path=tmp_path / "scene.png", normalise_size=False, size=(800, 400),
                                     shared_ground=True))
    ink = _without_lines(_ink(_above_ground(image)))          # without the labels under the ground line
    left, right = ink[:, :400], ink[:, 400:]
    left_bottom, right_bottom = np.nonzero(left)[0].max(), np.nonzero(right)[0].max()
    box_height = _ink_box(left)[1]
    assert right_bottom < left_bottom - 0.35 * box_height     # drawn floating, by about half its height
    with pytest.raises(ValueError, match="normalise_size=False"):
        render_comparison(meshes, path=tmp_path / "no.png", normalise_size=True, shared_ground=True)


def _body_and_knob(knob_scale: float = 1.0):
    """A big sphere with a small one far in front of it: the knob is the part a close-up frames."""
    body = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    knob = trimesh.creation.icosphere(subdivisions=3, radius=0.15 * knob_scale)
    knob.apply_translation([3.0, 0.0, 0.0])
    both = trimesh.util.concatenate([body, knob])
    focus = np.zeros(len(both.vertices), dtype=bool)
    focus[len(body.vertices):] = True
    return np.asarray(both.vertices), np.asarray(both.faces), focus


def test_closeups_frame_the_part_at_the_same_size_in_every_panel(tmp_path: Path) -> None:
    vertices, faces, focus = _body_and_knob()
    bigger, _, _ = _body_and_knob(knob_scale=2.0)
    frame = Frame(up=np.array([0.0, 1.0, 0.0]), forward=np.array([1.0, 0.0, 0.0]))
    image = _image(render_closeups([(vertices, faces, "knob"), (bigger, faces, "knob x2")], focus,
                                   path=tmp_path / "closeups.png", frame=frame, views=("side",), cell_size=(300, 240)))
    assert image.shape[:2] == (24 + 240, 600)
    panels = [image[24:, :300], image[24:, 300:]]
    sizes = [_ink_box(_ink(panel)) for panel in panels]
    for width, height in sizes:
        assert height > 0.6 * 240                              # the small knob fills its panel
    assert sizes[1][1] == pytest.approx(sizes[0][1], rel=0.05)  # shape, not size: both drawn alike
    with pytest.raises(ValueError, match="same vertices"):
        render_closeups([(vertices[:-1], faces[:1], "short")], focus, path=tmp_path / "no.png")
    with pytest.raises(ValueError, match="no vertex"):
        render_closeups([(vertices, faces, "knob")], np.zeros(len(vertices), bool), path=tmp_path / "no.png")


def test_gallery_grid_with_missing_cell(tmp_path: Path) -> None:
    box = _long_box()
    ball = trimesh.creation.icosphere(subdivisions=2)
    grid = {
        "box": {"minified": (box.vertices * 0.8, box.faces), "original": (box.vertices, box.faces),
                "magnified": (box.vertices * 1.25, box.faces)},
        "ball": {"original": (ball.vertices, ball.faces),
                 "magnified": (ball.vertices * 2, ball.faces, np.tile([0.0, 0.45, 0.7], (len(ball.vertices), 1)))},
    }
    path = render_gallery(grid, path=tmp_path / "gallery.png", title="gallery", cell_size=(200, 150))
    image = _image(path)
    assert image.shape[:2] == (28 + 30 + 3 * 150, 90 + 2 * 200)
    assert image.var() > 1e-3
    true = _image(render_gallery(grid, path=tmp_path / "true.png", normalise_size=False, cell_size=(200, 150)))
    top = 28
    cell = lambda row, column: true[top + row * 150: top + (row + 1) * 150, 90 + column * 200: 90 + (column + 1) * 200]  # noqa: E731
    widths = [_ink_box(_without_lines(_ink(cell(row, 0))))[0] for row in range(3)]
    assert widths[0] < widths[1] < widths[2]  # true scale inside a column
    normalised = _image(path)
    cell = lambda row, column: normalised[58 + row * 150: 58 + (row + 1) * 150, 90 + column * 200: 90 + (column + 1) * 200]  # noqa: E731
    widths = [_ink_box(_without_lines(_ink(cell(row, 0))))[0] for row in range(3)]
    assert max(widths) - min(widths) <= 2


# ------------------------------------------------------------------------------------------
# Spectrum plot


def test_plot_spectrum(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    eigenvalues = np.r_[0.0, np.sort(rng.uniform(0.1, 500, 199))]
    coefficients = rng.normal(size=(200, 3)) * eigenvalues[:, None].clip(0.1) ** -1.2
    path = plot_spectrum(eigenvalues, coefficients, -1.2, 0.0, -0.97, path=tmp_path / "spectrum.png",
                         title="test", size=(600, 500))
    image = _image(path)
    assert image.shape[:2] == (500, 600)
    red = (image[:, :, 0] > 0.7) & (image[:, :, 1] < 0.4) & (image[:, :, 2] < 0.4)
    assert red.sum() > 200  # the red crosses are there
    with pytest.raises(ValueError):
        plot_spectrum(eigenvalues, coefficients[:10], -1.2, 0.0, -0.97, path=tmp_path / "bad.png")


# ------------------------------------------------------------------------------------------
# Real and generated animals


@pytest.mark.slow
def test_generated_horse_renders_with_regions(tmp_path: Path) -> None:
    from allorules.mesh import quadruped
    horse = quadruped.generate_quadruped("horse", vertices=3000)
    body = horse.body()
    path = render_views(horse.vertices, horse.faces, path=tmp_path / "horse.png", views=("side", "three-quarter"),
                        frame=body.frame, vertex_colors=region_colors(horse.labels, horse.region_names),
                        legend=region_legend(horse.labels, horse.region_names), size=(800, 400))
    image = _image(path)
    for name in ("head", "forelimbs", "hindlimbs"):
        if name in horse.region_names:
            assert _hue_pixels(image, region_color(name)[:3]) > 100, name


@pytest.mark.shared_meshes
def test_real_horse_side_view(tmp_path: Path) -> None:
    path = SHARED_MESHES / "horse.obj"
    if not path.is_file():
        pytest.skip("shared meshes not available")
    mesh = trimesh.load(path, force="mesh", process=False)
    image = _image(render_views(mesh.vertices, mesh.faces, path=tmp_path / "horse.png", size=(600, 400)))
    width, height = _ink_box(_ink(image))
    assert width > height  # a horse from the side


# ------------------------------------------------------------------------------------------
# HTML report (allorules.output.html)


def test_html_report_is_self_contained(tmp_path: Path) -> None:
    import base64
    import re

    from allorules.output.html import Table, write_html_report

    box = _long_box()
    picture = render_views(box.vertices, box.faces, path=tmp_path / "side_view.png", size=(200, 150))
    report = write_html_report(
        tmp_path / "report.html",
        title="Horse <scaled>",
        summary={"mass ratio": 2.0, "steps": 7, "converged": True, "mesh": "horse.obj"},
        tables=[
            Table("Rules", ["rule", "target", "achieved"], [["foreleg length", 0.36, 0.3581]]),
            {"title": "Regions", "rows": [{"region": "head", "vertices": 812}]},
            [{"quantity": "mass", "value": float("nan")}],
        ],
        images=[picture, (tmp_path / "gone.png", "deleted picture")],
    )
    text = report.read_text()
    assert "Horse &lt;scaled&gt;" in text and "<scaled>" not in text  # escaped
    assert "foreleg length" in text and "0.3581" in text and "812" in text and "Regions" in text
    assert "picture missing" in text  # named, not fatal
    assert not re.search(r"(src|href)=\"(http|//)", text)  # nothing fetched from the network
    embedded = re.search(r'src="data:image/png;base64,([^"]+)"', text)
    assert embedded and base64.b64decode(embedded.group(1)) == picture.read_bytes()
    picture.unlink()
    assert "data:image/png;base64" in report.read_text()  # still complete without the file
    assert not any(name.name.endswith(".tmp") for name in tmp_path.iterdir())


def test_html_report_rejects_unknown_table_shapes(tmp_path: Path) -> None:
    from allorules.output.html import write_html_report

    with pytest.raises(TypeError, match="table 1"):
        write_html_report(tmp_path / "r.html", title="t", summary={}, tables=[42])
    assert not (tmp_path / "r.html").exists()


def test_empty_or_broken_faces_are_refused(tmp_path: Path) -> None:
    box = _long_box()
    with pytest.raises(ValueError, match="nothing to draw"):
        render_views(box.vertices, np.zeros((0, 3), dtype=int), path=tmp_path / "empty.png")
    with pytest.raises(ValueError, match="do not exist"):
        render_views(box.vertices, box.faces + 50, path=tmp_path / "broken.png")
