"""Batch runs: many meshes × mass ratios × rulesets from one manifest, in parallel, resumable.

A manifest (YAML, safe-loaded; schema in docs/batch.md) names meshes (paths relative to the
manifest), mass ratios and rulesets (``global`` for global allometric scaling). Every combination
is a :class:`Job`. :func:`run_batch` runs the jobs that are not finished yet in a process pool
(all cores by default) and writes one summary.

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
``summary.md`` (one table), written atomically at the end of every run, also an interrupted one
(jobs not reached are listed as ``not run``).

This module imports nothing numerical at module level, so pool workers can limit their BLAS
threads before numpy loads (one job per core, one thread per job).
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import math
import os
import re
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from allorules import __version__
from allorules.errors import AllorulesError, RulesetError, SourceLocation

log = logging.getLogger("allorules")

GLOBAL = "global"
REPORT_NAME = "report.json"
REPORT_FORMAT = "allorules-batch-job"
REPORT_VERSION = 1
OUTPUT_FORMATS = ("obj", "ply", "stl", "glb", "off")
MANIFEST_KEYS = ("output", "meshes", "ratios", "rulesets", "modes", "format", "plugins")
MESH_KEYS = ("path", "segmentation", "name")
STATUS_DONE, STATUS_FAILED, STATUS_NOT_RUN = "done", "failed", "not run"


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

    def jobs(self) -> list["Job"]:
        return [Job(mesh.path, mesh.name, mesh.segmentation, ratio, ruleset, self.modes,
                    self.format or _output_format(mesh.path), self.plugins)
                for mesh in self.meshes for ruleset in self.rulesets for ratio in self.ratios]


def _output_format(mesh: Path) -> str:
    suffix = mesh.suffix.lower().lstrip(".")
    return suffix if suffix in OUTPUT_FORMATS else "glb" if suffix == "gltf" else "obj"


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "mesh"


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
        name = _safe_name(name)
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
                _load_ruleset(value, tuple(plugins))
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
    return Manifest(path, output_path, tuple(meshes), tuple(ratios), tuple(rulesets), modes, output_format, tuple(plugins))


# ---------------------------------------------------------------------------------------------
# Jobs


@dataclass(frozen=True)
class Job:
    """One mesh scaled by one mass ratio with one ruleset (or globally)."""

    mesh: Path
    name: str
    segmentation: Path | None
    ratio: float
    ruleset: str
    modes: int | None
    format: str
    plugins: tuple[Path, ...] = ()

    @property
    def ruleset_label(self) -> str:
        return self.ruleset if self.ruleset == GLOBAL or not self.ruleset.endswith((".yaml", ".yml")) \
            else _safe_name(Path(self.ruleset).stem)

    @property
    def id(self) -> str:
        return f"{self.name}__{_safe_name(self.ruleset_label)}__x{self.ratio:g}"

    @property
    def output_name(self) -> str:
        return f"{self.name}_{_safe_name(self.ruleset_label)}_x{self.ratio:g}.{self.format}"

    def describe(self) -> dict[str, Any]:
        return {"id": self.id, "mesh": str(self.mesh), "segmentation": str(self.segmentation) if self.segmentation else None,
                "ratio": self.ratio, "ruleset": self.ruleset, "modes": self.modes, "format": self.format,
                "plugins": [str(plugin) for plugin in self.plugins]}


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    if path.is_dir():   # a plugin package: every file in it, in order
        for item in sorted(path.rglob("*")):
            if item.is_file() and "__pycache__" not in item.parts:
                digest.update(str(item.relative_to(path)).encode())
                digest.update(_file_digest(item).encode())
        return digest.hexdigest()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _load_ruleset(name: str, plugins: tuple[Path, ...]):
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset

    registry = registry_for(list(plugins))
    return load_ruleset(name, registry), registry


def job_fingerprint(job: Job, ruleset_text: str | None = None) -> str:
    """SHA-256 over everything that decides a job's output (see the module docstring).

    ``ruleset_text`` is the resolved ruleset (:func:`allorules.rules.dump_ruleset`); it is
    computed when not given, so a changed ruleset file (or one it extends) redoes the job."""
    if ruleset_text is None and job.ruleset != GLOBAL:
        from allorules.rules.model import dump_ruleset

        ruleset_text = dump_ruleset(_load_ruleset(job.ruleset, job.plugins)[0])
    inputs = {
        "mesh": _file_digest(job.mesh),
        "segmentation": _file_digest(job.segmentation) if job.segmentation else None,
        "ruleset": GLOBAL if job.ruleset == GLOBAL else ruleset_text,
        "ratio": repr(float(job.ratio)),
        "modes": job.modes,
        "format": job.format,
        "plugins": [_file_digest(plugin) for plugin in job.plugins],
    }
    return hashlib.sha256(json.dumps(inputs, sort_keys=True).encode()).hexdigest()


def read_report(folder: Path) -> dict | None:
    """A job folder's report, or ``None`` when there is none or it cannot be read."""
    try:
        report = json.loads((folder / REPORT_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return report if isinstance(report, dict) and report.get("format") == REPORT_FORMAT else None


def is_finished(job: Job, folder: Path, fingerprint: str) -> bool:
    """Done before with the same inputs, and its mesh is still there."""
    report = read_report(folder)
    return (report is not None and report.get("status") == STATUS_DONE and report.get("fingerprint") == fingerprint
            and (folder / job.output_name).is_file())


def scale_job(job: Job, folder: Path) -> dict[str, Any]:
    """Run one job through the pipeline (prepare, label, scale) and write its mesh; the report's figures."""
    from allorules.plugins.registry import registry_for
    from allorules.runs import pipeline

    if job.ruleset == GLOBAL:
        registry = registry_for(list(job.plugins))
        scaling = pipeline.GlobalScaling(job.ratio)
    else:
        ruleset, registry = _load_ruleset(job.ruleset, job.plugins)
        scaling = pipeline.RulesetScaling(ruleset, job.ratio)
    run = pipeline.run(job.mesh, scaling, registry=registry, labels=job.segmentation, modes=job.modes)
    saved = pipeline.save_output(run, folder / job.output_name, overwrite=True)
    report = run.report()
    return {"repairs": report.pop("repairs"), "labels": report.pop("labels"), "result": run.result.as_dict(),
            "carried": list(saved.carried), "notes": list(saved.notes)}


def _write_json(path: Path, document: dict) -> None:
    from allorules.files import write_json

    write_json(path, document)


@contextmanager
def messages_named(job_id: str) -> Iterator[None]:
    """Prefix every ``allorules`` log message with ``job_id`` while a job runs.

    Workers run in parallel and print to the same terminal: a warning such as "horse.obj: UVs
    dropped" must say which job (mesh × ratio × ruleset) it came from."""
    previous = logging.getLogRecordFactory()

    def named(*args, **kwargs) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        if record.name == "allorules" or record.name.startswith("allorules."):
            record.msg = f"{job_id}: {record.msg}"
        return record

    logging.setLogRecordFactory(named)
    try:
        yield
    finally:
        logging.setLogRecordFactory(previous)


def run_job(job: Job, output: Path, fingerprint: str, scale: Callable[[Job, Path], dict] | None = None) -> dict[str, Any]:
    """Run one job and write its report (the done marker) atomically; never raises for a job
    that fails (the failure is its report), only for interruptions. Its log messages name it."""
    with messages_named(job.id):
        return _run_job(job, output, fingerprint, scale)


def _run_job(job: Job, output: Path, fingerprint: str, scale: Callable[[Job, Path], dict] | None) -> dict[str, Any]:
    folder = output / job.id
    folder.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    report: dict[str, Any] = {"format": REPORT_FORMAT, "version": REPORT_VERSION, "allorules": __version__,
                              "job": job.describe(), "fingerprint": fingerprint, "output": job.output_name}
    try:
        report.update((scale or scale_job)(job, folder))
        report["status"] = STATUS_DONE
    except AllorulesError as error:
        report.update(status=STATUS_FAILED, error=str(error))
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as error:  # a bug: record it (with its traceback) and go on with the others
        report.update(status=STATUS_FAILED, error=f"{type(error).__name__}: {error}", traceback=traceback.format_exc())
    report["seconds"] = round(time.perf_counter() - start, 3)
    _write_json(folder / REPORT_NAME, report)
    return report


def _worker_init() -> None:
    """One BLAS thread per worker: the pool already uses every core."""
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(variable, "1")
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the parent handles Ctrl-C and cancels the rest


# ---------------------------------------------------------------------------------------------
# A run


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


def run_batch(
    manifest: str | Path | Manifest,
    *,
    jobs: int | None = None,
    redo: bool = False,
    scale: Callable[[Job, Path], dict] | None = None,
) -> BatchResult:
    """Run a manifest's unfinished jobs, ``jobs`` at a time (default: every core; 1 runs them in
    this process, in order), and write the summary. ``redo`` runs finished jobs again. ``scale``
    replaces :func:`scale_job` (tests; only used in-process). A Ctrl-C writes the summary of
    what is finished and re-raises."""
    manifest = manifest if isinstance(manifest, Manifest) else load_manifest(manifest)
    workers = jobs if jobs is not None else (os.cpu_count() or 1)
    if workers < 1:
        raise AllorulesError(f"--jobs must be at least 1, got {workers}")
    manifest.output.mkdir(parents=True, exist_ok=True)
    all_jobs = manifest.jobs()
    texts = {}
    for name in manifest.rulesets:
        if name != GLOBAL:
            from allorules.rules.model import dump_ruleset

            texts[name] = dump_ruleset(_load_ruleset(name, manifest.plugins)[0])
    fingerprints = {job.id: job_fingerprint(job, texts.get(job.ruleset)) for job in all_jobs}
    result = BatchResult(manifest)
    pending = []
    for job in all_jobs:
        if not redo and is_finished(job, manifest.output / job.id, fingerprints[job.id]):
            result.skipped += 1
        else:
            pending.append(job)
    log.info("%d jobs: %d finished before, %d to run with %d worker%s", len(all_jobs), result.skipped, len(pending),
             min(workers, max(1, len(pending))), "" if min(workers, max(1, len(pending))) == 1 else "s")

    reports: dict[str, dict] = {}
    done_count = 0

    def finished(job: Job, report: dict) -> None:
        nonlocal done_count
        done_count += 1
        reports[job.id] = report
        figures = report.get("result") or {}
        detail = (f"mass ×{figures['mass_ratio']:.4f}" if report["status"] == STATUS_DONE and "mass_ratio" in figures
                  else report.get("error", ""))
        log.info("[%d/%d] %s: %s (%.0f s) %s", done_count, len(pending), job.id, report["status"],
                 report.get("seconds", 0.0), detail)

    try:
        if workers == 1 or len(pending) <= 1:
            for job in pending:
                finished(job, run_job(job, manifest.output, fingerprints[job.id], scale))
        else:
            _run_pool(pending, manifest.output, fingerprints, min(workers, len(pending)), finished)
    except KeyboardInterrupt:
        result.interrupted = True
        log.warning("interrupted: %d of %d jobs finished in this run; run the same command again to resume",
                    done_count, len(pending))
    result.ran = done_count
    result.rows = [_summary_row(job, manifest.output, fingerprints[job.id]) for job in all_jobs]
    result.summary_files = write_summary(manifest, result.rows, interrupted=result.interrupted)
    if result.interrupted:
        raise KeyboardInterrupt
    return result


def _run_pool(pending: Sequence[Job], output: Path, fingerprints: dict, workers: int, finished) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    # "spawn": fresh interpreters, safe with BLAS/OpenMP threads in this process.
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init)
    futures = {pool.submit(run_job, job, output, fingerprints[job.id]): job for job in pending}
    try:
        remaining = set(futures)
        while remaining:
            completed, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            for future in completed:
                job = futures[future]
                try:
                    report = future.result()
                except BrokenProcessPool:
                    report = {"status": STATUS_FAILED, "error": "the worker process died (out of memory?)"}
                except Exception as error:  # the worker could not even start or report
                    report = {"status": STATUS_FAILED, "error": f"{type(error).__name__}: {error}"}
                finished(job, report)
    except BaseException:
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:   # stop the jobs in flight now: they are redone on the next run
            process.terminate()
        raise
    pool.shutdown(wait=True)


# ---------------------------------------------------------------------------------------------
# Summary

SUMMARY_COLUMNS = ("job", "mesh", "ruleset", "ratio", "status", "mass_ratio", "stress_ratio", "converged",
                   "worst_rule", "worst_rule_residual", "warnings", "seconds", "output", "error")


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
    if report.get("status") == STATUS_DONE:
        row["output"] = str(Path(job.id) / job.output_name)
    rules = figures.get("rules") or []
    if rules:
        worst = max(rules, key=lambda rule: abs(rule.get("error") or 0.0))
        row.update(worst_rule=worst.get("id"), worst_rule_residual=worst.get("error"))
    return row


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else ""
    return str(value)


def write_summary(manifest: Manifest, rows: list[dict[str, Any]], *, interrupted: bool = False) -> list[Path]:
    """``summary.json``, ``summary.csv`` and ``summary.md`` in the output folder (atomically)."""
    from allorules.files import atomic_write

    counts = {status: sum(1 for row in rows if row["status"] == status)
              for status in (STATUS_DONE, STATUS_FAILED, STATUS_NOT_RUN)}
    document = {"format": "allorules-batch-summary", "version": 1, "manifest": str(manifest.path),
                "interrupted": interrupted, "counts": counts, "jobs": rows}
    paths = [manifest.output / "summary.json", manifest.output / "summary.csv", manifest.output / "summary.md"]
    _write_json(paths[0], document)
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
    """``allorules batch``: run, print the table, exit 0 when every job is done, 1 otherwise."""
    result = run_batch(arguments.manifest, jobs=arguments.jobs, redo=arguments.redo)
    done, failed = result.count(STATUS_DONE), result.count(STATUS_FAILED)
    print(f"{done} done ({result.skipped} finished before, {result.ran} run now), {failed} failed")
    for row in result.rows:
        if row["status"] == STATUS_FAILED:
            print(f"  failed: {row['job']}: {row['error']}")
    print(f"summary: {result.summary_files[2]} (also .json, .csv)")
    return 0 if failed == 0 else 1
