"""Stands where it stood, and the quality measures of an output (issue 18)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from allorules.body import Body
from allorules.measure.features import (
    SmallFeature,
    feature_shape_change,
    find_small_features,
)
from allorules.measure.ground import GroundError, ground_contact, place_on_ground
from allorules.measure.quality import (
    FEATURE_SHAPE_LIMIT,
    ROUGHNESS_SHARE_LIMIT,
    distortions,
    flipped_faces,
    intersecting_face_pairs,
    quality_report,
    rule_checks,
    self_intersections,
    surface_roughness,
    trunk_shape_change,
)
from allorules.mesh.geometry import count_flipped_faces, similarity_fit


def _turn(vertices, seed=3):
    rotation = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))[0]
    return vertices @ rotation.T * 7.5 + np.array([3.0, -2.0, 11.0]), rotation


@pytest.mark.parametrize("factor", [2 ** (1 / 3), 0.5 ** (1 / 3)])
def test_scaled_animal_stands_on_the_inputs_ground(generated_horse, factor):
    """Scaled about its centroid, a ×2 animal sinks and a ×0.5 one floats; placed, its feet are on
    the input's ground at the same place (to 0.5 % of its height), also turned and in other units."""
    from allorules.body import Frame

    for turned in (False, True):
        body = generated_horse.body()
        if turned:
            vertices, rotation = _turn(body.vertices)
            body = Body(vertices, body.faces, body.labels, body.region_names,
                        Frame(up=rotation @ body.frame.up, forward=rotation @ body.frame.forward))
        up = body.frame.up
        height = float(np.ptp(body.vertices @ up))
        centre = body.vertices.mean(axis=0)
        scaled = centre + factor * (body.vertices - centre)
        before = ground_contact(body)
        sunk = before.at(scaled)
        assert abs(sunk.height - before.height) > 0.05 * height        # the centroid scaling is off the ground
        placed = place_on_ground(body, scaled)
        after = before.at(placed)
        assert abs(after.height - before.height) <= 0.005 * height
        assert np.allclose(after.contacts @ up, before.height, atol=0.005 * height)   # all four feet down
        assert np.linalg.norm(after.anchor - before.anchor) <= 0.005 * height
        assert np.allclose(place_on_ground(body, scaled, anchor="centroid"), scaled)


def test_nothing_of_the_placed_output_goes_below_the_inputs_floor(generated_horse):
    """Eq. 9 can bend a leg so that a point beside a foot's contact ends lowest (the Blender
    add-on's displaced horse, 0.5 % of its height): the floor is the body's lowest point, on the
    input and on the output alike."""
    body = generated_horse.body()
    up = body.frame.up
    height = float(np.ptp(body.vertices @ up))
    before = ground_contact(body)
    assert before.height == pytest.approx(float((body.vertices @ up).min()))
    in_feet = np.zeros(len(body.vertices), dtype=bool)
    in_feet[np.concatenate(before.feet)] = True
    beside = np.flatnonzero(~in_feet)[np.argmin((body.vertices @ up)[~in_feet])]
    scaled = 1.26 * body.vertices
    scaled[beside] -= (float(scaled[beside] @ up) - float((scaled @ up).min()) + 0.01 * height) * up
    placed = place_on_ground(body, scaled)
    assert float((placed @ up).min()) == pytest.approx(before.height, abs=1e-9 * height)
    assert np.linalg.norm(before.at(placed).anchor - before.anchor) <= 0.005 * height

def test_ground_needs_an_up_direction():
    mesh = trimesh.creation.icosphere(2)
    with pytest.raises(GroundError, match="up"):
        ground_contact(Body(mesh.vertices, mesh.faces))
    contact = ground_contact(Body(mesh.vertices, mesh.faces), up=[0, 0, 1])
    assert contact.height == pytest.approx(-1.0, abs=0.01)


def _two_spheres(offset):
    first = trimesh.creation.icosphere(2)
    second = trimesh.creation.icosphere(2)
    vertices = np.vstack([first.vertices, second.vertices + [offset, 0, 0]])
    faces = np.vstack([first.faces, second.faces + len(first.vertices)])
    labels = np.r_[np.zeros(len(first.vertices), int), np.ones(len(second.vertices), int)]
    return Body(vertices, faces, labels, ("forelimbs", "hindlimbs"))


def test_self_intersections_are_counted_with_the_regions_that_touch():
    apart = _two_spheres(2.5)
    assert len(intersecting_face_pairs(apart.vertices, apart.faces)) == 0
    overlapping = _two_spheres(1.5)
    found = self_intersections(overlapping)
    assert found.pairs > 20 and found.faces > 20
    assert set(found.regions) == {"forelimbs|hindlimbs"}
    moved = self_intersections(apart, overlapping.vertices)      # as an output of the apart input
    assert moved.new_pairs == moved.pairs == found.pairs
    # a closed surface alone (neighbouring faces share vertices) has none
    sphere = trimesh.creation.icosphere(3)
    assert len(intersecting_face_pairs(sphere.vertices, sphere.faces)) == 0


def test_flips_and_roughness_against_uniform_scaling():
    sphere = trimesh.creation.icosphere(3)
    body = Body(sphere.vertices, sphere.faces)
    assert flipped_faces(body, 2.0 * sphere.vertices).count == 0
    assert surface_roughness(sphere.vertices, 2.0 * sphere.vertices + 5, sphere.faces).rms_degrees < 1e-6
    bumpy = sphere.vertices * (1 + 0.05 * np.sin(9 * sphere.vertices[:, :1]))
    assert surface_roughness(sphere.vertices, bumpy, sphere.faces).rms_degrees > 0.5
    mirrored = sphere.vertices * [1, 1, -1]     # a mirror turns n into −M n: faces facing sideways flip
    normals = sphere.face_normals
    expected = int(np.sum(normals[:, 0] ** 2 + normals[:, 1] ** 2 >= normals[:, 2] ** 2))
    assert 0 < flipped_faces(body, mirrored).count == expected


def test_shape_change_removes_similarity_and_sees_stretching():
    points = np.random.default_rng(0).normal(size=(60, 3))
    feature = SmallFeature("protrusion", np.arange(60), 0, 0.01, 0.1)
    moved, rotation = _turn(points)
    scale, fitted, _ = similarity_fit(points, moved)
    assert scale == pytest.approx(7.5) and np.allclose(fitted, rotation)
    assert feature_shape_change(points, moved, feature).shape_change < 1e-9
    stretched = points * [1.3, 1.0, 1.0]
    change = feature_shape_change(points, stretched, feature).shape_change
    assert 0.05 < change < 0.3


def test_small_features_of_the_generated_horse_are_its_ends(generated_horse):
    """Hooves, the tail's tip and the muzzle are found; legs, neck and tail are not small."""
    features = find_small_features(generated_horse.vertices, generated_horse.faces)
    assert len(features) >= 5
    names = generated_horse.region_names
    regions = {names[np.bincount(generated_horse.labels[f.vertices]).argmax()] for f in features}
    assert {"forelimbs", "hindlimbs", "tail", "head"} <= regions
    area = sum(f.area_share for f in features)
    assert area < 0.1                                          # small: legs and tail are not taken whole


def test_distortions_name_lumps_and_mangled_features_beyond_the_limits(generated_horse):
    """Uniform scaling is the same animal: nothing. Lumps all over (the pig 388's legs) and one
    small feature crumpled (its snout) are each named, with their figure and the limit."""
    body = generated_horse.body()
    assert distortions(body, 1.7 * body.vertices + 3.0) == []
    rng = np.random.default_rng(1)
    scale = np.ptp(body.vertices, axis=0).max()
    lumpy = body.vertices + rng.normal(scale=0.01 * scale, size=body.vertices.shape)
    found = distortions(body, lumpy)
    assert any("lumpy" in line and f"limit {100 * ROUGHNESS_SHARE_LIMIT:.0f}%" in line for line in found), found
    feature = find_small_features(body.vertices, body.faces)[0]
    crumpled = body.vertices.copy()
    points = crumpled[feature.vertices]
    size = np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1)))
    crumpled[feature.vertices] += rng.normal(scale=0.6 * size, size=points.shape)
    found = distortions(body, crumpled)
    assert any("small feature" in line and f"limit {100 * FEATURE_SHAPE_LIMIT:.0f}%" in line for line in found), found


def test_rule_checks_and_report_are_json_ready(generated_horse):
    import json
    from types import SimpleNamespace

    checks = rule_checks([SimpleNamespace(id="a", exponent=0.36, achieved_exponent=0.37),
                          SimpleNamespace(id="b", exponent=0.36, achieved_exponent=0.39)], tolerance=0.02)
    assert [check.met for check in checks] == [True, False]
    body = generated_horse.body()
    report = quality_report(body, 1.2 * body.vertices, rules=[SimpleNamespace(id="a", exponent=1, achieved_exponent=1)])
    data = json.loads(json.dumps(report.as_dict()))
    assert data["flipped_faces"]["count"] == 0 and data["self_intersections"]["pairs"] == 0
    assert data["worst_feature_change"] < 1e-9 and data["roughness"]["rms_degrees"] < 1e-6
    assert all(abs(leg["tilt_degrees"]) < 1e-6 for leg in data["legs"]) and len(data["legs"]) == 4


@pytest.mark.heavy
def test_the_report_counts_the_flipped_faces_of_the_mesh_written(generated_horse, tmp_path):
    """Quality is measured on the working mesh; the faces written are the user's, carried from it,
    and the report counts their flips too (a transfer can fold what the working mesh did not)."""
    import dataclasses

    from allorules.runs import pipeline

    path = tmp_path / "horse.obj"
    trimesh.Trimesh(generated_horse.body().vertices, generated_horse.body().faces, process=False).export(path)
    run = pipeline.run(path, pipeline.GlobalScaling(2.0), modes=30, working_vertices=2000)
    assert run.working.binding is not None                     # a 4,000-vertex horse on a 2,000-vertex working mesh
    quality = run.quality()
    assert quality.flipped.count == 0 and quality.written_flipped.count == 0
    assert "0 in the mesh written" in quality.summary()
    assert quality.as_dict()["written_flipped_faces"] == {"count": 0, "regions": {}}
    # fold the working mesh's head through itself: the written mesh's faces there flip with it
    folded = run.result.body.vertices.copy()
    head = run.body.region_mask("head")
    centre = folded[head].mean(axis=0)
    folded[head] = centre - (folded[head] - centre)            # a point reflection turns every head face
    run = dataclasses.replace(run, result=dataclasses.replace(run.result, body=run.result.body.with_vertices(folded)),
                              _quality=None, _carried=None)
    quality = run.quality()
    assert quality.written_flipped.count > 0 and set(quality.written_flipped.regions) >= {"head"}
    assert quality.written_flipped.regions["head"] > 0.5 * quality.written_flipped.count


def test_a_face_the_run_folded_is_unfolded_in_the_mesh_written(generated_horse, tmp_path):
    """A vertex of the output dragged past its neighbour folds the faces around it: the mesh written
    (every front end's Run.body_vertices) has none, the report says how many were unfolded; raw
    Eq. 4 is written as it is."""
    import dataclasses

    from allorules.runs import pipeline
    from allorules.runs.results import RawGlobalResult

    body = generated_horse.body()
    run = pipeline.run(trimesh.Trimesh(body.vertices, body.faces, process=False), pipeline.GlobalScaling(1.5), modes=30)
    assert run.working is None and run.quality().written_flipped is None      # nothing folded, one mesh
    folded = run.result.body.vertices.copy()
    tip = int(np.flatnonzero(run.body.region_mask("abdomen"))[0])
    neighbour = next(int(v) for v in run.body.faces[np.any(run.body.faces == tip, axis=1)].ravel() if v != tip)
    folded[tip] += 2.5 * (folded[neighbour] - folded[tip])
    run = dataclasses.replace(run, result=dataclasses.replace(run.result, body=run.result.body.with_vertices(folded)),
                              _quality=None, _carried=None)
    quality = run.quality()
    assert quality.flipped.count >= 2 and quality.written_flipped.count == 0
    assert quality.unfolded == quality.flipped.count and 0 < quality.unfold_move < 0.05
    assert f"flipped faces as solved; in the mesh written {quality.unfolded} unfolded, 0 left" in quality.summary()
    assert count_flipped_faces(body.vertices, run.output_vertices(), body.faces) == 0
    assert run.report()["quality"]["unfolded_faces"] == quality.unfolded
    untouched = np.ones(len(folded), dtype=bool)
    untouched[np.flatnonzero(np.any(run.body_vertices() != folded, axis=1))] = False
    assert untouched.sum() > 0.98 * len(folded)                                # a patch, not the body
    raw = dataclasses.replace(run, result=RawGlobalResult(run.result.body, 0.0, 1.0, 1.0, 2), _quality=None, _carried=None)
    assert np.array_equal(raw.body_vertices(), folded)


def test_a_leg_swollen_along_part_of_its_length_is_measured(generated_horse):
    """girth_spread: 0 under a similarity; a leg whose middle alone grows 40 % across measures about that."""
    from allorules.measure.limbs import limb_sections, posture_change
    from allorules.mesh.geometry import smoothstep

    body = generated_horse.body()
    turned, _ = _turn(body.vertices)
    moved = posture_change(body, body.with_vertices(turned))
    assert moved and all(change["girth_spread"] < 1e-6 for change in moved.values())
    limb = limb_sections(body, "forelimbs")[0]
    offsets, along = limb.offsets_across()
    swollen = body.vertices.copy()
    bump = smoothstep((along - 0.3) / 0.1) * (1.0 - smoothstep((along - 0.6) / 0.1))     # 1 from 0.4 to 0.6
    swollen[limb.mesh.vertex_index] += 0.4 * bump[:, None] * offsets
    change = posture_change(body, body.with_vertices(swollen))
    assert change["forelimbs[0]"]["girth_spread"] == pytest.approx(0.4, abs=0.1)
    assert all(change[leg]["girth_spread"] < 1e-6 for leg in change if leg != "forelimbs[0]")
    # a run's legs beyond the limit make it look distorted (ruleset_run._finish), one line per leg
    from allorules.measure.quality import LEG_GIRTH_SPREAD_LIMIT, distorted_legs

    assert distorted_legs(change) == []
    swollen[limb.mesh.vertex_index] += 2.0 * bump[:, None] * offsets                  # 2.4 × across in the middle
    lines = distorted_legs(posture_change(body, body.with_vertices(swollen)))
    assert len(lines) == 1 and lines[0].startswith("forelimbs[0] swelled") and f"limit {100 * LEG_GIRTH_SPREAD_LIMIT:.0f}%" in lines[0]


def test_a_leg_swung_or_crumpled_makes_the_run_look_distorted(generated_horse):
    """A fore leg turned rigidly by 45° about its junction measures a 45° tilt and no change of
    shape: one line, swung. Its lower half turned 90° about its middle (a knee bent backwards) changes
    its shape by 0.46 of its size; turned 30° (0.14), under both limits, it is let through."""
    from scipy.spatial.transform import Rotation

    from allorules.measure.limbs import limb_sections, posture_change
    from allorules.measure.quality import (
        LEG_SHAPE_LIMIT,
        LEG_TURN_LIMIT,
        distorted_legs,
    )

    body = generated_horse.body()
    limb = limb_sections(body, "forelimbs")[0]
    index = limb.mesh.vertex_index
    side = np.cross(body.frame.forward, body.frame.up)

    def turned(points, pivot, degrees):
        return pivot + (points - pivot) @ Rotation.from_rotvec(np.radians(degrees) * side).as_matrix().T

    swung = body.vertices.copy()
    swung[index] = turned(swung[index], limb.junction, 45.0)
    change = posture_change(body, body.with_vertices(swung))
    assert change["forelimbs[0]"]["tilt_degrees"] == pytest.approx(45.0, abs=0.5)
    assert change["forelimbs[0]"]["shape_change"] < 0.01
    assert distorted_legs(change) == [f"forelimbs[0] swung by 45° over the run (limit {LEG_TURN_LIMIT:.0f}°)"]

    _, along = limb.offsets_across()
    lower = index[along > 0.5]
    knee = limb.section_at(0.5).loop.points.mean(axis=0)
    for degrees, distorted in ((30.0, False), (90.0, True)):
        bent = body.vertices.copy()
        bent[lower] = turned(bent[lower], knee, degrees)
        change = posture_change(body, body.with_vertices(bent))
        lines = [line for line in distorted_legs(change) if "changed shape" in line]
        assert (change["forelimbs[0]"]["shape_change"] > LEG_SHAPE_LIMIT) == distorted
        assert len(lines) == int(distorted)


def _humped(body, height):
    """``body`` with a smooth hump on its back over the abdomen: raised along up by ``height`` (in
    units of the trunk's radius) at the abdomen's middle, falling off along the body like a bell."""
    up, forward = np.asarray(body.frame.up, float), np.asarray(body.frame.forward, float)
    trunk = body.region_mask("chest") | body.region_mask("abdomen")
    abdomen = body.vertices[body.region_mask("abdomen")]
    centre, spread = abdomen @ forward, np.ptp(abdomen @ forward)
    radius = np.sqrt(np.sort(np.linalg.eigvalsh(np.cov(body.vertices[trunk].T)))[:2].sum())
    along = (body.vertices @ forward - centre.mean()) / (0.3 * spread)
    rise = body.vertices @ up - (body.vertices[trunk] @ up).mean()
    top = np.clip(rise / np.ptp(body.vertices[trunk] @ up), 0.0, None)      # the back, not the belly
    bumped = body.vertices + (height * radius * np.exp(-along ** 2) * top * trunk)[:, None] * up
    return bumped


def test_the_trunks_shape_change_sees_a_hump_not_a_stretch(generated_horse):
    """A trunk made longer, deeper, sheared, turned and moved is the same trunk (0); a hump on the
    back is measured, in proportion to its height and alike in any units and orientation."""
    body = generated_horse.body()
    forward, up = np.asarray(body.frame.forward, float), np.asarray(body.frame.up, float)
    stretch = np.eye(3) + 0.3 * np.outer(forward, forward) - 0.2 * np.outer(up, up) + 0.1 * np.outer(up, forward)
    assert trunk_shape_change(body, body.vertices @ stretch.T + 4.0) < 1e-9
    low, high = trunk_shape_change(body, _humped(body, 0.2)), trunk_shape_change(body, _humped(body, 0.4))
    assert 0.02 < low < high and high == pytest.approx(2 * low, rel=0.15)     # a tenth of the hump at least
    turned, rotation = _turn(body.vertices)
    again = body.with_vertices(turned)
    assert trunk_shape_change(again, _turn(_humped(body, 0.4))[0]) == pytest.approx(high, rel=1e-6)
    assert trunk_shape_change(Body(body.vertices, body.faces), body.vertices) is None     # no regions


def test_a_trunk_humped_beyond_the_limit_is_a_distortion(generated_horse):
    """Beyond TRUNK_SHAPE_LIMIT of its radius a trunk's hump is one line of the run's distortions
    (which make it miss, as a lumpy surface does); a stretch, a hump within the limit or a body
    without a trunk to measure is none."""
    from allorules.measure.quality import TRUNK_SHAPE_LIMIT, distorted_trunk

    body = generated_horse.body()
    assert distorted_trunk(trunk_shape_change(body, 1.3 * body.vertices)) == []
    assert distorted_trunk(None) == []
    height = 0.4
    while trunk_shape_change(body, _humped(body, height)) <= TRUNK_SHAPE_LIMIT:
        height *= 1.2
    over = trunk_shape_change(body, _humped(body, height))
    within = trunk_shape_change(body, _humped(body, height / 1.2))
    assert within <= TRUNK_SHAPE_LIMIT < over
    assert distorted_trunk(within) == []
    (line,) = distorted_trunk(over)
    assert f"{100 * over:.0f}%" in line and f"limit {100 * TRUNK_SHAPE_LIMIT:.0f}%" in line


def test_a_humped_trunk_is_warned_of_and_reported(generated_horse):
    """The run's warning names a hump beyond TRUNK_SHAPE_WARNING and says where to read about it;
    the quality report carries the figure in its JSON and its terminal line."""
    from allorules.measure.quality import TRUNK_SHAPE_WARNING, trunk_shape_warning

    body = generated_horse.body()
    assert trunk_shape_warning(trunk_shape_change(body, 1.3 * body.vertices)) is None
    assert trunk_shape_warning(None) is None                                  # no trunk to measure
    height = 0.4
    while trunk_shape_change(body, _humped(body, height)) <= TRUNK_SHAPE_WARNING:
        height *= 1.5
    line = trunk_shape_warning(trunk_shape_change(body, _humped(body, height)))
    assert line is not None and "trunk changed shape" in line and "docs/measurements.md" in line
    report = quality_report(body, _humped(body, height), intersections=False)
    assert report.as_dict()["trunk_shape_change"] == pytest.approx(trunk_shape_change(body, _humped(body, height)))
    assert "the trunk" in report.summary()


def test_the_head_turn_is_the_angle_its_best_similarity_turns(generated_horse):
    """:func:`head_turn`: 0 for the body scaled and moved, the angle for a head (and neck) nodded
    about the neck's root, None without a head."""
    from scipy.spatial.transform import Rotation

    from allorules.measure.quality import head_turn

    body = generated_horse.body()
    assert head_turn(body, 1.3 * body.vertices + 2.0) == pytest.approx(0.0, abs=1e-4)
    nodding = body.region_mask("head") | body.region_mask("neck")
    root = body.vertices[body.region_mask("neck")].min(axis=0)
    moved = body.vertices.copy()
    moved[nodding] = (moved[nodding] - root) @ Rotation.from_euler("z", 12, degrees=True).as_matrix().T + root
    assert head_turn(body, 0.8 * moved) == pytest.approx(12.0, abs=0.5)
    assert head_turn(Body(body.vertices, body.faces), moved) is None
