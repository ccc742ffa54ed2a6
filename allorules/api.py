"""The public Python API: what a script needs, from one place.

    from allorules.api import scale_mesh

    run = scale_mesh("horse.obj", 2.0, ruleset="quadruped", output="big_horse.obj")
    print(run.converged, run.report()["rules"])

:func:`scale_mesh` is the whole pipeline in one call (:mod:`allorules.runs.pipeline`: prepare →
label → scale → save); the stages are here too (:func:`prepare`, :func:`label`, :func:`scale`,
:func:`save_output`), with the kinds of scaling (:class:`RulesetScaling`, :class:`GlobalScaling`,
:class:`LocalScaling`, :class:`RawGlobalScaling`), the building blocks (harmonic basis, spectrum,
measures, rulesets, plugins, the generated quadruped) and the errors. Everything a run can fail
on is an :class:`AllorulesError` whose message says what to do.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

from allorules.body import UNLABELLED, Body, Frame, Labelling
from allorules.errors import (
    AllorulesError,
    BasisError,
    MeasurementError,
    MeshError,
    OutputError,
    PluginError,
    RulesetError,
    ScalingError,
    SegmentationError,
)
from allorules.files import Output, check_outputs, protection_scope
from allorules.measure.girth import region_girth
from allorules.measure.length import region_length
from allorules.measure.mass import body_mass, region_mass
from allorules.measure.stress import SectionChoice, peak_stress
from allorules.mesh.quadruped import generate_quadruped
from allorules.mesh.repair import PreparedMesh, prepare_mesh
from allorules.plugins import PluginRegistry, registry_for
from allorules.rules.find import list_rulesets
from allorules.rules.model import Rule, Ruleset, SegmenterUse
from allorules.rules.resolve import load_ruleset
from allorules.runs.pipeline import (
    GlobalScaling,
    LocalScaling,
    RawGlobalScaling,
    RulesetScaling,
    Run,
    label,
    prepare,
    run,
    save_output,
    save_picture,
    scale,
)
from allorules.runs.progress import RunProgress
from allorules.spectral.basis import HarmonicBasis, compute_basis
from allorules.spectral.spectrum import spectrum_fit


def scale_mesh(
    mesh: str | Path | Any,
    mass_ratio: float,
    *,
    ruleset: str | Path | Ruleset | None = "quadruped",
    output: str | Path | None = None,
    overwrite: bool = False,
    labels: str | Path | None = None,
    plugins: Iterable[str | Path] = (),
    modes: int | None = None,
    progress: RunProgress | None = None,
    placement: str = "ground",
    working_vertices: int | None = None,
) -> Run:
    """Scale ``mesh`` (a file, a ``trimesh.Trimesh`` or a :class:`Body`) to ``mass_ratio`` times
    its body mass: biology-aware with ``ruleset`` (a built-in name, a YAML path or a loaded
    :class:`Ruleset`), or globally with ``ruleset=None``. Regions come from ``labels`` (a file),
    the mesh file's own labels file beside it (``NAME.labels.json``, where it fits) or the
    ruleset's segmenter. With ``output``, the result is written in the input's own layout, its
    regions beside it as ``OUTPUT-NAME.labels.json``, when the run converged (an unconverged run
    raises :class:`ScalingError` and writes nothing); no input is ever overwritten. The output
    stands where the input stood (``placement="centroid"``: its centroid in place). A mesh above ``working_vertices`` (default 8,000) is
    scaled on a working mesh and the result carried back to every one of its vertices. Returns the
    :class:`Run` (``run.report()`` is its JSON)."""
    registry = registry_for(list(plugins))
    if ruleset is None:
        scaling = GlobalScaling(mass_ratio)
    else:
        loaded = ruleset if isinstance(ruleset, Ruleset) else load_ruleset(ruleset, registry)
        scaling = RulesetScaling(loaded, mass_ratio)
    with protection_scope():
        if output is not None:   # before any work; no input (mesh, labels, ruleset, plugin) is ever replaced
            from allorules.output.export import SUPPORTED_FORMATS
            from allorules.segment.labels_io import labels_file_beside

            mesh_file = Path(mesh) if isinstance(mesh, (str, Path)) else None
            beside = labels_file_beside(mesh_file) if mesh_file is not None and labels is None else None
            check_outputs([Output.of(output, "output", SUPPORTED_FORMATS),
                           Output.of(labels_file_beside(output), "the labels file beside the output", (".json",))],
                          {"input mesh": mesh_file, "labels file": labels,
                           "input's labels file": beside if beside is not None and beside.is_file() else None,
                           "ruleset": getattr(scaling, "ruleset", None) and scaling.ruleset.path,
                           "plugin": list(plugins)}, force=overwrite, force_option="overwrite=True")
        result = run(mesh, scaling, registry=registry, labels=labels, modes=modes, progress=progress,
                     placement=placement, working_vertices=working_vertices)
        if output is not None:
            if not result.converged:
                raise ScalingError(f"not written: the run did not reach its targets "
                                   f"({'; '.join(result.result.messages)})", closest=result.result)
            save_output(result, output, overwrite=overwrite)
    return result


__all__ = [
    "scale_mesh", "run", "prepare", "label", "scale", "save_output", "save_picture", "Run",
    "RulesetScaling", "GlobalScaling", "LocalScaling", "RawGlobalScaling",
    "Body", "Frame", "Labelling", "UNLABELLED", "PreparedMesh", "prepare_mesh", "generate_quadruped",
    "HarmonicBasis", "compute_basis", "spectrum_fit",
    "body_mass", "region_mass", "region_length", "region_girth", "peak_stress", "SectionChoice",
    "Ruleset", "Rule", "SegmenterUse", "load_ruleset", "list_rulesets", "PluginRegistry", "registry_for",
    "RunProgress",
    "AllorulesError", "MeshError", "OutputError", "BasisError", "SegmentationError", "MeasurementError", "PluginError",
    "RulesetError", "ScalingError",
]
