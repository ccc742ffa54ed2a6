"""The run pipeline: prepare → label → scale → save, with the report. Every front end calls it:
``allorules scale``, ``measure`` and ``segment``, batch runs, the demo, the Python API
(:mod:`allorules.api`) and the Blender add-on.

1. :func:`prepare`: the user's file (or a ``trimesh.Trimesh``, or a :class:`~allorules.body.Body`)
   becomes a repaired body that remembers how it maps back onto the input (METHOD §1).
2. :func:`label`: regions from a labels file (allorules JSON or Princeton ``.seg``) or from a
   segmenter through the plugin hook (the ruleset's, ``auto-quadruped`` by default); then regions
   nobody asked for are folded into their neighbour (:func:`allorules.segment.regions.fold_regions`).
   The body's :class:`~allorules.body.Labelling` says which file or segmenter labelled it.
3. :func:`scale`: one of the four kinds of scaling (:data:`Scaling`).
4. :func:`save_output` / :func:`save_picture`: the output in the input's own vertex layout (UVs,
   materials and detached parts kept) and a before/after picture; :meth:`Run.report` is the JSON.

:func:`run` does 1-3 and returns a :class:`Run`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Union

import numpy as np

from allorules import __version__
from allorules.body import Body, Labelling
from allorules.errors import MeasurementError, SegmentationError
from allorules.measure.mass import body_mass
from allorules.measure.stress import SectionChoice, peak_stress
from allorules.mesh.geometry import count_flipped_faces
from allorules.mesh.repair import PreparedMesh, prepare_mesh
from allorules.output.export import SaveResult, save_mesh
from allorules.plugins.registry import PluginRegistry, registry_for
from allorules.rules.model import Ruleset, SegmenterUse
from allorules.runs.global_run import scale_globally, scale_globally_raw
from allorules.runs.local import scale_region, seam_strain
from allorules.runs.progress import RunProgress
from allorules.runs.results import LocalResult, RawGlobalResult, ScalingResult
from allorules.runs.ruleset_run import scale_with_ruleset
from allorules.segment.labels_io import read_labels, read_seg
from allorules.segment.regions import QUADRUPED_REGIONS, fold_regions
from allorules.spectral.laplacian import lumped_mass

log = logging.getLogger("allorules")


# ---------------------------------------------------------------------------------------------
# What to do


@dataclass(frozen=True)
class GlobalScaling:
    """Paper §3.1: one α for the whole body; the mass changes by ``mass_ratio`` at unchanged peak
    limb stress (``section`` overrides where the stress is taken)."""

    mass_ratio: float
    section: SectionChoice | None = None


@dataclass(frozen=True)
class RulesetScaling:
    """Paper §3.3: the ruleset's rules and constraints met at body-mass ratio ``mass_ratio``."""

    ruleset: Ruleset
    mass_ratio: float
    section: SectionChoice | None = None


@dataclass(frozen=True)
class RawGlobalScaling:
    """Paper Eq. 4 once, with the user's α and isometric factor s (no measuring)."""

    alpha: float
    scale: float = 1.0


@dataclass(frozen=True)
class LocalScaling:
    """Paper Eq. 5-7 on one region; ``arithmetic_factor`` instead scales the region's vertices (the
    paper's bad example, for comparison only)."""

    region: str
    alpha: float = 0.0
    arithmetic_factor: float | None = None
    form: str = "per-axis"


Scaling = Union[GlobalScaling, RulesetScaling, RawGlobalScaling, LocalScaling]
Result = Union[ScalingResult, RawGlobalResult, LocalResult]


# ---------------------------------------------------------------------------------------------
# The stages


def prepare(source: str | Path | Any) -> PreparedMesh:
    """A mesh file, a ``trimesh.Trimesh`` or a :class:`Body` as a prepared body (each repair logged).

    A ``Body`` is taken as already prepared (the generated quadruped, a body from the API); its
    labels, if any, travel with it (see :func:`run`)."""
    if isinstance(source, Body):
        return PreparedMesh(source.vertices, source.faces, [])
    prepared = prepare_mesh(source)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    return prepared


def wanted_regions(ruleset: Ruleset | None) -> tuple[str, ...]:
    """The regions a run keeps apart: the six of a quadruped and every region the ruleset names."""
    names = list(QUADRUPED_REGIONS)
    if ruleset is not None:
        names += [name for name in ruleset.regions if name not in names]
        names += [rule.region for rule in ruleset.rules if rule.region and rule.region not in names]
    return tuple(names)


def label(
    body: Body,
    *,
    registry: PluginRegistry,
    segmenter: SegmenterUse | None = None,
    labels: str | Path | None = None,
    up: np.ndarray | None = None,
    forward: np.ndarray | None = None,
    regions: Iterable[str] = QUADRUPED_REGIONS,
) -> Body:
    """``body`` with regions, from the ``labels`` file or the ``segmenter`` (default
    ``auto-quadruped``) called through the plugin registry; regions not among ``regions`` join
    their neighbour. ``up``/``forward`` go to a segmenter that takes them."""
    if labels is not None:
        labelled = _read_labels_file(Path(labels), body)
        if up is not None or forward is not None:
            log.warning("--up/--forward are ignored: the regions come from %s", labels)
    else:
        labelled = _segment(body, registry, segmenter or SegmenterUse(), up, forward)
    return fold_regions(labelled, tuple(regions))


def _read_labels_file(path: Path, body: Body) -> Body:
    if path.suffix.lower() == ".seg":
        labelled = read_seg(path, body, QUADRUPED_REGIONS)
    else:
        labelled = read_labels(path, body)
    source = Labelling(f"labels file {path}")
    if labelled.labelling is not None:   # a labels file written by a segmenter keeps what it said
        source = Labelling(f"labels file {path} ({labelled.labelling.source})", labelled.labelling.confidence,
                           labelled.labelling.notes)
    return labelled.with_labels(labelled.labels, labelled.region_names, source)


def _segment(body: Body, registry: PluginRegistry, use: SegmenterUse, up, forward) -> Body:
    spec = registry.segmenter(use.name)
    options = spec.complete_parameters(use.options)
    for name, direction in (("up", up), ("forward", forward)):
        if direction is None:
            continue
        if name not in spec.parameter_specs():
            raise SegmentationError(f"segmenter {use.name!r} does not take --{name}; leave it out or use a "
                                    "segmenter that does (allorules plugins)")
        options[name] = np.asarray(direction, dtype=float)
    plugin = registry.provider("segmenter", use.name)
    labelled = spec.segment(Body(body.vertices, body.faces), **options)
    source = f"segmenter {use.name}" + ("" if plugin == "builtin" else f" (plugin {plugin})")
    said = labelled.labelling
    return labelled.with_labels(labelled.labels, labelled.region_names,
                                Labelling(source, dict(said.confidence) if said else {}, said.notes if said else ()))


def scale(body: Body, scaling: Scaling, *, registry: PluginRegistry, modes: int | None = None,
          use_cache: bool = True, progress: RunProgress | None = None) -> Result:
    """Scale a labelled ``body`` as ``scaling`` says. Raises :class:`~allorules.errors.ScalingError`
    (with ``closest``) when a step cannot be solved at all; an unconverged ruleset run returns its
    result with ``converged`` false and ``messages`` saying what was missed."""
    if isinstance(scaling, RulesetScaling):
        return scale_with_ruleset(body, scaling.ruleset, scaling.mass_ratio, registry=registry, modes=modes,
                                  section=scaling.section, use_cache=use_cache, progress=progress)
    if isinstance(scaling, GlobalScaling):
        return scale_globally(body, scaling.mass_ratio, modes=modes, section=scaling.section, use_cache=use_cache,
                              progress=progress)
    if isinstance(scaling, RawGlobalScaling):
        scaled = scale_globally_raw(body, scaling.alpha, scaling.scale, modes, use_cache=use_cache)
        return RawGlobalResult(scaled, scaling.alpha, scaling.scale, body_mass(scaled) / body_mass(body),
                               count_flipped_faces(body.vertices, scaled.vertices, body.faces))
    if isinstance(scaling, LocalScaling):
        if scaling.region not in body.region_names:
            raise SegmentationError(f"no region {scaling.region!r}; the body has {', '.join(body.region_names)}")
        scaled = scale_region(body, scaling.region, scaling.alpha, modes=modes, arithmetic_factor=scaling.arithmetic_factor,
                              use_cache=use_cache, form=scaling.form)
        seam = seam_strain(body.vertices, scaled.vertices, body.faces, body.region_mask(scaling.region))
        return LocalResult(scaled, scaling.region, scaling.alpha, scaling.arithmetic_factor, scaling.form, seam,
                           count_flipped_faces(body.vertices, scaled.vertices, body.faces))
    raise TypeError(f"not a kind of scaling: {scaling!r}")


# ---------------------------------------------------------------------------------------------
# A run


@dataclass
class Run:
    """One run: the prepared input, its labelled body, what was asked and what came out."""

    prepared: PreparedMesh
    body: Body
    scaling: Scaling
    result: Result
    labels_file: Path | None = None

    @property
    def converged(self) -> bool:
        return bool(self.result.converged)

    def output_vertices(self) -> np.ndarray:
        """The scaled positions of every vertex of the input, in the input's own order."""
        return self.prepared.source_positions(self.result.body.vertices)

    def report(self) -> dict[str, Any]:
        """The run as JSON: the input, its repairs, who labelled it, and the result's figures."""
        prepared = self.prepared
        document: dict[str, Any] = {
            "allorules": __version__,
            "input": str(prepared.source_path) if prepared.source_path else None,
            "vertices": int(len(prepared.vertices)),
            "faces": int(len(prepared.faces)),
            "repairs": list(prepared.repairs),
            "labels": _labels_report(self.body),
        }
        document.update(self.result.as_dict())
        if isinstance(self.scaling, GlobalScaling):
            document.update(_independent_check(self.body, self.result))
        return document


def run(
    source: str | Path | Any,
    scaling: Scaling,
    *,
    registry: PluginRegistry | None = None,
    labels: str | Path | None = None,
    segmenter: SegmenterUse | None = None,
    up: np.ndarray | None = None,
    forward: np.ndarray | None = None,
    modes: int | None = None,
    use_cache: bool = True,
    progress: RunProgress | None = None,
) -> Run:
    """Prepare, label and scale ``source`` (a mesh file, a ``trimesh.Trimesh`` or a
    :class:`Body`; a labelled ``Body`` keeps its labels). The segmenter is ``segmenter``, else the
    ruleset's, else ``auto-quadruped``; ``labels`` (a file) replaces it."""
    registry = registry if registry is not None else registry_for(None)
    ruleset = scaling.ruleset if isinstance(scaling, RulesetScaling) else None
    prepared = prepare(source)
    body = Body(prepared.vertices, prepared.faces)
    if isinstance(source, Body) and source.labels is not None and labels is None:
        body = fold_regions(source, wanted_regions(ruleset))
    elif isinstance(scaling, RawGlobalScaling) and labels is None:
        pass   # Eq. 4 once measures nothing: no regions needed
    else:
        body = label(body, registry=registry, segmenter=segmenter or (ruleset.segmenter if ruleset else None),
                     labels=labels, up=up, forward=forward, regions=wanted_regions(ruleset))
    result = scale(body, scaling, registry=registry, modes=modes, use_cache=use_cache, progress=progress)
    return Run(prepared, body, scaling, result, Path(labels) if labels else None)


def save_output(run: Run, path: str | Path, *, overwrite: bool = False) -> SaveResult:
    """Write the run's output mesh in the input's own layout (UVs, materials, detached parts kept);
    the input is never overwritten. ``save_mesh`` says on the log what the export could not carry over."""
    prepared = run.prepared
    if prepared.source is not None:
        saved = save_mesh(path, run.output_vertices(), np.asarray(prepared.source.faces), source=prepared.source,
                          input_path=prepared.source_path, overwrite=overwrite)
    else:
        saved = save_mesh(path, run.result.body.vertices, prepared.faces, input_path=prepared.source_path,
                          overwrite=overwrite)
    return saved   # save_mesh has said what it could not carry over (saved.notes), once


def save_picture(run: Run, path: str | Path, *, output_name: str = "output") -> Path:
    """The input and the output side by side, at true relative size."""
    from allorules.output.render import render_comparison

    body = run.body
    return render_comparison([(body.vertices, body.faces, "input"), (run.result.body.vertices, body.faces, output_name)],
                             path=path, normalise_size=False, frame=body.frame)


# ---------------------------------------------------------------------------------------------
# Report helpers


def _labels_report(body: Body) -> dict[str, Any]:
    """Who labelled the body, how sure it was, and each region's share of the surface."""
    labelling = body.labelling.as_dict() if body.labelling else {"source": "given", "confidence": {}, "notes": []}
    if body.labels is not None:
        area = lumped_mass(body.vertices, body.faces)
        shares = np.bincount(body.labels[body.labels >= 0], weights=area[body.labels >= 0],
                             minlength=len(body.region_names)) / area.sum()
        labelling["regions"] = {name: round(float(share), 4) for name, share in zip(body.region_names, shares)}
    return labelling


def _independent_check(body: Body, result: ScalingResult) -> dict[str, Any]:
    """Mass and peak stress of a global run's output measured from scratch (new contours, new choice)."""
    fresh_in = Body(body.vertices, body.faces, body.labels, body.region_names, body.frame)
    fresh_out = Body(result.body.vertices, body.faces, body.labels, body.region_names, body.frame)
    check: dict[str, Any] = {"mass_ratio_measured": body_mass(fresh_out) / body_mass(fresh_in)}
    try:
        check["stress_ratio_reselected"] = peak_stress(fresh_out) / peak_stress(fresh_in)
    except MeasurementError as error:
        check["stress_ratio_reselected"] = None
        check["messages"] = list(result.messages) + [f"independent stress check failed: {error}"]
    return check


__all__ = ["GlobalScaling", "RulesetScaling", "RawGlobalScaling", "LocalScaling", "Scaling", "Run", "prepare",
           "label", "scale", "run", "save_output", "save_picture", "wanted_regions"]
