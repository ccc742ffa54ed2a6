"""The working mesh of bodies with holes: its triangles beside the rims, and what its basis costs.

Run: .venv/bin/python benchmarks/bench_working_mesh.py [MESH ...] [--sizes 50000 200000]

Each mesh (default: the shared meshes that have holes, the real horse and the wolf) is prepared as
a run prepares it, split at its edges' midpoints until it has at least each size (the very same
surface, finer), and made into a working mesh (default size). Printed per mesh and size: the
working mesh's vertices, the holes before and after, its largest angle (180°: a flat triangle), its
smallest angle, the first percentile of its triangles' smallest angles, the share of triangles
under 10°, and the time of one cold 1,000-mode basis on it. To compare two versions of the code
side by side, run this file twice at once with ``PYTHONPATH`` pointing at each (the largest angle
is trimesh's, so that any version runs it). Record results in docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

from allorules.mesh.repair import prepare_mesh
from allorules.mesh.topology import count_boundary_loops
from allorules.mesh.working import make_working_mesh, triangle_quality
from allorules.spectral.basis import compute_basis

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("meshes", nargs="*", type=Path, default=[MESHES / "horse.obj", MESHES / "wolf.obj"])
    parser.add_argument("--sizes", nargs="*", type=int, default=[0, 50000, 200000],
                        help="split each mesh until it has at least this many vertices (0: as it comes)")
    arguments = parser.parse_args()
    print("| mesh | vertices | working mesh | holes (body → working) | largest angle | smallest angle | "
          "1st percentile | under 10° | cold basis |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in arguments.meshes:
        body = prepare_mesh(path)
        for size in arguments.sizes:
            vertices, faces = body.vertices, body.faces
            while len(vertices) < size:
                vertices, faces = trimesh.remesh.subdivide(vertices, faces)
            working = make_working_mesh(vertices, faces)
            quality = triangle_quality(working.vertices, working.faces)
            started = time.perf_counter()
            compute_basis(working.vertices, working.faces, use_cache=False)
            seconds = time.perf_counter() - started
            print(f"| {path.stem} | {len(vertices):,} | {len(working.vertices):,} ({working.method}) | "
                  f"{count_boundary_loops(faces)} → {count_boundary_loops(working.faces)} | "
                  f"{np.degrees(trimesh.triangles.angles(working.vertices[working.faces]).max()):.4g}° | "
                  f"{quality['min_angle']:.3g}° | {quality['min_angle_p1']:.1f}° | {100 * quality['below_10']:.2f} % | "
                  f"{seconds:.1f} s |", flush=True)


if __name__ == "__main__":
    main()
