"""Progress on the terminal: bars only where a person watches, a bar each for steps, basis, trials."""
from __future__ import annotations

import io
import logging

from allorules.runs import progress as progress_module
from allorules.runs.progress import (
    LineRunProgress,
    RunProgress,
    Steps,
    TerminalRunProgress,
    count_bar,
    run_progress,
)


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_no_bars_when_nobody_watches(monkeypatch):
    monkeypatch.setattr("sys.stderr", io.StringIO())          # a pipe or a log file
    logger = logging.getLogger("allorules")
    previous = logger.level
    logger.setLevel(logging.WARNING)                         # --quiet: nothing at all
    try:
        assert count_bar("steps") is None
        assert type(run_progress()) is RunProgress
    finally:
        logger.setLevel(previous)


def test_lines_instead_of_bars_in_a_pipe_or_a_log(monkeypatch, caplog):
    """A long run nobody watches on a terminal is not silent: a line when each step starts and
    ends, and at most one every LINE_INTERVAL seconds in between (issue 19)."""
    monkeypatch.setattr("sys.stderr", io.StringIO())
    clock = [1000.0]
    monkeypatch.setattr(progress_module.time, "monotonic", lambda: clock[0])
    with caplog.at_level(logging.INFO, logger="allorules"):
        progress = run_progress("scaling steps")
        assert isinstance(progress, LineRunProgress)
        progress.step_started(1, 2)
        for trial in range(1, 101):          # 100 trials over 95 s: three lines, not a hundred
            clock[0] += 0.95
            progress.trial(trial, 1.0 / trial)
        progress.step_finished(1, 2)
        counter = count_bar("harmonic basis", unit="modes")
        for done in range(0, 101, 10):
            counter(done, 100)                 # no time passes: only the complete count
    lines = [record.getMessage() for record in caplog.records]
    assert lines[0] == "scaling steps: step 1/2 started"
    solving = [line for line in lines if "solving" in line]
    assert len(solving) == 3 and "misfit" in solving[0]
    assert "scaling steps: step 1/2 done (95 s)" in lines
    assert lines[-1] == "harmonic basis: 100/100 modes"


def test_no_bars_when_quiet(monkeypatch):
    monkeypatch.setattr("sys.stderr", Terminal())
    logger = logging.getLogger("allorules")
    previous = logger.level
    logger.setLevel(logging.WARNING)                         # --quiet
    try:
        assert count_bar("steps") is None and type(run_progress()) is RunProgress
    finally:
        logger.setLevel(previous)


def test_terminal_run_progress_draws_steps_basis_and_trials(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr("sys.stderr", terminal)
    logger = logging.getLogger("allorules")
    previous = logger.level
    logger.setLevel(logging.INFO)
    try:
        progress = run_progress("scaling steps")
        assert isinstance(progress, TerminalRunProgress)
        for step in (1, 2):
            progress.step_started(step, 2)
            for done in (40, 80, 100):
                progress.basis(done, 100)
            for count, misfit in enumerate((3e-2, 1e-4, 2e-9), start=1):
                progress.trial(count, misfit)
            progress.step_finished(step, 2)
    finally:
        logger.setLevel(previous)
    drawn = terminal.getvalue()
    for text in ("scaling steps", "step 1: harmonic basis", "step 2: harmonic basis", "step 2: solving",
                 "modes", "trials"):
        assert text in drawn, text


def test_steps_are_numbered_and_timed(caplog):
    steps = Steps(2)
    with caplog.at_level(logging.INFO, logger="allorules"):
        with steps.step("generate"):
            pass
        steps.skip("render", "no display")
    messages = [record.getMessage() for record in caplog.records]
    assert messages[0] == "[1/2] generate …" and messages[1].strip().startswith("done (")
    assert messages[2] == "[2/2] render: skipped, no display"
    assert [text for text, _ in steps.timings] == ["generate", "render"]
