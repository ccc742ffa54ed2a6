"""Segmentation: spectral patches, label files, merge files, the automatic quadruped labeller, CLI."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from rotations import random_rotation

from allorules.body import Body
from allorules.errors import RulesetError, SegmentationError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.topology import vertex_components, vertex_graph
from allorules.segment.labeller import label_quadruped
from allorules.segment.labels_io import (
    apply_merge_file,
    face_labels_from_vertices,
    read_labels,
    read_seg,
    write_labels,
    write_seg,
)
from allorules.segment.patches import spectral_patches
from allorules.segment.regions import QUADRUPED_REGIONS, fold_regions

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


# ---------------------------------------------------------------- fixtures

@pytest.fixture(scope="session")
def generated():
    """Generated quadrupeds with their truth, ~2000 vertices (the generator is the slow part)."""
    from allorules.mesh import quadruped
    return {preset: quadruped.generate_quadruped(preset, vertices=2000, seed=0)
            for preset in ("horse", "giraffe", "dog", "elephant")}


def truth_body(animal) -> Body:
    """The generator's truth with the tail folded into the abdomen, as the labeller does."""
    return fold_regions(animal.body())


def area_agreement(labels_a, labels_b, vertices, faces) -> float:
    mass = vertex_areas(vertices, faces)
    return float(mass[labels_a == labels_b].sum() / mass.sum())


@pytest.fixture(scope="session")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope="session")
def capsule():
    mesh = trimesh.creation.capsule(height=4.0, radius=0.5, count=[24, 24])
    mesh.merge_vertices()
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


# ---------------------------------------------------------------- patches

def test_patches_are_connected_numbered_and_deterministic(capsule):
    vertices, faces = capsule
    patches = spectral_patches(vertices, faces, 8, seed=3)
    assert sorted(np.unique(patches)) == list(range(8))
    graph = vertex_graph(vertices, faces)
    for patch in range(8):
        parts = vertex_components(graph, patches == patch)
        assert parts.max() == 0, f"patch {patch} is in {parts.max() + 1} pieces"
    # Numbered by lowest vertex index.
    firsts = [np.flatnonzero(patches == patch)[0] for patch in range(8)]
    assert firsts == sorted(firsts)
    again = spectral_patches(vertices, faces, 8, seed=3)
    np.testing.assert_array_equal(patches, again)


def test_patches_on_a_capsule_cut_across_its_length(capsule):
    """The low harmonics of a long capsule run along it: patches are bands along the axis."""
    vertices, faces = capsule
    patches = spectral_patches(vertices, faces, 4, seed=0)
    axis = np.argmax(np.ptp(vertices, axis=0))
    extents = sorted((vertices[patches == p, axis].min(), vertices[patches == p, axis].max()) for p in range(4))
    span = np.ptp(vertices[:, axis])
    for (low_a, high_a), (low_b, high_b) in zip(extents, extents[1:]):
        assert high_a <= low_b + 0.1 * span  # bands follow each other, overlapping little


def test_too_many_patches_is_a_clear_error(sphere):
    vertices, faces = sphere
    with pytest.raises(SegmentationError, match="too many"):
        spectral_patches(vertices, faces, 500)


# ---------------------------------------------------------------- files

def test_labels_round_trip_and_validation(tmp_path, sphere):
    vertices, faces = sphere
    labels = (vertices[:, 0] > 0).astype(np.int64)
    labels[:5] = -1
    body = Body(vertices, faces, labels, ("left", "right"))
    path = tmp_path / "labels.json"
    write_labels(path, body)
    document = json.loads(path.read_text())
    assert document["format"] == "allorules-labels" and document["version"] == 1
    read = read_labels(path, Body(vertices, faces))
    np.testing.assert_array_equal(read.labels, labels)
    assert read.region_names == ("left", "right")
    document["labels"] = document["labels"][:-1]
    path.write_text(json.dumps(document))
    with pytest.raises(SegmentationError, match="labels but the mesh has"):
        read_labels(path, Body(vertices, faces))
    document["labels"] = [7] * len(vertices)
    path.write_text(json.dumps(document))
    with pytest.raises(SegmentationError, match="not a region index"):
        read_labels(path, Body(vertices, faces))


def test_seg_round_trip_per_face(tmp_path, sphere):
    vertices, faces = sphere
    labels = np.digitize(vertices[:, 2], [-0.3, 0.4]).astype(np.int64)
    body = Body(vertices, faces, labels, ("a", "b", "c"))
    path = tmp_path / "body.seg"
    write_seg(path, body)
    lines = path.read_text().split()
    assert len(lines) == len(faces)  # one integer per face
    face_labels = np.array(lines, dtype=int)
    np.testing.assert_array_equal(face_labels, face_labels_from_vertices(faces, labels))
    read = read_seg(path, Body(vertices, faces), ("a", "b", "c"))
    # Majority face→vertex conversion returns every vertex away from the band borders unchanged.
    assert np.mean(read.labels == labels) > 0.9
    border = np.zeros(len(vertices), dtype=bool)
    for face, label in zip(faces, face_labels):
        if len(set(labels[face])) > 1:
            border[face] = True
    np.testing.assert_array_equal(read.labels[~border], labels[~border])
    path.write_text("0\n" * (len(faces) - 1))
    with pytest.raises(SegmentationError, match="face labels but the mesh has"):
        read_seg(path, Body(vertices, faces))


MERGE_OK = """\
head: [0]
neck: [1]
chest: [2]
abdomen: [3, 4]
forelimbs: [5]
hindlimbs: [6, 7]
"""


@pytest.fixture
def patched(capsule):
    vertices, faces = capsule
    patches = spectral_patches(vertices, faces, 8, seed=0)
    return Body(vertices, faces), patches


def test_merge_file_turns_patches_into_regions(tmp_path, patched):
    body, patches = patched
    path = tmp_path / "merge.yaml"
    path.write_text(MERGE_OK)
    merged = apply_merge_file(body, patches, path)
    assert merged.region_names == QUADRUPED_REGIONS
    np.testing.assert_array_equal(merged.labels[patches == 3], 3)
    np.testing.assert_array_equal(merged.labels[patches == 7], 5)
    assert (merged.labels >= 0).all()


@pytest.mark.parametrize("text, line, message", [
    (MERGE_OK.replace("[6, 7]", "[6, 7, 8]"), 6, "unknown patch id 8"),
    (MERGE_OK.replace("neck: [1]", "neck: [1, 0]"), 2, "patch 0 is in two regions"),
    (MERGE_OK.replace("chest: [2]\n", ""), None, "required region chest missing"),
    (MERGE_OK.replace("abdomen: [3, 4]", "abdomen: [3]"), None, "patch 4 belong"),
    (MERGE_OK.replace("head: [0]", "head: [zero]"), 1, "not an integer"),
    ("head: [0\n", None, "not valid YAML"),
])
def test_bad_merge_files_name_file_and_line(tmp_path, patched, text, line, message):
    body, patches = patched
    path = tmp_path / "merge.yaml"
    path.write_text(text)
    with pytest.raises(SegmentationError, match=message) as caught:
        apply_merge_file(body, patches, path)
    assert isinstance(caught.value, RulesetError)
    assert str(caught.value).startswith(str(path))
    if line is not None:
        assert str(caught.value).startswith(f"{path}:{line}:")


# ---------------------------------------------------------------- automatic labeller

def test_non_quadrupeds_are_refused_clearly(sphere, capsule):
    for vertices, faces in (sphere, capsule):
        with pytest.raises(SegmentationError, match="quadruped"):
            label_quadruped(Body(vertices, faces))


@pytest.mark.parametrize("preset", ["horse", "giraffe", "dog", "elephant"])
def test_labels_agree_with_generator_truth(generated, preset):
    check_agreement(generated[preset], preset)


@pytest.mark.slow
@pytest.mark.parametrize("vertices", [1500, 4000])
@pytest.mark.parametrize("preset", ["horse", "giraffe", "dog", "elephant"])
def test_labels_agree_with_generator_truth_at_other_sizes(preset, vertices):
    """The giraffe at 4,000 vertices was a known shortfall (0.949) until a neck section slipped into
    a gap was stepped over (0.965; docs/segmentation.md)."""
    from allorules.mesh import quadruped
    check_agreement(quadruped.generate_quadruped(preset, vertices=vertices), preset)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["horse", "giraffe", "dog", "elephant"])
def test_labels_agree_with_generator_truth_on_a_varied_animal(preset):
    """Seed 1 varies every length by up to ±8% (measured 2000 vertices, seeds 1/2/3: giraffe
    0.962/0.966/0.962, dog 0.972/0.985/0.977, horse 0.963/0.973/0.966, elephant 0.955/0.964/0.969;
    the horse of seed 1 was 0.950 while its hind legs took in a pool of the belly, the elephant
    0.945 while its forelegs ran on past a pool that grew into the belly)."""
    from allorules.mesh import quadruped
    check_agreement(quadruped.generate_quadruped(preset, vertices=2000, seed=1), preset)


# A cartoon dog: legs under half the dog's length and up to 1.8 times as thick, a head twice as
# big on a neck a third as long (factors of the dog preset's own parameters).
CARTOON = dict(foreleg_length=0.45, hindleg_length=0.45, foreleg_radius_top=1.4, foreleg_radius_bottom=1.8,
               hindleg_radius_top=1.4, hindleg_radius_bottom=1.8, head_length=1.4, head_height=1.9, head_width=1.9,
               neck_length=0.35, neck_radius=1.2, neck_head_radius=1.6, tail_length=0.6)


@pytest.mark.slow
def test_a_cartoon_dog_with_stubby_legs_and_a_big_head_is_labelled_right():
    """Issue 17 (cartoon proportions). Measured turned at random (the same for every turn): 0.929
    of its area at 3,000 vertices, 0.946 at 6,000, legs 0.99-1.00; short of the standing animals'
    0.95 at 3,000 where the chest's line against the neck and abdomen moves."""
    from allorules.mesh import quadruped

    base = quadruped.PRESETS["dog"]
    animal = quadruped.generate_quadruped("dog", vertices=3000, **{k: getattr(base, k) * f for k, f in CARTOON.items()})
    truth = truth_body(animal)
    labelled = label_six(animal.vertices @ random_rotation(17).T, animal.faces)
    assert area_agreement(labelled.labels, truth.labels, animal.vertices, animal.faces) >= 0.92
    legs = np.isin(truth.labels, [QUADRUPED_REGIONS.index(n) for n in ("forelimbs", "hindlimbs")])
    got_legs = np.isin(labelled.labels, [QUADRUPED_REGIONS.index(n) for n in ("forelimbs", "hindlimbs")])
    assert area_agreement(got_legs, legs, animal.vertices, animal.faces) >= 0.98
    head = QUADRUPED_REGIONS.index("head")
    assert area_agreement(labelled.labels == head, truth.labels == head, animal.vertices, animal.faces) >= 0.95


@pytest.mark.slow
def test_a_head_wider_than_the_chest_sat_on_it_with_no_neck_is_labelled_whole():
    """Issue 17 (cartoon proportions): a kitten's big round head sits on its body with no neck
    between, wider than its chest; followed from the bend at the back of the head the sections
    narrow to where it meets the chest and grow only a little, and no wider than the head. The
    head is all that lies beyond that narrowest section (before, the neck was not found and only
    the muzzle was labelled head: 0.61 of the head's area)."""
    from allorules.mesh import quadruped

    base = quadruped.PRESETS["dog"]
    animal = quadruped.generate_quadruped(
        "dog", vertices=3000, head_length=3.2 * base.head_length, head_height=4 * base.head_height,
        head_width=4 * base.head_width, neck_length=0.1 * base.neck_length, neck_radius=1.3 * base.neck_radius,
        neck_head_radius=1.3 * base.neck_radius, foreleg_length=0.6 * base.foreleg_length,
        hindleg_length=0.6 * base.hindleg_length)
    truth = truth_body(animal)
    labelled = label_six(animal.vertices @ random_rotation(5).T, animal.faces)
    head = QUADRUPED_REGIONS.index("head")
    assert area_agreement(labelled.labels == head, truth.labels == head, animal.vertices, animal.faces) >= 0.95
    assert area_agreement(labelled.labels, truth.labels, animal.vertices, animal.faces) >= 0.93


def label_six(vertices, faces, **options):
    """The automatic labels on the six regions (a tail, ears, horns or trunk folded into their neighbours)."""
    return fold_regions(label_quadruped(Body(vertices, faces), **options))


def check_agreement(animal, preset):
    truth = truth_body(animal)
    labelled = label_six(animal.vertices, animal.faces)
    assert labelled.region_names == QUADRUPED_REGIONS
    np.testing.assert_allclose(labelled.frame.up, [0, 1, 0], atol=0.05)
    np.testing.assert_allclose(labelled.frame.forward, [1, 0, 0], atol=0.05)
    agreement = area_agreement(labelled.labels, truth.labels, animal.vertices, animal.faces)
    assert agreement >= 0.95, f"{preset}: {agreement:.3f} of the surface agrees with the truth"
    limbs = [QUADRUPED_REGIONS.index(name) for name in ("forelimbs", "hindlimbs")]
    for limb in limbs:
        leg_agreement = area_agreement(labelled.labels == limb, truth.labels == limb, animal.vertices, animal.faces)
        assert leg_agreement >= 0.98


def test_elephant_trunk_is_not_a_foot(generated):
    """The trunk tip hangs low near the head end; the feet are the four that stand on the ground."""
    animal = generated["elephant"]
    truth = truth_body(animal)
    labelled = label_six(animal.vertices, animal.faces)
    np.testing.assert_allclose(labelled.frame.up, [0, 1, 0], atol=0.05)
    np.testing.assert_allclose(labelled.frame.forward, [1, 0, 0], atol=0.05)
    limbs = np.isin(labelled.labels, [QUADRUPED_REGIONS.index(n) for n in ("forelimbs", "hindlimbs")])
    head = truth.region_mask("head")
    mass = vertex_areas(animal.vertices, animal.faces)
    assert mass[head & limbs].sum() < 0.01 * mass[head].sum()
    # the trunk (in the generator's head) is labelled head, all of it
    assert mass[head & labelled.region_mask("head")].sum() > 0.7 * mass[head].sum()
    for limb in ("forelimbs", "hindlimbs"):
        index = QUADRUPED_REGIONS.index(limb)
        assert area_agreement(labelled.labels == index, truth.labels == index, animal.vertices, animal.faces) >= 0.97


def test_elephant_trunk_is_a_trunk(generated):
    """The generated elephant's trunk (a tube 7-9 of its radii long) is cut from its head as a
    trunk: TRUNK_LENGTH (5 radii; a wolf's upper jaw with its mouth open is 3.3) lets it through."""
    animal = generated["elephant"]
    labelled = label_quadruped(Body(animal.vertices, animal.faces))
    mass = vertex_areas(animal.vertices, animal.faces)
    trunk, head = labelled.region_mask("trunk"), truth_body(animal).region_mask("head")
    assert mass[trunk].sum() > 0.1 * mass[head].sum()
    assert mass[trunk & head].sum() > 0.95 * mass[trunk].sum()


@pytest.mark.parametrize("preset", ["horse", "dog"])
@pytest.mark.parametrize("transform", ["rotated", "mirrored", "tiny", "huge"])
def test_labels_do_not_depend_on_orientation_mirroring_or_scale(generated, transform, preset):
    animal = generated[preset]
    reference = label_six(animal.vertices, animal.faces)
    matrix = {"rotated": random_rotation(1), "mirrored": np.diag([1.0, 1.0, -1.0]) @ random_rotation(2),
              "tiny": 0.001 * random_rotation(3), "huge": 1000.0 * np.eye(3)}[transform]
    moved = animal.vertices @ matrix.T + np.array([5.0, -3.0, 2.0]) * np.abs(matrix).max()
    faces = animal.faces if np.linalg.det(matrix) > 0 else animal.faces[:, ::-1]
    labelled = label_six(moved, faces)
    assert area_agreement(labelled.labels, reference.labels, animal.vertices, animal.faces) >= 0.99
    scale = np.cbrt(abs(np.linalg.det(matrix)))
    np.testing.assert_allclose(labelled.frame.up, matrix @ reference.frame.up / scale, atol=0.02)
    np.testing.assert_allclose(labelled.frame.forward, matrix @ reference.frame.forward / scale, atol=0.02)


def test_up_and_forward_overrides_are_used(generated):
    animal = generated["horse"]
    labelled = label_six(animal.vertices, animal.faces, up=[0, 2, 0], forward=[3, 0, 0])
    np.testing.assert_allclose(labelled.frame.up, [0, 1, 0])
    np.testing.assert_allclose(labelled.frame.forward, [1, 0, 0])
    # Forward given backwards: the labeller follows the user (fore and hind swap).
    backwards = fold_regions(label_quadruped(Body(animal.vertices, animal.faces), up=[0, 1, 0], forward=[-1, 0, 0],
                                             complete=False))
    fore = QUADRUPED_REGIONS.index("forelimbs")
    hind = QUADRUPED_REGIONS.index("hindlimbs")
    np.testing.assert_array_equal(backwards.labels == fore, labelled.labels == hind)
    np.testing.assert_allclose(backwards.frame.forward, [-1, 0, 0])


@pytest.mark.parametrize("preset", ["horse", "giraffe", "dog", "elephant"])
def test_leg_lengths_and_volumes_from_automatic_labels_match_truth(generated, preset):
    """Labeller and generator cut a leg at the same place: its saddle (armpit / groin)."""
    from allorules.measure.length import region_length
    from allorules.measure.mass import region_mass
    animal = generated[preset]
    labelled = label_six(animal.vertices, animal.faces)
    for region in ("forelimbs", "hindlimbs"):
        assert region_mass(labelled, region) == pytest.approx(animal.truth.region_volume[region], rel=0.05)
        assert region_length(labelled, region) == pytest.approx(animal.truth.leg_length[region], rel=0.05)


@pytest.mark.parametrize("preset", ["horse", "giraffe", "dog", "elephant"])
def test_legs_end_at_their_armpits_and_groins_not_in_a_pool_of_the_belly(generated, preset):
    """A pool of the torso's underside that a leg's sweep takes in just below where it meets the
    body is not leg (POOL_PART, POOL_RISE): taken in, it gave the generated horse's hind legs 5.4 %
    more surface than the generator's and the giraffe's 3.5 % (the cow 381's forelegs a strip of
    chest joining them). Each pair's surface within 2.5 % of the truth's."""
    animal = generated[preset]
    truth = truth_body(animal)
    labelled = label_six(animal.vertices, animal.faces)
    mass = vertex_areas(animal.vertices, animal.faces)
    for region in ("forelimbs", "hindlimbs"):
        found, true = mass[labelled.region_mask(region)].sum(), mass[truth.region_mask(region)].sum()
        assert found == pytest.approx(true, rel=0.025), region


# ---------------------------------------------------------------- real meshes

REAL_ANIMALS = ["horse", "lion", "wolf", "camel", "dog-lowpoly"]


def _load_real(name):
    if not SHARED.is_dir():
        pytest.skip("../shared/meshes is not present")
    from allorules.mesh.repair import prepare_mesh

    prepared = prepare_mesh(SHARED / f"{name}.obj")
    return Body(prepared.vertices, prepared.faces)


@pytest.mark.shared_meshes
@pytest.mark.parametrize("name", REAL_ANIMALS)
def test_real_quadrupeds_are_labelled(name):
    body = _load_real(name)
    labelled = fold_regions(label_quadruped(body))
    # All six regions present, legs in two separate parts each, up along the file's +Y.
    mass = vertex_areas(body.vertices, body.faces)
    shares = np.bincount(labelled.labels, weights=mass, minlength=6) / mass.sum()
    assert (labelled.labels >= 0).all()
    assert np.all(shares[2:] > 0.02), dict(zip(QUADRUPED_REGIONS, shares))
    assert labelled.frame.up[1] > 0.95
    graph = vertex_graph(body.vertices, body.faces)
    for limb in ("forelimbs", "hindlimbs"):
        parts = vertex_components(graph, labelled.region_mask(limb))
        # the camel's forelegs touch at the knees (the mesh joins them there): one piece
        expected = 1 if (name, limb) == ("camel", "forelimbs") else 2
        assert parts.max() + 1 == expected, f"{name}: {limb} in {parts.max() + 1} parts"


@pytest.mark.shared_meshes
def test_real_camel_forelegs_that_touch_at_the_knees_reach_up_to_the_body():
    """Two legs touching is not the body: the sweep goes on past the knees to the armpits."""
    body = _load_real("camel")
    labelled = fold_regions(label_quadruped(body))
    height = body.vertices @ labelled.frame.up
    height = (height - height.min()) / np.ptp(height)
    # knees at ~0.3 of the height, the armpits at ~0.5 (looked at in the region picture)
    assert height[labelled.region_mask("forelimbs")].max() > 0.45
    assert height[labelled.region_mask("chest")].min() > 0.4


@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.parametrize("name", ["wolf", "horse", "camel"])
def test_real_labels_do_not_depend_on_a_random_rotation(name):
    body = _load_real(name)
    reference = fold_regions(label_quadruped(body))
    for seed in (11, 12):
        matrix = random_rotation(seed)
        turned = fold_regions(label_quadruped(Body(body.vertices @ matrix.T, body.faces)))
        assert area_agreement(turned.labels, reference.labels, body.vertices, body.faces) >= 0.99
        np.testing.assert_allclose(turned.frame.up, matrix @ reference.frame.up, atol=0.02)


@pytest.mark.shared_meshes
def test_real_elephant_is_refused_clearly():
    """The shared elephant is a cartoon standing on two legs with its arms out: not labelled, with
    one line that says how to settle it."""
    body = _load_real("elephant")
    with pytest.raises(SegmentationError, match="--forward|allorules segment") as refused:
        label_quadruped(body)
    assert "\n" not in str(refused.value)
    # Told which way it faces, as that message suggests, it is still refused: its ears (or its legs)
    # would be taken for hind feet, a head of 0.2 % of the surface and hind limbs of half of it
    # (the proportions' check); since 1495ff6 a pair of its tips left in its chest, which no
    # four-legged animal's chest holds, refused it first, both ways, and now the choice of its feet
    # does (a pair left out, 0.39 and 0.38, stands out more than a foot taken, 0.28)
    for forward in ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0)):
        with pytest.raises(SegmentationError, match="(not a four-legged animal's|ears or horns was labelled chest|"
                                                    "a pair left out).*--segmentation"):
            label_quadruped(body, forward=np.array(forward))


@pytest.mark.parametrize("given", [False, True])
def test_a_leg_that_cannot_be_followed_is_refused_with_how_to_settle_it(monkeypatch, generated, given):
    """Where a leg cannot be followed up from one of the feet found (a voxel horse's blocks), the
    feet may not be the animal's: one line that says how to settle it, the directions first
    unless they were given."""
    from allorules.segment import labeller

    monkeypatch.setattr(labeller, "_follow_tip", lambda *arguments: None)
    horse = generated["horse"]
    directions = {"up": np.array([0.0, 1.0, 0.0]), "forward": np.array([0.0, 0.0, 1.0])} if given else {}
    with pytest.raises(SegmentationError, match="followed up from one of the four feet") as refused:
        label_quadruped(Body(horse.vertices, horse.faces), **directions)
    message = str(refused.value)
    assert "\n" not in message and "--patches 24" in message and "--segmentation FILE" in message
    assert ("--up DIR and --forward DIR" in message) is not given


def test_regions_no_quadruped_has_are_refused(generated):
    """The proportions check: a truth passes; the same with the head handed to the hind limbs, or
    the torso to the forelimbs, is refused with what is wrong."""
    from allorules.segment.labeller import _check_proportions

    truth = truth_body(generated["horse"])
    area = vertex_areas(truth.vertices, truth.faces)
    _check_proportions(truth.labels, area)
    index = {name: number for number, name in enumerate(truth.region_names)}
    headless = truth.labels.copy()
    headless[np.isin(headless, [index["head"], index["neck"], index["chest"]])] = index["hindlimbs"]
    with pytest.raises(SegmentationError, match=r"head 0\.0%, hindlimbs \d+%"):
        _check_proportions(headless, area)
    no_torso = truth.labels.copy()
    no_torso[np.isin(no_torso, [index["chest"], index["abdomen"]])] = index["forelimbs"]
    with pytest.raises(SegmentationError, match="chest and abdomen 0%"):
        _check_proportions(no_torso, area)


# ---------------------------------------------------------------- CLI

@pytest.mark.shared_meshes
def test_segment_command_writes_labels_seg_and_picture(tmp_path):
    from allorules.cli import main

    mesh = SHARED / "camel.obj"
    if not mesh.exists():
        pytest.skip("../shared/meshes is not present")
    labels, seg, png = tmp_path / "camel.labels.json", tmp_path / "camel.seg", tmp_path / "camel.png"
    assert main(["-q", "segment", str(mesh), "-o", str(labels), "--seg", str(seg), "--png", str(png)]) == 0
    document = json.loads(labels.read_text())
    # the six, then what else the labeller found (the camel's tail): every region kept
    assert document["regions"][:6] == list(QUADRUPED_REGIONS)
    assert set(document["regions"][6:]) <= {"tail", "ears", "horns", "trunk"}
    assert set(document["labelling"]["confidence"]) == {"feet", "fore-hind pairs", "head-tail"}
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    assert main(["-q", "segment", str(mesh), "-o", str(labels)]) != 0  # exists: kept without --force
    patches_png = tmp_path / "patches.png"
    assert main(["-q", "segment", str(mesh), "--patches", "12", "-o", str(tmp_path / "p.json"),
                 "--png", str(patches_png)]) == 0
    assert json.loads((tmp_path / "p.json").read_text())["regions"][-1] == "patch11"
    assert patches_png.exists()


def test_measure_command_on_a_generated_horse(tmp_path, generated, capsys):
    from allorules.cli import main

    animal = generated["horse"]
    mesh = tmp_path / "horse.obj"
    animal.to_trimesh().export(mesh)
    assert main(["-q", "measure", str(mesh), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["body_mass"] == pytest.approx(animal.truth.body_volume, rel=0.01)
    assert result["peak_stress"] > 0
    assert {rule["id"] for rule in result["rules"]} >= {"foreleg-length", "chest-girth", "head-mass"}


def test_a_region_the_labeller_cannot_find_is_an_error_not_an_empty_region(generated, monkeypatch):
    # When no neck is found the labeller must say so instead of returning empty regions.
    from allorules.segment import labeller

    animal = generated["horse"]
    monkeypatch.setattr(labeller, "_neck_cuts", lambda *args: (None, None))
    monkeypatch.setattr(labeller, "_ring_head_and_neck", lambda *args: None)
    with pytest.raises(SegmentationError, match="found no head and no neck"):
        label_quadruped(Body(animal.vertices, animal.faces))
    partial = label_quadruped(Body(animal.vertices, animal.faces), complete=False)
    assert not np.isin(partial.labels, [0, 1]).any()


def test_where_the_skeletons_bend_gives_no_neck_the_rings_from_the_head_tip_do(generated, monkeypatch):
    """The fallback: the head to the throat's ring, the rest of the front end neck. It is generous:
    the generated horse has no narrowing behind its head, so its fallback head takes the upper
    neck too (measured: 2.1 times the generator's head, 0.87 of the area agreeing)."""
    from allorules.segment import labeller

    animal = generated["horse"]
    monkeypatch.setattr(labeller, "_neck_cuts", lambda *args: (None, None))
    labelled = label_six(animal.vertices, animal.faces)
    truth = truth_body(animal)
    mass = vertex_areas(animal.vertices, animal.faces)
    head, found = truth.region_mask("head"), labelled.region_mask("head")
    assert mass[head & found].sum() > 0.95 * mass[head].sum()
    assert mass[found].sum() < 2.5 * mass[head].sum()
    assert labelled.region_mask("neck").any()
    assert area_agreement(labelled.labels, truth.labels, animal.vertices, animal.faces) > 0.85


def test_a_leg_that_never_meets_a_body_is_refused_with_the_way_by_hand():
    """The leg's sweep from its foot up finds no level where it meets the body (a lone capsule:
    nothing else there; a walking cartoon puppy whose tail and ear were taken for feet): refused,
    saying how to give the regions by hand."""
    import trimesh

    from allorules.mesh.geometry import vertex_areas
    from allorules.segment import body_plan, labeller

    leg = trimesh.creation.capsule(height=4.0, radius=1.0, count=[16, 16])
    vertices, faces = np.array(leg.vertices), np.array(leg.faces)
    foot = int(np.argmin(vertices[:, 2]))
    graph = labeller.vertex_graph(vertices, faces)
    with pytest.raises(SegmentationError, match="could not be separated") as refused:
        labeller._cut_legs(vertices, faces, graph, vertex_areas(vertices, faces), [foot], {foot: np.array([0, 0, 1.0])})
    assert body_plan.BY_HAND in str(refused.value)


def test_a_chest_that_rises_far_above_the_back_is_refused():
    """A head cut through and left with the chest (a cartoon kitten's big round head sat on its
    body with no neck: its face alone labelled head, 1.43) rises far above the back; a generated
    dog with a big head on a short upright neck does not (0.1-0.2), and with its head and neck
    given to the chest it rises beyond MAX_CHEST_RISE and is refused, saying how to give the
    regions by hand."""
    from allorules.mesh.quadruped import generate_quadruped
    from allorules.segment import body_plan, labeller

    dog = generate_quadruped("dog", 2000, neck_angle=85.0, neck_length=0.04, head_length=0.4, head_height=0.45,
                             head_width=0.4, head_angle=0.0)
    body = dog.body()
    index = {name: labeller.REGIONS.index(name) for name in labeller.REGIONS}
    labels = np.array([index.get(name, -1) for name in np.asarray(body.region_names)[body.labels]])
    up = np.array([0.0, 1.0, 0.0])
    assert labeller.chest_rise(body.vertices, labels, up) < 0.3
    labeller._check_chest_rise(body.vertices, labels, up)
    swallowed = labels.copy()
    swallowed[np.isin(labels, [labeller.HEAD, labeller.NECK])] = labeller.CHEST
    assert labeller.chest_rise(body.vertices, swallowed, up) > labeller.MAX_CHEST_RISE
    with pytest.raises(SegmentationError, match="rises far above the back") as refused:
        labeller._check_chest_rise(body.vertices, swallowed, up)
    assert body_plan.BY_HAND in str(refused.value)


# ---------------------------------------------------------------- an animal modelled in pieces


def test_an_animal_modelled_in_pieces_is_labelled_on_every_piece():
    from pieces import pieces_quadruped

    from allorules.runs.pipeline import input_regions

    mesh, marks = pieces_quadruped()
    regions, working = input_regions(mesh)
    names = np.asarray(regions.region_names)
    assert (regions.labels >= 0).all()                        # every vertex of every piece has a region
    for mark, region in (("muzzle", "head"), ("tail", "tail"), ("forelimbs", "forelimbs"), ("hindlimbs", "hindlimbs")):
        assert len(marks[mark]) > 0 and (names[regions.labels[marks[mark]]] == region).all(), mark
    assert working.frame.up[2] > 0.95 and working.frame.forward[0] > 0.95
