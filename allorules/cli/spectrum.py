"""``allorules spectrum MESH``: vertex count, modes and Table 1's slope α and correlation R."""
from __future__ import annotations

import argparse
import json
import logging

from allorules.mesh.repair import prepare_mesh
from allorules.spectral.basis import compute_basis, default_modes
from allorules.spectral.spectrum import spectrum_fit

log = logging.getLogger("allorules")


def register(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "spectrum",
        help="power-law statistics of a mesh's harmonic spectrum (paper Table 1)",
        description="Prepare the mesh, compute its manifold harmonic basis and fit log |r̃| "
        "against log λ over modes 1…m−1: prints the slope α and Pearson's R.",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    parser.add_argument("--modes", type=int, default=None, metavar="M",
                        help="number of harmonic modes (default 1000, at most vertices − 1)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    parser.add_argument("--plot", metavar="FILE.png", help="write |r̃| against λ on log-log axes (Figure 4)")
    parser.add_argument("--no-cache", action="store_true", help="do not read or write the basis cache")
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    prepared = prepare_mesh(arguments.mesh)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    modes = default_modes(len(prepared.vertices), arguments.modes)
    basis = compute_basis(prepared.vertices, prepared.faces, modes, use_cache=not arguments.no_cache,
                          progress=_progress("harmonic basis"))
    fit = spectrum_fit(basis, prepared.vertices)
    if arguments.plot:
        from allorules.output.render import plot_spectrum

        # Draw the modes that were fitted (1 … m−1): the constant mode's λ_0 is zero up to
        # round-off and has no place on log axes.
        plot_spectrum(fit.eigenvalues[1:], fit.radial[1:], fit.slope, fit.intercept, fit.r,
                      path=arguments.plot, title=str(arguments.mesh))
        log.info("wrote %s", arguments.plot)
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


def _progress(description: str):
    from allorules.runs.progress import count_bar

    return count_bar(description)
