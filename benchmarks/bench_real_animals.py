"""The quadruped ruleset on every real animal of shared/meshes, at R = 2 and 0.5.

Run: .venv/bin/python benchmarks/bench_real_animals.py [--modes M] [--picture PNG]

Each mesh is prepared and labelled automatically, as ``allorules scale MESH --ruleset quadruped``
does, then scaled at R = 0.5 and 2 (basis cache off). Prints a table (converged, every rule's
achieved exponent, mass and stress ratios, the largest foot lift and bow, wall time) and draws the
animals at ×0.5, as they came and at ×2, each at the same head-to-tail length (default
docs/images/real_animals.png). A mesh the labeller refuses is listed with its reason. Record
results in docs/biology-scaling.md.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.repair import prepare_mesh
from allorules.output.render import region_colors, render_gallery
from allorules.plugins.registry import registry_for
from allorules.rules.resolve import load_ruleset
from allorules.runs.ruleset_run import scale_with_ruleset
from allorules.segment.labeller import label_quadruped
from allorules.segment.regions import fold_regions

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
PICTURE = Path(__file__).resolve().parents[1] / "docs" / "images" / "real_animals.png"
ANIMALS = ("horse", "lion", "wolf", "camel", "dog-lowpoly", "elephant")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", type=int, default=None, help="basis size (default 1000)")
    parser.add_argument("--picture", default=str(PICTURE))
    arguments = parser.parse_args()
    if not MESHES.is_dir():
        raise SystemExit(f"{MESHES} is not here")
    registry = registry_for(None)
    ruleset = load_ruleset("quadruped", registry)
    ids = [rule.id for rule in ruleset.rules]
    print(f"| animal | vertices | R | converged | {' | '.join(ids)} | mass ratio | stress ratio | feet lift up to | "
          "a leg bows up to | wall |")
    print("|---|---|---|---|" + "---|" * len(ids) + "---|---|---|---|---|")
    grid, frames = {}, {}
    for name in ANIMALS:
        prepared = prepare_mesh(MESHES / f"{name}.obj")
        try:
            body = fold_regions(label_quadruped(Body(prepared.vertices, prepared.faces)))   # the six regions
        except AllorulesError as error:
            print(f"| {name} | {len(prepared.vertices):,} | – | refused: {error} |")
            continue
        colors = region_colors(body.labels, body.region_names)
        grid[name], frames[name] = {"as it came": (body.vertices, body.faces, colors)}, body.frame
        for ratio in (0.5, 2.0):
            wall = time.perf_counter()
            try:
                result = scale_with_ruleset(body, ruleset, ratio, registry=registry, modes=arguments.modes, use_cache=False)
            except AllorulesError as error:
                print(f"| {name} | {len(body.vertices):,} | {ratio:g} | failed: {error} |")
                continue
            wall = time.perf_counter() - wall
            achieved = " | ".join(f"{rule.achieved_exponent:.3f}" for rule in result.rules)
            lift = max(abs(change["foot_lift"]) for change in result.posture.values())
            bend = max(change["bend"] for change in result.posture.values())
            print(f"| {name} | {len(body.vertices):,} | {ratio:g} | {'yes' if result.converged else 'no'} | {achieved} | "
                  f"{result.mass_ratio:.4f} | {result.stress_ratio:.4f} | {100 * lift:.1f} % | {100 * bend:+.1f} % | "
                  f"{wall:.0f} s |", flush=True)
            grid[name][f"×{ratio:g}"] = (result.body.vertices, result.body.faces, colors)
    print(f"targets: {', '.join(f'{rule.id} {rule.exponent:.3f}' for rule in ruleset.rules)}")
    render_gallery(grid, path=arguments.picture, rows=("×0.5", "as it came", "×2"), frames=frames,
                   title="quadruped ruleset on the real animals of shared/meshes, each drawn at the same length")
    print(f"picture: {arguments.picture}")


if __name__ == "__main__":
    main()
