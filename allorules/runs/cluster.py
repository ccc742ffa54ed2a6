"""Batch jobs on a Dask cluster: the same manifest past one machine, surviving a lost worker.

``allorules batch MANIFEST.yaml --scheduler tcp://HOST:PORT`` (or ``scheduler:`` in the manifest)
sends every pending job to a Dask distributed scheduler (the optional extra
``pip install allorules[distributed]``); workers are started with Dask's own ``dask worker`` or a
cluster manager (dask-jobqueue on Slurm, docs/batch.md).

**A job carries what it needs** (:class:`JobPayload`): the mesh file's bytes and the files it
refers to (materials, textures: :mod:`allorules.mesh.references`), the labels file, the resolved
ruleset as YAML with the files it names (plugins, a segmenter's merge file), the manifest's
plugin files. On the worker, :func:`run_payload` writes them into a temporary folder of the
worker's own scratch space, runs the job through the one run pipeline
(:func:`allorules.runs.jobs.run_job`), and returns its report and output files
(:class:`JobOutcome`); the worker's file system is never shared with the client's.

**Where the folders are shared** (``--shared-files``, ``shared_files: true``: the workers see the
manifest's files and the output folder at the same paths), a job carries only its paths; the
worker runs it in a staging folder inside the output folder (``.allorules-staging/``) and the
client moves the files into place (a rename on the same file system: no bytes travel).

**The client writes**, in the output folder, each job's files atomically, its mesh first and its
report (the "done" marker) last, exactly as the local pool does: resuming, failures per job and
the summary work the same. Each finished future is written once; a future finishes once.

**A lost worker** (killed, its machine gone) costs only its jobs in flight: the scheduler runs
them again on the other workers (up to ``distributed.scheduler.allowed-failures`` times, 3 by
default; after that the job is recorded as failed). Nothing of theirs was written, because only
the client writes. A client interrupted (Ctrl-C, SIGTERM) cancels its futures and writes the
summary; jobs already running on workers finish there and are dropped.

**Threads**: each task sets its worker process's BLAS to one thread; Dask runs one task per worker
thread. Run workers with ``--nthreads 1`` and as many processes as cores and memory allow
(docs/batch.md: a 1,000-mode basis of an 8k-vertex mesh, measured).

Dask is imported only when a scheduler is used, so the batch runs on one machine without it.
"""
from __future__ import annotations

import logging
import os
import re
import signal
import tempfile
import threading
import time
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from allorules import __version__
from allorules.errors import AllorulesError
from allorules.runs.jobs import (
    GLOBAL,
    REPORT_NAME,
    STATUS_FAILED,
    Job,
    record_failure,
    run_job,
)

log = logging.getLogger("allorules")

STAGING = ".allorules-staging"   # in the output folder: where workers run jobs when the folders are shared
INSTALL_HINT = "pip install 'allorules[distributed]' (it brings dask and distributed)"
CONNECT_SECONDS = 20
POLL_SECONDS = 0.25
STATUS_SECONDS = 2.0


class ClusterError(AllorulesError):
    """Dask is missing, the scheduler cannot be reached, or it went away during the run."""


# ---------------------------------------------------------------------------------------------
# The scheduler


def scheduler_address(value: Any, base: Path) -> str:
    """A scheduler given in a manifest or on the command line, checked: ``tcp://HOST:PORT`` (or
    another Dask protocol), ``HOST:PORT`` (tcp), or a scheduler file ``*.json`` (relative to
    ``base``) as written by ``dask scheduler --scheduler-file``."""
    if not isinstance(value, str) or not value.strip():
        raise ClusterError("the scheduler is an address (tcp://HOST:PORT) or a scheduler file (.json)")
    value = value.strip()
    if value.lower().endswith(".json"):
        return str((base / Path(value).expanduser()).resolve())
    if re.fullmatch(r"[a-z][a-z0-9+]*://\S+", value):
        return value
    if re.fullmatch(r"[\w.\-]+:\d+|\[[0-9a-fA-F:]+\]:\d+", value):
        return f"tcp://{value}"
    raise ClusterError(f"scheduler {value!r} is neither an address (tcp://HOST:PORT) nor a scheduler file (.json)")


def distributed_module():
    """``distributed``, or a one-line :class:`ClusterError` saying what to install."""
    try:
        import distributed
    except ImportError:
        raise ClusterError(f"--scheduler needs Dask distributed, which is not installed: {INSTALL_HINT}") from None
    return distributed


def connect(address: str):
    """A Dask client of the scheduler at ``address`` (see :func:`scheduler_address`)."""
    distributed = distributed_module()
    try:
        if address.lower().endswith(".json"):
            if not Path(address).is_file():
                raise ClusterError(f"scheduler file {address} not found; start the scheduler with "
                                   f"'dask scheduler --scheduler-file {address}' or give its address")
            return distributed.Client(scheduler_file=address, timeout=CONNECT_SECONDS, set_as_default=False)
        return distributed.Client(address, timeout=CONNECT_SECONDS, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ClusterError(f"cannot reach the Dask scheduler at {address} ({reason}); start one with "
                           "'dask scheduler' and give the address it prints") from None


def _from_dask(record: logging.LogRecord) -> bool:
    return record.name.split(".")[0] in ("distributed", "tornado", "asyncio") or "/distributed/" in record.pathname


def disconnect(client) -> None:
    """Close the client. After the scheduler was lost, Dask's own reconnect attempts end in
    tracebacks on its loggers as the client closes; the user has had the one-line reason, so
    Dask's messages are kept off the terminal while it closes."""
    quiet = logging.Filter()
    quiet.filter = lambda record: not _from_dask(record)   # type: ignore[method-assign]
    handlers = list(logging.getLogger().handlers)
    for handler in handlers:
        handler.addFilter(quiet)
    try:
        client.close(timeout=10)
    except Exception:   # closing a client whose scheduler is gone may fail: nothing is left to close
        pass
    finally:
        for handler in handlers:
            handler.removeFilter(quiet)


# ---------------------------------------------------------------------------------------------
# What a job carries


@dataclass(frozen=True)
class CarriedFile:
    """A file travelling with a job: its path relative to where it is laid out, and its bytes."""

    path: str
    data: bytes


@dataclass(frozen=True)
class JobPayload:
    """Everything a worker needs to run one job, with no file system shared with the client."""

    job: Job                                   # as on the client (its paths name the client's files)
    fingerprint: str
    mesh: tuple[CarriedFile, ...]              # the mesh file first, then the files it refers to
    segmentation: CarriedFile | None = None
    ruleset: str | None = None                 # resolved ruleset YAML; its files relative to it
    ruleset_files: tuple[CarriedFile, ...] = ()
    ruleset_origin: str | None = None          # where the client read the ruleset
    plugins: tuple[tuple[str, tuple[CarriedFile, ...]], ...] = ()   # (client path, its files)
    staging: str | None = None                 # shared files: the job's paths are valid on the worker, and
                                               # it runs in this folder (inside the output folder)

    @property
    def size(self) -> int:
        files = list(self.mesh) + list(self.ruleset_files) + [f for _, carried in self.plugins for f in carried]
        return sum(len(f.data) for f in files) + (len(self.segmentation.data) if self.segmentation else 0)


def _carry(path: Path, relative_to: Path) -> list[CarriedFile]:
    """A file, or every file of a folder (a plugin package), relative to ``relative_to``."""
    if path.is_dir():
        return [CarriedFile(item.relative_to(relative_to).as_posix(), item.read_bytes())
                for item in sorted(path.rglob("*"))
                if item.is_file() and "__pycache__" not in item.parts
                and not any(part.startswith(".") for part in item.relative_to(path).parts)]
    return [CarriedFile(path.relative_to(relative_to).as_posix(), path.read_bytes())]


def job_payload(job: Job, fingerprint: str, ruleset=None, *, shared_output: Path | None = None) -> JobPayload:
    """What ``job`` carries to a worker; ``ruleset`` is its resolved
    :class:`~allorules.rules.model.Ruleset` (``None`` for global scaling). With ``shared_output``
    (the output folder, seen by the workers at the same path) the job carries no file, only paths."""
    from allorules.mesh.references import referenced_files

    if shared_output is not None:
        return JobPayload(job, fingerprint, (), staging=str(shared_output / STAGING))

    mesh = [CarriedFile(job.mesh.name, job.mesh.read_bytes())]
    mesh += [CarriedFile(name, (job.mesh.parent / name).read_bytes()) for name in referenced_files(job.mesh)
             if name != job.mesh.name]
    segmentation = CarriedFile(job.segmentation.name, job.segmentation.read_bytes()) if job.segmentation else None
    plugins = tuple((str(plugin), tuple(_carry(plugin, plugin.parent))) for plugin in job.plugins)
    text, files, origin = None, [], None
    if job.ruleset != GLOBAL:
        import yaml

        from allorules.rules.model import ruleset_to_dict

        if ruleset is None:
            from allorules.runs.jobs import ruleset_with_plugins

            ruleset = ruleset_with_plugins(job.ruleset, job.plugins)[0]
        document = ruleset_to_dict(ruleset)
        # The files the ruleset names travel beside it; the document names them relative to itself.
        if ruleset.plugins:
            document["plugins"] = []
            for index, plugin in enumerate(ruleset.plugins):
                folder = f"files/plugin{index}"
                files += [CarriedFile(f"{folder}/{f.path}", f.data) for f in _carry(plugin, plugin.parent)]
                document["plugins"].append(f"{folder}/{plugin.name}")
        options = dict(ruleset.segmenter.options)
        for index, (key, value) in enumerate(sorted(options.items())):
            if isinstance(value, Path) and value.is_file():
                folder = f"files/segmenter{index}"
                files.append(CarriedFile(f"{folder}/{value.name}", value.read_bytes()))
                document["segmenter"]["options"][key] = f"{folder}/{value.name}"
        text = yaml.safe_dump(document, sort_keys=False, allow_unicode=True, width=100)
        origin = str(ruleset.path) if ruleset.path else job.ruleset
    return JobPayload(job, fingerprint, tuple(mesh), segmentation, text, tuple(files), origin, plugins)


def _lay_out(folder: Path, files: Sequence[CarriedFile]) -> None:
    for carried in files:
        target = _inside(folder, carried.path)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(carried.data)


def _inside(folder: Path, relative: str) -> Path:
    """``folder / relative``, refusing names that would leave the folder."""
    path = Path(relative)
    if path.is_absolute() or ".." in path.parts or not path.parts:
        raise ClusterError(f"refusing the file name {relative!r}: it would be written outside {folder}")
    return folder / path


def materialise(payload: JobPayload, folder: Path) -> tuple[Job, dict[str, str]]:
    """Lay the payload's files out in ``folder``; the job with its paths there, and the map from
    those paths back to the client's (for the report)."""
    job = payload.job
    _lay_out(folder / "mesh", payload.mesh)
    renamed = {str(folder / "mesh" / payload.mesh[0].path): str(job.mesh)}
    segmentation = None
    if payload.segmentation is not None:
        _lay_out(folder / "labels", [payload.segmentation])
        segmentation = folder / "labels" / payload.segmentation.path
        renamed[str(segmentation)] = str(job.segmentation)
    plugins = []
    for index, (original, files) in enumerate(payload.plugins):
        _lay_out(folder / "plugins" / str(index), files)
        plugins.append(folder / "plugins" / str(index) / Path(original).name)
        renamed[str(plugins[-1])] = original
    ruleset = GLOBAL
    if payload.ruleset is not None:
        _lay_out(folder / "ruleset", payload.ruleset_files)
        path = folder / "ruleset" / f"{job.ruleset_label}.yaml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(payload.ruleset, encoding="utf-8")
        ruleset = str(path)
        renamed[str(path)] = payload.ruleset_origin or job.ruleset
    local = Job(folder / "mesh" / payload.mesh[0].path, job.name, segmentation, job.ratio, ruleset, job.modes,
                job.format, tuple(plugins))
    if local.id != job.id or local.output_name != job.output_name:   # pragma: no cover - a bug, not an input
        raise ClusterError(f"job {job.id} would be named {local.id} on the worker")
    return local, renamed


def _renamed(value: Any, renamed: dict[str, str]) -> Any:
    """``value`` (a report) with the worker's temporary paths replaced by the client's files."""
    if isinstance(value, dict):
        return {key: _renamed(item, renamed) for key, item in value.items()}
    if isinstance(value, list):
        return [_renamed(item, renamed) for item in value]
    if isinstance(value, str):
        for local in sorted(renamed, key=len, reverse=True):
            value = value.replace(local, renamed[local])
    return value


# ---------------------------------------------------------------------------------------------
# On the worker


@dataclass
class JobOutcome:
    """What a worker returns: the job's report, its output files and the warnings it printed."""

    report: dict[str, Any]
    files: dict[str, bytes] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)
    allorules: str = __version__
    worker: str | None = None
    staged: dict[str, str] = field(default_factory=dict)   # shared files: name → the file in the staging folder
    staging: str | None = None


_blas_lock = threading.Lock()
_blas_limited: list = []


def one_blas_thread() -> None:
    """Limit this process's BLAS and OpenMP pools to one thread (a Dask nanny already sets the
    environment so; a worker started without one needs this)."""
    with _blas_lock:
        if _blas_limited:
            return
        for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(variable, "1")
        from threadpoolctl import threadpool_limits

        _blas_limited.append(threadpool_limits(limits=1))


class _ThreadMessages(logging.Handler):
    """Collects the ``allorules`` warnings logged by one thread (a worker runs jobs side by side)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.thread = threading.get_ident()
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.messages.append(record.getMessage())


def _capture() -> _ThreadMessages:
    handler = _ThreadMessages()
    logging.getLogger("allorules").addHandler(handler)
    return handler


def _worker_address() -> tuple[str | None, Path]:
    """This worker's address and its scratch folder (outside a worker: none, and the temp folder)."""
    try:
        from distributed import get_worker

        worker = get_worker()
        return worker.address, Path(worker.local_directory)
    except (ImportError, ValueError):
        return None, Path(tempfile.gettempdir())


def run_payload(payload: JobPayload) -> JobOutcome:
    """Run one job on a worker: its files laid out in a temporary folder, the job run through the
    pipeline (:func:`allorules.runs.jobs.run_job`), its report and output files returned. With
    shared files, the job runs on its own paths in a staging folder and returns the staged files'
    paths instead of their bytes."""
    one_blas_thread()
    address, scratch = _worker_address()
    if payload.staging is not None:
        return _run_shared(payload, address)
    with tempfile.TemporaryDirectory(prefix="allorules-job-", dir=scratch) as temporary:
        folder = Path(temporary)
        job, renamed = materialise(payload, folder)
        handler = _capture()
        try:
            report = run_job(job, folder / "out", payload.fingerprint)
        finally:
            logging.getLogger("allorules").removeHandler(handler)
        produced = folder / "out" / job.id
        files = {item.relative_to(produced).as_posix(): item.read_bytes() for item in _produced(produced)}
        renamed[str(produced)] = f"<output>/{payload.job.id}"
        renamed[str(folder)] = "<worker scratch>"
        report = _renamed(report, renamed)
    report["job"] = payload.job.describe()
    report["worker"] = address
    return JobOutcome(report, files, [_renamed(m, renamed) for m in handler.messages], __version__, address)


def _produced(folder: Path) -> list[Path]:
    return [item for item in sorted(folder.rglob("*"))
            if item.is_file() and item.name != REPORT_NAME and not item.name.endswith(".tmp")]


def _run_shared(payload: JobPayload, address: str | None) -> JobOutcome:
    job = payload.job
    missing = [path for path in (job.mesh, job.segmentation, *job.plugins) if path is not None and not path.exists()]
    staging = Path(payload.staging)
    if missing or not staging.parent.is_dir():
        where = missing[0] if missing else staging.parent
        report = {"status": STATUS_FAILED, "worker": address,
                  "error": f"worker {address} does not see {where}: the folders are not shared with it; "
                           "run without --shared-files (the jobs then carry their files)"}
        return JobOutcome(report, {}, [], __version__, address)
    staging.mkdir(exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix=f"{job.id}.", dir=staging))
    handler = _capture()
    try:
        report = run_job(job, folder, payload.fingerprint)
    finally:
        logging.getLogger("allorules").removeHandler(handler)
    produced = folder / job.id
    renamed = {str(produced): f"<output>/{job.id}"}
    report = _renamed(report, renamed)
    report["worker"] = address
    staged = {item.relative_to(produced).as_posix(): str(item) for item in _produced(produced)}
    return JobOutcome(report, {}, [_renamed(m, renamed) for m in handler.messages], __version__, address,
                      staged, str(folder))


# ---------------------------------------------------------------------------------------------
# On the client


def write_outcome(job: Job, outcome: JobOutcome, output: Path) -> dict[str, Any]:
    """Write a job's outputs into ``output/<job id>/`` atomically, the report (done marker) last."""
    from allorules.files import atomic_write, write_json

    folder = output / job.id
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in sorted(outcome.files.items()):
        atomic_write(_inside(folder, name), data)
    for name, staged in sorted(outcome.staged.items()):   # shared files: a rename, no copy
        target = _inside(folder, name)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staged, target)
    write_json(folder / REPORT_NAME, outcome.report)
    log.debug("cluster: wrote %s (%s)", folder, ", ".join(sorted([*outcome.files, *outcome.staged, REPORT_NAME])))
    if outcome.staging:
        import shutil

        shutil.rmtree(outcome.staging, ignore_errors=True)
    return outcome.report


def _key(job: Job, fingerprint: str) -> str:
    return f"allorules-{job.id}-{fingerprint[:16]}"


def _failure(job: Job, error: BaseException) -> str:
    from distributed import KilledWorker

    if isinstance(error, KilledWorker):
        return ("the Dask workers running this job died each time (out of memory? see the workers' logs and size "
                "them as docs/batch.md says); run the batch again to retry")
    if isinstance(error, ImportError) and "allorules" in str(error):
        return (f"a Dask worker cannot import allorules: install allorules[distributed] {__version__} on every "
                "worker")
    text = str(error).splitlines()[0] if str(error) else ""
    return f"{type(error).__name__}: {text}".rstrip(": ")


def _lost_with_the_scheduler(client, future, error: BaseException) -> bool:
    """Whether a future's error is the scheduler's loss, not the job's: cancelled by no one of ours
    (the scheduler went away or restarted), or its result lost in transit as the connection closed
    (a job in flight when the scheduler dies may end either way)."""
    from distributed.comm.core import CommClosedError

    return (future.status == "cancelled" or isinstance(error, CommClosedError)
            or client.status not in ("running", "connecting"))


class _ClusterWatch:
    """The cluster as the client sees it: its workers and how many of our jobs run on them."""

    def __init__(self, client) -> None:
        self.client = client
        self.workers: dict[str, int] = {}
        self.told_empty = False
        self.checked = 0.0
        self.last_line = ""

    def threads(self) -> int:
        return sum(self.workers.values())

    def update(self, keys: set[str], progress) -> None:
        now = time.monotonic()
        if now - self.checked < STATUS_SECONDS and self.checked:
            return
        self.checked = now
        from distributed.comm.core import CommClosedError

        try:
            workers = dict(self.client.nthreads())
            processing = self.client.processing()
        except (CommClosedError, OSError, TimeoutError):   # the scheduler went away between two looks
            raise ClusterError("lost the connection to the Dask scheduler (or it restarted); run the batch again "
                               "to resume") from None
        for address in sorted(set(self.workers) - set(workers)):
            log.warning("cluster: worker %s left; its jobs in flight run again on the other workers", address)
        for address in sorted(set(workers) - set(self.workers)):
            log.info("cluster: worker %s joined (%d thread%s)", address, workers[address],
                     "" if workers[address] == 1 else "s")
        self.workers = workers
        if not workers and not self.told_empty:
            log.warning("cluster: no worker is connected to the scheduler: start some with "
                        "'dask worker %s --nthreads 1'", self.client.scheduler.address)
        self.told_empty = not workers
        running = 0
        for address, tasks in processing.items():
            ours = sum(1 for key in tasks if key in keys)
            running += min(ours, workers.get(address, 0))
        progress.running = running
        line = f"{progress.counts()} on {len(workers)} worker{'' if len(workers) == 1 else 's'}"
        if line != self.last_line:
            log.info("cluster: %s", line)
            self.last_line = line


def run_on_cluster(client, pending: Sequence[Job], output: Path, fingerprints: dict[str, str],
                   rulesets: dict[str, Any], progress, *, shared_files: bool = False) -> None:
    """Run ``pending`` jobs on the cluster of ``client``, writing each job's outputs and report as
    it finishes and telling ``progress`` (:class:`allorules.runs.batch.BatchProgress`). Jobs are
    submitted a window at a time (twice the cluster's threads, at least 4), so the client holds
    few payloads at once. ``shared_files``: the workers see the inputs and ``output`` at the same
    paths (jobs carry paths; outputs are moved into place). Any interruption cancels the futures in
    flight and re-raises."""
    queue: deque[Job] = deque(pending)
    in_flight: dict[Any, Job] = {}
    watch = _ClusterWatch(client)
    told_version: set[str] = set()
    # Ctrl-C only sets a flag that the loop reads: raised wherever it lands, a KeyboardInterrupt can
    # be swallowed inside distributed's client calls (seen once in CI: the batch ran to the end)
    interrupted = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, lambda number, frame: interrupted.set())
    try:
        watch.update(set(), progress)
        while queue or in_flight:
            if interrupted.is_set():
                raise KeyboardInterrupt
            while queue and len(in_flight) < max(4, 2 * watch.threads()):
                job = queue.popleft()
                payload = job_payload(job, fingerprints[job.id], rulesets.get(job.ruleset),
                                      shared_output=output if shared_files else None)
                with warnings.catch_warnings():   # a job carrying a large mesh is the design, not a mistake
                    warnings.filterwarnings("ignore", message="Sending large graph")
                    future = client.submit(run_payload, payload, key=_key(job, fingerprints[job.id]), pure=False,
                                           retries=0)
                in_flight[future] = job
            completed = [future for future in in_flight if future.done()]
            for future in completed:
                job = in_flight.pop(future)
                try:
                    outcome = future.result()
                except Exception as error:   # the task never returned a report: record why
                    if _lost_with_the_scheduler(client, future, error):   # not the job's failure
                        raise ClusterError("lost the connection to the Dask scheduler (or it restarted); run the "
                                           "batch again to resume") from None
                    report = record_failure(job, output, fingerprints[job.id], _failure(job, error))
                else:
                    for message in outcome.messages:
                        log.warning("%s", message)
                    if outcome.allorules != __version__ and outcome.allorules not in told_version:
                        told_version.add(outcome.allorules)
                        log.warning("cluster: worker %s runs allorules %s, this client %s; install the same "
                                    "version everywhere", outcome.worker, outcome.allorules, __version__)
                    if "format" in outcome.report:
                        report = write_outcome(job, outcome, output)
                    else:   # the job could not start there (shared files not seen)
                        report = record_failure(job, output, fingerprints[job.id], outcome.report["error"])
                progress.running = max(0, progress.running - 1)
                progress.finished(job, report)
            if not completed:
                time.sleep(POLL_SECONDS)
            watch.update({future.key for future in in_flight}, progress)
            if client.status not in ("running", "connecting"):
                raise ClusterError(f"the Dask client is {client.status}: lost the scheduler; run the batch again to "
                                   "resume")
        if shared_files:
            try:
                (output / STAGING).rmdir()   # empty once every job's files are in place
            except OSError:
                pass
    except BaseException:
        if in_flight:
            try:
                client.cancel(list(in_flight), force=True)
            except Exception:   # the scheduler may be gone already
                pass
            log.warning("cluster: cancelled %d job%s in flight", len(in_flight), "" if len(in_flight) == 1 else "s")
        raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
