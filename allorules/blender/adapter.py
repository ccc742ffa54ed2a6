"""The one door between Blender and allorules: arrays in, new vertex positions and a report out.

:func:`scale_arrays` is all the add-on knows of allorules. It takes the mesh as Blender holds it
(world-space vertex positions and triangles, one row per Blender vertex) and returns a new
position for every one of those vertices, so that the add-on can write them into a copy of the
mesh and keep its quads, UVs, materials and shading. No ``bpy`` here: the adapter is tested and
used without Blender.

It is one call to the run pipeline (:mod:`allorules.runs.pipeline`), the same every front end
uses (which also stands the output where the input stood).
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from allorules.errors import AllorulesError, MeshError, ScalingError
from allorules.runs.progress import RunProgress

POSTURES = ("keep", "upright", "free")

# The add-on's choices of the animal's forward direction (tail to head), in world space; Blender's
# front view looks along +Y, so a model facing it faces −Y.
FORWARD_DIRECTIONS = {"AUTO": None, "-Y": (0.0, -1.0, 0.0), "+Y": (0.0, 1.0, 0.0), "+X": (1.0, 0.0, 0.0),
                      "-X": (-1.0, 0.0, 0.0)}

# The command line's direction options as the panel names them: a refusal says how to settle it
# (the labeller: "settle it with --up DIR and --forward DIR ..."), and in Blender that is the panel.
_PANEL_TERMS = (("--up DIR and --forward DIR (the body's feet-to-back and tail-to-head)", "the Up and Forward settings"),
                ("--forward DIR (tail to head)", "the Forward setting"),
                ("--up/--forward", "the Up and Forward settings"))


def in_panel_terms(message: str) -> str:
    """``message`` with the command line's --up/--forward named as the panel's settings."""
    for option, setting in _PANEL_TERMS:
        message = message.replace(option, setting)
    return message


def check_settings(*, ruleset: str, mass_ratio: float, modes: int | None, posture: str | None,
                   global_mode: bool) -> None:
    """Refuse settings a run would refuse, before any work (one-line :class:`AllorulesError`)."""
    from allorules.runs.steps import check_mass_ratio

    check_mass_ratio(mass_ratio)
    if posture is not None and posture not in POSTURES:
        raise AllorulesError(f"posture must be one of {', '.join(POSTURES)}, got {posture!r}")
    if modes is not None and modes < 2:
        raise AllorulesError(f"modes must be at least 2, got {modes}")
    if not global_mode:
        from allorules.rules.resolve import load_ruleset

        load_ruleset(ruleset)


def scale_arrays(vertices: np.ndarray, faces: np.ndarray, *, ruleset: str = "quadruped", mass_ratio: float,
                 modes: int | None = None, posture: str | None = None, global_mode: bool = False,
                 up: np.ndarray | None = None, forward: np.ndarray | None = None,
                 progress: RunProgress | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Scale the quadruped ``vertices`` (n×3) / ``faces`` (m×3 triangles) by the body-mass ratio.

    ``ruleset``: a ruleset name or YAML path (ignored with ``global_mode``, which scales with one
    α at unchanged limb stress). ``modes``: harmonic basis size (``None``: the library's default).
    ``posture``: ``keep`` / ``upright`` / ``free``, or ``None`` for the ruleset's own. ``up``,
    ``forward``: the body's up (feet to back) and forward (tail to head), detected when ``None``.
    ``progress`` is told of steps, bases and trials and may raise to cancel the run.

    Returns the new position of every input vertex (n×3) and the run's report (JSON-ready, as
    ``allorules scale --report`` writes it, plus ``up`` and ``forward``: the body's frame in the
    input's coordinates). The output stands where the input stood: the pipeline puts its feet on
    the input's ground plane at the same place. Raises :class:`AllorulesError` with a
    one-line message when the mesh cannot be used or the run misses its targets.
    """
    import trimesh

    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline

    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1:] != (3,) or faces.ndim != 2 or faces.shape[1:] != (3,):
        raise MeshError(f"expected n×3 vertices and m×3 triangles, got {vertices.shape} and {faces.shape}")
    check_settings(ruleset=ruleset, mass_ratio=mass_ratio, modes=modes, posture=posture, global_mode=global_mode)
    registry = registry_for(None)
    if global_mode:
        scaling = pipeline.GlobalScaling(mass_ratio)
    else:
        rules = load_ruleset(ruleset, registry)
        if posture:
            rules = replace(rules, solver=replace(rules.solver, posture=posture))
        scaling = pipeline.RulesetScaling(rules, mass_ratio)
    run = pipeline.run(trimesh.Trimesh(vertices, faces, process=False), scaling, registry=registry, up=up,
                       forward=forward, modes=modes, progress=progress)
    report = run.report()
    if not run.converged:
        raise ScalingError(f"{run.missed()}; nothing was added", closest=run.result)
    new_vertices = run.output_vertices()      # placed by the pipeline: the feet where the input's were
    body = run.body
    frame_up = np.asarray(body.frame.up, dtype=float)
    report["up"] = frame_up.tolist()
    report["forward"] = np.asarray(body.frame.forward, dtype=float).tolist()
    return new_vertices, report
