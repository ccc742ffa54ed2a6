"""Hook specifications: the four ways a plugin extends allorules.

A plugin is a Python module (or package) with functions decorated by :data:`hookimpl` whose
names match the hooks below. Each hook returns a list; allorules gathers the lists of every
registered plugin (the built-ins included, which register through these same hooks as
plugin ``builtin``). Write a plugin like this::

    from allorules.hookspecs import hookimpl
    from allorules.specs import MeasureSpec

    @hookimpl
    def allorules_measures():
        return [MeasureSpec(name="ear-length", kind="length", isometric_exponent=1/3,
                            compute=ear_length, description="length of the ears")]

See ``docs/plugins.md`` for the whole story (entry points, ``--plugin PATH``, failures).
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:  # pragma: no cover
    from allorules.plugins.specs import ConstraintSpec, MeasureSpec, SegmenterSpec

PROJECT_NAME = "allorules"

hookspec = pluggy.HookspecMarker(PROJECT_NAME)
hookimpl = pluggy.HookimplMarker(PROJECT_NAME)


@hookspec
def allorules_measures() -> "list[MeasureSpec]":
    """Return the measures this plugin provides.

    A measure turns a :class:`~allorules.body.Body` (and optionally one of its regions) into
    one positive number. Only ratios of a measure between two meshes are ever used, so its
    units do not matter. Rules of a ruleset name measures by :attr:`MeasureSpec.name`.
    """


@hookspec
def allorules_segmenters() -> "list[SegmenterSpec]":
    """Return the segmenters this plugin provides.

    A segmenter labels the vertices of a body with region names:
    ``segment(body, **options) -> Body``.
    """


@hookspec
def allorules_constraints() -> "list[ConstraintSpec]":
    """Return the constraints (energy terms) this plugin provides.

    A constraint returns named relative residuals, dimensionless and 0 when satisfied. The
    solver squares each, multiplies by the weight the ruleset gives the constraint and adds
    them to the energy (paper Eq. 11).
    """


@hookspec
def allorules_ruleset_paths() -> "list[Path]":
    """Return folders (searched for ``*.yaml``) or ruleset files this plugin ships.

    Rulesets found there can be named by their name (file stem) like the built-in ones.
    """
