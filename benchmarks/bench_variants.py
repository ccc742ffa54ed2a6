"""Every real animal as a user might bring it: turned, in other units, at another resolution.

Run: .venv/bin/python benchmarks/bench_variants.py WORK_DIR [--jobs 2] [--json FILE]

Makes one variant of each of the ten Princeton quadrupeds and the real horse, lion, wolf and camel
of ``../shared/meshes`` (seeded, so the same variants every time): a random rotation, a change of
units by a power of ten (0.01 to 100), and another resolution: quadric decimation to 3,500
vertices for a mesh above 6,000 (fast-simplification), else one midpoint subdivision (trimesh;
the camel's 7,639 vertices are then used as they are, the 384's, lion's and wolf's ~19k are
remeshed to the working mesh). Then scales each with ``quadruped`` at ×0.5 and ×2 through
``allorules batch`` (one manifest in WORK_DIR, resumable) and prints its summary: converged, the
worst rule's residual, the quality columns (faces turned inside out in the mesh written, new
self-intersections, roughness, worst small feature) and the time. The variants are written to
WORK_DIR (never into the repository).
"""
from __future__ import annotations

import argparse
import csv
import json
import logging
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
SEED = 20261203
DECIMATE_ABOVE = 6_000
DECIMATED = 3_500


def make_variants(work: Path) -> list[Path]:
    """The seeded variants, written as OBJ files into ``work``."""
    import fast_simplification
    import trimesh
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(SEED)
    sources = sorted((SHARED / "psb-fourleg").glob("*.off")) + [SHARED / f"{name}.obj"
                                                                 for name in ("horse", "lion", "wolf", "camel")]
    paths = []
    for source in sources:
        mesh = trimesh.load(source, force="mesh", process=True)
        vertices, faces = mesh.vertices, mesh.faces
        if len(vertices) > DECIMATE_ABOVE:
            vertices, faces = fast_simplification.simplify(vertices.astype(np.float32), faces,
                                                           target_reduction=1 - DECIMATED / len(vertices))
            kind = "dec"
        else:
            vertices, faces = trimesh.remesh.subdivide(vertices, faces)
            kind = "sub"
        rotation = Rotation.random(random_state=rng).as_matrix()
        unit = 10.0 ** rng.integers(-2, 3)
        vertices = (np.asarray(vertices, dtype=float) @ rotation.T) * unit
        path = work / f"{source.stem}-{kind}{len(vertices)}.obj"
        trimesh.Trimesh(vertices, faces, process=False).export(path)
        paths.append(path)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("work", type=Path, help="folder for the variants, the manifest and the results")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write the summary rows here")
    options = parser.parse_args()
    if not SHARED.is_dir():
        raise SystemExit(f"{SHARED} is not present")
    from allorules.runs.batch import run_batch

    logging.basicConfig(level=logging.INFO, format="%(message)s")   # the batch's progress, one line per job
    work = options.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    variants = make_variants(work)
    manifest = work / "variants.yaml"
    manifest.write_text("output: results\nmeshes:\n" + "".join(f"  - {path.name}\n" for path in variants)
                        + "ratios: [0.5, 2]\nrulesets: [quadruped]\n")
    run_batch(manifest, jobs=options.jobs)
    with open(work / "results" / "summary.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    columns = ("job", "converged", "worst_rule_residual", "flipped_faces", "self_intersections",
               "roughness_degrees", "worst_feature_change", "seconds", "error")
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for row in rows:
        print("| " + " | ".join(row[column][:90] for column in columns) + " |")
    converged = sum(row["converged"] == "True" for row in rows)
    print(f"{converged} of {len(rows)} converged")
    if options.json:
        options.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
