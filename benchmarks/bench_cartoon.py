"""Cartoon proportions: generated animals with stubby legs, big heads and no neck, labelled in poses
and scaled.

Run: .venv/bin/python benchmarks/bench_cartoon.py [--styles cartoon-cow chibi-dog ...]
     [--poses stand walk ...] [--scale 2 0.5] [--rule head-mass=1 --rule abdomen-mass=1] [--json FILE]

Each style is ``allorules generate`` with a preset and overrides (:data:`STYLES`), 6,000 vertices,
so its true regions are known. Labels: each pose turned three ways at random, the share of the
surface labelled as the generator labels it (the six regions, appendages folded in), or the
refusal. With ``--scale``, each style standing is scaled as ``allorules scale`` scales it (working
mesh, ``quadruped`` with the ``--rule`` overrides given, every try): converged, the worst rule,
the trunk's length and shape, seconds, and what a refusal says.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from scipy.spatial.transform import Rotation

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.quadruped import generate_quadruped
from allorules.segment.labeller import label_quadruped
from allorules.segment.regions import fold_regions

# (preset, overrides): what cartoons draw unlike a real animal
STYLES: dict[str, tuple[str, dict[str, float]]] = {
    "cartoon-cow": ("horse", dict(
        foreleg_length=0.38, hindleg_length=0.36, foreleg_radius_top=0.13, foreleg_radius_bottom=0.11,
        hindleg_radius_top=0.14, hindleg_radius_bottom=0.11, head_length=0.7, head_height=0.42, head_width=0.38,
        neck_length=0.18, neck_radius=0.22, neck_head_radius=0.2, head_angle=-10, horn_length=0.18, horn_radius=0.04,
        chest_height=0.8, abdomen_height=0.8, chest_width=0.7, abdomen_width=0.75, leg_spacing=0.3, tail_length=0.4)),
    "chibi-dog": ("dog", dict(
        head_length=0.36, head_height=0.24, head_width=0.24, foreleg_length=0.16, hindleg_length=0.17,
        foreleg_radius_top=0.04, foreleg_radius_bottom=0.035, hindleg_radius_top=0.045, hindleg_radius_bottom=0.035,
        neck_length=0.05, leg_spacing=0.14, chest_width=0.26, abdomen_width=0.25)),
    "no-neck-pig": ("horse", dict(
        neck_length=0.06, neck_radius=0.3, neck_head_radius=0.26, neck_angle=10, head_length=0.55, head_height=0.4,
        head_width=0.4, head_angle=-5, foreleg_length=0.45, hindleg_length=0.45, chest_height=0.8, abdomen_height=0.85,
        chest_width=0.7, abdomen_width=0.75, leg_spacing=0.38, tail_length=0.2, tail_radius=0.06, tail_angle=10)),
    "big-head-horse": ("horse", dict(head_length=0.9, head_height=0.4, head_width=0.34)),
}
VERTICES = 6000
TURNS = 3


def _agreement(animal, labelled: Body) -> float:
    truth, found = fold_regions(animal.body()), fold_regions(labelled)
    area = vertex_areas(animal.vertices, animal.faces)
    return float(area[truth.labels == found.labels].sum() / area.sum())


def _labels(style: str, pose: str) -> list:
    preset, overrides = STYLES[style]
    animal = generate_quadruped(preset, VERTICES, pose=None if pose == "stand" else pose, **overrides)
    cells = []
    for seed in range(TURNS):
        turn = Rotation.random(random_state=seed).as_matrix()
        try:
            cells.append(round(_agreement(animal, label_quadruped(Body(animal.vertices @ turn.T, animal.faces))), 3))
        except AllorulesError as error:
            cells.append(f"refused: {error}")
    return cells


def _scale(style: str, ratio: float, rules: dict[str, float]) -> dict:
    from allorules.rules.overrides import override_exponents
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline

    preset, overrides = STYLES[style]
    animal = generate_quadruped(preset, VERTICES, **overrides)
    started = time.perf_counter()
    try:
        ruleset = override_exponents(load_ruleset("quadruped"), rules)
        run = pipeline.run(Body(animal.vertices, animal.faces), pipeline.RulesetScaling(ruleset, ratio))
    except AllorulesError as error:
        return {"ratio": ratio, "refused": str(error), "seconds": time.perf_counter() - started}
    result = run.result
    worst = max(result.rules, key=lambda rule: abs(rule.error))
    return {"ratio": ratio, "converged": bool(result.converged), "worst_rule": worst.id, "worst_error": float(worst.error),
            "trunk": result.trunk_length_exponent, "trunk_shape": result.trunk_shape,
            "missed": run.missed() if not result.converged else "", "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--styles", nargs="*", default=list(STYLES))
    parser.add_argument("--poses", nargs="*", default=["stand", "walk", "gallop", "sit", "lie"])
    parser.add_argument("--scale", nargs="*", type=float, default=[])
    parser.add_argument("--rule", action="append", default=[], metavar="ID=EXPONENT")
    parser.add_argument("--json", type=Path, default=None)
    arguments = parser.parse_args()
    rules = {text.split("=")[0]: float(text.split("=")[1]) for text in arguments.rule}
    results = {}
    for style in arguments.styles:
        for pose in arguments.poses:
            cells = _labels(style, pose)
            results[f"{style} {pose}"] = cells
            print(f"| {style} | {pose} | " + " | ".join(str(cell) for cell in cells) + " |", flush=True)
        for ratio in arguments.scale:
            outcome = _scale(style, ratio, rules)
            results[f"{style} x{ratio:g}"] = outcome
            print(f"| {style} | x{ratio:g} | {json.dumps(outcome)} |", flush=True)
    if arguments.json:
        arguments.json.write_text(json.dumps(results, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
