"""Blender objects in and out: the evaluated world-space mesh to arrays, new positions to a new object.

What crosses over (see docs/blender.md): the original's mesh *as evaluated* (modifiers, shape
keys and armature pose applied, as the viewport shows it) in *world space* (its object
transform, parents and constraints applied). allorules sees those vertex positions and the
mesh's triangles (``loop_triangles``); it returns a new world position for every Blender
vertex. The new object's mesh is a copy of the evaluated mesh (``new_from_object``), so quads,
n-gons, UV layers, materials, smooth/flat shading and every other attribute stay; only the
positions are written. The new object keeps the original's world matrix, moved sideways, and
has no modifiers (they are already applied). The original is never written to, except by the
Label Regions operator, which is asked to: it adds the vertex groups ``region:<name>``
(:func:`write_regions`), and the body's up and forward it found, in the object's own coordinates
(:func:`write_frame`, the custom property ``allorules_frame``). :func:`read_regions` and
:func:`read_frame` read them back (the groups through the modifiers, from the evaluated mesh).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import bpy
import mathutils
import numpy as np

from allorules.blender.adapter import GROUP_PREFIX, REGION_GROUPS
from allorules.errors import AllorulesError, MeshError, SegmentationError

FRAME_PROPERTY = "allorules_frame"   # Label Regions' up and forward, in the object's coordinates


@dataclass
class SourceMesh:
    """The original as allorules sees it, and copies of its evaluated mesh for the outputs."""

    object_name: str
    matrix: np.ndarray           # 4×4 world matrix of the (evaluated) original
    vertices: np.ndarray         # n×3 world-space positions, one per Blender vertex
    triangles: np.ndarray        # m×3 vertex indices (loop triangles)
    copies: list = field(default_factory=list)   # bpy.types.Mesh, not yet used by any object
    collections: list = field(default_factory=list)
    object_materials: dict = field(default_factory=dict)   # slot index -> material, for slots linked to the object
    regions: tuple[np.ndarray, tuple[str, ...]] | None = None   # from the vertex groups, when asked (read_regions)
    label_frame: tuple[np.ndarray, np.ndarray] | None = None   # (up, forward) in world space: Label Regions' (read_frame)


def read_source(context, obj, copies: int = 1, regions: bool = False) -> SourceMesh:
    """The evaluated, world-space mesh of ``obj`` and ``copies`` copies of its mesh data; with
    ``regions``, the regions of its ``region:`` vertex groups too (:func:`read_regions`)."""
    if obj is None or obj.type != 'MESH':
        raise MeshError("select a mesh object (the animal) and make it active")
    depsgraph = context.evaluated_depsgraph_get()
    evaluated = obj.evaluated_get(depsgraph)
    mesh = bpy.data.meshes.new_from_object(evaluated, preserve_all_data_layers=True, depsgraph=depsgraph)
    made = [mesh]
    try:
        count = len(mesh.vertices)
        if count == 0 or len(mesh.polygons) == 0:
            raise MeshError(f"{obj.name}: the mesh has no faces; allorules needs a surface")
        matrix = np.array(evaluated.matrix_world, dtype=np.float64)
        if abs(np.linalg.det(matrix[:3, :3])) < 1e-12:
            raise MeshError(f"{obj.name}: its object scale is zero along an axis; give it a non-zero scale")
        local = np.empty(count * 3, dtype=np.float32)
        mesh.vertices.foreach_get("co", local)
        local = local.reshape(-1, 3).astype(np.float64)
        mesh.calc_loop_triangles()
        triangles = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int32)
        mesh.loop_triangles.foreach_get("vertices", triangles)
        world = local @ matrix[:3, :3].T + matrix[:3, 3]
        painted = read_regions(obj, mesh) if regions else None
        frame = read_frame(obj, matrix) if regions else None
        for _ in range(copies - 1):
            made.append(mesh.copy())
    except BaseException:
        for item in made:
            bpy.data.meshes.remove(item)
        raise
    object_materials = {index: slot.material for index, slot in enumerate(obj.material_slots) if slot.link == 'OBJECT'}
    return SourceMesh(obj.name, matrix, world, triangles.reshape(-1, 3).astype(np.int64), made,
                      list(obj.users_collection), object_materials, painted, frame)


def region_groups(obj) -> dict[int, str]:
    """``obj``'s vertex groups that carry a region: group index -> region name."""
    return {group.index: group.name[len(GROUP_PREFIX):] for group in obj.vertex_groups
            if group.name.startswith(GROUP_PREFIX) and len(group.name) > len(GROUP_PREFIX)}


def read_regions(obj, mesh) -> tuple[np.ndarray, tuple[str, ...]]:
    """The region of every vertex of ``mesh`` (``obj``'s evaluated mesh, whose vertex weights came
    through the modifiers): the ``region:`` group it weighs most in, -1 where none."""
    groups = region_groups(obj)
    if not groups:
        raise SegmentationError(f"{obj.name} has no vertex groups named {REGION_GROUPS}; make them with "
                                "Label Regions (or paint them), or set Regions to Detect")
    names = tuple(groups.values())
    column = {index: names.index(name) for index, name in groups.items()}
    labels = np.full(len(mesh.vertices), -1, dtype=np.int64)
    for vertex in mesh.vertices:
        best = 0.0
        for element in vertex.groups:
            if element.group in column and element.weight > best:
                best, labels[vertex.index] = element.weight, column[element.group]
    if (labels < 0).all():
        raise SegmentationError(f"{obj.name}: its region vertex groups hold no vertex; paint them, or set Regions "
                                "to Detect")
    return labels, names


def write_frame(obj, matrix: np.ndarray, up, forward) -> None:
    """Keep the body's up and forward (world space, as Label Regions found them) on ``obj``, in its
    own coordinates (``FRAME_PROPERTY``), so that they follow the object when it is moved or turned."""
    inverse = np.linalg.inv(np.asarray(matrix, dtype=float)[:3, :3])
    local = {name: (inverse @ np.asarray(direction, dtype=float)).tolist() for name, direction in
             (("up", up), ("forward", forward))}
    obj[FRAME_PROPERTY] = json.dumps(local)


def read_frame(obj, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The (up, forward) :func:`write_frame` kept on ``obj``, in world space now; None when it has
    none (regions painted by hand) or one that cannot be read."""
    try:
        local = json.loads(obj.get(FRAME_PROPERTY, ""))
        up, forward = (np.asarray(local[name], dtype=float) for name in ("up", "forward"))
    except (TypeError, ValueError, KeyError):
        return None
    if up.shape != (3,) or forward.shape != (3,) or not (np.isfinite(up).all() and np.isfinite(forward).all()):
        return None
    linear = np.asarray(matrix, dtype=float)[:3, :3]
    up, forward = linear @ up, linear @ forward
    if min(np.linalg.norm(up), np.linalg.norm(forward)) < 1e-12:
        return None
    return up / np.linalg.norm(up), forward / np.linalg.norm(forward)


def check_regions_writable(obj, count: int) -> None:
    """Refuse, before any work, what :func:`write_regions` would refuse for labels of ``count``
    vertices (those of ``obj``'s evaluated mesh): region groups the object has already (someone may
    have painted them), modifiers that change its vertices."""
    painted = region_groups(obj)
    if painted:
        raise SegmentationError(f"{obj.name} already has region vertex groups ({', '.join(sorted(painted.values()))}); "
                                "delete them to label it again")
    if count != len(obj.data.vertices):
        raise MeshError(f"{obj.name}: its modifiers change its vertices ({len(obj.data.vertices)} → {count}); "
                        "label a copy with the modifiers applied, or paint the region groups by hand")


def write_regions(obj, labels: np.ndarray, names) -> list[str]:
    """Add a vertex group ``region:<name>`` (weight 1) to ``obj`` for each region with vertices;
    ``labels`` holds one region index per vertex of ``obj``'s own mesh. Refused as
    :func:`check_regions_writable` says. Returns the groups' names."""
    check_regions_writable(obj, len(labels))
    added = []
    for index, name in enumerate(names):
        members = np.flatnonzero(np.asarray(labels) == index)
        if len(members):
            group = obj.vertex_groups.new(name=GROUP_PREFIX + name)
            group.add(members.tolist(), 1.0, 'REPLACE')
            added.append(group.name)
    return added


def discard(source: SourceMesh) -> None:
    """Remove the mesh copies no object took (after an error or a cancel)."""
    for mesh in source.copies:
        try:
            if mesh.users == 0:
                bpy.data.meshes.remove(mesh)
        except ReferenceError:   # already gone (undo, file reload)
            pass
    source.copies.clear()


def beside(reference: np.ndarray, placed: np.ndarray, direction: np.ndarray, gap: float, after: bool = True) -> np.ndarray:
    """The translation along the unit ``direction`` that puts ``placed`` just past ``reference``
    (``after``: on the positive side, else the negative), ``gap`` apart."""
    along_reference, along_placed = reference @ direction, placed @ direction
    if after:
        shift = along_reference.max() + gap - along_placed.min()
    else:
        shift = along_reference.min() - gap - along_placed.max()
    return shift * direction


def frame_axes(report: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit up, forward and left (up × forward) of the body, in world space, from a run's report."""
    up = np.asarray(report["up"], dtype=float)
    forward = np.asarray(report["forward"], dtype=float)
    forward = forward - (forward @ up) * up
    forward /= np.linalg.norm(forward)
    left = np.cross(up, forward)
    return up, forward, left


def add_object(context, source: SourceMesh, world_positions: np.ndarray, name: str, offset: np.ndarray):
    """A new object from one of ``source``'s mesh copies with ``world_positions`` + ``offset``.

    The object gets the original's world matrix moved by ``offset`` (so it looks like the original
    moved aside), its collections and object-linked materials; it is selected and made active.
    """
    if not source.copies:
        raise AllorulesError("internal: no mesh copy left for the new object")
    mesh = source.copies.pop(0)
    if len(mesh.vertices) != len(world_positions):
        bpy.data.meshes.remove(mesh)
        raise MeshError(f"{source.object_name}: the mesh changed while allorules was running; run it again")
    inverse = np.linalg.inv(source.matrix)
    local = world_positions @ inverse[:3, :3].T + inverse[:3, 3]
    mesh.vertices.foreach_set("co", local.astype(np.float32).ravel())
    mesh.update()
    mesh.name = name
    obj = bpy.data.objects.new(name, mesh)
    matrix = source.matrix.copy()
    matrix[:3, 3] += offset
    obj.matrix_world = mathutils.Matrix(matrix.tolist())      # rows, as np.array(Matrix) gave them
    collections = [c for c in source.collections if _alive(c)] or [context.scene.collection]
    for collection in collections:
        collection.objects.link(obj)
    for index, material in source.object_materials.items():
        if index < len(obj.material_slots):
            obj.material_slots[index].link = 'OBJECT'
            obj.material_slots[index].material = material
    for other in context.view_layer.objects:
        other.select_set(False)
    if obj.name in context.view_layer.objects:
        obj.select_set(True)
        context.view_layer.objects.active = obj
    return obj


def _alive(collection) -> bool:
    try:
        return collection.name is not None
    except ReferenceError:
        return False
