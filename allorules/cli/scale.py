"""``allorules scale``: scale a mesh, globally, with a ruleset, or one region locally.

* ``allorules scale MESH --ruleset quadruped --mass-ratio 2 -o OUT.obj [--report R.json]
  [--rule neck-length=0.45] [--segmentation LABELS.json] [--keep-unconverged]`` — biology-aware
  scaling (docs/biology-scaling.md); ``--mass-ratio R`` with no kind chosen means ``--ruleset quadruped``.
* ``allorules scale MESH --global --mass-ratio R -o OUT`` — one α for the whole body, the mass
  changed by R at unchanged peak limb stress; ``--global --alpha A [--scale S]`` applies the
  power law once with the user's α.
* ``allorules scale MESH --region head --alpha 0.3 -o OUT`` — the local power law on one region;
  ``--arithmetic F`` scales the region's vertices by F instead (for comparison only: it tears).

Every kind goes through :mod:`allorules.runs.pipeline`. Output paths are checked before any work.
A mesh written with regions has them beside it as ``OUT.labels.json`` (the run's regions on the
output's vertices, with the run's axes): ``allorules measure OUT.obj`` reads them, so the output is
measured with the regions the run measured; the input's own ``MESH.labels.json`` is read likewise
(``--relabel`` labels afresh).
A run that misses a target exits non-zero and writes NO mesh, only the report (``converged:
false``), unless ``--keep-unconverged``, which writes the mesh as ``OUT.unconverged.EXT`` with a
warning, never under the name asked for.
"""
from __future__ import annotations

import argparse
import logging
import math
from dataclasses import replace
from pathlib import Path

from allorules.cli.arguments import (
    add_direction_arguments,
    add_plugin_argument,
    add_png_argument,
    add_relabel_argument,
    add_working_vertices_argument,
    labels_beside_input,
    plugin_files,
)
from allorules.errors import AllorulesError, ScalingError

log = logging.getLogger("allorules")
DEFAULT_RULESET = "quadruped"   # what --mass-ratio R alone scales with


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "scale",
        help=command_help("scale"),
        description="Biology-aware scaling with --ruleset NAME --mass-ratio R (--mass-ratio R alone: the "
        f"{DEFAULT_RULESET} ruleset): the ruleset's allometric rules "
        "(leg length, chest girth, head and abdominal mass against body mass) and its limit on limb stress are "
        "met (docs/biology-scaling.md, docs/rulesets.md). --global: one exponent α for the whole body (--mass-ratio "
        "R keeps the peak limb stress; --alpha A [--scale S] applies the power law once: α > 0 amplifies fine "
        "features, α < 0 damps them; docs/method.md). --region NAME --alpha A: one region only. Outputs are "
        "described in docs/outputs.md.",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    kind = parser.add_argument_group("what to do (one of)")
    kind.add_argument("--ruleset", metavar="NAME|FILE",
                      help=f"biology-aware scaling with this ruleset (a name or a .yaml path; default {DEFAULT_RULESET} "
                      "when only --mass-ratio is given)")
    kind.add_argument("--global", dest="global_scaling", action="store_true",
                      help="global allometric scaling (one α for the whole body)")
    kind.add_argument("--region", metavar="NAME", help="local scaling of one region, with --alpha")
    parser.add_argument("--mass-ratio", type=float, metavar="R", help="total body-mass ratio (2 doubles the mass, 0.5 halves it)")
    parser.add_argument("--alpha", type=float, metavar="A",
                        help="with --global: apply the power law with this α directly (no stress constraint); with "
                        "--region: the local exponent (α > 0 shrinks the region, α < 0 grows it)")
    parser.add_argument("--scale", type=float, metavar="S", help="with --global --alpha: the isometric factor s (default 1)")
    parser.add_argument("--arithmetic", type=float, metavar="F", help="with --region: scale the region's vertices by F "
                        "instead (the paper's arithmetic variant, for comparison only: it tears seams)")
    parser.add_argument("--rule", action="append", default=[], metavar="ID=EXPONENT",
                        help="override one rule's exponent, e.g. --rule neck-length=0.45 (repeatable)")
    parser.add_argument("--transform", choices=("per-mode", "per-axis"),
                        help="how the power law acts on the coefficients: per-axis (default, in the animal's own axes) "
                        "or per-mode (on each mode's vector length); overrides the ruleset's solver.transform")
    parser.add_argument("--posture", choices=("keep", "upright", "free"),
                        help="the stance through the steps: keep (default; legs upright, feet on the ground, legs' lines "
                        "kept), upright (legs turned upright only) or free; overrides the ruleset's solver.posture")
    parser.add_argument("--placement", choices=("ground", "centroid"), default="ground",
                        help="where the output stands: ground (default: its feet on the input's ground plane at the "
                        "same place) or centroid (its centroid where the input's was)")
    parser.add_argument("-o", "--output", metavar="OUT.obj",
                        help="output mesh; the format follows the extension (.obj .ply .stl .glb .off)")
    parser.add_argument("--report", metavar="REPORT.json", help="write the run's report as JSON (also when it fails)")
    add_png_argument(parser, "the input and the output side by side, at true scale (also when the run misses its targets)")
    parser.add_argument("--modes", type=int, metavar="M", help="harmonic basis size (default 1000, at most vertices − 1)")
    add_working_vertices_argument(parser)
    parser.add_argument("--section", metavar="REGION:FRACTION[:PART]",
                        help="load-bearing section for the stress, e.g. forelimbs:0.5 (default: the smallest limb "
                        "section away from junction and tip)")
    parser.add_argument("--segmentation", metavar="FILE",
                        help="labels file (.json or Princeton .seg) instead of the ruleset's segmenter")
    add_relabel_argument(parser)
    parser.add_argument("--keep-unconverged", action="store_true",
                        help="write the mesh of a run that missed its targets, as OUT.unconverged.EXT")
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files (never an input of the command: mesh, labels, ruleset, plugin)")
    parser.add_argument("--no-cache", action="store_true", help="do not read or write the basis cache")
    add_direction_arguments(parser)
    add_plugin_argument(parser)
    parser.set_defaults(run=run)


# ---------------------------------------------------------------------------------------------
# Checking the command line before any work


def _scaling(arguments: argparse.Namespace, registry):
    """The pipeline's kind of scaling for these options (every option combination checked)."""
    from allorules.runs.pipeline import (
        GlobalScaling,
        LocalScaling,
        RawGlobalScaling,
        RulesetScaling,
    )
    from allorules.runs.steps import check_mass_ratio

    chosen = [name for name, given in (("--ruleset", arguments.ruleset), ("--global", arguments.global_scaling),
                                       ("--region", arguments.region)) if given]
    if not chosen and arguments.mass_ratio is not None and arguments.alpha is None and arguments.arithmetic is None:
        # a mesh and a mass ratio: what the tool is for, biology-aware with the quadruped ruleset
        arguments.ruleset, chosen = DEFAULT_RULESET, ["--ruleset"]
        log.info("biology-aware scaling with the %s ruleset (--ruleset NAME for another, --global for one exponent)",
                 DEFAULT_RULESET)
    if len(chosen) != 1:
        raise AllorulesError("choose the kind of scaling: --ruleset NAME (biology-aware), --global (with --mass-ratio R or --alpha A), or --region NAME"
                             + (f" (got {' and '.join(chosen)})" if chosen else ""))
    if arguments.modes is not None and arguments.modes < 2:
        raise AllorulesError(f"--modes must be at least 2, got {arguments.modes}")
    section = _section_choice(arguments.section)
    if arguments.region:
        if arguments.alpha is None and arguments.arithmetic is None:
            raise ScalingError("--region needs --alpha A (local power law) or --arithmetic F (comparison only)")
        if arguments.alpha is not None and not math.isfinite(arguments.alpha):
            raise ScalingError(f"--alpha must be a finite number, got {arguments.alpha}")
        return LocalScaling(arguments.region, 0.0 if arguments.alpha is None else float(arguments.alpha),
                            arguments.arithmetic, arguments.transform or "per-axis")
    if arguments.global_scaling:
        if (arguments.mass_ratio is None) == (arguments.alpha is None):
            raise AllorulesError("--global needs exactly one of --mass-ratio R (stress kept) or --alpha A (the power law once)")
        if arguments.mass_ratio is not None:
            if arguments.scale is not None:
                raise AllorulesError("--scale goes with --alpha; with --mass-ratio the isometric factor is solved for")
            return GlobalScaling(check_mass_ratio(arguments.mass_ratio), section)
        if not math.isfinite(arguments.alpha):
            raise ScalingError(f"--alpha must be a finite number, got {arguments.alpha}")
        if arguments.scale is not None and not (math.isfinite(arguments.scale) and arguments.scale > 0):
            raise ScalingError(f"--scale must be a positive number, got {arguments.scale}")
        return RawGlobalScaling(float(arguments.alpha), 1.0 if arguments.scale is None else float(arguments.scale))
    if arguments.mass_ratio is None:
        raise ScalingError("--ruleset needs --mass-ratio R (2 doubles the mass, 0.5 halves it)")
    check_mass_ratio(arguments.mass_ratio)
    from allorules.rules.overrides import override_exponents, parse_rule_overrides
    from allorules.rules.resolve import load_ruleset

    ruleset = load_ruleset(arguments.ruleset, registry)
    ruleset = override_exponents(ruleset, parse_rule_overrides(arguments.rule or []), registry)
    if arguments.transform or arguments.posture:
        ruleset = replace(ruleset, solver=replace(ruleset.solver, transform=arguments.transform or ruleset.solver.transform,
                                                  posture=arguments.posture or ruleset.solver.posture))
    return RulesetScaling(ruleset, arguments.mass_ratio, section)


def _section_choice(text: str | None):
    if not text:
        return None
    from allorules.measure.stress import SectionChoice

    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        fraction = float(parts[1])
        part = int(parts[2]) if len(parts) == 3 else None
    except ValueError:
        raise AllorulesError(f"--section {text!r}: write REGION:FRACTION[:PART], e.g. forelimbs:0.5 or hindlimbs:0.4:1") from None
    if not 0.0 <= fraction <= 1.0:
        raise AllorulesError(f"--section fraction must be between 0 (junction) and 1 (tip), got {fraction:g}")
    return SectionChoice(parts[0], fraction, part)


def output_path(arguments: argparse.Namespace, scaling=None, registry=None) -> Path:
    """The output mesh, checked with every other output (picture, report, the unconverged name, the
    labels file beside each mesh) against every input of the command (allorules.files.check_outputs), before any work."""
    from allorules.files import JSON, PNG, Output, check_outputs, unconverged_path
    from allorules.output.export import SUPPORTED_FORMATS
    from allorules.runs.pipeline import RawGlobalScaling
    from allorules.segment.labels_io import labels_file_beside

    if not arguments.output:
        raise AllorulesError("give the output mesh with -o OUT (e.g. -o heavier.obj)")
    output = Path(arguments.output)
    outputs = [Output.of(output, "-o", SUPPORTED_FORMATS), Output.of(arguments.png, "--png", PNG),
               Output.of(arguments.report, "--report", JSON)]
    if arguments.keep_unconverged:
        outputs.append(Output.of(unconverged_path(output),
                                 "--keep-unconverged", SUPPORTED_FORMATS))
    if not isinstance(scaling, RawGlobalScaling) or arguments.segmentation:
        # the regions of a run that has them go beside its mesh (pipeline.save_output)
        outputs += [Output.of(labels_file_beside(mesh.path), f"the labels file beside {mesh.option}", JSON)
                    for mesh in list(outputs) if mesh is not None and mesh.option in ("-o", "--keep-unconverged")]
    check_outputs(outputs, command_inputs(arguments, scaling, registry), force=arguments.force)
    return output


def command_inputs(arguments: argparse.Namespace, scaling=None, registry=None) -> dict:
    """Every file the command reads, by what it is (protected from its outputs)."""
    ruleset = getattr(scaling, "ruleset", None)
    inputs = {"input mesh": arguments.mesh, "labels file": arguments.segmentation,
              "input's labels file": labels_beside_input(arguments)}
    if ruleset is not None:
        inputs["ruleset"] = ruleset.path
        inputs["segmenter's file"] = [value for value in ruleset.segmenter.options.values() if isinstance(value, Path)]
    inputs["plugin"] = plugin_files(registry, arguments)
    return inputs


def write_report(path: str | None, report: dict) -> None:
    if not path:
        return
    from allorules.files import write_json

    write_json(path, report)
    log.info("wrote %s", path)


# ---------------------------------------------------------------------------------------------
# The run


def run(arguments: argparse.Namespace) -> int:
    from allorules.files import unconverged_path
    from allorules.plugins.registry import registry_for
    from allorules.runs import pipeline
    from allorules.runs.progress import run_progress

    registry = registry_for(arguments)
    scaling = _scaling(arguments, registry)
    output = output_path(arguments, scaling, registry)
    if arguments.plugins and not isinstance(scaling, pipeline.RulesetScaling):
        log.warning("--plugin: not used by %s scaling (plugins provide a ruleset's measures, constraints and "
                    "segmenter); use --ruleset to use them", "region" if arguments.region else "global")
    try:
        result_run = pipeline.run(arguments.mesh, scaling, registry=registry, labels=arguments.segmentation or None,
                                  up=arguments.up, forward=arguments.forward, modes=arguments.modes,
                                  use_cache=not arguments.no_cache, progress=run_progress("scaling steps"),
                                  placement=arguments.placement, working_vertices=arguments.working_vertices,
                                  labels_beside=not arguments.relabel)
    except ScalingError as error:
        _keep_what_a_stopped_run_reached(arguments, output, error)
        raise
    report = result_run.report()
    report["output"] = str(output)
    if isinstance(scaling, pipeline.RulesetScaling):
        from allorules.rules.overrides import parse_rule_overrides

        report["rule_overrides"] = parse_rule_overrides(arguments.rule or [])
    if isinstance(scaling, pipeline.LocalScaling) and scaling.arithmetic_factor is not None:
        log.warning("--arithmetic: the paper's bad example, for comparison only; the region's boundary tears")

    written = output if result_run.converged else None
    if not result_run.converged and arguments.keep_unconverged:
        written = unconverged_path(output)   # checked before the run
    if written is not None:
        pipeline.save_output(result_run, written, overwrite=arguments.force)
    if arguments.png:   # also for a run that missed: there must be something to look at
        pipeline.save_picture(result_run, arguments.png,
                              output_name=written.name if written else f"{output.name} (NOT converged, not written)")
        log.info("wrote %s", arguments.png)
    report["output"] = None if written is None else str(written)
    write_report(arguments.report, report)
    print(summary(scaling, result_run.result, report, written or output))
    print(result_run.quality().summary())
    if not result_run.converged:
        for message in result_run.result.messages[1:]:   # the first one is the error line's
            log.warning("%s", message)
        where = f"the mesh was written to {written} (NOT the requested {output})" if written else \
            f"no mesh written (use --keep-unconverged to write it as {unconverged_path(output).name})"
        raise ScalingError(f"{result_run.missed()}; {where}" + coarser_working_hint(result_run.working))
    if written is not None and hasattr(scaling, "ruleset"):
        print(f"wrote {written}")
    return 0


def coarser_working_hint(working) -> str:
    """For a run that missed: the other working meshes it was made again on (coarser ones, or a
    coarse body split finer), and missed on too (:func:`allorules.runs.pipeline.run` tries them
    where the default working mesh misses)."""
    tried = () if working is None else working.also_tried
    if not tried:
        return ""
    return ("; made again on other working meshes, it missed there too ("
            + "; ".join(f"{other.vertices:,} vertices: {other.missed}" for other in tried) + ")")


def _keep_what_a_stopped_run_reached(arguments: argparse.Namespace, output: Path, error: ScalingError) -> None:
    """A run a step stopped still leaves what there is to look at (issue 18 §4): its report, its
    picture, and with --keep-unconverged the mesh it reached, under the .unconverged name."""
    from allorules.files import unconverged_path
    from allorules.runs import pipeline

    stopped = error.run       # the run as far as it went (pipeline.run), where a step stopped it
    kept = unconverged_path(output) if stopped is not None and arguments.keep_unconverged else None
    if kept is not None:
        pipeline.save_output(stopped, kept, overwrite=arguments.force)
        log.warning("the run stopped; the mesh it reached was written to %s (NOT the requested %s)", kept, output)
    if arguments.png and stopped is not None:
        pipeline.save_picture(stopped, arguments.png, output_name=kept.name if kept else f"{output.name} (stopped)")
        log.info("wrote %s", arguments.png)
    if arguments.report:
        if stopped is not None:
            report = stopped.report()
        elif hasattr(error.closest, "as_dict") and hasattr(error.closest, "body"):
            report = error.closest.as_dict()
        else:
            report = {"converged": False}
        write_report(arguments.report, {"input": str(arguments.mesh), **report, "error": str(error),
                                        "output": None if kept is None else str(kept)})


# ---------------------------------------------------------------------------------------------
# What the terminal shows


def summary(scaling, result, report: dict, output: Path) -> str:
    from allorules.runs.pipeline import GlobalScaling, LocalScaling, RawGlobalScaling

    if isinstance(scaling, RawGlobalScaling):
        return (f"{output}: α = {scaling.alpha:g}, s = {scaling.scale:g}: mass ×{report['mass_ratio']:.4f}, "
                f"{report['flipped_faces']} flipped faces")
    if isinstance(scaling, LocalScaling):
        what = (f"×{scaling.arithmetic_factor:g} (arithmetic)" if scaling.arithmetic_factor is not None
                else f"α = {scaling.alpha:g}")
        return (f"{output}: region {scaling.region} {what}; seam {report['seam']['seam']:.3g} (edge strain across its "
                f"boundary over the strain on either side; about 1 is seamless), {report['flipped_faces']} flipped faces")
    if isinstance(scaling, GlobalScaling):
        return global_summary(output, report)
    return format_table(result)


def format_table(result) -> str:
    """A ruleset run as the terminal shows it: one row per rule, then the body-wide figures."""
    from allorules.runs.results import EXPONENT_TOLERANCE

    rows = [("rule", "region", "measure", "target exponent", "achieved exponent", "exponent error",
             f"met (±{EXPONENT_TOLERANCE:g})")]
    for rule in result.rules:
        rows.append((rule.id, rule.region or "-", rule.measure, f"{rule.exponent:.3f}", f"{rule.achieved_exponent:.3f}",
                     f"{rule.error:+.3f}", "yes" if abs(rule.error) <= EXPONENT_TOLERANCE else "NO"))
    widths = [max(len(row[k]) for row in rows) for k in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * width for width in widths))
    stress = "n/a" if result.stress_ratio is None else f"{result.stress_ratio:.4f}"
    lines.append("")
    lines.append(f"mass ratio {result.mass_ratio:.4f} (target {result.target_mass_ratio:g}), stress ratio {stress}, "
                 f"{len(result.steps)} steps, {result.flipped_faces} flipped faces, "
                 f"{'converged' if result.converged else 'NOT converged'}")
    for key, value in result.constraints.items():
        lines.append(f"constraint {key}: residual {value:+.4f}")
    if result.posture:
        tilt = max(change["tilt_degrees"] for change in result.posture.values())
        lift = max(change["foot_lift"] for change in result.posture.values())
        bend = max(change["bend"] for change in result.posture.values())
        spread = max(change.get("girth_spread", 0.0) for change in result.posture.values())
        shape = max(change.get("shape_change", 0.0) for change in result.posture.values())
        fold = max(change.get("fold_degrees", 0.0) for change in result.posture.values())
        lines.append(f"legs lean by up to {tilt:.1f}°, a foot rose {100 * lift:.1f}% of a leg's length, bow added up to "
                     f"{100 * bend:+.1f}% of a leg's length, a leg's fold opened or closed by up to {fold:.1f}°, girth "
                     f"changed unevenly along a leg by up to {100 * spread:.0f}%, a leg's shape changed by up to "
                     f"{100 * shape:.0f}% of its size beyond a stretch (not rules; see the report's posture)")
    if result.open_regions:
        lines.append(open_regions_line(result.open_regions))
    return "\n".join(lines)


def open_regions_line(outcomes) -> str:
    """What the regions no rule measures reached, one line: each open region's exponents (length,
    mass, ...) against isometric, ``NO`` after a region held isometric that strayed beyond the
    tolerance (or could not be measured), ``-`` for a measure that could not be measured."""
    measures = list(dict.fromkeys(outcome.measure for outcome in outcomes))
    isometric = {outcome.measure: outcome.isometric_exponent for outcome in outcomes}
    tolerance = max(outcome.tolerance for outcome in outcomes)
    parts = []
    for region in dict.fromkeys(outcome.region for outcome in outcomes):
        mine = {outcome.measure: outcome for outcome in outcomes if outcome.region == region}
        values = " / ".join("-" if name not in mine or mine[name].achieved_exponent is None
                            else f"{mine[name].achieved_exponent:.3f}" for name in measures)
        parts.append(f"{region} {values}" + ("" if all(outcome.met for outcome in mine.values()) else " NO"))
    return (f"open regions, {' / '.join(measures)} exponents (isometric "
            f"{' / '.join(f'{isometric[name]:.3f}' for name in measures)}; NO: held isometric and beyond "
            f"±{tolerance:g}): " + ", ".join(parts))


def global_summary(output: Path, report: dict) -> str:
    """The terminal's few lines about a global run."""
    alphas, scales = report["alphas"], report["scales"]
    span = (lambda values: f"{min(values):.4g}…{max(values):.4g}" if len(values) > 1 else f"{values[0]:.4g}") if alphas else None
    reselected = report.get("stress_ratio_reselected")
    lines = [
        f"{output}: mass ×{report['mass_ratio']:.4f} (target {report['target_mass_ratio']:g}), "
        f"stress ×{report['stress_ratio']:.4f}"
        + (f" (×{reselected:.4f} at a section re-chosen on the output)" if reselected is not None else ""),
        f"{report['steps']} step(s)" + (f", α {span(alphas)}, s {span(scales)}" if alphas else "")
        + f", {report['flipped_faces']} of {report['faces']} faces flipped, "
        + ("converged" if report["converged"] else "NOT converged"),
    ]
    return "\n".join(lines)
