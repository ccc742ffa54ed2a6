"""Batch runs on a Dask cluster: one and two local workers on the same manifest, and the memory a
worker needs for a 1,000-mode basis of the ~8k-vertex working mesh.

Run: .venv/bin/python benchmarks/bench_batch_dask.py [--vertices N] [--modes M] [--skip-memory]
(needs ``pip install '.[distributed]'``). Record the results in docs/benchmarks.md.

**Throughput.** One manifest (the generated horse and dog with their true labels, ``global`` and
``quadruped``, mass ratios 0.5 and 2: 8 jobs), run three ways in one go, each with an empty basis
cache so every run computes its own bases: this machine's process pool (``--jobs 2``, the
reference), a Dask cluster of one worker, and one of two workers (``dask worker --nthreads 1``,
all on 127.0.0.1). Wall time of the whole ``allorules batch`` command, and the jobs' own seconds.

**Memory.** One job run the way a worker runs it (:func:`allorules.runs.cluster.run_payload`) in a
fresh process: ``../shared/meshes/horse.obj`` (8,431 vertices; the generated horse of 8,000 where
the shared meshes are absent) with a basis of 1,000 modes at mass ratio 2, global scaling cold
(the basis computed) and warm (read from the cache), and the ``quadruped`` ruleset (a basis per
step, cold); the peak resident memory of that process, and of a process that only imported
allorules and distributed (what an idle worker holds).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CLI = [sys.executable, "-c", "import sys; from allorules.cli import main; sys.exit(main())"]
DASK = [sys.executable, "-m", "dask"]


def make_inputs(folder: Path, vertices: int) -> list[str]:
    import trimesh

    from allorules.mesh.quadruped import generate_quadruped

    names = []
    for preset in ("horse", "dog"):
        animal = generate_quadruped(preset, vertices)
        trimesh.Trimesh(animal.vertices, animal.faces, process=False).export(folder / f"{preset}.obj")
        (folder / f"{preset}.labels.json").write_text(json.dumps(animal.labels_document()))
        names.append(preset)
    return names


def write_manifest(folder: Path, names: list[str], modes: int, output: str) -> Path:
    meshes = "\n".join(f"  - {{path: {name}.obj, segmentation: {name}.labels.json}}" for name in names)
    path = folder / f"{output}.yaml"
    path.write_text(f"output: {output}\nmeshes:\n{meshes}\nratios: [0.5, 2]\nrulesets: [global, quadruped]\n"
                    f"modes: {modes}\n")
    return path


class LoopbackCluster:
    """A scheduler and ``workers`` workers on 127.0.0.1, each in its own session; stopped on exit."""

    def __init__(self, folder: Path, workers: int, environment: dict[str, str]):
        self.folder, self.processes = folder, []
        self.scheduler_file = folder / "scheduler.json"
        self.environment = environment
        self._start(DASK + ["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                            "--scheduler-file", str(self.scheduler_file)])
        while not self.scheduler_file.exists():
            time.sleep(0.1)
        for index in range(workers):
            self._start(DASK + ["worker", "--scheduler-file", str(self.scheduler_file), "--nthreads", "1",
                                "--no-dashboard", "--host", "127.0.0.1", "--name", f"w{index}",
                                "--local-directory", str(folder / f"w{index}")])
        import distributed

        with distributed.Client(scheduler_file=str(self.scheduler_file), set_as_default=False) as client:
            client.wait_for_workers(workers, timeout=120)

    def _start(self, command: list[str]) -> None:
        log = open(self.folder / f"process{len(self.processes)}.log", "w")
        self.processes.append(subprocess.Popen(command, cwd=self.folder, stdout=log, stderr=subprocess.STDOUT,
                                               start_new_session=True, env=self.environment))
        log.close()

    def __enter__(self) -> "LoopbackCluster":
        return self

    def __exit__(self, *exc) -> None:
        for process in reversed(self.processes):
            try:
                os.killpg(process.pid, signal.SIGTERM)
                process.wait(20)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                pass
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            process.wait(20)


def timed_batch(manifest: Path, extra: list[str], environment: dict[str, str]) -> dict:
    start = time.perf_counter()
    done = subprocess.run(CLI + ["-q", "batch", str(manifest)] + extra, cwd=manifest.parent, env=environment,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    summary = json.loads((manifest.parent / manifest.stem / "summary.json").read_text())
    seconds = [row["seconds"] for row in summary["jobs"] if row["seconds"] is not None]
    return {"wall_seconds": round(wall, 1), "exit": done.returncode, "counts": summary["counts"],
            "job_seconds_sum": round(sum(seconds), 1), "job_seconds_max": round(max(seconds), 1)}


def throughput(vertices: int, modes: int) -> dict:
    results = {}
    with tempfile.TemporaryDirectory(prefix="bench-batch-dask-") as temporary:
        folder = Path(temporary)
        names = make_inputs(folder, vertices)
        for label, workers in (("local pool --jobs 2", None), ("dask, 1 worker", 1), ("dask, 2 workers", 2)):
            output = label.replace(" ", "_").replace(",", "").replace("-", "")
            manifest = write_manifest(folder, names, modes, output)
            environment = dict(os.environ, ALLORULES_CACHE_DIR=str(folder / f"cache-{output}"))
            if workers is None:
                results[label] = timed_batch(manifest, ["--jobs", "2"], environment)
            else:
                (folder / output).mkdir()
                with LoopbackCluster(folder / output, workers, environment) as cluster:
                    results[label] = timed_batch(manifest, ["--scheduler", str(cluster.scheduler_file)], environment)
            print(f"{label}: {results[label]}", flush=True)
    return results


MEMORY_JOB = """
import json, resource, sys, time
from pathlib import Path
from allorules.runs.cluster import job_payload, run_payload
from allorules.runs.jobs import Job
mesh, modes, ruleset = Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
job = Job(mesh, mesh.stem, None, 2.0, ruleset, modes, "obj")
start = time.perf_counter()
outcome = run_payload(job_payload(job, "benchmark"))
print(json.dumps({"status": outcome.report["status"], "error": outcome.report.get("error"),
                  "seconds": round(time.perf_counter() - start, 1),
                  "peak_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)}))
"""

IDLE = """
import json, resource
import allorules.runs.cluster, allorules.runs.pipeline, distributed
print(json.dumps({"peak_mib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)}))
"""


def memory(modes: int) -> dict:
    shared = ROOT.parent / "shared" / "meshes" / "horse.obj"
    with tempfile.TemporaryDirectory(prefix="bench-batch-memory-") as temporary:
        folder = Path(temporary)
        if shared.is_file():
            mesh = shared
        else:
            import trimesh

            from allorules.mesh.quadruped import generate_quadruped

            animal = generate_quadruped("horse", 8000)
            mesh = folder / "horse.obj"
            trimesh.Trimesh(animal.vertices, animal.faces, process=False).export(mesh)
        environment = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        found = {"mesh": str(mesh.name), "modes": modes}
        # "warm" reads the basis "cold" computed; the ruleset run starts from an empty cache of its own.
        for label, ruleset, cache in (("cold", "global", "cache"), ("warm", "global", "cache"),
                                      ("quadruped, cold", "quadruped", "cache-ruleset")):
            environment["ALLORULES_CACHE_DIR"] = str(folder / cache)
            done = subprocess.run([sys.executable, "-c", MEMORY_JOB, str(mesh), str(modes), ruleset],
                                  env=environment, capture_output=True, text=True, check=True)
            found[label] = json.loads(done.stdout.strip().splitlines()[-1])
            print(f"memory, {label}: {found[label]}", flush=True)
        done = subprocess.run([sys.executable, "-c", IDLE], env=environment, capture_output=True, text=True, check=True)
        found["idle"] = json.loads(done.stdout.strip().splitlines()[-1])
        print(f"memory, idle worker imports: {found['idle']}", flush=True)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=3000, help="vertices of each generated animal")
    parser.add_argument("--modes", type=int, default=200, help="basis size of the throughput manifest")
    parser.add_argument("--memory-modes", type=int, default=1000)
    parser.add_argument("--skip-memory", action="store_true")
    parser.add_argument("--skip-throughput", action="store_true")
    arguments = parser.parse_args()
    path = RESULTS / "batch_dask.json"
    results: dict = json.loads(path.read_text()) if path.exists() else {}   # a skipped part keeps its figures
    results.update({"cores": os.cpu_count(), "vertices": arguments.vertices, "modes": arguments.modes})
    if not arguments.skip_throughput:
        results["throughput"] = throughput(arguments.vertices, arguments.modes)
    if not arguments.skip_memory:
        results["memory"] = memory(arguments.memory_modes)
    RESULTS.mkdir(exist_ok=True)
    path.write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
