"""The demo: every promised file is written and holds what it says; earlier demos are never overwritten."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from allorules.cli import main
from allorules.runs.demo import (
    DEFAULT_FOLDER,
    DemoError,
    choose_folder,
    format_rule_table,
    run_demo,
)

PROMISED = ["original.obj", "labels.json", "regions.png", "gallery.png", "gallery_true_scale.png", "demo.json",
            "report.html"]
RATIOS = (0.9, 1.1)   # one step each: the whole pipeline, cheaply


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    folder = tmp_path_factory.mktemp("demo") / "out"
    return run_demo(folder, vertices=1000, modes=20, ratios=RATIOS)


@pytest.mark.slow
def test_demo_writes_every_promised_file(demo):
    names = {path.name for _, path in demo.files}
    runs = [f"{mode}_x{ratio:g}" for mode in ("global", "biology") for ratio in RATIOS]
    for name in PROMISED + [f"{run}.obj" for run in runs] + [f"{run}.json" for run in runs] + \
            [f"{run}.labels.json" for run in runs]:
        assert name in names, name
        assert (demo.folder / name).is_file() and (demo.folder / name).stat().st_size > 0, name
    assert sorted(path.name for path in demo.folder.iterdir()) == sorted(names)   # and nothing else (no temp files)
    for run in demo.runs:
        assert run.error is None, run.error


@pytest.mark.slow
def test_demo_meshes_reach_their_mass_ratios(demo):
    """Measured on the written files, not on the run's own numbers."""
    import trimesh

    from allorules.mesh.geometry import enclosed_volume

    original = trimesh.load(demo.folder / "original.obj", process=False)
    volume = enclosed_volume(np.asarray(original.vertices), np.asarray(original.faces))
    for run in demo.runs:
        scaled = trimesh.load(demo.folder / f"{run.name}.obj", process=False)
        assert np.array_equal(np.asarray(scaled.faces), np.asarray(original.faces))   # connectivity kept
        ratio = enclosed_volume(np.asarray(scaled.vertices), np.asarray(scaled.faces)) / volume
        assert ratio == pytest.approx(run.ratio, rel=0.01), run.name


@pytest.mark.slow
def test_demo_reports(demo):
    document = json.loads((demo.folder / "demo.json").read_text())
    assert [row["run"] for row in document["runs"]] == [run.name for run in demo.runs]
    assert 0.5 < document["label_agreement"] <= 1.0
    rules = document["rules"]
    # body mass and the five quadruped rules for every run
    assert len(rules) == 6 * len(demo.runs)
    for row in rules:
        assert row["achieved exponent"] is not None and math.isfinite(row["achieved exponent"])
        assert row["exponent error"] == pytest.approx(row["achieved exponent"] - row["target exponent"])
    for row in rules:
        if row["rule"] == "body mass":
            assert row["achieved exponent"] == pytest.approx(1.0, abs=0.02)
    run_report = json.loads((demo.folder / "biology_x1.1.json").read_text())
    assert run_report["mesh"] == "biology_x1.1.obj" and run_report["result"]["mode"] == "ruleset"
    html = (demo.folder / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 3            # gallery, true scale, regions, embedded
    assert "http://" not in html and "https://" not in html     # opens offline
    for run in demo.runs:
        assert run.name in html
    # every leg of every biology-aware run in the stance table (the generated horse has four)
    assert "Legs: stance and shape over the run" in html
    for run in demo.runs:
        if run.mode == "biology":
            assert sorted(run.result["posture"]) == ["forelimbs[0]", "forelimbs[1]", "hindlimbs[0]", "hindlimbs[1]"]
            for leg in run.result["posture"]:
                assert f"<td>{run.name}</td><td>{leg}</td>" in html
    table = format_rule_table(demo.rule_rows())
    assert "chest-girth" in table and "biology_x0.9" in table
    # the quality report of every run: in its JSON, and a row of the HTML report's quality table
    assert "Quality: what an artist would look for" in html
    for run in demo.runs:
        quality = json.loads((demo.folder / f"{run.name}.json").read_text())["quality"]
        assert quality == run.quality and quality["roughness"]["rms_degrees"] >= 0.0
        trunk = quality["trunk_shape_change"]
        flipped = (quality.get("written_flipped_faces") or quality["flipped_faces"])["count"]
        assert f"<td>{run.name}</td><td class=number>{flipped}</td>" in html
        assert trunk is not None and 0.0 <= trunk < 1.0
        assert "head turned (°)" in html and 0.0 <= quality["head_turn_degrees"] < 10.0   # the generated horse has a head


def test_named_folder_with_files_is_refused(tmp_path):
    folder = tmp_path / "old"
    folder.mkdir()
    (folder / "gallery.png").write_bytes(b"earlier demo")
    with pytest.raises(DemoError, match="--force"):
        choose_folder(folder)
    assert (folder / "gallery.png").read_bytes() == b"earlier demo"
    assert choose_folder(folder, force=True) == folder
    assert choose_folder(tmp_path / "empty") == tmp_path / "empty"   # an empty or new folder is fine
    (tmp_path / "file").write_text("x")
    with pytest.raises(DemoError, match="is a file"):
        choose_folder(tmp_path / "file")


def test_default_folder_is_numbered_when_taken(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert choose_folder(None).name == DEFAULT_FOLDER            # created, empty
    assert choose_folder(None).name == DEFAULT_FOLDER            # still empty: reused
    (tmp_path / DEFAULT_FOLDER / "report.html").write_text("earlier")
    second = choose_folder(None)
    assert second.name == f"{DEFAULT_FOLDER}-2"
    (second / "report.html").write_text("earlier too")
    assert choose_folder(None).name == f"{DEFAULT_FOLDER}-3"
    assert (tmp_path / DEFAULT_FOLDER / "report.html").read_text() == "earlier"


@pytest.mark.slow
def test_cli_names_the_runs_with_warnings(demo, monkeypatch, capsys):
    """A warned run says so in the final summary, where the log line above it is easily missed."""
    import copy

    import allorules.runs.demo

    warned = copy.deepcopy(demo)
    for run in warned.runs:
        run.result["warnings"] = []
    warned.runs[-1].result["warnings"] = ["hindlimbs[0] bows by 6.0% of its length more than in the input"]
    monkeypatch.setattr(allorules.runs.demo, "run_demo", lambda *args, **kwargs: warned)
    assert main(["demo"]) == 0
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.startswith(("global_", "biology_"))}
    assert lines[warned.runs[-1].name].endswith(" s), 1 warning: see the report")
    assert all("warning" not in lines[run.name] for run in warned.runs[:-1])


def test_cli_refuses_a_folder_with_files(tmp_path, capsys):
    (tmp_path / "keep.txt").write_text("mine")
    assert main(["demo", "-o", str(tmp_path), "--quick"]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").read_text() == "mine"


def test_measure_writes_a_picture(tmp_path, capsys):
    """``measure --png``: regions in colour and the load-bearing section marked, without a display."""
    import trimesh

    from allorules.mesh.quadruped import generate_quadruped

    horse = generate_quadruped("horse", 600)
    trimesh.Trimesh(horse.vertices, horse.faces, process=False).export(tmp_path / "horse.obj")
    (tmp_path / "horse.labels.json").write_text(json.dumps(horse.labels_document()))
    picture = tmp_path / "measured.png"
    assert main(["measure", str(tmp_path / "horse.obj"), "--segmentation", str(tmp_path / "horse.labels.json"),
                 "--png", str(picture)]) == 0
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["measure", str(tmp_path / "horse.obj"), "--png", str(tmp_path / "measured.jpg")]) == 2
    assert ".png" in capsys.readouterr().err
