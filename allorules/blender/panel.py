"""The sidebar panel (3D viewport, N panel, tab "allorules") and the settings it edits.

The settings live on the scene (``scene.allorules``): the ruleset (built-ins and plugins' sets
with their descriptions, or a file), the mass ratio with x0.5 / x2, modes, posture, global mode,
up, forward and where the regions come from (detected, or the vertex groups Label Regions adds).
Scale and Gallery call the operators with them (invoked, so they run in the background).
After a run the panel shows its table: each rule's target and achieved exponent, met or not,
the mass and stress ratios, and any warnings.
"""
# No "from __future__ import annotations": Blender reads the property annotations as objects.
import json
import textwrap

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    StringProperty,
)

from allorules.blender.operators import (
    FORWARD_ITEMS,
    POSTURE_ITEMS,
    REGIONS_ITEMS,
    UP_ITEMS,
)
from allorules.blender.results import RunSummary

FILE = "__FILE__"
_ITEMS: list = []     # Blender needs the enum items kept alive while they are shown


def ruleset_items(self, context):
    """Every ruleset that can be named (name, description), then "File…"."""
    if not _ITEMS:
        try:
            from allorules.rules.find import list_rulesets

            for summary in list_rulesets():
                _ITEMS.append((summary.name, summary.name, summary.description or summary.name))
        except Exception as error:   # noqa: BLE001 - a broken plugin must not break the panel
            _ITEMS.append(("quadruped", "quadruped", f"(the ruleset list failed: {error})"))
        _ITEMS.append((FILE, "File…", "a ruleset YAML file of your own"))
    return _ITEMS


class AllorulesSettings(bpy.types.PropertyGroup):
    ruleset: EnumProperty(name="Ruleset", items=ruleset_items, description="which allometric rules to follow")
    ruleset_file: StringProperty(name="File", subtype='FILE_PATH', description="a ruleset YAML file")
    mass_ratio: FloatProperty(name="Mass ratio", default=2.0, min=0.001, max=1000.0, soft_min=0.1, soft_max=10.0,
                              precision=3, description="body-mass ratio: 2 doubles the mass, 0.5 halves it")
    modes: IntProperty(name="Modes", default=0, min=0, soft_max=3000,
                       description="harmonic basis size; 0 = the default (1000)")
    posture: EnumProperty(name="Posture", items=POSTURE_ITEMS, default="RULESET")
    global_mode: BoolProperty(name="Global scaling", default=False,
                              description="one exponent for the whole body at unchanged limb stress (no ruleset)")
    up: EnumProperty(name="Up", items=UP_ITEMS, default="Z")
    forward: EnumProperty(name="Forward", items=FORWARD_ITEMS, default="AUTO")
    regions: EnumProperty(name="Regions", items=REGIONS_ITEMS, default="DETECT")
    last_result: StringProperty(name="Last result", default="", options={'HIDDEN'})

    def chosen_ruleset(self) -> str:
        return self.ruleset_file if self.ruleset == FILE else self.ruleset


def _fill(operator, settings: AllorulesSettings) -> None:
    operator.ruleset = settings.chosen_ruleset()
    operator.mass_ratio = settings.mass_ratio
    operator.modes = settings.modes
    operator.posture = settings.posture
    operator.global_mode = settings.global_mode
    operator.up = settings.up
    operator.forward = settings.forward
    operator.regions = settings.regions


def _wrapped(layout, text: str, width: int = 44, icon: str = 'NONE') -> None:
    for number, line in enumerate(textwrap.wrap(text, width) or [""]):
        layout.label(text=line, icon=icon if number == 0 else 'BLANK1' if icon != 'NONE' else 'NONE')


class VIEW3D_PT_allorules(bpy.types.Panel):
    bl_label = "Allometric Scaling"
    bl_idname = "VIEW3D_PT_allorules"
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "allorules"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.allorules
        column = layout.column()
        column.prop(settings, "global_mode")
        if not settings.global_mode:
            column.prop(settings, "ruleset")
            if settings.ruleset == FILE:
                column.prop(settings, "ruleset_file")
            else:
                description = next((item[2] for item in ruleset_items(settings, context) if item[0] == settings.ruleset), "")
                box = column.box()
                _wrapped(box.column(align=True), description)
        row = column.row(align=True)
        row.prop(settings, "mass_ratio")
        row.operator("allorules.mass_ratio_times", text="x0.5").factor = 0.5
        row.operator("allorules.mass_ratio_times", text="x2").factor = 2.0
        column.prop(settings, "posture")
        column.prop(settings, "up")
        column.prop(settings, "forward")
        row = column.row(align=True)
        row.prop(settings, "regions")
        label = row.operator("allorules.label_regions", text="", icon='GROUP_VERTEX')
        label.up, label.forward = settings.up, settings.forward
        column.prop(settings, "modes")
        column.separator()
        _fill(column.operator("allorules.scale", text="Scale", icon='FULLSCREEN_ENTER'), settings)
        _fill(column.operator("allorules.gallery", text="Gallery", icon='MOD_ARRAY'), settings)
        if settings.last_result:
            self.draw_result(layout, settings.last_result)

    @staticmethod
    def draw_result(layout, text: str) -> None:
        try:
            summaries = [RunSummary.from_dict(item) for item in json.loads(text)]
        except (ValueError, TypeError, KeyError):
            return
        for summary in summaries:
            box = layout.box()
            box.label(text=f"{summary.object} ({summary.ruleset or summary.kind})",
                      icon='CHECKMARK' if summary.all_met else 'ERROR')
            stress = "" if summary.stress_ratio is None else f", stress ×{summary.stress_ratio:.3f}"
            box.label(text=f"mass ×{summary.mass_ratio:.3f} (target {summary.target_mass_ratio:g}){stress}")
            if summary.rules:
                grid = box.grid_flow(row_major=True, columns=4, even_columns=False, align=True)
                for cell in ("rule", "target", "achieved", ""):
                    grid.label(text=cell)
                for rule in summary.rules:
                    grid.label(text=rule.id)
                    grid.label(text=f"{rule.target:.3f}")
                    grid.label(text=f"{rule.achieved:.3f}")
                    grid.label(text="met" if rule.met else "missed", icon='CHECKMARK' if rule.met else 'X')
            for warning in summary.warnings:
                _wrapped(box.column(align=True), warning, icon='ERROR')


CLASSES = (AllorulesSettings, VIEW3D_PT_allorules)
