"""How long a render takes: wall and CPU time of render_views for meshes of growing size.

Run: .venv/bin/python benchmarks/bench_render.py  (writes PNGs to a temporary folder).
Compares the PolyCollection painter's renderer with matplotlib's mplot3d on the same mesh.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from allorules.output.render import render_views


def timed(function) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def mplot3d_render(vertices: np.ndarray, faces: np.ndarray, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    figure = Figure(figsize=(9, 6), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot(projection="3d")
    collection = Poly3DCollection(vertices[faces], facecolors=(0.74, 0.75, 0.78), shade=True,
                                  edgecolors=(0.74, 0.75, 0.78), linewidths=0.25)
    axes.add_collection3d(collection)
    axes.auto_scale_xyz(*vertices.T)
    axes.view_init(elev=0, azim=-90)
    axes.set_axis_off()
    figure.savefig(path)


def main() -> None:
    folder = Path(tempfile.mkdtemp(prefix="allorules-bench-"))
    print(f"{'faces':>8} {'views':>6} {'wall s':>8} {'cpu s':>8}   renderer")
    for subdivisions in (3, 4, 5, 6):
        sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
        vertices = sphere.vertices * np.array([3.0, 1.0, 1.0])
        faces = sphere.faces
        render_views(vertices, faces, path=folder / "warm.png")  # imports, font cache
        for views in (("side",), ("side", "three-quarter")):
            wall, cpu = timed(lambda: render_views(vertices, faces, path=folder / "a.png", views=views))
            print(f"{len(faces):>8} {len(views):>6} {wall:>8.2f} {cpu:>8.2f}   allorules.output.render")
        if len(faces) <= 20_480:
            wall, cpu = timed(lambda: mplot3d_render(vertices, faces, folder / "b.png"))
            print(f"{len(faces):>8} {1:>6} {wall:>8.2f} {cpu:>8.2f}   mplot3d Poly3DCollection")


if __name__ == "__main__":
    main()
