"""Benchmark of the harmonic-basis eigensolver (issue 7).

For each size, on a generated quadruped: the reference (scipy's shift-invert ``eigsh`` over the
whole range) and the project's spectrum-slicing solver, cold, in the same run; then a warm
solve after one small deformation (a global scale step of 1.1 with a smooth bump) against a
cold solve of the same deformed mesh. Each case runs in its own subprocess so that its peak
memory (ru_maxrss, minus the process's baseline after building the operators) is its own.

    .venv/bin/python benchmarks/bench_basis.py --sizes 8000 48000 --modes 1000
    .venv/bin/python benchmarks/bench_basis.py --sizes 8000 --modes 300 --skip-eigsh

Writes benchmarks/results/basis.json and basis.md (a markdown table).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import threadpoolctl

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def machine_description() -> dict:
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float("nan")
    return {"cpus": os.cpu_count(), "cpu_model": model, "python": platform.python_version(),
            "load_average_1min_at_start": load}


def build_mesh(size: int, deformed: bool):
    from allorules.mesh.quadruped import generate_quadruped

    quadruped = generate_quadruped("horse", vertices=size)
    vertices = np.asarray(quadruped.vertices, dtype=np.float64).copy()
    faces = np.asarray(quadruped.faces, dtype=np.int64)
    if deformed:
        # One scaling step: global ×1.1 and a smooth bump across the body.
        centre = vertices.mean(axis=0)
        extent = np.ptp(vertices, axis=0).max()
        offset = (vertices - centre) / extent
        vertices = centre + 1.1 * (vertices - centre)
        vertices += 0.03 * extent * np.exp(-8.0 * (offset ** 2).sum(axis=1))[:, None] * offset
    return vertices, faces


def run_case(arguments: argparse.Namespace) -> None:
    """Child process: one solve, reported as JSON on stdout."""
    from allorules.mesh.geometry import vertex_areas
    from allorules.spectral.eigen import smallest_eigenpairs
    from allorules.spectral.laplacian import cotangent_laplacian

    vertices, faces = build_mesh(arguments.size, arguments.deformed)
    stiffness = cotangent_laplacian(vertices, faces)
    mass = vertex_areas(vertices, faces)
    initial = None
    if arguments.initial:
        initial = np.load(arguments.initial)
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # Every method with one BLAS thread, as the bands run themselves: on a shared 2-core machine
    # spinning BLAS threads slow eigsh (ARPACK's level-2 work) as much as anything else.
    with threadpoolctl.threadpool_limits(limits=1, user_api="blas"):
        start = time.perf_counter()
        values, vectors = smallest_eigenpairs(stiffness, mass, arguments.modes, method=arguments.method,
                                              initial=initial)
        seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    residual = stiffness @ vectors - mass[:, None] * vectors * values
    residual_norms = np.sqrt(np.einsum("ij,i,ij->j", residual, 1.0 / mass, residual))
    floor = values[1]
    gram = vectors.T @ (mass[:, None] * vectors)
    if arguments.save_values:
        np.save(arguments.save_values, values)
    if arguments.save_vectors:
        np.save(arguments.save_vectors, vectors)
    print(json.dumps({
        "seconds": seconds,
        "peak_extra_mib": (peak - baseline) / 1024.0,
        "basis_mib": vectors.nbytes / 2 ** 20,
        "max_relative_residual": float(np.max(residual_norms / np.maximum(values, floor))),
        "max_orthonormality_error": float(np.max(np.abs(gram - np.eye(len(values))))),
        "vertices": len(vertices),
    }))


def spawn(size: int, modes: int, method: str, *, deformed=False, initial=None, save_values=None,
          save_vectors=None) -> dict:
    command = [sys.executable, str(Path(__file__).resolve()), "--case", "--size", str(size),
               "--modes", str(modes), "--method", method]
    if deformed:
        command.append("--deformed")
    if initial:
        command += ["--initial", str(initial)]
    if save_values:
        command += ["--save-values", str(save_values)]
    if save_vectors:
        command += ["--save-vectors", str(save_vectors)]
    output = subprocess.run(command, check=True, capture_output=True, text=True).stdout
    result = json.loads(output.strip().splitlines()[-1])
    print(f"  {size:>7} {method:<6} {'warm' if initial else 'cold'}{' deformed' if deformed else ''}: "
          f"{result['seconds']:.1f} s, +{result['peak_extra_mib']:.0f} MiB", flush=True)
    return result


def relative_error(values: np.ndarray, reference: np.ndarray) -> float:
    nonzero = reference[np.abs(reference) > 1e-9 * np.abs(reference).max()]
    return float(np.max(np.abs(values - reference) / np.maximum(np.abs(reference), nonzero[0])))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[8000, 48000])
    parser.add_argument("--modes", type=int, default=1000)
    parser.add_argument("--skip-eigsh", action="store_true", help="no reference eigsh run (slow at 100k)")
    parser.add_argument("--output", default=str(RESULTS / "basis"))
    # Child-process arguments.
    parser.add_argument("--case", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--size", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--method", default="bands", help=argparse.SUPPRESS)
    parser.add_argument("--deformed", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--initial", help=argparse.SUPPRESS)
    parser.add_argument("--save-values", help=argparse.SUPPRESS)
    parser.add_argument("--save-vectors", help=argparse.SUPPRESS)
    arguments = parser.parse_args()
    if arguments.case:
        run_case(arguments)
        return

    report = {"machine": machine_description(), "modes": arguments.modes, "cases": []}
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        for size in arguments.sizes:
            print(f"size {size}, m = {arguments.modes}", flush=True)
            row: dict = {"requested_vertices": size}
            bands = spawn(size, arguments.modes, "bands", save_values=scratch / "bands.npy",
                          save_vectors=scratch / "basis.npy")
            row["bands_cold"] = bands
            row["vertices"] = bands["vertices"]
            if not arguments.skip_eigsh:
                reference = spawn(size, arguments.modes, "eigsh", save_values=scratch / "eigsh.npy")
                row["eigsh_cold"] = reference
                row["speedup_vs_eigsh"] = reference["seconds"] / bands["seconds"]
                row["bands_vs_eigsh_max_relative_eigenvalue_error"] = relative_error(
                    np.load(scratch / "bands.npy"), np.load(scratch / "eigsh.npy"))
            cold = spawn(size, arguments.modes, "bands", deformed=True, save_values=scratch / "cold.npy")
            warm = spawn(size, arguments.modes, "bands", deformed=True, initial=scratch / "basis.npy",
                         save_values=scratch / "warm.npy")
            row["bands_cold_deformed"] = cold
            row["bands_warm_deformed"] = warm
            row["warm_speedup"] = cold["seconds"] / warm["seconds"]
            row["warm_vs_cold_max_relative_eigenvalue_error"] = relative_error(
                np.load(scratch / "warm.npy"), np.load(scratch / "cold.npy"))
            report["cases"].append(row)
            write(report, Path(arguments.output))
    write(report, Path(arguments.output))


def write(report: dict, output: Path) -> None:
    output.parent.mkdir(parents=True, exist_ok=True)
    lines = [
        f"Machine: {report['machine']['cpus']} × {report['machine']['cpu_model']}, "
        f"load average at start {report['machine']['load_average_1min_at_start']:.1f}; m = {report['modes']}.",
        "",
        "| vertices | eigsh cold (s) | bands cold (s) | speed-up | bands warm after deformation (s) | "
        "cold same mesh (s) | warm speed-up | peak extra memory (MiB) / basis (MiB) | "
        "max rel. eigenvalue error vs eigsh | warm vs cold | max rel. residual | max ‖HᵀDH−I‖ |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["cases"]:
        bands = row["bands_cold"]
        reference = row.get("eigsh_cold")
        memory = max(bands["peak_extra_mib"], row["bands_warm_deformed"]["peak_extra_mib"])
        lines.append(
            f"| {row['vertices']:,} | {reference['seconds']:.1f} | " if reference else f"| {row['vertices']:,} | — | "
        )
        lines[-1] += (
            f"{bands['seconds']:.1f} | "
            + (f"{row['speedup_vs_eigsh']:.1f}× | " if reference else "— | ")
            + f"{row['bands_warm_deformed']['seconds']:.1f} | {row['bands_cold_deformed']['seconds']:.1f} | "
            f"{row['warm_speedup']:.1f}× | {memory:.0f} / {bands['basis_mib']:.0f} | "
            + (f"{row['bands_vs_eigsh_max_relative_eigenvalue_error']:.1e} | " if reference else "— | ")
            + f"{row['warm_vs_cold_max_relative_eigenvalue_error']:.1e} | "
            f"{max(bands['max_relative_residual'], row['bands_warm_deformed']['max_relative_residual']):.1e} | "
            f"{max(bands['max_orthonormality_error'], row['bands_warm_deformed']['max_orthonormality_error']):.1e} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    for suffix, content in ((".json", json.dumps(report, indent=2)), (".md", text)):
        target = output.with_suffix(suffix)
        temporary = target.with_suffix(suffix + ".tmp")
        temporary.write_text(content)
        os.replace(temporary, target)


if __name__ == "__main__":
    main()
