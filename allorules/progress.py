"""Progress on the terminal for long commands: numbered step lines and optional bars.

:class:`Steps` prints ``[2/7] scale globally ×0.5 …`` before a step and ``… done (3.1 s)`` after
it, through the ``allorules`` logger at INFO level, so ``--quiet`` (WARNING) silences it and
``--verbose`` (DEBUG) adds the inner details the modules log themselves. Bars (tqdm) are drawn
only when stderr is a terminal and INFO is enabled, so pipes, CI logs and tests stay clean.

Every bar in the package is made here by :func:`count_bar` (the eigensolver's
``terminal_progress`` is a bar of modes found).
"""
from __future__ import annotations

import logging
import sys
import time
from contextlib import contextmanager
from typing import Callable, Iterator

log = logging.getLogger("allorules")

ProgressCallback = Callable[[int, int], None]


def showing_progress() -> bool:
    """Bars are drawn when the user sees stderr on a terminal and did not ask for ``--quiet``."""
    stream = sys.stderr
    return bool(getattr(stream, "isatty", lambda: False)()) and log.isEnabledFor(logging.INFO)


def basis_bar(description: str = "harmonic basis") -> ProgressCallback | None:
    """A ``progress(done, total)`` callback for an eigensolve (modes found), or ``None``."""
    return count_bar(description, unit="modes")


def count_bar(description: str, unit: str = "steps") -> ProgressCallback | None:
    """A ``progress(done, total)`` callback drawing a tqdm bar counting ``unit``, or ``None``."""
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
