"""allorules in Blender: the add-on (operators, sidebar panel) and its packaging as an extension.

``import allorules.blender`` works without Blender: only :func:`register` / :func:`unregister`
import ``bpy``. :mod:`~allorules.blender.adapter` (arrays in, new positions out) and
:mod:`~allorules.blender.build` (the extension archive) never need it. See docs/blender.md.

In Blender: install the extension file (Preferences > Get Extensions > Install from Disk), or
from a script where allorules is importable: ``import allorules.blender; allorules.blender.register()``,
then ``bpy.ops.allorules.scale(ruleset="quadruped", mass_ratio=2.0)`` on the active mesh object.
"""
from __future__ import annotations


def register() -> None:
    """Register the operators, the panel and ``Scene.allorules`` (needs ``bpy``)."""
    import bpy

    from allorules.blender import operators, panel

    for cls in (*operators.CLASSES, *panel.CLASSES):
        bpy.utils.register_class(cls)
    bpy.types.Scene.allorules = bpy.props.PointerProperty(type=panel.AllorulesSettings)


def unregister() -> None:
    """Undo :func:`register`."""
    import bpy

    from allorules.blender import operators, panel

    if hasattr(bpy.types.Scene, "allorules"):
        del bpy.types.Scene.allorules
    for cls in reversed((*operators.CLASSES, *panel.CLASSES)):
        bpy.utils.unregister_class(cls)
