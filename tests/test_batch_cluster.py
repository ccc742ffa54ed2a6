"""Batch runs on a real Dask cluster (issue 21): a `dask scheduler` and two `dask worker` processes on
127.0.0.1, started and stopped by the fixtures, every job identical to a local run's, a worker
killed mid-run, resuming, failures per job, Ctrl-C on the client.

Marked ``distributed`` (``-m 'not distributed'`` leaves them out); skipped where Dask is not
installed (``pip install '.[distributed]'``).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

distributed = pytest.importorskip("distributed", reason="needs Dask: pip install '.[distributed]'")

from allorules.runs import cluster as cluster_module  # noqa: E402
from allorules.runs.batch import load_manifest, run_batch  # noqa: E402
from allorules.segment.labels_io import labels_file_beside  # noqa: E402

pytestmark = pytest.mark.distributed

CLI = [sys.executable, "-c", "import sys; from allorules.cli import main; sys.exit(main())"]
DASK = [sys.executable, "-m", "dask"]


# ---------------------------------------------------------------------------------------------
# A cluster on the loopback, started and stopped by the test


@dataclass
class Cluster:
    folder: Path
    scheduler_file: Path
    processes: dict[str, subprocess.Popen] = field(default_factory=dict)

    def start(self, name: str, command: list[str]) -> subprocess.Popen:
        log = open(self.folder / f"{name}.log", "w")
        # Its own session: the worker's nanny and the worker process it spawns are stopped together.
        process = subprocess.Popen(command, cwd=self.folder, stdout=log, stderr=subprocess.STDOUT,
                                   start_new_session=True)
        log.close()
        self.processes[name] = process
        return process

    def start_worker(self, name: str) -> None:
        self.start(name, DASK + ["worker", "--scheduler-file", str(self.scheduler_file), "--nthreads", "1",
                                 "--nworkers", "1", "--name", name, "--no-dashboard", "--host", "127.0.0.1",
                                 "--local-directory", str(self.folder / name)])

    @property
    def address(self) -> str:
        return json.loads(self.scheduler_file.read_text())["address"]

    def client(self):
        return distributed.Client(self.address, timeout=30, set_as_default=False)

    def wait_for_workers(self, count: int, seconds: float = 90) -> dict[str, str]:
        """{worker name: address} once ``count`` workers are connected."""
        with self.client() as client:
            client.wait_for_workers(count, timeout=seconds)
            return {info["name"]: address for address, info in client.scheduler_info()["workers"].items()}

    def kill(self, name: str, how: int = signal.SIGKILL) -> None:
        """Kill a process and everything it started (its session's process group)."""
        process = self.processes[name]
        try:
            os.killpg(process.pid, how)
        except ProcessLookupError:
            pass
        process.wait(30)

    def stop(self) -> None:
        for name, process in reversed(list(self.processes.items())):
            if process.poll() is None:
                try:
                    os.killpg(process.pid, signal.SIGTERM)
                    process.wait(15)
                except (ProcessLookupError, subprocess.TimeoutExpired):
                    pass
            try:
                os.killpg(process.pid, signal.SIGKILL)   # whatever is left of the group
            except (ProcessLookupError, PermissionError):
                pass
            process.wait(15)


def start_cluster(folder: Path, request) -> Cluster:
    cluster = Cluster(folder, folder / "scheduler.json")
    request.addfinalizer(cluster.stop)   # registered first: stopped even when starting fails
    cluster.start("scheduler", DASK + ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                       "--scheduler-file", str(cluster.scheduler_file)])
    deadline = time.monotonic() + 60
    while not cluster.scheduler_file.exists():
        if time.monotonic() > deadline or cluster.processes["scheduler"].poll() is not None:
            pytest.fail(f"the Dask scheduler did not start: {(folder / 'scheduler.log').read_text()}")
        time.sleep(0.1)
    cluster.start_worker("w1")
    cluster.start_worker("w2")
    cluster.wait_for_workers(2)
    return cluster


@pytest.fixture(scope="module")
def cluster(tmp_path_factory, request) -> Cluster:
    return start_cluster(tmp_path_factory.mktemp("dask"), request)


@pytest.fixture
def own_cluster(tmp_path_factory, request) -> Cluster:
    """A cluster for a test that kills one of its workers."""
    return start_cluster(tmp_path_factory.mktemp("dask-own"), request)


# ---------------------------------------------------------------------------------------------
# Inputs: generated animals with their true labels, and a ball no labeller can label


@pytest.fixture(scope="module")
def animals(tmp_path_factory) -> Path:
    import trimesh

    from allorules.mesh.quadruped import generate_quadruped

    folder = tmp_path_factory.mktemp("animals")
    for name, preset, vertices in (("horse", "horse", 600), ("dog", "dog", 800)):
        animal = generate_quadruped(preset, vertices)
        trimesh.Trimesh(animal.vertices, animal.faces, process=False).export(folder / f"{name}.obj")
        (folder / f"{name}.labels.json").write_text(json.dumps(animal.labels_document()))
    trimesh.creation.icosphere(3).export(folder / "ball.obj")
    return folder


def manifest(folder: Path, animals: Path, meshes: list[str], *, output: str = "out", modes: int = 16,
             rulesets: str = "[global, quadruped]") -> Path:
    lines = [f"output: {output}", "meshes:"]
    for name in meshes:
        labels = animals / f"{name}.labels.json"
        lines.append(f"  - path: {animals / name}.obj" + (f"\n    segmentation: {labels}" if labels.exists() else ""))
    lines += ["ratios: [0.8, 1.25]", f"rulesets: {rulesets}", f"modes: {modes}"]
    path = folder / f"{output}.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def figures(report: dict) -> dict:
    """A report without what may differ between two runs of the same job: times and the worker."""
    def strip(value):
        if isinstance(value, dict):
            return {key: strip(item) for key, item in value.items() if not key.endswith("seconds") and key != "worker"}
        if isinstance(value, list):
            return [strip(item) for item in value]
        return value

    return strip(report)


def reports(output: Path) -> dict[str, dict]:
    return {path.parent.name: json.loads(path.read_text()) for path in sorted(output.glob("*/report.json"))}


class Writes:
    """Counts what the client writes per job (outputs and failure reports)."""

    def __init__(self, monkeypatch) -> None:
        self.count: dict[str, int] = {}
        write, fail = cluster_module.write_outcome, cluster_module.record_failure

        def counted_write(job, outcome, output):
            self.count[job.id] = self.count.get(job.id, 0) + 1
            return write(job, outcome, output)

        def counted_failure(job, output, fingerprint, error):
            self.count[job.id] = self.count.get(job.id, 0) + 1
            return fail(job, output, fingerprint, error)

        monkeypatch.setattr(cluster_module, "write_outcome", counted_write)
        monkeypatch.setattr(cluster_module, "record_failure", counted_failure)


# ---------------------------------------------------------------------------------------------
# The tests


def test_cluster_jobs_equal_local_jobs_and_failures_stay_per_job(cluster, animals, tmp_path, monkeypatch):
    writes = Writes(monkeypatch)
    on_cluster = manifest(tmp_path, animals, ["horse", "ball"], output="cluster")
    result = run_batch(on_cluster, scheduler=cluster.address)
    status = {row["job"]: row["status"] for row in result.rows}
    assert len(status) == 8 and result.ran == 8 and not result.interrupted
    assert {job: state for job, state in status.items() if job.startswith("horse")} == dict.fromkeys(
        ["horse__global__x0.8", "horse__global__x1.25", "horse__quadruped__x0.8", "horse__quadruped__x1.25"], "done")
    # The ball has no legs: each of its jobs fails with the labeller's reason; the horse's ran on.
    for row in result.rows:
        if row["job"].startswith("ball"):
            assert row["status"] == "failed" and "feet" in row["error"], row
    assert writes.count == dict.fromkeys(status, 1)
    summary = json.loads((tmp_path / "cluster" / "summary.json").read_text())
    assert summary["counts"] == {"done": 4, "failed": 4, "not run": 0}

    # The same manifest on this machine's pool: the same reports and the same mesh files.
    local = manifest(tmp_path, animals, ["horse", "ball"], output="local")
    run_batch(local, jobs=2)
    remote, here = reports(tmp_path / "cluster"), reports(tmp_path / "local")
    assert remote.keys() == here.keys()
    workers = set(cluster.wait_for_workers(2).values())
    for job, report in remote.items():
        if report["status"] == "done":
            assert report["worker"] in workers
            assert figures(report) == figures(here[job]), job
            mesh = report["output"]
            assert (tmp_path / "cluster" / job / mesh).read_bytes() == (tmp_path / "local" / job / mesh).read_bytes()
        else:
            assert report["error"] == here[job]["error"]
    assert "labels file " + str(animals / "horse.labels.json") in remote["horse__global__x0.8"]["labels"]["source"]
    assert not list((tmp_path / "cluster").rglob("*.tmp"))

    # Resumed: the finished jobs are skipped (not written again), the failed ones are retried.
    stamps = {job: (tmp_path / "cluster" / job / "report.json").stat().st_mtime_ns for job in status
              if status[job] == "done"}
    writes.count.clear()
    again = run_batch(on_cluster, scheduler=cluster.address)
    assert again.skipped == 4 and again.ran == 4
    assert sorted(writes.count) == sorted(job for job in status if job.startswith("ball"))
    assert {job: (tmp_path / "cluster" / job / "report.json").stat().st_mtime_ns for job in stamps} == stamps


def test_a_worker_killed_mid_run_costs_only_its_jobs_in_flight(own_cluster, animals, tmp_path, monkeypatch):
    writes = Writes(monkeypatch)
    path = manifest(tmp_path, animals, ["horse", "dog"], modes=24)
    names = own_cluster.wait_for_workers(2)
    output = load_manifest(path).output
    killed: dict[str, object] = {}

    def kill_w1_mid_job() -> None:
        """Once a job is done and w1 is running one, kill w1 and its nanny (a machine gone)."""
        with own_cluster.client() as client:
            deadline = time.monotonic() + 300
            while time.monotonic() < deadline:
                processing = client.processing().get(names["w1"], [])
                if processing and any(output.glob("*/report.json")):
                    killed["keys"] = [str(key) for key in processing]
                    own_cluster.kill("w1")
                    killed["at"] = time.monotonic()
                    return
                time.sleep(0.05)

    killer = threading.Thread(target=kill_w1_mid_job, daemon=True)
    killer.start()
    result = run_batch(path, scheduler=own_cluster.address)
    killer.join(30)
    assert killed.get("keys"), "w1 was never seen running a job"
    assert own_cluster.processes["w1"].poll() is not None
    status = {row["job"]: row["status"] for row in result.rows}
    assert status == dict.fromkeys(status, "done") and len(status) == 8
    assert writes.count == dict.fromkeys(status, 1)       # each output written once
    done = reports(output)
    # The jobs w1 had in flight were run again on w2 (one may have finished, and been fetched, in
    # the instant between looking and killing).
    lost = [job for job in done if any(key.startswith(f"allorules-{job}-") for key in killed["keys"])]
    assert lost and any(done[job]["worker"] == names["w2"] for job in lost)
    assert {report["worker"] for report in done.values()} <= {names["w1"], names["w2"]}
    assert not list(output.rglob("*.tmp"))
    summary = json.loads((output / "summary.json").read_text())
    assert summary["counts"] == {"done": 8, "failed": 0, "not run": 0}


def test_ctrl_c_on_the_client_cancels_its_jobs_and_writes_the_summary(cluster, animals, tmp_path):
    path = manifest(tmp_path, animals, ["horse", "dog"], modes=24)
    out = tmp_path / "out"
    client = subprocess.Popen(CLI + ["batch", str(path), "--scheduler", str(cluster.scheduler_file)], cwd=tmp_path,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not any(out.glob("*/report.json")) and time.monotonic() < deadline and client.poll() is None:
            time.sleep(0.05)
        client.send_signal(signal.SIGINT)
        printed, _ = client.communicate(timeout=60)
    finally:
        if client.poll() is None:
            os.killpg(client.pid, signal.SIGKILL)
            client.communicate()
    assert client.returncode == 130, printed
    assert "cancelled" in printed and "Traceback" not in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and summary["counts"]["done"] >= 1 and summary["counts"]["not run"] >= 1
    # The scheduler forgets the cancelled jobs.
    with cluster.client() as observer:
        deadline = time.monotonic() + 30
        while any(str(key).startswith("allorules-") for keys in observer.processing().values() for key in keys):
            assert time.monotonic() < deadline, observer.processing()
            time.sleep(0.2)


def test_an_unreachable_scheduler_is_one_line(animals, tmp_path, capsys, monkeypatch):
    import socket

    from allorules.cli import main

    with socket.socket() as probe:       # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    monkeypatch.setattr(cluster_module, "CONNECT_SECONDS", 2)
    path = manifest(tmp_path, animals, ["horse"])
    assert main(["batch", str(path), "--scheduler", f"tcp://127.0.0.1:{port}"]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port}" in error
    assert not (tmp_path / "out").exists()


@pytest.fixture
def blas_restored():
    """run_payload sets its process's BLAS to one thread, as on a worker: undone for this process."""
    yield
    while cluster_module._blas_limited:
        cluster_module._blas_limited.pop().restore_original_limits()


def test_a_job_carries_its_files_and_runs_where_they_are_not(animals, tmp_path, blas_restored):
    """The payload alone (no access to the client's files) runs the job: the worker's function is
    called here on a copy whose original files are gone."""
    import shutil

    copy = tmp_path / "inputs"
    shutil.copytree(animals, copy)
    (copy / "horse.mtl").write_text("newmtl skin\nmap_Kd textures/skin.png\n")
    (copy / "textures").mkdir()
    (copy / "textures" / "skin.png").write_bytes(b"\x89PNG not really")
    obj = (copy / "horse.obj").read_text()
    (copy / "horse.obj").write_text("mtllib horse.mtl\nusemtl skin\n" + obj)
    job = load_manifest(manifest(tmp_path, copy, ["horse"], rulesets="[quadruped]")).jobs()[0]
    payload = cluster_module.job_payload(job, "fingerprint")
    assert [carried.path for carried in payload.mesh] == ["horse.obj", "horse.mtl", "textures/skin.png"]
    assert payload.segmentation.path == "horse.labels.json" and "name: quadruped" in payload.ruleset
    shutil.rmtree(copy)
    outcome = cluster_module.run_payload(payload)
    assert outcome.report["status"] == "done", outcome.report.get("error")
    regions = labels_file_beside(job.output_name).as_posix()     # the output's own labels file
    assert set(outcome.files) == {job.output_name, regions, "horse.mtl", "textures/skin.png"}
    assert outcome.report["job"]["mesh"] == str(job.mesh)
    assert str(job.segmentation) in outcome.report["labels"]["source"]
    assert "allorules-job-" not in json.dumps(outcome.report)   # no worker scratch path leaks into the report


def test_shared_files_travel_as_paths_and_outputs_are_moved_into_place(cluster, animals, tmp_path, monkeypatch):
    sizes = []
    make = cluster_module.job_payload

    def recorded(*args, **kwargs):
        payload = make(*args, **kwargs)
        sizes.append(payload.size)
        return payload

    monkeypatch.setattr(cluster_module, "job_payload", recorded)
    path = manifest(tmp_path, animals, ["horse"], rulesets="[global]")
    path.write_text(path.read_text() + "shared_files: true\n")
    result = run_batch(path, scheduler=cluster.address)
    assert sizes == [0, 0]                        # no file's bytes went through Dask
    assert [row["status"] for row in result.rows] == ["done", "done"]
    out = tmp_path / "out"
    for row in result.rows:
        report = json.loads((out / row["job"] / "report.json").read_text())
        assert report["result"]["mass_ratio"] == pytest.approx(row["ratio"], rel=1e-3)
        assert (out / row["output"]).stat().st_size > 0
    assert not (out / ".allorules-staging").exists()


def test_shared_files_a_worker_cannot_see_is_a_clear_failure(tmp_path, blas_restored):
    from allorules.runs.jobs import Job

    job = Job(tmp_path / "not-here.obj", "ghost", None, 2.0, "global", 12, "obj")
    outcome = cluster_module.run_payload(cluster_module.job_payload(job, "f", shared_output=tmp_path / "out"))
    assert "does not see" in outcome.report["error"] and "without --shared-files" in outcome.report["error"]


def test_a_lost_scheduler_stops_the_run_with_its_summary(own_cluster, animals, tmp_path):
    from allorules.runs.cluster import ClusterError

    path = manifest(tmp_path, animals, ["horse", "dog"], modes=24)
    out = tmp_path / "out"

    def kill_the_scheduler() -> None:
        deadline = time.monotonic() + 300
        while not any(out.glob("*/report.json")) and time.monotonic() < deadline:
            time.sleep(0.05)
        own_cluster.kill("scheduler")

    threading.Thread(target=kill_the_scheduler, daemon=True).start()
    with pytest.raises(ClusterError, match="lost the connection to the Dask scheduler"):
        run_batch(path, scheduler=own_cluster.address)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] and summary["counts"]["done"] >= 1 and summary["counts"]["not run"] >= 1
    assert summary["counts"]["failed"] == 0        # a lost scheduler is not the jobs' failure


def test_a_result_lost_as_the_connection_closes_is_the_schedulers_loss_not_the_jobs():
    """A job in flight when the scheduler dies may end cancelled or with its result lost in transit
    (CommClosedError): both stop the run as a lost scheduler; the job's own error stays its failure."""
    from types import SimpleNamespace

    from distributed.comm.core import CommClosedError

    lost = cluster_module._lost_with_the_scheduler
    running = SimpleNamespace(status="running")
    assert lost(running, SimpleNamespace(status="error"), CommClosedError("in: Stream is closed"))
    assert lost(running, SimpleNamespace(status="cancelled"), RuntimeError("cancelled"))
    assert lost(SimpleNamespace(status="closed"), SimpleNamespace(status="error"), RuntimeError("gone"))
    assert not lost(running, SimpleNamespace(status="error"), MemoryError("the job's own"))
