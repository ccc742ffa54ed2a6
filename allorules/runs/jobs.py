"""One batch job: what it is (:class:`Job`), what decides its output (:func:`job_fingerprint`),
running it through the run pipeline (:func:`scale_job`, :func:`run_job`) and its report, the
job's "done" marker (:func:`read_report`, :func:`is_finished`).

Shared by the local process pool (:mod:`allorules.runs.batch`) and Dask workers
(:mod:`allorules.runs.cluster`), which both call :func:`run_job`. Like the batch module it
imports nothing numerical at module level, so a worker can limit its BLAS threads first.
"""
from __future__ import annotations

import hashlib
import json
import logging
import re
import threading
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

from allorules import __version__
from allorules.errors import AllorulesError

GLOBAL = "global"
REPORT_NAME = "report.json"
REPORT_FORMAT = "allorules-batch-job"
REPORT_VERSION = 1
STATUS_DONE, STATUS_FAILED, STATUS_NOT_RUN = "done", "failed", "not run"


def safe_name(text: str) -> str:
    """``text`` as a file-name part: letters, digits, ``.``, ``_`` and ``-`` only."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "mesh"


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
            else safe_name(Path(self.ruleset).stem)

    @property
    def id(self) -> str:
        return f"{self.name}__{safe_name(self.ruleset_label)}__x{self.ratio:g}"

    @property
    def output_name(self) -> str:
        return f"{self.name}_{safe_name(self.ruleset_label)}_x{self.ratio:g}.{self.format}"

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


def ruleset_with_plugins(name: str, plugins: tuple[Path, ...]):
    """The ruleset ``name`` (a name or a .yaml path) and the plugin registry it was checked against."""
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

        ruleset_text = dump_ruleset(ruleset_with_plugins(job.ruleset, job.plugins)[0])
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
    from allorules.errors import ScalingError
    from allorules.files import unconverged_path
    from allorules.plugins.registry import registry_for
    from allorules.runs import pipeline

    if job.ruleset == GLOBAL:
        registry = registry_for(list(job.plugins))
        scaling = pipeline.GlobalScaling(job.ratio)
    else:
        ruleset, registry = ruleset_with_plugins(job.ruleset, job.plugins)
        scaling = pipeline.RulesetScaling(ruleset, job.ratio)
    try:
        run = pipeline.run(job.mesh, scaling, registry=registry, labels=job.segmentation, modes=job.modes)
    except ScalingError as error:
        if error.run is None:
            raise
        run = error.run     # a run a step stopped is kept as one that missed: its mesh, its figures
    # a run that missed its targets is written under the unconverged name only, and the job fails
    # saying where (as `allorules scale --keep-unconverged`): a batch left alone must not leave a
    # mesh that looks done
    name = Path(job.output_name)
    if not run.converged:   # (and no mesh an earlier run of this job wrote under the output's name stays)
        (folder / name).unlink(missing_ok=True)
        name = unconverged_path(name)
    saved = pipeline.save_output(run, folder / name, overwrite=True)
    report = run.report()
    figures = {"repairs": report.pop("repairs"), "labels": report.pop("labels"), "result": run.result.as_dict(),
               "working_mesh": report["working_mesh"], "placement": report["placement"], "quality": report["quality"],
               "carried": list(saved.carried), "notes": list(saved.notes), "output": str(name)}
    if not run.converged:
        figures["error"] = f"{run.missed()}; the mesh was written to {name} (NOT {job.output_name})"
    return figures


def _write_json(path: Path, document: dict) -> None:
    from allorules.files import write_json

    write_json(path, document)


_running = threading.local()     # the job the current thread runs (Dask runs jobs in threads)
_factory_lock = threading.Lock()


def _naming_factory(previous: Callable[..., logging.LogRecord]) -> Callable[..., logging.LogRecord]:
    def named(*args, **kwargs) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        job_id = getattr(_running, "job_id", None)
        if job_id and not hasattr(record, "allorules_job") and (
                record.name == "allorules" or record.name.startswith("allorules.")):
            record.msg = f"{job_id}: {record.msg}"
            record.allorules_job = job_id   # named once, however many factories wrap this one
        return record

    named.allorules_job_names = True   # type: ignore[attr-defined]
    return named


@contextmanager
def messages_named(job_id: str) -> Iterator[None]:
    """Prefix every ``allorules`` log message with ``job_id`` while a job runs in this thread.

    Workers run in parallel and print to the same terminal: a warning such as "horse.obj: UVs
    dropped" must say which job (mesh × ratio × ruleset) it came from. The name is kept per
    thread, so jobs running side by side in one process (a Dask worker's threads) each name
    their own messages; the record factory that reads it is installed once."""
    with _factory_lock:
        factory = logging.getLogRecordFactory()
        if not getattr(factory, "allorules_job_names", False):
            logging.setLogRecordFactory(_naming_factory(factory))
    outer = getattr(_running, "job_id", None)
    _running.job_id = job_id
    try:
        yield
    finally:
        _running.job_id = outer


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
        report["status"] = STATUS_FAILED if report.get("error") else STATUS_DONE
    except AllorulesError as error:
        report.update(status=STATUS_FAILED, error=str(error))
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as error:  # a bug: record it (with its traceback) and go on with the others
        report.update(status=STATUS_FAILED, error=f"{type(error).__name__}: {error}", traceback=traceback.format_exc())
    report["seconds"] = round(time.perf_counter() - start, 3)
    _write_json(folder / REPORT_NAME, report)
    return report


def record_failure(job: Job, output: Path, fingerprint: str, error: str) -> dict[str, Any]:
    """Write the failed report of a job that could not even report for itself (its worker died)."""
    from allorules.files import write_json

    report = {"format": REPORT_FORMAT, "version": REPORT_VERSION, "allorules": __version__,
              "job": job.describe(), "fingerprint": fingerprint, "output": job.output_name,
              "status": STATUS_FAILED, "error": error}
    write_json(output / job.id / REPORT_NAME, report)
    return report
