"""The generated quadruped: closed one-piece mesh, vertex count, labels, and truth that checks out."""
from __future__ import annotations

import dataclasses
import functools
import json
import math

import numpy as np
import pytest
import scipy.sparse as sparse
import trimesh

from allorules.body import UNLABELLED, Body
from allorules.cli import main
from allorules.errors import AllorulesError
from allorules.mesh.quadruped import (
    LIMB_REGIONS,
    PRESETS,
    REGION_NAMES,
    HalfSpace,
    QuadrupedParameters,
    _closed_surface_problem,
    _layout,
    clipped_volume,
    generate_quadruped,
)


@functools.lru_cache(maxsize=None)
def animal(preset: str, vertices: int, seed: int = 0):
    return generate_quadruped(preset, vertices, seed=seed)


def region_components(faces: np.ndarray, mask: np.ndarray) -> int:
    """Connected components of the vertices in ``mask`` along mesh edges between them."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = edges[mask[edges[:, 0]] & mask[edges[:, 1]]]
    n = len(mask)
    graph = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, component = sparse.csgraph.connected_components(graph, directed=False)
    return len(np.unique(component[mask]))


# ------------------------------------------------------------------------------ the mesh

@pytest.mark.parametrize("vertices", [2000, 8000])
@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_mesh_is_closed_manifold_outward_and_one_piece(preset, vertices):
    generated = animal(preset, vertices)
    mesh = generated.to_trimesh()
    assert mesh.is_watertight                      # every edge in exactly two faces
    assert mesh.is_winding_consistent
    assert mesh.volume > 0                         # outward
    assert len(mesh.split(only_watertight=False)) == 1
    assert mesh.euler_number == 2                  # a sphere topologically: no handles
    assert len(np.unique(np.sort(generated.faces, axis=1), axis=0)) == len(generated.faces)
    areas = mesh.area_faces
    assert areas.min() > 1e-4 * areas.mean()       # no degenerate triangles
    assert np.degrees(mesh.face_angles.min()) > 0.5
    assert np.isfinite(generated.vertices).all()
    assert abs(generated.vertices[:, 1].min()) < 0.02 * generated.truth.height   # feet on y ≈ 0


@pytest.mark.parametrize("vertices", [1000, 8000, pytest.param(50000, marks=pytest.mark.slow)])
def test_vertex_count_is_about_the_request(vertices):
    got = len(animal("horse", vertices).vertices)
    assert 0.8 * vertices <= got <= 1.2 * vertices


def test_vertex_count_for_other_presets_at_low_counts():
    for preset in ("giraffe", "elephant", "dog"):
        got = len(animal(preset, 2000).vertices)
        assert 1600 <= got <= 2400, preset


def test_generation_is_deterministic_and_seed_varies_it():
    first = generate_quadruped("dog", 1000, seed=3)
    again = generate_quadruped("dog", 1000, seed=3)
    np.testing.assert_array_equal(first.vertices, again.vertices)
    np.testing.assert_array_equal(first.faces, again.faces)
    np.testing.assert_array_equal(first.labels, again.labels)
    assert first.truth.as_dict() == again.truth.as_dict()
    other = generate_quadruped("dog", 1000, seed=4)
    assert other.parameters != first.parameters
    assert generate_quadruped("dog", 1000, seed=0).parameters == PRESETS["dog"]


def scaled_parameters(preset: str, factor: float) -> dict[str, float]:
    return {f.name: factor * getattr(PRESETS[preset], f.name) for f in dataclasses.fields(QuadrupedParameters)
            if not f.name.endswith(("_angle", "_offset"))}


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_seeded_variants_are_valid_animals(preset):
    generated = generate_quadruped(preset, 2000, seed=11)
    assert generated.parameters != PRESETS[preset]
    assert _closed_surface_problem(generated.vertices, generated.faces) is None
    for index, name in enumerate(REGION_NAMES):
        expected = 2 if name in LIMB_REGIONS else 1
        assert region_components(generated.faces, generated.labels == index) == expected, name
    truth = generated.truth
    assert sum(truth.region_volume.values()) == pytest.approx(truth.body_volume, rel=5e-3)


def test_result_is_exactly_equivariant_under_power_of_two_scaling():
    # scaling by 8 is exact in floating point, so any absolute threshold would show up here
    small = animal("dog", 1500)
    big = generate_quadruped("dog", 1500, **scaled_parameters("dog", 8.0))
    np.testing.assert_array_equal(big.faces, small.faces)
    np.testing.assert_array_equal(big.labels, small.labels)
    np.testing.assert_array_equal(big.vertices, 8 * small.vertices)
    assert big.truth.body_volume == pytest.approx(512 * small.truth.body_volume, rel=1e-12)
    assert big.truth.leg_radius["forelimbs"] == pytest.approx(8 * small.truth.leg_radius["forelimbs"], rel=1e-12)


def test_result_does_not_depend_on_absolute_size():
    small = animal("dog", 1500)
    big = generate_quadruped("dog", 1500, **scaled_parameters("dog", 10.0))
    # the same grid in units of the animal, so the same mesh up to rounding in edge-collapse ties
    # (mirror-image edges of equal length); well-resolved quantities agree closely
    assert len(big.vertices) == pytest.approx(len(small.vertices), rel=0.01)
    assert big.truth.body_volume == pytest.approx(1000 * small.truth.body_volume, rel=2e-3)
    assert big.truth.chest_girth == pytest.approx(10 * small.truth.chest_girth, rel=2e-3)
    for region in LIMB_REGIONS:
        assert big.truth.leg_length[region] == pytest.approx(10 * small.truth.leg_length[region], rel=2e-3)
    for region in REGION_NAMES:
        assert big.truth.region_volume[region] == pytest.approx(
            1000 * small.truth.region_volume[region], abs=2e-3 * 1000 * small.truth.body_volume)


def test_overrides_change_the_shape_and_bad_input_is_refused():
    longer = generate_quadruped("horse", 1500, neck_length=0.9)
    assert longer.truth.neck_length == pytest.approx(0.9)
    assert longer.parameters.neck_length == 0.9
    with pytest.raises(AllorulesError, match="unknown preset"):
        generate_quadruped("unicorn")
    with pytest.raises(AllorulesError, match="unknown quadruped parameter"):
        generate_quadruped("horse", 1500, wings=2.0)
    with pytest.raises(AllorulesError, match="vertex count"):
        generate_quadruped("horse", 10)
    with pytest.raises(AllorulesError, match="leg_spacing"):
        generate_quadruped("horse", 1500, leg_spacing=2.0)
    with pytest.raises(AllorulesError, match="tail_angle"):
        generate_quadruped("horse", 1500, tail_angle=88.0)
    with pytest.raises(AllorulesError, match="positive"):
        generate_quadruped("horse", 1500, neck_length=-1.0)


# ------------------------------------------------------------------------------ labels

@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_labels_cover_every_vertex_and_every_region_is_one_patch(preset):
    generated = animal(preset, 2000)
    assert generated.region_names == REGION_NAMES
    assert (generated.labels != UNLABELLED).all()
    assert set(np.unique(generated.labels)) == set(range(len(REGION_NAMES)))
    for index, name in enumerate(REGION_NAMES):
        expected = 2 if name in LIMB_REGIONS else 1
        assert region_components(generated.faces, generated.labels == index) == expected, name


def test_labels_follow_anatomy():
    generated = animal("horse", 2000)
    v, labels = generated.vertices, generated.labels
    centroid = {name: v[labels == i].mean(axis=0) for i, name in enumerate(REGION_NAMES)}
    assert centroid["head"][0] > centroid["neck"][0] > centroid["chest"][0] > centroid["abdomen"][0] > centroid["tail"][0]
    assert centroid["head"][1] > centroid["chest"][1] > centroid["forelimbs"][1]
    assert centroid["forelimbs"][0] > centroid["hindlimbs"][0]
    assert v[labels == REGION_NAMES.index("forelimbs"), 1].min() == pytest.approx(v[:, 1].min(), abs=0.05)


def test_body_and_trimesh_views():
    generated = animal("horse", 2000)
    body = generated.body()
    assert isinstance(body, Body)
    np.testing.assert_array_equal(body.frame.up, [0, 1, 0])
    np.testing.assert_array_equal(body.frame.forward, [1, 0, 0])
    assert body.region_mask("head").sum() == (generated.labels == 0).sum()
    body.vertices[0] += 1.0                         # a copy: the generated animal is untouched
    assert not np.allclose(body.vertices[0], generated.vertices[0])
    mesh = generated.to_trimesh()
    assert mesh.volume == pytest.approx(generated.truth.body_volume)


# ------------------------------------------------------------------------------ truth

def test_clipped_volume_is_exact_on_a_box_and_close_on_a_sphere():
    box = trimesh.creation.box(extents=(2.0, 4.0, 6.0))
    cell = (HalfSpace(np.array([1.0, 0, 0]), 0.5), HalfSpace(np.array([0, -1.0, 0]), 1.0))
    # x ≤ 0.5 (of −1…1) and y ≥ −1 (of −2…2): 1.5 × 3 × 6
    assert clipped_volume(box.vertices, box.faces, cell) == pytest.approx(27.0, rel=1e-12)
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    normal = np.array([math.cos(0.3), math.sin(0.3), 0.0])
    cap = clipped_volume(sphere.vertices, sphere.faces, (HalfSpace(-normal, -0.4),))  # n·p ≥ 0.4
    h = 1 - 0.4
    assert cap == pytest.approx(math.pi * h * h * (3 - h) / 3, rel=2e-3)
    with pytest.raises(ValueError):
        clipped_volume(box.vertices, box.faces, (HalfSpace(np.array([0, 0, 1.0]), 0.5),))


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_region_volumes_add_up_to_the_body_volume(preset):
    truth = animal(preset, 2000).truth
    assert set(truth.region_volume) == set(REGION_NAMES)
    assert all(volume > 0 for volume in truth.region_volume.values())
    assert sum(truth.region_volume.values()) == pytest.approx(truth.body_volume, rel=5e-3)
    assert truth.body_volume == pytest.approx(animal(preset, 2000).to_trimesh().volume, rel=1e-9)


def section_loops_area(mesh: trimesh.Trimesh, height: float, centre_xz, limit: float) -> float:
    """Independent check: chain trimesh's plane-section segments into a loop around the leg axis;
    its shoelace area and number of sides."""
    segments = trimesh.intersections.mesh_plane(mesh, plane_normal=[0, 1, 0], plane_origin=[0, height, 0])
    points = segments.reshape(-1, 3)[:, [0, 2]]
    keep = np.hypot(points[:, 0] - centre_xz[0], points[:, 1] - centre_xz[1]) < limit
    keep = keep.reshape(-1, 2).all(axis=1)
    segs = segments[keep][:, :, [0, 2]]
    # chain segments by matching endpoints
    key = lambda p: (round(p[0], 9), round(p[1], 9))  # noqa: E731
    nexts: dict = {}
    for a, b in segs:
        nexts.setdefault(key(a), []).append(b)
        nexts.setdefault(key(b), []).append(a)
    start = segs[0][0]
    loop, previous, current = [start], None, start
    for _ in range(len(segs) + 1):
        options = [p for p in nexts[key(current)] if previous is None or key(p) != key(previous)]
        previous, current = current, options[0]
        if key(current) == key(start):
            break
        loop.append(current)
    assert len(loop) == len(segs), "the leg section is one closed loop"
    loop = np.array(loop)
    x, z = loop[:, 0], loop[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(z, 1)) - np.dot(z, np.roll(x, 1))), len(loop)


@pytest.mark.parametrize("preset", ["horse", "elephant"])
def test_leg_radius_agrees_with_an_independent_section_and_with_the_primitive(preset):
    generated = animal(preset, 8000)
    truth, p = generated.truth, generated.parameters
    mesh = generated.to_trimesh()
    layout = _layout(p)
    for region in LIMB_REGIONS:
        radii, analytic = [], []
        bottom_radius, top_radius = ((p.foreleg_radius_bottom, p.foreleg_radius_top) if region == "forelimbs"
                                     else (p.hindleg_radius_bottom, p.hindleg_radius_top))
        for axis in layout.leg_axes[region]:
            near = np.hypot(generated.vertices[:, 0] - axis[0], generated.vertices[:, 2] - axis[1]) < 2 * top_radius
            foot = generated.vertices[near & (generated.labels == REGION_NAMES.index(region)), 1].min()
            cut = truth.leg_cut_height[region]
            height = 0.5 * (cut + foot)
            band = np.linspace(cut - 0.55 * (cut - foot), cut - 0.45 * (cut - foot), 15)
            area = np.mean([section_loops_area(mesh, y, axis, 2 * top_radius)[0] for y in band])
            radii.append(math.sqrt(area / math.pi))
            single = math.sqrt(section_loops_area(mesh, height, axis, 2 * top_radius)[0] / math.pi)
            assert single == pytest.approx(radii[-1], rel=0.05)   # one slice: within the wobble
            # round cone between spheres at y = r_bottom and y = top: ρ(s) = r_b / cos θ + s tan θ
            top = next(c.upper[1] - top_radius for c in layout.primitives if c.name == f"{region}-left")
            length = top - bottom_radius
            theta = math.asin((top_radius - bottom_radius) / length)
            circle = bottom_radius / math.cos(theta) + (height - bottom_radius) * math.tan(theta)
            analytic.append(circle)
            # vertices lie on the true surface ...
            band = near & (np.abs(generated.vertices[:, 1] - height) < 0.5 * circle)
            distance = np.hypot(generated.vertices[band, 0] - axis[0], generated.vertices[band, 2] - axis[1])
            assert distance.mean() == pytest.approx(circle, rel=5e-3)
        assert truth.leg_radius[region] == pytest.approx(np.mean(radii), rel=0.02)
        # ... and flat triangles (circumradius ≈ e/√3 for edge length e) cut inside a surface of
        # radius ρ by at most e²/(6ρ): the section's equivalent radius lies between
        edges = mesh.edges_unique_length[np.isin(mesh.edges_unique, np.flatnonzero(
            generated.labels == REGION_NAMES.index(region))).all(axis=1)].mean()
        rho = np.mean(analytic)
        assert rho - edges ** 2 / (6 * rho) <= truth.leg_radius[region] <= rho * 1.001
        assert truth.leg_radius_at(region, 0.5) == pytest.approx(truth.leg_radius[region], rel=1e-9)
        profile = [truth.leg_radius_at(region, f) for f in (0.05, 0.3, 0.5, 0.7, 0.95)]
        assert all(np.diff(profile) < 0), "legs taper towards the foot"


def test_leg_length_and_neck_length_match_the_labelled_mesh():
    generated = animal("horse", 8000)
    truth, v, labels = generated.truth, generated.vertices, generated.labels
    for region in LIMB_REGIONS:
        mine = v[labels == REGION_NAMES.index(region)]
        extent = truth.leg_cut_height[region] - mine[:, 1].min()
        assert truth.leg_length[region] == pytest.approx(extent, rel=0.01)
        assert mine[:, 1].max() <= truth.leg_cut_height[region]
        assert mine[:, 1].max() == pytest.approx(truth.leg_cut_height[region], rel=0.05)
    u = next(c.normal for c in truth.cuts if c.name == "neck")
    neck = v[labels == REGION_NAMES.index("neck")] @ u
    assert np.ptp(neck) == pytest.approx(truth.neck_length, rel=0.05)


def test_leg_proportions_order_giraffe_horse_elephant():
    def legginess(preset):
        truth = animal(preset, 2000).truth
        return np.mean(list(truth.leg_length.values())) / truth.torso_height
    assert legginess("giraffe") > legginess("horse") > legginess("elephant")
    assert animal("giraffe", 2000).truth.neck_length / animal("giraffe", 2000).truth.torso_height > \
        animal("horse", 2000).truth.neck_length / animal("horse", 2000).truth.torso_height


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_chest_girth_is_an_interior_maximum_behind_the_forelimbs(preset):
    generated = animal(preset, 2000)
    truth, p = generated.truth, generated.parameters
    layout = _layout(p)
    low, high = layout.split_x, layout.leg_cell_bound["forelimbs"]
    margin = 0.05 * (high - low)
    assert low + margin < truth.chest_girth_x < high - margin
    # the chest ellipse's own perimeter (Ramanujan) bounds it closely from below: the smooth
    # union with the abdomen only adds
    a, b = p.chest_height / 2, p.chest_width / 2
    ellipse = math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b)))
    assert 0.97 * ellipse < truth.chest_girth < 1.10 * ellipse
    assert 0.97 * p.chest_height < truth.torso_height < 1.10 * p.chest_height


def test_truth_is_stable_across_resolutions():
    coarse, fine = animal("horse", 2000).truth, animal("horse", 8000).truth
    assert coarse.body_volume == pytest.approx(fine.body_volume, rel=0.03)
    assert coarse.chest_girth == pytest.approx(fine.chest_girth, rel=0.01)
    for region in LIMB_REGIONS:
        assert coarse.leg_length[region] == pytest.approx(fine.leg_length[region], rel=0.03)
    for region in REGION_NAMES:   # thin legs lose more (fewer sides around), so in body units
        assert coarse.region_volume[region] == pytest.approx(fine.region_volume[region],
                                                             abs=0.01 * fine.body_volume), region


# ------------------------------------------------------------------------------ CLI

def test_generate_command_writes_mesh_labels_and_truth(tmp_path, capsys):
    out, labels, truth = tmp_path / "dog.obj", tmp_path / "labels.json", tmp_path / "truth.json"
    arguments = ["generate", "--preset", "dog", "--vertices", "1200", "-o", str(out),
                 "--labels", str(labels), "--truth", str(truth), "--set", "tail_length=0.2"]
    assert main(arguments) == 0
    mesh = trimesh.load(out, process=False)
    document = json.loads(labels.read_text())
    assert document["format"] == "allorules-labels" and document["version"] == 1
    assert document["regions"] == list(REGION_NAMES)
    assert len(document["labels"]) == len(mesh.vertices)
    facts = json.loads(truth.read_text())
    assert facts["parameters"]["tail_length"] == 0.2
    assert facts["body_volume"] == pytest.approx(mesh.volume, rel=1e-5)
    assert set(facts["region_volume"]) == set(REGION_NAMES)

    before = out.read_bytes()
    assert main(arguments) != 0                     # refuses to overwrite
    assert "already exist" in capsys.readouterr().err
    assert out.read_bytes() == before
    assert main(arguments + ["--force"]) == 0
    assert main(["generate", "-o", str(tmp_path / "x.obj"), "--set", "neck_length"]) != 0
    assert not (tmp_path / "x.obj").exists()


def test_generate_command_stands_the_animal_in_a_pose(tmp_path, capsys):
    """``--pose`` gives the posed animal the library makes (same faces, the standing labels); a pose
    the generator does not know is refused with the list, nothing written."""
    out, labels, truth = tmp_path / "galloping.obj", tmp_path / "labels.json", tmp_path / "truth.json"
    assert main(["generate", "--vertices", "1200", "--pose", "gallop", "-o", str(out), "--labels", str(labels),
                 "--truth", str(truth)]) == 0
    mesh = trimesh.load(out, process=False)
    expected = generate_quadruped("horse", 1200, pose="gallop")
    assert np.allclose(mesh.vertices, expected.vertices, atol=1e-5)
    assert not np.allclose(mesh.vertices, generate_quadruped("horse", 1200).vertices, atol=1e-3)
    assert json.loads(labels.read_text())["labels"] == expected.labels.tolist()
    assert json.loads(truth.read_text())["pose"] == "gallop"
    assert main(["generate", "-o", str(tmp_path / "x.obj"), "--pose", "dance"]) != 0
    assert "unknown pose 'dance'" in capsys.readouterr().err and not (tmp_path / "x.obj").exists()
