"""``allorules spectrum MESH``: vertex count, modes, and the power law of the harmonic spectrum
(slope α and correlation R of log |r̃| against log λ; docs/method.md)."""
from __future__ import annotations

import argparse
import json
import logging
import math

from allorules.cli.arguments import add_png_argument, png_path

log = logging.getLogger("allorules")


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "spectrum",
        help=command_help("spectrum"),
        description="Prepare the mesh, compute its manifold harmonic basis and fit log |r̃| "
        "against log λ over modes 1…m−1: prints the slope α and Pearson's R (docs/method.md).",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    parser.add_argument("--modes", type=int, default=None, metavar="M",
                        help="number of harmonic modes (default 1000, at most vertices − 1)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_png_argument(parser, "|r̃| against λ on log-log axes, with the fitted line", old_spelling="--plot")
    parser.add_argument("--force", action="store_true", help="replace an existing picture (never the input mesh)")
    parser.add_argument("--no-cache", action="store_true", help="do not read or write the basis cache")
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    from allorules.files import PNG, Output, check_outputs
    from allorules.mesh.repair import prepare_mesh
    from allorules.runs.progress import count_bar
    from allorules.spectral.basis import compute_basis, default_modes
    from allorules.spectral.spectrum import spectrum_fit

    picture, option = png_path(arguments, "--plot")
    check_outputs([Output.of(picture, option, PNG)], {"input mesh": arguments.mesh}, force=arguments.force)
    if arguments.modes is not None and arguments.modes < 2:
        from allorules.errors import AllorulesError

        raise AllorulesError(f"--modes must be at least 2, got {arguments.modes}")
    prepared = prepare_mesh(arguments.mesh)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    modes = default_modes(len(prepared.vertices), arguments.modes)
    basis = compute_basis(prepared.vertices, prepared.faces, modes, use_cache=not arguments.no_cache,
                          progress=count_bar("harmonic basis", unit="modes"))
    fit = spectrum_fit(basis, prepared.vertices)
    if not all(math.isfinite(value) for value in (fit.slope, fit.r)):
        from allorules.errors import BasisError

        raise BasisError(f"{arguments.mesh}: the spectrum's power law came out as slope {fit.slope}, R {fit.r}; the "
                         "mesh's harmonic basis is degenerate (faces of zero area?): repair the mesh and try again")
    if picture:
        from allorules.output.render import plot_spectrum

        # Draw the modes that were fitted (1 … m−1): the constant mode's λ_0 is zero up to
        # round-off and has no place on log axes.
        plot_spectrum(fit.eigenvalues[1:], fit.radial[1:], fit.slope, fit.intercept, fit.r,
                      path=picture, title=str(arguments.mesh))
        log.info("wrote %s", picture)
    result = {
        "mesh": str(arguments.mesh),
        "vertices": int(len(prepared.vertices)),
        "input_vertices": int(len(prepared.source.vertices)) if prepared.source is not None else None,
        "faces": int(len(prepared.faces)),
        "modes": int(basis.modes),
        "slope": fit.slope,
        "r": fit.r,
        "intercept": fit.intercept,
        "repairs": prepared.repairs,
    }
    if arguments.json:
        print(json.dumps(result))
    else:
        print(f"{arguments.mesh}: {result['vertices']} vertices, {result['modes']} modes, "
              f"slope α = {fit.slope:.3f}, R = {fit.r:.3f}")
    return 0
