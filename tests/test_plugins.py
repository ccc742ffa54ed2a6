"""Plugins: hooks, the built-in plugin, discovery by entry point and by path, failures, examples."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from allorules.body import Body, Frame
from allorules.cli import main
from allorules.errors import PluginError
from allorules.plugins import ConstraintContext, ConstraintSpec, ParameterSpec
from allorules.plugins.registry import registry_for
from allorules.rules.find import list_rulesets
from allorules.rules.resolve import load_ruleset

REPO = Path(__file__).resolve().parents[1]
PLUGINS = REPO / "plugins"


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text).lstrip("\n"), encoding="utf-8")
    return path


GOOD_PLUGIN = """
from allorules.plugins import hookimpl
from allorules.plugins import MeasureSpec

def ear_length(body, region):
    return 2.0

@hookimpl
def allorules_measures():
    return [MeasureSpec("ear-length", "length", 1/3, ear_length, "length of the ears")]
"""


def box(size=(4.0, 1.0, 1.0), labels=None, names=()):
    """A closed axis-aligned box (12 triangles, outward), optionally with per-vertex labels."""
    import trimesh

    mesh = trimesh.creation.box(extents=size)
    return Body(mesh.vertices, mesh.faces, labels, names)


def rotation(seed=3):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


# -- the built-in plugin ---------------------------------------------------------------------------
def test_builtin_plugin_registers_through_the_hooks():
    registry = registry_for([], entry_points=False)
    assert set(registry.measures()) == {"mass", "length", "girth", "trunk-length", "stress"}
    assert set(registry.constraints()) == {"terrestrial-limb-stress"}
    assert set(registry.segmenters()) == {"auto-quadruped", "merge-file"}
    [info] = registry.describe()
    assert (info.name, info.origin) == ("builtin", "built-in")
    assert info.provides["measure"] == ["mass", "length", "girth", "trunk-length", "stress"]
    assert registry.failures == []
    # the hooks are ordinary pluggy hooks: each returns a list per plugin
    assert [len(items) for items in registry.hook.allorules_measures()] == [5]


def test_builtin_measure_wrappers_call_the_measure_modules(monkeypatch):
    calls = []

    def fake(name, value):
        def compute(*args):
            calls.append((name,) + tuple(arg for arg in args[1:]))
            return value
        return compute

    monkeypatch.setattr("allorules.measure.mass.body_mass", fake("body_mass", 8.0))
    monkeypatch.setattr("allorules.measure.mass.region_mass", fake("region_mass", 2.0))
    monkeypatch.setattr("allorules.measure.length.region_length", fake("region_length", 3.0))
    monkeypatch.setattr("allorules.measure.girth.region_girth", fake("region_girth", 5.0))
    monkeypatch.setattr("allorules.measure.stress.peak_stress", fake("peak_stress", 7.0))
    monkeypatch.setattr("allorules.measure.length.trunk_length", fake("trunk_length", 11.0))
    measures = registry_for([], entry_points=False).measures()
    body = box()
    assert measures["mass"].compute(body, None) == 8.0
    assert measures["mass"].compute(body, "head") == 2.0
    assert measures["length"].compute(body, "forelimbs") == 3.0
    assert measures["girth"].compute(body, "chest") == 5.0
    assert measures["stress"].compute(body, None) == 7.0
    assert measures["trunk-length"].compute(body, None) == 11.0
    assert calls == [("body_mass",), ("region_mass", "head"), ("region_length", "forelimbs"),
                     ("region_girth", "chest"), ("peak_stress",), ("trunk_length",)]
    assert [measures[n].isometric_exponent for n in ("mass", "length", "girth", "stress")] == \
        pytest.approx([1, 1 / 3, 1 / 3, 1 / 3])


def test_builtin_segmenter_wrappers_call_the_segment_modules(monkeypatch):
    monkeypatch.setattr("allorules.segment.labeller.label_quadruped", lambda body, **options: ("labelled", options))
    monkeypatch.setattr("allorules.segment.patches.spectral_patches", lambda vertices, faces, count, seed: ("patches", count, seed))
    monkeypatch.setattr("allorules.segment.labels_io.apply_merge_file", lambda body, patches, path: ("merged", patches, path))
    segmenters = registry_for([], entry_points=False).segmenters()
    assert segmenters["auto-quadruped"].segment(box(), up=(0, 0, 1)) == ("labelled", {"up": (0, 0, 1), "forward": None})
    assert segmenters["merge-file"].segment(box(), path="m.yaml", patches=12) == ("merged", ("patches", 12, 0), "m.yaml")
    assert set(segmenters["merge-file"].parameter_specs()) == {"path", "patches", "seed"}
    assert segmenters["merge-file"].parameter_specs()["path"].required


def stress_context(initial_stress, candidate_stress, mass_ratio, initial=None, candidate=None):
    initial = initial if initial is not None else box()
    candidate = candidate if candidate is not None else box()

    def measure(name, body, region):
        assert name == "stress" and region is None
        return initial_stress if body is initial else candidate_stress

    return ConstraintContext(initial, candidate, mass_ratio, measure)


def test_terrestrial_limb_stress_residual():
    spec = registry_for([], entry_points=False).constraint("terrestrial-limb-stress")
    parameters = spec.complete_parameters({})
    assert parameters == {"exponent": 0.0}
    assert spec.residuals(stress_context(2.0, 2.0, 1.1), parameters) == {"stress": pytest.approx(0.0)}
    assert spec.residuals(stress_context(2.0, 2.2, 1.1), parameters) == {"stress": pytest.approx(0.1)}
    # uniform scaling by s multiplies σ by s; with exponent 1/3 and r = s³ that is satisfied
    s = 1.1 ** (1 / 3)
    assert spec.residuals(stress_context(2.0, 2.0 * s, 1.1), {"exponent": 1 / 3})["stress"] == pytest.approx(0.0)


def test_unknown_names_raise_plugin_error_with_suggestion():
    registry = registry_for([], entry_points=False)
    with pytest.raises(PluginError, match="unknown measure 'lenght'; did you mean 'length'"):
        registry.measure("lenght")


# -- loading by path and failures ------------------------------------------------------------------
def test_plugin_from_file_path(tmp_path):
    path = write(tmp_path, "ears.py", GOOD_PLUGIN)
    registry = registry_for([path], entry_points=False)
    assert registry.measure("ear-length").compute(box(), "head") == 2.0
    info = {i.name: i for i in registry.describe()}["ears"]
    assert info.origin == "path" and info.location == str(path.resolve())
    assert info.provides == {"measure": ["ear-length"]}
    # the same file given twice (command line and ruleset) registers once
    assert registry.load_path(path) == "ears" and registry.load_path(tmp_path / "." / "ears.py") == "ears"
    assert len(registry.get_plugins()) == 2


def test_plugin_package_folder_and_project_folder(tmp_path):
    write(tmp_path, "earpkg/__init__.py", "from .hooks import allorules_measures\n")
    write(tmp_path, "earpkg/hooks.py", GOOD_PLUGIN)
    registry = registry_for([tmp_path / "earpkg"], entry_points=False)
    assert "ear-length" in registry.measures()
    registry = registry_for([PLUGINS / "allorules-flight"], entry_points=False)
    assert "flight-wing-loading" in registry.constraints()


def test_failing_plugins_are_reported_by_name_and_the_rest_work(tmp_path, caplog):
    broken = write(tmp_path, "broken.py", "import not_a_module_anywhere\n")
    exits = write(tmp_path, "exits.py", "raise SystemExit(3)\n")
    raising = write(tmp_path, "raising.py", """
        from allorules.plugins import hookimpl
        @hookimpl
        def allorules_measures():
            raise RuntimeError("measure table missing")
        @hookimpl
        def allorules_constraints():
            return []
        """)
    wrong = write(tmp_path, "wrong.py", """
        from allorules.plugins import hookimpl
        @hookimpl
        def allorules_measures():
            return ["not a spec"]
        @hookimpl
        def allorules_constraints():
            return 5
        """)
    clash = write(tmp_path, "clash.py", """
        from allorules.plugins import hookimpl
        from allorules.plugins import MeasureSpec
        @hookimpl
        def allorules_measures():
            return [MeasureSpec("mass", "mass", 1.0, lambda b, r: 1.0, "fake mass"),
                    MeasureSpec("", "mass", 1.0, lambda b, r: 1.0, "nameless")]
        """)
    badhook = write(tmp_path, "badhook.py", """
        from allorules.plugins import hookimpl
        @hookimpl
        def allorules_measures(extra_argument):
            return []
        """)
    good = write(tmp_path, "ears.py", GOOD_PLUGIN)
    registry = registry_for([broken, exits, raising, wrong, clash, badhook, tmp_path / "missing.py", good],
                            entry_points=False)
    measures = registry.measures()
    assert "ear-length" in measures and measures["mass"].description != "fake mass"
    failures = {(f.plugin, f.message.split(":")[0]) for f in registry.failures}
    messages = "\n".join(str(f) for f in registry.failures)
    assert "plugin 'broken' (path): failed to import" in messages and "not_a_module_anywhere" in messages
    assert "plugin 'exits' (path): failed to import" in messages and "SystemExit" in messages
    assert "plugin 'raising' (path): hook allorules_measures raised RuntimeError: measure table missing" in messages
    assert "plugin 'wrong' (path): hook allorules_measures returned a str; expected MeasureSpec" in messages
    assert "plugin 'wrong' (path): hook allorules_constraints returned int" in messages
    assert "measure 'mass' is already provided by plugin 'builtin'" in messages
    assert "its name must be non-empty" in messages
    assert "plugin 'badhook' (path): could not be registered" in messages
    assert "plugin 'missing' (path)" in messages and "does not exist" in messages
    assert {name for name, _ in failures} == {"broken", "exits", "raising", "wrong", "clash", "badhook", "missing"}
    # each failure is on stderr (the log) by name, once
    assert sum("plugin 'raising'" in record.getMessage() for record in caplog.records) == 1
    described = {info.name: info for info in registry.describe()}
    assert described["broken"].failed and described["ears"].provides == {"measure": ["ear-length"]}


def test_ruleset_path_hook_makes_rulesets_nameable(tmp_path):
    write(tmp_path, "sets/pony.yaml", """
        description: a small horse
        extends: quadruped
        rules:
          - {id: head-mass, exponent: 0.8, source: test}
        """)
    plugin = write(tmp_path, "ponies.py", f"""
        from pathlib import Path
        from allorules.plugins import hookimpl
        @hookimpl
        def allorules_ruleset_paths():
            return [Path({str(tmp_path / 'sets')!r})]
        """)
    registry = registry_for([plugin], entry_points=False)
    summaries = {s.name: s for s in list_rulesets(registry)}
    assert summaries["pony"].origin == "plugin ponies" and summaries["pony"].description == "a small horse"
    assert load_ruleset("pony", registry).rule("head-mass").exponent == 0.8


def test_ruleset_names_its_plugin_relative_to_its_file(tmp_path):
    write(tmp_path, "plug/ears.py", GOOD_PLUGIN)
    path = write(tmp_path, "eared.yaml", """
        extends: quadruped
        plugins: [plug/ears.py]
        rules:
          - {id: ears, region: head, measure: ear-length, exponent: 0.3}
        """)
    registry = registry_for([], entry_points=False)
    ruleset = load_ruleset(path, registry)
    assert ruleset.plugins == ((tmp_path / "plug" / "ears.py").resolve(),)
    assert "ear-length" in registry.measures()   # loaded into the registry the caller passed


def test_parameter_spec_checks():
    number = ParameterSpec(0.5, minimum=0.0, maximum=1.0)
    assert number.check(1) is None and number.check(0.25) is None
    assert "at most" in number.check(2.0) and "must be a number" in number.check("x")
    assert "must be a number" in number.check(True) and "finite" in number.check(float("nan"))
    text = ParameterSpec("a", kind=str, choices=("a", "b"))
    assert text.check("b") is None and "one of a, b" in text.check("c")
    spec = ConstraintSpec("c", "d", lambda context, parameters: {}, {"plain": 2.0, "flag": True})
    assert spec.parameter_specs()["plain"].check("x") and spec.parameter_specs()["flag"].check(1)
    assert spec.complete_parameters({"plain": 3}) == {"plain": 3, "flag": True}


# -- discovery through an installed package's entry point -----------------------------------------
def install_plugin(project: Path, target: Path) -> None:
    """Install a plugin project into ``target`` with pip, offline, as a user would (``pip install``).

    The test extras provide setuptools and wheel, so the build needs no network.
    """
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index",
                    "--quiet", "--target", str(target), str(project)], check=True)


def run_cli(*arguments: str, pythonpath: Path | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    environment = dict(os.environ, ALLORULES_CACHE_DIR="off")
    if pythonpath is not None:
        environment["PYTHONPATH"] = str(pythonpath)
    command = [sys.executable, "-c", "import sys; from allorules.cli import main; sys.exit(main(sys.argv[1:]))"]
    return subprocess.run([*command, *arguments], capture_output=True, text=True,
                          env=environment, cwd=cwd, timeout=120)


@pytest.mark.slow
def test_entry_point_discovery_in_a_temporary_environment(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    install_plugin(PLUGINS / "allorules-surface-area", site)
    # a broken installed plugin is reported by name and does not take the others down
    broken = site / "allorules_broken-0.1.dist-info"
    broken.mkdir()
    (broken / "METADATA").write_text("Metadata-Version: 2.1\nName: allorules-broken\nVersion: 0.1\n")
    (broken / "entry_points.txt").write_text("[allorules]\nbroken = allorules_not_there\n")

    result = run_cli("plugins", pythonpath=site, cwd=tmp_path)
    assert result.returncode == 1, result.stderr
    assert "surface-area  (entry point: surface-area = allorules_surface_area)" in result.stdout
    assert "measures: surface-area" in result.stdout
    assert "broken  (entry point" in result.stdout and "FAILED: failed to import" in result.stdout
    assert "plugin 'broken' (entry point)" in result.stderr
    assert "builtin  (built-in" in result.stdout

    # the example ruleset names the plugin by path too: it is registered once, no clash
    ruleset = PLUGINS / "allorules-surface-area" / "heat-balance.yaml"
    result = run_cli("ruleset", "check", str(ruleset), pythonpath=site, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "already provided" not in result.stderr

    # without the installation the plugin is not there (nothing is picked up from elsewhere)
    result = run_cli("plugins", cwd=tmp_path)
    assert result.returncode == 0 and "surface-area" not in result.stdout


def test_cli_plugins_with_plugin_path(capsys):
    assert main(["plugins", "--details", "--plugin", str(PLUGINS / "allorules-swimming" / "allorules_swimming.py")]) == 0
    out = capsys.readouterr().out
    assert "allorules_swimming  (path: " in out and "constraints: aquatic-locomotion" in out
    assert "parameter buoyancy (default 0.5)" in out
    assert main(["plugins", "--plugin", "no/such/plugin.py"]) == 1
    assert "FAILED: no/such/plugin.py does not exist" in capsys.readouterr().out


def test_nothing_is_loaded_from_the_current_folder(tmp_path):
    write(tmp_path, "allorules_sneaky.py", GOOD_PLUGIN)
    write(tmp_path, "ears.py", GOOD_PLUGIN)
    result = run_cli("plugins", cwd=tmp_path)
    assert result.returncode == 0 and "ear-length" not in result.stdout


# -- the example plugins ----------------------------------------------------------------------------
def load_example(name: str):
    registry = registry_for([next((PLUGINS / name).glob("allorules_*.py"))], entry_points=False)
    assert registry.failures == []
    return registry


def test_surface_area_measure_of_a_box_and_a_region():
    measure = load_example("allorules-surface-area").measure("surface-area")
    assert measure.isometric_exponent == pytest.approx(2 / 3) and not measure.needs_region
    body = box((4.0, 1.0, 1.0))
    assert measure.compute(body, None) == pytest.approx(2 * (4 + 4 + 1))
    rotated = body.with_vertices(3.0 * body.vertices @ rotation().T)
    assert measure.compute(rotated, None) == pytest.approx(9 * 18)       # area ∝ s²
    labels = (body.vertices[:, 0] > 0).astype(int)                         # the +x end: 4 corners
    labelled = Body(body.vertices, body.faces, labels, ("rear", "front"))
    # faces with ≥ 2 corners at +x: the end cap (2 triangles, area 1) and half of each side
    assert measure.compute(labelled, "front") == pytest.approx(1 + 4 * 2)
    from allorules.errors import MeasurementError

    with pytest.raises(MeasurementError, match="no region 'tail'"):
        measure.compute(labelled, "tail")


def test_flight_wing_loading_residual_under_uniform_scaling():
    spec = load_example("allorules-flight").constraint("flight-wing-loading")
    body = box((4.0, 1.0, 1.0))
    labelled = Body(body.vertices, body.faces, (body.vertices[:, 0] > 0).astype(int), ("body", "forelimbs"))
    s = 1.1 ** (1 / 3)
    scaled = labelled.with_vertices(labelled.vertices * s)

    def measure(name, candidate, region):   # mass ∝ volume
        assert name == "mass" and region is None
        return 4.0 * (s ** 3 if candidate is scaled else 1.0)

    context = ConstraintContext(labelled, scaled, 1.1, measure)
    # M ∝ s³, S ∝ s², so Q = M/S grows by s: exponent 1/3 is satisfied, exponent 0 misses by s − 1
    assert spec.residuals(context, {"wing_region": "forelimbs", "exponent": 1 / 3}) == {"wing-loading": pytest.approx(0)}
    assert spec.residuals(context, spec.complete_parameters({}))["wing-loading"] == pytest.approx(s - 1)


def test_aquatic_locomotion_residuals():
    import trimesh

    spec = load_example("allorules-swimming").constraint("aquatic-locomotion")
    from allorules_plugin_allorules_swimming import (
        fineness_ratio,  # the module load_example loaded
    )
    tube = trimesh.creation.cylinder(radius=0.5, height=20.0, sections=128)   # along z, 2R = 1
    body = Body(tube.vertices, tube.faces)
    assert fineness_ratio(body) == pytest.approx(20.0, rel=0.03)           # caps shift it a little
    turned = body.with_vertices(2.5 * body.vertices @ rotation().T + 7.0)
    assert fineness_ratio(turned) == pytest.approx(fineness_ratio(body), rel=1e-9)   # size and orientation free
    framed = Body(tube.vertices, tube.faces, frame=Frame(np.array([1.0, 0, 0]), np.array([0, 0, 1.0])))
    assert fineness_ratio(framed) == pytest.approx(fineness_ratio(body), rel=1e-9)
    square = box((4.0, 1.0, 1.0))                                          # degenerate cross-section
    turned_square = square.with_vertices(square.vertices @ rotation(5).T)
    assert fineness_ratio(turned_square) == pytest.approx(fineness_ratio(square), rel=1e-9)
    stretched = body.with_vertices(body.vertices * [1.0, 1.0, 1.2])

    def context(candidate, stress_ratio):
        return ConstraintContext(body, candidate, 1.1,
                                 lambda name, b, region: 2.0 * (stress_ratio if b is candidate else 1.0))

    parameters = spec.complete_parameters({"buoyancy": 0.75})
    residuals = spec.residuals(context(stretched, 1.2), parameters)
    assert residuals["fineness"] == pytest.approx(0.2, abs=0.005)         # F grows by the stretch
    assert residuals["limb-stress"] == pytest.approx(0.25 * 0.2)          # (1 − b)(σ'/σ − 1)
    assert spec.residuals(context(body.with_vertices(body.vertices * 3), 1.0), parameters)["fineness"] == \
        pytest.approx(0.0, abs=1e-12)
    floating = spec.residuals(context(stretched, 1.2), {"buoyancy": 1.0, "streamlining": 0.0})
    assert floating == {}
    terrestrial = spec.residuals(context(stretched, 1.2), {"buoyancy": 0.0, "streamlining": 1.0})
    assert terrestrial["limb-stress"] == pytest.approx(0.2)


@pytest.mark.parametrize("ruleset, constraint", [
    ("allorules-flight/bat.yaml", "flight-wing-loading"),
    ("allorules-swimming/otter.yaml", "aquatic-locomotion"),
    ("allorules-surface-area/heat-balance.yaml", None),
])
def test_example_rulesets_load_with_their_plugins(ruleset, constraint):
    registry = registry_for([], entry_points=False)
    loaded = load_ruleset(PLUGINS / ruleset, registry)
    assert loaded.extends == ("quadruped",)
    assert registry.failures == []
    if constraint:
        assert constraint in [use.name for use in loaded.constraints]
    else:
        assert loaded.rule("skin-area").measure == "surface-area"
    if "otter" in ruleset:
        assert [use.name for use in loaded.constraints] == ["aquatic-locomotion"]


def test_painted_regions_segmenter_reads_the_regions_an_artist_painted(tmp_path):
    """The worked example of a segmenter plugin: the generator's regions painted as vertex colours
    come back as the body's regions; a painted mesh that is not this body is refused."""
    import trimesh

    from allorules.errors import SegmentationError
    from allorules.mesh.quadruped import generate_quadruped

    spec = load_example("allorules-painted-regions").segmenter("painted-regions")
    module = sys.modules[spec.segment.__module__]
    horse = generate_quadruped("horse", 1500)
    colours = np.array([[int(module.DEFAULT_COLORS[horse.region_names[label]][k:k + 2], 16) for k in (1, 3, 5)] + [255]
                        for label in horse.labels], dtype=np.uint8)
    painted = trimesh.Trimesh(horse.vertices, horse.faces, vertex_colors=colours, process=False)
    painted.export(tmp_path / "painted.ply")
    body = horse.body()
    turned = Body(body.vertices, body.faces)
    labelled = spec.segment(turned, path=tmp_path / "painted.ply")
    names = np.asarray(labelled.region_names, dtype=object)[labelled.labels]
    truth = np.asarray(horse.region_names, dtype=object)[horse.labels]
    assert np.all(names == truth)
    assert labelled.labelling.confidence["painted"] == 1.0
    trimesh.creation.icosphere(3, radius=0.1).export(tmp_path / "other.ply")
    with pytest.raises(SegmentationError, match="has no vertex colours|does not lie on this mesh"):
        spec.segment(turned, path=tmp_path / "other.ply")
    ruleset = load_ruleset(PLUGINS / "allorules-painted-regions" / "painted.yaml", registry_for([], entry_points=False))
    assert ruleset.segmenter.name == "painted-regions"
    assert ruleset.segmenter.options["path"] == (PLUGINS / "allorules-painted-regions" / "horse-painted.ply").resolve()
