"""Every real animal of shared/meshes at ×0.5, ×1 and ×2, run as a user runs it (issue 18 §5).

    .venv/bin/python benchmarks/gallery_real_animals.py OUT [--reuse] [--animals horse psb-383 ...]
                                                           [--pictures docs/images/gallery]

Each run is the command line in its own process,

    allorules scale MESH --ruleset quadruped --mass-ratio R -o OUT/NAME-xR.obj
                   --report OUT/NAME-xR.json --keep-unconverged

(basis cache as the user has it); ``--reuse`` reads back a run whose report is in OUT. For each
animal one picture: the three at true scale as they stand in one scene (the outputs as written,
read back in the input's vertex order), then close-ups of the head and of the tail (each framed
on the part, so what changes is its shape). A refused run is drawn as the mesh
``--keep-unconverged`` wrote, titled with why. Prints a Markdown table of the runs (also
OUT/summary.md) for docs/biology-scaling.md.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.image import imread
from PIL import Image

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.load import load_mesh
from allorules.output.render import render_closeups, render_comparison
from allorules.plugins.registry import registry_for
from allorules.rules.resolve import load_ruleset
from allorules.runs import pipeline

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "meshes"
ANIMALS = {name: SHARED / f"{name}.obj" for name in ("horse", "lion", "wolf", "camel", "elephant", "dog-lowpoly")}
ANIMALS.update({f"psb-{number}": SHARED / "psb-fourleg" / f"{number}.off" for number in range(381, 391)})
RATIOS = (0.5, 2.0)
ALLORULES = Path(sys.executable).parent / "allorules"


@dataclass
class RunFiles:
    """What one command-line run left in OUT."""

    ratio: float
    report: dict | None          # None: the command stopped before its report (a refusal)
    mesh: Path | None            # the output, or the kept unconverged output
    said: str                    # the command's last line on stderr
    seconds: float | None


def run_cli(name: str, path: Path, ratio: float, out: Path, reuse: bool) -> RunFiles:
    stem = f"{name}-x{ratio:g}"       # (not Path.with_suffix: "x0.5" has a suffix of its own)
    report, timing, said, output, kept = (out / f"{stem}{suffix}" for suffix in
                                          (".json", ".seconds", ".said", ".obj", ".unconverged.obj"))
    if not (reuse and (report.exists() or said.exists())):
        # the labels files written beside the meshes too: the command never replaces a file unasked
        for old in (report, said, timing, output, kept, out / f"{stem}.labels.json", out / f"{stem}.unconverged.labels.json"):
            old.unlink(missing_ok=True)
        started = time.time()
        done = subprocess.run([str(ALLORULES), "scale", str(path), "--ruleset", "quadruped", "--mass-ratio",
                               f"{ratio:g}", "-o", str(output), "--report", str(report),
                               "--keep-unconverged"], capture_output=True, text=True)
        timing.write_text(f"{time.time() - started:.1f}\n")
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        said.write_text((lines[-1] if lines else "") + "\n")
    mesh = next((candidate for candidate in (output, kept) if candidate.exists()), None)
    return RunFiles(ratio, json.loads(report.read_text()) if report.exists() else None, mesh,
                    said.read_text().strip() if said.exists() else "",
                    float(timing.read_text()) if timing.exists() else None)


def body_positions(prepared, mesh_path: Path) -> np.ndarray:
    """The output file's vertices on the input's prepared body (the file keeps the input's order)."""
    written = np.asarray(load_mesh(mesh_path).vertices, dtype=float)
    index = prepared.source_vertex_index
    if len(written) != len(index):
        raise ValueError(f"{mesh_path} has {len(written)} vertices, the input {len(index)}")
    positions = np.empty_like(prepared.vertices)
    positions[index[index >= 0]] = written[index >= 0]
    return positions


def verdict(files: RunFiles) -> str:
    if files.report is None:
        return "refused before scaling"
    if files.report["converged"]:
        return "converged"
    return "refused (kept unconverged)" if files.mesh else "refused"


def worst_rule(report: dict) -> tuple[str, float]:
    worst = max(report["rules"], key=lambda rule: abs(rule["error"]))
    return worst["id"], worst["error"]


def stack(paths: list[Path], target: Path) -> None:
    """Pictures one above the other (rows of pairs side by side), white-padded to one width."""
    rows = []
    for row in paths:
        images = [imread(path)[:, :, :3] for path in (row if isinstance(row, list) else [row])]
        height = max(image.shape[0] for image in images)
        rows.append(np.concatenate([np.pad(image, ((0, height - image.shape[0]), (0, 0), (0, 0)), constant_values=1.0)
                                    for image in images], axis=1))
    width = max(row.shape[1] for row in rows)
    picture = np.concatenate([np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0)), constant_values=1.0)
                              for row in rows], axis=0)
    # 256 colours are plenty for grey clay renders and make the docs' pictures a third of the size
    Image.fromarray(np.round(picture * 255).astype(np.uint8)).quantize(256).save(target, optimize=True)


def draw(name: str, path: Path, runs: list[RunFiles], out: Path, pictures: Path) -> str | None:
    """The animal's picture; returns why there are no close-ups, if there are none."""
    registry = registry_for(None)
    ruleset = load_ruleset("quadruped", registry)
    prepared = pipeline.prepare(path)
    user = Body(prepared.vertices, prepared.faces)
    meshes = {1.0: user.vertices}
    for files in runs:
        if files.mesh is not None:
            meshes[files.ratio] = body_positions(prepared, files.mesh)
    captions = {1.0: "input"}
    captions.update({files.ratio: f"x{files.ratio:g}: {verdict(files)}" for files in runs})
    try:
        work = pipeline.working(prepared)
        labelled = pipeline.label_working(prepared, work, registry=registry, segmenter=ruleset.segmenter,
                                          regions=pipeline.wanted_regions(ruleset))
        user = work.labels_to_user(labelled, user)
        missing = None
    except AllorulesError as error:
        missing = f"no regions: {error}"
    order = sorted(meshes)
    parts = [out / f"{name}-scene.png"]
    render_comparison([(meshes[ratio], user.faces, captions[ratio]) for ratio in order], path=parts[0],
                      normalise_size=False, frame=user.frame, shared_ground=True, size=(1200, 380),
                      title=f"{name}: x0.5, the input and x2 at true scale, as they stand in one scene")
    closeups = []
    for region, views in (("head", ("side", "three-quarter")), ("tail", ("side",))):
        if user.labels is None or region not in user.region_names:
            continue
        focus = user.labels == user.region_names.index(region)
        target = out / f"{name}-{region}.png"
        render_closeups([(meshes[ratio], user.faces, "input" if ratio == 1.0 else f"x{ratio:g}") for ratio in order],
                        focus, path=target, frame=user.frame, views=views, cell_size=(200, 150),
                        title=f"{region}, each framed on the part")
        closeups.append(target)
    if closeups:
        parts.append(closeups)
    pictures.mkdir(parents=True, exist_ok=True)
    stack(parts, pictures / f"{name}.png")
    return missing


def _flipped(quality: dict) -> str:
    """Faces folded as solved, and in the mesh written where they differ (unfolded, or carried)."""
    solved, written = quality["flipped_faces"]["count"], quality.get("written_flipped_faces")
    if written is None or written["count"] == solved and not quality.get("unfolded_faces"):
        return str(solved)
    return f"{solved} → {written['count']}"


def table_row(name: str, files: RunFiles) -> str:
    report = files.report
    seconds = f"{files.seconds:.0f} s" if files.seconds is not None else "–"
    if report is None:
        return f"| {name} | x{files.ratio:g} | **refused**: {files.said} | | | | | | {seconds} |"
    rule, error = worst_rule(report)
    opened = {}
    for item in report.get("open_regions", []):
        if item["measure"] == "length" and item["achieved_exponent"] is not None:
            opened[item["region"]] = item["achieved_exponent"]
    open_text = ", ".join(f"{region} {value:.3f}" for region, value in opened.items()) or "–"
    quality = report["quality"]
    trunk = report.get("trunk_length_exponent")
    why = "; ".join(report["messages"])[:160] if not report["converged"] else ""
    return (f"| {name} | x{files.ratio:g} | {'yes' if report['converged'] else '**no**: ' + why} | "
            f"{rule} {error:+.3f} | {report['mass_ratio']:.4f} | {open_text} | "
            f"{'–' if trunk is None else f'{trunk:.3f}'} | {_flipped(quality)} / "
            f"{quality['roughness']['rms_degrees']:.1f}° / {quality['worst_feature_change'] or 0:.2f} / "
            f"{_number(quality.get('trunk_shape_change'))} | {seconds} |")


def _number(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for the runs' files and the pictures' parts")
    parser.add_argument("--reuse", action="store_true", help="read back runs whose report is in OUT")
    parser.add_argument("--animals", nargs="*", default=list(ANIMALS), choices=list(ANIMALS))
    parser.add_argument("--pictures", type=Path, default=ROOT / "docs" / "images" / "gallery")
    arguments = parser.parse_args(argv)
    if not SHARED.is_dir():
        print(f"needs the shared meshes at {SHARED}", file=sys.stderr)
        return 2
    arguments.out.mkdir(parents=True, exist_ok=True)
    rows = ["| animal | ×R | converged | worst rule (error) | mass ratio | open regions' length exponent | "
            "trunk length exponent | flipped (as solved → written) / roughness / worst feature / trunk shape | wall |",
            "|---|---|---|---|---|---|---|---|---|"]
    for name in arguments.animals:
        runs = [run_cli(name, ANIMALS[name], ratio, arguments.out, arguments.reuse) for ratio in RATIOS]
        rows += [table_row(name, files) for files in runs]
        missing = draw(name, ANIMALS[name], runs, arguments.out, arguments.pictures)
        print("\n".join(rows[-2:]) + (f"\n  ({name}: {missing})" if missing else ""), flush=True)
    (arguments.out / "summary.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
