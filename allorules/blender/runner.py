"""Running allorules off Blender's main thread: a worker thread, its progress, cancelling it.

No ``bpy`` here. The scale operator, when invoked from the UI, hands its work (a function of a
:class:`~allorules.runs.progress.RunProgress`) to a :class:`BackgroundRun`, polls it from a modal
timer, shows :meth:`BackgroundRun.status` in the status bar and calls :meth:`BackgroundRun.cancel`
on Esc. The worker touches only numpy arrays, never Blender data. Cancelling is cooperative: the
progress object raises :class:`Cancelled` at the run's next report (a basis mode found, a trial
mesh measured, a step begun), which is at most a fraction of a second away on meshes of a few
thousand vertices; the run then unwinds like any failure.
"""
from __future__ import annotations

import threading
import time
from typing import Any, Callable

from allorules.runs.progress import RunProgress


class Cancelled(Exception):
    """The user cancelled the run. Not an AllorulesError, so no library code catches it."""


class ThreadProgress(RunProgress):
    """Remembers where a run is (for the status bar) and raises :class:`Cancelled` once asked to."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self.stage = ""             # e.g. "run 1 of 2" in a gallery
        self.step = 0
        self.steps = 0
        self.detail = "preparing the mesh"
        self.started = time.monotonic()

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def check(self) -> None:
        if self._cancel.is_set():
            raise Cancelled("cancelled")

    def _set(self, **values: Any) -> None:
        self.check()
        with self._lock:
            for key, value in values.items():
                setattr(self, key, value)

    def begin(self, stage: str, detail: str = "preparing the mesh") -> None:
        self._set(stage=stage, step=0, steps=0, detail=detail)

    def step_started(self, step: int, steps: int) -> None:
        self._set(step=step, steps=steps, detail="starting")

    def basis(self, done: int, total: int) -> None:
        self._set(detail=f"harmonic basis {done}/{total} modes")

    def trial(self, count: int, misfit: float) -> None:
        self._set(detail=f"solving, {count} trial meshes (misfit {misfit:.1e})")

    def step_finished(self, step: int, steps: int) -> None:
        self._set(detail="step done")

    def fraction(self) -> float:
        """How far the run is, 0..1, by steps done."""
        with self._lock:
            return 0.0 if not self.steps else max(0.0, min(1.0, (self.step - 1) / self.steps))

    def text(self) -> str:
        with self._lock:
            parts = []
            if self.stage:
                parts.append(self.stage)
            if self.steps:
                parts.append(f"step {self.step}/{self.steps}")
            parts.append(self.detail)
        seconds = time.monotonic() - self.started
        return f"allorules: {', '.join(parts)} ({seconds:.0f} s) - Esc to cancel"


class BackgroundRun:
    """``work(progress)`` in a daemon thread; ``result`` or ``error`` once ``done``."""

    def __init__(self, work: Callable[[ThreadProgress], Any]) -> None:
        self.progress = ThreadProgress()
        self.result: Any = None
        self.error: BaseException | None = None
        self._work = work
        self._thread = threading.Thread(target=self._run, name="allorules-run", daemon=True)

    def start(self) -> "BackgroundRun":
        self._thread.start()
        return self

    def _run(self) -> None:
        try:
            self.result = self._work(self.progress)
        except BaseException as error:   # handed to the main thread, which reports it
            self.error = error

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def cancel(self) -> None:
        self.progress.cancel()

    def wait(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return self.done

    def status(self) -> str:
        return "allorules: cancelling…" if self.progress.cancelled else self.progress.text()
