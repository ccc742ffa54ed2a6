"""The same animal at any resolution (issue 16 §3-4): a whole ``quadruped`` run on the working mesh,
carried back, at several tessellations of one animal, compared with each other; time and peak
memory of each, against today's direct run on the 8.4k horse in the same session.

Run: .venv/bin/python benchmarks/bench_resolution.py [--mass-ratio R] [--animals generated horse]
     [--sizes 3000 12000 48000 200000] [--working-vertices N] [--modes M] [--million] [--no-baseline] [--reuse]
     [--results FILE.json]

Animals: ``generated`` = ``generate_quadruped("horse", vertices=N)`` (one implicit shape,
marching cubes at each size); ``horse`` (or any NAME of shared/meshes/NAME.obj, or ``psb-NNN`` for
shared/meshes/psb-fourleg/NNN.off, or a mesh file's path) decimated (fast-simplification) to a smaller size, as it is,
and Loop-subdivided (trimesh; split at edge midpoints instead where Loop moves the mesh's extent
by over 1 %: spikes at an open boundary) 1-3 times then decimated to a larger one (12k, 48k, 200k); size 0
is the shared mesh as it is. ``--million``: the horse at 1,000,000 vertices (Loop ×3, midpoint ×1, decimated),
time and memory only. Each run is its own subprocess (peak memory = its ru_maxrss). The basis
cache is off. Per run: the working mesh, the time of each part, converged or not, every rule's
achieved exponent measured on the working mesh and, afresh, on the full-resolution output with the
carried labels. Across the sizes of one animal: the share of surface area whose labels agree
(every pair, on the finest mesh's surface), the spread of every initial measurement and of every
achieved exponent. Results: benchmarks/results/resolution.json; record them in docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT.parent / "shared" / "meshes"
WORK = Path(os.environ.get("ALLORULES_BENCH_WORK", "/tmp/allorules-bench-resolution"))
RESULTS = ROOT / "benchmarks" / "results" / "resolution.json"


# ---------------------------------------------------------------------------------------------
# The animal at several tessellations


def _decimate(vertices, faces, count):
    import fast_simplification

    if len(vertices) <= count:
        return vertices, faces
    v, f = fast_simplification.simplify(vertices, faces, target_count=2 * count)
    return np.asarray(v, dtype=float), np.asarray(f, dtype=np.int64)


def source(animal: str) -> Path:
    """The shared mesh an animal's variants are made from (an animal given as a mesh file's path:
    that file, a mesh from outside shared/)."""
    if Path(animal).suffix and Path(animal).is_file():
        return Path(animal).resolve()
    if animal.startswith("psb-"):
        return MESHES / "psb-fourleg" / f"{animal[4:]}.off"
    return MESHES / f"{animal}.obj"


def _name(animal: str) -> str:
    """The animal's name in file names: a path's stem, or the name itself."""
    return Path(animal).stem if Path(animal).suffix else animal


def make_variant(animal: str, size: int) -> Path:
    """An npz (vertices, faces) of ``animal`` at about ``size`` vertices (0: as it is), made once."""
    import trimesh

    WORK.mkdir(parents=True, exist_ok=True)
    path = WORK / f"{_name(animal)}-{size}.npz"
    if path.exists():
        return path
    if animal == "generated":
        from allorules.mesh.quadruped import generate_quadruped

        mesh = generate_quadruped("horse", vertices=size)
        vertices, faces = mesh.vertices, mesh.faces
    else:
        from allorules.mesh.repair import prepare_mesh

        prepared = prepare_mesh(source(animal))
        vertices, faces = prepared.vertices, prepared.faces
        if 0 < size < len(vertices):   # (size 0: as it is)
            vertices, faces = _decimate(vertices, faces, size)
        elif size > len(vertices) * 1.05:
            # Loop can grow spikes at an open boundary (the wolf's open mouth: its length 8.34 ->
            # 8.73); where it moves the mesh's extent by more than 1 % of its size, the mesh is split
            # at its edges' midpoints instead, which keeps its shape exactly
            times, original = 0, (vertices.min(axis=0), vertices.max(axis=0))
            while len(vertices) < size and times < 3:
                looped, looped_faces = trimesh.remesh.subdivide_loop(vertices, faces, iterations=1)
                moved = np.abs(np.concatenate([looped.min(axis=0) - original[0], looped.max(axis=0) - original[1]]))
                if moved.max() > 0.01 * np.linalg.norm(original[1] - original[0]):
                    looped, looped_faces = trimesh.remesh.subdivide(vertices, faces)
                vertices, faces = looped, looped_faces
                times += 1
            if len(vertices) < size:
                vertices, faces = trimesh.remesh.subdivide(vertices, faces)
            vertices, faces = _decimate(vertices, faces, size)
    partial = path.with_name(f"{path.stem}.{os.getpid()}.partial.npz")   # two invocations may make it at once
    np.savez(partial, vertices=np.asarray(vertices, dtype=float), faces=np.asarray(faces, dtype=np.int64))
    os.replace(partial, path)
    return path


# ---------------------------------------------------------------------------------------------
# One run (in its own process)


def _peak_mib() -> float:
    """This process's peak resident memory (VmHWM: it starts afresh at exec, where ru_maxrss keeps
    the forking parent's peak), MiB."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one_run(variant: Path, output: Path, mass_ratio: float, working_vertices: int | None, modes: int | None,
            direct: bool, full_measure: bool) -> None:
    import trimesh

    from allorules.body import Body
    from allorules.mesh.repair import prepare_mesh
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset

    data = np.load(variant)
    timing = {}
    start_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    wall = time.perf_counter()
    prepared = prepare_mesh(trimesh.Trimesh(data["vertices"], data["faces"], process=False))
    timing["prepare"] = time.perf_counter() - wall
    body = Body(prepared.vertices, prepared.faces)
    registry = registry_for(None)
    ruleset = load_ruleset("quadruped", registry)
    record = {"variant": variant.stem, "vertices": int(len(body.vertices)), "direct": direct}
    if direct:      # the yardstick: label and scale the body itself (the pipeline's scale stage, its fallbacks included)
        from allorules.runs import pipeline

        started = time.perf_counter()
        labelled = pipeline.label(body, registry=registry, regions=pipeline.wanted_regions(ruleset))
        timing["labels"] = time.perf_counter() - started
        started = time.perf_counter()
        result = pipeline.scale(labelled, pipeline.RulesetScaling(ruleset, mass_ratio), registry=registry, modes=modes,
                                use_cache=False)
        timing["run"] = time.perf_counter() - started
        vertices, labels, working = result.body.vertices, labelled.labels, None
        record["working"] = {"method": "direct", "vertices": int(len(body.vertices))}
    else:           # the run pipeline: working mesh, labels, run, carried back
        from allorules.runs import pipeline

        started = time.perf_counter()
        run = pipeline.run(body, pipeline.RulesetScaling(ruleset, mass_ratio), registry=registry, modes=modes,
                           use_cache=False, working_vertices=working_vertices)
        timing["run (working mesh, labels, run)"] = time.perf_counter() - started
        started = time.perf_counter()
        vertices = run.body_vertices()
        labels = run.body.labels if run.working is None else run.working.labels_to_user(run.body, body).labels
        timing["transfer"] = time.perf_counter() - started
        result = run.result
        working = run.working.mesh if run.working else None
        record["working"] = ({"method": "as-is", "vertices": int(len(body.vertices))} if working is None else
                             {"method": working.method, "vertices": int(len(working.vertices)),
                              "seconds": working.seconds, "quality": working.quality})
    timing["total"] = time.perf_counter() - wall
    record["peak_rss_mib"] = _peak_mib()
    record["rss_before_mib"] = start_rss / 1024
    record["seconds"] = timing
    record["converged"] = bool(result.converged)
    record["steps"] = len(result.steps)
    record["bases"] = None
    record["trials"] = [step.evaluations for step in result.steps]
    record["mass_ratio"] = float(result.mass_ratio)
    record["stress_ratio"] = None if result.stress_ratio is None else float(result.stress_ratio)
    record["flipped_faces"] = int(result.flipped_faces)
    record["rules"] = {rule.id: {"target": rule.exponent, "achieved": rule.achieved_exponent, "initial": rule.initial}
                       for rule in result.rules}
    record["messages"] = list(result.messages)
    if full_measure and working is not None and not working.is_source:
        # the rules measured afresh on the user's full-resolution body, before and after, with the carried labels
        import math

        from allorules.solve.energy import cached_measure

        started = time.perf_counter()
        measure = cached_measure(registry)
        before = Body(body.vertices, body.faces, labels, run.body.region_names, run.body.frame)
        after = Body(vertices, body.faces, labels, run.body.region_names, run.body.frame)
        record["full_resolution"] = {}
        for rule in ruleset.rules:
            try:
                q0, q1 = measure(rule.measure, before, rule.region), measure(rule.measure, after, rule.region)
                record["full_resolution"][rule.id] = {"initial": q0, "achieved": math.log(q1 / q0) / math.log(mass_ratio)}
            except Exception as error:  # a measure that fails at full resolution is a finding, not a crash
                record["full_resolution"][rule.id] = {"error": str(error)}
        mass = measure("mass", before, None), measure("mass", after, None)
        record["full_resolution"]["mass_ratio"] = mass[1] / mass[0]
        record["full_resolution_seconds"] = time.perf_counter() - started
    names = labelled.region_names if direct else run.body.region_names
    np.savez(output.with_suffix(".npz"), labels=labels, vertices=vertices, input_vertices=body.vertices,
             faces=body.faces, region_names=np.array(names))
    output.write_text(json.dumps(record, indent=1, default=float))


# ---------------------------------------------------------------------------------------------
# Comparison


def label_agreement(reference: Path, other: Path) -> float:
    """Share of the reference mesh's area whose label the other run gives too (the other's labels
    read at each reference vertex's closest point on the other's mesh)."""
    from allorules.mesh.geometry import vertex_areas
    from allorules.mesh.transfer import bind, carry_labels

    a, b = np.load(reference), np.load(other)
    names_a, names_b = list(a["region_names"]), list(b["region_names"])
    binding = bind(a["input_vertices"], b["input_vertices"], b["faces"])
    carried = np.array(names_b)[carry_labels(binding, b["labels"])]
    mine = np.array(names_a)[a["labels"]]
    mass = vertex_areas(a["input_vertices"], a["faces"])
    return float(mass[carried == mine].sum() / mass.sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mass-ratio", type=float, default=2.0)
    parser.add_argument("--animals", nargs="+", default=["generated", "horse"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[3000, 12000, 48000, 200000])
    parser.add_argument("--working-vertices", type=int, default=None)
    parser.add_argument("--modes", type=int, default=None)
    parser.add_argument("--million", action="store_true", help="also the horse at 1,000,000 vertices (time, memory)")
    parser.add_argument("--no-baseline", action="store_true", help="skip today's direct run on the 8.4k horse")
    parser.add_argument("--no-full-measure", action="store_true", help="skip measuring the full-resolution outputs")
    parser.add_argument("--reuse", action="store_true", help="read back runs an earlier invocation left in the work folder")
    parser.add_argument("--results", type=Path, default=RESULTS, help=f"where to write the results (default {RESULTS})")
    parser.add_argument("--one", nargs=7, help=argparse.SUPPRESS)
    arguments = parser.parse_args()
    if arguments.one:
        variant, output, ratio, working, modes, direct, full = arguments.one
        one_run(Path(variant), Path(output), float(ratio), None if working == "-" else int(working),
                None if modes == "-" else int(modes), direct == "1", full == "1")
        return

    runs: list[dict] = []

    def launch(animal: str, size: int, direct: bool = False, full: bool = True) -> dict | None:
        variant = make_variant(animal, size)
        kind = "direct" if direct else "working"
        output = WORK / f"run-{_name(animal)}-{size}-{kind}-{arguments.mass_ratio:g}.json"
        command = [sys.executable, __file__, "--one", str(variant), str(output), str(arguments.mass_ratio),
                   str(arguments.working_vertices or "-"), str(arguments.modes or "-"), "1" if direct else "0",
                   "1" if full and not arguments.no_full_measure else "0"]
        started = time.perf_counter()
        if arguments.reuse and output.exists():       # a run of an earlier invocation, read back
            finished = subprocess.CompletedProcess(command, 0, "", "")
        else:
            finished = subprocess.run(command, capture_output=True, text=True, env=dict(os.environ))
        if finished.returncode != 0:
            print(f"{animal} {size}: FAILED\n{finished.stderr[-2000:]}")
            return None
        record = json.loads(output.read_text())
        record["animal"], record["size"], record["load"] = animal, size, os.getloadavg()[0]
        record["process_seconds"] = time.perf_counter() - started
        record["npz"] = str(output.with_suffix(".npz"))
        runs.append(record)
        seconds = ", ".join(f"{key} {value:.1f}" for key, value in record["seconds"].items())
        worst = max(abs(rule["achieved"] - rule["target"]) for rule in record["rules"].values())
        print(f"{animal} {record['vertices']:>8} vertices -> {record['working']['method']} {record['working']['vertices']}: "
              f"{'converged' if record['converged'] else 'NOT converged'}, worst |e' - e| {worst:.3f}, "
              f"{seconds} s, peak {record['peak_rss_mib']:.0f} MiB, load {record['load']:.1f}", flush=True)
        return record

    if not arguments.no_baseline and (MESHES / "horse.obj").exists():
        launch("horse", 8431, direct=True)
    for animal in arguments.animals:
        if animal != "generated" and not source(animal).exists():
            print(f"{animal}: {source(animal)} absent, skipped")
            continue
        mine = [launch(animal, size) for size in arguments.sizes]
        mine = [record for record in mine if record is not None]
        if len(mine) < 2:
            continue
        finest = max(mine, key=lambda record: record["vertices"])
        print(f"{animal}: across {', '.join(str(record['vertices']) for record in mine)} vertices")
        agreements = {}
        for index, first in enumerate(mine):
            for second in mine[index + 1:]:
                reference, other = (first, second) if first["vertices"] >= second["vertices"] else (second, first)
                agreements[f"{reference['vertices']}~{other['vertices']}"] = label_agreement(Path(reference["npz"]), Path(other["npz"]))
        print(f"  labels agree on {min(agreements.values()):.1%} of the area at worst (goal >= 95%): "
              + ", ".join(f"{key} {value:.1%}" for key, value in agreements.items()))
        spread = {}
        for rule in finest["rules"]:
            initial = [record["rules"][rule]["initial"] for record in mine]
            achieved = [record["rules"][rule]["achieved"] for record in mine]
            full = [record.get("full_resolution", {}).get(rule, {}).get("achieved") for record in mine]
            full = [value for value in full if value is not None]
            spread[rule] = {"initial": max(initial) / min(initial) - 1, "achieved": max(achieved) - min(achieved),
                            "achieved_full": (max(full) - min(full)) if len(full) > 1 else None,
                            "worst_error": max(abs(value - finest["rules"][rule]["target"]) for value in achieved)}
            print(f"  {rule:16s} measurements spread {spread[rule]['initial']:.2%} (goal <= 2%), exponents spread "
                  f"{spread[rule]['achieved']:.4f} (goal <= 0.01), worst |e' - e| {spread[rule]['worst_error']:.4f}"
                  + (f", on full-resolution outputs: spread {spread[rule]['achieved_full']:.4f}" if spread[rule]["achieved_full"] is not None else ""))
        runs.append({"animal": animal, "summary": {"label_agreement": agreements, "spread": spread}})
    if arguments.million and (MESHES / "horse.obj").exists():
        launch("horse", 1_000_000, full=False)
    arguments.results.parent.mkdir(parents=True, exist_ok=True)
    arguments.results.write_text(json.dumps(runs, indent=1, default=float))
    print(f"wrote {arguments.results}")


if __name__ == "__main__":
    main()
