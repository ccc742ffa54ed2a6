"""The project's eigensolver against scipy's shifted eigsh on the real meshes of shared/meshes.

Run: .venv/bin/python benchmarks/bench_basis_real.py [--modes M] [--meshes horse lion ...]

Issue 7 is checked "on real meshes, with eigenvalues compared against a reference solve". Each
mesh is loaded as trimesh loads it (vertices merged; holes, stray parts and several components
left as they are: the wolf has three, so λ = 0 three times), its L and D built, and the m
smallest pairs of L h = λ D h computed by ``eigsh`` (the reference) and by the project's default
(``auto``: dense up to 2,500 vertices, bands above), both with one BLAS thread. Prints times, the
largest relative eigenvalue difference (against max(|λ|, the smallest non-zero λ)), the largest
relative residual and ‖HᵀDH − I‖. Record results in docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import threadpoolctl
import trimesh

from allorules.mesh.geometry import vertex_areas
from allorules.spectral.eigen import smallest_eigenpairs
from allorules.spectral.laplacian import cotangent_laplacian

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


def quality(stiffness, mass, values, vectors, floor: float) -> tuple[float, float]:
    residual = stiffness @ vectors - mass[:, None] * vectors * values
    norms = np.sqrt(np.einsum("ij,i,ij->j", residual, 1.0 / mass, residual))
    gram = vectors.T @ (mass[:, None] * vectors)
    return float(np.max(norms / np.maximum(np.abs(values), floor))), float(np.max(np.abs(gram - np.eye(len(values)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", type=int, default=1000)
    parser.add_argument("--meshes", nargs="*", default=["horse", "elephant", "lion", "wolf", "camel", "dog-lowpoly"])
    arguments = parser.parse_args()
    print("| mesh | vertices | components | modes | eigsh | ours (auto) | speed-up | max rel. eigenvalue difference | "
          "max rel. residual (ours / eigsh) | max ‖HᵀDH − I‖ (ours) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in arguments.meshes:
        mesh = trimesh.load(MESHES / f"{name}.obj", process=True, force="mesh")
        vertices, faces = np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces)
        stiffness, mass = cotangent_laplacian(vertices, faces), vertex_areas(vertices, faces)
        if np.any(mass <= 0):
            keep = mass > 0
            print(f"| {name} | {len(vertices):,} | – | – | {int((~keep).sum())} unreferenced vertices: skipped |")
            continue
        count = min(arguments.modes, len(vertices) - 1)
        components = len(mesh.split(only_watertight=False))
        with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
            start = time.perf_counter()
            reference, reference_vectors = smallest_eigenpairs(stiffness, mass, count, method="eigsh")
            eigsh_seconds = time.perf_counter() - start
            start = time.perf_counter()
            values, vectors = smallest_eigenpairs(stiffness, mass, count)
            ours_seconds = time.perf_counter() - start
        nonzero = reference[np.abs(reference) > 1e-9 * np.abs(reference).max()]
        floor = float(nonzero[0]) if len(nonzero) else 1.0
        difference = float(np.max(np.abs(values - reference) / np.maximum(np.abs(reference), floor)))
        ours_residual, ours_gram = quality(stiffness, mass, values, vectors, floor)
        eigsh_residual, _ = quality(stiffness, mass, reference, reference_vectors, floor)
        print(f"| {name} | {len(vertices):,} | {components} | {count} | {eigsh_seconds:.1f} s | {ours_seconds:.1f} s | "
              f"{eigsh_seconds / ours_seconds:.1f}× | {difference:.1e} | {ours_residual:.1e} / {eigsh_residual:.1e} | "
              f"{ours_gram:.1e} |", flush=True)


if __name__ == "__main__":
    main()
