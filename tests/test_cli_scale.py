"""``allorules scale`` as users run it: outputs in the input's layout, --png, never the input."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from allorules.cli import main


def test_scale_writes_mesh_report_and_before_after_picture(tmp_path):
    source = tmp_path / "bone.obj"
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[16, 16]).export(source)
    before = source.read_bytes()
    output, picture, report = tmp_path / "thick.obj", tmp_path / "thick.png", tmp_path / "thick.json"
    code = main(["scale", str(source), "--global", "--alpha", "0.05", "--modes", "40", "-o", str(output),
                 "--png", str(picture), "--report", str(report)])
    assert code == 0
    assert source.read_bytes() == before                      # the input is untouched
    loaded = trimesh.load(output, process=False)
    original = trimesh.load(source, process=False)
    assert np.array_equal(loaded.faces, original.faces)       # connectivity kept
    assert np.all(np.isfinite(loaded.vertices)) and not np.allclose(loaded.vertices, original.vertices)
    assert picture.stat().st_size > 5_000 and report.exists()


def test_a_raw_power_law_on_a_mesh_above_the_working_size_is_written_with_its_quality(tmp_path, capsys):
    """--global --alpha on a body that gets a working mesh: nothing is labelled, and the faces
    written are still counted (it crashed carrying no regions back to the user's body)."""
    source = tmp_path / "bone.obj"
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[48, 48]).export(source)
    output, report = tmp_path / "thin.obj", tmp_path / "thin.json"
    code = main(["scale", str(source), "--global", "--alpha", "-0.1", "--modes", "30", "--working-vertices", "2000",
                 "--placement", "centroid", "-o", str(output), "--report", str(report)])
    assert code == 0, capsys.readouterr().err
    document = json.loads(report.read_text())
    assert document["working_mesh"]["method"] == "remeshed" and "written_flipped_faces" in document["quality"]
    assert trimesh.load(output, process=False).vertices.shape == trimesh.load(source, process=False).vertices.shape


def test_scale_refuses_to_write_over_its_input(tmp_path, capsys):
    source = tmp_path / "bone.obj"
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[16, 16]).export(source)
    before = source.read_bytes()
    assert main(["scale", str(source), "--global", "--alpha", "0.05", "--modes", "40", "-o", str(source)]) != 0
    assert "input" in capsys.readouterr().err
    assert source.read_bytes() == before


def test_a_run_stopped_at_a_step_still_writes_its_report_and_picture(tmp_path, monkeypatch, capsys,
                                                                     second_output_unmeasurable):
    """A ruleset run that a step stops (its output cannot be measured) ends the command with one
    line, and still leaves what there is to look at: the report of the run as far as it went, its
    picture, and with --keep-unconverged its mesh under the .unconverged name (issue 18 §4)."""
    import json

    from allorules.mesh.quadruped import generate_quadruped

    source = tmp_path / "horse.obj"
    horse = generate_quadruped("horse", vertices=1000)
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(source)
    monkeypatch.setenv("ALLORULES_CACHE_DIR", "off")
    output, picture, report = tmp_path / "big.obj", tmp_path / "big.png", tmp_path / "big.json"
    code = main(["scale", str(source), "--mass-ratio", "1.21", "--modes", "60", "-o", str(output), "--png", str(picture),
                 "--report", str(report), "--keep-unconverged"])
    assert code != 0
    said = capsys.readouterr().err
    assert "step 2 of 2: its output could not be measured" in said and "Traceback" not in said
    data = json.loads(report.read_text())
    assert data["converged"] is False and "could not be measured" in data["error"]
    assert abs(data["mass_ratio"] - 1.1) < 0.011            # judged on step 1's output, the last measured
    assert "quality" in data and data["output"] == str(tmp_path / "big.unconverged.obj")
    assert picture.stat().st_size > 5_000
    assert (tmp_path / "big.unconverged.obj").exists() and not output.exists()


def test_measuring_with_a_labels_file_measures_as_the_labeller_did(tmp_path, capsys):
    """`allorules segment` then `allorules measure --segmentation` (how an output is checked with its
    input's regions) measures what the automatic labelling measures: the labels file keeps the
    labeller's frame, so the torso is measured along the same axis."""
    import json

    from allorules.mesh.quadruped import generate_quadruped

    source, labels = tmp_path / "horse.obj", tmp_path / "horse.labels.json"
    horse = generate_quadruped("horse", vertices=3000, pose="walk")
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(source)
    assert main(["segment", str(source), "-o", str(labels)]) == 0
    capsys.readouterr()
    assert main(["measure", str(source), "--json"]) == 0
    automatic = json.loads(capsys.readouterr().out)
    assert main(["measure", str(source), "--json", "--segmentation", str(labels)]) == 0
    from_file = json.loads(capsys.readouterr().out)
    for direction in ("up", "forward"):
        assert from_file["frame"][direction] == pytest.approx(automatic["frame"][direction])
    for ours, theirs in zip(from_file["rules"], automatic["rules"]):
        assert ours["value"] == pytest.approx(theirs["value"], rel=1e-9), ours["id"]


def test_a_run_missed_on_coarser_working_meshes_too_says_what_each_missed():
    from types import SimpleNamespace

    from allorules.cli.scale import coarser_working_hint
    from allorules.runs.pipeline import WorkingTry

    tried = (WorkingTry(3912, "rule 'chest-girth' reached exponent 0.386, target 0.365"), WorkingTry(2466, "mass ×1.95"))
    hint = coarser_working_hint(SimpleNamespace(also_tried=tried))
    assert "3,912 vertices: rule 'chest-girth' reached exponent 0.386" in hint and "2,466 vertices: mass ×1.95" in hint
    # nothing to say: no other working mesh tried, no working mesh
    assert coarser_working_hint(SimpleNamespace(also_tried=())) == ""
    assert coarser_working_hint(None) == ""
