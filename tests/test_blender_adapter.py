"""The Blender add-on's parts that need no Blender: the adapter, the run summary, the worker
thread, and building the extension archive (offline, from local wheels)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import tomllib

try:
    import fcntl
except ImportError:                 # not on Windows: builds there are not locked
    fcntl = None

from allorules.blender import adapter
from allorules.blender.build import BuildError, build_extension
from allorules.blender.results import run_summary
from allorules.blender.runner import BackgroundRun, Cancelled
from allorules.errors import AllorulesError, RulesetError

ROOT = Path(__file__).resolve().parents[1]


def test_importing_the_addon_needs_no_bpy():
    code = ("import sys; sys.modules['bpy'] = None\n"
            "import allorules, allorules.blender, allorules.blender.adapter, allorules.blender.build, "
            "allorules.blender.results, allorules.blender.runner\n"
            "try:\n    allorules.blender.register()\nexcept ImportError:\n    print('register needs bpy')\n")
    completed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert completed.returncode == 0, completed.stderr
    assert completed.stdout.strip() == "register needs bpy"


@pytest.fixture(scope="module")
def standing_z_up():
    """The generated horse turned to stand on the XY plane (+Z up), with its seams split as a
    UV-mapped mesh has them: the first 50 triangles get vertices of their own."""
    from allorules.mesh.quadruped import generate_quadruped

    horse = generate_quadruped("horse", 2000)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])    # +Y up becomes +Z up
    vertices = horse.vertices @ turn.T + np.array([3.0, -1.0, 0.25])
    faces = horse.faces.copy()
    split = faces[:50].ravel().copy()
    faces[:50] = (len(vertices) + np.arange(len(split))).reshape(-1, 3)
    return np.vstack([vertices, vertices[split]]), faces, split


def test_scale_arrays_gives_every_blender_vertex_a_place_on_the_same_ground(standing_z_up):
    vertices, faces, split = standing_z_up
    new, report = adapter.scale_arrays(vertices, faces, mass_ratio=1.2, modes=40, global_mode=True)
    assert new.shape == vertices.shape
    assert report["converged"] and report["mass_ratio"] == pytest.approx(1.2, rel=1e-3)
    # split seam vertices stay with the vertex they were split from
    np.testing.assert_allclose(new[len(vertices) - len(split):], new[split], atol=1e-12)
    # detected up is +Z, and the lowest point stays on the input's ground
    assert np.dot(report["up"], [0.0, 0.0, 1.0]) > 0.99
    up = np.asarray(report["up"])
    assert (new @ up).min() == pytest.approx((vertices @ up).min(), abs=1e-9)
    # it did change the animal: mass up 20 % means about 6 % longer
    assert np.ptp(new[:, 0]) / np.ptp(vertices[:, 0]) == pytest.approx(1.2 ** (1 / 3), rel=0.05)


def test_a_refusals_mass_rules_are_named_as_a_ruleset_file_in_the_panel(tmp_path):
    """The panel has no --rule overrides: a refusal's advice to hold the mass rules isometric names
    the ruleset file that does it, which loads with those rules at exponent 1."""
    from allorules.body import Body
    from allorules.rules.resolve import load_ruleset
    from allorules.runs.results import BiologyScalingResult, RuleOutcome

    rules = [RuleOutcome("head-mass", "head", "mass", 0.70, 1.0, 0.6, 0.5),
             RuleOutcome("abdomen-mass", "abdomen", "mass", 0.74, 1.0, 0.6, 0.74)]
    body = Body(np.eye(3), np.array([[0, 1, 2]]))
    refused = BiologyScalingResult(body, 0.5, rules=rules, missed=("rule",),
                                   mass_budget="the rules leave the chest ×0.35 in mass where the body changes ×0.5")
    said = adapter.in_panel_terms(refused.settle())
    assert "--rule" not in said and "(Ruleset, File…) with extends: the ruleset and " in said
    held = re.search(r"with extends: the ruleset and (.*) \(docs", said).group(1)
    assert held == "{id: head-mass, exponent: 1}, {id: abdomen-mass, exponent: 1}"
    path = tmp_path / "cartoon.yaml"
    path.write_text("name: cartoon\ndescription: as the refusal says\nextends: quadruped\nrules:\n"
                    + "".join(f"  - {rule}\n" for rule in re.findall(r"\{[^}]*\}", held)), encoding="utf-8")
    exponents = {rule.id: rule.exponent for rule in load_ruleset(str(path)).rules}
    assert exponents["head-mass"] == exponents["abdomen-mass"] == 1.0


def test_a_sitting_animal_refused_for_its_feet_is_scaled_once_forward_is_set():
    """The generated horse sitting, as Blender holds it (+Z up, facing -Y): with the panel's Up
    alone its feet are in doubt, and the refusal names the panel's settings (not the command
    line's); with Forward set to World -Y as well, the feet are found and it is scaled."""
    from allorules.mesh.quadruped import generate_quadruped

    horse = generate_quadruped("horse", 2000, pose="sit")
    turn = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # +X forward → −Y, +Y up → +Z
    vertices, up = horse.vertices @ turn.T, np.array([0.0, 0.0, 1.0])
    with pytest.raises(AllorulesError, match="feet") as refused:
        adapter.scale_arrays(vertices, horse.faces, mass_ratio=2.0, modes=40, global_mode=True, up=up)
    said = adapter.in_panel_terms(str(refused.value))
    assert "the Up and Forward settings" in said and "--up" not in said and "--forward" not in said
    forward = np.array(adapter.FORWARD_DIRECTIONS["-Y"])
    new, report = adapter.scale_arrays(vertices, horse.faces, mass_ratio=2.0, modes=40, global_mode=True, up=up,
                                       forward=forward)
    assert report["converged"] and np.dot(report["forward"], forward) > 0.99
    assert report["mass_ratio"] == pytest.approx(2.0, rel=0.01) and new.shape == vertices.shape


def test_regions_painted_where_the_labeller_refuses_are_used_for_the_run():
    """The same sitting horse, up given, forward not: Label Regions is refused for its feet, and the
    refusal names the region vertex groups to paint (not the command line's labels file); the
    regions painted (the generator's truth, as an artist would paint them) are what the run uses,
    including the vertices in no group; a standing animal's regions come out as the truth's."""
    from allorules.mesh.quadruped import generate_quadruped

    horse = generate_quadruped("horse", 2000, pose="sit")
    turn = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # +X forward → −Y, +Y up → +Z
    vertices, up = horse.vertices @ turn.T, np.array([0.0, 0.0, 1.0])
    with pytest.raises(AllorulesError, match="feet") as refused:
        adapter.label_arrays(vertices, horse.faces, up=up)
    said = adapter.in_panel_terms(str(refused.value))
    assert "or vertex groups region:head, region:neck" in said and "Regions set to Vertex groups" in said
    assert "--segmentation" not in said and "merge file" not in said
    # the labeller's other refusals name the labels file the same way
    from allorules.segment.body_plan import BY_HAND

    said = adapter.in_panel_terms(f"found no neck on this mesh; give the regions with {BY_HAND}, or try --up/--forward")
    assert said == (f"found no neck on this mesh; give the regions with {adapter.PAINT_GROUPS}, or try the Up and "
                    "Forward settings")
    painted = horse.labels.copy()
    painted[::40] = -1                                   # a few vertices the brush missed
    new, report = adapter.scale_arrays(vertices, horse.faces, mass_ratio=2.0, modes=40, global_mode=True, up=up,
                                       regions=(painted, horse.region_names))
    assert report["converged"] and report["labels"]["source"] == "vertex groups"
    assert report["mass_ratio"] == pytest.approx(2.0, rel=0.01) and new.shape == vertices.shape
    assert np.dot(report["forward"], adapter.FORWARD_DIRECTIONS["-Y"]) > 0.9      # read off the painted regions
    with pytest.raises(AllorulesError, match="labels for a mesh of"):
        adapter.scale_arrays(vertices, horse.faces, mass_ratio=2.0, modes=40, global_mode=True,
                             regions=(painted[:-1], horse.region_names))

    standing = generate_quadruped("horse", 2000)
    labels, names, found = adapter.label_arrays(standing.vertices, standing.faces)
    truth = np.asarray(standing.region_names)[standing.labels]
    assert labels.shape == (len(standing.vertices),) and (labels >= 0).all()
    assert np.mean(np.asarray(names)[labels] == truth) > 0.9
    assert found["confidence"]["head-tail"] > 0.6 and np.dot(found["up"], [0.0, 1.0, 0.0]) > 0.99


def test_bad_settings_are_refused_before_any_work(standing_z_up):
    vertices, faces, _ = standing_z_up
    with pytest.raises(RulesetError, match="unknown ruleset 'no-such-set'"):
        adapter.scale_arrays(vertices, faces, ruleset="no-such-set", mass_ratio=2.0)
    with pytest.raises(AllorulesError, match="posture"):
        adapter.check_settings(ruleset="quadruped", mass_ratio=2.0, modes=None, posture="crouch", global_mode=False)
    with pytest.raises(AllorulesError):
        adapter.check_settings(ruleset="quadruped", mass_ratio=-1.0, modes=None, posture=None, global_mode=False)


def test_run_summary_marks_rules_within_the_tolerance_as_met():
    report = {"mode": "ruleset", "ruleset": "quadruped", "target_mass_ratio": 2.0, "mass_ratio": 2.001,
              "stress_ratio": 1.0, "tolerances": {"exponent": 0.02}, "warnings": ["a leg bows"], "messages": [],
              "rules": [{"id": "foreleg-length", "exponent": 0.36, "achieved_exponent": 0.375},
                        {"id": "head-mass", "exponent": 0.7, "achieved_exponent": 0.65}]}
    summary = run_summary(report, object_name="Horse_x2", source_name="Horse")
    assert [(rule.id, rule.met) for rule in summary.rules] == [("foreleg-length", True), ("head-mass", False)]
    assert not summary.all_met and summary.warnings == ("a leg bows",)
    assert "1/2 rules met" in summary.line() and "1 warning" in summary.line()
    assert type(summary).from_dict(summary.as_dict()) == summary
    # faces the run folded were smoothed back in the object added: the panel says so
    report["quality"] = {"unfolded_faces": 3, "unfold_largest_move": 0.012}
    summary = run_summary(report, object_name="Horse_x2", source_name="Horse")
    assert summary.warnings[-1].startswith("3 folded face(s) were smoothed back") and "1.2%" in summary.warnings[-1]


def test_a_background_run_stops_when_cancelled(standing_z_up):
    vertices, faces, _ = standing_z_up

    def work(progress):
        progress.begin("test")
        return adapter.scale_arrays(vertices, faces, mass_ratio=3.0, modes=40, global_mode=True, progress=progress)

    run = BackgroundRun(work).start()
    deadline = time.monotonic() + 120
    while run.progress.steps == 0 and not run.done and time.monotonic() < deadline:
        time.sleep(0.05)
    # the status names the step it is at (a fast machine is already past step 1 when looked at)
    at = re.search(r"step (\d+)/(\d+)", run.status())
    assert at and 1 <= int(at[1]) < int(at[2]) == run.progress.steps
    run.cancel()
    assert run.status() == "allorules: cancelling…"
    assert run.wait(30), "the run did not stop within 30 s of being cancelled"
    assert isinstance(run.error, Cancelled) and run.result is None


# --- the extension archive ------------------------------------------------------------------------


@pytest.fixture(scope="session")
def allorules_wheel(tmp_path_factory) -> Path:
    """The allorules wheel, built offline from this checkout, one build at a time: setuptools builds
    in the checkout's build/ folder, and two test workers building at once broke each other's
    (found with -n 2: "No such file or directory" copying build/lib)."""
    folder = tmp_path_factory.mktemp("allorules-wheel")
    with open(Path(tempfile.gettempdir()) / "allorules-wheel-build.lock", "w") as lock:
        if fcntl is not None:
            fcntl.flock(lock, fcntl.LOCK_EX)          # released when the file closes
        completed = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
                                    "--no-index", "-q", "-w", str(folder)], capture_output=True, text=True)
    assert completed.returncode == 0, completed.stderr
    (wheel,) = folder.glob("allorules-*.whl")
    return wheel


def dependency_wheels() -> Path | None:
    """Dependency wheels prepared beforehand (``python -m allorules.blender.build --fetch-wheels DIR``)."""
    folder = os.environ.get("ALLORULES_BLENDER_WHEELS")
    return Path(folder) if folder and Path(folder).is_dir() else None


def check_archive(archive: Path) -> dict:
    """The archive's manifest, after checking what Blender needs of it."""
    with zipfile.ZipFile(archive) as opened:
        names = set(opened.namelist())
        manifest = tomllib.loads(opened.read("blender_manifest.toml").decode("utf-8"))
        init = opened.read("__init__.py").decode("utf-8")
    for key in ("schema_version", "id", "version", "name", "tagline", "maintainer", "type", "blender_version_min",
                "license"):
        assert manifest.get(key), f"manifest lacks {key}"
    assert manifest["type"] == "add-on" and manifest["schema_version"] == "1.0.0"
    assert tuple(int(part) for part in manifest["blender_version_min"].split(".")) >= (4, 2, 0)
    assert len(manifest["tagline"]) <= 64 and not manifest["tagline"].endswith(".")
    for wheel in manifest["wheels"]:
        assert wheel.startswith("./wheels/") and wheel[2:] in names, f"{wheel} is not in the archive"
    assert {name for name in names if name.startswith("wheels/")} == {wheel[2:] for wheel in manifest["wheels"]}
    assert "def register" in init and "allorules.blender" in init
    assert not any("/numpy-" in name for name in names), "numpy is Blender's own"
    return manifest


def test_build_names_missing_dependencies(allorules_wheel, tmp_path):
    folder = tmp_path / "wheels"
    folder.mkdir()
    (folder / allorules_wheel.name).write_bytes(allorules_wheel.read_bytes())
    with pytest.raises(BuildError, match=r"no wheel for .*scipy.*--fetch-wheels"):
        build_extension(folder, tmp_path / "out.zip")
    assert not (tmp_path / "out.zip").exists()
    (folder / "nlopt-2.7.1-cp311-cp311-win_amd64.whl").write_bytes(b"")
    with pytest.raises(BuildError, match="not linux-x64"):
        build_extension(folder, tmp_path / "out.zip", require_dependencies=False)


def test_build_an_archive_from_local_wheels(allorules_wheel, tmp_path):
    """With the dependency wheels (ALLORULES_BLENDER_WHEELS) the whole extension, else the add-on
    and its allorules wheel alone; either way a manifest Blender accepts."""
    folder = tmp_path / "wheels"
    folder.mkdir()
    complete = dependency_wheels()
    if complete is not None:
        for wheel in complete.glob("*.whl"):
            if not wheel.name.startswith("allorules-"):
                (folder / wheel.name).symlink_to(wheel.resolve())
    (folder / allorules_wheel.name).write_bytes(allorules_wheel.read_bytes())
    archive = build_extension(folder, tmp_path / "allorules-blender.zip", require_dependencies=complete is not None)
    manifest = check_archive(archive)
    assert manifest["platforms"] == ["linux-x64"]
    bundled = {Path(wheel).name.split("-")[0].lower() for wheel in manifest["wheels"]}
    assert "allorules" in bundled
    if complete is not None:
        assert {"scipy", "trimesh", "nlopt", "pyyaml", "pluggy", "jsonschema"} <= bundled
    with zipfile.ZipFile(archive) as opened, zipfile.ZipFile(allorules_wheel) as wheel:
        inner = opened.read(f"wheels/{allorules_wheel.name}")
        assert inner == allorules_wheel.read_bytes()
        assert "allorules/blender/operators.py" in wheel.namelist()


def test_a_run_that_misses_its_targets_adds_nothing_and_says_what_it_missed(standing_z_up, tmp_path):
    """Blender hears the line ``allorules scale`` and a batch job print (Run.missed), so a run
    refused for its trunk tells the artist in Blender too how to settle it."""
    vertices, faces, _ = standing_z_up
    ruleset = tmp_path / "contradiction.yaml"
    ruleset.write_text("name: contradiction\ndescription: two rules on the fore legs' length that cannot both hold\n"
                       "extends: quadruped\nrules:\n"
                       "  - {id: foreleg-length-again, region: forelimbs, measure: length, exponent: 1.0}\n"
                       "solver: {max_evaluations: 40, limb_thickness: 'off', trunk_stretch: 'off'}\n", encoding="utf-8")
    with pytest.raises(AllorulesError) as refused:
        adapter.scale_arrays(vertices, faces, ruleset=str(ruleset), mass_ratio=1.1, modes=40)
    message = str(refused.value)
    assert message.startswith("ruleset 'contradiction' did not reach its targets at mass ratio 1.1: ")
    assert "foreleg-length" in message and message.endswith("; nothing was added")


def test_regions_painted_without_one_a_ruleset_needs_are_refused_in_the_panel_s_terms():
    from allorules.mesh.quadruped import generate_quadruped

    horse = generate_quadruped("horse", 2000)
    painted = horse.labels.copy()
    painted[painted == list(horse.region_names).index("neck")] = -1      # no neck painted
    with pytest.raises(AllorulesError, match="needs region") as refused:
        adapter.scale_arrays(horse.vertices, horse.faces, mass_ratio=2.0, regions=(painted, horse.region_names))
    said = adapter.in_panel_terms(str(refused.value))
    assert "paint the vertex groups it lacks (region:<name>)" in said and "--segmentation" not in said


def test_regions_from_vertex_groups_are_measured_along_the_animals_axes():
    """Label Regions' groups given back without a frame (painted, or the frame not kept): the run
    reads up and forward off the regions, as the labeller found them (the giraffe's regions'
    centroids alone were 41° off); given the labeller's up and forward, it uses them."""
    from allorules.mesh.quadruped import generate_quadruped

    giraffe = generate_quadruped("giraffe", 2000)
    labels, names, found = adapter.label_arrays(giraffe.vertices, giraffe.faces)
    up, forward = np.asarray(found["up"]), np.asarray(found["forward"])
    _, bare = adapter.scale_arrays(giraffe.vertices, giraffe.faces, mass_ratio=1.2, modes=40, global_mode=True,
                                   regions=(labels, names))
    assert np.dot(bare["up"], up) > np.cos(np.radians(3.0)) and np.dot(bare["forward"], forward) > np.cos(np.radians(3.0))
    _, given = adapter.scale_arrays(giraffe.vertices, giraffe.faces, mass_ratio=1.2, modes=40, global_mode=True,
                                    regions=(labels, names), up=up, forward=forward)
    assert np.dot(given["up"], up) > 1 - 1e-9 and np.dot(given["forward"], forward) > 1 - 1e-9
