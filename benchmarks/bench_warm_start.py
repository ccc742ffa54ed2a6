"""How close the previous basis is to the new one after one step: the bound on any warm start.

Run: .venv/bin/python benchmarks/bench_warm_start.py [--vertices N] [--modes M]

Issue 7 asks for a warm start 3x faster than a cold solve of the deformed mesh. A solver that
starts from the previous basis begins with an error of about sin θ_i, the angle between each new
eigenvector h_i and the previous basis, and must bring it to the cold solve's accuracy (relative
residual 1e-9, about 10 orders from a random start). With any iteration that gains a fixed factor
per sweep (Krylov, subspace or Davidson), the saving is at most
log(1e-10) / log(1e-10 / sin θ): 1.25x at sin θ = 1e-2, 2x at 1e-5, 3x needs sin θ ≈ 2e-7.

Measured here, on the generated horse, for two deformations:

* ``bench``: the one bench_basis.py warm-starts from (global ×1.1 and a smooth bump);
* ``step``: one real step of a ruleset run (``quadruped``, r = 1.1), the deformation a run makes.

For each: per range of modes, the median and largest sin θ_i of the new eigenvectors against the
whole previous basis (D-orthogonal projection), and against the single best previous vector (what
a band's start vector has). Record results in docs/benchmarks.md.

Then the bound for the whole solve: the share of a cold solve's time each range of modes takes
(timed band by band through the progress callback), each divided by its range's bound, summed; and
the same with the lowest ranges free, the most any warm start could give if it got those modes at
no cost at all.
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")

import numpy as np  # noqa: E402

from allorules.mesh.quadruped import generate_quadruped
from allorules.spectral.basis import compute_basis


def bench_deformation(vertices: np.ndarray) -> np.ndarray:
    """The deformation of benchmarks/bench_basis.py: global ×1.1 and a smooth bump."""
    centre = vertices.mean(axis=0)
    extent = np.ptp(vertices, axis=0).max()
    offset = (vertices - centre) / extent
    moved = centre + 1.1 * (vertices - centre)
    return moved + 0.03 * extent * np.exp(-8.0 * (offset ** 2).sum(axis=1))[:, None] * offset


def step_deformation(body, basis) -> np.ndarray:
    """One step of a quadruped run (r = 1.1) from ``body``."""
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.solve.step import solve_step

    registry = registry_for(None)
    return solve_step(body, basis, load_ruleset("quadruped", registry), registry, 1.1).body.vertices


def angles(previous: np.ndarray, new: np.ndarray, mass: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sin θ of each column of ``new`` (D-orthonormal) against span(``previous``) and against the
    best single column of ``previous``, in the inner product of the new mass D."""
    gram = previous.T @ (mass[:, None] * previous)                  # HₚᵀDHₚ (not I: D changed)
    cross = previous.T @ (mass[:, None] * new)                       # HₚᵀDH
    inside = np.einsum("ij,ij->j", cross, np.linalg.solve(gram, cross))   # ‖P h_i‖²_D
    whole = np.sqrt(np.clip(1.0 - inside, 0.0, 1.0))
    norms = np.sqrt(np.diag(gram))
    best = np.abs(cross / norms[:, None]).max(axis=0)
    single = np.sqrt(np.clip(1.0 - best ** 2, 0.0, 1.0))
    return whole, single


RANGE_EDGES = (1, 10, 100, 300, 600)


def range_bounds(whole: np.ndarray, modes: int) -> list[tuple[int, int, float]]:
    """``(low, high, bound)`` per range of modes: warm/cold ≤ 10 / (10 + log10 median sin θ)."""
    edges = [edge for edge in RANGE_EDGES if edge < modes] + [modes]
    bounds = []
    for low, high in zip(edges[:-1], edges[1:]):
        median = float(np.median(whole[low:high]))
        bounds.append((low, high, 10.0 / max(10.0 + np.log10(max(median, 1e-10)), 1e-9)))
    return bounds


def cold_time_shares(vertices: np.ndarray, faces: np.ndarray, modes: int) -> tuple[float, np.ndarray]:
    """A cold solve's wall time and, per mode, the share of it spent on that mode's band (each
    band's time spread evenly over the pairs it accepted)."""
    marks = []
    started = time.perf_counter()
    compute_basis(vertices, faces, modes, use_cache=False,
                  progress=lambda done, total: marks.append((done, time.perf_counter() - started)))
    total = time.perf_counter() - started
    per_mode = np.zeros(modes)
    done_before, time_before = 0, 0.0
    for done, at in marks:
        if done > done_before:
            per_mode[done_before:done] = (at - time_before) / (done - done_before)
            done_before, time_before = done, at
    per_mode[:max(done_before, 1)] += (total - time_before) / max(done_before, 1)   # the final checks
    return total, per_mode / total


def whole_solve_bound(bounds, shares: np.ndarray, free_below: int = 0) -> float:
    """warm/cold ≤ 1 / Σ_ranges share / bound, with the modes below ``free_below`` costing nothing."""
    warm = shares[:1].sum() if free_below == 0 else 0.0          # mode 0 is in the first band
    for low, high, bound in bounds:
        if high > free_below:
            warm += shares[max(low, free_below):high].sum() / bound
    return 1.0 / warm


def report(name: str, previous, new, modes: int, vertices: np.ndarray, faces: np.ndarray) -> None:
    whole, single = angles(previous.vectors, new.vectors, new.mass)
    print(f"{name}:")
    print("  | modes | sin θ to the previous basis: median | largest | to the best single previous vector: median | largest | best possible warm/cold |")
    print("  |---|---|---|---|---|---|")
    bounds = range_bounds(whole, modes)
    for low, high, bound in bounds:
        part, best = whole[low:high], single[low:high]
        print(f"  | {low}–{high - 1} | {np.median(part):.1e} | {part.max():.1e} | {np.median(best):.2f} | "
              f"{best.max():.2f} | {bound:.2f}x |")
    seconds, shares = cold_time_shares(vertices, faces, modes)
    ranges = ", ".join(f"{low}–{high - 1}: {shares[low:high].sum():.0%}" for low, high, _ in bounds)
    print(f"  cold solve of the deformed mesh: {seconds:.1f} s; share of it by modes: {ranges}")
    print(f"  whole-solve bound on warm/cold: {whole_solve_bound(bounds, shares):.2f}x; "
          + "; ".join(f"with modes below {free} free: {whole_solve_bound(bounds, shares, free):.2f}x"
                      for free in (100, 300) if free < modes))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vertices", type=int, default=8000)
    parser.add_argument("--modes", type=int, default=1000)
    arguments = parser.parse_args()
    body = generate_quadruped("horse", vertices=arguments.vertices).body()
    basis = compute_basis(body.vertices, body.faces, arguments.modes, use_cache=False)
    print(f"generated horse, {len(body.vertices)} vertices, {basis.modes} modes")
    for name, moved in (("bench (×1.1 and a bump)", bench_deformation(body.vertices)),
                        ("step (one quadruped step, r = 1.1)", step_deformation(body, basis))):
        new = compute_basis(moved, body.faces, arguments.modes, use_cache=False)
        report(name, basis, new, basis.modes, moved, body.faces)


if __name__ == "__main__":
    main()
