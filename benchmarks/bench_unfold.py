"""What unfolding costs a large mesh written (allorules.mesh.unfold, docs/outputs.md "Folded faces").

    .venv/bin/python benchmarks/bench_unfold.py [--subdivisions 9] [--repeat 3]

An icosphere (subdivision 9: 2,621,442 vertices, 5,242,880 faces, the size of a user's 2M-vertex
animal) scaled ×2, once with nothing folded (the check every run written pays) and once with one
vertex dragged past its neighbour (two faces folded), timed side by side in one process; prints
the best of ``--repeat`` and the patch each fold needed, as JSON.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
import trimesh

from allorules.mesh.unfold import unfold_faces


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=9)
    parser.add_argument("--repeat", type=int, default=3)
    arguments = parser.parse_args(argv)
    sphere = trimesh.creation.icosphere(arguments.subdivisions)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    scaled = 2.0 * vertices
    folded = scaled.copy()
    neighbour = next(int(v) for v in faces[np.any(faces == 0, axis=1)].ravel() if v != 0)
    folded[0] = 2.0 * (vertices[0] + 2.5 * (vertices[neighbour] - vertices[0]))
    figures = {"vertices": len(vertices), "faces": len(faces)}
    for name, after in (("nothing_folded", scaled), ("one_fold", folded)):
        times = []
        for _ in range(arguments.repeat):
            start = time.perf_counter()
            unfolding = unfold_faces(vertices, after, faces)
            times.append(time.perf_counter() - start)
        figures[name] = {"seconds": round(min(times), 2), "folded": unfolding.folded, "left": unfolding.left,
                         "moved": unfolding.moved}
    print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
