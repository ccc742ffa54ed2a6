"""Batch runs: manifest validation with file:line, interruption and resume, failures per job, summary."""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

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


def test_a_jobs_report_keeps_the_outputs_quality_and_the_summary_shows_it(inputs, tmp_path):
    """What `allorules scale --report` says of the output (faces turned inside out, new
    self-intersections, roughness, small features) a batch job's report says too, and its summary
    row shows; the batch kept only the result and threw the quality it had measured away."""
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST.replace("  - ball.obj\n", "").replace("[0.9, 1.1]", "[1.1]"))
    result = run_batch(manifest, jobs=1)
    report = json.loads((tmp_path / "out" / "horse__global__x1.1" / "report.json").read_text())
    quality = report["quality"]
    assert quality["flipped_faces"]["count"] == 0 and quality["self_intersections"]["new_pairs"] == 0
    assert quality["roughness"]["rms_degrees"] >= 0 and report["placement"] == "ground"
    row = result.rows[0]
    assert row["flipped_faces"] == 0 and row["self_intersections"] == 0
    assert row["roughness_degrees"] == quality["roughness"]["rms_degrees"]
    assert row["head_turn_degrees"] == quality["head_turn_degrees"] is not None
    with open(tmp_path / "out" / "summary.csv", newline="") as handle:
        cells = next(csv.DictReader(handle))
    assert cells["flipped_faces"] == "0" and float(cells["roughness_degrees"]) == pytest.approx(row["roughness_degrees"], rel=1e-3)


@pytest.mark.heavy
def test_a_job_that_misses_its_targets_fails_and_writes_only_the_unconverged_mesh(inputs, tmp_path):
    """As `allorules scale --keep-unconverged`: the mesh goes to OUT.unconverged.EXT, never under the
    name asked for, and the job fails saying so. A batch wrote it as the output and counted the job
    done (the generated dog walking at x2, its trunk stretched to 0.475, among 24 posed runs)."""
    copy_inputs(inputs, tmp_path)
    (tmp_path / "contradiction.yaml").write_text(
        "name: contradiction\nextends: quadruped\nrules:\n  - id: foreleg-length-again\n    region: forelimbs\n"
        "    measure: length\n    exponent: 1.0\nsolver:\n  max_evaluations: 40\n")
    manifest = write_manifest(tmp_path, MANIFEST.replace("  - ball.obj\n", "").replace("[0.9, 1.1]", "[1.1]")
                              .replace("[global]", "[contradiction.yaml]"))
    folder = tmp_path / "out" / "horse__contradiction__x1.1"
    folder.mkdir(parents=True)
    (folder / "horse_contradiction_x1.1.obj").write_text("left by an earlier run that converged")
    result = run_batch(manifest, jobs=1)
    row = result.rows[0]
    assert row["status"] == "failed" and row["converged"] is False
    assert "did not reach its targets" in row["error"] and "horse_contradiction_x1.1.unconverged.obj" in row["error"]
    assert row["output"] == str(Path("horse__contradiction__x1.1") / "horse_contradiction_x1.1.unconverged.obj")
    assert (folder / "horse_contradiction_x1.1.unconverged.obj").is_file()
    assert not (folder / "horse_contradiction_x1.1.obj").exists()
    assert "0 done, 1 failed, 0 not run" in (tmp_path / "out" / "summary.md").read_text()


def test_a_job_a_step_stops_keeps_its_mesh_and_figures_as_one_that_missed(inputs, tmp_path,
                                                                          second_output_unmeasurable):
    """A job whose run a step stops (its output cannot be measured) fails as a missed one does: the
    mesh it reached under the unconverged name, its figures, and the step that stopped it, as
    `allorules scale --keep-unconverged` keeps them; before, the job's report held the error alone."""
    from allorules.runs.jobs import scale_job

    copy_inputs(inputs, tmp_path)
    job = load_manifest(write_manifest(tmp_path, MANIFEST.replace("[global]", "[quadruped]")
                                       .replace("[0.9, 1.1]", "[1.21]"))).jobs()[0]
    folder = tmp_path / "out" / job.id
    folder.mkdir(parents=True)
    figures = scale_job(job, folder)
    assert "step 2 of 2: its output could not be measured" in figures["error"]
    assert figures["output"].endswith(".unconverged.obj") and (folder / figures["output"]).is_file()
    assert figures["result"]["converged"] is False and abs(figures["result"]["mass_ratio"] - 1.1) < 0.011


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


# ---------------------------------------------------------------------------------------------
# Stopping a batch (issue 19 §5): its workers go with it; SIGTERM writes the summary.

CLI = [sys.executable, "-c", "import sys; from allorules.cli import main; sys.exit(main())"]
SIGNAL_MANIFEST = """\
output: out
meshes:
  - path: horse.obj
    segmentation: horse.labels.json
ratios: [0.6, 0.8, 1.25, 1.6]
rulesets: [global, quadruped]
modes: 12
"""


def descendants(pid: int) -> set[int]:
    """Every live process below ``pid`` (from /proc)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return state[state.rindex(")") + 2] != "Z"


@pytest.fixture
def running_batch(inputs, tmp_path):
    """``allorules batch --jobs 2`` started as a process, once both its workers run jobs; stopped
    (with every process it started) however the test ends."""
    if not Path("/proc/self/stat").exists():
        pytest.skip("needs /proc to see the batch's worker processes")
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, SIGNAL_MANIFEST)
    process = subprocess.Popen(CLI + ["batch", str(manifest), "--jobs", "2"], cwd=tmp_path, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, start_new_session=True)
    seen: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and process.poll() is None:
            seen |= descendants(process.pid)
            workers = [pid for pid in seen if alive(pid) and b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()]
            if len(workers) == 2 and any((tmp_path / "out").glob("*__*")):
                break
            time.sleep(0.1)
        else:
            pytest.fail(f"the batch did not start two workers: {process.communicate()[0] if process.poll() is not None else ''}")
        yield process, tmp_path / "out", set(workers)
    finally:
        for pid in [process.pid] + sorted(seen | descendants(process.pid)):
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
        process.communicate()


def wait_gone(pids: set[int], seconds: float = 10.0) -> set[int]:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(alive(pid) for pid in pids):
        time.sleep(0.05)
    return {pid for pid in pids if alive(pid)}


@pytest.mark.slow
def test_a_batch_killed_with_sigkill_takes_its_workers_with_it(running_batch):
    process, out, workers = running_batch
    assert all(alive(pid) for pid in workers)
    process.kill()
    process.wait(10)
    assert wait_gone(workers, 5.0) == set()     # they used to run on, orphaned, forever
    assert not (out / "summary.json").exists() or json.loads((out / "summary.json").read_text())


@pytest.mark.slow
def test_a_terminated_batch_stops_its_workers_and_writes_its_summary(running_batch):
    process, out, workers = running_batch
    process.terminate()
    printed, _ = process.communicate(timeout=60)
    assert process.returncode == 128 + signal.SIGTERM, printed
    assert "SIGTERM" in printed and "Traceback" not in printed
    assert wait_gone(workers) == set()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert sum(summary["counts"].values()) == 8 and summary["counts"]["not run"] >= 1
    assert not list(out.rglob(".*.tmp"))          # no half-written file left behind
    # Resuming runs only what was not finished (a stand-in scaling: which jobs run is the point).
    finished = {row["job"] for row in summary["jobs"] if row["status"] == "done"}
    resumed = []
    result = run_batch(out.parent / "manifest.yaml", jobs=1, scale=lambda job, folder: resumed.append(job.id) or {})
    assert result.skipped == len(finished) and sorted(resumed) == sorted({row["job"] for row in summary["jobs"]} - finished)


def test_an_unknown_output_format_is_refused_before_anything_runs(inputs, tmp_path, capsys):
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST.replace("modes: 12", "modes: 12\nformat: fbx"))
    assert main(["batch", str(manifest)]) == 2
    error = capsys.readouterr().err
    assert "manifest.yaml:9" in error and "'fbx' is not one of obj, ply, stl, glb, off" in error
    assert not (tmp_path / "out").exists()


def test_the_batch_formats_are_the_exporters():
    from allorules.output.export import SUPPORTED_FORMATS
    from allorules.runs.batch import OUTPUT_FORMATS

    assert tuple(f".{name}" for name in OUTPUT_FORMATS) == SUPPORTED_FORMATS


def test_an_output_folder_that_cannot_be_written_is_refused_before_anything_runs(inputs, tmp_path, capsys):
    copy_inputs(inputs, tmp_path)
    (tmp_path / "blocked").write_text("a file where the output folder's parent should be")
    manifest = write_manifest(tmp_path, MANIFEST.replace("output: out", "output: blocked/out"))
    calls = []
    with pytest.raises(AllorulesError, match="cannot write into the output folder"):
        run_batch(manifest, jobs=1, scale=lambda job, folder: calls.append(job))
    assert calls == []


def test_leftover_temporary_files_of_a_killed_run_are_removed(inputs, tmp_path):
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST)
    folder = tmp_path / "out" / "horse__global__x0.9"
    folder.mkdir(parents=True)
    (folder / ".horse_global_x0.9.obj.abc123.tmp").write_text("half a mesh")
    (folder / "keep.txt").write_text("not ours to delete")
    run_batch(manifest, jobs=1, scale=lambda job, folder: {})
    assert not (folder / ".horse_global_x0.9.obj.abc123.tmp").exists() and (folder / "keep.txt").exists()


# ---------------------------------------------------------------------------------------------
# The scheduler option without Dask, and in the manifest (the cluster itself: test_batch_cluster.py)


def test_scheduler_without_dask_says_what_to_install(inputs, tmp_path, capsys, monkeypatch):
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST)
    monkeypatch.setitem(sys.modules, "distributed", None)     # as if it were not installed
    assert main(["batch", str(manifest), "--scheduler", "tcp://127.0.0.1:8786"]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "pip install 'allorules[distributed]'" in error
    assert not (tmp_path / "out").exists()


def test_scheduler_and_jobs_do_not_go_together(inputs, tmp_path, capsys):
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST)
    assert main(["batch", str(manifest), "--scheduler", "tcp://127.0.0.1:8786", "--jobs", "2"]) == 2
    assert "--jobs is for runs on this machine" in capsys.readouterr().err


@pytest.mark.parametrize("value, expected", [
    ("tcp://10.0.0.5:8786", "tcp://10.0.0.5:8786"),
    ("node17:8786", "tcp://node17:8786"),
    ("tls://head.cluster:8786", "tls://head.cluster:8786"),
    ("cluster/scheduler.json", "SCHEDULER_FILE"),
])
def test_the_manifest_names_the_scheduler(inputs, tmp_path, value, expected):
    copy_inputs(inputs, tmp_path)
    manifest = load_manifest(write_manifest(tmp_path, MANIFEST + f"scheduler: {value}\n"))
    if expected == "SCHEDULER_FILE":
        expected = str((tmp_path / "cluster" / "scheduler.json").resolve())
    assert manifest.scheduler == expected


@pytest.mark.parametrize("value", ["42", "somewhere", "''"])
def test_a_bad_scheduler_is_a_manifest_error(inputs, tmp_path, value):
    copy_inputs(inputs, tmp_path)
    with pytest.raises(ManifestError) as caught:
        load_manifest(write_manifest(tmp_path, MANIFEST + f"scheduler: {value}\n"))
    assert "manifest.yaml:9" in str(caught.value) and "scheduler" in str(caught.value)


def test_shared_files_go_with_a_scheduler(inputs, tmp_path, capsys):
    copy_inputs(inputs, tmp_path)
    manifest = write_manifest(tmp_path, MANIFEST)
    assert main(["batch", str(manifest), "--shared-files"]) == 2
    assert "--shared-files goes with --scheduler" in capsys.readouterr().err
    with pytest.raises(ManifestError, match="manifest.yaml:9.*'shared_files' is true or false"):
        load_manifest(write_manifest(tmp_path, MANIFEST + "shared_files: sometimes\n"))
    assert load_manifest(write_manifest(tmp_path, MANIFEST + "shared_files: true\n")).shared_files is True
