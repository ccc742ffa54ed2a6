"""Building test scenes in Blender (bpy), shared by the add-on's tests and the script that runs
the installed extension in a separate interpreter (so: no pytest here)."""
from __future__ import annotations

import math

import bpy
import numpy as np

DISPLACE = 0.02     # the Displace modifier's strength: the evaluated surface moves 0.01 out (object units)


def world_positions(obj, evaluated: bool = False) -> np.ndarray:
    source = obj
    if evaluated:
        source = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = source.data if not evaluated else source.to_mesh()
    local = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", local)
    if evaluated:
        source.to_mesh_clear()
    matrix = np.array(source.matrix_world)
    return local.reshape(-1, 3).astype(float) @ matrix[:3, :3].T + matrix[:3, 3]


def quadruped_object(name: str, vertices: int = 2000, modifier: bool = True, pose: str | None = None):
    """The generated horse (in ``pose``, standing by default) as a Blender object: +Y up in its
    mesh, turned to stand on Z by its object rotation, scaled and moved; UV-mapped, two materials,
    smooth shaded, optionally with a Displace modifier (so the evaluated mesh differs from the mesh
    data). The generator's truth is the object's ``truth`` property (JSON: region names, labels)."""
    import json

    from allorules.mesh.quadruped import generate_quadruped

    horse = generate_quadruped("horse", vertices, pose=pose)
    mesh = bpy.data.meshes.new(f"{name}Mesh")
    mesh.from_pydata(horse.vertices.tolist(), [], horse.faces.tolist())
    mesh.update()
    uv = mesh.uv_layers.new(name="UVMap")
    corners = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    uv.data.foreach_set("uv", (horse.vertices[corners][:, :2] * 0.3 + 0.5).astype(np.float32).ravel())
    for material in ("Coat", "Hooves"):
        mesh.materials.append(bpy.data.materials.get(material) or bpy.data.materials.new(material))
    centres = np.array([polygon.center[1] for polygon in mesh.polygons])
    mesh.polygons.foreach_set("material_index", (centres < np.quantile(centres, 0.1)).astype(np.int32))
    mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    obj["truth"] = json.dumps({"regions": list(horse.region_names), "labels": horse.labels.tolist()})
    bpy.context.scene.collection.objects.link(obj)
    obj.rotation_euler = (math.pi / 2, 0.0, 0.4)
    obj.scale = (2.0, 2.0, 2.0)
    obj.location = (3.0, -1.0, 0.5)
    if modifier:
        displace = obj.modifiers.new("Displace", 'DISPLACE')
        displace.strength = DISPLACE
    for other in bpy.context.view_layer.objects:
        other.select_set(False)
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    bpy.context.view_layer.update()
    return obj
