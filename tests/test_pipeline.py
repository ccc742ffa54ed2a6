"""The run pipeline every front end calls, the segmenter hook through it, and plugins contained."""
from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from allorules.body import Body
from allorules.cli import main
from allorules.errors import MeasurementError, PluginError, SegmentationError
from allorules.mesh.quadruped import generate_quadruped
from allorules.plugins.registry import registry_for
from allorules.rules.resolve import check_ruleset, load_ruleset
from allorules.runs import pipeline
from allorules.segment.regions import fold_regions

# A segmenter plugin that leaves a marker and labels with the regions of a labels file.
MARKING_SEGMENTER = """
from pathlib import Path

from allorules.body import Labelling
from allorules.plugins import ParameterSpec, SegmenterSpec, hookimpl
from allorules.segment.labels_io import read_labels


def segment(body, *, labels, marker):
    Path(marker).write_text("called", encoding="utf-8")
    labelled = read_labels(labels, body)
    return labelled.with_labels(labelled.labels, labelled.region_names, Labelling("truth", {"certain": 1.0}))


@hookimpl
def allorules_segmenters():
    return [SegmenterSpec("from-truth", "the generator's own regions, and a marker", segment,
                          {"labels": ParameterSpec(None, "labels file", kind=Path, required=True),
                           "marker": ParameterSpec(None, "file to touch", kind=Path, required=True)})]
"""


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text).lstrip("\n"), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def animal_files(tmp_path_factory):
    """A small generated horse as OBJ, its true labels (with a tail), a segmenter plugin and a
    ruleset naming it with options relative to the ruleset's folder."""
    import trimesh

    folder = tmp_path_factory.mktemp("pipeline")
    horse = generate_quadruped("horse", 1200)
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(folder / "horse.obj")
    (folder / "horse.labels.json").write_text(json.dumps(horse.labels_document()))
    write(folder, "truth_segmenter.py", MARKING_SEGMENTER)
    write(folder, "truthful.yaml", """
        extends: quadruped
        plugins: [truth_segmenter.py]
        segmenter:
          name: from-truth
          options: {labels: horse.labels.json, marker: marker.txt}
        solver: {step_ratio_up: 1.1}
        """)
    return folder, horse


def truth_folded(horse) -> tuple[np.ndarray, tuple[str, ...]]:
    """The truth as a `quadruped` run keeps it: its tail apart (held by its shape, the default)."""
    folded = fold_regions(horse.body(), pipeline.wanted_regions(load_ruleset("quadruped")))
    return folded.labels, folded.region_names


def labels_as_names(body: Body) -> np.ndarray:
    return np.asarray(body.region_names, dtype=object)[body.labels]


# -- a ruleset's segmenter labels every run --------------------------------------------------------


def test_a_rulesets_segmenter_labels_a_scale_run_and_the_report_names_it(animal_files, tmp_path):
    folder, horse = animal_files
    (folder / "marker.txt").unlink(missing_ok=True)
    report = tmp_path / "report.json"
    code = main(["scale", str(folder / "horse.obj"), "--ruleset", str(folder / "truthful.yaml"), "--mass-ratio", "1.05",
                 "--modes", "30", "-o", str(tmp_path / "out.obj"), "--report", str(report), "--keep-unconverged"])
    assert (folder / "marker.txt").read_text() == "called"
    data = json.loads(report.read_text())
    assert data["labels"]["source"] == "segmenter from-truth (plugin truth_segmenter)"
    assert data["labels"]["confidence"] == {"certain": 1.0}
    assert code in (0, 2)       # converged or not, the run was labelled by the plugin
    # the regions are the file's (the tail kept apart), not the automatic labeller's
    truth, names = truth_folded(horse)
    assert set(data["labels"]["regions"]) == set(names)


def test_the_segmenter_changes_what_a_run_labels(animal_files):
    folder, horse = animal_files
    registry = registry_for([])
    ruleset = load_ruleset(folder / "truthful.yaml", registry)
    prepared = pipeline.prepare(folder / "horse.obj")
    body = Body(prepared.vertices, prepared.faces)
    by_plugin = pipeline.label(body, registry=registry, segmenter=ruleset.segmenter,
                               regions=pipeline.wanted_regions(ruleset))
    automatic = pipeline.label(body, registry=registry, regions=pipeline.wanted_regions(ruleset))
    truth, names = truth_folded(horse)
    assert list(labels_as_names(by_plugin)) == list(np.asarray(names, dtype=object)[truth])
    assert np.mean(labels_as_names(by_plugin) != labels_as_names(automatic)) > 0.001   # the labeller differs somewhere
    assert automatic.labelling.source == "segmenter auto-quadruped"


def test_measure_uses_the_rulesets_segmenter(animal_files, capsys):
    folder, _ = animal_files
    (folder / "marker.txt").unlink(missing_ok=True)
    assert main(["measure", str(folder / "horse.obj"), "--ruleset", str(folder / "truthful.yaml"), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert (folder / "marker.txt").exists()
    assert data["labels"]["source"] == "segmenter from-truth (plugin truth_segmenter)"


def test_segment_command_takes_a_segmenter_from_a_plugin(animal_files, tmp_path, capsys):
    folder, horse = animal_files
    out = tmp_path / "labels.json"
    assert main(["segment", str(folder / "horse.obj"), "--plugin", str(folder / "truth_segmenter.py"),
                 "--segmenter", "from-truth", "--option", f"labels={folder / 'horse.labels.json'}",
                 "--option", f"marker={tmp_path / 'm.txt'}", "-o", str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["labelling"]["source"] == "segmenter from-truth (plugin truth_segmenter)"
    assert "tail" in document["regions"]                   # a labels file keeps every region it holds
    assert (tmp_path / "m.txt").exists()


def test_segment_command_refuses_unknown_options(animal_files, tmp_path, capsys):
    folder, _ = animal_files
    code = main(["segment", str(folder / "horse.obj"), "--plugin", str(folder / "truth_segmenter.py"),
                 "--segmenter", "from-truth", "--option", "label=x.json", "-o", str(tmp_path / "l.json")])
    assert code != 0
    assert "unknown option 'label'; did you mean 'labels'?" in capsys.readouterr().err


def test_the_api_runs_the_same_pipeline(animal_files, tmp_path):
    from allorules.api import scale_mesh

    folder, _ = animal_files
    (folder / "marker.txt").unlink(missing_ok=True)
    run = scale_mesh(folder / "horse.obj", 1.05, ruleset=folder / "truthful.yaml", modes=30)
    assert (folder / "marker.txt").exists()
    assert run.report()["labels"]["source"].startswith("segmenter from-truth")
    assert run.output_vertices().shape == run.prepared.vertices.shape


@pytest.mark.slow
def test_batch_jobs_are_labelled_by_the_rulesets_segmenter(animal_files, tmp_path):
    from allorules.runs.batch import run_batch

    folder, _ = animal_files
    (folder / "marker.txt").unlink(missing_ok=True)
    manifest = write(folder, "manifest.yaml", f"""
        output: {tmp_path / 'out'}
        meshes: [horse.obj]
        ratios: [1.05]
        rulesets: [truthful.yaml]
        modes: 30
        """)
    result = run_batch(manifest, jobs=1)
    [row] = result.rows
    report = json.loads((tmp_path / "out" / row["job"] / "report.json").read_text())
    assert (folder / "marker.txt").exists()
    assert report["labels"]["source"] == "segmenter from-truth (plugin truth_segmenter)"


def test_a_labels_file_overrides_the_segmenter(animal_files):
    folder, horse = animal_files
    registry = registry_for([])
    ruleset = load_ruleset(folder / "truthful.yaml", registry)
    prepared = pipeline.prepare(folder / "horse.obj")
    labelled = pipeline.label(Body(prepared.vertices, prepared.faces), registry=registry, segmenter=ruleset.segmenter,
                              labels=folder / "horse.labels.json", regions=pipeline.wanted_regions(ruleset))
    assert labelled.labelling.source == f"labels file {folder / 'horse.labels.json'}"


def test_regions_a_ruleset_lists_are_kept_others_fold_into_their_neighbour(animal_files, tmp_path):
    folder, horse = animal_files
    write(tmp_path, "with-tail.yaml", "extends: quadruped\nregions: [head, neck, chest, abdomen, forelimbs, hindlimbs, tail]\n")
    registry = registry_for([])
    prepared = pipeline.prepare(folder / "horse.obj")
    body = Body(prepared.vertices, prepared.faces)
    with_tail = pipeline.label(body, registry=registry, labels=folder / "horse.labels.json",
                               regions=pipeline.wanted_regions(load_ruleset(tmp_path / "with-tail.yaml", registry)))
    write(tmp_path, "soft.yaml", "extends: quadruped\nopen_regions: {hold: soft}\n")
    without = pipeline.label(body, registry=registry, labels=folder / "horse.labels.json",
                             regions=pipeline.wanted_regions(load_ruleset(tmp_path / "soft.yaml", registry)))
    assert "tail" in with_tail.region_names and "tail" not in without.region_names
    # held by their shape (the default), appendages are kept apart without being listed
    default = pipeline.label(body, registry=registry, labels=folder / "horse.labels.json",
                             regions=pipeline.wanted_regions(load_ruleset("quadruped", registry)))
    assert np.array_equal(labels_as_names(default), labels_as_names(with_tail))
    tail = with_tail.region_mask("tail")
    assert tail.any() and np.all(labels_as_names(without)[tail] == "abdomen")


# -- ruleset segmenter options are validated with file:line ------------------------------------------


@pytest.mark.parametrize("segmenter, message", [
    ("segmenter: {name: merge-file}", "segmenter 'merge-file': needs option 'path'"),
    ("segmenter: {name: merge-file, options: {path: m.yaml, patchs: 3}}", "unknown option 'patchs'; did you mean 'patches'?"),
    ("segmenter: {name: merge-file, options: {path: m.yaml, patches: many}}", "option 'patches' must be an integer"),
    ("segmenter: {name: auto-quadruped, options: {up: [0, 0, 0]}}", "option 'up' must be a direction"),
    ("segmenter: auto-quadrupde", "unknown segmenter 'auto-quadrupde'; did you mean 'auto-quadruped'?"),
    ("segmenter: {name: auto-quadruped, optons: {}}", "unknown key 'optons'"),
])
def test_segmenter_options_are_checked_with_file_and_line(tmp_path, segmenter, message):
    path = write(tmp_path, "set.yaml", f"extends: quadruped\n{segmenter}\n")
    problems = check_ruleset(path, registry_for([]))
    assert problems, "the ruleset should be refused"
    assert message in str(problems[0]) and f"{path}:2" in str(problems[0])


def test_merge_file_segmenter_path_is_relative_to_the_ruleset(tmp_path):
    (tmp_path / "sets").mkdir()
    path = write(tmp_path / "sets", "set.yaml", "extends: quadruped\nsegmenter: {name: merge-file, options: {path: m.yaml}}\n")
    ruleset = load_ruleset(path, registry_for([]))
    assert ruleset.segmenter.options["path"] == (tmp_path / "sets" / "m.yaml").resolve()
    assert load_ruleset(path, registry_for([])).segmenter == ruleset.segmenter


# -- a misbehaving plugin ends in one line that names it ---------------------------------------------

MISBEHAVING = """
import sys

from allorules.plugins import ConstraintSpec, MeasureSpec, SegmenterSpec, hookimpl


def raises(body, region):
    raise ValueError("division by zero somewhere")


def exits(body, region):
    sys.exit(3)


def negative(body, region):
    return -2.5


def text(body, region):
    return "long"


def not_a_body(body):
    return [1, 2, 3]


@hookimpl
def allorules_measures():
    return [MeasureSpec("raises", "length", 1 / 3, raises, "raises"),
            MeasureSpec("exits", "length", 1 / 3, exits, "exits"),
            MeasureSpec("negative", "length", 1 / 3, negative, "negative"),
            MeasureSpec("text", "length", 1 / 3, text, "text"),
            MeasureSpec("oddkind", "weight", 1 / 3, negative, "its kind is not a kind")]


@hookimpl
def allorules_segmenters():
    return [SegmenterSpec("not-a-body", "returns a list", not_a_body)]


@hookimpl
def allorules_constraints():
    return [ConstraintSpec("bad-residuals", "returns text", lambda context, parameters: {"x": "big"})]
"""


@pytest.fixture()
def misbehaving(tmp_path):
    return write(tmp_path, "misbehaving.py", MISBEHAVING)


@pytest.mark.parametrize("measure, message", [
    ("raises", "plugin 'misbehaving', measure 'raises', failed with ValueError: division by zero somewhere"),
    ("exits", "plugin 'misbehaving', measure 'exits', called sys.exit(3)"),
    ("negative", "plugin 'misbehaving', measure 'negative', returned -2.5; a measure must be a positive"),
    ("text", "plugin 'misbehaving', measure 'text', returned a str"),
])
def test_a_plugin_measure_that_misbehaves_is_named(misbehaving, measure, message):
    spec = registry_for([misbehaving], entry_points=False).measure(measure)
    body = generate_quadruped("horse", 600).body()
    with pytest.raises(PluginError) as caught:
        spec.compute(body, "head")
    assert str(caught.value).startswith(message) and "\n" not in str(caught.value)


def test_a_plugins_own_error_keeps_its_kind_and_names_the_plugin(tmp_path):
    plugin = write(tmp_path, "careful.py", """
        from allorules.errors import MeasurementError
        from allorules.plugins import MeasureSpec, hookimpl

        def wings(body, region):
            raise MeasurementError("this body has no wings")

        @hookimpl
        def allorules_measures():
            return [MeasureSpec("wing-span", "length", 1 / 3, wings, "span")]
        """)
    spec = registry_for([plugin], entry_points=False).measure("wing-span")
    with pytest.raises(MeasurementError, match="^plugin 'careful', measure 'wing-span': this body has no wings$"):
        spec.compute(generate_quadruped("horse", 600).body(), None)


def test_a_measure_of_an_unknown_kind_is_refused(misbehaving):
    registry = registry_for([misbehaving], entry_points=False)
    assert "oddkind" not in registry.measures()
    assert any("kind 'weight' is not one of" in failure.message for failure in registry.failures)


def test_a_segmenter_and_a_constraint_that_return_the_wrong_thing_are_named(misbehaving):
    registry = registry_for([misbehaving], entry_points=False)
    body = generate_quadruped("horse", 600).body()
    with pytest.raises(PluginError, match="segmenter 'not-a-body', returned a list; a segmenter returns the Body"):
        registry.segmenter("not-a-body").segment(body)
    with pytest.raises(PluginError, match="constraint 'bad-residuals', returned 'x': 'big'"):
        registry.constraint("bad-residuals").residuals(None, {})


def test_the_command_line_names_the_plugin_in_one_line(misbehaving, animal_files, tmp_path, capsys):
    mesh = animal_files[0] / "horse.obj"
    ruleset = write(tmp_path, "set.yaml", f"""
        extends: quadruped
        plugins: [{misbehaving}]
        rules:
          - {{id: odd, region: head, measure: raises, exponent: 0.3}}
        """)
    code = main(["measure", str(mesh), "--ruleset", str(ruleset)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and "Traceback" not in "\n".join(err)
    assert err[-1].startswith("allorules measure: error: ") and "plugin 'misbehaving', measure 'raises'" in err[-1]


def test_sys_exit_in_a_hook_is_named_not_a_silent_exit(tmp_path, capsys):
    plugin = write(tmp_path, "quitter.py", """
        import sys
        from allorules.plugins import hookimpl

        @hookimpl
        def allorules_measures():
            sys.exit(4)
        """)
    assert main(["plugins", "--plugin", str(plugin)]) == 1       # the command lists it as failed
    err = capsys.readouterr().err
    assert "plugin 'quitter' (path): hook allorules_measures called sys.exit(4)" in err


def test_a_hook_name_typo_is_warned_about_with_a_suggestion(tmp_path):
    plugin = write(tmp_path, "typo.py", """
        from allorules.plugins import ConstraintSpec, hookimpl

        @hookimpl
        def allorules_constraint():
            return [ConstraintSpec("c", "d", lambda context, parameters: {})]

        def allorules_measures():
            return []
        """)
    registry = registry_for([plugin], entry_points=False)
    messages = [failure.message for failure in registry.failures]
    assert any("allorules_constraint is not an allorules hook and is never called; did you mean allorules_constraints?"
               in message for message in messages)
    assert any("allorules_measures is not marked @hookimpl" in message for message in messages)
    assert any("implements none of the hooks" in message for message in messages)


def test_the_old_plugin_import_paths_still_work_with_a_warning():
    import importlib
    import sys

    for name in ("allorules.hookspecs", "allorules.specs"):
        sys.modules.pop(name, None)
        with pytest.warns(DeprecationWarning, match="allorules.plugins"):
            importlib.import_module(name)


def test_a_run_without_regions_to_scale_says_what_to_do(tmp_path):
    import trimesh

    mesh = tmp_path / "ball.obj"
    trimesh.creation.icosphere(3).export(mesh)
    with pytest.raises(SegmentationError):
        pipeline.run(mesh, pipeline.GlobalScaling(1.1), modes=12)



def test_regions_go_to_every_input_vertex_and_come_back_from_them():
    """:func:`pipeline.input_regions` gives every vertex of the input as it came a region (split
    seam vertices their twin's, an eye shell the head's, as the body vertex it sits by), and
    :class:`pipeline.VertexRegions` given back label the prepared body as they were."""
    import trimesh

    horse = generate_quadruped("horse", 2000)
    faces = horse.faces.copy()
    split = faces[:30].ravel().copy()                  # a UV seam: these corners get vertices of their own
    faces[:30] = (len(horse.vertices) + np.arange(len(split))).reshape(-1, 3)
    vertices = np.vstack([horse.vertices, horse.vertices[split]])
    nose = horse.vertices[np.argmax(horse.vertices[:, 0])]
    eye = trimesh.creation.icosphere(1, radius=0.01)
    vertices_eye = eye.vertices + nose - [0.03, 0.0, 0.0]
    mesh = trimesh.Trimesh(np.vstack([vertices, vertices_eye]), np.vstack([faces, eye.faces + len(vertices)]),
                           process=False)

    regions, body = pipeline.input_regions(mesh)
    assert regions.labels.shape == (len(mesh.vertices),)
    names = np.asarray(regions.region_names)
    np.testing.assert_array_equal(regions.labels[len(horse.vertices):len(vertices)], regions.labels[split])
    assert set(names[regions.labels[len(vertices):]]) == {"head"}
    assert np.mean(names[regions.labels[:len(horse.vertices)]] == np.asarray(horse.region_names)[horse.labels]) > 0.9

    prepared = pipeline.prepare(mesh)
    given = regions.on(prepared)
    np.testing.assert_array_equal(prepared.source_labels(given.labels)[:len(vertices)], regions.labels[:len(vertices)])
    with pytest.raises(SegmentationError, match="labels for a mesh of"):
        pipeline.VertexRegions(regions.labels[1:], regions.region_names, "vertex groups").on(prepared)
    with pytest.raises(SegmentationError, match="not a region index"):
        pipeline.VertexRegions(regions.labels + 10, regions.region_names, "vertex groups").on(prepared)


def _forced_misses(monkeypatch, missed) -> tuple[list[int], list[int]]:
    """Runs through the pipeline's real ``scale`` and ``label``, spied on: the sizes of the bodies
    scaled and labelled, in order; the n-th scale reports a miss with the message ``missed(n)``
    (``None``: as it came)."""
    from dataclasses import replace as replaced

    real_scale, real_label = pipeline.scale, pipeline.label
    calls: list[int] = []
    labelled: list[int] = []

    def scale(body, scaling, **options):
        result = real_scale(body, scaling, **options)
        calls.append(len(body.vertices))
        message = missed(len(calls))
        return result if message is None else replaced(result, converged=False, messages=[message])

    def label(body, **options):
        labelled.append(len(body.vertices))
        return real_label(body, **options)

    monkeypatch.setattr(pipeline, "scale", scale)
    monkeypatch.setattr(pipeline, "label", label)
    return calls, labelled


@pytest.mark.parametrize("second_misses", [False, pytest.param(True, marks=pytest.mark.heavy)])
def test_a_run_that_misses_on_a_coarse_body_is_made_again_on_it_split_finer(monkeypatch, second_misses):
    """A body under SPLIT_BELOW vertices is used as it is; where its run misses, the run is made
    again on the body split at its edges' midpoints (the same surface), with the regions the
    labeller found on the body as it comes (it labels once). The run kept is the one that
    converged, on every vertex of the user's body, its report naming the mesh it missed on; where
    both miss, the first stands and names the split."""
    from allorules.mesh.working import SPLIT_BELOW

    horse = generate_quadruped("horse", 600)
    calls, labelled = _forced_misses(monkeypatch, lambda n: f"forced miss {n}" if n == 1 or second_misses else None)
    scaling = pipeline.RulesetScaling(load_ruleset("quadruped"), 1.05)
    run = pipeline.run(Body(horse.vertices, horse.faces), scaling, modes=30, use_cache=False)

    count = len(horse.vertices)
    assert len(calls) == 2 and calls[0] == count and SPLIT_BELOW <= calls[1] < 4 * SPLIT_BELOW
    assert labelled == [count]                           # labelled once, on the body as it comes
    assert run.output_vertices().shape == horse.vertices.shape
    if second_misses:
        assert not run.converged and run.working.mesh.is_source
        assert [(other.vertices, other.missed) for other in run.working.also_tried] == [(calls[1], "forced miss 2")]
        return
    assert run.converged and run.working.mesh.method == "split" and len(run.working.mesh.vertices) == calls[1]
    assert np.array_equal(run.working.mesh.vertices[:count], horse.vertices)    # the same surface, split
    assert run.report()["working_mesh"]["also_tried"] == [{"vertices": count, "missed": "forced miss 1"}]
    carried = np.asarray(run.user_body().region_names, dtype=object)[run.user_body().labels]
    truth = labels_as_names(fold_regions(horse.body(), pipeline.wanted_regions(load_ruleset("quadruped"))))
    assert np.mean(carried == truth) > 0.9


@pytest.mark.parametrize("given", [True, False])
def test_a_run_that_misses_on_its_working_mesh_is_made_again_on_a_coarser_one(monkeypatch, given):
    """Where the run misses on the default working mesh (here the body itself), it is made again
    on a coarser working mesh: labelled there by the segmenter, or with the regions the user gave
    carried across; the run kept is the one that converged, carried back to every vertex of the
    user's body, and its report names the mesh it missed on. A size the user chose is never
    changed."""
    horse = generate_quadruped("horse", 3000)
    calls, labelled = _forced_misses(monkeypatch, lambda n: "forced miss" if n == 1 else None)
    monkeypatch.setattr(pipeline, "COARSER_WORKING", (1500,))
    monkeypatch.setattr("allorules.mesh.working.MIN_WORKING_VERTICES", 1000)   # a small, fast test
    scaling = pipeline.RulesetScaling(load_ruleset("quadruped"), 1.05)
    source = horse.body() if given else Body(horse.vertices, horse.faces)
    run = pipeline.run(source, scaling, modes=30, use_cache=False)

    assert calls[0] == len(horse.vertices) and 1200 < calls[1] < 1800
    assert labelled == ([] if given else calls)          # the segmenter labels each working mesh it runs on
    assert run.converged and len(run.working.mesh.vertices) == calls[1]
    assert [(other.vertices, other.missed) for other in run.working.also_tried] == [(len(horse.vertices), "forced miss")]
    assert run.report()["working_mesh"]["also_tried"] == [{"vertices": len(horse.vertices), "missed": "forced miss"}]
    assert run.output_vertices().shape == horse.vertices.shape
    carried = np.asarray(run.user_body().region_names, dtype=object)[run.user_body().labels]
    truth = labels_as_names(fold_regions(horse.body(), pipeline.wanted_regions(load_ruleset("quadruped"))))
    assert np.mean(carried == truth) > (0.95 if given else 0.9)
    if not given:
        return
    calls.clear()
    chosen = pipeline.run(horse.body(), scaling, modes=30, use_cache=False, working_vertices=len(horse.vertices))
    assert not chosen.converged and chosen.working is None
    assert calls == [len(horse.vertices)]   # the user's size: one run, nothing coarser
