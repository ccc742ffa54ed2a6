"""Real animals in the generated animal's poses: labelled against their standing labels, and scaled.

Run: .venv/bin/python benchmarks/bench_real_poses.py [--animals horse.obj 387.off ...]
     [--poses walk gallop ...] [--scale 2 0.5] [--json FILE]

Each shared animal with hand marks (tests/data/hand_marks.json) is labelled standing as it comes;
those labels are its truth. It is then put into each pose of
:data:`allorules.mesh.quadruped_poses.POSES` from those labels (:func:`allorules.mesh.repose.repose`)
and turned at random, as a user's posed file would come, and labelled again: the share of the
surface whose label agrees with the standing one, the hand marks' verdict (nose on the head, each
foot on a leg; head and tail swapped?), or the refusal; a refusal is then settled as it says, with
the directions it names (``--forward``, or ``--up`` and ``--forward``) given from the standing
frame turned with the mesh, as a user who knows the file's axes gives them. With ``--scale``,
each posed animal is then scaled as ``allorules scale`` would (its own labels, the working mesh,
``quadruped``): converged, the worst rule's miss, the trunk's length exponent, folded faces,
seconds. Animals whose legs touch
(one piece for a pair) cannot be posed and are listed as such.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.geometry import vertex_areas
from allorules.mesh.quadruped_poses import POSES
from allorules.mesh.repair import prepare_mesh
from allorules.mesh.repose import repose
from allorules.segment import label_check
from allorules.segment.labeller import label_quadruped

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
HAND_MARKS = Path(__file__).resolve().parents[1] / "tests" / "data" / "hand_marks.json"


def _path(name: str) -> Path:
    return SHARED / "psb-fourleg" / name if name.endswith(".off") else SHARED / name


def _agreement(labelled: Body, truth: Body) -> float:
    """Share of the surface whose region name is the same in both."""
    got = np.asarray(labelled.region_names)[labelled.labels]
    want = np.asarray(truth.region_names)[truth.labels]
    area = vertex_areas(truth.vertices, truth.faces)
    return float(area[got == want].sum() / area.sum())


def _scale(vertices: np.ndarray, faces: np.ndarray, ratio: float) -> dict:
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline

    started = time.perf_counter()
    try:
        run = pipeline.run(Body(vertices, faces), pipeline.RulesetScaling(load_ruleset("quadruped"), ratio))
    except AllorulesError as error:
        return {"ratio": ratio, "refused": str(error), "seconds": time.perf_counter() - started}
    result = run.result
    worst = max(result.rules, key=lambda rule: abs(rule.error))
    return {"ratio": ratio, "converged": bool(result.converged), "worst_rule": worst.id,
            "worst_error": float(worst.error), "trunk": result.trunk_length_exponent,
            "flipped_faces": int(result.flipped_faces), "missed": run.missed() if not result.converged else "",
            "seconds": time.perf_counter() - started}


def _settled(error: AllorulesError, turned: np.ndarray, faces: np.ndarray, standing: Body, rotation: np.ndarray,
             marks) -> dict:
    """The refused animal labelled again with the directions its refusal names."""
    directions = {"forward": rotation @ standing.frame.forward}
    if "--up" in str(error):
        directions["up"] = rotation @ standing.frame.up
    try:
        labelled = label_quadruped(Body(turned, faces), **directions)
    except AllorulesError as again:
        return {"given": sorted(directions), "refused": str(again)}
    verdict = label_check.check_labels(labelled, marks)
    return {"given": sorted(directions), "agreement": _agreement(labelled, standing), "right": verdict.right,
            "swapped": verdict.swapped}


def main() -> None:
    marks_of = label_check.read_hand_marks(HAND_MARKS)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--animals", nargs="*", default=sorted(marks_of))
    parser.add_argument("--poses", nargs="*", default=["walk", "gallop", "rear", "graze", "lie", "sit"])
    parser.add_argument("--scale", nargs="*", type=float, default=[])
    parser.add_argument("--json", type=Path, default=None)
    arguments = parser.parse_args()
    if not SHARED.is_dir():
        raise SystemExit(f"{SHARED} is not present")
    rows = []
    for name in arguments.animals:
        prepared = prepare_mesh(_path(name))
        marks = marks_of[name].on_body(prepared.source_vertex_index)
        try:
            standing = label_quadruped(Body(prepared.vertices, prepared.faces))
        except AllorulesError as error:
            print(f"| {name} | – | standing refused: {error} |", flush=True)
            continue
        for pose in arguments.poses:
            row = {"animal": name, "pose": pose}
            try:
                posed = repose(standing, POSES[pose])
            except AllorulesError as error:
                row["cannot_pose"] = str(error)
                print(f"| {name} | {pose} | cannot be posed: {error} |", flush=True)
                rows.append(row)
                break
            rotation = Rotation.random(random_state=sum(map(ord, name + pose))).as_matrix()
            turned = posed @ rotation.T
            started = time.perf_counter()
            try:
                labelled = label_quadruped(Body(turned, prepared.faces))
            except AllorulesError as error:
                row.update(refused=str(error), seconds=time.perf_counter() - started)
                settled = row["settled"] = _settled(error, turned, prepared.faces, standing, rotation, marks)
                given = " and ".join(f"--{direction}" for direction in settled["given"])
                outcome = (f"refused again: {settled['refused']}" if "refused" in settled else
                           f"{settled['agreement']:.3f} {'right' if settled['right'] else 'WRONG'}"
                           f"{', SWAPPED' if settled['swapped'] else ''}")
                print(f"| {name} | {pose} | refused: {error} | given {given}: {outcome} |", flush=True)
                rows.append(row)
                continue
            verdict = label_check.check_labels(labelled, marks)
            row.update(agreement=_agreement(labelled, standing), right=verdict.right, swapped=verdict.swapped,
                       problems=list(verdict.problems), regions=[n for n in labelled.region_names
                                                                 if labelled.region_mask(n).any()],
                       seconds=time.perf_counter() - started)
            row["runs"] = [_scale(turned, prepared.faces, ratio) for ratio in arguments.scale]
            runs = "; ".join(
                f"×{run['ratio']:g} refused: {run['refused']}" if "refused" in run else
                f"×{run['ratio']:g} {'converged' if run['converged'] else 'NOT converged'}, worst {run['worst_rule']} "
                f"{run['worst_error']:+.3f}, trunk {run['trunk'] if run['trunk'] is None else round(run['trunk'], 3)}, "
                f"{run['flipped_faces']} folded, {run['seconds']:.0f} s" + (f" ({run['missed']})" if run["missed"] else "")
                for run in row["runs"])
            print(f"| {name} | {pose} | {row['agreement']:.3f} | {'right' if verdict.right else 'WRONG'}"
                  f"{', SWAPPED' if verdict.swapped else ''} | {runs} |", flush=True)
            rows.append(row)
    if arguments.json:
        arguments.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
