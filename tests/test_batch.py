"""Batch runs: manifest validation with file:line, interruption and resume, failures per job, summary."""
from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest

from allorules.cli import main
from allorules.errors import AllorulesError
from allorules.runs.batch import (
    ManifestError,
    is_finished,
    job_fingerprint,
    load_manifest,
    run_batch,
    run_job,
    scale_job,
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A tiny generated horse with its true labels, and a ball (no legs: auto-labelling fails)."""
    import trimesh

    from allorules.mesh.quadruped import generate_quadruped

    folder = tmp_path_factory.mktemp("batch-inputs")
    horse = generate_quadruped("horse", 600)
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(folder / "horse.obj")
    (folder / "horse.labels.json").write_text(json.dumps(horse.labels_document()))
    trimesh.creation.icosphere(3).export(folder / "ball.obj")
    return folder


def write_manifest(folder, text: str, name: str = "manifest.yaml"):
    path = folder / name
    path.write_text(text)
    return path


def copy_inputs(inputs, folder):
    for item in inputs.iterdir():
        shutil.copy(item, folder / item.name)


MANIFEST = """\
output: out
meshes:
  - path: horse.obj
    segmentation: horse.labels.json
  - ball.obj
ratios: [0.9, 1.1]
rulesets: [global]
modes: 12
"""


@pytest.mark.slow
def test_interrupted_batch_resumes_without_redoing_finished_jobs(inputs, tmp_path, capsys):
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST)
    out = tmp_path / "out"
    calls = []

    def interrupted_at_second_job(job, folder):
        calls.append(job.id)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return scale_job(job, folder)

    with pytest.raises(KeyboardInterrupt):
        run_batch(manifest, jobs=1, scale=interrupted_at_second_job)
    first_report = out / "horse__global__x0.9" / "report.json"
    first_mesh = out / "horse__global__x0.9" / "horse_global_x0.9.obj"
    assert json.loads(first_report.read_text())["status"] == "done"
    assert not (out / "horse__global__x1.1" / "report.json").exists()
    partial = json.loads((out / "summary.json").read_text())
    assert partial["interrupted"] and partial["counts"] == {"done": 1, "failed": 0, "not run": 3}
    stamps = first_report.stat().st_mtime_ns, first_mesh.stat().st_mtime_ns

    result = run_batch(manifest, jobs=2)            # resumed in a process pool
    assert (first_report.stat().st_mtime_ns, first_mesh.stat().st_mtime_ns) == stamps   # not redone
    assert result.skipped == 1 and result.ran == 3 and not result.interrupted
    status = {row["job"]: row["status"] for row in result.rows}
    assert status == {"horse__global__x0.9": "done", "horse__global__x1.1": "done",
                      "ball__global__x0.9": "failed", "ball__global__x1.1": "failed"}
    ball = next(row for row in result.rows if row["job"] == "ball__global__x0.9")
    assert "feet" in ball["error"]                  # the labeller's one-line reason, per job

    # The written mesh has the asked mass ratio (measured on the file).
    import trimesh

    from allorules.mesh.geometry import enclosed_volume

    def volume(path):
        mesh = trimesh.load(path, process=False)
        return enclosed_volume(np.asarray(mesh.vertices), np.asarray(mesh.faces))

    scaled = out / "horse__global__x1.1" / "horse_global_x1.1.obj"
    assert volume(scaled) / volume(tmp_path / "horse.obj") == pytest.approx(1.1, rel=1e-3)

    # One summary listing every job, in three forms.
    summary = json.loads((out / "summary.json").read_text())
    assert summary["counts"] == {"done": 2, "failed": 2, "not run": 0} and not summary["interrupted"]
    with open(out / "summary.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [row["job"] for row in rows] == list(status)
    assert rows[1]["mass_ratio"] and float(rows[1]["mass_ratio"]) == pytest.approx(1.1, rel=1e-4)
    markdown = (out / "summary.md").read_text()
    assert all(job in markdown for job in status)

    # A third run retries only the failed jobs.
    retried = []

    def record(job, folder):
        retried.append(job.id)
        raise AllorulesError("still no legs")

    again = run_batch(manifest, jobs=1, scale=record)
    assert sorted(retried) == ["ball__global__x0.9", "ball__global__x1.1"]
    assert again.skipped == 2 and first_report.stat().st_mtime_ns == stamps[0]

    # The command: nothing left but the failures; exit status 1 says so.
    capsys.readouterr()
    assert main(["batch", str(manifest), "--jobs", "1"]) == 1
    printed = capsys.readouterr().out
    assert "2 done" in printed and "2 failed" in printed and "summary.md" in printed


def test_changed_inputs_change_the_fingerprint(inputs, tmp_path):
    copy_inputs(inputs, tmp_path)
    manifest = load_manifest(write_manifest(tmp_path, MANIFEST))
    job = manifest.jobs()[0]
    before = job_fingerprint(job)
    assert job_fingerprint(job) == before
    with open(tmp_path / "horse.obj", "a") as handle:
        handle.write("# edited\n")
    assert job_fingerprint(job) != before
    edited_mesh = job_fingerprint(job)
    labels = json.loads((tmp_path / "horse.labels.json").read_text())
    labels["labels"][0] = (labels["labels"][0] + 1) % len(labels["regions"])
    (tmp_path / "horse.labels.json").write_text(json.dumps(labels))
    assert job_fingerprint(job) != edited_mesh
    assert job_fingerprint(manifest.jobs()[1]) != job_fingerprint(job)     # another ratio


def test_a_report_is_finished_only_with_its_fingerprint_and_mesh(inputs, tmp_path):
    copy_inputs(inputs, tmp_path)
    manifest = load_manifest(write_manifest(tmp_path, MANIFEST))
    job = manifest.jobs()[0]
    folder = tmp_path / "job"
    folder.mkdir()
    assert not is_finished(job, folder, "abc")
    (folder / "report.json").write_text(json.dumps({"format": "allorules-batch-job", "status": "done",
                                                    "fingerprint": "abc"}))
    assert not is_finished(job, folder, "abc")           # its mesh is missing
    (folder / job.output_name).write_text("v 0 0 0\n")
    assert is_finished(job, folder, "abc")
    assert not is_finished(job, folder, "changed")
    (folder / "report.json").write_text("{ half written")
    assert not is_finished(job, folder, "abc")


def test_the_summary_lists_what_each_output_should_be_looked_at_for(inputs, tmp_path):
    copy_inputs(inputs, tmp_path)
    bowed = "hindlimbs[0] bows by 6.0% of its length more than in the input"

    def scale(job, folder):   # the report of a converged run whose output still shows something
        warnings = [bowed, "the legs lean by up to 4.0°"] if job.ratio < 1 else []
        return {"result": {"converged": True, "mass_ratio": job.ratio, "warnings": warnings}}

    result = run_batch(write_manifest(tmp_path, MANIFEST), jobs=1, scale=scale)
    with open(tmp_path / "out" / "summary.csv", newline="") as handle:
        warnings = {row["job"]: row["warnings"] for row in csv.DictReader(handle)}
    assert warnings["horse__global__x0.9"] == f"{bowed}; the legs lean by up to 4.0°"
    assert warnings["horse__global__x1.1"] == ""
    assert bowed in (tmp_path / "out" / "summary.md").read_text()
    assert [row["warnings"] for row in result.rows if row["job"].endswith("x1.1")] == [None, None]


def test_a_jobs_warnings_name_the_job(inputs, tmp_path, caplog):
    """Workers share one terminal: a warning from deep inside a job (export, say) names the job."""
    import logging

    copy_inputs(inputs, tmp_path)
    job = load_manifest(write_manifest(tmp_path, MANIFEST)).jobs()[0]

    def scale(job, folder):
        logging.getLogger("allorules.output.export").warning("%s: UVs dropped", "horse.obj")
        logging.getLogger("somebody.else").warning("not ours")
        return {}

    with caplog.at_level(logging.WARNING):
        report = run_job(job, tmp_path / "out", "fingerprint", scale)
    assert report["status"] == "done"
    messages = {record.name: record.getMessage() for record in caplog.records}
    assert messages["allorules.output.export"] == f"{job.id}: horse.obj: UVs dropped"
    assert messages["somebody.else"] == "not ours"
    logging.getLogger("allorules").warning("after the job")
    assert caplog.records[-1].getMessage() == "after the job"


def test_a_ruleset_job_is_named_and_validated(inputs, tmp_path):
    copy_inputs(inputs, tmp_path)
    manifest = load_manifest(write_manifest(tmp_path, MANIFEST.replace("[global]", "[global, quadruped]")
                                            .replace("modes: 12", "modes: 12\nformat: ply")))
    ids = [job.id for job in manifest.jobs()]
    assert len(ids) == 8 and len(set(ids)) == 8
    assert "horse__quadruped__x1.1" in ids
    assert all(job.output_name.endswith(".ply") for job in manifest.jobs())
    assert manifest.output == (tmp_path / "out").resolve()


@pytest.mark.parametrize(
    "text, line, message",
    [
        ("meshes: [horse.obj]\nratios: [0.9]\nrulesets: [global]\nratio: 2\n", 4, "unknown key 'ratio'"),
        ("meshes: [nothere.obj]\nratios: [0.9]\nrulesets: [global]\n", 1, "not found"),
        ("meshes: [horse.obj]\nratios: [0.9, -2]\nrulesets: [global]\n", 2, "positive"),
        ("meshes: [horse.obj]\nratios: [0.9, 0.9]\nrulesets: [global]\n", 2, "twice"),
        ("meshes: [horse.obj]\nratios: [two]\nrulesets: [global]\n", 2, "not a number"),
        ("meshes: [horse.obj]\nratios: [0.9]\nrulesets: [global, nosuch]\n", 3, "unknown ruleset"),
        ("meshes: [horse.obj]\nratios: [0.9]\n", 1, "'rulesets' is missing"),
        ("meshes: [horse.obj]\nratios: [0.9]\nrulesets: [global]\nmodes: 1\n", 4, "modes"),
        ("meshes: [horse.obj]\nratios: [0.9]\nrulesets: [global]\nformat: fbx\n", 4, "fbx"),
        ("meshes:\n  - horse.obj\n  - path: horse.obj\nratios: [0.9]\nrulesets: [global]\n", 3, "different 'name:'"),
        ("meshes:\n  - path: horse.obj\n    colour: red\nratios: [0.9]\nrulesets: [global]\n", 3, "unknown key 'colour'"),
        ("meshes: [horse.obj]\nratios: [0.9]\nratios: [2]\nrulesets: [global]\n", 3, "given twice"),
        ("meshes: [horse.obj\nratios: [0.9]\n", 2, "YAML syntax error"),
        ("- horse.obj\n", 1, "mapping"),
        ("", 1, "empty"),
    ],
)
def test_manifest_errors_name_file_and_line(inputs, tmp_path, text, line, message):
    copy_inputs(inputs, tmp_path)
    path = write_manifest(tmp_path, text, "bad.yaml")
    with pytest.raises(ManifestError) as caught:
        load_manifest(path)
    text = str(caught.value)
    assert f"bad.yaml:{line}" in text and message in text and "\n" not in text


def test_cli_reports_manifest_errors_in_one_line(tmp_path, capsys):
    path = write_manifest(tmp_path, "meshes: [horse.obj]\n", "bad.yaml")
    assert main(["batch", str(path)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("allorules batch: error:") and "bad.yaml:1" in error and len(error.splitlines()) == 1
