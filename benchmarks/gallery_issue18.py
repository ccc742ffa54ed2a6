"""Before/after of the real animals at ×0.5, ×1 and ×2 on one common ground line at true scale
(issue 18), with close-ups of heads and tails, and each run's quality report.

    python benchmarks/gallery_issue18.py OUT_FOLDER [--modes 300] [MESH ...]

Each output is placed on the input's ground (allorules.measure.ground.place_on_ground) before drawing, so
the picture shows what a user sees with input and output in one scene.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[2] / "shared" / "meshes"
DEFAULT = ["horse.obj", "lion.obj", "wolf.obj", "camel.obj", "dog-lowpoly.obj", "elephant.obj"] + \
          [f"psb-fourleg/{n}.off" for n in range(381, 391)]


def draw(path, body, outputs, title):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from allorules.output.render import _draw_shot, camera_for, make_shot

    up, forward = body.frame.up, body.frame.forward
    camera = camera_for("side", up, forward, np.cross(forward, up))
    projection = np.stack([camera.right, camera.up], axis=1)
    figure, axes = plt.subplots(1, 1, figsize=(14, 4))
    ground = float((body.vertices @ projection)[:, 1].min())
    cursor = 0.0
    for label, vertices in outputs:
        xy = vertices @ projection
        shot = make_shot(vertices, body.faces, camera)
        moved = shot.transformed(1.0, (cursor - xy[:, 0].min(), 0.0))
        _draw_shot(axes, moved)
        axes.text(cursor + (xy[:, 0].max() - xy[:, 0].min()) / 2, ground - 0.04 * np.ptp(xy[:, 1]), label, ha="center", va="top")
        cursor += (xy[:, 0].max() - xy[:, 0].min()) * 1.1
    axes.axhline(ground, color="0.5", linewidth=0.8)
    axes.set_aspect("equal")
    axes.axis("off")
    axes.set_title(title, fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=80)
    plt.close(figure)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("out")
    parser.add_argument("meshes", nargs="*")
    parser.add_argument("--modes", type=int, default=300)
    parser.add_argument("--ruleset", default="quadruped")
    arguments = parser.parse_intermixed_args(argv)
    from allorules.body import Body
    from allorules.errors import AllorulesError
    from allorules.measure.ground import place_on_ground
    from allorules.measure.quality import quality_report
    from allorules.mesh.load import load_mesh
    from allorules.mesh.repair import prepare_mesh
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.runs.ruleset_run import scale_with_ruleset
    from allorules.segment import labelled_body

    out = Path(arguments.out)
    out.mkdir(parents=True, exist_ok=True)
    registry = registry_for(None)
    ruleset = load_ruleset(arguments.ruleset, registry)
    summary = {}
    for name in arguments.meshes or DEFAULT:
        stem = Path(name).stem
        try:
            prepared = prepare_mesh(load_mesh(SHARED / name))
            body = labelled_body(Body(prepared.vertices, prepared.faces), None)
        except AllorulesError as error:
            summary[stem] = {"refused": str(error)}
            print(stem, "refused:", error, flush=True)
            continue
        outputs, runs = [], {}
        for ratio in (0.5, 2.0):
            started = time.time()
            try:
                result = scale_with_ruleset(body, ruleset, ratio, registry=registry, modes=arguments.modes)
            except AllorulesError as error:
                runs[str(ratio)] = {"error": str(error)}
                continue
            placed = place_on_ground(body, result.body.vertices)
            report = quality_report(body, placed, rules=result.rules)
            runs[str(ratio)] = {"converged": result.converged, "seconds": round(time.time() - started, 1),
                                "mass_ratio": result.mass_ratio,
                                "open_regions": [o.as_dict() for o in result.open_regions],
                                "quality": report.as_dict()}
            outputs.append((f"x{ratio:g}", placed))
            np.save(out / f"{stem}_x{ratio:g}.npy", placed)
            print(stem, ratio, "converged", result.converged, f"{time.time() - started:.0f}s",
                  "flipped", report.flipped.count, "intersections", report.intersections.pairs,
                  "worst feature %.3f" % report.worst_feature_change, flush=True)
        ordered = [item for item in outputs if item[0] == "x0.5"] + [("x1", body.vertices)] + \
                  [item for item in outputs if item[0] == "x2"]
        draw(out / f"{stem}.png", body, ordered, f"{stem}: x0.5, input, x2 at true scale on the input's ground")
        summary[stem] = runs
        (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
