"""The one door between Blender and allorules: arrays in, new vertex positions and a report out.

:func:`scale_arrays` is all the add-on knows of allorules. It takes the mesh as Blender holds it
(world-space vertex positions and triangles, one row per Blender vertex) and returns a new
position for every one of those vertices, so that the add-on can write them into a copy of the
mesh and keep its quads, UVs, materials and shading. No ``bpy`` here: the adapter is tested and
used without Blender.

It is one call to the run pipeline (:mod:`allorules.runs.pipeline`), the same every front end
uses (which also stands the output where the input stood). :func:`label_arrays` is the pipeline's
labelling alone: the regions of every vertex, which the add-on writes as vertex groups named
``region:<name>`` (:data:`GROUP_PREFIX`) for the artist to check and paint; :func:`scale_arrays`
takes them back (``regions``) instead of labelling the animal itself.
"""
from __future__ import annotations

import re
from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from allorules.body import Frame
from allorules.errors import AllorulesError, MeshError, ScalingError
from allorules.runs.progress import RunProgress
from allorules.segment.body_plan import BY_HAND
from allorules.segment.regions import QUADRUPED_REGIONS

POSTURES = ("keep", "upright", "free")

# The add-on's choices of the animal's forward direction (tail to head), in world space; Blender's
# front view looks along +Y, so a model facing it faces −Y.
FORWARD_DIRECTIONS = {"AUTO": None, "-Y": (0.0, -1.0, 0.0), "+Y": (0.0, 1.0, 0.0), "+X": (1.0, 0.0, 0.0),
                      "-X": (-1.0, 0.0, 0.0)}

# The vertex groups that carry regions in Blender: "region:head", "region:forelimbs", ... (other
# groups, an armature's bone weights among them, are not regions).
GROUP_PREFIX = "region:"
REGION_GROUPS = ", ".join(GROUP_PREFIX + name for name in QUADRUPED_REGIONS)
PAINT_GROUPS = f"vertex groups {REGION_GROUPS} painted by hand and Regions set to Vertex groups"

# The command line's options as the panel names them: a refusal says how to settle it (the labeller:
# "settle it with --up DIR and --forward DIR ..., or a labels file ..."), and in Blender that is the panel.
_PANEL_TERMS = (("--up DIR and --forward DIR (the body's feet-to-back and tail-to-head)", "the Up and Forward settings"),
                ("--forward DIR (tail to head)", "the Forward setting"),
                ("--up/--forward", "the Up and Forward settings"),
                (f", {BY_HAND}", f", or {PAINT_GROUPS}"),     # "settle it with the Forward setting, or ..."
                (BY_HAND, PAINT_GROUPS),                       # "give the regions with ..."
                ("segment it (allorules segment) or give --segmentation FILE",
                 f"paint the vertex groups it lacks ({GROUP_PREFIX}<name>), or set Regions to Detect"))


# A refusal's mass rules to hold isometric (BiologyScalingResult.settle) as the command line's
# overrides; the panel has no overrides, only a ruleset file of one's own.
_HELD_RULES = re.compile(r"hold their mass isometric \(((?:--rule [\w-]+=1 ?)+)\) or give a ruleset of your own")


def in_panel_terms(message: str) -> str:
    """``message`` with the command line's --up/--forward named as the panel's settings, and its
    --rule overrides as a ruleset file (the panel's Ruleset, File…)."""
    for option, setting in _PANEL_TERMS:
        message = message.replace(option, setting)
    return _HELD_RULES.sub(
        lambda held: "hold their mass isometric: a ruleset file of your own (Ruleset, File…) with extends: the "
                     "ruleset and " + ", ".join(f"{{id: {rule}, exponent: 1}}" for rule in re.findall(r"--rule ([\w-]+)=1",
                                                                                            held.group(1))),
        message)


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


def _arrays(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1:] != (3,) or faces.ndim != 2 or faces.shape[1:] != (3,):
        raise MeshError(f"expected n×3 vertices and m×3 triangles, got {vertices.shape} and {faces.shape}")
    return vertices, faces


def _frame(body) -> dict[str, list[float]]:
    """The body's ``up`` and ``forward`` in the input's coordinates: the labeller's frame, else the
    regions' (:func:`allorules.solve.transform.anatomical_axes`)."""
    from allorules.solve.transform import anatomical_axes

    forward, up, _ = anatomical_axes(body)
    return {"up": up.tolist(), "forward": forward.tolist()}


def given_frame(up: np.ndarray | None, forward: np.ndarray | None) -> Frame | None:
    """The frame painted regions are measured in: ``up``, and ``forward`` made square to it; None
    unless both are given (and not parallel)."""
    if up is None or forward is None:
        return None
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    forward = np.asarray(forward, dtype=float) - np.dot(forward, up) * up
    length = np.linalg.norm(forward)
    return None if length < 1e-6 else Frame(up=up, forward=forward / length)


def label_arrays(vertices: np.ndarray, faces: np.ndarray, *, up: np.ndarray | None = None,
                 forward: np.ndarray | None = None) -> tuple[np.ndarray, tuple[str, ...], dict[str, Any]]:
    """The regions of the animal ``vertices`` / ``faces`` as a run finds them (every one the labeller
    finds: tail, ears, horns too): a region index for every input vertex (-1: none), the region
    names, and a report (``up``, ``forward``, the labelling's ``source`` and ``confidence``).
    Raises :class:`AllorulesError` with the labeller's one-line refusal."""
    import trimesh

    from allorules.runs import pipeline

    vertices, faces = _arrays(vertices, faces)
    regions, body = pipeline.input_regions(trimesh.Trimesh(vertices, faces, process=False), up=up, forward=forward)
    report: dict[str, Any] = {"source": regions.source, **_frame(body)}
    if body.labelling is not None:
        report["confidence"] = {key: float(value) for key, value in body.labelling.confidence.items()}
    return regions.labels, regions.region_names, report


def scale_arrays(vertices: np.ndarray, faces: np.ndarray, *, ruleset: str = "quadruped", mass_ratio: float,
                 modes: int | None = None, posture: str | None = None, global_mode: bool = False,
                 up: np.ndarray | None = None, forward: np.ndarray | None = None,
                 regions: tuple[np.ndarray, Sequence[str]] | None = None,
                 progress: RunProgress | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Scale the quadruped ``vertices`` (n×3) / ``faces`` (m×3 triangles) by the body-mass ratio.

    ``ruleset``: a ruleset name or YAML path (ignored with ``global_mode``, which scales with one
    α at unchanged limb stress). ``modes``: harmonic basis size (``None``: the library's default).
    ``posture``: ``keep`` / ``upright`` / ``free``, or ``None`` for the ruleset's own. ``up``,
    ``forward``: the body's up (feet to back) and forward (tail to head), detected when ``None``.
    ``regions``: (a region index for every input vertex, -1 for none; the region names), the
    regions painted as vertex groups, used instead of labelling the animal; ``up`` and ``forward``,
    both given, are then the axes the regions are measured along (those Label Regions found:
    :func:`label_arrays`'s report), else the axes come from the regions themselves. ``progress``
    is told of steps, bases and trials and may raise to cancel the run.

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

    vertices, faces = _arrays(vertices, faces)
    check_settings(ruleset=ruleset, mass_ratio=mass_ratio, modes=modes, posture=posture, global_mode=global_mode)
    registry = registry_for(None)
    if global_mode:
        scaling = pipeline.GlobalScaling(mass_ratio)
    else:
        rules = load_ruleset(ruleset, registry)
        if posture:
            rules = replace(rules, solver=replace(rules.solver, posture=posture))
        scaling = pipeline.RulesetScaling(rules, mass_ratio)
    labels = None if regions is None else pipeline.VertexRegions(np.asarray(regions[0]), tuple(regions[1]),
                                                                  "vertex groups", given_frame(up, forward))
    run = pipeline.run(trimesh.Trimesh(vertices, faces, process=False), scaling, registry=registry, labels=labels,
                       up=up, forward=forward, modes=modes, progress=progress)
    report = run.report()
    if not run.converged:
        raise ScalingError(f"{run.missed()}; nothing was added", closest=run.result)
    new_vertices = run.output_vertices()      # placed by the pipeline: the feet where the input's were
    report.update(_frame(run.body))
    return new_vertices, report
