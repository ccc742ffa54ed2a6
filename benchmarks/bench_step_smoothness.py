"""Are a step's residuals smooth in its variables? The first step of a whole run, probed.

Run: .venv/bin/python benchmarks/bench_step_smoothness.py [MESH] [--mass-ratio R]

The run is made as ``allorules scale`` makes it (working mesh, the regions a ruleset keeps apart,
basis cache off) up to the first step's forward differences; there, for every variable, the
residual vector's central difference at h = 1e-4, 1e-3, 1e-2, 3e-2 (of s relative to s) and its
second difference are printed, then plain Gauss-Newton steps with fresh Jacobians from the same
start. Smooth residuals give the same derivative at every h and second differences ∝ h²; noise
would show as derivatives that change with h. Default mesh: the shared real horse. Record what it
says in docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("ALLORULES_CACHE_DIR", "off")

import numpy as np

from allorules.plugins.registry import registry_for
from allorules.rules.resolve import load_ruleset
from allorules.runs import pipeline
from allorules.runs.ruleset_run import scale_with_ruleset
from allorules.solve import step as step_module

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
STEPS = (1e-4, 1e-3, 1e-2, 3e-2)
GAUSS_NEWTON = 6
FORWARD_DIFFERENCES = step_module._finite_difference_jacobian     # the solver's own, before it is probed


class _Probed(Exception):
    """Raised once the first step has been probed: the run goes no further."""


def probe(energy, at, lower, upper) -> None:
    names = ["s", "alpha0", *energy.transform.regions]
    names += [f"extra{index}" for index in range(len(at.variables) - len(names))]
    terms = list(at.residuals)
    print(f"residuals at the start: {dict(zip(terms, np.round(at.vector[:len(terms)], 5)))}")
    for index, name in enumerate(names):
        print(f"{name}:")
        for h in STEPS:
            step = h * at.variables[0] if index == 0 else h
            plus, minus = at.variables.copy(), at.variables.copy()
            plus[index] += step
            minus[index] -= step
            up, down = energy.evaluate(plus).vector[:len(terms)], energy.evaluate(minus).vector[:len(terms)]
            derivative = (up - down) / (2 * step)
            second = up + down - 2 * at.vector[:len(terms)]
            print(f"  h={h:<6g} derivative {np.array2string(derivative, precision=4, suppress_small=True)}"
                  f"  second difference {np.array2string(second, precision=1)}")
    variables, vector = at.variables.copy(), at.vector
    for iteration in range(GAUSS_NEWTON):
        jacobian = FORWARD_DIFFERENCES(energy, energy.evaluate(variables), lower, upper)
        delta = np.linalg.lstsq(jacobian, -vector, rcond=1e-10)[0]
        variables = np.clip(variables + delta, lower, upper)
        trial = energy.evaluate(variables)
        print(f"Gauss-Newton {iteration + 1}: step {dict(zip(names, np.round(delta, 3)))}; misfit {trial.misfit:.3g}, "
              f"residuals {np.round(trial.vector[:len(terms)], 5)}")
        vector = trial.vector
    raise _Probed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", type=Path, default=MESHES / "horse.obj")
    parser.add_argument("--mass-ratio", type=float, default=2.0)
    arguments = parser.parse_args()
    registry = registry_for(None)
    ruleset = load_ruleset("quadruped", registry)
    prepared = pipeline.prepare(arguments.mesh)
    body = pipeline.label_working(prepared, pipeline.working(prepared), registry=registry,
                                  regions=pipeline.wanted_regions(ruleset))
    step_module._finite_difference_jacobian = probe
    try:
        scale_with_ruleset(body, ruleset, arguments.mass_ratio, registry=registry, use_cache=False)
    except _Probed:
        pass
    finally:
        step_module._finite_difference_jacobian = FORWARD_DIFFERENCES


if __name__ == "__main__":
    main()
