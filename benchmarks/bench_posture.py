"""The stance a run ends with, for each ``solver.posture``: legs' lean, feet's lift and legs' bow.

Run: .venv/bin/python benchmarks/bench_posture.py [--vertices N] [--modes M] [--picture PNG]

The generated horse (1,500 vertices, 300 modes by default) with ``quadruped`` at R = 0.5 and 2,
posture free, upright and keep. Prints, per run, whether it converged, the largest lean, the
largest foot lift and the largest bow added (docs/biology-scaling.md, posture), how much the
back pitched (the chest's centroid against the abdomen's, positive: nose up), and draws the
outputs side by side at the same length (default docs/images/posture.png). Record results in
docs/biology-scaling.md.
"""
from __future__ import annotations

import argparse
import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")

import numpy as np  # noqa: E402

from allorules.measure.limbs import limb_sections, stance_down
from allorules.mesh.quadruped import generate_quadruped
from allorules.output.render import region_colors, region_legend, render_comparison
from allorules.plugins.registry import registry_for
from allorules.rules.model import POSTURES
from allorules.rules.resolve import load_ruleset
from allorules.runs.ruleset_run import scale_with_ruleset

PICTURE = Path(__file__).resolve().parents[1] / "docs" / "images" / "posture.png"


def back_pitch(body, down: np.ndarray) -> float:
    """Degrees the abdomen → chest direction rises above the ground plane (⊥ ``down``)."""
    forward = body.vertices[body.region_mask("chest")].mean(axis=0) - body.vertices[body.region_mask("abdomen")].mean(axis=0)
    rise = -forward @ down
    return float(np.degrees(np.arctan2(rise, np.linalg.norm(forward + rise * down))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=1500)
    parser.add_argument("--modes", type=int, default=300)
    parser.add_argument("--picture", default=str(PICTURE))
    arguments = parser.parse_args()
    registry = registry_for(None)
    quadruped = load_ruleset("quadruped", registry)
    body = generate_quadruped("horse", vertices=arguments.vertices).body()
    colors = region_colors(body.labels, body.region_names)
    meshes = {1.0: [(body.vertices, body.faces, "input", colors)], 0.5: [], 2.0: []}
    down = stance_down([limb for region in ("forelimbs", "hindlimbs") for limb in limb_sections(body, region)], body.frame)
    print("| R | posture | converged | largest lean | largest foot lift | largest bow added | back pitch change | "
          "every rule within ±0.02 |")
    print("|---|---|---|---|---|---|---|---|")
    for ratio in (0.5, 2.0):
        for posture in reversed(POSTURES):                       # free, upright, keep
            ruleset = replace(quadruped, solver=replace(quadruped.solver, posture=posture))
            result = scale_with_ruleset(body, ruleset, ratio, registry=registry, modes=arguments.modes, use_cache=False)
            lean = max(change["tilt_degrees"] for change in result.posture.values())
            lift = max(abs(change["foot_lift"]) for change in result.posture.values())
            bow = max(change["bend"] for change in result.posture.values())
            within = all(abs(rule.error) <= 0.02 for rule in result.rules)
            pitch = back_pitch(result.body, down) - back_pitch(body, down)
            print(f"| {ratio:g} | {posture} | {'yes' if result.converged else 'no'} | {lean:.1f}° | "
                  f"{100 * lift:.1f} % of a leg | {100 * bow:+.1f} % | {pitch:+.1f}° | {'yes' if within else 'no'} |")
            meshes[ratio].append((result.body.vertices, result.body.faces, f"×{ratio:g} {posture} ({lean:.1f}°, "
                                                                            f"feet {100 * lift:.0f}%)", colors))
    render_comparison(meshes[0.5] + meshes[1.0] + meshes[2.0], path=arguments.picture, normalise_size=True,
                      size=(3200, 520), title="quadruped ruleset: each posture at ×0.5 and ×2 (largest lean, largest foot lift)",
                      legend=region_legend(body.labels, body.region_names))
    print(f"picture: {arguments.picture}")


if __name__ == "__main__":
    main()
