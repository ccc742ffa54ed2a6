"""The add-on's operators: ``allorules.scale``, ``allorules.gallery``, ``allorules.label_regions`` and
the panel's x0.5 / x2.

From a script (``EXEC_DEFAULT``) a run or a labelling completes before the call returns. From the
UI (``INVOKE_DEFAULT``) it runs in a worker thread (:mod:`allorules.blender.runner`) polled by a
modal timer (:class:`_InBackground`): the status bar shows its progress, Esc cancels it, Blender
stays responsive. Either way, failures become one Blender report with allorules' one-line message;
a failed or cancelled run adds nothing. Everything allorules does goes through
:mod:`allorules.blender.adapter` (``scale_arrays``, ``label_arrays``).
"""
# No "from __future__ import annotations": Blender reads the property annotations as objects.
import json
import logging
from dataclasses import dataclass
from typing import Callable

import bpy
import numpy as np
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    StringProperty,
)

from allorules.blender import adapter
from allorules.blender.objects import (
    SourceMesh,
    add_object,
    beside,
    check_regions_writable,
    discard,
    frame_axes,
    read_source,
    write_frame,
    write_regions,
)
from allorules.blender.results import RunSummary, run_summary
from allorules.blender.runner import BackgroundRun, Cancelled
from allorules.errors import AllorulesError, MeshError

log = logging.getLogger("allorules.blender")

POSTURE_ITEMS = [
    ("RULESET", "Ruleset's", "the posture the ruleset asks for (keep, unless it says otherwise)"),
    ("keep", "Keep", "legs upright, feet on the ground, the legs' lines kept"),
    ("upright", "Upright", "legs turned upright only"),
    ("free", "Free", "as the power laws leave them"),
]
UP_ITEMS = [
    ("Z", "World +Z", "the animal stands on the XY plane, back towards +Z (Blender's convention)"),
    ("AUTO", "Detect", "let allorules find the body's up direction from its shape"),
]
FORWARD_ITEMS = [
    ("AUTO", "Detect", "let allorules tell the head from the tail from the animal's shape"),
    ("-Y", "World -Y", "the animal faces -Y, towards Blender's front view"),
    ("+Y", "World +Y", "the animal faces +Y"),
    ("+X", "World +X", "the animal faces +X"),
    ("-X", "World -X", "the animal faces -X"),
]
REGIONS_ITEMS = [
    ("DETECT", "Detect", "let allorules find the head, neck, chest, abdomen, legs (and tail, ears, horns)"),
    ("GROUPS", "Vertex groups", "the regions painted as vertex groups region:head, region:neck, region:chest, "
                                "region:abdomen, region:forelimbs, region:hindlimbs (Label Regions makes them)"),
]
GAP = 0.25   # space left between copies, as a share of the original's extent in that direction


@dataclass(frozen=True)
class Settings:
    """One operator call's settings, as the adapter takes them."""

    ruleset: str
    modes: int | None
    posture: str | None
    global_mode: bool
    up: np.ndarray | None
    forward: np.ndarray | None
    painted: bool = False            # the regions come from the object's region: vertex groups

    def scale(self, source: SourceMesh, ratio: float, progress=None):
        up, forward = self.up, self.forward
        if source.regions is not None and source.label_frame is not None and forward is None:
            up, forward = source.label_frame      # the axes Label Regions found, unless Forward is set
        return adapter.scale_arrays(source.vertices, source.triangles, ruleset=self.ruleset, mass_ratio=ratio,
                                    modes=self.modes, posture=self.posture, global_mode=self.global_mode,
                                    up=up, forward=forward, regions=source.regions, progress=progress)


def copy_name(source_name: str, ratio: float) -> str:
    """``Horse_x2``, ``Horse_x0.5``: the original's name and the mass ratio."""
    return f"{source_name}_x{ratio:.3g}"


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


def _directions(up: str, forward: str) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The Up and Forward settings as the adapter takes them (``None``: detected)."""
    facing = adapter.FORWARD_DIRECTIONS[forward]
    return (np.array([0.0, 0.0, 1.0]) if up == "Z" else None), (None if facing is None else np.array(facing))


def _poll_animal(cls, context) -> bool:
    """An operator on the animal runs on the active mesh object, in Object Mode."""
    obj = context.active_object
    if obj is None or obj.type != 'MESH':
        cls.poll_message_set("select the animal's mesh object and make it active")
        return False
    if context.mode != 'OBJECT':
        cls.poll_message_set("switch to Object Mode first")
        return False
    return True


class _InBackground:
    """What the operators share: their work runs before the call returns from a script (``execute``)
    and in a worker thread from the UI (``invoke``, then ``modal`` polls it); either way every
    failure becomes one report and a failed or cancelled operator adds nothing.

    An operator says what its work is (:meth:`begin`, on the main thread: it reads the Blender data
    and checks the settings, so that bad settings are refused before any work) and what becomes of
    its result (:meth:`finish`, on the main thread again)."""

    def begin(self, context) -> tuple[SourceMesh, Callable]:
        """The Blender data read (a :class:`SourceMesh`, discarded after) and the work: a function of
        a progress object (``None`` from a script) that touches numpy arrays only."""
        raise NotImplementedError

    def finish(self, context, source: SourceMesh, result) -> set[str]:
        raise NotImplementedError

    def stage(self, source: SourceMesh) -> tuple[str, str]:
        """What the status bar says first (the work's progress says what follows): the stage, what
        is being done."""
        return source.object_name, "preparing the mesh"

    def fail(self, error: BaseException) -> set[str]:
        if isinstance(error, Cancelled):
            self.report({'WARNING'}, "allorules: cancelled; nothing was added")
        elif isinstance(error, AllorulesError):
            self.report({'ERROR'}, adapter.in_panel_terms(_one_line(error)))
        else:   # a bug: the traceback goes to the console, the user gets one line
            log.error("allorules failed", exc_info=(type(error), error, error.__traceback__))
            self.report({'ERROR'}, f"allorules failed unexpectedly ({type(error).__name__}: {_one_line(error)}); "
                                   "the console has the details, please report it")
        return {'CANCELLED'}

    def execute(self, context):
        source = None
        try:
            source, work = self.begin(context)
            return self.finish(context, source, work(None))
        except BaseException as error:   # noqa: BLE001 - every failure becomes a report
            if source is not None:
                discard(source)
            if isinstance(error, (KeyboardInterrupt, SystemExit)):
                raise
            return self.fail(error)

    def invoke(self, context, event):
        if context.window is None:        # no UI (background): nothing to keep responsive
            return self.execute(context)
        try:
            source, work = self.begin(context)
        except AllorulesError as error:
            return self.fail(error)
        self._source = source
        self._run = BackgroundRun(work)
        self._run.progress.begin(*self.stage(source))
        self._run.start()
        manager = context.window_manager
        self._timer = manager.event_timer_add(0.25, window=context.window)
        manager.modal_handler_add(self)
        context.workspace.status_text_set(self._run.status())
        return {'RUNNING_MODAL'}

    def modal(self, context, event):
        if event.type == 'ESC' and event.value == 'PRESS':
            self._run.cancel()
            context.workspace.status_text_set(self._run.status())
            return {'RUNNING_MODAL'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        if not self._run.done:
            context.workspace.status_text_set(self._run.status())
            return {'PASS_THROUGH'}
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        error = Cancelled("cancelled") if self._run.progress.cancelled else self._run.error
        if error is not None:           # cancelled after the work's last check: its result is dropped too
            discard(self._source)
            return self.fail(error)
        try:
            return self.finish(context, self._source, self._run.result)
        except Exception as error:   # noqa: BLE001 - every failure becomes a report
            return self.fail(error)

    def cancel(self, context):      # Blender closes the operator (file loaded, window closed)
        self._run.cancel()
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        self._run.wait(30)
        discard(self._source)


class _RunsAllorules(_InBackground):
    """What the scale and gallery operators share: their settings, their work (one run per mass
    ratio) and the summary of each object they add."""

    ruleset: StringProperty(name="Ruleset", default="quadruped",
                            description="a ruleset name (see the allorules panel) or the path of a ruleset YAML file")
    mass_ratio: FloatProperty(name="Mass ratio", default=2.0, min=0.001, max=1000.0, soft_min=0.1, soft_max=10.0,
                              precision=3, description="body-mass ratio: 2 doubles the animal's mass, 0.5 halves it")
    modes: IntProperty(name="Modes", default=0, min=0, soft_max=3000,
                       description="harmonic basis size; 0 = allorules' default (1000, as the command line)")
    posture: EnumProperty(name="Posture", items=POSTURE_ITEMS, default="RULESET",
                          description="how the legs stand through the steps")
    global_mode: BoolProperty(name="Global", default=False,
                              description="global allometric scaling: one exponent for the whole body, limb stress "
                                          "kept (the ruleset is not used)")
    up: EnumProperty(name="Up", items=UP_ITEMS, default="Z", description="which way is up for the animal")
    forward: EnumProperty(name="Forward", items=FORWARD_ITEMS, default="AUTO",
                          description="which way the animal faces (tail to head); set it when allorules cannot tell")
    regions: EnumProperty(name="Regions", items=REGIONS_ITEMS, default="DETECT",
                          description="where the body's regions come from")

    poll = classmethod(_poll_animal)

    # --- what differs between the operators -----------------------------------------------------
    def ratios(self) -> list[float]:
        raise NotImplementedError

    def place(self, context, source: SourceMesh, results) -> list:
        raise NotImplementedError

    # --- shared ---------------------------------------------------------------------------------
    def settings(self) -> Settings:
        ruleset = bpy.path.abspath(self.ruleset) if self.ruleset.startswith("//") else self.ruleset
        up, forward = _directions(self.up, self.forward)
        settings = Settings(ruleset=ruleset, modes=self.modes or None,
                            posture=None if self.posture == "RULESET" else self.posture,
                            global_mode=self.global_mode, up=up, forward=forward,
                            painted=self.regions == "GROUPS")
        for ratio in self.ratios():
            adapter.check_settings(ruleset=settings.ruleset, mass_ratio=ratio, modes=settings.modes,
                                   posture=settings.posture, global_mode=settings.global_mode)
        return settings

    def _copy_stage(self, source: SourceMesh, index: int) -> str:
        ratios = self.ratios()
        name = copy_name(source.object_name, ratios[index])
        return f"{name} ({index + 1} of {len(ratios)})" if len(ratios) > 1 else name

    def stage(self, source: SourceMesh) -> tuple[str, str]:
        return self._copy_stage(source, 0), "preparing the mesh"

    def work(self, settings: Settings, source: SourceMesh, progress=None) -> list:
        results = []
        for index, ratio in enumerate(self.ratios()):
            if progress is not None:
                progress.begin(self._copy_stage(source, index))
            results.append(settings.scale(source, ratio, progress))
        return results

    def begin(self, context):
        settings = self.settings()
        source = read_source(context, context.active_object, copies=len(self.ratios()), regions=settings.painted)
        return source, lambda progress: self.work(settings, source, progress)

    def finish(self, context, source: SourceMesh, results) -> set[str]:
        try:
            objects = self.place(context, source, results)
        finally:
            discard(source)
        summaries = []
        for obj, (_, report) in zip(objects, results):
            summary = run_summary(report, object_name=obj.name, source_name=source.object_name)
            obj["allorules"] = json.dumps(summary.as_dict())
            summaries.append(summary.as_dict())
        context.scene.allorules.last_result = json.dumps(summaries)
        for summary in summaries:
            self.report({'INFO'}, RunSummary.from_dict(summary).line())
        return {'FINISHED'}


class ALLORULES_OT_scale(_RunsAllorules, bpy.types.Operator):
    """Scale the active animal by a body-mass ratio the way biology does; the result is a new object beside it"""

    bl_idname = "allorules.scale"
    bl_label = "Scale Animal"
    bl_options = {'REGISTER', 'UNDO'}

    def ratios(self) -> list[float]:
        return [float(self.mass_ratio)]

    def place(self, context, source: SourceMesh, results) -> list:
        (positions, report), = results
        up, forward, left = frame_axes(report)
        width = float(np.ptp(source.vertices @ left))
        offset = beside(source.vertices, positions, left, GAP * width + 1e-9, after=True)
        return [add_object(context, source, positions, copy_name(source.object_name, self.mass_ratio), offset)]


class ALLORULES_OT_gallery(_RunsAllorules, bpy.types.Operator):
    """The paper's row: a minified and a magnified copy of the active animal on either side of it, on its ground"""

    bl_idname = "allorules.gallery"
    bl_label = "Gallery (minified / original / magnified)"
    bl_options = {'REGISTER', 'UNDO'}

    def ratios(self) -> list[float]:
        ratio = max(float(self.mass_ratio), 1.0 / float(self.mass_ratio))
        return [1.0 / ratio, ratio]

    def place(self, context, source: SourceMesh, results) -> list:
        (small, report), (large, _) = results
        up, forward, left = frame_axes(report)
        length = float(np.ptp(source.vertices @ forward))
        gap = GAP * length + 1e-9
        ratios = self.ratios()
        return [
            add_object(context, source, small, copy_name(source.object_name, ratios[0]),
                       beside(source.vertices, small, forward, gap, after=False)),
            add_object(context, source, large, copy_name(source.object_name, ratios[1]),
                       beside(source.vertices, large, forward, gap, after=True)),
        ]


class ALLORULES_OT_label_regions(_InBackground, bpy.types.Operator):
    """Find the active animal's regions as a run would and add them to it as vertex groups region:<name>, to check and paint before scaling with Regions set to Vertex groups"""

    bl_idname = "allorules.label_regions"
    bl_label = "Label Regions"
    bl_options = {'REGISTER', 'UNDO'}

    up: EnumProperty(name="Up", items=UP_ITEMS, default="Z", description="which way is up for the animal")
    forward: EnumProperty(name="Forward", items=FORWARD_ITEMS, default="AUTO",
                          description="which way the animal faces (tail to head); set it when allorules cannot tell")

    poll = classmethod(_poll_animal)

    def begin(self, context):
        obj = context.active_object
        source = read_source(context, obj, copies=1)
        try:   # what would stop the groups being written is refused before the work
            check_regions_writable(obj, len(source.vertices))
        except AllorulesError:
            discard(source)
            raise
        up, forward = _directions(self.up, self.forward)

        return source, lambda progress: adapter.label_arrays(source.vertices, source.triangles, up=up, forward=forward)

    def stage(self, source: SourceMesh) -> tuple[str, str]:
        return source.object_name, "finding its regions"

    def finish(self, context, source: SourceMesh, result) -> set[str]:
        labels, names, report = result
        try:
            obj = bpy.data.objects.get(source.object_name)
            if obj is None:
                raise MeshError(f"{source.object_name} was removed while its regions were found; nothing was added")
            if len(obj.data.vertices) != len(source.vertices):
                raise MeshError(f"{obj.name}'s mesh changed while its regions were found; run Label Regions again")
            added = write_regions(obj, labels, names)
            write_frame(obj, source.matrix, report["up"], report["forward"])
        finally:
            discard(source)
        sure = ", ".join(f"{key} {value:.2f}" for key, value in report.get("confidence", {}).items())
        self.report({'INFO'}, f"{obj.name}: {len(added)} region vertex groups added ({', '.join(added)})"
                              + (f"; confidence {sure}" if sure else "") + "; check them, paint where wrong, "
                              "then scale with Regions set to Vertex groups")
        return {'FINISHED'}


class ALLORULES_OT_mass_ratio_times(bpy.types.Operator):
    """Multiply the panel's mass ratio"""

    bl_idname = "allorules.mass_ratio_times"
    bl_label = "Multiply Mass Ratio"
    bl_options = {'INTERNAL'}

    factor: FloatProperty(name="Factor", default=2.0)

    def execute(self, context):
        settings = context.scene.allorules
        settings.mass_ratio = min(1000.0, max(0.001, settings.mass_ratio * self.factor))
        return {'FINISHED'}


CLASSES = (ALLORULES_OT_scale, ALLORULES_OT_gallery, ALLORULES_OT_label_regions, ALLORULES_OT_mass_ratio_times)
