"""The animal's frame read off its regions (measure/frame.py), for bodies whose regions came
without one (a merge file, a .seg, regions painted in Blender, an older labels file), and the run
pipeline giving it to every such body, so that the measures, the per-axis power law and the
ground use the animal's own up and forward."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from rotations import random_rotation

from allorules.body import Body
from allorules.measure.frame import regions_frame
from allorules.mesh.quadruped import generate_quadruped
from allorules.plugins.registry import registry_for
from allorules.runs import pipeline

UP, FORWARD = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])   # the generator's frame


def degrees(first: np.ndarray, second: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(first @ second, -1.0, 1.0))))


@pytest.mark.parametrize("preset, pose, seed, within", [
    ("horse", None, 1, 3.0), ("giraffe", None, 2, 3.0), ("dog", None, 3, 3.0), ("elephant", None, 4, 3.0),
    ("giraffe", "graze", 6, 3.0), ("dog", "curl", 7, 3.0),
    # walking, a foot lifted: three feet make the ground, as for the labeller, whose own up is as far
    # off on these meshes (the giraffe walking at 2,000-6,000 vertices: 2-8°, the labeller's 3-8°)
    ("horse", "walk", 5, 10.0), ("giraffe", "walk", 8, 10.0),
    # seated, the body turned up 32-36° on its hips: the ground is still the feet's (measured 2-4.3°)
    ("horse", "sit", 9, 6.0), ("dog", "sit", 10, 6.0)])
def test_the_frame_read_off_the_regions_is_the_animals_own(preset, pose, seed, within):
    """Standing, walking, grazing, sitting, turned at random: up and forward near the generator's, where
    the regions' centroids alone (head and neck against abdomen, torso against legs) were up to 41°
    off on the giraffe."""
    animal = generate_quadruped(preset, 2500, pose=pose)
    turn = random_rotation(seed)
    body = Body(animal.vertices @ turn.T, animal.faces, animal.labels, animal.region_names)
    frame = regions_frame(body)
    assert degrees(frame.up, turn @ UP) < within
    assert degrees(frame.forward, turn @ FORWARD) < within
    assert abs(frame.up @ frame.forward) < 1e-9


def test_no_frame_without_a_torso_and_one_from_the_legs_there_are():
    """No chest, or a chest region with no vertex in it: no frame (not one from an empty region's
    centroid). Hind legs alone (the fore legs labelled chest) still give up and forward."""
    animal = generate_quadruped("horse", 1500)
    names = tuple("body" if name in ("chest", "abdomen") else name for name in animal.region_names)
    assert regions_frame(Body(animal.vertices, animal.faces, animal.labels, names)) is None
    assert regions_frame(Body(animal.vertices, animal.faces)) is None
    index = {name: number for number, name in enumerate(animal.region_names)}
    no_chest = np.where(animal.labels == index["chest"], index["abdomen"], animal.labels)
    assert regions_frame(Body(animal.vertices, animal.faces, no_chest, animal.region_names)) is None
    hind_only = np.where(animal.labels == index["forelimbs"], index["chest"], animal.labels)
    frame = regions_frame(Body(animal.vertices, animal.faces, hind_only, animal.region_names))
    assert degrees(frame.up, UP) < 10.0 and degrees(frame.forward, FORWARD) < 10.0


def test_a_body_labelled_without_a_frame_is_given_one_by_the_pipeline(tmp_path):
    """A labels file with no frame (an older one, the generator's) and regions given per vertex
    (Blender's painted groups) are measured along the animal's axes, and the report says where
    they came from."""
    giraffe = generate_quadruped("giraffe", 2500)
    turn = random_rotation(11)
    mesh = tmp_path / "giraffe.obj"
    trimesh.Trimesh(giraffe.vertices @ turn.T, giraffe.faces, process=False).export(mesh)
    (tmp_path / "regions.json").write_text(json.dumps(giraffe.labels_document()))
    registry = registry_for(None)
    prepared = pipeline.prepare(mesh)
    work = pipeline.working(prepared)
    for labels in (tmp_path / "regions.json",
                   pipeline.VertexRegions(giraffe.labels, giraffe.region_names, "vertex groups")):
        body = pipeline.label_working(prepared, work, registry=registry, labels=labels)
        assert degrees(body.frame.up, turn @ UP) < 3.0 and degrees(body.frame.forward, turn @ FORWARD) < 3.0
        assert any("read off the regions" in note for note in body.labelling.notes)


def test_a_labels_files_frame_from_another_orientation_is_not_used(tmp_path, caplog):
    """The mesh exported turned since it was labelled (the same faces, its vertices turned a
    quarter round): the labels file's up and forward are the old orientation's, 90° off, and the
    regions' own are used instead, saying so; a frame that fits is kept as it is."""
    import logging

    from allorules.segment.labels_io import write_labels

    horse = generate_quadruped("horse", 2500)
    labels = tmp_path / "horse.labels.json"
    write_labels(labels, horse.body())                       # its frame: +Y up, +X forward
    registry = registry_for(None)
    quarter = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])   # +Y up becomes +Z up
    for turn, kept in ((np.eye(3), True), (quarter, False)):
        mesh = tmp_path / "horse.obj"
        trimesh.Trimesh(horse.vertices @ turn.T, horse.faces, process=False).export(mesh)
        prepared = pipeline.prepare(mesh)
        with caplog.at_level(logging.WARNING, logger="allorules"):
            caplog.clear()
            body = pipeline.label_working(prepared, pipeline.working(prepared), registry=registry, labels=labels)
        assert degrees(body.frame.up, turn @ UP) < 3.0 and degrees(body.frame.forward, turn @ FORWARD) < 3.0
        assert ("since it was labelled" in caplog.text) != kept
        if kept:
            np.testing.assert_allclose(body.frame.up, UP)
