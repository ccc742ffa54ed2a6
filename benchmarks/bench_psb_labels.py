"""Automatic regions against the human segmentations of the Princeton benchmark's ten quadrupeds.

Run: .venv/bin/python benchmarks/bench_psb_labels.py [--pictures DIR] [--json FILE]

For each model of ``../shared/meshes/psb-fourleg`` (381–390): the automatic labels (every region
found: the six and a tail, ears, horns or trunk) as per-face segments, compared with each person's
``seg/NNN/NNN_K.seg`` by the benchmark's Rand index. Chen, Golovinskiy and Funkhouser (2009) report
``1 − RI``, the share of face pairs the two segmentations disagree on (same segment in one, different
in the other); 0 is identical, lower is better. Per model it is averaged over the people, then over
the models. For scale, the same is given for the people among themselves (each person against the
others), for one segment over the whole mesh, and for the labeller's six regions alone (tail, ears
and horns folded into their neighbours).

Granularity: the people cut at their own grain (some split every leg at the knee, some keep the tail,
ears or horns apart, some cut the torso once, some not at all), while the labeller always makes the
six regions plus what it finds. Faces are unweighted, as in the benchmark, so a fine tessellation
of the head weighs more than a coarse torso. Rand index measures agreement on which faces belong
together, not the names: it does not tell head from tail (the hand marks in tests/data do).

Also prints, per model, the labelling's confidence and seconds, and draws each model's regions
(default docs/images/psb-NNN-regions.png).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.repair import prepare_mesh
from allorules.output.render import render_regions
from allorules.segment.labeller import label_quadruped
from allorules.segment.labels_io import face_labels_from_vertices
from allorules.segment.regions import fold_regions

PSB = Path(__file__).resolve().parents[1].parent / "shared" / "meshes" / "psb-fourleg"
PICTURES = Path(__file__).resolve().parents[1] / "docs" / "images"
MODELS = tuple(str(n) for n in range(381, 391))


def rand_index_complement(first: np.ndarray, second: np.ndarray) -> float:
    """1 − RI of two per-face segmentations, as the Princeton benchmark computes it: with a the
    sizes of the first's segments, b the second's and n the sizes of their intersections,
    (Σ a(a−1) + Σ b(b−1) − 2 Σ n(n−1)) / (N(N−1)), N faces."""
    first = np.unique(np.asarray(first), return_inverse=True)[1]
    second = np.unique(np.asarray(second), return_inverse=True)[1]
    count = len(first)
    table = np.zeros((first.max() + 1, second.max() + 1))
    np.add.at(table, (first, second), 1.0)

    def pairs(sizes):
        return float((sizes * (sizes - 1)).sum())

    return (pairs(table.sum(axis=1)) + pairs(table.sum(axis=0)) - 2.0 * pairs(table)) / (count * (count - 1.0))


def _shrink(path: Path) -> None:
    """Rewrite a picture at half size with a 128-colour palette (a tenth of the bytes, for docs/)."""
    from PIL import Image

    image = Image.open(path).convert("RGB")
    image = image.resize((image.width // 2, image.height // 2), Image.LANCZOS)
    image.quantize(colors=128).save(path, optimize=True)


def read_segmentations(model: str) -> list[np.ndarray]:
    return [np.loadtxt(path, dtype=np.int64) for path in sorted((PSB / "seg" / model).glob(f"{model}_*.seg"),
                                                                key=lambda p: int(p.stem.split("_")[1]))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pictures", default=str(PICTURES), help="folder for psb-NNN-regions.png ('' for none)")
    parser.add_argument("--json", default=None, help="also write the numbers here")
    arguments = parser.parse_args()
    if not PSB.is_dir():
        raise SystemExit(f"{PSB} is not here")
    rows = []
    print("| model | animal's regions found | people | 1 − RI: labeller (all regions) | labeller (six) | people among "
          "themselves | one segment | confidence feet / fore-hind / head-tail | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    for model in MODELS:
        prepared = prepare_mesh(PSB / f"{model}.off")
        if len(prepared.faces) != len(prepared.source.faces) or not np.array_equal(prepared.faces, prepared.source.faces):
            raise SystemExit(f"{model}: preparation changed the faces; the .seg files would not line up")
        humans = read_segmentations(model)
        among = np.mean([np.mean([rand_index_complement(h, g) for j, g in enumerate(humans) if j != i])
                         for i, h in enumerate(humans)])
        one = np.mean([rand_index_complement(np.zeros(len(h), dtype=np.int64), h) for h in humans])
        started = time.perf_counter()
        try:
            labelled = label_quadruped(Body(prepared.vertices, prepared.faces))
        except AllorulesError as error:
            seconds = time.perf_counter() - started
            rows.append({"model": model, "refused": str(error), "people": len(humans), "among": among, "one": one})
            print(f"| {model} | refused: {error} | {len(humans)} | – | – | {among:.3f} | {one:.3f} | – | {seconds:.1f} |")
            continue
        seconds = time.perf_counter() - started
        faces = face_labels_from_vertices(prepared.faces, labelled.labels)
        six = face_labels_from_vertices(prepared.faces, fold_regions(labelled).labels)
        ours = float(np.mean([rand_index_complement(faces, h) for h in humans]))
        ours_six = float(np.mean([rand_index_complement(six, h) for h in humans]))
        confidence = labelled.labelling.confidence
        rows.append({"model": model, "regions": list(labelled.region_names), "people": len(humans),
                     "labeller": ours, "labeller_six": ours_six, "among": among, "one": one,
                     "confidence": confidence, "seconds": seconds})
        extra = ", ".join(labelled.region_names[6:]) or "–"
        print(f"| {model} | six + {extra} | {len(humans)} | {ours:.3f} | {ours_six:.3f} | {among:.3f} | {one:.3f} | "
              f"{confidence['feet']:.2f} / {confidence['fore-hind pairs']:.2f} / {confidence['head-tail']:.2f} | "
              f"{seconds:.1f} |", flush=True)
        if arguments.pictures:
            picture = Path(arguments.pictures) / f"psb-{model}-regions.png"
            render_regions(labelled, picture, title=f"PSB {model}: automatic regions (1 − RI {ours:.3f} against "
                           f"{len(humans)} people)")
            _shrink(picture)
    done = [row for row in rows if "labeller" in row]
    if done:
        print(f"| mean of {len(done)} | | | {np.mean([r['labeller'] for r in done]):.3f} | "
              f"{np.mean([r['labeller_six'] for r in done]):.3f} | {np.mean([r['among'] for r in done]):.3f} | "
              f"{np.mean([r['one'] for r in done]):.3f} | | |")
    if arguments.json:
        Path(arguments.json).write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
