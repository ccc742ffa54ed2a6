"""Posing a labelled animal from its labels (allorules/mesh/repose.py), and real animals so posed
labelled right or refused, never with head and tail swapped (issue 17: any pose)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
from rotations import random_rotation

from allorules.body import Body, Frame
from allorules.errors import SegmentationError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.quadruped import generate_quadruped
from allorules.mesh.quadruped_poses import POSES, Pose
from allorules.mesh.repose import repose
from allorules.mesh.working import make_working_mesh
from allorules.segment import label_check
from allorules.segment.labeller import label_quadruped

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
HAND_MARKS = Path(__file__).resolve().parent / "data" / "hand_marks.json"


@pytest.fixture(scope="module")
def horse() -> Body:
    """The generated horse with its true labels and frame (+Y up, +X forward)."""
    body = generate_quadruped("horse", vertices=3000).body()
    return Body(body.vertices, body.faces, labels=body.labels, region_names=body.region_names,
                frame=Frame(up=np.array([0.0, 1.0, 0.0]), forward=np.array([1.0, 0.0, 0.0])))


def _leg(body: Body, region: str, side: float) -> np.ndarray:
    """The leg of ``region`` on the +Z (side = 1) or −Z side of the generated horse."""
    mask = body.region_mask(region)
    return mask & (np.sign(body.vertices[:, 2]) == side)


def test_a_swung_leg_moves_forward_rigidly_and_nothing_else_moves(horse):
    """A fore leg swung 30° forward: its foot moves forward, the leg below its joint's blend keeps
    its shape (distances between its vertices), the other legs and the head do not move."""
    side = np.cross(horse.frame.forward, horse.frame.up)                   # +Z: the left legs
    moved = repose(horse, Pose(swing={"fore-left": 30.0}))
    leg = _leg(horse, "forelimbs", np.sign(side[2]))
    foot = leg & (horse.vertices[:, 1] < horse.vertices[leg, 1].min() + 0.02)
    assert (moved[foot, 0] - horse.vertices[foot, 0]).mean() > 0.1 * np.ptp(horse.vertices[:, 0])
    lower = leg & (horse.vertices[:, 1] < np.median(horse.vertices[leg, 1]))
    before, after = horse.vertices[lower], moved[lower]
    pairs = np.random.default_rng(0).integers(0, len(before), size=(200, 2))
    np.testing.assert_allclose(np.linalg.norm(after[pairs[:, 0]] - after[pairs[:, 1]], axis=1),
                               np.linalg.norm(before[pairs[:, 0]] - before[pairs[:, 1]], axis=1), atol=1e-9)
    still = (_leg(horse, "forelimbs", -np.sign(side[2])) | horse.region_mask("hindlimbs") | horse.region_mask("head"))
    np.testing.assert_allclose(moved[still], horse.vertices[still], atol=1e-12)   # turned by 0


def test_neck_and_tail_turn_up_with_positive_angles(horse):
    moved = repose(horse, Pose(neck=20.0, tail=30.0))
    head, tail = horse.region_mask("head"), horse.region_mask("tail")
    assert moved[head, 1].mean() > horse.vertices[head, 1].mean() + 0.02
    assert moved[tail, 1].mean() > horse.vertices[tail, 1].mean() + 0.02
    assert np.array_equal(repose(horse, Pose()), horse.vertices)


def test_a_pitch_turns_the_body_up_about_its_hips_and_the_legs_stay_upright(horse):
    """``pitch`` turns the whole body nose-up about its hips; the legs' swings are counted from the
    vertical, so a leg with no swing stands as it stood (the lower half of each leg the same
    direction as standing, where the body's own axis turned by the pitch)."""
    moved = repose(horse, Pose(pitch=20.0))
    head, hind = horse.region_mask("head"), horse.region_mask("hindlimbs")
    assert moved[head, 1].mean() > horse.vertices[head, 1].mean() + 0.1 * np.ptp(horse.vertices[:, 1])
    chest, abdomen = (moved[horse.region_mask(name)].mean(axis=0) for name in ("chest", "abdomen"))
    assert np.degrees(np.arctan2(chest[1] - abdomen[1], chest[0] - abdomen[0])) == pytest.approx(20.0, abs=4.0)
    for region in ("forelimbs", "hindlimbs"):
        leg = _leg(horse, region, 1.0)
        low = leg & (horse.vertices[:, 1] < np.median(horse.vertices[leg, 1]))
        top, bottom = np.flatnonzero(low)[[np.argmax(horse.vertices[low, 1]), np.argmin(horse.vertices[low, 1])]]
        line, standing = moved[top] - moved[bottom], horse.vertices[top] - horse.vertices[bottom]
        cosine = line @ standing / (np.linalg.norm(line) * np.linalg.norm(standing))
        assert np.degrees(np.arccos(min(cosine, 1.0))) < 1.0, region
    assert np.linalg.norm(moved[hind].mean(axis=0) - horse.vertices[hind].mean(axis=0)) < 0.05 * np.ptp(horse.vertices[:, 0])


def test_a_body_without_labels_or_frame_is_refused(horse):
    with pytest.raises(Exception, match="labelled body"):
        repose(Body(horse.vertices, horse.faces), POSES["gallop"])


# ---------------------------------------------------------------- real animals posed

POSED = [("horse.obj", "gallop"), ("horse.obj", "lie"), ("lion.obj", "walk"), ("wolf.obj", "walk"),
         ("wolf.obj", "gallop"), ("387.off", "rear"), ("390.off", "gallop"), ("381.off", "graze"),
         ("wolf.obj", "graze"), ("lion.obj", "lie"), ("wolf.obj", "sit"), ("lion.obj", "sit")]


def _posed_real(name: str, pose: str):
    """A shared animal as prepared, its standing labels, the random turn of (name, pose), and the
    animal put into the pose from those labels and turned by it (skips without shared/)."""
    if not SHARED.is_dir():
        pytest.skip("../shared/meshes is not present")
    from allorules.mesh.repair import prepare_mesh

    prepared = prepare_mesh(SHARED / "psb-fourleg" / name if name.endswith(".off") else SHARED / name)
    standing = label_quadruped(Body(prepared.vertices, prepared.faces))
    rotation = random_rotation(sum(map(ord, name + pose)))
    return prepared, standing, rotation, Body(repose(standing, POSES[pose]) @ rotation.T, prepared.faces)


@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.parametrize("name, pose", POSED)
def test_real_animals_posed_are_labelled_right_never_swapped(name, pose):
    """A real animal labelled standing, put into one of the generated animal's poses from those
    labels, turned at random: labelled right against the hand marks (its nose the head, each foot
    a leg's), or refused with a way to settle it. The wolf's upper jaw, its mouth open, ends a tube
    3.3 of its radii long when its head turns: it is no trunk (TRUNK_LENGTH)."""
    prepared, _, _, posed = _posed_real(name, pose)
    marks = label_check.read_hand_marks(HAND_MARKS)[name].on_body(prepared.source_vertex_index)
    try:
        labelled = label_quadruped(posed)
    except SegmentationError as error:
        assert "\n" not in str(error) and "--forward" in str(error), str(error)
        return
    verdict = label_check.check_labels(labelled, marks)
    assert not verdict.swapped and verdict.right, verdict.problems
    assert "trunk" not in labelled.region_names or not labelled.region_mask("trunk").any()


# A head turned keeps its head and neck: the share of each (by area, as labelled standing) that is
# labelled the same posed. Before the two fixes the grazing wolf's nose was labelled ears (its
# ear, more prominent than its nose with the head hanging, was taken for the main tip: neck 0.06),
# and the lying or rearing lion's head was cut at its muzzle (head 0.40).
HEAD_TURNED = [("wolf.obj", "graze"), ("lion.obj", "lie"), ("lion.obj", "rear")]
KEPT = 0.7


@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.parametrize("name, pose", HEAD_TURNED)
def test_a_turned_head_keeps_its_head_and_neck(name, pose):
    prepared, standing, _, posed = _posed_real(name, pose)
    labelled = label_quadruped(posed)
    area = vertex_areas(prepared.vertices, prepared.faces)
    for region in ("head", "neck"):
        before = standing.region_mask(region)
        kept = area[before & labelled.region_mask(region)].sum() / area[before].sum()
        assert kept >= KEPT, f"{region}: {kept:.2f} of it labelled {region} when posed"


class PosedHead(NamedTuple):
    """A shared animal posed and labelled afresh, its head and neck against its standing labels."""

    prepared: Any
    posed: Body
    labelled: Body
    kept: float          # share of the standing head (by area) labelled head when posed
    grown: float         # the posed head's area over the standing head's
    neck: float          # the posed neck's area
    neck_standing: float


def _posed_head(name: str, pose: str) -> PosedHead:
    prepared, standing, _, posed = _posed_real(name, pose)
    labelled = label_quadruped(posed)
    area = vertex_areas(prepared.vertices, prepared.faces)
    head_before, head_after = standing.region_mask("head"), labelled.region_mask("head")
    return PosedHead(prepared, posed, labelled, area[head_before & head_after].sum() / area[head_before].sum(),
                     area[head_after].sum() / area[head_before].sum(), area[labelled.region_mask("neck")].sum(),
                     area[standing.region_mask("neck")].sum())


@pytest.mark.shared_meshes
@pytest.mark.slow
def test_a_grazing_pig_s_head_is_its_head_not_its_snout():
    """The pig 383 grazing, its head lowered: both the head's and the neck's cuts fell at its snout's
    bend (head and neck 1.7 % of the surface; the rest of the head and its ears labelled chest, the
    nose still on the head, so the hand marks passed it). Now the rings decide its head, with a
    short neck: 0.97 of the standing head labelled head, the head 0.20 of the surface for 0.14
    standing (the rings' head takes the standing neck and a little of the chest)."""
    pig = _posed_head("383.off", "graze")
    assert pig.kept >= 0.9 and pig.grown <= 1.5
    assert 0.0 < pig.neck <= 2.0 * pig.neck_standing


@pytest.mark.shared_meshes
@pytest.mark.slow
def test_a_rearing_pig_keeps_a_neck_behind_its_ears():
    """The pig 383 rearing, its head raised: its ears reach back past the neck's cut, the head
    taken back to behind them took every neck vertex, and the pig was refused for "no neck" in
    every turn (on its 8,000-vertex working mesh all but one: a neck with no face, which a run
    could neither measure nor hold). Now the neck is the band at the base of the cut's neck and
    the ring next to it: 0.98 of the standing head labelled head, the head 1.4 × the standing one
    (it takes the standing neck), a neck of 0.7 % of the surface (4.8 % standing), 143 faces."""
    pig = _posed_head("383.off", "rear")
    assert pig.kept >= 0.9 and pig.grown <= 1.6
    assert 0.0 < pig.neck <= pig.neck_standing
    assert pig.labelled.region_mask("neck")[pig.prepared.faces].all(axis=1).sum() >= 20   # faces to measure it by
    working = make_working_mesh(pig.posed.vertices, pig.posed.faces)          # as a run labels it: 26 faces
    small = label_quadruped(Body(working.vertices, working.faces))
    assert small.region_mask("neck")[working.faces].all(axis=1).sum() >= 10


# Feet in doubt are settled by the body's directions, as the refusal says: the donkey 385 lying,
# its head down, has its ears mirrored across its midplane like a pair of feet (0.16 of cost from
# its feet as it comes; refused). Given its up and forward, the feet are below its centre and each
# pair's feet on either side of its midplane (body_plan.SIDES, ABOVE). The bull 386 galloping is
# refused for a pair of legs unalike; given its directions, a fore foot crossing its midplane must
# not make its feet cost more than a quadruped's (it did: 1.61).
@pytest.mark.shared_meshes
@pytest.mark.slow
@pytest.mark.parametrize("name, pose", [("385.off", "lie"), ("386.off", "gallop")])
def test_feet_in_doubt_are_settled_with_the_bodys_up_and_forward(name, pose):
    prepared, standing, rotation, posed = _posed_real(name, pose)
    marks = label_check.read_hand_marks(HAND_MARKS)[name].on_body(prepared.source_vertex_index)
    with pytest.raises(SegmentationError, match="feet") as refused:
        label_quadruped(posed)
    assert "--up DIR and --forward DIR" in str(refused.value)
    labelled = label_quadruped(posed, up=rotation @ standing.frame.up, forward=rotation @ standing.frame.forward)
    verdict = label_check.check_labels(labelled, marks)
    assert not verdict.swapped and verdict.right, verdict.problems


def test_hand_marks_cover_the_posed_animals():
    names = set(json.loads(HAND_MARKS.read_text())["marks"])
    assert {name for name, _ in POSED} <= names
