"""A run's outputs measured as an outside check might: as written, with the input's labels, and afresh.

Run: .venv/bin/python benchmarks/bench_output_relabelled.py GALLERY_OUT

GALLERY_OUT is a folder written by ``benchmarks/gallery_real_animals.py`` (NAME-xR.obj and
NAME-xR.json per run, and NAME-xR.labels.json, the regions the run wrote beside its mesh). For every
converged run, the input (from ``../shared/meshes``) and the output are measured with ``allorules
measure --json`` three ways: as written (the output with the labels file beside it, which
``measure`` reads; the input labelled as a run labels it), with the input's labels (``allorules
segment`` on the input; the output keeps the input's vertices in their order) and each labelled
afresh (``--relabel``). Prints, per run, each rule's achieved exponent both ways against its target, and the head's
vertex count each way. Record what it says in docs/measurements.md.

``--inputs DIR``: the inputs are ``DIR/NAME.obj`` where one is there (runs on one's own variants,
e.g. an animal subdivided to 200k vertices, scaled with ``allorules scale NAME.obj -o NAME-xR.obj
--report NAME-xR.json``), else the shared mesh.
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"
ALLORULES = Path(sys.executable).parent / "allorules"


def source(name: str, inputs: Path | None = None) -> Path:
    """The mesh a gallery run named ``name`` scaled: ``inputs/NAME.obj`` where given and there, else
    the shared mesh."""
    if inputs is not None and (inputs / f"{name}.obj").is_file():
        return inputs / f"{name}.obj"
    return SHARED / "psb-fourleg" / f"{name[4:]}.off" if name.startswith("psb-") else SHARED / f"{name}.obj"


def measure(mesh: Path, labels: Path | None = None, relabel: bool = False) -> dict[str, float] | None:
    """Each rule's quantity of ``mesh`` (labelled from ``labels``, else from its own labels file
    beside it, else afresh; ``relabel``: afresh), or None on a refusal."""
    command = [str(ALLORULES), "measure", str(mesh), "--json"] + (["--segmentation", str(labels)] if labels else []) \
        + (["--relabel"] if relabel else [])
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        return None
    document = json.loads(done.stdout)
    return {rule["id"]: rule["value"] for rule in document["rules"]}


def segment(mesh: Path, labels: Path) -> dict | None:
    """The labels ``allorules segment`` gives ``mesh``, written to ``labels``."""
    done = subprocess.run([str(ALLORULES), "segment", str(mesh), "-o", str(labels), "--force"], capture_output=True,
                          text=True)
    return json.loads(labels.read_text()) if done.returncode == 0 else None


def exponents(before: dict[str, float], after: dict[str, float], ratio: float) -> dict[str, float]:
    return {rule: math.log(after[rule] / before[rule]) / math.log(ratio) for rule in before}


def head_count(labels: dict | None) -> int | None:
    if labels is None or "head" not in labels["regions"]:
        return None
    return sum(1 for label in labels["labels"] if label == labels["regions"].index("head"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("gallery", type=Path)
    parser.add_argument("--inputs", type=Path, help="folder of the runs' inputs (NAME.obj), where not shared meshes")
    arguments = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        for report_path in sorted(path for path in arguments.gallery.glob("*-x*.json")
                                  if not path.name.endswith(".labels.json")):   # the outputs' own labels files
            name, ratio = report_path.stem.rsplit("-x", 1)
            mesh = source(name, arguments.inputs)
            report, output = json.loads(report_path.read_text()), report_path.with_suffix(".obj")
            if not report.get("converged") or not output.exists():
                print(f"{report_path.stem}: not converged, not measured")
                continue
            input_labels, output_labels = folder / f"{name}.labels.json", folder / f"{report_path.stem}.labels.json"
            labelled_in, labelled_out = segment(mesh, input_labels), segment(output, output_labels)
            afresh_in = measure(mesh, relabel=True)
            measured = {
                "as written": (afresh_in, measure(output)),
                "input's labels": (measure(mesh, input_labels), measure(output, input_labels)),
                "afresh": (afresh_in, measure(output, relabel=True)),
            }
            targets = {rule["id"]: rule["exponent"] for rule in report["rules"]}
            print(f"{report_path.stem}: head {head_count(labelled_in)} vertices as it comes, "
                  f"{head_count(labelled_out)} on the output labelled afresh")
            for how, (before, after) in measured.items():
                if before is None or after is None:
                    print(f"  {how}: could not be measured")
                    continue
                errors = {rule: value - targets[rule] for rule, value in exponents(before, after, float(ratio)).items()}
                print(f"  {how}: " + ", ".join(f"{rule} {error:+.3f}" for rule, error in errors.items()))


if __name__ == "__main__":
    main()
