"""Benchmark: open regions held by their shape against soft terms (issue 18 §1).

For each mass ratio, the same animal is scaled with `quadruped` twice in one run, once with
``open_regions: {hold: shape}`` (the default) and once with ``{hold: soft}`` (the soft terms of
weight 0.01), and for each: whether it converged, each rule's achieved exponent, the mass ratio,
every open region's length and mass exponents, and the time. Default animal: the generated horse
with its true labels (neck and tail); ``--mesh`` runs a real mesh through the whole pipeline
instead (labelled by the ruleset's segmenter).

    .venv/bin/python benchmarks/bench_open_regions.py                       # generated, 3,000 vertices, 200 modes
    .venv/bin/python benchmarks/bench_open_regions.py --mesh ../shared/meshes/horse.obj --modes 1000

Writes benchmarks/results/open_regions.json and open_regions.md (a markdown table).
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _ruleset(hold: str, folder: Path):
    from allorules.rules.resolve import load_ruleset

    path = folder / f"{hold}.yaml"
    path.write_text(f"extends: quadruped\nopen_regions: {{hold: {hold}}}\n")
    return load_ruleset(path)


def _row(result, hold: str, ratio: float, seconds: float) -> dict:
    return {"hold": hold, "mass_ratio_target": ratio, "converged": bool(result.converged),
            "mass_ratio": float(result.mass_ratio),
            "rules": {rule.id: round(float(rule.achieved_exponent), 4) for rule in result.rules},
            "open_regions": {f"{o.region} {o.measure}": None if o.achieved_exponent is None else round(o.achieved_exponent, 4)
                             for o in result.open_regions},
            "seconds": round(seconds, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ratios", type=float, nargs="+", default=[2.0, 0.5])
    parser.add_argument("--vertices", type=int, default=3000, help="generated horse's size")
    parser.add_argument("--modes", type=int, default=200)
    parser.add_argument("--mesh", type=Path, help="a real mesh instead of the generated horse")
    args = parser.parse_args()

    rows = []
    with tempfile.TemporaryDirectory() as folder:
        rulesets = {hold: _ruleset(hold, Path(folder)) for hold in ("shape", "soft")}
        if args.mesh is None:
            from allorules.mesh.quadruped import generate_quadruped
            from allorules.runs.ruleset_run import scale_with_ruleset

            body = generate_quadruped("horse", args.vertices).body()
            for ratio in args.ratios:
                for hold, ruleset in rulesets.items():
                    started = time.perf_counter()
                    result = scale_with_ruleset(body, ruleset, ratio, modes=args.modes)
                    rows.append(_row(result, hold, ratio, time.perf_counter() - started))
                    print(rows[-1], flush=True)
        else:
            from allorules.api import scale_mesh

            for ratio in args.ratios:
                for hold, ruleset in rulesets.items():
                    started = time.perf_counter()
                    run = scale_mesh(args.mesh, ratio, ruleset=ruleset, modes=args.modes)
                    rows.append(_row(run.result, hold, ratio, time.perf_counter() - started))
                    print(rows[-1], flush=True)
    animal = str(args.mesh) if args.mesh else f"generated horse, {args.vertices} vertices (true labels)"
    results = HERE / "results"
    results.mkdir(exist_ok=True)
    (results / "open_regions.json").write_text(json.dumps({"animal": animal, "modes": args.modes, "rows": rows}, indent=2))
    rule_ids = list(rows[0]["rules"]) if rows else []
    opened = sorted({key for row in rows for key in row["open_regions"]})
    lines = [f"{animal}, {args.modes} modes, `quadruped`", "",
             "| ×R | hold | converged | mass ratio | " + " | ".join(rule_ids) + " | " + " | ".join(opened) + " | time |",
             "|---" * (5 + len(rule_ids) + len(opened)) + "|"]
    for row in rows:
        lines.append(f"| {row['mass_ratio_target']:g} | {row['hold']} | {'yes' if row['converged'] else 'no'} | "
                     f"{row['mass_ratio']:.4f} | " + " | ".join(f"{row['rules'][k]:.3f}" for k in rule_ids) + " | "
                     + " | ".join("—" if row["open_regions"].get(k) is None else f"{row['open_regions'][k]:.3f}" for k in opened)
                     + f" | {row['seconds']:.0f} s |")
    (results / "open_regions.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
