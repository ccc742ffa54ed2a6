"""Batch runs: many meshes × mass ratios × rulesets from one manifest, in parallel, resumable.

A manifest (YAML, safe-loaded; schema in docs/batch.md) names meshes (paths relative to the
manifest), mass ratios and rulesets (``global`` for global allometric scaling). Every combination
is a :class:`~allorules.runs.jobs.Job`. :func:`run_batch` runs the jobs that are not finished yet
in a process pool (all cores by default), or on a Dask cluster (``scheduler``, see
:mod:`allorules.runs.cluster`), and writes one summary.

**Resuming.** Each job writes into its own folder ``<output>/<job id>/``: first the scaled mesh,
then ``report.json``, both atomically (temporary file + ``os.replace``). The report is the
job's "done" marker: it holds a *fingerprint* of the job's inputs (SHA-256 over the mesh file's
and segmentation file's bytes, the resolved ruleset, the ratio, the basis size, the output
format and any plugin files). On a later run a job is skipped when its report says ``done`` with
the same fingerprint and its mesh is there; a changed input, a failed or an interrupted job is
run again. An interrupted run therefore loses at most the jobs that were in flight.

**Failures** are recorded per job (``status: failed`` with the one-line error in its report and
in the summary) without stopping the others; they are retried on the next run.

**Summary**: ``summary.json`` (every job, its status and figures), ``summary.csv`` and
``summary.md`` (one table), written atomically at the end of every run, also an interrupted
(Ctrl-C, SIGTERM) one: jobs not reached are listed as ``not run``.

**Stopping.** The pool's workers die with the batch: a worker whose parent is gone (even killed
with SIGKILL) ends itself at once. SIGTERM (and SIGHUP) stop the batch as Ctrl-C does: the jobs
in flight are stopped, the summary is written, the exit status is 143.

This module imports nothing numerical at module level, so pool workers can limit their BLAS
threads before numpy loads (one job per core, one thread per job).
"""
from __future__ import annotations

import csv
import io
import logging
import math
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from allorules.errors import AllorulesError, RulesetError, SourceLocation
from allorules.runs.jobs import (  # noqa: F401  (the batch API: one import for callers and tests)
    GLOBAL,
    REPORT_FORMAT,
    REPORT_NAME,
    REPORT_VERSION,
    STATUS_DONE,
    STATUS_FAILED,
    STATUS_NOT_RUN,
    Job,
    is_finished,
    job_fingerprint,
    messages_named,
    read_report,
    record_failure,
    ruleset_with_plugins,
    run_job,
    safe_name,
    scale_job,
)

log = logging.getLogger("allorules")

OUTPUT_FORMATS = ("obj", "ply", "stl", "glb", "off")   # allorules.output.export.SUPPORTED_FORMATS, checked by a test
MANIFEST_KEYS = ("output", "meshes", "ratios", "rulesets", "modes", "format", "plugins", "scheduler", "shared_files")
MESH_KEYS = ("path", "segmentation", "name")


class ManifestError(RulesetError):
    """A batch manifest is invalid; the message names file and line."""


# ---------------------------------------------------------------------------------------------
# The manifest


@dataclass(frozen=True)
class MeshEntry:
    path: Path
    name: str
    segmentation: Path | None = None


@dataclass(frozen=True)
class Manifest:
    """A validated manifest; paths are absolute (resolved against the manifest's folder)."""

    path: Path
    output: Path
    meshes: tuple[MeshEntry, ...]
    ratios: tuple[float, ...]
    rulesets: tuple[str, ...]          # "global", a ruleset name, or an absolute .yaml path
    modes: int | None = None
    format: str | None = None          # output extension without dot; None: the input's
    plugins: tuple[Path, ...] = ()
    scheduler: str | None = None       # a Dask scheduler's address or scheduler file; None: this machine
    shared_files: bool = False         # the Dask workers see the inputs and the output folder at the same paths

    def jobs(self) -> list["Job"]:
        return [Job(mesh.path, mesh.name, mesh.segmentation, ratio, ruleset, self.modes,
                    self.format or _output_format(mesh.path), self.plugins)
                for mesh in self.meshes for ruleset in self.rulesets for ratio in self.ratios]


def _output_format(mesh: Path) -> str:
    suffix = mesh.suffix.lower().lstrip(".")
    return suffix if suffix in OUTPUT_FORMATS else "glb" if suffix == "gltf" else "obj"


def _read_yaml(path: Path):
    """(data, location-of(keys)) of a manifest, with file:line errors (the rules module's reader)."""
    from allorules.rules.located_yaml import read_located_yaml

    document = read_located_yaml(path, kind="manifest", error=ManifestError,
                                 empty="the manifest is empty; it needs at least 'meshes', 'ratios' and 'rulesets'")

    def at(*keys, key: bool = False) -> SourceLocation:
        return document.key_at(*keys) if key else document.at(*keys)

    return document.data, at


def _list(data: dict, key: str, at, what: str) -> list:
    value = data.get(key)
    if value is None:
        raise ManifestError(f"'{key}' is missing: give a list of {what}", at())
    if isinstance(value, (str, int, float)) and not isinstance(value, bool):
        value = [value]
    if not isinstance(value, list) or not value:
        raise ManifestError(f"'{key}' must be a non-empty list of {what}", at(key))
    return value


def load_manifest(path: str | Path) -> Manifest:
    """Read and validate a manifest; every problem raises :class:`ManifestError` with file:line."""
    from allorules.runs.steps import check_mass_ratio

    path = Path(path).expanduser().resolve()
    data, at = _read_yaml(path)
    if not isinstance(data, dict):
        raise ManifestError("a manifest is a mapping of keys (meshes, ratios, rulesets, output, ...)", at())
    for key in data:
        if key not in MANIFEST_KEYS:
            raise ManifestError(f"unknown key {key!r}; a manifest has {', '.join(MANIFEST_KEYS)}", at(key, key=True))
    base = path.parent

    meshes: list[MeshEntry] = []
    for index, item in enumerate(_list(data, "meshes", at, "mesh files")):
        where = at("meshes", index)
        if isinstance(item, str):
            item = {"path": item}
        if not isinstance(item, dict):
            raise ManifestError("a mesh is a path, or a mapping with 'path' (and 'segmentation', 'name')", where)
        for key in item:
            if key not in MESH_KEYS:
                raise ManifestError(f"unknown key {key!r} for a mesh; use {', '.join(MESH_KEYS)}", at("meshes", index, key, key=True))
        if not isinstance(item.get("path"), str) or not item["path"].strip():
            raise ManifestError("the mesh needs 'path': the mesh file, relative to the manifest", where)
        mesh = (base / Path(item["path"]).expanduser()).resolve()
        if not mesh.is_file():
            raise ManifestError(f"mesh {item['path']!r} not found (looked for {mesh})", at("meshes", index, "path"))
        segmentation = None
        if item.get("segmentation") is not None:
            if not isinstance(item["segmentation"], str):
                raise ManifestError("'segmentation' is a labels .json or .seg path", at("meshes", index, "segmentation"))
            segmentation = (base / Path(item["segmentation"]).expanduser()).resolve()
            if not segmentation.is_file():
                raise ManifestError(f"segmentation {item['segmentation']!r} not found (looked for {segmentation})",
                                    at("meshes", index, "segmentation"))
        name = item.get("name", mesh.stem)
        if not isinstance(name, str) or not name.strip():
            raise ManifestError("'name' must be text", at("meshes", index, "name"))
        name = safe_name(name)
        if any(entry.name == name for entry in meshes):
            raise ManifestError(f"two meshes are named {name!r}; give one of them a different 'name:'", where)
        meshes.append(MeshEntry(mesh, name, segmentation))

    ratios: list[float] = []
    for index, value in enumerate(_list(data, "ratios", at, "mass ratios")):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ManifestError(f"mass ratio {value!r} is not a number (2 doubles the mass, 0.5 halves it)",
                                at("ratios", index))
        try:
            ratio = check_mass_ratio(value)
        except AllorulesError as error:
            raise ManifestError(str(error), at("ratios", index)) from None
        if ratio == 1.0:
            raise ManifestError("mass ratio 1 leaves the mesh as it is; leave it out", at("ratios", index))
        if ratio in ratios:
            raise ManifestError(f"mass ratio {ratio:g} is listed twice", at("ratios", index))
        ratios.append(ratio)

    plugins: list[Path] = []
    for index, value in enumerate(data.get("plugins") or []):
        if not isinstance(value, str):
            raise ManifestError("a plugin is a .py file or package folder path", at("plugins", index))
        plugin = (base / Path(value).expanduser()).resolve()
        if not plugin.exists():
            raise ManifestError(f"plugin {value!r} not found (looked for {plugin})", at("plugins", index))
        plugins.append(plugin)

    rulesets: list[str] = []
    for index, value in enumerate(_list(data, "rulesets", at, f"ruleset names or files ('{GLOBAL}' for global scaling)")):
        if not isinstance(value, str) or not value.strip():
            raise ManifestError(f"a ruleset is a name, a .yaml path or '{GLOBAL}'", at("rulesets", index))
        if value != GLOBAL:
            from allorules.rules.find import looks_like_path

            if looks_like_path(value):
                value = str((base / Path(value).expanduser()).resolve())
            try:
                ruleset_with_plugins(value, tuple(plugins))
            except AllorulesError as error:
                raise ManifestError(f"ruleset {value!r}: {error}", at("rulesets", index)) from None
        if value in rulesets:
            raise ManifestError(f"ruleset {value!r} is listed twice", at("rulesets", index))
        rulesets.append(value)

    modes = data.get("modes")
    if modes is not None and (isinstance(modes, bool) or not isinstance(modes, int) or modes < 2):
        raise ManifestError(f"'modes' must be a whole number of at least 2, got {modes!r}", at("modes"))
    output_format = data.get("format")
    if output_format is not None:
        output_format = str(output_format).lower().lstrip(".")
        if output_format not in OUTPUT_FORMATS:
            raise ManifestError(f"format {data['format']!r} is not one of {', '.join(OUTPUT_FORMATS)}", at("format"))
    output = data.get("output", f"{path.stem}-results")
    if not isinstance(output, str) or not output.strip():
        raise ManifestError("'output' is the folder for the results, relative to the manifest", at("output"))
    output_path = (base / Path(output).expanduser()).resolve()
    if output_path.exists() and not output_path.is_dir():
        raise ManifestError(f"output {output!r} is a file; give a folder", at("output"))
    scheduler = data.get("scheduler")
    if scheduler is not None:
        from allorules.runs.cluster import scheduler_address

        try:
            scheduler = scheduler_address(scheduler, base)
        except AllorulesError as error:
            raise ManifestError(str(error), at("scheduler")) from None
    shared_files = data.get("shared_files", False)
    if not isinstance(shared_files, bool):
        raise ManifestError("'shared_files' is true or false (true: the Dask workers see these files and the output "
                            "folder at the same paths)", at("shared_files"))
    return Manifest(path, output_path, tuple(meshes), tuple(ratios), tuple(rulesets), modes, output_format,
                    tuple(plugins), scheduler, shared_files)



# ---------------------------------------------------------------------------------------------
# A run


class BatchTerminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP reached the batch: it stops as on Ctrl-C (summary written, exit 143)."""


@contextmanager
def terminated_as_interrupted() -> Iterator[None]:
    """While the batch runs, SIGTERM and SIGHUP raise :class:`BatchTerminated` in the main thread,
    so the jobs in flight are stopped and the summary is written, as on Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    names = [name for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]

    def stop(number, frame) -> None:
        for name in names:   # once is enough: let the summary be written
            signal.signal(getattr(signal, name), signal.SIG_IGN)
        raise BatchTerminated(signal.Signals(number).name)

    previous = {name: signal.signal(getattr(signal, name), stop) for name in names}
    try:
        yield
    finally:
        for name, handler in previous.items():
            signal.signal(getattr(signal, name), handler)


@dataclass
class BatchResult:
    manifest: Manifest
    rows: list[dict[str, Any]] = field(default_factory=list)
    ran: int = 0
    skipped: int = 0
    interrupted: bool = False
    summary_files: list[Path] = field(default_factory=list)

    def count(self, status: str) -> int:
        return sum(1 for row in self.rows if row["status"] == status)


class BatchProgress:
    """Progress on the terminal: a line per finished job with the counts done / running / failed."""

    def __init__(self, total: int):
        self.total = total
        self.finished_count = 0
        self.failed = 0
        self.running = 0

    @property
    def done(self) -> int:
        return self.finished_count - self.failed

    def counts(self) -> str:
        waiting = self.total - self.finished_count - self.running
        return (f"{self.done} done, {self.running} running, {self.failed} failed"
                + (f", {waiting} waiting" if waiting > 0 else ""))

    def finished(self, job: Job, report: dict) -> None:
        self.finished_count += 1
        if report["status"] != STATUS_DONE:
            self.failed += 1
        figures = report.get("result") or {}
        detail = (f"mass ×{figures['mass_ratio']:.4f}" if report["status"] == STATUS_DONE and "mass_ratio" in figures
                  else report.get("error", ""))
        log.info("[%d/%d] %s: %s (%.0f s) %s · %s", self.finished_count, self.total, job.id, report["status"],
                 report.get("seconds") or 0.0, detail, self.counts())


def check_output_folder(folder: Path) -> None:
    """Create the output folder and make sure a file can be written in it, before any job runs."""
    import tempfile

    try:
        folder.mkdir(parents=True, exist_ok=True)
        handle, probe = tempfile.mkstemp(prefix=".allorules-probe.", dir=folder)
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        raise AllorulesError(f"cannot write into the output folder {folder} ({error.strerror or error}); "
                             "choose another 'output:' in the manifest or fix the folder's permissions") from None


def remove_leftovers(folder: Path, jobs: Sequence[Job]) -> int:
    """Delete the temporary files of atomic writes that a killed run left behind (``.NAME.*.tmp``),
    and the staging folder of jobs run on Dask workers with shared files."""
    import shutil

    from allorules.runs.cluster import STAGING

    removed = 0
    if (folder / STAGING).is_dir():
        shutil.rmtree(folder / STAGING, ignore_errors=True)
        removed += 1
    for place in [folder] + [folder / job.id for job in jobs]:
        if not place.is_dir():
            continue
        for item in place.glob(".*.tmp"):
            try:
                item.unlink()
                removed += 1
            except OSError:
                pass
    return removed


def run_batch(
    manifest: str | Path | Manifest,
    *,
    jobs: int | None = None,
    redo: bool = False,
    scale: Callable[[Job, Path], dict] | None = None,
    scheduler: str | None = None,
    shared_files: bool | None = None,
) -> BatchResult:
    """Run a manifest's unfinished jobs, ``jobs`` at a time (default: every core; 1 runs them in
    this process, in order), or on the Dask cluster whose scheduler is ``scheduler`` (an address
    ``tcp://HOST:PORT`` or a scheduler file; default: the manifest's ``scheduler:``), and write
    the summary. ``shared_files`` (default: the manifest's): the workers see the inputs and the
    output folder at the same paths, so jobs carry paths, not bytes. ``redo`` runs finished jobs again. ``scale`` replaces :func:`scale_job` (tests;
    only used in-process). A Ctrl-C (or SIGTERM under :func:`terminated_as_interrupted`) writes
    the summary of what is finished and re-raises."""
    manifest = manifest if isinstance(manifest, Manifest) else load_manifest(manifest)
    if scheduler is not None:
        from allorules.runs.cluster import scheduler_address

        scheduler = scheduler_address(scheduler, Path.cwd())
    scheduler = scheduler or manifest.scheduler
    if scheduler and jobs is not None:
        raise AllorulesError("--jobs is for runs on this machine; on a Dask cluster every worker thread runs one job "
                             "(start the workers with --nthreads 1 and as many as you want: docs/batch.md)")
    workers = jobs if jobs is not None else (os.cpu_count() or 1)
    if workers < 1:
        raise AllorulesError(f"--jobs must be at least 1, got {workers}")
    client = None
    if scheduler:
        from allorules.runs.cluster import connect

        client = connect(scheduler)   # before any work: no Dask, or no scheduler there, is said at once
    shared = manifest.shared_files if shared_files is None else shared_files
    if shared_files and not scheduler:
        raise AllorulesError("--shared-files goes with --scheduler: it says the Dask workers share this machine's "
                             "folders")
    try:
        return _run_batch(manifest, workers, redo, scale, client, shared)
    finally:
        if client is not None:
            from allorules.runs.cluster import disconnect

            disconnect(client)


def _run_batch(manifest: Manifest, workers: int, redo: bool, scale, client, shared_files: bool) -> BatchResult:
    check_output_folder(manifest.output)
    all_jobs = manifest.jobs()
    removed = remove_leftovers(manifest.output, all_jobs)
    if removed:
        log.info("removed %d temporary file%s left by an interrupted run", removed, "" if removed == 1 else "s")
    rulesets = {}
    for name in manifest.rulesets:
        if name != GLOBAL:
            rulesets[name] = ruleset_with_plugins(name, manifest.plugins)[0]
    from allorules.rules.model import dump_ruleset

    texts = {name: dump_ruleset(ruleset) for name, ruleset in rulesets.items()}
    fingerprints = {job.id: job_fingerprint(job, texts.get(job.ruleset)) for job in all_jobs}
    result = BatchResult(manifest)
    pending = []
    for job in all_jobs:
        if not redo and is_finished(job, manifest.output / job.id, fingerprints[job.id]):
            result.skipped += 1
        else:
            pending.append(job)
    if client is not None:
        where = f"on the Dask cluster at {client.scheduler.address}"
    else:
        count = min(workers, max(1, len(pending)))
        where = f"with {count} worker{'' if count == 1 else 's'}"
    log.info("%d jobs: %d finished before, %d to run %s", len(all_jobs), result.skipped, len(pending), where)

    progress = BatchProgress(len(pending))
    stop: BaseException | None = None
    try:
        if client is not None:
            from allorules.runs.cluster import run_on_cluster

            run_on_cluster(client, pending, manifest.output, fingerprints, rulesets, progress,
                           shared_files=shared_files)
        elif workers == 1 or len(pending) <= 1:
            for job in pending:
                progress.running = 1
                report = run_job(job, manifest.output, fingerprints[job.id], scale)
                progress.running = 0
                progress.finished(job, report)
        else:
            _run_pool(pending, manifest.output, fingerprints, min(workers, len(pending)), progress)
    except KeyboardInterrupt as interruption:   # Ctrl-C, or SIGTERM (BatchTerminated)
        stop = interruption
        why = "terminated" if isinstance(interruption, BatchTerminated) else "interrupted"
        log.warning("%s: %d of %d jobs finished in this run; run the same command again to resume", why,
                    progress.finished_count, len(pending))
    except AllorulesError as error:               # e.g. the Dask scheduler went away
        stop = error
    result.interrupted = stop is not None
    result.ran = progress.finished_count
    result.rows = [_summary_row(job, manifest.output, fingerprints[job.id]) for job in all_jobs]
    result.summary_files = write_summary(manifest, result.rows, interrupted=result.interrupted)
    if stop is not None:
        raise stop
    return result


def _worker_init(parent: int) -> None:
    """A pool worker: one BLAS thread (the pool already uses every core), Ctrl-C left to the
    parent, and it ends itself when the parent is gone (see :func:`die_with_parent`)."""
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(variable, "1")
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the parent handles Ctrl-C and cancels the rest
    die_with_parent(parent)


def die_with_parent(parent: int, interval: float = 0.5) -> None:
    """End this process as soon as process ``parent`` is gone, even when it was killed with
    SIGKILL (which leaves it no chance to stop its workers): on Linux the kernel sends SIGKILL
    (``PR_SET_PDEATHSIG``); everywhere a watcher thread checks the parent twice a second."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)   # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:   # already gone before the watch began
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(interval)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="allorules-watch-parent", daemon=True).start()


def _run_pool(pending: Sequence[Job], output: Path, fingerprints: dict, workers: int, progress: BatchProgress) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    # "spawn": fresh interpreters, safe with BLAS/OpenMP threads in this process.
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init, initargs=(os.getpid(),))
    futures = {pool.submit(run_job, job, output, fingerprints[job.id]): job for job in pending}
    try:
        remaining = set(futures)
        while remaining:
            progress.running = min(workers, len(remaining))
            completed, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            progress.running = min(workers, len(remaining))
            for future in completed:
                job = futures[future]
                try:
                    report = future.result()
                except BrokenProcessPool:
                    report = record_failure(job, output, fingerprints[job.id],
                                            "the worker process died (out of memory?); run the batch again to retry")
                except Exception as error:  # the worker could not even start or report
                    report = record_failure(job, output, fingerprints[job.id], f"{type(error).__name__}: {error}")
                progress.finished(job, report)
    except BaseException:
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:   # stop the jobs in flight now: they are redone on the next run
            process.terminate()
        for process in processes:
            process.join(5)
        raise
    pool.shutdown(wait=True)


# ---------------------------------------------------------------------------------------------
# Summary

SUMMARY_COLUMNS = ("job", "mesh", "ruleset", "ratio", "status", "mass_ratio", "stress_ratio", "converged",
                   "worst_rule", "worst_rule_residual", "flipped_faces", "self_intersections", "roughness_degrees",
                   "worst_feature_change", "trunk_shape_change", "head_turn_degrees", "warnings", "seconds", "output",
                   "error")


def _summary_row(job: Job, output: Path, fingerprint: str) -> dict[str, Any]:
    folder = output / job.id
    report = read_report(folder)
    row = dict.fromkeys(SUMMARY_COLUMNS)
    row.update(job=job.id, mesh=job.name, ruleset=job.ruleset_label, ratio=job.ratio)
    if report is None or report.get("fingerprint") != fingerprint:
        row["status"] = STATUS_NOT_RUN
        return row
    figures = report.get("result") or {}
    row.update(status=report.get("status"), seconds=report.get("seconds"), error=report.get("error"),
               mass_ratio=figures.get("mass_ratio"), stress_ratio=figures.get("stress_ratio"),
               converged=figures.get("converged"), warnings="; ".join(figures.get("warnings") or []) or None)
    if report.get("result") and report.get("output"):   # done, or missed its targets (the unconverged mesh)
        row["output"] = str(Path(job.id) / report["output"])
    rules = figures.get("rules") or []
    if rules:
        worst = max(rules, key=lambda rule: abs(rule.get("error") or 0.0))
        row.update(worst_rule=worst.get("id"), worst_rule_residual=worst.get("error"))
    row.update(_quality_cells(report.get("quality")))
    return row


def _quality_cells(quality: dict[str, Any] | None) -> dict[str, Any]:
    """The summary's quality columns from a job report's ``quality`` (allorules.measure.quality):
    faces turned inside out in the mesh written, new self-intersecting face pairs, roughness, the
    worst small feature's shape change, the trunk's shape, the head's turn. Empty for a report
    without it (failed, or written before)."""
    if not quality:
        return {}
    flipped = quality.get("written_flipped_faces") or quality.get("flipped_faces") or {}
    crossings = quality.get("self_intersections") or {}
    new_pairs = crossings.get("new_pairs")
    return {"flipped_faces": flipped.get("count"),
            "self_intersections": crossings.get("pairs") if new_pairs is None else new_pairs,
            "roughness_degrees": (quality.get("roughness") or {}).get("rms_degrees"),
            "worst_feature_change": quality.get("worst_feature_change"),
            "trunk_shape_change": quality.get("trunk_shape_change"),
            "head_turn_degrees": quality.get("head_turn_degrees")}


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else ""
    return str(value)


def write_summary(manifest: Manifest, rows: list[dict[str, Any]], *, interrupted: bool = False) -> list[Path]:
    """``summary.json``, ``summary.csv`` and ``summary.md`` in the output folder (atomically)."""
    from allorules.files import atomic_write, write_json

    counts = {status: sum(1 for row in rows if row["status"] == status)
              for status in (STATUS_DONE, STATUS_FAILED, STATUS_NOT_RUN)}
    document = {"format": "allorules-batch-summary", "version": 1, "manifest": str(manifest.path),
                "interrupted": interrupted, "counts": counts, "jobs": rows}
    paths = [manifest.output / "summary.json", manifest.output / "summary.csv", manifest.output / "summary.md"]
    write_json(paths[0], document)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({key: _cell(value) for key, value in row.items()} for row in rows)
    atomic_write(paths[1], buffer.getvalue())
    lines = [f"# Batch summary: {manifest.path.name}", "",
             f"{counts[STATUS_DONE]} done, {counts[STATUS_FAILED]} failed, {counts[STATUS_NOT_RUN]} not run"
             + (" (the run was interrupted; run it again to resume)" if interrupted else ""), "",
             "| " + " | ".join(SUMMARY_COLUMNS) + " |", "|" + "---|" * len(SUMMARY_COLUMNS)]
    for row in rows:
        lines.append("| " + " | ".join(_cell(row[column]).replace("|", "\\|").replace("\n", " ")
                                       for column in SUMMARY_COLUMNS) + " |")
    atomic_write(paths[2], "\n".join(lines) + "\n")
    return paths


# ---------------------------------------------------------------------------------------------
# Command line


def run_batch_command(arguments) -> int:
    """``allorules batch``: run, print the table, exit 0 when every job is done, 1 otherwise;
    SIGTERM or SIGHUP stop it as Ctrl-C does, with the summary written, and exit 143."""
    try:
        with terminated_as_interrupted():
            result = run_batch(arguments.manifest, jobs=arguments.jobs, redo=arguments.redo,
                               scheduler=getattr(arguments, "scheduler", None),
                               shared_files=True if getattr(arguments, "shared_files", False) else None)
    except BatchTerminated as stop:
        print(f"allorules batch: {stop} received: stopped; the summary is written; run the same command again "
              "to resume", file=sys.stderr)
        return 128 + int(getattr(signal, str(stop), signal.SIGTERM))
    done, failed = result.count(STATUS_DONE), result.count(STATUS_FAILED)
    print(f"{done} done ({result.skipped} finished before, {result.ran} run now), {failed} failed")
    for row in result.rows:
        if row["status"] == STATUS_FAILED:
            print(f"  failed: {row['job']}: {row['error']}")
    print(f"summary: {result.summary_files[2]} (also .json, .csv)")
    return 0 if failed == 0 else 1
