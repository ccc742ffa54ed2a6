"""How long a whole biology-aware run takes: R = 2 (or ``--mass-ratio``) with ``quadruped``.

Run: .venv/bin/python benchmarks/bench_scale.py [--modes M] [--vertices N] [--mass-ratio R] [--skip-real]
     [--cold-bases K] [--basis-every B] [--whole]

``--cold-bases K`` times K cold bases of the same mesh right before its run, in the same process
(issue 16 §4: a whole R = 2 run should cost at most 4 of them), and prints the run in those units.
``--basis-every B`` sets how many steps one basis serves (biology_scaling.BASIS_EVERY by default).
``--whole`` times the run as ``allorules scale`` makes it: the working mesh, every region the
ruleset keeps apart, and the runs made again when the first misses (runs/pipeline.py), counted;
without it, the first run alone on the body labelled into six regions.

Two animals of about 8,400 vertices: the real horse of /work/shared/meshes (8,431 vertices,
labelled automatically; skipped when the folder is absent) and the generated horse. Prints wall
and CPU time of the run split into bases and solves, trials per step, each step's largest
residual and the achieved figures.
The basis cache is off, so every basis is computed. Record results in docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")

from allorules.body import Body
from allorules.plugins.registry import registry_for
from allorules.rules.resolve import load_ruleset
from allorules.runs.ruleset_run import scale_with_ruleset

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


def cold_bases(body: Body, modes: int | None, count: int) -> float:
    """Mean wall time of ``count`` cold bases of ``body`` (no cache, no warm start)."""
    from allorules.spectral.basis import compute_basis

    times = []
    for _ in range(count):
        started = time.perf_counter()
        compute_basis(body.vertices, body.faces, modes, use_cache=False)
        times.append(time.perf_counter() - started)
    print(f"  {count} cold bases: {', '.join(f'{t:.2f}' for t in times)} s (mean {sum(times) / count:.2f} s)")
    return sum(times) / count


def whole_run(body: Body, ruleset, mass_ratio: float, registry, modes: int | None):
    """The scale stage of ``allorules scale`` (its runs made again included) and how many runs it made."""
    from allorules.runs import pipeline

    runs = []

    def counted(*arguments, **options):
        runs.append(1)
        return scale_with_ruleset(*arguments, **options)

    pipeline.scale_with_ruleset, original = counted, pipeline.scale_with_ruleset
    try:
        result = pipeline.scale(body, pipeline.RulesetScaling(ruleset, mass_ratio), registry=registry, modes=modes,
                                use_cache=False)
    finally:
        pipeline.scale_with_ruleset = original
    return result, len(runs)


def run(name: str, body: Body, modes: int | None, mass_ratio: float = 2.0, basis_every: int | None = None,
        cold: int = 0, whole: bool = False) -> None:
    registry = registry_for(None)
    basis_time = cold_bases(body, modes, cold) if cold else None
    ruleset = load_ruleset("quadruped", registry)
    wall, cpu = time.perf_counter(), time.process_time()
    if whole:
        result, runs = whole_run(body, ruleset, mass_ratio, registry, modes)
    else:
        result, runs = scale_with_ruleset(body, ruleset, mass_ratio, registry=registry, modes=modes, use_cache=False,
                                          basis_every=basis_every), 1
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    bases = sum(step.basis_seconds for step in result.steps)
    solves = sum(step.solve_seconds for step in result.steps)
    trials = [step.evaluations for step in result.steps]
    print(f"{name}: {len(body.vertices)} vertices, {result.steps[0].modes} modes, {len(result.steps)} steps, "
          f"{runs} run{'s' * (runs > 1)}")
    kept = " (the kept run's)" if runs > 1 else ""
    print(f"  wall {wall:.1f} s (bases {bases:.1f} s, solves {solves:.1f} s{kept}), cpu {cpu:.1f} s, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"  trials per step {trials} (total {sum(trials)})")
    if basis_time:
        print(f"  the run = {wall / basis_time:.2f} cold bases of this mesh (goal: at most 4)")
    for index, step in enumerate(result.steps, 1):
        worst = max(step.residuals, key=lambda key: abs(step.residuals[key]))
        alphas = ", ".join(f"{region} {alpha:+.3f}" for region, alpha in step.alphas.items())
        print(f"  step {index}: {step.status}, largest residual {worst} {step.residuals[worst]:+.4f}; "
              f"s {step.scale:.4f}, alpha0 {step.alpha0:+.3f}, {alphas}")
    print(f"  converged {result.converged}, mass ratio {result.mass_ratio:.4f}, stress ratio "
          f"{result.stress_ratio if result.stress_ratio is None else round(result.stress_ratio, 4)}, "
          f"flipped faces {result.flipped_faces}")
    for rule in result.rules:
        print(f"  {rule.id:16s} target {rule.exponent:.3f} achieved {rule.achieved_exponent:.3f}")
    if result.posture:
        print(f"  posture ({ruleset.solver.posture}): legs lean up to "
              f"{max(change['tilt_degrees'] for change in result.posture.values()):.2f}°, feet lift up to "
              f"{100 * max(change['foot_lift'] for change in result.posture.values()):.1f}% of a leg")
    for message in result.messages:
        print(f"  ! {message}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", type=int, default=None, help="basis size (default 1000)")
    parser.add_argument("--vertices", type=int, default=8400, help="vertices of the generated horse")
    parser.add_argument("--mass-ratio", type=float, default=2.0, help="R (default 2)")
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--cold-bases", type=int, default=0, help="time this many cold bases of each mesh first")
    parser.add_argument("--basis-every", type=int, default=None, help="steps one basis serves")
    parser.add_argument("--skip-generated", action="store_true")
    parser.add_argument("--whole", action="store_true", help="the run as allorules scale makes it, runs made again included")
    arguments = parser.parse_args()
    if arguments.whole and arguments.basis_every:
        parser.error("--basis-every applies to the first run alone; leave it out with --whole")
    if not arguments.skip_real and (MESHES / "horse.obj").exists():
        from allorules.mesh.repair import prepare_mesh
        from allorules.segment.labeller import label_quadruped
        from allorules.segment.regions import fold_regions

        started = time.perf_counter()
        if arguments.whole:
            from allorules.runs import pipeline

            prepared = pipeline.prepare(MESHES / "horse.obj")
            body = pipeline.label_working(prepared, pipeline.working(prepared), registry=registry_for(None),
                                          regions=pipeline.wanted_regions(load_ruleset("quadruped")))
        else:
            prepared = prepare_mesh(MESHES / "horse.obj")
            body = fold_regions(label_quadruped(Body(prepared.vertices, prepared.faces)))   # the six regions
        print(f"real horse prepared and labelled in {time.perf_counter() - started:.1f} s")
        run("real horse (shared/meshes/horse.obj)", body, arguments.modes, arguments.mass_ratio,
            arguments.basis_every, arguments.cold_bases, arguments.whole)
    if not arguments.skip_generated:
        from allorules.mesh.quadruped import generate_quadruped
        from allorules.segment.regions import fold_regions

        generated = generate_quadruped("horse", vertices=arguments.vertices).body()
        if arguments.whole:                  # its own labels, with the regions a run keeps apart
            from allorules.runs.pipeline import wanted_regions

            generated = fold_regions(generated, wanted_regions(load_ruleset("quadruped")))
        run("generated horse", generated, arguments.modes, arguments.mass_ratio, arguments.basis_every,
            arguments.cold_bases, arguments.whole)


if __name__ == "__main__":
    main()
