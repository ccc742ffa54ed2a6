"""An output's own labels file: `allorules scale` writes the run's regions beside the mesh it
writes (OUT.labels.json), and `measure` / `scale` read a mesh's own labels file where it fits the
mesh, so that an output is measured with the regions and axes its run measured instead of being
labelled afresh as another animal (docs/segmentation.md, "A mesh's own labels file")."""
from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest

from allorules.body import Body
from allorules.cli import main
from allorules.errors import SegmentationError
from allorules.mesh.quadruped import generate_quadruped
from allorules.segment.labels_io import (
    UnsaidMeshError,
    faces_fingerprint,
    labels_file_beside,
    read_labels,
)

RATIO = 1.1


@pytest.fixture(scope="module")
def scaled(tmp_path_factory):
    """A small generated horse as OBJ (no labels beside it) and one converged run of it, ×1.1."""
    import trimesh

    folder = tmp_path_factory.mktemp("output_labels")
    horse = generate_quadruped("horse", 1200)
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(folder / "horse.obj")
    code = main(["scale", str(folder / "horse.obj"), "--mass-ratio", str(RATIO), "--modes", "20",
                 "-o", str(folder / "big.obj"), "--report", str(folder / "big.json")])
    assert code == 0
    return folder


def measured(arguments: list[str], capsys, said: list[str] | None = None) -> dict:
    """``allorules measure ... --json`` as a dict; what it said on stderr appended to ``said``."""
    capsys.readouterr()
    assert main(["measure", *arguments, "--json"]) == 0
    captured = capsys.readouterr()
    if said is not None:
        said.append(captured.err)
    return json.loads(captured.out)


def sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_output_carries_the_regions_its_run_measured(scaled):
    import trimesh

    labels = scaled / "big.labels.json"
    assert labels == labels_file_beside(scaled / "big.obj")
    document = json.loads(labels.read_text())
    out = trimesh.load(scaled / "big.obj", process=False)
    assert document["faces_sha256"] == faces_fingerprint(np.asarray(out.faces))
    assert len(document["labels"]) == len(out.vertices)
    report = json.loads((scaled / "big.json").read_text())
    assert set(document["regions"]) >= {"head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs"}
    assert set(report["labels"]["regions"]) == set(document["regions"])
    assert "up" in document["frame"] and "forward" in document["frame"]
    tape = document["heart_girth_tape"]          # where the run put heart girth's tape on its input
    assert tape["piece"] in ("part", "torso", "body") and tape["levels"] and 0 <= tape["margin"] < 1


def test_measuring_the_output_again_gives_the_exponents_its_run_reported(scaled, capsys):
    """The input labelled afresh and the output with its own labels file: each rule's exponent as
    the run's report says (a fresh labelling of the output is told apart: --relabel)."""
    before = measured([str(scaled / "horse.obj")], capsys)
    after = measured([str(scaled / "big.obj")], capsys)
    assert before["segmentation"] == "automatic"
    assert after["segmentation"] == str(scaled / "big.labels.json")
    report = json.loads((scaled / "big.json").read_text())
    achieved = {rule["id"]: rule["achieved_exponent"] for rule in report["rules"]}
    for first, second in zip(before["rules"], after["rules"]):
        exponent = math.log(second["value"] / first["value"]) / math.log(RATIO)
        assert exponent == pytest.approx(achieved[first["id"]], abs=0.01), first["id"]
    assert measured([str(scaled / "big.obj"), "--relabel"], capsys)["segmentation"] == "automatic"


def test_a_labels_file_beside_made_for_another_mesh_is_passed_over(scaled, tmp_path, capsys):
    import shutil

    shutil.copy(scaled / "horse.obj", tmp_path / "horse.obj")
    other = json.loads((scaled / "big.labels.json").read_text())
    other["faces_sha256"] = "0" * 64
    (tmp_path / "horse.labels.json").write_text(json.dumps(other))
    said: list[str] = []
    assert measured([str(tmp_path / "horse.obj")], capsys, said)["segmentation"] == "automatic"
    assert "made for another mesh" in said[0] and "labelling the mesh afresh" in said[0]
    del other["faces_sha256"]          # an older file: says nothing, and was never read beside a mesh
    (tmp_path / "horse.labels.json").write_text(json.dumps(other))
    assert measured([str(tmp_path / "horse.obj")], capsys)["segmentation"] == "automatic"
    # named, a file is still used as given
    named = measured([str(tmp_path / "horse.obj"), "--segmentation", str(tmp_path / "horse.labels.json")], capsys)
    assert named["segmentation"] == str(tmp_path / "horse.labels.json")


def test_reading_a_labels_file_checks_its_faces():
    horse = generate_quadruped("horse", 1200)
    body = Body(horse.vertices, horse.faces)
    document = {"format": "allorules-labels", "version": 1, "regions": ["a"], "labels": [0] * len(horse.vertices)}
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "x.labels.json"
        path.write_text(json.dumps(document))
        assert read_labels(path, body).labels.sum() == 0          # an older file, named: read
        with pytest.raises(UnsaidMeshError):
            read_labels(path, body, same_faces=True)
        path.write_text(json.dumps({**document, "faces_sha256": faces_fingerprint(horse.faces[::-1])}))
        with pytest.raises(SegmentationError, match="made for another mesh"):
            read_labels(path, body, same_faces=True)
        path.write_text(json.dumps({**document, "faces_sha256": faces_fingerprint(horse.faces)}))
        assert read_labels(path, body, same_faces=True).region_names == ("a",)


def test_the_outputs_labels_file_is_checked_before_the_work(scaled, capsys):
    """An existing labels file beside -o is refused without --force, the input's own labels file
    always (here -o big.ply beside big.obj, whose labels file is big.labels.json), before any run;
    nothing the user has changes."""
    kept = {path.name: sha256(path) for path in scaled.iterdir()}
    (scaled / "small.labels.json").write_text("{}")
    assert main(["scale", str(scaled / "big.obj"), "--mass-ratio", "0.5", "-o", str(scaled / "small.obj")]) != 0
    assert "small.labels.json" in capsys.readouterr().err
    assert not (scaled / "small.obj").exists()
    (scaled / "small.labels.json").unlink()
    assert main(["scale", str(scaled / "big.obj"), "--mass-ratio", "0.5", "-o", str(scaled / "big.ply"), "--force"]) != 0
    error = capsys.readouterr().err
    assert "big.labels.json" in error and "never overwritten" in error
    assert not (scaled / "big.ply").exists()
    assert {path.name: sha256(path) for path in scaled.iterdir()} == kept


def test_a_labels_files_tape_is_where_heart_girth_is_measured(tmp_path):
    """The tape a labels file keeps is read back as it was written, a malformed one is passed over
    (the tape placed afresh), and heart girth is measured where the tape says: at its levels only,
    not at the largest of the levels it would choose itself."""
    from dataclasses import replace

    from allorules.body import HeartGirthTape
    from allorules.measure.girth import chest_girth, heart_girth_tape
    from allorules.segment.labels_io import write_labels

    horse = generate_quadruped("horse", 2000).body()
    chosen = heart_girth_tape(horse)
    assert chosen is not None and len(chosen.levels) > 1
    path = tmp_path / "horse.labels.json"
    write_labels(path, replace(horse, tape=chosen))
    assert read_labels(path, Body(horse.vertices, horse.faces)).tape == chosen
    document = json.loads(path.read_text())
    document["heart_girth_tape"]["piece"] = "somewhere"
    path.write_text(json.dumps(document))
    assert read_labels(path, Body(horse.vertices, horse.faces)).tape is None

    largest = chest_girth(horse.with_vertices(horse.vertices))
    one_level = [replace(horse.with_vertices(horse.vertices), tape=HeartGirthTape((level,), chosen.piece, chosen.margin))
                 for level in chosen.levels[:3]]
    girths = [chest_girth(body) for body in one_level]
    assert max(girths) <= largest + 1e-12 and min(girths) < largest - 1e-6


def test_a_labels_file_far_larger_than_its_mesh_needs_is_not_read(tmp_path):
    """A file named like a mesh's labels that is something else (here 2 MB of spaces beside a
    1,200-vertex mesh's regions) is refused by its size, before it is read whole."""
    horse = generate_quadruped("horse", 1200)
    path = tmp_path / "horse.labels.json"
    path.write_text(json.dumps(horse.labels_document()) + " " * 2_000_000)
    with pytest.raises(SegmentationError, match="too large for the labels of a mesh of"):
        read_labels(path, Body(horse.vertices, horse.faces))


@pytest.fixture(scope="module")
def remeshed(tmp_path_factory):
    """A generated horse of 3,000 vertices run ×1.5 on a working mesh of 2,000 (remeshed), its
    output saved with its labels file, and the run."""
    import trimesh

    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline

    folder = tmp_path_factory.mktemp("recorded_working")
    horse = generate_quadruped("horse", 3000)
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(folder / "horse.obj")
    run = pipeline.run(folder / "horse.obj", pipeline.RulesetScaling(load_ruleset("quadruped"), 1.5), modes=30,
                       working_vertices=2000, use_cache=False)
    assert run.working is not None and run.working.mesh.method == "remeshed"
    pipeline.save_output(run, folder / "big.obj")
    return folder, run


def test_an_output_is_measured_on_the_working_mesh_its_run_measured(remeshed, capsys):
    """The output's labels file records the run's working mesh as points of the input; measuring
    the output takes the same points of the output (the run's working output, to the transfer's
    sampling error) with the run's own regions, so every exponent is the report's to 0.005. The
    output remeshed afresh instead (another working size) is off by up to 0.08 here (head mass)."""
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline

    folder, run = remeshed
    prepared = pipeline.prepare(folder / "big.obj")
    work, body = pipeline.labelled_working(prepared, registry=registry_for(None),
                                           regions=pipeline.wanted_regions(load_ruleset("quadruped")))
    assert work.mesh.method == "recorded" and work.binding is not None
    after = run.result.body.vertices
    assert np.abs(work.mesh.vertices - after).max() < 0.005 * np.ptp(after, axis=0).max()
    assert body.region_names == run.body.region_names and np.array_equal(body.labels, run.body.labels)
    assert body.tape is not None and body.frame is not None

    before = measured([str(folder / "horse.obj"), "--working-vertices", "2000"], capsys)
    again = measured([str(folder / "big.obj")], capsys)
    assert again["vertices"] == len(run.body.vertices) and again["working_mesh"] == "recorded"
    assert before["working_mesh"] == "remeshed"
    achieved = {rule["id"]: rule["achieved_exponent"] for rule in run.report()["rules"]}
    for first, second in zip(before["rules"], again["rules"]):
        exponent = math.log(second["value"] / first["value"]) / math.log(1.5)
        assert exponent == pytest.approx(achieved[first["id"]], abs=0.005), first["id"]


def test_a_recorded_working_mesh_is_used_only_where_it_fits(remeshed, caplog):
    """Another working size asked for, a malformed record, or a body moved so far that the recorded
    points no longer make a mesh: the output is remeshed afresh and the regions carried over."""
    import logging

    from allorules.mesh.working import WorkingRecord
    from allorules.plugins.registry import registry_for
    from allorules.runs import pipeline

    folder, run = remeshed
    prepared = pipeline.prepare(folder / "big.obj")
    registry = registry_for(None)
    work, body = pipeline.labelled_working(prepared, registry=registry, working_vertices=2100)
    assert work.mesh.method == "remeshed" and body.labels is not None

    record = pipeline.read_labels_beside(prepared).working
    assert isinstance(record, WorkingRecord) and record.target_vertices == 2000
    collapsed = prepared.vertices * np.array([1.0, 1e-3, 1.0])       # flattened: slivers everywhere
    assert record.on(collapsed, prepared.faces) is None
    assert record.on(prepared.vertices, prepared.faces) is not None

    path = folder / "big.labels.json"
    document = json.loads(path.read_text())
    try:
        path.write_text(json.dumps({**document, "working_mesh": {**document["working_mesh"], "triangles": [10**9]}}))
        with caplog.at_level(logging.WARNING, logger="allorules"):
            work, body = pipeline.labelled_working(pipeline.prepare(folder / "big.obj"), registry=registry,
                                                   working_vertices=2000)
        assert work.mesh.method == "remeshed" and body.labels is not None
        assert "working_mesh is malformed" in caplog.text
    finally:
        path.write_text(json.dumps(document))


def test_a_working_record_gives_back_its_working_mesh_on_its_own_body(tmp_path):
    """Recorded on the body it was made from and read back from a labels file, the working mesh is
    the same to 1e-8 of its size (weights kept to 1e-9)."""
    from allorules.mesh.working import WorkingRecord, make_working_mesh
    from allorules.segment.labels_io import read_labels_file, write_labels

    horse = generate_quadruped("horse", 3000).body()
    mesh = make_working_mesh(horse.vertices, horse.faces, 2000)
    record = WorkingRecord.of(mesh, horse.vertices, horse.faces, labels=np.zeros(len(mesh.vertices), dtype=int))
    size = np.ptp(horse.vertices, axis=0).max()
    assert np.abs(record.on(horse.vertices, horse.faces).vertices - mesh.vertices).max() < 1e-12 * size
    write_labels(tmp_path / "horse.labels.json", horse, record)
    back = read_labels_file(tmp_path / "horse.labels.json", Body(horse.vertices, horse.faces)).working
    rebuilt = back.on(horse.vertices, horse.faces)
    assert rebuilt.method == "recorded" and np.array_equal(rebuilt.faces, mesh.faces)
    assert np.abs(rebuilt.vertices - mesh.vertices).max() < 1e-8 * size
    assert np.array_equal(back.labels, record.labels)
    # made for other faces, the record is not read (the labels are, with a warning)
    other = Body(horse.vertices, horse.faces[::-1])
    assert read_labels_file(tmp_path / "horse.labels.json", other).working is None


def test_an_animal_in_pieces_is_written_piece_by_piece_with_no_labels_file(tmp_path):
    """Its output keeps every piece's vertices and faces, scaled with the joined surface; no labels
    file is written beside it (read again, its pieces are joined into a surface of other vertices)."""
    import trimesh
    from pieces import pieces_quadruped

    from allorules.runs import pipeline

    mesh, marks = pieces_quadruped()
    mesh.export(tmp_path / "toy.obj")
    run = pipeline.run(tmp_path / "toy.obj", pipeline.GlobalScaling(RATIO), modes=12, working_vertices=2000,
                       use_cache=False)
    assert run.prepared.pieces is not None
    pipeline.save_output(run, tmp_path / "big.obj")
    pipeline.save_picture(run, tmp_path / "big.png")
    written = trimesh.load(tmp_path / "big.obj", force="mesh", process=False)
    assert written.vertices.shape == mesh.vertices.shape and np.array_equal(written.faces, mesh.faces)
    assert np.isfinite(written.vertices).all()
    assert not labels_file_beside(tmp_path / "big.obj").exists() and (tmp_path / "big.png").stat().st_size > 0
    # every piece moved: the muzzle forward, the feet still on the ground (Z up)
    grown = np.ptp(written.vertices, axis=0) / np.ptp(mesh.vertices, axis=0)
    assert np.all(grown > 1.0) and np.all(grown < RATIO)
    feet = np.concatenate([marks["forelimbs"], marks["hindlimbs"]])
    height = np.ptp(mesh.vertices[:, 2])
    assert abs(written.vertices[feet, 2].min() - mesh.vertices[feet, 2].min()) < 0.005 * height
