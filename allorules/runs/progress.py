"""Progress for long commands: numbered step lines, bars on a terminal, lines in a log.

:class:`Steps` prints ``[2/7] scale globally ×0.5 …`` before a step and ``… done (3.1 s)`` after
it, through the ``allorules`` logger at INFO level, so ``--quiet`` (WARNING) silences it and
``--verbose`` (DEBUG) adds the inner details the modules log themselves. Bars (tqdm) are drawn
only when stderr is a terminal and INFO is enabled; when stderr is a pipe or a log file (CI, a
batch script, ``2> run.log``) the same progress comes as plain lines instead, one when a step
starts and ends and at most one every :data:`LINE_INTERVAL` seconds in between, so a
ten-minute run is never silent and a log is never flooded.

Every bar or line counter in the package is made here by :func:`count_bar`. A multi-step scaling
run reports to a :class:`RunProgress`: its steps, each step's basis (modes found) and each step's
solve (trial meshes measured); :func:`run_progress` gives bars on a terminal and lines elsewhere.
"""
from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager
from typing import Callable, Iterator

log = logging.getLogger("allorules")

ProgressCallback = Callable[[int, int], None]

# Seconds between two progress lines of the same step when stderr is not a terminal.
LINE_INTERVAL = 30.0


def _on_terminal() -> bool:
    return bool(getattr(sys.stderr, "isatty", lambda: False)())


def showing_progress() -> bool:
    """Bars are drawn when the user sees stderr on a terminal and did not ask for ``--quiet``."""
    return _on_terminal() and log.isEnabledFor(logging.INFO)


def writing_progress_lines() -> bool:
    """Progress lines are written when stderr is not a terminal and ``--quiet`` was not asked for."""
    return not _on_terminal() and log.isEnabledFor(logging.INFO)


def basis_bar(description: str = "harmonic basis") -> ProgressCallback | None:
    """A ``progress(done, total)`` callback for an eigensolve (modes found), or ``None``."""
    return count_bar(description, unit="modes")


def count_bar(description: str, unit: str = "steps") -> ProgressCallback | None:
    """A ``progress(done, total)`` callback: a tqdm bar counting ``unit`` on a terminal, progress
    lines elsewhere (:data:`LINE_INTERVAL`), ``None`` with ``--quiet``."""
    if writing_progress_lines():
        return _line_counter(description, unit)
    if not showing_progress():
        return None
    from tqdm import tqdm

    bars: list = []

    def progress(done: int, total: int) -> None:
        if not bars:
            bars.append(tqdm(total=total, desc=description, unit=unit, file=sys.stderr, leave=False))
        bar = bars[0]
        bar.total = total
        bar.update(max(0, min(done, total) - bar.n))
        if done >= total:
            bar.close()

    return progress


def _line_counter(description: str, unit: str) -> ProgressCallback:
    """``progress(done, total)`` that logs ``description: done/total unit`` at most every
    :data:`LINE_INTERVAL` seconds, and when the count is complete."""
    last = [time.monotonic()]

    def progress(done: int, total: int) -> None:
        now = time.monotonic()
        if done >= total or now - last[0] >= LINE_INTERVAL:
            last[0] = now
            log.info("%s: %d/%d %s", description, min(done, total), total, unit)

    return progress


class RunProgress:
    """What a multi-step scaling run reports as it goes; this base class ignores all of it.

    ``scale_globally`` and ``scale_with_ruleset`` call, for step k of n: ``step_started(k, n)``;
    ``basis(done, total)`` as the step's eigenpairs are found (not called when the basis comes from
    the cache); ``trial(count, misfit)`` after each trial mesh the step's solver measures (``misfit``
    = the best energy so far, the sum of squared relative residuals); ``step_finished(k, n)``.
    Subclass it to show progress elsewhere (a GUI, a log).
    """

    def step_started(self, step: int, steps: int) -> None:
        """Step ``step`` (1-based) of ``steps`` begins."""

    def basis(self, done: int, total: int) -> None:
        """``done`` of the step's ``total`` eigenpairs are found."""

    def trial(self, count: int, misfit: float) -> None:
        """The step's solver has measured ``count`` trial meshes; the best misfit so far."""

    def step_finished(self, step: int, steps: int) -> None:
        """Step ``step`` of ``steps`` is done."""


class TerminalRunProgress(RunProgress):
    """tqdm bars on stderr: the run's steps, and under them the current step's basis, then its trials."""

    def __init__(self, description: str = "scaling steps"):
        from tqdm import tqdm

        self._tqdm = tqdm
        self.description = description
        self._steps = None
        self._inner = None
        self._step = 0

    def _close_inner(self) -> None:
        if self._inner is not None:
            self._inner.close()
            self._inner = None

    def step_started(self, step: int, steps: int) -> None:
        if self._steps is None:
            self._steps = self._tqdm(total=steps, desc=self.description, unit="steps", file=sys.stderr, leave=False,
                                     position=0)
        self._step = step

    def basis(self, done: int, total: int) -> None:
        if self._inner is None:
            self._inner = self._tqdm(total=total, desc=f"step {self._step}: harmonic basis", unit="modes",
                                     file=sys.stderr, leave=False, position=1)
        self._inner.update(max(0, min(done, total) - self._inner.n))
        if done >= total:
            self._close_inner()

    def trial(self, count: int, misfit: float) -> None:
        if self._inner is None:
            self._inner = self._tqdm(desc=f"step {self._step}: solving", unit="trials", file=sys.stderr, leave=False,
                                     position=1)
        self._inner.update(count - self._inner.n)
        self._inner.set_postfix_str(f"misfit {misfit:.1e}", refresh=False)

    def step_finished(self, step: int, steps: int) -> None:
        self._close_inner()
        if self._steps is not None:
            self._steps.update(step - self._steps.n)
            if step >= steps:
                self._steps.close()
                self._steps = None


class LineRunProgress(RunProgress):
    """Progress lines on the log for a run nobody watches on a terminal: when each step starts and
    ends, and in between at most one line every :data:`LINE_INTERVAL` seconds (the basis's modes
    found, the solver's trials and best misfit)."""

    def __init__(self, description: str = "scaling steps"):
        self.description = description
        self._step, self._steps = 0, 0
        self._started = self._last = time.monotonic()

    def _due(self) -> bool:
        now = time.monotonic()
        if now - self._last >= LINE_INTERVAL:
            self._last = now
            return True
        return False

    def step_started(self, step: int, steps: int) -> None:
        self._step, self._steps = step, steps
        self._started = self._last = time.monotonic()
        if step == 1:   # then one line per step, when it is done
            log.info("%s: step 1/%d started", self.description, steps)

    def basis(self, done: int, total: int) -> None:
        if self._due():
            log.info("%s: step %d/%d: harmonic basis, %d/%d modes", self.description, self._step, self._steps,
                     min(done, total), total)

    def trial(self, count: int, misfit: float) -> None:
        if self._due():
            log.info("%s: step %d/%d: solving, %d trial meshes, misfit %.1e", self.description, self._step,
                     self._steps, count, misfit)

    def step_finished(self, step: int, steps: int) -> None:
        log.info("%s: step %d/%d done (%.0f s)", self.description, step, steps, time.monotonic() - self._started)


def run_progress(description: str = "scaling steps") -> RunProgress:
    """Bars for a scaling run when the user watches a terminal (see :func:`showing_progress`),
    lines when stderr is a pipe or a file, nothing with ``--quiet``."""
    if showing_progress():
        return TerminalRunProgress(description)
    return LineRunProgress(description) if writing_progress_lines() else RunProgress()


class Steps:
    """Numbered steps of one command, each announced and timed (see the module docstring).

    >>> steps = Steps(3)
    >>> with steps.step("generate the quadruped"):
    ...     pass
    """

    def __init__(self, total: int, *, logger: logging.Logger | None = None):
        self.total = int(total)
        self.number = 0
        self.logger = logger or log
        self.timings: list[tuple[str, float]] = []

    @contextmanager
    def step(self, text: str) -> Iterator[None]:
        self.number += 1
        self.logger.info("[%d/%d] %s …", self.number, self.total, text)
        start = time.perf_counter()
        try:
            yield
        finally:
            seconds = time.perf_counter() - start
            self.timings.append((text, seconds))
        self.logger.info("      done (%.1f s)", seconds)

    def skip(self, text: str, why: str) -> None:
        """Count a step that is not run and say why (as a warning: the user should know)."""
        self.number += 1
        self.logger.warning("[%d/%d] %s: skipped, %s", self.number, self.total, text, why)
        self.timings.append((text, 0.0))
