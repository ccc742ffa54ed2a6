"""``allorules scale``: scale a mesh (global allometric scaling here; biology-aware elsewhere).

* ``allorules scale MESH --global --mass-ratio R -o OUT [--report REPORT.json]``: find α and s of
  Eq. 4 step by step so that the mass changes by R at unchanged peak stress (METHOD §4).
* ``allorules scale MESH --global --alpha A [--scale S] -o OUT``: Eq. 4 once, with the user's α, s.

The biology-aware options (``--ruleset``, ``--region``, …) are added to the same parser by
:mod:`allorules.cli.scale_ruleset` and handled there: :func:`run` hands over when that module's
``wanted(arguments)`` says so. Nothing is written unless the run succeeded: a failed run exits
non-zero with one line saying why (and the closest result reached), and writes only the report.
"""
from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

from ..errors import AllorulesError, MeshError, ScalingError

log = logging.getLogger("allorules")


def _ruleset_module():
    try:
        from . import scale_ruleset
    except ImportError:  # pragma: no cover - the biology-aware half is optional
        return None
    return scale_ruleset


def register(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "scale",
        help="scale a mesh allometrically (--global, or --ruleset for biology-aware scaling)",
        description="Global allometric scaling (paper Eq. 4): with --mass-ratio R the mass changes by R and "
        "the peak stress in the legs stays as it was (heavier animals get relatively thicker legs); with "
        "--alpha A [--scale S] the spectrum is scaled by (λ_i/λ_1)^A once. α > 0 amplifies fine features "
        "(limbs thicken relative to the body), α < 0 damps them.",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    parser.add_argument("--global", dest="global_scaling", action="store_true",
                        help="global allometric scaling (one α for the whole body)")
    parser.add_argument("--mass-ratio", type=float, metavar="R", help="total body-mass ratio (2 doubles the mass, 0.5 halves it)")
    parser.add_argument("--alpha", type=float, metavar="A",
                        help="with --global: apply Eq. 4 with this α directly (no stress constraint)")
    parser.add_argument("--scale", type=float, metavar="S", help="with --alpha: the isometric factor s (default 1)")
    parser.add_argument("-o", dest="output", metavar="OUT", help="output mesh (format from the extension)")
    parser.add_argument("--report", metavar="REPORT.json", help="write the run's report as JSON (also when it fails)")
    parser.add_argument("--png", metavar="FILE.png", help="picture of the input and the output side by side, at true scale")
    parser.add_argument("--modes", type=int, metavar="M", help="harmonic basis size (default 1000, at most vertices − 1)")
    parser.add_argument("--section", metavar="REGION:FRACTION[:PART]",
                        help="load-bearing section for the stress, e.g. forelimbs:0.5 (default: the smallest limb "
                        "section away from junction and tip)")
    parser.add_argument("--segmentation", metavar="FILE", help="labels file (.json or Princeton .seg); automatic labelling when not given")
    parser.add_argument("--force", action="store_true", help="overwrite existing output files (never the input)")
    parser.add_argument("--no-cache", action="store_true", help="do not read or write the basis cache")
    ruleset = _ruleset_module()
    if ruleset is not None:
        ruleset.add_arguments(parser)
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    ruleset = _ruleset_module()
    if ruleset is not None and ruleset.wanted(arguments):
        if arguments.global_scaling:
            raise AllorulesError("--global cannot be combined with --ruleset or --region; choose one kind of scaling")
        return ruleset.run(arguments)
    if not arguments.global_scaling:
        raise AllorulesError("choose the kind of scaling: --global (with --mass-ratio R or --alpha A), or --ruleset NAME")
    return run_global(arguments)


# ---------------------------------------------------------------------------------------------
# Global scaling


def _check_arguments(arguments: argparse.Namespace) -> None:
    from ..global_scaling import check_mass_ratio

    if (arguments.mass_ratio is None) == (arguments.alpha is None):
        raise AllorulesError("--global needs exactly one of --mass-ratio R (stress kept) or --alpha A (raw Eq. 4)")
    if arguments.mass_ratio is not None:
        check_mass_ratio(arguments.mass_ratio)
        if arguments.scale is not None:
            raise AllorulesError("--scale goes with --alpha; with --mass-ratio the isometric factor is solved for")
    else:
        if not math.isfinite(arguments.alpha):
            raise ScalingError(f"--alpha must be a finite number, got {arguments.alpha}")
        if arguments.scale is not None and not (math.isfinite(arguments.scale) and arguments.scale > 0):
            raise ScalingError(f"--scale must be a positive number, got {arguments.scale}")
    if arguments.modes is not None and arguments.modes < 2:
        raise AllorulesError(f"--modes must be at least 2, got {arguments.modes}")


def output_path(arguments: argparse.Namespace) -> Path:
    mesh = Path(arguments.mesh)
    if not arguments.output:
        raise AllorulesError("give the output mesh with -o OUT (e.g. -o heavier.obj)")
    output = Path(arguments.output)
    if mesh.exists() and output.exists() and output.resolve() == mesh.resolve():
        raise MeshError(f"{output}: refusing to overwrite the input mesh; choose another output name")
    if output.exists() and not arguments.force:
        raise MeshError(f"{output}: already exists; use --force to overwrite it")
    if not output.parent.exists():
        raise MeshError(f"{output.parent}: folder does not exist")
    if arguments.report:
        report = Path(arguments.report)
        if report.exists() and not arguments.force:
            raise MeshError(f"{report}: already exists; use --force to overwrite it")
        if report.resolve() in (output.resolve(), mesh.resolve()):
            raise MeshError(f"{report}: the report must not be the input or the output mesh")
    return output


def _section_choice(text: str | None):
    if not text:
        return None
    from ..measures import SectionChoice

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


def labelled_body(arguments: argparse.Namespace, prepared):
    """The prepared body with regions from ``--segmentation`` or the automatic labeller."""
    from ..body import Body
    from ..segmentation import labelled_body as with_regions

    return with_regions(Body(prepared.vertices, prepared.faces), arguments.segmentation or None,
                        up=getattr(arguments, "up", None), forward=getattr(arguments, "forward", None))


def save_scaled(output: Path, prepared, body, vertices, arguments: argparse.Namespace) -> None:
    """Write the scaled body in the input's own layout (UVs, materials, detached parts kept), say
    what the export could not carry over, and draw ``--png`` if asked."""
    import numpy as np

    from ..export import save_mesh

    if getattr(prepared, "source", None) is not None:
        result = save_mesh(output, prepared.source_positions(vertices), np.asarray(prepared.source.faces),
                           source=prepared.source, input_path=arguments.mesh, overwrite=arguments.force)
    else:
        result = save_mesh(output, vertices, prepared.faces, input_path=arguments.mesh, overwrite=arguments.force)
    for note in getattr(result, "notes", []) or []:
        log.info("export: %s", note)
    if getattr(arguments, "png", None):
        from ..render import render_comparison

        render_comparison([(body.vertices, body.faces, "input"), (vertices, body.faces, output.name)],
                          path=arguments.png, normalise_size=False, frame=body.frame)
        log.info("wrote %s", arguments.png)


def write_report(path: str | None, report: dict) -> None:
    if not path:
        return
    from ..export import write_json

    write_json(path, report)
    log.info("wrote %s", path)


def run_global(arguments: argparse.Namespace) -> int:
    from ..body import Body
    from ..global_scaling import ScalingResult, count_flipped_faces, scale_globally, scale_globally_raw
    from ..measures import body_mass
    from ..preparation import prepare_mesh

    _check_arguments(arguments)
    output = output_path(arguments)
    section = _section_choice(arguments.section)
    prepared = prepare_mesh(arguments.mesh)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    base = {"input": str(arguments.mesh), "output": str(output), "vertices": int(len(prepared.vertices)),
            "faces": int(len(prepared.faces)), "repairs": list(prepared.repairs)}

    if arguments.alpha is not None:
        body = Body(prepared.vertices, prepared.faces)
        scale = 1.0 if arguments.scale is None else float(arguments.scale)
        scaled = scale_globally_raw(body, float(arguments.alpha), scale, arguments.modes, use_cache=not arguments.no_cache)
        report = {**base, "mode": "global-raw", "alpha": float(arguments.alpha), "scale": scale,
                  "mass_ratio": body_mass(scaled) / body_mass(body),
                  "flipped_faces": count_flipped_faces(body.vertices, scaled.vertices, body.faces), "converged": True}
        save_scaled(output, prepared, body, scaled.vertices, arguments)
        write_report(arguments.report, report)
        print(f"{output}: α = {arguments.alpha:g}, s = {scale:g}: mass ×{report['mass_ratio']:.4f}, "
              f"{report['flipped_faces']} flipped faces")
        return 0

    body = labelled_body(arguments, prepared)
    from ..progress import run_progress

    progress = run_progress("scaling steps")
    try:
        result = scale_globally(body, arguments.mass_ratio, modes=arguments.modes, section=section,
                                use_cache=not arguments.no_cache, progress=progress)
    except ScalingError as error:
        closest = error.closest
        if isinstance(closest, ScalingResult):
            write_report(arguments.report, {**base, **closest.as_dict(), "error": str(error)})
        else:
            write_report(arguments.report, {**base, "mode": "global", "target_mass_ratio": arguments.mass_ratio,
                                             "converged": False, "error": str(error)})
        raise
    report = {**base, **result.as_dict()}
    report.update(_independent_check(body, result))
    if not result.converged:
        write_report(arguments.report, report)
        raise ScalingError(f"nothing written: {'; '.join(result.messages)}", closest=result)
    save_scaled(output, prepared, body, result.body.vertices, arguments)
    write_report(arguments.report, report)
    print(summary(output, report))
    return 0


def _independent_check(body, result) -> dict:
    """Mass and peak stress of the output measured from scratch (new contours, new choice)."""
    from ..body import Body
    from ..errors import MeasurementError
    from ..measures import body_mass, peak_stress

    fresh_in = Body(body.vertices, body.faces, body.labels, body.region_names, body.frame)
    fresh_out = Body(result.body.vertices, body.faces, body.labels, body.region_names, body.frame)
    check = {"mass_ratio_measured": body_mass(fresh_out) / body_mass(fresh_in)}
    try:
        check["stress_ratio_reselected"] = peak_stress(fresh_out) / peak_stress(fresh_in)
    except MeasurementError as error:
        check["stress_ratio_reselected"] = None
        check["messages"] = list(result.messages) + [f"independent stress check failed: {error}"]
    return check


def summary(output: Path, report: dict) -> str:
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
