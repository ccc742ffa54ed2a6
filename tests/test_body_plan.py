"""The pose- and style-general labeller: generated animals in poses (their standing labels are the
truth), the head/tail cues one by one, refusals, hand-marked real meshes, regions on demand."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rotations import random_rotation

from allorules.body import Body
from allorules.errors import SegmentationError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.quadruped import REGION_NAMES, generate_quadruped, horn_vertices
from allorules.mesh.quadruped_poses import Pose
from allorules.segment import body_plan, label_check
from allorules.segment.labeller import label_quadruped
from allorules.segment.labels_io import read_labels, write_labels
from allorules.segment.regions import QUADRUPED_REGIONS, fold_regions

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
HAND_MARKS = Path(__file__).resolve().parent / "data" / "hand_marks.json"
SETTLE = "--forward|allorules segment"


def agreement(animal, labelled) -> float:
    """Share of the area where the labels (folded to the six) agree with the generator's."""
    truth = fold_regions(animal.body())
    six = fold_regions(labelled)
    mass = vertex_areas(animal.vertices, animal.faces)
    return float(mass[six.labels == truth.labels].sum() / mass.sum())


@pytest.fixture(scope="module")
def posed():
    """Generated animals in poses, 2000 vertices (made once: the generator is the slow part)."""
    cache = {}

    def make(preset, pose):
        if (preset, pose) not in cache:
            cache[preset, pose] = generate_quadruped(preset, 2000, pose=pose)
        return cache[preset, pose]
    return make


# ---------------------------------------------------------------- the generator's poses

def test_poses_keep_faces_and_labels_and_move_only_what_they_name(posed):
    standing = posed("horse", "stand")
    walking = posed("horse", "walk")
    np.testing.assert_array_equal(walking.faces, standing.faces)
    np.testing.assert_array_equal(walking.labels, standing.labels)
    moved = np.linalg.norm(walking.vertices - standing.vertices, axis=1) > 1e-9
    legs = np.isin(standing.labels, [REGION_NAMES.index("forelimbs"), REGION_NAMES.index("hindlimbs")])
    # every leg moves; the head and the tail stay (the walk turns the neck a little: its base blends)
    assert moved[legs].mean() > 0.95
    assert not moved[standing.labels == REGION_NAMES.index("tail")].any()
    # a leg below its saddle swings rigidly: its length and the distances within it are kept
    leg = np.flatnonzero((standing.labels == REGION_NAMES.index("forelimbs")) & (standing.vertices[:, 2] > 0))
    low = leg[standing.vertices[leg, 1] < 0.5 * standing.truth.leg_cut_height["forelimbs"]]   # the left one: no knee
    pairs = np.random.default_rng(0).choice(low, size=(200, 2))
    before = np.linalg.norm(standing.vertices[pairs[:, 0]] - standing.vertices[pairs[:, 1]], axis=1)
    after = np.linalg.norm(walking.vertices[pairs[:, 0]] - walking.vertices[pairs[:, 1]], axis=1)
    np.testing.assert_allclose(after, before, atol=1e-9)


def test_pose_angles_move_the_parts_the_way_their_sign_says():
    horse = generate_quadruped("horse", 1500)
    forward = generate_quadruped("horse", 1500, pose=Pose(swing={"fore-left": 30}))
    raised = generate_quadruped("horse", 1500, pose=Pose(tail=40, neck=20))
    fore = (forward.labels == REGION_NAMES.index("forelimbs")) & (horse.vertices[:, 2] > 0)   # left: z > 0
    lowest = np.flatnonzero(fore)[np.argmin(horse.vertices[fore, 1])]
    assert forward.vertices[lowest, 0] > horse.vertices[lowest, 0] + 0.1      # the foot went forward (+X)
    tail = horse.labels == REGION_NAMES.index("tail")
    head = horse.labels == REGION_NAMES.index("head")
    assert raised.vertices[tail, 1].mean() > horse.vertices[tail, 1].mean()  # tail up
    assert raised.vertices[head, 1].mean() > horse.vertices[head, 1].mean()  # head up
    assert forward.truth.body_volume == pytest.approx(horse.truth.body_volume, rel=0.01)


@pytest.mark.parametrize("preset", ["horse", "dog", "elephant"])
def test_a_seated_animal_sits_on_one_ground_its_body_turned_up(posed, preset):
    """Seated, the fore feet stand on the ground the folded hind legs rest on, the fore legs upright,
    the body turned nose-up about its hips (the pitch solved for each animal's proportions), set
    down on the standing animal's ground; the legs below their joints keep their shape."""
    standing, seated = posed(preset, "stand"), posed(preset, "sit")
    height = np.ptp(standing.vertices[:, 1])
    y = seated.vertices[:, 1]
    fore, hind = (seated.labels == REGION_NAMES.index(name) for name in ("forelimbs", "hindlimbs"))
    assert abs(y[fore].min() - y[hind].min()) < 0.005 * height
    assert y.min() == pytest.approx(standing.vertices[:, 1].min(), abs=1e-9)
    chest, abdomen = (seated.vertices[seated.labels == REGION_NAMES.index(name)].mean(axis=0) for name in ("chest", "abdomen"))
    rise = np.degrees(np.arctan2(chest[1] - abdomen[1], chest[0] - abdomen[0]))
    assert rise > 10.0                                               # the chest above the belly: sitting up
    leg = np.flatnonzero(fore & (standing.vertices[:, 2] > 0)
                         & (standing.vertices[:, 1] < 0.5 * standing.truth.leg_cut_height["forelimbs"]))
    top, bottom = leg[np.argmax(y[leg])], leg[np.argmin(y[leg])]
    upright = seated.vertices[top] - seated.vertices[bottom]
    assert abs(upright[0]) < 0.25 * np.linalg.norm(upright)            # a fore leg stands within ~15° of upright
    pairs = np.random.default_rng(1).choice(leg, size=(200, 2))
    np.testing.assert_allclose(np.linalg.norm(seated.vertices[pairs[:, 0]] - seated.vertices[pairs[:, 1]], axis=1),
                               np.linalg.norm(standing.vertices[pairs[:, 0]] - standing.vertices[pairs[:, 1]], axis=1),
                               atol=1e-9)


def test_an_animal_whose_fore_legs_are_too_long_to_sit_is_refused():
    from allorules.errors import AllorulesError

    with pytest.raises(AllorulesError, match="cannot sit.*choose another pose"):
        generate_quadruped("giraffe", 1500, pose="sit")


def test_an_unknown_pose_is_a_clear_error():
    from allorules.mesh.quadruped import QuadrupedParameterError

    with pytest.raises(QuadrupedParameterError, match="unknown pose 'dance'.*stand"):
        generate_quadruped("dog", 1500, pose="dance")


# ---------------------------------------------------------------- labels in poses

POSED_CASES = [(preset, pose) for preset in ("horse", "dog") for pose in ("stand", "walk", "gallop", "rear", "lie", "curl")]


@pytest.mark.parametrize("preset,pose", POSED_CASES)
def test_labels_agree_with_the_truth_in_six_poses_turned_at_random(posed, preset, pose):
    """Measured (2000 vertices, turned at random): horse 0.959/0.953/0.954/0.968/0.959/0.955,
    dog 0.982/0.972/0.969/0.966/0.970/0.975 (stand, walk, gallop, rear, lie, curl)."""
    animal = posed(preset, pose)
    matrix = random_rotation(hash((preset, pose)) % 1000)
    labelled = label_quadruped(Body(animal.vertices @ matrix.T, animal.faces))
    assert agreement(animal, labelled) >= 0.95


def test_a_sitting_horse_refused_is_labelled_as_its_refusal_says(posed):
    """Sitting (its chest up on straight fore legs, its rump on the ground), the horse's feet are in
    doubt (its tail's tip lies on the ground by its folded hind feet); the refusal names the
    directions that settle it, and given them (as a user who knows the file's axes gives them) the
    labels agree with the truth: 0.972 (0.898 while the torso was split across the level forward
    direction rather than along its girdles' chord)."""
    animal = posed("horse", "sit")
    matrix = random_rotation(2)
    body = Body(animal.vertices @ matrix.T, animal.faces)
    with pytest.raises(SegmentationError, match="feet") as refused:
        label_quadruped(body)
    assert "--up DIR and --forward DIR" in str(refused.value)
    labelled = label_quadruped(body, up=matrix @ [0.0, 1.0, 0.0], forward=matrix @ [1.0, 0.0, 0.0])
    assert agreement(animal, labelled) >= 0.95


@pytest.mark.parametrize("seed, turn", [(0, 2), (1, 3)])
def test_a_sitting_elephant_is_labelled_as_sitting(seed, turn):
    """The elephant seated, its girdles only 17-18° from level on its short legs: read as standing
    (a level fore girdle plane, its head end and rump alike in mass) it was refused, head or tail;
    read as far seated as it sits (body_plan.seated_share) it is labelled, 0.892 and 0.900 turned
    at random (given --up and --forward before, 0.866)."""
    animal = generate_quadruped("elephant", 2000 + 500 * seed, pose="sit", seed=seed)
    matrix = random_rotation(turn)
    labelled = label_quadruped(Body(animal.vertices @ matrix.T, animal.faces))
    assert agreement(animal, labelled) >= 0.88


@pytest.mark.parametrize("seed", [2, 7])
def test_a_sitting_dog_is_labelled_right_turned_at_random(posed, seed):
    """The dog seated, its girdles 32° from level: its ends are read across the chord between them
    (where they were read across the level spine, its head end lost its neck and the mass cue
    pointed at the rump: refused, "mass +1.00 ... thickness -1.00"), its torso split along it:
    0.970 at both turns."""
    animal = posed("dog", "sit")
    matrix = random_rotation(seed)
    labelled = label_quadruped(Body(animal.vertices @ matrix.T, animal.faces))
    assert labelled.labelling.notes[0].startswith("head-tail cues")
    assert agreement(animal, labelled) >= 0.95


@pytest.mark.slow
@pytest.mark.parametrize("pose", ["stand", "walk", "rear", "lie", "curl"])
def test_the_giraffe_in_poses(posed, pose):
    """Measured: 0.964/0.967/0.978/0.975/0.961. (Galloping: 0.886, its head and neck from the rings.)"""
    animal = posed("giraffe", pose)
    labelled = label_quadruped(Body(animal.vertices @ random_rotation(5).T, animal.faces))
    assert agreement(animal, labelled) >= 0.95


@pytest.mark.slow
@pytest.mark.parametrize("preset,pose", [(p, q) for p in ("horse", "dog", "giraffe", "elephant")
                                         for q in ("sit", "graze", "gallop", "walk", "lie")
                                         if (p, q) != ("giraffe", "sit")])
def test_every_pose_is_labelled_right_or_refused_never_swapped(posed, preset, pose):
    """Where the poses are hard (sitting, grazing, the elephant's short thick legs), the labels
    may be rough or refused, but the head is never taken for the tail nor a fore leg for a hind one."""
    animal = posed(preset, pose)
    try:
        labelled = label_quadruped(Body(animal.vertices, animal.faces))
    except SegmentationError as error:
        assert "\n" not in str(error)
        return
    six = fold_regions(labelled)
    truth = fold_regions(animal.body())
    mass = vertex_areas(animal.vertices, animal.faces)
    for region in ("head", "forelimbs", "hindlimbs"):
        mine = truth.labels == QUADRUPED_REGIONS.index(region)
        found = six.labels == QUADRUPED_REGIONS.index(region)
        assert mass[mine & found].sum() > 0.5 * mass[mine].sum(), f"{region} not found where it is"
    assert agreement(animal, labelled) >= 0.7


# ---------------------------------------------------------------- horns

def _feature(flatness_at, rings: int = 60, around: int = 48):
    """A feature one unit long along z, open at its root (z = 0) and closed at its tip (z = 1):
    elliptic rings whose long axis over short axis is ``flatness_at(distance from the tip)``; and
    that distance (1 − z)."""
    vertices, faces = [], []
    angle = np.linspace(0, 2 * np.pi, around, endpoint=False)
    for i in range(rings):
        height = 0.99 * i / (rings - 1)                         # from the root to just below the tip
        distance = 1.0 - height
        width = 0.15 * np.sqrt(distance)
        ratio = flatness_at(distance)
        vertices += [[width * np.sqrt(ratio) * np.cos(a), width / np.sqrt(ratio) * np.sin(a), height] for a in angle]
    vertices.append([0.0, 0.0, 1.0])
    for i in range(rings - 1):
        for k in range(around):
            a, b = i * around + k, i * around + (k + 1) % around
            faces += [[a, b, b + around], [a, b + around, a + around]]
    tip = len(vertices) - 1
    faces += [[(rings - 1) * around + k, (rings - 1) * around + (k + 1) % around, tip] for k in range(around)]
    vertices = np.array(vertices)
    return vertices, np.array(faces), 1.0 - vertices[:, 2]


def test_an_ear_flat_near_its_tip_is_flat_and_a_horn_is_not():
    """An ear is flattest near its tip: one ring of a game donkey's ear read 1.87 at 136k vertices
    (2.6 as it comes) and the ear was taken for a horn. Its flatter ring of two is read."""
    ear = _feature(lambda distance: 1.2 + 4.0 * np.exp(-distance / 0.1))    # reads 2.44 at 0.075, 1.77 at 0.15
    horn = _feature(lambda distance: 1.15)
    assert body_plan.ring_flatness(*ear, 0.15) < body_plan.FLAT_APPENDAGE      # the one ring read before
    assert body_plan.feature_flatness(*ear, 1.0) >= body_plan.FLAT_APPENDAGE
    assert body_plan.feature_flatness(*horn, 1.0) < body_plan.FLAT_APPENDAGE


@pytest.mark.parametrize("left,right", [(1.9, 2.3), (1.9, 1.95)])
def test_twins_straight_across_the_body_are_one_kind(monkeypatch, left, right):
    """A TOSCA horse's two ears, each near the line between ear and horn, were named one ears and
    one horns. Twins are read as a pair: here a generated dog's thin horns are made to read flat
    on one side only (1.9 and 2.3: both ears) or not at all (both horns)."""
    animal = generate_quadruped("dog", 3000, horn_length=0.3, horn_radius=0.03)
    flatness = body_plan.feature_flatness

    def one_side_flat(vertices, faces, field, reach):
        tip = int(np.argmin(field))
        if np.isin(tip, np.concatenate(horn_vertices(animal))):
            return left if vertices[tip, 2] > 0 else right
        return flatness(vertices, faces, field, reach)

    monkeypatch.setattr(body_plan, "feature_flatness", one_side_flat)
    labelled = label_quadruped(Body(animal.vertices, animal.faces))
    kinds = [set(np.array(labelled.region_names)[labelled.labels[horn]]) - {"head"} for horn in horn_vertices(animal)]
    expected = {"ears"} if (left + right) / 2 >= body_plan.FLAT_APPENDAGE else {"horns"}
    assert kinds == [expected, expected]


@pytest.mark.parametrize("angle", [80, 120])
def test_a_horn_is_not_taken_for_the_nose(angle):
    """Two horns as long as the dog's head, out sideways (80°) or down (120°): a horn, the most
    prominent tip of the head end, was its main tip, so that at 120° one horn was labelled head
    and the head itself neck (agreement 0.797). A horn has a twin straight across the body, a nose
    none. Measured: 0.986 and 0.970."""
    animal = generate_quadruped("dog", 3000, horn_length=0.25, horn_radius=0.05, horn_angle=angle)
    turned = random_rotation(angle)
    labelled = label_quadruped(Body(animal.vertices @ turned.T, animal.faces))
    assert agreement(animal, labelled) >= 0.95
    mass = vertex_areas(animal.vertices, animal.faces)
    for horn in horn_vertices(animal):
        assert mass[horn][labelled.labels[horn] == labelled.region_names.index("head")].sum() < 0.5 * mass[horn].sum()


@pytest.mark.parametrize("pose,angle", [("graze", 30), ("graze", 80), ("stand", 30), ("stand", 80)])
def test_horns_longer_than_the_head_are_no_feet(pose, angle):
    """Grazing, a dog with horns longer than its head rests on a plane through its forefeet and
    its horns' tips as well as on its ground; the horns (more prominent than legs) were taken for
    hind legs and head and tail swapped (agreement 0.318 and 0.304); standing, it was refused (the
    horns as feet within 0.12 of its legs). Feet are at the end of legs reaching down to their
    ground, the horns reach along that plane. Measured: 0.926, 0.968, 0.976, 0.984."""
    animal = generate_quadruped("dog", 3000, pose=pose, horn_length=0.45, horn_radius=0.05, horn_angle=angle)
    labelled = label_quadruped(Body(animal.vertices @ random_rotation(angle + 1).T, animal.faces))
    assert agreement(animal, labelled) >= 0.9


@pytest.mark.parametrize("preset,horn_length,horn_radius", [("dog", 0.25, 0.05), ("horse", 0.3, 0.06)])
def test_a_head_taken_for_a_leg_is_told_by_its_horns(preset, horn_length, horn_radius):
    """A cat leaping, its fore legs stretched out, one beside its nose, had its nose taken for a
    foot and its head for that foot's leg (then its tail for its head, every cue sure of it). A
    leg carries no pair of ears or horns: the head and neck read as the nose's "leg" are found out
    (the horns 0.56-0.95 of it from the nose, twins unlike in prominence but alike in girth), the
    four true legs are not, nor is a hornless head (nothing to tell it by). A horn the "leg"'s cut
    left out counts where it lies within the leg's length of the "foot"."""
    from allorules.segment.labeller import vertex_graph

    def read(animal):
        graph = vertex_graph(animal.vertices, animal.faces)
        return body_plan.read_extremities(graph, vertex_areas(animal.vertices, animal.faces), animal.vertices, animal.faces)

    def legs_and_feet(animal, extremities):
        names = np.array(animal.region_names)[animal.labels]
        tips = [int(t) for t in extremities.vertices]
        legs, feet = np.full(len(animal.vertices), -1), []
        for name in ("forelimbs", "hindlimbs"):
            for side in (animal.vertices[:, 2] > 0, animal.vertices[:, 2] < 0):
                leg = (names == name) & side
                foot = min((t for t in tips if leg[t]), key=lambda t: animal.vertices[t, 1])
                legs[leg] = foot
                feet.append(foot)
        head = (names == "head") | (names == "neck")
        horns = np.zeros(len(animal.vertices), dtype=bool)
        for horn in horn_vertices(animal):
            horns[horn] = True
        nose = max((t for t in tips if names[t] == "head" and not horns[t]), key=lambda t: animal.vertices[t, 0])
        as_leg = np.full(len(animal.vertices), -1)
        as_leg[head] = nose
        return legs, feet, as_leg, nose

    horned = generate_quadruped(preset, 3000, horn_length=horn_length, horn_radius=horn_radius)
    extremities = read(horned)
    legs, feet, head_as_leg, nose = legs_and_feet(horned, extremities)
    assert body_plan.head_taken_for_a_leg(extremities, head_as_leg, [nose], horned.vertices, horned.faces) == nose
    # the "leg"'s cut across the head may leave one horn out (the leaping cat split twice at its
    # edges' midpoints: one ear on its "leg", the other beside it, and its head found on its tail)
    one_horn_out = head_as_leg.copy()
    one_horn_out[list(horn_vertices(horned))[0]] = -1
    assert body_plan.head_taken_for_a_leg(extremities, one_horn_out, [nose], horned.vertices, horned.faces) == nose
    assert body_plan.head_taken_for_a_leg(extremities, legs, feet, horned.vertices, horned.faces) is None
    plain = generate_quadruped(preset, 3000)
    extremities = read(plain)
    legs, feet, head_as_leg, nose = legs_and_feet(plain, extremities)
    assert body_plan.head_taken_for_a_leg(extremities, head_as_leg, [nose], plain.vertices, plain.faces) is None
    assert body_plan.head_taken_for_a_leg(extremities, legs, feet, plain.vertices, plain.faces) is None


@pytest.mark.parametrize("preset,horn_length,horn_radius", [("dog", 0.25, 0.05), ("horse", 0.3, 0.06)])
def test_ears_or_horns_in_the_chest_are_found(preset, horn_length, horn_radius):
    """Chest and abdomen carry no pair of ears or horns: a real elephant told its forward direction
    had its trunk labelled head and its head, ears and all, chest. On the generated horned head:
    labelled right, none in the torso; the head given to the chest, its horns found there (twins
    unlike in prominence, alike in girth); a hornless head given to the chest, nothing to find."""
    from allorules.segment.labeller import vertex_graph

    for animal, horned in ((generate_quadruped(preset, 3000, horn_length=horn_length, horn_radius=horn_radius), True),
                           (generate_quadruped(preset, 3000), False)):
        extremities = body_plan.read_extremities(vertex_graph(animal.vertices, animal.faces),
                                                 vertex_areas(animal.vertices, animal.faces), animal.vertices, animal.faces)
        names = np.array(animal.region_names)[animal.labels]
        torso = (names == "chest") | (names == "abdomen")
        assert body_plan.features_in(extremities, torso, animal.vertices, animal.faces) is None
        found = body_plan.features_in(extremities, torso | (names == "head"), animal.vertices, animal.faces)
        if horned:
            horns = horn_vertices(animal)
            assert found is not None and {bool(np.isin(tip, horns[0])) for tip in found} == {True, False}
            assert all(np.isin(tip, np.concatenate(horns)) for tip in found)
        else:
            assert found is None


def test_a_flat_tail_behind_a_faint_bump_is_what_the_thickness_cue_measures(monkeypatch):
    """A realistic elephant's tail is a flat sheet, an appendage by its ring as an ear is, so the
    tail end's main tip was a faint bump on its rump (persistence 0.03) and the thickness cue
    measured the rump's rings: head or tail refused (thickness −0.66). The generated elephant, its
    tail flattened into a sheet and a faint tip put on its rump where the AGD found the real one's:
    refused before, now labelled right, the thickness cue for the head end."""
    from scipy.sparse.csgraph import dijkstra

    animal = generate_quadruped("elephant", 3000)
    vertices = animal.vertices.copy()
    tail = animal.labels == REGION_NAMES.index("tail")
    root = vertices[tail][np.argsort(vertices[tail][:, 0])[-5:]].mean(axis=0)
    vertices[tail, 2] = root[2] + 0.15 * (vertices[tail, 2] - root[2])      # a sheet, across the body
    abdomen = np.flatnonzero(animal.labels == REGION_NAMES.index("abdomen"))
    rear = abdomen[vertices[abdomen, 0] < np.percentile(vertices[abdomen, 0], 3)]
    bump = int(rear[np.argmax(vertices[rear, 2])])                            # on a buttock, beside the tail
    read = body_plan.read_extremities

    def with_a_bump(graph, mass, vertices, faces):
        found = read(graph, mass, vertices, faces)
        fields = dict(found.distance)
        fields[bump] = dijkstra(graph, indices=bump)
        return body_plan.Extremities(np.append(found.vertices, bump), np.append(found.persistence, 0.028),
                                     np.append(found.agd, 0.7), fields, found.contrast)

    monkeypatch.setattr(body_plan, "read_extremities", with_a_bump)
    labelled = label_quadruped(Body(vertices, animal.faces))
    assert agreement(animal, labelled) > 0.9
    assert "thickness +1.00" in labelled.labelling.notes[0]


def _elephant_cut_at_its_trunk(monkeypatch):
    """The generated horned elephant (horns for ears) whose labeller cuts its head by hand at the
    trunk: a fifth of its head left as head, the rest and its horns chest. Returns the animal, its
    true names, its true head, its vertex areas and the geodesic distance from its nose."""
    from scipy.sparse.csgraph import dijkstra

    from allorules.segment import labeller

    animal = generate_quadruped("elephant", 3000, horn_length=0.8, horn_radius=0.12)
    names = np.array(animal.region_names)[animal.labels]
    head = names == "head"
    mass = vertex_areas(animal.vertices, animal.faces)
    nose = int(np.flatnonzero(head)[np.argmax(animal.vertices[head, 0])])
    from_nose = dijkstra(labeller.vertex_graph(animal.vertices, animal.faces), indices=nose)
    reach = from_nose[head].max()
    split = labeller._split_torso

    def cut_at_the_trunk(vertices, faces, graph, mass, axis, labels, ends, head_tip):
        split(vertices, faces, graph, mass, axis, labels, ends, head_tip)
        labels[np.isin(labels, (labeller.HEAD, labeller.NECK))] = labeller.CHEST
        labels[head & (from_nose < 0.4 * reach)] = labeller.HEAD
        labels[head & (from_nose >= 0.4 * reach) & (from_nose < 0.5 * reach)] = labeller.NECK

    monkeypatch.setattr(labeller, "_split_torso", cut_at_the_trunk)
    assert mass[head & (from_nose < 0.4 * reach)].sum() < 0.25 * mass[head].sum()
    return animal, names, head, mass, from_nose


def _head_taken_back_whole(labelled, names, head, mass, share: float = 0.8) -> None:
    found = np.array(labelled.region_names)[labelled.labels]
    as_head = np.isin(found, ("head", "horns", "ears", "trunk"))
    assert mass[head & as_head].sum() > share * mass[head].sum()
    assert labelled.region_mask("neck").any()
    assert not (as_head | (found == "neck"))[names == "abdomen"].any()


def test_a_head_cut_at_its_trunk_takes_its_ears_back_from_the_chest(monkeypatch):
    """A realistic elephant's head was cut where its trunk meets it: the trunk labelled head, the
    head with its ears (hanging back behind the fore girdle's plane) chest, and so refused. The
    generated horned elephant, its head cut by hand at the trunk (:func:`_elephant_cut_at_its_trunk`):
    refused before; now the head is taken back to just behind its horns (0.85 of the true head;
    0.93 as the labeller cuts it itself), a neck behind it, nothing of the abdomen taken."""
    animal, names, head, mass, _ = _elephant_cut_at_its_trunk(monkeypatch)
    _head_taken_back_whole(label_quadruped(Body(animal.vertices, animal.faces)), names, head, mass)


def test_an_ear_followed_past_its_root_does_not_take_the_head_into_the_body(monkeypatch):
    """A realistic elephant's ear hangs over its shoulder, and followed from its tip its root was
    found as far back as its fore legs' tops where its twin's lay on its head: its head and neck
    were taken back to there, ran on into its abdomen, were left as cut, and the elephant refused.
    A mirrored pair's head ends at its nearer twin's root (``labeller.features_reach``). The
    horned elephant cut at its trunk, one horn's root found at the back of its chest: labelled as
    with both found right, but for the nearer root (0.80 of its true head for 0.85)."""
    from allorules.segment import labeller

    animal, names, head, mass, from_nose = _elephant_cut_at_its_trunk(monkeypatch)
    chest = np.flatnonzero(names == "chest")
    far_back = animal.vertices[chest[np.argmax(from_nose[chest])]]     # the chest's end behind the fore legs
    follow, overshot = labeller._follow_tip, []

    def followed_past_its_root(vertices, faces, graph, tip, field, span):
        followed = follow(vertices, faces, graph, tip, field, span)
        if followed is None or overshot or names[tip] != "head":    # a horn's tip (horns are the true head's)
            return followed
        overshot.append(tip)
        core, axis, centre, length, root, rest = followed
        return core, axis, far_back + (centre - root), length, far_back, rest

    monkeypatch.setattr(labeller, "_follow_tip", followed_past_its_root)
    labelled = label_quadruped(Body(animal.vertices, animal.faces))
    assert overshot
    _head_taken_back_whole(labelled, names, head, mass, share=0.75)    # to its other horn's root: 0.80
    reach = labeller.features_reach
    assert reach({1: 0.70, 2: 0.52, 3: 0.30}, [(1, 2)]) == 0.52            # one twin followed past its root
    assert reach({1: 0.44, 2: 0.42, 3: 0.30}, [(1, 2)]) == 0.44            # twins alike: the farther
    assert reach({1: 0.7, 3: 0.4}, [(1, 2)]) == 0.7                        # a twin not followed
    assert reach({}, [(1, 2)]) == 0.0


def test_a_feature_whose_rings_run_into_the_head_ends_near_its_tip(monkeypatch):
    """A faceted bison's face slopes down into its hump. Its ears, followed from their tips, had
    their rings run up its face and into the hump: a ring radius 0.99 of the tip's distance from
    the nose (the features followed right on the shared and held-out animals: up to 0.22), a root
    2.2 times as far from the nose as the tip (up to 1.17). The head was taken back to that "root"
    and took its throat and hump (29 % of its surface); both ears alike, so the twins' rule could
    not catch it. Such a feature now ends ``labeller.ROOT_BEYOND_TIP`` times its tip's distance
    from the nose. The horned elephant cut at its trunk, given one more feature in the neck the
    cut leaves, its rings as wide as its distance from the nose and their root at the back of its
    chest: labelled as without it (before: its head ran into its abdomen, and it was refused)."""
    from scipy.sparse.csgraph import dijkstra

    from allorules.segment import labeller

    animal, names, head, mass, from_nose = _elephant_cut_at_its_trunk(monkeypatch)
    reach = from_nose[head].max()
    neck = np.flatnonzero(head & (from_nose >= 0.4 * reach) & (from_nose < 0.5 * reach))
    cheek = int(neck[np.argmax(animal.vertices[neck, 1])])   # on one side of the head
    chest = np.flatnonzero(names == "chest")
    far_back = animal.vertices[chest[np.argmax(from_nose[chest])]]
    holds, follow, followed_cheek = labeller._head_holds_its_features, labeller._follow_tip, []

    def with_a_cheek(vertices, faces, graph, mass, labels, ends, head_tip, distance):
        assert labels[cheek] == labeller.NECK
        ends.head.features[cheek] = "flat"
        distance[cheek] = dijkstra(graph, indices=cheek)
        try:
            holds(vertices, faces, graph, mass, labels, ends, head_tip, distance)
        finally:
            del ends.head.features[cheek]

    def into_the_head(vertices, faces, graph, tip, field, span):
        followed = follow(vertices, faces, graph, tip, field, span)
        if tip != cheek or followed is None:
            return followed
        followed_cheek.append(tip)
        core, axis, _, length, _, rest = followed
        radius = float(from_nose[cheek])          # as wide as its tip lies from the nose
        return core, axis, far_back - radius * axis, length, far_back, rest

    monkeypatch.setattr(labeller, "_head_holds_its_features", with_a_cheek)
    monkeypatch.setattr(labeller, "_follow_tip", into_the_head)
    labelled = label_quadruped(Body(animal.vertices, animal.faces))
    assert followed_cheek
    _head_taken_back_whole(labelled, names, head, mass)


def _sphere_with_a_well_and_a_spike():
    """A unit sphere with a deep, narrow well pushed in at +z (the inside of an open mouth) and a
    spike pulled out at −z (a protrusion)."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=5)
    vertices, faces = np.asarray(sphere.vertices, dtype=float), np.asarray(sphere.faces, dtype=np.int64)
    from_top = np.arccos(np.clip(vertices[:, 2], -1.0, 1.0))
    radius = (1.0 - 0.8 * np.sqrt(np.clip(1.0 - (from_top / 0.2) ** 2, 0.0, None))
              + 0.8 * np.clip(1.0 - (np.pi - from_top) / 0.3, 0.0, None))
    return vertices * radius[:, None], faces


def test_the_end_of_a_well_is_a_cavity_and_a_spikes_tip_is_not():
    """The AGD peaks at the end of a modelled mouth as at a nose (the TOSCA horses' mouths were
    their heads' tips): the end of a well is enclosed and concave, a spike's tip and a point of the
    sphere are not; a surface turned inside out has no cavity (its normals would make all one)."""
    from allorules.segment.labeller import vertex_graph

    vertices, faces = _sphere_with_a_well_and_a_spike()
    direction = vertices / np.linalg.norm(vertices, axis=1)[:, None]
    tips = [int(np.argmax(direction[:, 2])), int(np.argmin(direction[:, 2])), int(np.argmax(direction[:, 0]))]
    fields = body_plan.geodesic_fields(vertex_graph(vertices, faces), tips)
    assert body_plan.cavity_ends(vertices, faces, tips, fields).tolist() == [True, False, False]
    assert not body_plan.cavity_ends(vertices, faces[:, ::-1], tips, fields).any()


def test_a_yielding_maximum_gives_its_prominence_to_the_one_it_meets():
    """Persistence on a path 0, 2, 1, 5, 4.5, 0: the peak 5 lives to the end (5), the peak 2 dies
    where they meet at 1 (persistence 1). The peak 5 yielding (a cavity's end) dies there instead
    (4) and the peak 2 carries on to the end (2)."""
    from scipy.sparse import coo_matrix

    values = np.array([0.0, 2.0, 1.0, 5.0, 4.5, 0.0])
    a, b = np.arange(len(values) - 1), np.arange(1, len(values))
    graph = coo_matrix((np.ones(2 * len(a)), (np.r_[a, b], np.r_[b, a])), shape=(len(values),) * 2).tocsr()
    tips, persistence = body_plan.persistent_maxima(values, graph)
    assert dict(zip(tips.tolist(), persistence.tolist())) == {3: 5.0, 1: 1.0}
    tips, persistence = body_plan.persistent_maxima(values, graph, yielding=[3])
    assert dict(zip(tips.tolist(), persistence.tolist())) == {1: 2.0, 3: 4.0}


LEAP = Pose(swing={"fore-left": 80, "fore-right": 70, "hind-left": -80, "hind-right": -70}, neck=-30, head=-20, tail=10)


def test_a_horned_dog_leaping_is_labelled_right_given_its_directions():
    """Leaping, fore and hind legs stretched out level, a dog with horns is labelled right once
    its up and forward are given (docs/segmentation.md, known limits). Measured: 0.864."""
    animal = generate_quadruped("dog", 3000, pose=LEAP, horn_length=0.2, horn_radius=0.05)
    labelled = label_quadruped(Body(animal.vertices, animal.faces), up=(0, 1, 0), forward=(1, 0, 0))
    assert agreement(animal, labelled) >= 0.85


def test_a_horned_horse_leaping_is_refused_not_labelled_wrong():
    """Leaping, its horns and fore feet all reaching forward to one plane, the horse had them for its
    four feet (the ground's bonus) and its head and tail swapped (agreement 0.333); the bonus now
    counts only for legs alike in length (the horns' 'legs' 0.35 of the fore legs')."""
    animal = generate_quadruped("horse", 3000, pose=LEAP, horn_length=0.3, horn_radius=0.06)
    try:
        labelled = label_quadruped(Body(animal.vertices, animal.faces))
    except SegmentationError as error:
        assert "feet" in str(error)
        return
    assert agreement(animal, labelled) >= 0.85


def test_a_horned_dog_leaping_is_labelled_right_or_refused():
    """Its horns as long as its short legs, the dog leaping had its horns and fore feet for its four
    feet (agreement 0.378) and its hind legs for its head's ears, where the ground's bonus for legs
    alike in length did not help: a pair left out that stands out more than a foot taken, as only
    legs do, now refuses it (docs/segmentation.md)."""
    animal = generate_quadruped("dog", 3000, pose=LEAP, horn_length=0.2, horn_radius=0.05)
    try:
        labelled = label_quadruped(Body(animal.vertices, animal.faces))
    except SegmentationError as error:
        assert "a pair left out" in str(error) and "--up" in str(error)
        return
    assert agreement(animal, labelled) >= 0.85


def test_a_pair_left_out_on_the_midplane_is_no_pair_of_legs_once_the_sides_are_known():
    """A low-poly horse's tail of strands hanging to its hocks had two strands' tips for a pair of
    tips left out that stands out more than a hoof (0.79 and 0.67, the hoof 0.67), as only legs do,
    and stayed refused with the up and forward the refusal asks for. Given them, a pair of legs lies
    on either side of the body's midplane, about as far apart as the feet of a pair: two tips on it,
    or beside each other across it, are no pair of legs; mirrored as feet are, they are."""
    tips = body_plan._Tips(vertices=np.arange(6), persistence=np.array([0.9, 0.9, 0.8, 0.67, 0.79, 0.75]),
                           agd=np.array([0.9, 0.9, 0.9, 0.9, 0.8, 0.8]), flatness=np.ones(6),
                           pointing=np.tile([0.0, -1.0, 0.0], (6, 1)))
    d = np.full((6, 6), 1.0) - np.eye(6)
    feet, other = (0, 1), (2, 3)
    assert body_plan._pair_left_out(tips, d, feet, other) == (0.79, 0.75, 0.67)   # sides unknown: legs
    on_the_midplane = np.array([-0.3, 0.3, -0.3, 0.3, 0.01, -0.02])
    assert body_plan._pair_left_out(tips, d, feet, other, on_the_midplane) is None
    mirrored = np.array([-0.3, 0.3, -0.3, 0.3, -0.25, 0.28])
    assert body_plan._pair_left_out(tips, d, feet, other, mirrored) == (0.79, 0.75, 0.67)
    side_by_side = np.array([-0.3, 0.3, -0.3, 0.3, -0.02, 0.04])   # either side, but a tail's width apart
    assert body_plan._pair_left_out(tips, d, feet, other, side_by_side) is None


def test_a_pair_of_flat_sheets_left_out_is_no_pair_of_legs():
    """A held-out elephant's big ears (ring flatness 4.5 and 7.6) stood out more than its hind feet
    (0.32 and 0.31 against 0.28) and refused it as a pair of legs left out; legs are tubes."""
    flatness = np.array([1.1, 1.2, 1.2, 1.2, 4.5, 7.6])
    tips = body_plan._Tips(vertices=np.arange(6), persistence=np.array([0.45, 0.45, 0.28, 0.28, 0.32, 0.31]),
                           agd=np.array([0.55, 0.55, 0.75, 0.75, 0.5, 0.49]), flatness=flatness,
                           pointing=np.tile([0.0, -1.0, 0.0], (6, 1)))
    d = np.full((6, 6), 1.0) - np.eye(6)
    assert body_plan._pair_left_out(tips, d, (0, 1), (2, 3)) is None
    tubes = body_plan._Tips(tips.vertices, tips.persistence, tips.agd, np.full(6, 1.2), tips.pointing)
    assert body_plan._pair_left_out(tubes, d, (0, 1), (2, 3)) == (0.32, 0.31, 0.28)


def test_given_forward_a_pair_at_the_tail_end_is_no_head_left_in_the_body(monkeypatch):
    """Ears or horns left in the chest or abdomen refuse a labelling: the head was not found whole,
    or head and tail were swapped. Given --forward the ends are the user's, and a pair of tips at the
    tail end is the tail's (the low-poly horse's strands, two left in its abdomen beside the one cut
    out as its tail; told forward alone, it is labelled). The generated horse, a pair "found"
    wherever the region asked about holds the back of its rump: refused without forward, labelled
    right with it."""
    animal = generate_quadruped("horse", 3000)
    names = np.array(animal.region_names)[animal.labels]
    behind = np.flatnonzero((names == "abdomen") & (animal.vertices[:, 0] < animal.vertices[names == "hindlimbs", 0].min()))
    rump = behind[np.argmax(animal.vertices[behind, 1])]     # its rump's top behind its hind legs (it faces +x)
    found = body_plan.features_in

    def strands_at_the_rump(extremities, region, vertices, faces):
        return (int(rump), int(rump)) if region[rump] else found(extremities, region, vertices, faces)

    monkeypatch.setattr(body_plan, "features_in", strands_at_the_rump)
    body = Body(animal.vertices, animal.faces)
    with pytest.raises(SegmentationError, match="ears or horns was labelled chest or abdomen.*--forward DIR"):
        label_quadruped(body)      # (the refusal says what settles it)
    assert agreement(animal, label_quadruped(body, forward=(1, 0, 0))) >= 0.95


# ---------------------------------------------------------------- the head/tail cues, one by one

@pytest.mark.parametrize("preset,pose", [("horse", "stand"), ("horse", "gallop"), ("dog", "rear"), ("dog", "curl"),
                                         ("giraffe", "lie"), ("elephant", "stand")])
def test_each_cue_points_at_the_head_on_generated_animals(posed, preset, pose, monkeypatch):
    """The cues are independent: each (where it has something to say) picks the generator's head
    end on its own. The generated animals have no ears, so 'features' stays silent there."""
    animal = posed(preset, pose)
    seen = {}
    decide = body_plan.decide_head

    def spy(first, second, forward_hint=None, vertices=None):
        decision = decide(first, second, forward_hint, vertices)
        seen["decision"] = decision
        return decision

    monkeypatch.setattr(body_plan, "decide_head", spy)
    label_quadruped(Body(animal.vertices, animal.faces))
    decision = seen["decision"]
    head = REGION_NAMES.index("forelimbs")
    assert all(animal.labels[foot] == head for foot in decision.head.pair)   # the chosen head end is the front
    assert decision.cues["mass"] > 0.25
    assert decision.cues["thickness"] > 0.25
    assert decision.cues["features"] == 0.0


def _end(area, thickness, mirror=False, protrudes=True, toes=None):
    return body_plan.End(pair=(0, 1), girdle=0, centre=np.zeros(3), region=np.zeros(1, dtype=bool), area=area,
                         tips=[2], main_tip=2, mirror_pairs=[(3, 4)] if mirror else [], thickness=thickness,
                         prominence=1.0 if protrudes else 0.0, toes=toes)


def test_cues_that_disagree_refuse_instead_of_guessing():
    # more surface at the first end, but a thicker protrusion and the ears at the second
    with pytest.raises(SegmentationError, match="disagree") as refused:
        body_plan.decide_head(_end(2.0, 0.1), _end(1.0, 0.4, mirror=True))
    assert "--forward" in str(refused.value) and "merge file" in str(refused.value)
    # one cue alone is not enough, however strong
    with pytest.raises(SegmentationError, match="at least two"):
        body_plan.decide_head(_end(3.0, 0.2), _end(1.0, 0.2))
    # agreeing cues decide, and the user's --forward overrides them
    decision = body_plan.decide_head(_end(2.0, 0.4, mirror=True), _end(1.0, 0.1))
    assert decision.head.area == 2.0 and decision.margin > 1.5


def test_an_end_with_almost_nothing_beyond_its_legs_is_refused():
    settle = body_plan.settle_feet(None, None)
    with pytest.raises(SegmentationError, match="almost nothing of the body lies beyond") as refused:
        body_plan.check_ends(_end(1.0, 0.2), _end(0.05, 0.1), settle)
    assert "5.0%" in str(refused.value) and "--up" in str(refused.value) and "merge file" in str(refused.value)
    with pytest.raises(SegmentationError, match="almost nothing"):        # whichever end it is
        body_plan.check_ends(_end(0.05, 0.1), _end(1.0, 0.2), settle)
    body_plan.check_ends(_end(1.0, 0.2), _end(0.17, 0.1), settle)          # the smallest real share seen


def test_an_upright_toy_bear_is_refused_not_labelled():
    from pieces import upright_toy_bear

    from allorules.runs.pipeline import input_regions

    # its arms and legs (or ears) make four feet, but nothing lies beyond its hips
    with pytest.raises(SegmentationError, match="almost nothing of the body lies beyond"):
        input_regions(upright_toy_bear(), working_vertices=3000)


def test_toes_are_a_weak_cue_that_can_be_the_second_to_agree():
    # a fox: its bushy tail as heavy and as thick as its head, its ears at the second end
    fox = (_end(1.05, 0.30), _end(1.0, 0.25, mirror=True))
    with pytest.raises(SegmentationError, match="at least two"):
        body_plan.decide_head(*fox)
    # standing, its paws reach 2 leg radii towards its head: the second end
    decision = body_plan.decide_head(*(replace(end, toes=toes) for end, toes in zip(fox, (-2.0, 2.0))))
    assert decision.head is not fox[0] and decision.head.mirror_pairs
    assert decision.cues["toes"] == pytest.approx(body_plan.TOES_CUE)
    # toes that barely reach (a generated foot, a cartoon's stub) say nothing
    faint = [replace(end, toes=toes) for end, toes in zip(fox, (-0.4, 0.4))]
    with pytest.raises(SegmentationError, match="at least two"):
        body_plan.decide_head(*faint)
    # alone they never decide, and against the others, even at their clearest, they never refuse
    # (a generated horse lying on its folded legs read them the wrong way)
    with pytest.raises(SegmentationError, match="cannot tell the head from the tail"):
        body_plan.decide_head(_end(1.0, 0.2, toes=2.0), _end(1.0, 0.2, toes=-2.0))
    decision = body_plan.decide_head(_end(2.0, 0.4, mirror=True, toes=-2.0), _end(1.0, 0.1, toes=2.0))
    assert decision.head.area == 2.0 and decision.cues["toes"] == pytest.approx(-body_plan.TOES_CUE)


def _foot(reach: float):
    """A vertical leg (a capsule of radius 1 standing on z = 0, 12 tall) whose lower cap is drawn
    out by ``reach`` along +x at its bottom (a toe), as (vertices, faces, tip)."""
    import trimesh

    leg = trimesh.creation.capsule(height=10.0, radius=1.0, count=[24, 24])
    vertices = np.array(leg.vertices)
    vertices[:, 2] += 6.0
    low = vertices[:, 2] < 1.0                       # the lower cap: a paw pushed forward
    vertices[low, 0] += reach * (1.0 - vertices[low, 2])
    tip = int(np.argmin(vertices[:, 2] - 1e-3 * vertices[:, 0]))
    return vertices, np.array(leg.faces), tip


@pytest.mark.parametrize("reach", [0.0, 1.5])
def test_a_toe_reaches_forward_of_its_leg(reach):
    from allorules.mesh.topology import vertex_graph

    vertices, faces, tip = _foot(reach)
    field = body_plan.geodesic_fields(vertex_graph(vertices, faces), [tip])[tip]
    leg = np.ones(len(vertices), dtype=bool)
    up, forward = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    ahead = body_plan._toe_reach(vertices, faces, field, tip, leg, up, forward)
    behind = body_plan._toe_reach(vertices, faces, field, tip, leg, up, -forward)
    assert ahead == pytest.approx(-behind)
    if reach == 0.0:        # a round foot straight under its leg: nothing to read
        assert abs(ahead) < 0.2
    else:                   # drawn forward by 1.5 radii
        assert ahead > body_plan.TOES_CLEAR * 0.8


def test_a_constructed_animal_whose_ends_look_alike_is_refused():
    """A 'pushmi-pullyu': the tail made as long and thick as neck and head, the head as thin as a
    tail. The cues cannot tell the ends apart, so the labeller must refuse rather than guess."""
    animal = generate_quadruped("dog", 2000, tail_length=0.30, tail_radius=0.05, tail_angle=-35.0,
                                head_length=0.12, head_height=0.05, head_width=0.05, neck_length=0.10)
    with pytest.raises(SegmentationError, match=SETTLE) as refused:
        labelled = label_quadruped(Body(animal.vertices, animal.faces))
        pytest.fail(f"labelled with confidence {labelled.labelling.confidence}")
    assert "\n" not in str(refused.value)


def test_forward_settles_the_head_end(posed):
    animal = posed("dog", "stand")
    labelled = label_quadruped(Body(animal.vertices, animal.faces), forward=[1, 0.3, 0])
    assert agreement(animal, labelled) >= 0.95
    assert labelled.labelling.confidence["head-tail"] == 1.0     # the user decided
    # told the head is where the tail is: followed (fore and hind legs swap), or refused where no
    # head is found there; never the automatic guess against the user
    try:
        reversed_ = label_quadruped(Body(animal.vertices, animal.faces), forward=[-1, 0, 0], complete=False)
    except SegmentationError:
        return
    fore_truth = animal.labels == REGION_NAMES.index("forelimbs")
    hind = reversed_.region_names.index("hindlimbs")
    assert (reversed_.labels[fore_truth] == hind).mean() > 0.9


# ---------------------------------------------------------------- appendages and regions on demand

def test_the_tail_is_its_own_region_and_folds_into_the_abdomen(posed):
    animal = posed("horse", "stand")
    labelled = label_quadruped(Body(animal.vertices, animal.faces))
    assert labelled.region_names[:6] == QUADRUPED_REGIONS and "tail" in labelled.region_names
    mass = vertex_areas(animal.vertices, animal.faces)
    truth_tail = animal.labels == REGION_NAMES.index("tail")
    found = labelled.region_mask("tail")
    assert mass[truth_tail & found].sum() > 0.8 * mass[truth_tail].sum()
    # the labeller's tail starts at its root, where the rings flare; the generator cuts it a little
    # further out, past the rump's fillet: the rest is that root, nothing else
    abdomen = animal.labels == REGION_NAMES.index("abdomen")
    assert not (found & ~truth_tail & ~abdomen).any()
    assert mass[found].sum() < 1.8 * mass[truth_tail].sum()
    folded = fold_regions(labelled)
    assert folded.region_names == QUADRUPED_REGIONS
    assert (folded.labels[found] == QUADRUPED_REGIONS.index("abdomen")).all()
    kept = fold_regions(labelled, QUADRUPED_REGIONS + ("tail",))
    assert kept.region_names[-1] == "tail" and kept.region_mask("tail").sum() == found.sum()
    assert kept.labelling.source == "segmenter auto-quadruped"
    assert set(kept.labelling.confidence) == {"feet", "fore-hind pairs", "head-tail"}


@pytest.mark.parametrize("preset", ["horse", "dog"])
def test_a_raised_curled_tails_region_is_the_tail_and_its_root_not_the_rump_behind_it(posed, preset):
    """A tail raised and curled over the back turns the plane across its root: on the tip's side of
    it lay the back of the rump (the bull 386's rump, a third of its tail region; here the tail came
    out 3.1 and 3.4 times the generator's). What the root adds stays near the tail's axis."""
    animal = posed(preset, "curl")
    labelled = label_quadruped(Body(animal.vertices, animal.faces))
    mass = vertex_areas(animal.vertices, animal.faces)
    truth_tail = animal.labels == REGION_NAMES.index("tail")
    found = labelled.region_mask("tail")
    assert mass[truth_tail & found].sum() > 0.95 * mass[truth_tail].sum()
    assert mass[found].sum() < 2.0 * mass[truth_tail].sum()


def test_a_tail_is_the_tube_its_rings_follow_and_a_bump_is_none(posed):
    """The tail's fallback when what its tip reaches runs on into the body (a tail hanging against
    the rump): the rings from the tip while they keep the tail's girth. On the generated dog its
    tube is its tail; a point on the back ends no tube."""
    from scipy.sparse.csgraph import dijkstra

    from allorules.mesh.topology import vertex_graph
    from allorules.segment.labeller import _tube

    animal = posed("dog", "stand")
    graph = vertex_graph(animal.vertices, animal.faces)
    mass = vertex_areas(animal.vertices, animal.faces)
    tail = animal.labels == REGION_NAMES.index("tail")
    centre = np.average(animal.vertices, axis=0, weights=mass)
    tip = int(np.flatnonzero(tail)[np.argmax(np.linalg.norm(animal.vertices[tail] - centre, axis=1))])
    field = dijkstra(graph, indices=tip)
    tube = _tube(animal.vertices, animal.faces, graph, tip, field, float(np.percentile(field, 50)))
    assert tube is not None
    assert mass[tube & tail].sum() > 0.8 * mass[tail].sum()
    assert mass[tube & ~tail].sum() < 0.25 * mass[tail].sum()
    back = int(np.argmax(np.where(animal.labels == REGION_NAMES.index("chest"), animal.vertices[:, 1], -np.inf)))
    field = dijkstra(graph, indices=back)
    assert _tube(animal.vertices, animal.faces, graph, back, field, float(np.percentile(field, 50))) is None


@pytest.mark.shared_meshes
def test_the_donkeys_tail_hanging_against_its_rump_is_its_own_region():
    """PSB 385: what the tail's tip reaches ran on over the rump (54 % of the torso), so the tail
    was left in the abdomen and reshaped with it (curled up short at x2); its tube is the tail."""
    prepared, _ = _real("385.off")
    labelled = label_quadruped(Body(prepared.vertices, prepared.faces))
    mass = vertex_areas(prepared.vertices, prepared.faces)
    tail = labelled.region_mask("tail")
    assert 0.003 < mass[tail].sum() / mass.sum() < 0.02
    # it hangs behind the hind legs, its tip the lowest point of the tail end
    lowest = prepared.vertices[tail] @ labelled.frame.up
    assert lowest.min() < (prepared.vertices[labelled.region_mask("abdomen")] @ labelled.frame.up).min()


@pytest.mark.shared_meshes
def test_a_bump_on_the_rump_is_no_tail_at_any_resolution():
    """PSB 381, a cow whose tail hangs flat against its rump: the tail end's tip is a bump there,
    followed for 1.1-1.7 of its radii. Decimated to 60 % of its vertices, what that tip reached
    below its root was taken as a tail of 16 % of the surface (the rump, held isometric by a run);
    as it comes and split at its edges' midpoints it has none. A tail followed for fewer than
    TUBE_LENGTH radii is its tube alone, if it has one (here none), at every resolution."""
    import fast_simplification

    prepared, _ = _real("381.off")
    mass = vertex_areas(prepared.vertices, prepared.faces)
    vertices, faces = fast_simplification.simplify(prepared.vertices, prepared.faces,
                                                   target_count=2 * int(0.6 * len(prepared.vertices)))
    decimated = Body(np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64))
    for body in (Body(prepared.vertices, prepared.faces), decimated):
        labelled = label_quadruped(body)
        mass = vertex_areas(body.vertices, body.faces)
        tail = labelled.region_mask("tail") if labelled.has_region("tail") else np.zeros(len(mass), dtype=bool)
        assert mass[tail].sum() < 0.02 * mass.sum()
        abdomen = mass[labelled.region_mask("abdomen")].sum() / mass.sum()
        assert abdomen > 0.3          # the rump stays with the abdomen (0.36 as it comes)


def test_labels_files_keep_every_region_and_the_labelling(tmp_path, posed):
    animal = posed("dog", "stand")
    body = Body(animal.vertices, animal.faces)
    labelled = label_quadruped(body)
    path = tmp_path / "dog.labels.json"
    write_labels(path, labelled)
    document = json.loads(path.read_text())
    assert document["version"] == 1 and document["regions"] == list(labelled.region_names)
    assert document["labelling"]["confidence"] == pytest.approx(labelled.labelling.confidence)
    back = read_labels(path, body)
    assert back.region_names == labelled.region_names
    np.testing.assert_array_equal(back.labels, labelled.labels)
    assert back.labelling.confidence == pytest.approx(labelled.labelling.confidence)
    # the labeller's frame goes with the labels, so a body labelled from the file is measured along
    # the same axes (without it, the torso's principal axis: the giraffe 390's output at ×0.5
    # measured with its input's labels gave a heart-girth exponent 0.152 off its run's)
    np.testing.assert_allclose(back.frame.up, labelled.frame.up)
    np.testing.assert_allclose(back.frame.forward, labelled.frame.forward)
    for frame in ({"up": [0, 1, 0], "forward": [0, 2, 0]}, {"up": [0, 1], "forward": [1, 0, 0]}, "up", None,
                  {"up": [0, float("nan"), 1], "forward": [1, 0, 0]}):
        document["frame"] = frame            # a malformed frame is ignored: the axes come from the regions
        path.write_text(json.dumps(document))
        assert read_labels(path, body).frame is None
    # an older file (no labelling) still reads; the generator's file keeps its tail
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"format": "allorules-labels", "version": 1, "regions": list(animal.region_names),
                               "labels": [int(v) for v in animal.labels]}))
    read = read_labels(old, body)
    assert read.region_names == REGION_NAMES and read.labelling is None
    with_tail = fold_regions(read, QUADRUPED_REGIONS + ("tail",))
    assert with_tail.region_mask("tail").sum() == (animal.labels == REGION_NAMES.index("tail")).sum()
    assert fold_regions(read).region_names == QUADRUPED_REGIONS


# ---------------------------------------------------------------- real meshes, against hand marks

def _real(name):
    if not SHARED.is_dir():
        pytest.skip("../shared/meshes is not present")
    from allorules.mesh.repair import prepare_mesh

    path = SHARED / "psb-fourleg" / name if name.endswith(".off") else SHARED / name
    prepared = prepare_mesh(path)
    return prepared, label_check.read_hand_marks(HAND_MARKS)[name].on_body(prepared.source_vertex_index)


MARKED = sorted(json.loads(HAND_MARKS.read_text())["marks"])


@pytest.mark.shared_meshes
@pytest.mark.parametrize("name", MARKED)
def test_real_meshes_are_labelled_right_or_refused_never_swapped(name):
    prepared, marks = _real(name)
    try:
        labelled = label_quadruped(Body(prepared.vertices, prepared.faces))
    except SegmentationError as error:
        assert "\n" not in str(error)
        assert any(hint in str(error) for hint in ("--forward", "allorules segment", "--segmentation")), str(error)
        return
    verdict = label_check.check_labels(labelled, marks)
    assert not verdict.swapped, verdict.problems
    assert verdict.right, verdict.problems
    # the forelimbs hang from the chest: a neck that reaches them has been followed over the
    # shoulders (measured before the neck stopped there: the pig 383 0.91 of their border, the bull
    # 386 0.44, the donkey 385 on its working mesh; 0 on every mesh since)
    assert _border_share(labelled, "forelimbs", "neck") <= 0.02
    # ears and horns grow from the top of the head, not at the nose (the wolf's lower jaw, a flat
    # sheet beside its nose, was cut as its ears)
    size = float(np.linalg.norm(np.ptp(labelled.vertices, axis=0)))
    for feature in ("ears", "horns"):
        if labelled.has_region(feature):
            near = np.linalg.norm(labelled.vertices[labelled.region_mask(feature)] - labelled.vertices[marks.nose], axis=1)
            assert near.min() > 0.05 * size, (feature, near.min() / size)


def _border_share(body: Body, region: str, neighbour: str) -> float:
    """Share of ``region``'s border edges whose other vertex is in ``neighbour``."""
    inside, other = body.region_mask(region), body.region_mask(neighbour) if body.has_region(neighbour) else None
    if other is None:
        return 0.0
    edges = np.concatenate([body.faces[:, [0, 1]], body.faces[:, [1, 2]], body.faces[:, [2, 0]]])
    border = edges[inside[edges[:, 0]] != inside[edges[:, 1]]]
    outside = np.where(inside[border[:, 0]], border[:, 1], border[:, 0])
    return float(other[outside].mean()) if len(outside) else 0.0


@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.heavy
def test_most_real_meshes_are_labelled_not_refused():
    """Measured: 15 of the 16 labelled right (the cartoon elephant standing on two legs is refused)."""
    right = 0
    for name in MARKED:
        prepared, marks = _real(name)
        try:
            labelled = label_quadruped(Body(prepared.vertices, prepared.faces))
        except SegmentationError:
            continue
        right += label_check.check_labels(labelled, marks).right
    assert right >= 14


def test_hand_marks_check_catches_a_swap(posed):
    """The check itself: a body labelled back to front is 'swapped'."""
    animal = posed("horse", "stand")
    truth = animal.body()
    head_tip = int(np.argmax(animal.vertices[:, 0]))
    feet = {region: [int(np.flatnonzero(animal.labels == REGION_NAMES.index(region))[0])] * 2
            for region in ("forelimbs", "hindlimbs")}
    marks = label_check.HandMarks(len(animal.vertices), head_tip, tuple(feet["forelimbs"]), tuple(feet["hindlimbs"]),
                                  int(np.argmin(animal.vertices[:, 0])))
    assert label_check.check_labels(truth, marks).right
    swap = {"head": "tail", "tail": "head", "forelimbs": "hindlimbs", "hindlimbs": "forelimbs", "neck": "abdomen",
            "abdomen": "neck", "chest": "chest"}
    swapped = Body(truth.vertices, truth.faces, truth.labels, tuple(swap[name] for name in truth.region_names))
    verdict = label_check.check_labels(swapped, marks)
    assert verdict.swapped and not verdict.right


@pytest.mark.shared_meshes
def test_a_pool_of_the_chest_between_the_forelegs_is_not_leg():
    """The cow 381's chest between its forelegs is flat and level with its armpits: a pool of 0.7 %
    of the surface that a foreleg's sweep took in just below where it met the body. Taken in, the
    forelegs' region ran across the chest and one foreleg measured 0.427 long against 0.365 for its
    mate (Loop-subdivided to 200k: +0.064 of exponent at ×2 on the full-resolution output). Given
    back to the body, the pair measure alike, as the hind legs do."""
    from allorules.measure.length import region_skeleton

    prepared, _ = _real("381.off")
    labelled = label_quadruped(Body(prepared.vertices, prepared.faces))
    for region in ("forelimbs", "hindlimbs"):
        lengths = [skeleton.diameter for skeleton in region_skeleton(labelled, region)]
        assert len(lengths) == 2 and max(lengths) < 1.03 * min(lengths), (region, lengths)


@pytest.mark.shared_meshes
def test_a_belly_a_leg_meets_small_that_grows_into_the_body_ends_the_leg():
    """The camel's forelegs meet the underside of its belly a little below their armpits, when
    that part of the belly is 1.25 % of the surface as the file comes (the body: the legs end
    there) and 0.92 % midpoint-subdivided (a pool: the forelegs' region ran on along the whole
    belly to the hind legs, and heart girth had no closed section of the chest). Judged by what
    the pool has grown into by the leg's cut, the subdivided camel's forelegs end where the
    file's do: their surface within 5 % and apart from the hind legs."""
    import trimesh

    from allorules.mesh.repair import prepare_mesh

    prepared, _ = _real("camel.obj")
    coarse = label_quadruped(Body(prepared.vertices, prepared.faces))
    vertices, faces = trimesh.remesh.subdivide(prepared.vertices, prepared.faces)
    fine_mesh = prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))
    fine = label_quadruped(Body(fine_mesh.vertices, fine_mesh.faces))
    for body in (coarse, fine):
        fore, hind = body.region_mask("forelimbs"), body.region_mask("hindlimbs")
        edges = np.concatenate([body.faces[:, [0, 1]], body.faces[:, [1, 2]], body.faces[:, [2, 0]]])
        assert not (fore[edges[:, 0]] & hind[edges[:, 1]]).any(), "the forelimbs' region reaches the hind legs"
    shares = [vertex_areas(body.vertices, body.faces)[body.region_mask("forelimbs")].sum()
              / vertex_areas(body.vertices, body.faces).sum() for body in (coarse, fine)]
    assert shares[1] == pytest.approx(shares[0], rel=0.05), shares


@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.heavy
def test_a_head_whose_ears_and_horns_are_cut_does_not_become_all_trunk():
    """The cow 381 Loop-subdivided three times and decimated to 200,000 vertices (as
    benchmarks/bench_resolution.py makes it), labelled on its working mesh: the smoothed muzzle
    followed from the nose is a tube, and once its ears and horns were cut the trunk's cut took
    all the head was left with (found no head: refused at 200k, labelled at 6.9k). A trunk is at
    most TRUNK_SHARE of the head the ears and horns leave."""
    from dataclasses import replace

    from scipy.spatial import cKDTree

    prepared, marks = _real("381.off")
    working = _working_mesh_of_200k(prepared)
    labelled = label_quadruped(Body(working.vertices, working.faces))
    nearest = cKDTree(working.vertices).query(prepared.vertices)[1]
    on_working = replace(marks, file_vertices=len(nearest)).on_body(nearest)   # the marks' nearest working vertices
    verdict = label_check.check_labels(labelled, on_working)
    assert verdict.right and not verdict.swapped, verdict.problems
    assert labelled.labels[on_working.nose] == labelled.region_names.index("head")


@pytest.mark.shared_meshes
@pytest.mark.slow
def test_a_stub_of_a_tail_counts_alike_whichever_side_of_the_threshold_a_resolution_puts_it(monkeypatch):
    """The horse 387's stub of a tail is a tip of persistence 0.075 as it comes and 0.084
    Loop-subdivided once, either side of CANDIDATE_PERSISTENCE: the presence cue flipped from +1 to
    0 and the subdivided horse was refused ("cannot tell the head from the tail"). Graded, the stub
    counts about half both times, and both are labelled right."""
    from dataclasses import replace

    import trimesh
    from scipy.spatial import cKDTree

    from allorules.mesh.repair import prepare_mesh
    from allorules.runs import pipeline

    prepared, marks = _real("387.off")
    decisions = []
    decide = body_plan.decide_head
    monkeypatch.setattr(body_plan, "decide_head", lambda *args: decisions.append(decide(*args)) or decisions[-1])
    vertices, faces = trimesh.remesh.subdivide_loop(prepared.vertices, prepared.faces, iterations=1)
    for mesh in (prepared, prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))):
        working = pipeline.working(mesh).mesh or mesh
        labelled = label_quadruped(Body(working.vertices, working.faces))
        nearest = cKDTree(working.vertices).query(prepared.vertices)[1]
        verdict = label_check.check_labels(labelled, replace(marks, file_vertices=len(nearest)).on_body(nearest))
        assert verdict.right and not verdict.swapped, verdict.problems
    presence = [decision.cues["presence"] for decision in decisions]
    assert len(presence) == 2 and all(0.3 < value < 0.7 for value in presence), presence


@pytest.mark.shared_meshes
def test_a_snout_bend_does_not_take_the_neck_into_the_head_of_a_decimated_pig():
    """The pig 383 decimated to 2,500 vertices: its snout bends about as sharply as its head, and
    from the snout the whole head runs on as a long "neck" narrowing over 0.21 radii, from the
    head's bend a short neck narrowing over 0.31. A short neck's narrowing counted only where no
    long one narrowed, and the head took its neck in (0.205 of the surface, neck 0.010; the file's
    13,331 vertices 0.143 and 0.048). The bend whose neck narrows most wins: head and neck within
    a fifth and a third of the file's."""
    import fast_simplification
    import trimesh

    from allorules.mesh.repair import prepare_mesh

    def shares(body):
        labelled = label_quadruped(Body(body.vertices, body.faces))
        mass = vertex_areas(labelled.vertices, labelled.faces)
        return {region: mass[labelled.region_mask(region)].sum() / mass.sum() for region in ("head", "neck")}

    prepared, _ = _real("383.off")
    vertices, faces = fast_simplification.simplify(prepared.vertices.astype(np.float32), prepared.faces,
                                                   target_reduction=1 - 2_500 / len(prepared.vertices))
    decimated = prepare_mesh(trimesh.Trimesh(np.asarray(vertices, dtype=float), faces, process=False))
    fine, coarse = shares(prepared), shares(decimated)
    assert coarse["head"] == pytest.approx(fine["head"], rel=0.2), (coarse, fine)
    assert coarse["neck"] == pytest.approx(fine["neck"], rel=1 / 3), (coarse, fine)


def _working_mesh_of_200k(prepared):
    """The working mesh of a real mesh Loop-subdivided three times (four for a coarse one) and
    decimated to 200,000 vertices, as benchmarks/bench_resolution.py makes its 200k variants."""
    import fast_simplification
    import trimesh

    from allorules.mesh.repair import prepare_mesh
    from allorules.runs import pipeline

    vertices, faces = trimesh.remesh.subdivide_loop(prepared.vertices, prepared.faces, iterations=3)
    while len(faces) <= 400_000:      # a coarse mesh (the 1.8k camel) once more
        vertices, faces = trimesh.remesh.subdivide_loop(vertices, faces, iterations=1)
    vertices, faces = fast_simplification.simplify(vertices, faces, target_count=400_000)
    working = pipeline.working(prepare_mesh(trimesh.Trimesh(vertices, faces, process=False))).mesh
    assert working is not None and 7_000 < len(working.vertices) < 9_000
    return working


@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.parametrize("name", ["389.off", "387.off", "camel.obj"])
@pytest.mark.heavy
def test_the_head_and_the_neck_end_at_the_same_places_as_they_come_and_at_200k(name):
    """The dog 389's narrowest neck section lies half way down its short neck (0.50 of it on the
    9k mesh's working mesh, 0.53 at 200k): where the head's end was the narrowest section up to
    half the neck and the bend beyond, its head was 0.129 of the surface at 9k and 0.073 at 200k;
    it now moves smoothly between the two. The horse 387's neck was followed along the chord from
    the first section's centre, which at 200k ran round the back of the head: the axis turned by
    46°, and the neck was 0.031 of the surface at 200k against 0.076 as it comes. The camel's
    S-shaped neck bends twice, at 200k as sharply at the chest as at the head, and the chest's bend
    was taken: head 0.113 and neck 0.022 against 0.070 and 0.036. Each region's share within 15 %
    of the other's."""
    from allorules.runs import pipeline

    prepared, _ = _real(name)
    shares = []
    for mesh in (pipeline.working(prepared).mesh, _working_mesh_of_200k(prepared)):
        labelled = label_quadruped(Body(mesh.vertices, mesh.faces))
        area = vertex_areas(labelled.vertices, labelled.faces)
        shares.append([area[labelled.region_mask(region)].sum() / area.sum() for region in ("head", "neck")])
    for region, (coming, fine) in zip(("head", "neck"), zip(*shares)):
        assert abs(coming / fine - 1) < 0.15, (region, shares)


def test_a_head_cut_at_the_snouts_tip_makes_what_the_necks_cut_took_off_the_head(posed, monkeypatch):
    """Where the bend taken was the muzzle's (an animal with no visible neck), the head cut is a
    snout's tip and what the neck's cut took off is the head itself: a head cut under MIN_HEAD_CUT
    of the surface becomes the head but for a band at its base (NECK_BAND). Here the generated
    horse's head cut is moved to just behind its nose."""
    from allorules.segment import labeller

    animal = posed("horse", "stand")
    body = Body(animal.vertices, animal.faces)
    plain = label_quadruped(body)
    cuts = labeller._neck_cuts

    def at_the_snout(vertices, faces, graph, rest, head_tip, forelimb):
        (point, normal), neck_cut = cuts(vertices, faces, graph, rest, head_tip, forelimb)
        depth = (vertices[head_tip] - point) @ normal
        return (point + 0.9 * depth * normal, normal), neck_cut

    monkeypatch.setattr(labeller, "_neck_cuts", at_the_snout)
    merged = label_quadruped(body)
    area = vertex_areas(animal.vertices, animal.faces)
    front = area[plain.region_mask("head") | plain.region_mask("neck")].sum()
    head, neck = (area[merged.region_mask(region)].sum() for region in ("head", "neck"))
    assert head + neck == pytest.approx(front, rel=0.02)
    assert 0 < neck < 2 * labeller.NECK_BAND * front and head > labeller.MIN_HEAD_CUT * area.sum()


def test_where_no_neck_runs_a_radius_the_bend_whose_neck_narrows_wins_over_the_sharpest(posed, monkeypatch):
    """Of the skeleton's bends, the sharpest whose neck narrows and runs MIN_NECK_LENGTH is taken;
    where none runs that far, one that narrows still wins over a sharper bend whose "neck" never
    narrows (a muzzle's): a blocky fox split twice, its neck 0.99 radii long, had its snout cut
    for its head and the rest of its head labelled chest. Here the generated dog's sharpest bend
    is given a long neck that does not narrow and every other a narrowing one just too short."""
    from allorules.segment import labeller

    animal = posed("dog", "stand")                           # two bends followed down a neck
    follow, cuts = labeller._follow_neck, labeller._neck_cuts
    necks, chosen = [], []

    def followed(vertices, faces, adjacency, start, direction, step, span, shoulders=None):
        neck = follow(vertices, faces, adjacency, start, direction, step, span, shoulders)
        if neck is not None:
            neck = (neck._replace(length=2.0, narrowing=0.0) if not necks else
                    neck._replace(length=0.9 * labeller.MIN_NECK_LENGTH, narrowing=2 * labeller.MIN_NARROWING))
            necks.append(neck)
        return neck

    def cut(*arguments):
        chosen.append(cuts(*arguments))
        return chosen[-1]

    monkeypatch.setattr(labeller, "_follow_neck", followed)
    monkeypatch.setattr(labeller, "_neck_cuts", cut)
    label_quadruped(Body(animal.vertices, animal.faces))
    assert len(necks) >= 2                                   # a sharpest bend and another
    _, (base, _) = chosen[0]                                # (head cut, neck cut)
    assert not np.allclose(base, necks[0].base)             # not the sharpest bend's
    assert any(np.allclose(base, neck.base) for neck in necks[1:])


@pytest.mark.shared_meshes
@pytest.mark.slow
def test_a_pig_with_no_visible_neck_keeps_its_head_and_its_tail_at_any_resolution():
    """The pig 383's snout bends as sharply as its head, and from the snout the whole head runs on
    as a "neck" 7 of its radii long that narrows over 0.14 of them as it comes and over none at
    200k: the snout's bend was taken, its cut a snout's tip merged back (head 0.203 of the surface)
    as it comes and at 6k vertices, the head's bend Loop-subdivided (0.123). A short neck that
    narrows (0.46 radii) now wins over a long one that hardly does: as it comes, at 6,000 vertices
    and Loop-subdivided once (each on its working mesh) head and neck differ on under 5 % of the
    surface (measured about 3 % and 2 %; 8 % and more before). At 3,000 the snout's "neck" narrows
    over 0.34 radii and the snout is still taken (head 0.205). Every head over a tenth of the
    surface, under 21 %. Its curly tail is thinner than a bump on its rump, which was that end's
    main tip: the tail was cut from the bump, 8.9 % of the surface as it comes and 11.3 % at 6,000
    vertices (a third of the rump), none at 3,000. Cut from the end's most prominent tip, it holds
    the marked tail tip and under 3 % of the surface at every size."""
    import trimesh
    from scipy.spatial import cKDTree

    from allorules.mesh.decimate import decimate
    from allorules.mesh.repair import prepare_mesh
    from allorules.runs import pipeline

    prepared, marks = _real("383.off")
    shares, labellings = {}, {}
    for size in (None, 6000, 3000, "loop"):
        # each labelled on its working mesh, as a run labels it (13k as it comes and 53k Loop-subdivided
        # are remeshed to 7.8k; 6k and 3k are their own)
        if size is None:
            mesh = prepared
        elif size == "loop":
            mesh = prepare_mesh(trimesh.Trimesh(
                *trimesh.remesh.subdivide_loop(prepared.vertices, prepared.faces, iterations=1), process=False))
        else:
            mesh = prepare_mesh(trimesh.Trimesh(*decimate(prepared.vertices, prepared.faces, size), process=False))
        working = pipeline.working(mesh).mesh or mesh
        vertices, faces = working.vertices, working.faces
        labelled = labellings[size] = label_quadruped(Body(vertices, faces))
        area = vertex_areas(labelled.vertices, labelled.faces)
        shares[size] = [area[labelled.region_mask(region)].sum() / area.sum() for region in ("head", "neck")]
        tail_tip = cKDTree(vertices).query(prepared.vertices[marks.tail])[1]
        assert labelled.has_region("tail") and labelled.region_mask("tail")[tail_tip], size
        assert area[labelled.region_mask("tail")].sum() < 0.03 * area.sum(), size
    assert all(0.1 < head < 0.21 for head, _ in shares.values()), shares
    coming = labellings[None]
    area = vertex_areas(coming.vertices, coming.faces)

    def front(body, at):   # head, neck or the rest, at vertices ``at``
        names = np.array(body.region_names)[body.labels[at]]
        return np.where(np.isin(names, ("head", "neck")), names, "body")

    for size in (6000, "loop"):   # each vertex against the other mesh's nearest, by area
        other = labellings[size]
        nearest = cKDTree(other.vertices).query(coming.vertices)[1]
        differ = front(coming, np.arange(len(coming.vertices))) != front(other, nearest)
        assert area[differ].sum() < 0.05 * area.sum(), (size, area[differ].sum() / area.sum(), shares)


def _revolved_tube(z: np.ndarray, radius: np.ndarray, *more) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a closed tube of revolution about the z axis, its radius given along z,
    with any ``more`` trimesh parts put in the same mesh."""
    import trimesh

    profile = np.vstack([[0.0, 0.0], np.column_stack([radius, z]), [0.0, z[-1]]])
    mesh = trimesh.util.concatenate([trimesh.creation.revolve(profile, sections=64), *more])
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)


def test_a_neck_that_widens_at_once_ends_where_the_widening_levels_off():
    """A TOSCA horse standing with its head low: from the back of its head the sections widen at
    once and steadily to the chest's girth, then level off; the knee below the chord fell half a
    radius from the bend (neck 0.9 % of the surface, the rest of it chest). A tube of revolution
    widening linearly from r 0.05 to 0.13 over 0.25, then straight, the shoulders just beyond:
    the neck ends where the widening levels off, at 0.25."""
    from allorules.mesh.topology import face_adjacency
    from allorules.segment import labeller

    z = np.linspace(0.0, 0.6, 121)
    vertices, faces = _revolved_tube(z, np.where(z < 0.25, 0.05 + 0.08 * z / 0.25, 0.13))
    around = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    shoulders = np.column_stack([0.13 * np.cos(around), 0.13 * np.sin(around), np.full(16, 0.3)])
    neck = labeller._follow_neck(vertices, faces, face_adjacency(faces), np.array([0.0, 0.0, 0.01]),
                                 np.array([0.0, 0.0, 1.0]), 0.004, 0.5, shoulders)
    assert neck is not None and 0.22 < neck.base[2] < 0.28


def test_a_neck_followed_steps_over_a_cavity_its_plane_slips_into():
    """An open mouth: a section plane through the neck's axis point that lies in a cavity nested in
    the tube takes the cavity's loop (the smallest around the point). The TOSCA horse trotting at
    200k vertices: sections of radius 0.06 fell to 0.01 for two steps, its "narrowest section" and
    so a neck narrowing over 3.4 radii that won over the true one (head 12.0 % of the surface for
    10.3 % at 3,400). A tube of radius 0.05 widening to 0.13 past z = 0.3, a closed pocket of radius
    0.01 nested in it at z 0.1: the neck's narrowest section is the tube's, not the pocket's."""
    import trimesh

    from allorules.mesh.topology import face_adjacency
    from allorules.segment import labeller

    z = np.linspace(0.0, 0.6, 121)
    pocket = trimesh.creation.cylinder(radius=0.01, segment=[[0.0, 0.0, 0.099], [0.0, 0.0, 0.107]], sections=16)
    vertices, faces = _revolved_tube(z, np.where(z < 0.3, 0.05, np.minimum(0.05 + 0.08 * (z - 0.3) / 0.1, 0.13)),
                                     pocket)
    neck = labeller._follow_neck(vertices, faces, face_adjacency(faces), np.array([0.0, 0.0, 0.01]),
                                 np.array([0.0, 0.0, 1.0]), 0.004, 0.5)
    assert neck is not None and abs(neck.narrowest_radius - 0.05) < 0.005, neck
    assert 0.28 < neck.base[2] < 0.35


def test_an_appendage_hangs_from_the_body_and_a_band_round_it_does_not():
    """Ears, horns, a trunk and a tail are leaves: the body without them is one piece. The realistic
    elephant's two ears, their roots wrapped round the back of its head, held its head on (a run
    then held them as a neck, the head their children, and their mass missed isometric by 0.04); a
    cap of a sphere is a leaf, a band round its equator is not (nor two half-bands that meet)."""
    import trimesh

    from allorules.segment.labeller import _a_leaf, vertex_graph

    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices, faces = np.asarray(sphere.vertices, dtype=float), np.asarray(sphere.faces, dtype=np.int64)
    graph, mass = vertex_graph(vertices, faces), vertex_areas(vertices, faces)
    height = vertices[:, 2]
    assert _a_leaf(faces, graph, mass, height > 0.8)
    band = np.abs(height) < 0.15
    assert not _a_leaf(faces, graph, mass, band)
    assert _a_leaf(faces, graph, mass, band & (vertices[:, 0] > 0.3))      # half a band: a leaf
    assert not _a_leaf(faces, graph, mass, band & (vertices[:, 0] > -0.1) | band & (vertices[:, 0] < 0.1))


def test_a_cloven_hoof_on_a_short_leg_is_no_head():
    """A low-poly pig standing, its legs short, was refused as a head taken for a foot: its two
    toes lay 0.37-0.38 of the leg's length from its heel, over the 0.3 that ears and horns were
    read beyond. Twins on a head read as a leg lie 0.56-0.95 of it from the nose (above), so a
    short leg (a capsule 4 tall, radius 1) with a heel and two toes (0.42-0.45 of it) is a leg."""
    import trimesh

    from allorules.mesh.topology import vertex_graph

    leg = trimesh.creation.capsule(height=2.0, radius=1.0, count=[32, 32])
    vertices, normals = np.array(leg.vertices) + [0.0, 0.0, 2.0], np.array(leg.vertex_normals)
    for centre, size, push in (([0.75, 0.45, 0.35], 0.45, 0.8), ([0.75, -0.45, 0.35], 0.45, 0.8),
                               ([-0.8, 0.0, 0.3], 0.5, 0.6)):          # two toes, a heel
        bump = np.clip(1.0 - np.linalg.norm(vertices - centre, axis=1) / size, 0.0, None) ** 2
        vertices = vertices + (push * bump)[:, None] * normals
    faces = np.array(leg.faces)
    extremities = body_plan.read_extremities(vertex_graph(vertices, faces), vertex_areas(vertices, faces), vertices,
                                             faces)
    heel = min((int(t) for t in extremities.vertices), key=lambda t: vertices[t, 0])
    length = extremities.distance[heel].max()
    toes = [t for t in extremities.vertices if vertices[t, 0] > 0.5 and vertices[t, 2] < 1.0]
    assert len(toes) == 2 and all(0.35 < extremities.distance[heel][t] / length < body_plan.LEG_FEATURE_REACH
                                  for t in toes)
    legs = np.full(len(vertices), heel)
    assert body_plan.head_taken_for_a_leg(extremities, legs, [heel], vertices, faces) is None
