"""The demo: the whole method on the built-in generated quadruped, in one folder.

:func:`run_demo` generates a quadruped (:mod:`allorules.mesh.quadruped`), labels its six regions with
the automatic labeller (and says how well they agree with the generator's own regions), scales
it globally (paper §3.1) and biology-aware with the ``quadruped`` ruleset (§3.3) to mass ratios
0.5 and 2, and writes into a fresh folder:

* ``original.obj`` and one OBJ per run (``global_x0.5.obj``, ``biology_x2.obj``, …), each with its
  regions beside it (``biology_x2.labels.json``, read by ``allorules measure``);
* ``labels.json`` (the automatic labels) and ``regions.png`` (the regions in colour);
* ``gallery.png`` (rows minified / original / magnified, columns global / biology-aware, every
  animal drawn at the same length, as the paper's Figures 17–18) and ``gallery_true_scale.png``
  (the same at true relative size);
* one JSON report per run, ``demo.json`` (everything, including the rule table) and
  ``report.html`` (one offline page with the pictures and tables).

The rule table compares, per rule of the ruleset, the target exponent e with the achieved
exponent e' = log(q_final / q_initial) / log R measured on the output (METHOD §6), for both the
global and the biology-aware runs: global scaling does not know the rules, so its exponent errors show
what the biology-aware solver buys.

A previous demo is never overwritten silently: the default folder ``allorules-demo`` becomes
``allorules-demo-2``, ``-3``, … when it already holds files; a folder the user names must be
empty unless ``force``.
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from allorules.errors import AllorulesError, ScalingError

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

log = logging.getLogger("allorules")

DEFAULT_FOLDER = "allorules-demo"
DEFAULT_PRESET = "horse"
DEFAULT_RULESET = "quadruped"
RATIOS = (0.5, 2.0)
# Sizes chosen so that the demo finishes in minutes on 2 cores (measured: docs/demo.md); at most
# 2500 vertices (eigensolver.DENSE_LIMIT) the basis is one dense solve; 2500 vertices took ~10 CPU-minutes.
DEFAULT_VERTICES = 2000
DEFAULT_MODES = 60
QUICK_VERTICES = 1000
QUICK_MODES = 30
MODES = ("global", "biology")
MODE_TITLES = {"global": "global", "biology": "biology-aware"}


class DemoError(AllorulesError):
    """The demo cannot write where it was asked to."""


@dataclass
class DemoRun:
    """One scaling of the demo animal: mode (global / biology), mass ratio and what it did."""

    mode: str
    ratio: float
    mesh: Path | None = None
    report: Path | None = None
    vertices: np.ndarray | None = None
    result: dict[str, Any] = field(default_factory=dict)
    rules: list[dict[str, Any]] = field(default_factory=list)
    quality: dict[str, Any] = field(default_factory=dict)   # the pipeline's quality report (measure/quality.py)
    seconds: float = 0.0
    error: str | None = None
    outcome: Any = field(default=None, repr=False)   # the pipeline's Run (allorules.runs.pipeline)

    @property
    def name(self) -> str:
        return f"{self.mode}_x{self.ratio:g}"

    def summary(self) -> dict[str, Any]:
        return {
            "run": self.name, "mode": MODE_TITLES[self.mode], "mass ratio": self.ratio,
            "achieved mass ratio": self.result.get("mass_ratio"),
            "stress ratio": self.result.get("stress_ratio"),
            "steps": self.result.get("steps"), "converged": self.result.get("converged"),
            "seconds": round(self.seconds, 1), "mesh": self.mesh.name if self.mesh else None,
            "error": self.error,
        }


@dataclass
class DemoResult:
    """What :func:`run_demo` wrote (``files``: (what, path) in the order written) and measured."""

    folder: Path
    settings: dict[str, Any]
    files: list[tuple[str, Path]] = field(default_factory=list)
    runs: list[DemoRun] = field(default_factory=list)
    label_agreement: float | None = None
    timings: list[tuple[str, float]] = field(default_factory=list)
    seconds: float = 0.0

    def rule_rows(self) -> list[dict[str, Any]]:
        return [dict(row, run=run.name) for run in self.runs for row in run.rules]

    def file(self, what: str) -> Path:
        for name, path in self.files:
            if name == what:
                return path
        raise KeyError(what)


# ---------------------------------------------------------------------------------------------
# Where to write


def _holds_files(folder: Path) -> bool:
    return folder.exists() and any(folder.iterdir())


def choose_folder(output: str | Path | None, *, force: bool = False) -> Path:
    """The folder to write into (created). Default: ``allorules-demo``, else the first free
    ``allorules-demo-N``. A named folder that already holds files is refused unless ``force``."""
    if output is None:
        candidate, number = Path(DEFAULT_FOLDER), 2
        while _holds_files(candidate) and not force:
            candidate, number = Path(f"{DEFAULT_FOLDER}-{number}"), number + 1
        folder = candidate
    else:
        folder = Path(output)
        if folder.exists() and not folder.is_dir():
            raise DemoError(f"{folder}: is a file; give a folder for the demo's output")
        if _holds_files(folder) and not force:
            raise DemoError(f"{folder}: already holds files (a previous demo?); choose another folder "
                            "or pass --force to overwrite its files")
    if folder.exists() and not folder.is_dir():
        raise DemoError(f"{folder}: is a file; give a folder for the demo's output")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise DemoError(f"{folder}: cannot create the folder ({error.strerror or error})") from None
    return folder


# ---------------------------------------------------------------------------------------------
# Measuring


def label_agreement(generated, labelled) -> float:
    """Share of the surface (by vertex area) where the automatic labels match the generator's
    regions (its tail counted as abdomen, as the labeller does)."""
    import numpy as np

    from allorules.mesh.geometry import vertex_areas
    from allorules.segment.regions import NEIGHBOUR_REGION

    truth = np.array([NEIGHBOUR_REGION.get(generated.region_names[label], generated.region_names[label])
                      if label >= 0 else "" for label in generated.labels])
    found = np.array([labelled.region_names[label] if label >= 0 else "?" for label in labelled.labels])
    area = vertex_areas(labelled.vertices, labelled.faces)
    return float(area[truth == found].sum() / area.sum())


def rule_outcomes(initial, final, ruleset, registry, ratio: float) -> list[dict[str, Any]]:
    """Per rule: target exponent e, achieved e' = log(q_final / q_initial) / log R, exponent error
    e' − e (METHOD §6), plus body mass (target exponent 1) and peak stress (target 0)."""
    from allorules.measure.mass import body_mass

    rows = []
    log_ratio = math.log(ratio)

    def row(rule_id: str, region, measure: str, exponent: float, before: float, after: float) -> dict[str, Any]:
        achieved = math.log(after / before) / log_ratio if before > 0 and after > 0 else float("nan")
        return {"rule": rule_id, "region": region, "measure": measure, "target exponent": float(exponent),
                "achieved exponent": achieved, "exponent error": achieved - exponent,
                "initial": float(before), "final": float(after)}

    rows.append(row("body mass", None, "mass", 1.0, body_mass(initial), body_mass(final)))
    for rule in ruleset.rules:
        compute = registry.measure(rule.measure).compute
        rows.append(row(rule.id, rule.region, rule.measure, rule.exponent,
                        float(compute(initial, rule.region)), float(compute(final, rule.region))))
    return rows


def format_rule_table(rows: Sequence[dict[str, Any]]) -> str:
    """The terminal table: run, rule, target exponent, achieved exponent, exponent error (the same
    columns as ``allorules scale``)."""
    header = (f"{'run':<14} {'rule':<20} {'target exponent':>15} {'achieved exponent':>17} "
              f"{'exponent error':>14}")
    lines = [header, "-" * len(header)]
    for item in rows:
        achieved = item["achieved exponent"]
        text = "n/a" if not math.isfinite(achieved) else f"{achieved:.3f}"
        error = "n/a" if not math.isfinite(item["exponent error"]) else f"{item['exponent error']:+.3f}"
        lines.append(f"{item.get('run', ''):<14} {item['rule']:<20} {item['target exponent']:>15.3f} {text:>17} "
                     f"{error:>14}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# The demo


def run_demo(
    output: str | Path | None = None,
    *,
    preset: str = DEFAULT_PRESET,
    vertices: int | None = None,
    modes: int | None = None,
    quick: bool = False,
    force: bool = False,
    ratios: Sequence[float] = RATIOS,
    ruleset: str = DEFAULT_RULESET,
) -> DemoResult:
    """Run the demo (see the module docstring) and return what it wrote and measured.

    ``quick`` uses a coarser animal and fewer modes (``QUICK_VERTICES``/``QUICK_MODES``) unless
    ``vertices``/``modes`` are given. Steps and timings are logged at INFO level; the basis and
    solver show bars on a terminal (:mod:`allorules.runs.progress`).
    """
    from allorules.runs.progress import Steps

    start = time.perf_counter()
    vertices = int(vertices if vertices is not None else QUICK_VERTICES if quick else DEFAULT_VERTICES)
    modes = int(modes if modes is not None else QUICK_MODES if quick else DEFAULT_MODES)
    ratios = tuple(float(ratio) for ratio in ratios)
    folder = choose_folder(output, force=force)
    settings = {"preset": preset, "vertices requested": vertices, "modes": modes, "ratios": list(ratios),
                "ruleset": ruleset, "quick": bool(quick)}
    demo = DemoResult(folder=folder, settings=settings)
    steps = Steps(4 + 2 * len(ratios) + 1)

    generated, body, registry, rules = _prepare(demo, steps, preset, vertices, force, ruleset)
    for mode in MODES:
        for ratio in ratios:
            with steps.step(f"scale {MODE_TITLES[mode]} to mass ratio {ratio:g}"):
                run = _scale(body, mode, ratio, modes, rules, registry)
                _write_run(demo, run, body, force)
                demo.runs.append(run)
                if run.error:
                    log.warning("      %s failed: %s", run.name, run.error)
    with steps.step("draw the gallery and write the reports"):
        _write_pictures(demo, body)
        demo.timings = list(steps.timings)
        demo.seconds = time.perf_counter() - start
        _write_reports(demo, generated, body)
    demo.seconds = time.perf_counter() - start
    return demo


def _prepare(demo: DemoResult, steps, preset: str, vertices: int, force: bool, ruleset_name: str):
    from allorules.body import Body
    from allorules.mesh.quadruped import generate_quadruped
    from allorules.output.export import save_mesh
    from allorules.output.render import render_regions
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.runs.pipeline import label, wanted_regions
    from allorules.segment.labels_io import write_labels

    folder = demo.folder
    with steps.step(f"generate the built-in quadruped ({preset}, about {vertices} vertices)"):
        generated = generate_quadruped(preset, vertices=vertices)
        path = folder / "original.obj"
        save_mesh(path, generated.vertices, generated.faces, overwrite=force)
        demo.files.append(("original mesh", path))
        demo.settings["vertices"] = int(len(generated.vertices))
        demo.settings["faces"] = int(len(generated.faces))
    with steps.step(f"load the {ruleset_name!r} ruleset"):
        registry = registry_for(None)
        rules = load_ruleset(ruleset_name, registry)
    with steps.step("label head, neck, chest, abdomen, forelimbs, hindlimbs automatically"):
        body = label(Body(generated.vertices, generated.faces), registry=registry, segmenter=rules.segmenter,
                     regions=wanted_regions(rules))
        demo.label_agreement = label_agreement(generated, body)
        write_labels(folder / "labels.json", body)
        demo.files.append(("labels", folder / "labels.json"))
        render_regions(body, folder / "regions.png", title=f"automatic regions ({100 * demo.label_agreement:.1f} % of "
                      "the surface as the generator placed them)")
        demo.files.append(("regions picture", folder / "regions.png"))
        log.info("      %.1f %% of the surface agrees with the generator's regions", 100 * demo.label_agreement)
    with steps.step("measure the original"):
        from allorules.measure.mass import body_mass
        from allorules.measure.stress import peak_stress

        demo.settings["body mass"] = float(body_mass(body))
        demo.settings["peak stress"] = float(peak_stress(body))
    return generated, body, registry, rules


def _scale(body, mode: str, ratio: float, modes: int, ruleset, registry) -> DemoRun:
    from allorules.runs import pipeline
    from allorules.runs.progress import run_progress

    run = DemoRun(mode, ratio)
    start = time.perf_counter()
    result = None
    scaling = pipeline.GlobalScaling(ratio) if mode == "global" else pipeline.RulesetScaling(ruleset, ratio)
    try:
        run.outcome = pipeline.run(body, scaling, registry=registry, modes=modes, progress=run_progress(run.name))
        result = run.outcome.result
        run.quality = run.outcome.quality().as_dict()
    except ScalingError as error:
        run.error = str(error)
        result = error.closest if getattr(error, "closest", None) is not None and hasattr(error.closest, "body") else None
    except AllorulesError as error:
        run.error = str(error)
    run.seconds = time.perf_counter() - start
    if result is not None:
        import numpy as np

        run.vertices = np.asarray(result.body.vertices)
        run.result = result.as_dict()
        run.rules = rule_outcomes(body, result.body, ruleset, registry, ratio)
    return run


def _write_run(demo: DemoResult, run: DemoRun, body, force: bool) -> None:
    from allorules.files import write_json
    from allorules.runs.pipeline import save_output
    from allorules.segment.labels_io import labels_file_beside

    if run.outcome is not None and run.error is None:
        run.mesh = demo.folder / f"{run.name}.obj"
        save_output(run.outcome, run.mesh, overwrite=force)
        demo.files.append((f"{run.name} mesh", run.mesh))
        if labels_file_beside(run.mesh).is_file():      # its regions, for allorules measure
            demo.files.append((f"{run.name} labels", labels_file_beside(run.mesh)))
    run.report = demo.folder / f"{run.name}.json"
    document = {"run": run.name, "mode": MODE_TITLES[run.mode], "mass_ratio": run.ratio,
                "mesh": run.mesh.name if run.mesh else None, "seconds": run.seconds, "error": run.error,
                "result": run.result, "rules": run.rules, "quality": run.quality}
    write_json(run.report, document)
    demo.files.append((f"{run.name} report", run.report))


def _write_pictures(demo: DemoResult, body) -> None:
    from allorules.output.render import region_colors, render_gallery

    colors = region_colors(body.labels, body.region_names)
    by_key = {(run.mode, run.ratio): run for run in demo.runs if run.vertices is not None and run.error is None}
    smallest, largest = min(demo.settings["ratios"]), max(demo.settings["ratios"])
    grid: dict[str, dict[str, tuple]] = {}
    for mode in MODES:
        column = {"original": (body.vertices, body.faces, colors)}
        for row, ratio in (("minified", smallest), ("magnified", largest)):
            run = by_key.get((mode, ratio))
            if run is not None:
                column[row] = (run.vertices, body.faces, colors)
        grid[MODE_TITLES[mode]] = column
    frames = {MODE_TITLES[mode]: body.frame for mode in MODES}
    rows = ("minified", "original", "magnified")
    for name, normalise, title in (
        ("gallery.png", True, f"mass ×{smallest:g} / ×1 / ×{largest:g}, drawn at the same length"),
        ("gallery_true_scale.png", False, f"mass ×{smallest:g} / ×1 / ×{largest:g}, true relative size"),
    ):
        path = demo.folder / name
        render_gallery(grid, path=path, rows=rows, normalise_size=normalise, frames=frames, title=title)
        demo.files.append((name.removesuffix(".png").replace("_", " "), path))


def _quality_row(run: DemoRun) -> list:
    """A run's row of the HTML report's quality table, from its quality report."""
    quality = run.quality
    written = quality.get("written_flipped_faces") or quality["flipped_faces"]
    crossings = quality.get("self_intersections") or {}
    trunk = quality.get("trunk_shape_change")
    head = quality.get("head_turn_degrees")
    rules = quality.get("rules") or []
    return [run.name, written["count"], crossings.get("new_pairs", crossings.get("pairs")),
            _tenths(quality["roughness"]["rms_degrees"]), round(100 * quality["worst_feature_change"]),
            "–" if trunk is None else round(100 * trunk), "–" if head is None else _tenths(head),
            f"{sum(rule['met'] for rule in rules)} of {len(rules)}" if rules else "–"]


def _tenths(value: float) -> float:
    """``value`` to one decimal, never −0 (a table cell)."""
    return round(value, 1) + 0.0


def _write_reports(demo: DemoResult, generated, body) -> None:
    from allorules.files import write_json
    from allorules.output.html import Table, write_html_report

    summary_path = demo.folder / "demo.json"
    html_path = demo.folder / "report.html"
    files = [(what, path) for what, path in demo.files] + [("demo report", summary_path), ("HTML report", html_path)]
    document = {
        "settings": demo.settings,
        "label_agreement": demo.label_agreement,
        "runs": [run.summary() for run in demo.runs],
        "rules": demo.rule_rows(),
        "timings": [{"step": text, "seconds": round(seconds, 2)} for text, seconds in demo.timings],
        "seconds": round(demo.seconds, 2),
        "files": {what: path.name for what, path in files},
        "truth": generated.truth.as_dict() if hasattr(generated.truth, "as_dict") else None,
    }
    write_json(summary_path, document)
    demo.files.append(("demo report", summary_path))

    summary = {
        "animal": f"generated {demo.settings['preset']}, {demo.settings['vertices']:,} vertices",
        "ruleset": demo.settings["ruleset"],
        "basis modes": demo.settings["modes"],
        "automatic regions agreeing with the generator": f"{100 * demo.label_agreement:.1f} % of the surface",
        "body mass (mesh units)": demo.settings["body mass"],
        "peak stress (mesh units)": demo.settings["peak stress"],
        "total time": f"{demo.seconds:.0f} s",
    }
    runs = Table("Runs", ["run", "mode", "mass ratio", "achieved mass ratio", "stress ratio", "steps",
                          "converged", "seconds", "mesh", "error"],
                 [list(run.summary().values()) for run in demo.runs],
                 note="Stress ratio: peak stress after / before, at the same load-bearing limb section (target 1).")
    rules = Table("Rules: target against achieved exponent", ["run", "rule", "region", "target exponent",
                                                               "achieved exponent", "exponent error"],
                  [[row["run"], row["rule"], row["region"] or "body", row["target exponent"], row["achieved exponent"],
                    row["exponent error"]] for row in demo.rule_rows()],
                  note="Achieved exponent e' = log(q_final / q_initial) / log R on the output. Global scaling does not "
                       "know the rules; the biology-aware runs solve for them.")
    stance = Table("Legs: stance and shape over the run", ["run", "leg", "lean (°)", "foot lift (% of the leg)",
                                                           "bow added (% of the leg)"],
                   [[run.name, leg, _tenths(change["tilt_degrees"]), _tenths(100 * change["foot_lift"]),
                     _tenths(100 * change["bend"])]
                    for run in demo.runs for leg, change in run.result.get("posture", {}).items()],
                   note="No rule asks for these; Eq. 9 can meet every rule and still tilt, lift or bow a leg. "
                        "Bow: how far the leg's centre line strays from straight, change over the run.")
    quality = Table("Quality: what an artist would look for", ["run", "flipped faces", "new self-intersecting pairs",
                                                               "roughness (°)", "worst small feature (% of its size)",
                                                               "trunk beyond a stretch (% of its radius)",
                                                               "head turned (°)", "rules met"],
                    [_quality_row(run) for run in demo.runs if run.quality],
                    note="Measured on the output against the input (docs/measurements.md, docs/method.md): faces turned "
                         "inside out, face pairs passing through each other that did not before, the RMS change of the "
                         "dihedral angles (0 for uniform scaling), the largest shape change of a horn, ear, eye or hoof, "
                         "how far the trunk is from any stretch of itself (a hump, a sag or a bulge), and how far "
                         "the head turned (a nod nobody asked for).")
    timings = Table("Steps", ["step", "seconds"], [[text, round(seconds, 1)] for text, seconds in demo.timings])
    notes = [f"{run.name}: {run.error}" for run in demo.runs if run.error]
    notes += [f"{run.name}: {message}" for run in demo.runs for message in run.result.get("messages", [])]
    notes += [f"{run.name}: {warning}" for run in demo.runs for warning in run.result.get("warnings", [])]
    write_html_report(
        html_path, title=f"allorules demo: a generated {demo.settings['preset']}, scaled", summary=summary,
        tables=[runs, rules, stance, quality, timings], notes=notes,
        images=[(demo.file("gallery"), "Gallery: columns global / biology-aware, rows minified / original / magnified, "
                 "drawn at the same length (paper Figures 17–18)"),
                (demo.file("gallery true scale"), "The same at true relative size"),
                (demo.file("regions picture"), "The automatic regions")],
    )
    demo.files.append(("HTML report", html_path))


