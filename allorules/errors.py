"""User-facing errors.

Every failure a user can fix raises a subclass of :class:`AllorulesError`. Its message is one
line that says what is wrong and what to do; the CLI prints it to stderr without a traceback
(unless ``--debug``) and exits non-zero. Programming errors stay ordinary exceptions.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any


class AllorulesError(Exception):
    """Base class for errors whose message is meant for the user."""

    exit_code: int = 2


class MeshError(AllorulesError):
    """The input mesh cannot be read or used (unreadable, empty, NaN, too small, ...)."""


class BasisError(AllorulesError):
    """The harmonic basis could not be computed to the required accuracy."""


class SegmentationError(AllorulesError):
    """Regions could not be found or a segmentation/merge file is invalid."""


class MeasurementError(AllorulesError):
    """A quantity (volume, limb cross-section, length, ...) cannot be measured on this mesh."""


class OutputError(AllorulesError):
    """An output cannot be written where asked: it would replace an input, exists, has the wrong
    extension, or its folder is missing or not writable. Raised before any work starts."""


class PluginError(AllorulesError):
    """A plugin failed to load or misbehaved."""


class ScalingError(AllorulesError):
    """A scaling run did not reach its targets. ``closest`` holds the best result reached, if any;
    ``run``, where the run pipeline stopped, the whole run as far as it went (its report and picture
    can still be written: ``allorules.runs.pipeline.Run``)."""

    def __init__(self, message: str, closest: Any = None, run: Any = None):
        super().__init__(message)
        self.closest = closest
        self.run = run


@dataclass
class SourceLocation:
    """Where in a file something was written (1-based line; column optional)."""

    path: str | Path
    line: int | None = None
    column: int | None = None

    def __str__(self) -> str:
        text = str(self.path)
        if self.line is not None:
            text += f":{self.line}"
            if self.column is not None:
                text += f":{self.column}"
        return text


class RulesetError(AllorulesError):
    """A ruleset (or merge file) is invalid; the message names file and line."""

    def __init__(self, message: str, location: SourceLocation | None = None):
        self.problem = message       # the message without its location
        self.location = location
        super().__init__(f"{location}: {message}" if location else message)


class RulesetProblems(RulesetError):
    """Several problems in one ruleset; ``problems`` holds each as a :class:`RulesetError`.

    Its message is the first problem (and how many more there are), so it still reads as one
    line; ``allorules ruleset check`` prints them all.
    """

    def __init__(self, problems: list[RulesetError]):
        self.problems = list(problems)
        first = self.problems[0]
        more = len(self.problems) - 1
        message = str(first) + (f" (and {more} more problem{'s' if more > 1 else ''}: run 'allorules ruleset check')" if more else "")
        super().__init__(message)
        self.location = first.location
