"""Seated animals scaled with and without their folded legs' folds kept in each trial, side by side.

Run: .venv/bin/python benchmarks/bench_folded_legs.py [--animals horse.obj 387.off ...]
     [--scale 0.5 2] [--json FILE]

Each shared animal is labelled standing, seated by :func:`allorules.mesh.repose.repose` (the
``sit`` pose of :data:`allorules.mesh.quadruped_poses.POSES`), turned at random as
``bench_real_poses.py`` turns it, and scaled as ``allorules scale`` would (its labels found
afresh, the working mesh, ``quadruped``) twice in one process: once as the run is made
(``posture.LimbFolds`` part of each step's transform), once with ``LimbFolds.of`` returning None
(the folds left to Eq. 9, as before 5 December). Per run: converged, the worst rule's miss, how
far the legs turned, changed shape and had their folds opened or closed (the report's
``posture``: ``tilt_degrees``, ``shape_change``, ``fold_degrees``), new self-intersecting face
pairs, roughness, the runs made, seconds.
"""
from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path
from unittest import mock

import numpy as np
from bench_real_poses import _path
from scipy.spatial.transform import Rotation

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.quadruped_poses import POSES
from allorules.mesh.repair import prepare_mesh
from allorules.mesh.repose import repose
from allorules.rules.resolve import load_ruleset
from allorules.runs import pipeline
from allorules.segment.labeller import label_quadruped
from allorules.solve import posture


class _Tries(logging.Handler):
    """Counts the runs made again (the pipeline says so in its log)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += "trying again" in record.getMessage()


def _scale(vertices: np.ndarray, faces: np.ndarray, ratio: float) -> dict:
    started, tries = time.perf_counter(), _Tries()
    logging.getLogger("allorules").addHandler(tries)
    try:
        run = pipeline.run(Body(vertices, faces), pipeline.RulesetScaling(load_ruleset("quadruped"), ratio))
    except AllorulesError as error:
        return {"refused": str(error), "runs": 1 + tries.count, "seconds": time.perf_counter() - started}
    finally:
        logging.getLogger("allorules").removeHandler(tries)
    result, quality = run.result, run.quality()
    legs = quality.legs
    return {"converged": bool(result.converged),
            "worst_error": max(abs(rule.error) for rule in result.rules),
            "tilt": max(leg.tilt_degrees for leg in legs), "shape": max(leg.shape_change for leg in legs),
            "fold_degrees": {leg.leg: round(leg.fold_degrees, 1) for leg in legs if leg.leg.startswith("hind")},
            "new_intersections": quality.intersections.new_pairs if quality.intersections else None,
            "roughness": quality.roughness.rms_degrees,
            "runs": 1 + tries.count,
            "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--animals", nargs="*", default=["horse.obj", "387.off", "385.off", "wolf.obj", "lion.obj",
                                                         "381.off"])
    parser.add_argument("--scale", nargs="*", type=float, default=[0.5, 2.0])
    parser.add_argument("--json", type=Path, default=None)
    arguments = parser.parse_args()
    rows = []
    for name in arguments.animals:
        prepared = prepare_mesh(_path(name))
        standing = label_quadruped(Body(prepared.vertices, prepared.faces))
        rotation = Rotation.random(random_state=sum(map(ord, name + "sit"))).as_matrix()
        seated = repose(standing, POSES["sit"]) @ rotation.T
        for ratio in arguments.scale:
            for variant in ("left to Eq. 9", "kept"):
                if variant == "kept":
                    row = _scale(seated, prepared.faces, ratio)
                else:
                    with mock.patch.object(posture.LimbFolds, "of", return_value=None):
                        row = _scale(seated, prepared.faces, ratio)
                row = {"animal": name, "ratio": ratio, "folds": variant, **row}
                rows.append(row)
                print(json.dumps(row), flush=True)
    if arguments.json:
        arguments.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
