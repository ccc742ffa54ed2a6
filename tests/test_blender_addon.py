"""The add-on in Blender itself (the bpy module, headless): operators on a UV-mapped, two-material
generated quadruped with an object transform and a modifier, and the extension installed from its
file as a user would. Runs where ``pip install '.[blender]'`` brought bpy; skipped elsewhere."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="the bpy module is not installed (pip install '.[blender]')")

pytestmark = pytest.mark.blender

from blender_scene import DISPLACE, quadruped_object, world_positions  # noqa: E402


@pytest.fixture(scope="module")
def blender():
    """A factory-fresh Blender with the add-on registered."""
    import allorules.blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    allorules.blender.register()
    yield bpy
    allorules.blender.unregister()


@pytest.fixture(scope="module")
def scaled(blender):
    """One ruleset run, as a script calls it: ``bpy.ops.allorules.scale(ruleset="quadruped", mass_ratio=2.0)``,
    with the default basis (a 40-mode basis of this 2,000-vertex horse cannot also hold the neck
    isometric and reaches mass x1.977: refused, as it should be)."""
    original = quadruped_object("Horse")
    data_before = np.array([vertex.co[:] for vertex in original.data.vertices])
    evaluated_before = world_positions(original, evaluated=True)
    objects_before = set(bpy.data.objects)
    result = bpy.ops.allorules.scale(ruleset="quadruped", mass_ratio=2.0)
    new = set(bpy.data.objects) - objects_before
    return dict(result=result, original=original, data_before=data_before, evaluated_before=evaluated_before, new=new)


def test_scale_adds_one_object_like_the_original(scaled):
    assert scaled["result"] == {'FINISHED'}
    (obj,) = scaled["new"]
    original = scaled["original"]
    assert obj.name == "Horse_x2" and obj.type == 'MESH'
    assert bpy.context.view_layer.objects.active == obj and obj.select_get() and not original.select_get()
    assert len(obj.data.vertices) == len(original.data.vertices)
    assert len(obj.data.polygons) == len(original.data.polygons)
    assert obj.data.uv_layers.keys() == ["UVMap"]
    assert [material.name for material in obj.data.materials] == ["Coat", "Hooves"]
    indices = np.empty(len(obj.data.polygons), dtype=np.int32)
    obj.data.polygons.foreach_get("material_index", indices)
    wanted = np.empty_like(indices)
    original.data.polygons.foreach_get("material_index", wanted)
    np.testing.assert_array_equal(indices, wanted)
    assert all(polygon.use_smooth for polygon in obj.data.polygons)
    uv_new = np.empty(len(obj.data.loops) * 2, dtype=np.float32)
    uv_old = np.empty_like(uv_new)
    obj.data.uv_layers["UVMap"].data.foreach_get("uv", uv_new)
    original.data.uv_layers["UVMap"].data.foreach_get("uv", uv_old)
    np.testing.assert_array_equal(uv_new, uv_old)
    assert len(obj.modifiers) == 0, "the modifiers are applied in the copy"


def test_the_original_is_untouched(scaled):
    original = scaled["original"]
    data_after = np.array([vertex.co[:] for vertex in original.data.vertices])
    np.testing.assert_array_equal(data_after, scaled["data_before"])
    assert [modifier.name for modifier in original.modifiers] == ["Displace"]
    assert tuple(original.location) == pytest.approx((3.0, -1.0, 0.5))


def test_it_stands_on_the_same_ground_beside_the_original(scaled):
    (obj,) = scaled["new"]
    before = scaled["evaluated_before"]           # the original as the viewport shows it (modifier on)
    after = world_positions(obj)
    size = np.ptp(before, axis=0).max()
    assert after[:, 2].min() == pytest.approx(before[:, 2].min(), abs=1e-5 * size)
    # the Displace modifier moved the feet by its strength × 0.5 × the object scale 2: the input was the evaluated mesh
    data_ground = world_positions(scaled["original"])[:, 2].min()
    assert data_ground - before[:, 2].min() == pytest.approx(DISPLACE, rel=0.2)
    # beside it, on the animal's left (it faces 0.4 rad from +X): no overlap across its width
    left = np.array([-math.sin(0.4), math.cos(0.4), 0.0])
    assert (after @ left).min() > (before @ left).max()
    # twice the mass: about 2^(1/3) = 1.26 times as long
    length = lambda points: np.ptp(points @ np.array([math.cos(0.4), math.sin(0.4), 0.0]))
    assert length(after) / length(before) == pytest.approx(2 ** (1 / 3), rel=0.08)


def test_the_report_says_every_rule_was_met(scaled):
    (obj,) = scaled["new"]
    (summary,) = json.loads(bpy.context.scene.allorules.last_result)
    assert summary["object"] == obj.name and summary["ruleset"] == "quadruped"
    assert summary["mass_ratio"] == pytest.approx(2.0, rel=0.01)
    assert {rule["id"] for rule in summary["rules"]} >= {"foreleg-length", "hindleg-length", "chest-girth"}
    assert all(rule["met"] for rule in summary["rules"])
    assert json.loads(obj["allorules"]) == summary


def test_a_bad_ruleset_is_a_report_and_adds_nothing(scaled):
    objects, meshes = set(bpy.data.objects), set(bpy.data.meshes)
    bpy.context.view_layer.objects.active = scaled["original"]
    with pytest.raises(RuntimeError) as raised:
        bpy.ops.allorules.scale(ruleset="no-such-ruleset", mass_ratio=2.0)
    message = str(raised.value)
    assert message.startswith("Error: unknown ruleset 'no-such-ruleset'; known: ")
    assert "Traceback" not in message and message.strip().count("\n") == 0
    assert set(bpy.data.objects) == objects and set(bpy.data.meshes) == meshes


def test_the_panel_draws_without_errors(scaled):
    from allorules.blender.panel import ruleset_items

    items = ruleset_items(None, bpy.context)
    names = [item[0] for item in items]
    assert "quadruped" in names and names[-1] == "__FILE__"
    assert all(item[2] for item in items), "every ruleset shows its description"
    assert bpy.types.VIEW3D_PT_allorules.bl_category == "allorules"
    settings = bpy.context.scene.allorules
    settings.mass_ratio = 2.0
    bpy.ops.allorules.mass_ratio_times(factor=0.5)
    assert settings.mass_ratio == pytest.approx(1.0)


class RecordingLayout:
    """Stands in for bpy.types.UILayout (which only Blender's UI can make): records what is drawn."""

    def __init__(self, log=None):
        self.log = [] if log is None else log

    def _child(self, *args, **kwargs):
        return RecordingLayout(self.log)

    column = row = box = grid_flow = _child

    def label(self, text="", icon='NONE'):
        self.log.append(("label", text, icon))

    def prop(self, data, name, **kwargs):
        assert hasattr(data, name), name
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        self.log.append(("operator", idname))
        return type("Properties", (), {})()

    def separator(self):
        pass


def test_the_panel_shows_the_settings_and_the_last_run(scaled):
    from allorules.blender.panel import VIEW3D_PT_allorules

    layout = RecordingLayout()
    VIEW3D_PT_allorules.draw(type("Panel", (), {"layout": layout,
                                                "draw_result": staticmethod(VIEW3D_PT_allorules.draw_result)})(),
                             bpy.context)
    drawn = layout.log
    assert ("prop", "ruleset") in drawn and ("prop", "mass_ratio") in drawn
    assert ("operator", "allorules.scale") in drawn and ("operator", "allorules.gallery") in drawn
    assert drawn.count(("operator", "allorules.mass_ratio_times")) == 2
    assert ("prop", "regions") in drawn and ("operator", "allorules.label_regions") in drawn
    labels = [entry[1] for entry in drawn if entry[0] == "label"]
    assert any("Horse_x2" in text for text in labels)
    for rule in ("foreleg-length", "hindleg-length", "chest-girth", "head-mass", "abdomen-mass"):
        assert rule in labels
    assert labels.count("met") == 5 and "missed" not in labels


def test_gallery_puts_minified_original_magnified_in_a_row(blender):
    original = quadruped_object("Foal", modifier=False)
    before = world_positions(original)
    objects = set(bpy.data.objects)
    # as the panel's button calls it; without a window (headless) the run completes before returning
    assert bpy.ops.allorules.gallery('INVOKE_DEFAULT', mass_ratio=1.2, global_mode=True, modes=40) == {'FINISHED'}
    small, large = sorted(set(bpy.data.objects) - objects, key=lambda obj: obj.name)
    assert (small.name, large.name) == ("Foal_x0.833", "Foal_x1.2")
    forward = np.array([math.cos(0.4), math.sin(0.4), 0.0])
    along = {name: world_positions(obj) @ forward for name, obj in (("small", small), ("large", large))}
    along["original"] = before @ forward
    assert along["small"].max() < along["original"].min() and along["original"].max() < along["large"].min()
    for obj in (small, large):
        assert world_positions(obj)[:, 2].min() == pytest.approx(before[:, 2].min(), abs=1e-5 * np.ptp(before))
    assert np.ptp(along["small"]) < np.ptp(along["original"]) < np.ptp(along["large"])


def _groups(obj) -> dict[str, np.ndarray]:
    """Each vertex group of ``obj``: the indices of its vertices."""
    members: dict[str, list[int]] = {group.name: [] for group in obj.vertex_groups}
    names = {group.index: group.name for group in obj.vertex_groups}
    for vertex in obj.data.vertices:
        for element in vertex.groups:
            members[names[element.group]].append(vertex.index)
    return {name: np.array(indices) for name, indices in members.items()}


def test_label_regions_adds_vertex_groups_that_a_run_then_uses(blender):
    """Label Regions on a standing horse: one group per region, as the generator's truth has them
    (modifier and object transform in the way); asked again, it refuses to replace them. A sitting
    horse (Up alone) is refused, the refusal naming the groups to paint; painted by hand (here: the
    truth, and a group of bone weights beside them that is not a region), Scale with Regions set to
    Vertex groups runs on them."""
    standing = quadruped_object("Standing")
    assert bpy.ops.allorules.label_regions(up="Z") == {'FINISHED'}
    truth = json.loads(standing["truth"])
    wanted = np.asarray(truth["regions"])[truth["labels"]]
    groups = _groups(standing)
    assert {"region:head", "region:neck", "region:chest", "region:abdomen", "region:forelimbs",
            "region:hindlimbs"} <= set(groups)
    found = np.full(len(wanted), "", dtype=object)
    for name, members in groups.items():
        found[members] = name.removeprefix("region:")
    assert np.mean(found == wanted) > 0.9
    with pytest.raises(RuntimeError, match="already has region vertex groups"):
        bpy.ops.allorules.label_regions(up="Z")

    sitting = quadruped_object("Sitting", pose="sit")
    with pytest.raises(RuntimeError) as refused:
        bpy.ops.allorules.label_regions(up="Z")
    assert "region:head" in str(refused.value) and "and Regions set to Vertex groups" in str(refused.value)
    assert len(sitting.vertex_groups) == 0
    with pytest.raises(RuntimeError, match="no vertex groups named region:head"):
        bpy.ops.allorules.scale(mass_ratio=1.5, global_mode=False, regions="GROUPS", modes=40)
    truth = json.loads(sitting["truth"])
    labels = np.asarray(truth["labels"])
    for index, name in enumerate(truth["regions"]):
        sitting.vertex_groups.new(name=f"region:{name}").add(np.flatnonzero(labels == index).tolist(), 1.0, 'REPLACE')
    sitting.vertex_groups.new(name="head").add(np.flatnonzero(labels == 5).tolist(), 0.5, 'REPLACE')   # a bone's
    objects = set(bpy.data.objects)
    assert bpy.ops.allorules.scale(mass_ratio=1.5, global_mode=True, regions="GROUPS", modes=40) == {'FINISHED'}
    (scaled,) = set(bpy.data.objects) - objects
    summary = json.loads(scaled["allorules"])
    assert summary["mass_ratio"] == pytest.approx(1.5, rel=0.01)


def test_label_regions_keeps_the_axes_it_found_and_they_follow_the_object(blender):
    """Label Regions keeps the up and forward it found on the object, in its own coordinates: read
    back after the object is turned, they are the labeller's turned with it, and Scale with the
    groups measures along them."""
    from allorules.blender.objects import read_source

    horse = quadruped_object("Framed")
    bpy.context.view_layer.update()
    assert bpy.ops.allorules.label_regions(up="Z") == {'FINISHED'}
    assert "allorules_frame" in horse.keys()
    before = read_source(bpy.context, horse, regions=True)
    up, forward = before.label_frame
    assert up @ np.array([0.0, 0.0, 1.0]) > 0.99          # it stands on Z (blender_scene turns it so)
    for mesh in before.copies:
        bpy.data.meshes.remove(mesh)
    horse.rotation_euler[2] += 0.7                          # turned about Z after labelling
    bpy.context.view_layer.update()
    after = read_source(bpy.context, horse, regions=True)
    turn = np.array([[math.cos(0.7), -math.sin(0.7), 0.0], [math.sin(0.7), math.cos(0.7), 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(after.label_frame[0], turn @ up, atol=1e-6)
    np.testing.assert_allclose(after.label_frame[1], turn @ forward, atol=1e-6)
    for mesh in after.copies:
        bpy.data.meshes.remove(mesh)


# --- the extension, installed from its file -------------------------------------------------------


INSTALLED = textwrap.dedent('''
    import json, sys
    import bpy
    try:
        import allorules
        print("allorules was importable before the install: " + allorules.__file__)
        sys.exit(3)
    except ImportError:
        pass
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default", enable_on_install=True)
    import allorules
    sys.path.insert(0, sys.argv[2])
    from blender_scene import quadruped_object
    horse = quadruped_object("Horse", modifier=False)
    before = len(bpy.data.objects)
    result = bpy.ops.allorules.scale(ruleset="quadruped", mass_ratio=1.1, modes=40, global_mode=True)
    new = bpy.context.active_object
    print(json.dumps({"module": allorules.__file__, "result": sorted(result), "objects": len(bpy.data.objects) - before,
                      "name": new.name, "vertices": len(new.data.vertices), "uv": new.data.uv_layers.keys(),
                      "materials": [m.name for m in new.data.materials]}))
''')


def isolated_path(folder: Path) -> Path:
    """A folder holding only bpy and what it imports (links), so that allorules can come only
    from the installed extension."""
    import importlib.util

    site = Path(bpy.__file__).resolve().parents[1]
    for name in ("bpy", "numpy", "numpy.libs", "requests", "urllib3", "idna", "certifi", "charset_normalizer",
                 "zstandard"):
        spec = importlib.util.find_spec(name.split(".")[0]) if name != "numpy.libs" else None
        target = site / name if spec is None else Path(spec.origin).parent
        if target.exists():
            (folder / name).symlink_to(target)
    return folder


def test_the_extension_installs_from_its_file_and_runs(tmp_path):
    from test_blender_adapter import dependency_wheels

    wheels = dependency_wheels()
    if wheels is None:
        pytest.skip("set ALLORULES_BLENDER_WHEELS to a folder made by 'python -m allorules.blender.build --fetch-wheels'")
    from allorules.blender.build import build_extension

    root = Path(__file__).resolve().parents[1]
    folder = tmp_path / "wheels"
    folder.mkdir()
    for wheel in wheels.glob("*.whl"):
        if not wheel.name.startswith("allorules-"):
            (folder / wheel.name).symlink_to(wheel.resolve())
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(root), "--no-deps", "--no-build-isolation", "--no-index",
                    "-q", "-w", str(folder)], check=True, capture_output=True)
    archive = build_extension(folder, tmp_path / "allorules-blender.zip")
    (tmp_path / "path").mkdir()
    paths = isolated_path(tmp_path / "path")
    script = tmp_path / "installed.py"
    script.write_text(INSTALLED)
    environment = {key: value for key, value in os.environ.items() if not key.startswith("PYTHON")}
    environment.update(PYTHONPATH=str(paths), BLENDER_USER_RESOURCES=str(tmp_path / "blender-user"))
    completed = subprocess.run([sys.executable, "-S", str(script), str(archive), str(Path(__file__).parent)],
                               capture_output=True, text=True, env=environment, timeout=600)
    assert completed.returncode == 0, completed.stdout[-2000:] + completed.stderr[-3000:]
    outcome = json.loads(completed.stdout.strip().splitlines()[-1])
    assert outcome["module"].startswith(str(tmp_path / "blender-user" / "extensions")), outcome["module"]
    assert outcome["result"] == ["FINISHED"] and outcome["objects"] == 1 and outcome["name"] == "Horse_x1.1"
    assert outcome["vertices"] > 1500 and outcome["uv"] == ["UVMap"] and outcome["materials"] == ["Coat", "Hooves"]


# --- the UI path: invoke, modal timer, Esc ------------------------------------------------------------


class ModalDriver:
    """Drives an operator's invoke/modal code (the scale operator's, or with ``label=True`` Label
    Regions') as Blender's event loop would (bpy has no window when headless): real Blender data, a
    stand-in window manager, workspace and events."""

    def __init__(self, label: bool = False, **settings):
        from allorules.blender import operators

        class Driven(operators._RunsAllorules):
            ratios = operators.ALLORULES_OT_scale.ratios
            place = operators.ALLORULES_OT_scale.place

            def report(self, kinds, text):
                self.reports.append((set(kinds), text))

        class DrivenLabel(operators._InBackground):
            begin = operators.ALLORULES_OT_label_regions.begin
            finish = operators.ALLORULES_OT_label_regions.finish
            stage = operators.ALLORULES_OT_label_regions.stage

            def report(self, kinds, text):
                self.reports.append((set(kinds), text))

        self.operator = DrivenLabel() if label else Driven()
        self.operator.reports = []
        defaults = dict(up="Z", forward="AUTO") if label else dict(
            ruleset="quadruped", mass_ratio=1.1, modes=40, posture="RULESET", global_mode=True, up="Z",
            forward="AUTO", regions="DETECT")
        for key, value in {**defaults, **settings}.items():
            setattr(self.operator, key, value)
        self.status: list = []
        self.timers = []
        driver = self

        class WindowManager:
            def event_timer_add(self, seconds, window=None):
                driver.timers.append("timer")
                return "timer"

            def event_timer_remove(self, timer):
                driver.timers.remove(timer)

            def modal_handler_add(self, operator):
                pass

        class Workspace:
            def status_text_set(self, text):
                driver.status.append(text)

        self.context = type("Context", (), {
            "window": object(), "window_manager": WindowManager(), "workspace": Workspace(),
            "active_object": property(lambda _: bpy.context.active_object),
            "scene": property(lambda _: bpy.context.scene), "view_layer": property(lambda _: bpy.context.view_layer),
            "evaluated_depsgraph_get": lambda _: bpy.context.evaluated_depsgraph_get(),
        })()

    def event(self, kind):
        return type("Event", (), {"type": kind, "value": "PRESS"})()

    def run(self, cancel_at_step: int | None = None, timeout: float = 300):
        import time

        assert self.operator.invoke(self.context, self.event("NONE")) == {'RUNNING_MODAL'}
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            time.sleep(0.1)
            if cancel_at_step is not None and self.operator._run.progress.step >= cancel_at_step:
                assert self.operator.modal(self.context, self.event("ESC")) == {'RUNNING_MODAL'}
                cancel_at_step = None
            outcome = self.operator.modal(self.context, self.event("TIMER"))
            if outcome != {'PASS_THROUGH'}:
                return outcome
        raise AssertionError("the run did not finish in time")


def test_from_the_ui_it_runs_in_the_background_and_shows_progress(blender):
    quadruped_object("Colt", modifier=False)
    objects, meshes = set(bpy.data.objects), set(bpy.data.meshes)
    driver = ModalDriver(mass_ratio=1.1)
    assert driver.run() == {'FINISHED'}
    (new,) = set(bpy.data.objects) - objects
    assert new.name == "Colt_x1.1" and bpy.context.active_object == new
    assert set(bpy.data.meshes) - meshes == {new.data}
    shown = [text for text in driver.status if text]
    assert shown and all(text.startswith("allorules: Colt_x1.1") and text.endswith("Esc to cancel") for text in shown)
    assert driver.status[-1] is None and driver.timers == []        # status bar cleared, timer removed
    assert any("mass ×1.100" in text for _, text in driver.operator.reports)


def test_esc_cancels_a_ui_run_and_adds_nothing(blender):
    quadruped_object("Filly", modifier=False)
    objects, meshes = set(bpy.data.objects), set(bpy.data.meshes)
    driver = ModalDriver(mass_ratio=3.0)
    assert driver.run(cancel_at_step=1) == {'CANCELLED'}
    assert driver.operator.reports == [({'WARNING'}, "allorules: cancelled; nothing was added")]
    assert "allorules: cancelling…" in driver.status and driver.status[-1] is None and driver.timers == []
    assert set(bpy.data.objects) == objects and set(bpy.data.meshes) == meshes


def test_label_regions_from_the_ui_runs_in_the_background_and_esc_cancels_it(blender):
    """Label Regions from the UI finds the regions in the worker thread (at 135k vertices it takes
    12 s, which froze Blender on the main thread), the status bar saying so; Esc adds nothing."""
    foal = quadruped_object("Yearling", modifier=False)
    driver = ModalDriver(label=True)
    assert driver.run(cancel_at_step=0) == {'CANCELLED'}
    assert driver.operator.reports == [({'WARNING'}, "allorules: cancelled; nothing was added")]
    assert len(foal.vertex_groups) == 0 and driver.status[-1] is None and driver.timers == []
    driver = ModalDriver(label=True)
    assert driver.run() == {'FINISHED'}
    shown = [text for text in driver.status if text]
    assert shown and all(text.startswith(f"allorules: {foal.name}, finding its regions (") and text.endswith("Esc to cancel")
                         for text in shown)
    assert driver.status[-1] is None and driver.timers == []
    assert {"region:head", "region:neck", "region:chest", "region:abdomen", "region:forelimbs",
            "region:hindlimbs"} <= set(_groups(foal))
    assert any("region vertex groups added" in text for _, text in driver.operator.reports)
