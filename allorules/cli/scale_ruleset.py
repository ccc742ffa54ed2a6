"""The biology-aware half of ``allorules scale``: ``--ruleset`` runs and ``--region`` local scaling.

Not a sub-command of its own: ``allorules/cli/scale.py`` (global scaling) adds these options with
:func:`add_arguments` and hands over to :func:`run` when :func:`wanted` says so.

* ``allorules scale MESH --ruleset quadruped --mass-ratio 2 -o OUT.obj [--report R.json]
  [--rule neck-length=0.45] [--segmentation LABELS.json] [--keep-unconverged]``
* ``allorules scale MESH --region head --alpha 0.3 -o OUT.obj`` — local power law (Eq. 5–7);
  ``--arithmetic F`` scales the region's vertices by F instead (the paper's bad example, for
  comparison only: it tears the region's boundary).

A run that misses a target (beyond the tolerances in :mod:`allorules.biology_scaling`) exits
non-zero and writes NO mesh, only the report (``converged: false``) — unless ``--keep-unconverged``,
which writes the mesh as ``OUT.unconverged.EXT`` with a warning, never under the name asked for.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..errors import AllorulesError, MeshError, ScalingError, SegmentationError

log = logging.getLogger("allorules")

# Loading, labelling, output checks and writing are shared with global scaling.
from .scale import labelled_body, output_path, save_scaled, write_report  # noqa: E402


def _has(parser: argparse.ArgumentParser, option: str) -> bool:
    return option in parser._option_string_actions


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ruleset / local-scaling options to the ``scale`` parser (skipping any it already has)."""
    from ..plugins import add_plugin_argument
    from .segment import add_direction_arguments

    options = [
        ("--ruleset", dict(metavar="NAME|FILE", help="biology-aware scaling with this ruleset (a name or a .yaml path)")),
        ("--rule", dict(action="append", default=[], metavar="ID=EXPONENT",
                        help="override one rule's exponent, e.g. --rule neck-length=0.45 (repeatable)")),
        ("--segmentation", dict(metavar="FILE", help="labels file (.json or Princeton .seg); automatic labelling when not given")),
        ("--region", dict(metavar="NAME", help="local scaling of one region (Eq. 5-7) with --alpha")),
        ("--alpha", dict(type=float, metavar="A", help="with --region: the local exponent (α > 0 shrinks the region, α < 0 grows it)")),
        ("--arithmetic", dict(type=float, metavar="F", help="with --region: scale the region's vertices by F instead "
                                                             "(the paper's arithmetic variant, for comparison only: it tears seams)")),
        ("--transform", dict(choices=("per-mode", "per-axis"), help="how the power law acts on the coefficients: "
                             "per-axis (default; METHOD §5, in the animal's own axes) or per-mode (on each mode's vector "
                             "length); overrides the ruleset's solver.transform")),
        ("--posture", dict(choices=("keep", "upright", "free"), help="the stance through the steps: keep (default; legs "
                           "upright, feet on the ground, legs' lines kept), upright (legs turned upright only) or free "
                           "(as Eq. 9 leaves them); "
                           "overrides the ruleset's solver.posture")),
        ("--mass-ratio", dict(type=float, metavar="R", help="total body-mass ratio (2 doubles the mass)")),
        ("-o", dict(dest="output", metavar="OUT", help="output mesh (format from the extension)")),
        ("--report", dict(metavar="REPORT.json", help="write the run's report as JSON")),
        ("--modes", dict(type=int, metavar="M", help="harmonic basis size (default 1000)")),
        ("--keep-unconverged", dict(action="store_true", help="write the mesh of a run that missed its targets, as OUT.unconverged.EXT")),
        ("--force", dict(action="store_true", help="overwrite existing output files")),
    ]
    for option, keywords in options:
        if not _has(parser, option):
            parser.add_argument(option, **keywords)
    if not _has(parser, "--up"):
        add_direction_arguments(parser)
    if not _has(parser, "--plugin"):
        add_plugin_argument(parser)


def wanted(arguments: argparse.Namespace) -> bool:
    """Whether these options, not global scaling, should handle the command."""
    return bool(getattr(arguments, "ruleset", None) or getattr(arguments, "region", None))


def format_table(result) -> str:
    """The run as the terminal shows it: one row per rule, then the body-wide figures."""
    rows = [("rule", "region", "measure", "target", "achieved", "error")]
    for rule in result.rules:
        rows.append((rule.id, rule.region or "-", rule.measure, f"{rule.exponent:.3f}", f"{rule.achieved_exponent:.3f}",
                     f"{rule.error:+.3f}"))
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
        lines.append(f"legs lean by up to {tilt:.1f}°, a foot rose {100 * lift:.1f}% of a leg's length, bow added up to "
                     f"{100 * bend:+.1f}% of a leg's length (not rules; see the report's posture)")
    return "\n".join(lines)


def run(arguments: argparse.Namespace) -> int:
    from ..preparation import prepare_mesh

    mesh = Path(arguments.mesh)
    if arguments.ruleset and arguments.region:
        raise AllorulesError("give either --ruleset (biology-aware run) or --region with --alpha (local scaling), not both")
    output = output_path(arguments)
    if arguments.region:
        if arguments.alpha is None and arguments.arithmetic is None:
            raise ScalingError("--region needs --alpha A (local power law) or --arithmetic F (comparison only)")
    else:
        if arguments.mass_ratio is None:
            raise ScalingError("--ruleset needs --mass-ratio R (2 doubles the mass, 0.5 halves it)")
        from ..global_scaling import check_mass_ratio

        check_mass_ratio(arguments.mass_ratio)
    prepared = prepare_mesh(mesh)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    body = labelled_body(arguments, prepared)
    if arguments.region:
        return _run_local(arguments, prepared, body, mesh, output)
    return _run_ruleset(arguments, prepared, body, mesh, output)


def _run_local(arguments, prepared, body, mesh: Path, output: Path) -> int:
    from ..biology_scaling import scale_region, seam_strain

    if arguments.region not in body.region_names:
        raise SegmentationError(f"no region {arguments.region!r}; the body has {', '.join(body.region_names)}")
    alpha = 0.0 if arguments.alpha is None else float(arguments.alpha)
    if arguments.arithmetic is not None:
        log.warning("--arithmetic: the paper's bad example, for comparison only; the region's boundary will tear")
    scaled = scale_region(body, arguments.region, alpha, modes=arguments.modes, arithmetic_factor=arguments.arithmetic,
                          use_cache=not getattr(arguments, "no_cache", False), form=arguments.transform or "per-axis")
    from ..global_scaling import count_flipped_faces

    seam = seam_strain(body.vertices, scaled.vertices, body.faces, body.region_mask(arguments.region))
    flipped = count_flipped_faces(body.vertices, scaled.vertices, body.faces)
    save_scaled(output, prepared, body, scaled.vertices, arguments)
    report = {"mode": "arithmetic" if arguments.arithmetic is not None else "local", "region": arguments.region,
              "transform": arguments.transform or "per-axis", "alpha": alpha, "arithmetic_factor": arguments.arithmetic, "seam": seam, "flipped_faces": flipped,
              "output": str(output)}
    if arguments.report:
        write_report(arguments.report, report)
    print(f"{output}: region {arguments.region} "
          f"{'×' + format(arguments.arithmetic, 'g') + ' (arithmetic)' if arguments.arithmetic is not None else 'α = ' + format(alpha, 'g')}; "
          f"seam {seam['seam']:.3g} (edge strain across its boundary over the strain on either side; about 1 is seamless), "
          f"{flipped} flipped faces")
    return 0


def _run_ruleset(arguments, prepared, body, mesh: Path, output: Path) -> int:
    from ..biology_scaling import scale_with_ruleset
    from ..plugins import registry_for
    from ..progress import run_progress
    from ..rules import load_ruleset, override_exponents, parse_rule_overrides

    registry = registry_for(arguments)
    ruleset = load_ruleset(arguments.ruleset, registry)
    ruleset = override_exponents(ruleset, parse_rule_overrides(arguments.rule or []), registry)
    if arguments.transform or arguments.posture:
        from dataclasses import replace

        ruleset = replace(ruleset, solver=replace(ruleset.solver, transform=arguments.transform or ruleset.solver.transform,
                                                  posture=arguments.posture or ruleset.solver.posture))
    progress = run_progress("scaling steps")
    section = None
    if getattr(arguments, "section", None):
        from .scale import _section_choice   # the --section option belongs to the scale command

        section = _section_choice(arguments.section)
    try:
        result = scale_with_ruleset(body, ruleset, arguments.mass_ratio, registry=registry, modes=arguments.modes,
                                    section=section, use_cache=not getattr(arguments, "no_cache", False),
                                    progress=progress)
    except ScalingError as error:
        if arguments.report and error.closest is not None:
            write_report(arguments.report, error.closest.as_dict())
        raise
    report = result.as_dict()
    report["input"] = str(mesh)
    report["rule_overrides"] = parse_rule_overrides(arguments.rule or [])
    written = None
    if result.converged:
        written = output
    elif arguments.keep_unconverged:
        written = output.with_name(f"{output.stem}.unconverged{output.suffix}")
        if written.exists() and not arguments.force:
            raise MeshError(f"{written}: already exists; use --force to overwrite it")
    if written is not None:
        save_scaled(written, prepared, body, result.body.vertices, arguments)
    report["output"] = None if written is None else str(written)
    if arguments.report:
        write_report(arguments.report, report)
    print(format_table(result))
    if not result.converged:
        for message in result.messages:
            log.warning("%s", message)
        where = f"the mesh was written to {written} (NOT the requested {output})" if written else \
            f"no mesh written (use --keep-unconverged to write it as {output.stem}.unconverged{output.suffix})"
        raise ScalingError(f"ruleset {ruleset.name!r} did not reach its targets at mass ratio "
                           f"{arguments.mass_ratio:g}: {result.messages[0]}; {where}")
    print(f"wrote {written}")
    return 0
