"""The same animal measured at any resolution (issue 16 §3: "measurements within 2 %").

Run: .venv/bin/python benchmarks/bench_measure_resolution.py [--animals horse lion psb-381 ...]
     [--results FILE.json]

Each animal (a shared mesh: NAME of shared/meshes/NAME.obj, or psb-NNN) at tessellations of one
and the same surface: as it comes, decimated to 60 % of its vertices (fast-simplification, within a
small fraction of an edge of the surface), and split at its edges' midpoints once and twice (4× and
16× the faces, the very same surface). Each is measured as ``allorules measure`` measures it
(prepared, its working mesh, labelled, every rule of ``quadruped`` and the body's mass) in this
process. Per animal: each quantity at each tessellation, its spread (largest over smallest − 1),
and the share of the surface each region takes. No mesh is written. Results: a JSON file (default
/tmp/allorules-bench-measure-resolution.json); record them in docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_resolution import _decimate, source  # noqa: E402

ANIMALS = ["horse", "lion", "wolf", "camel", "dog-lowpoly"] + [f"psb-{number}" for number in range(381, 391)]
LIMIT = 400_000   # a split variant larger than this many vertices is left out


def variants(animal: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The animal's tessellations of one surface, by name."""
    import trimesh

    from allorules.mesh.repair import prepare_mesh

    prepared = prepare_mesh(source(animal))
    vertices, faces = prepared.vertices, prepared.faces
    found = {"as it comes": (vertices, faces),
             "decimated 60 %": _decimate(vertices, faces, max(2000, int(0.6 * len(vertices))))}
    for times in (1, 2):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
        if len(vertices) > LIMIT:
            break
        found[f"split ×{times}"] = (np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64))
    return found


def measured(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Every rule's quantity of ``quadruped``, the body's mass and the regions' shares of the surface,
    as ``allorules measure`` takes them (or the refusal)."""
    import trimesh

    from allorules.errors import AllorulesError
    from allorules.measure.mass import body_mass
    from allorules.mesh.geometry import vertex_areas
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline

    registry = registry_for(None)
    ruleset = load_ruleset("quadruped", registry)
    try:
        prepared = pipeline.prepare(trimesh.Trimesh(vertices, faces, process=False))
        work, body = pipeline.labelled_working(prepared, registry=registry, regions=pipeline.wanted_regions(ruleset))
        values = {rule.id: float(registry.measure(rule.measure).compute(body, rule.region)) for rule in ruleset.rules}
        values["body-mass"] = float(body_mass(body))
    except AllorulesError as error:
        return {"refused": str(error)}
    area = vertex_areas(body.vertices, body.faces)
    shares = np.bincount(body.labels[body.labels >= 0], weights=area[body.labels >= 0],
                         minlength=len(body.region_names)) / area.sum()
    return {"vertices": int(len(prepared.vertices)), "working": int(len(work.mesh.vertices)), "values": values,
            "shares": {name: round(float(share), 4) for name, share in zip(body.region_names, shares)}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--animals", nargs="+", default=ANIMALS)
    parser.add_argument("--results", type=Path, default=Path("/tmp/allorules-bench-measure-resolution.json"))
    arguments = parser.parse_args()
    results = {}
    for animal in arguments.animals:
        started = time.perf_counter()
        rows = {name: measured(*mesh) for name, mesh in variants(animal).items()}
        good = [row for row in rows.values() if "values" in row]
        spread = {}
        if good:
            for quantity in good[0]["values"]:
                values = [row["values"][quantity] for row in good]
                spread[quantity] = max(values) / min(values) - 1.0 if min(values) > 0 else float("inf")
        results[animal] = {"variants": rows, "spread": spread}
        worst = sorted(spread.items(), key=lambda item: -item[1])[:3]
        print(f"{animal}: " + ", ".join(f"{name} {row.get('vertices', 'refused')}" for name, row in rows.items())
              + "; spread " + ", ".join(f"{quantity} {100 * value:.1f} %" for quantity, value in worst)
              + f" ({time.perf_counter() - started:.0f} s)", flush=True)
        for name, row in rows.items():
            if "refused" in row:
                print(f"  {name}: refused: {row['refused']}")
        arguments.results.write_text(json.dumps(results, indent=1))
    within = sum(1 for result in results.values() if result["spread"] and max(result["spread"].values()) <= 0.02)
    print(f"{within} of {len(results)} animals have every quantity within 2 % across their tessellations")


if __name__ == "__main__":
    main()
