"""Writing meshes that users open in Blender: formats, atomic files, what is carried over.

:func:`save_mesh` writes OBJ, PLY, STL, GLB or OFF (chosen by the output's extension). Every file
is written to a temporary file in the destination folder and moved into place with
``os.replace``, so a failure never leaves a half-written file; an existing file (and above all
the input) is never overwritten unless the caller asks.

When the caller passes ``source`` (the input's ``trimesh.Trimesh`` as loaded, with its UVs and
material) and positions for the *source's* vertex layout (same vertex count and faces — see
:meth:`allorules.mesh.repair.PreparedMesh.source_positions`), the output keeps the input's
texture coordinates and material references, with normals recomputed for the new shape:

* OBJ from an OBJ input: the input file is rewritten line by line — new ``v`` positions, each
  ``vn`` recomputed for the new shape over the corners that use it (hard edges stay hard), and
  everything else (``f``, ``vt``, ``mtllib``, ``usemtl``, groups, smoothing) kept verbatim, so
  multi-material files stay multi-material and the file loads back with the input's layout. The ``.mtl`` and its textures are
  referenced, and copied next to the output only when they are missing there.
* GLB, PLY, and OBJ from other inputs: through trimesh, with the source's visual (UVs,
  material) attached.
* STL and OFF hold geometry only.

Helpers :func:`atomic_write` / :func:`atomic_path` are shared by the render and report modules.
"""
from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from allorules.errors import MeshError
from allorules.files import atomic_path, atomic_write, same_file
from allorules.mesh.geometry import face_normals, vertex_normals
from allorules.mesh.references import MTLLIB, TEXTURE_MAP, texture_name

log = logging.getLogger("allorules.output.export")

SUPPORTED_FORMATS = (".obj", ".ply", ".stl", ".glb", ".off")


@dataclass
class SaveResult:
    """What :func:`save_mesh` wrote and what it could carry over from the input."""

    path: Path
    format: str
    carried: list[str] = field(default_factory=list)     # e.g. "UVs", "materials (mtllib x.mtl)"
    notes: list[str] = field(default_factory=list)       # things the user should know
    extra_files: list[Path] = field(default_factory=list)  # .mtl / textures written beside it


# --------------------------------------------------------------------------------------------
# Atomic files


# --------------------------------------------------------------------------------------------
# Output names


# --------------------------------------------------------------------------------------------
# Normals


# --------------------------------------------------------------------------------------------
# Saving


def save_mesh(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    source: Any = None,
    overwrite: bool = False,
    input_path: str | Path | None = None,
) -> SaveResult:
    """Write a triangle mesh; the format follows ``path``'s extension (.obj .ply .stl .glb .off).

    ``source`` is the input's ``trimesh.Trimesh`` as loaded. When ``vertices`` has the source's
    vertex count and ``faces`` equals the source's faces (the scaling keeps connectivity; use
    ``PreparedMesh.source_positions`` to get there), UVs and materials are carried over and
    normals recomputed. ``input_path`` is never overwritten unless ``overwrite=True``, and neither
    is any other existing file. Raises :class:`MeshError` for non-finite positions, bad faces,
    unsupported extensions and refused overwrites.
    """
    path = Path(path)
    extension = path.suffix.lower()
    if extension not in SUPPORTED_FORMATS:
        raise MeshError(
            f"{path}: cannot write {extension or 'a file without extension'}; "
            f"name the output with one of {', '.join(SUPPORTED_FORMATS)}"
        )
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"{path}: vertices must be an (n, 3) array, got shape {vertices.shape}")
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise MeshError(
            f"{path}: not written, {bad} vertex position(s) are NaN or infinite "
            "(the scaling diverged; try a smaller ratio or more steps)"
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or (len(faces) and not np.issubdtype(faces.dtype, np.integer)):
        raise MeshError(f"{path}: faces must be an (m, 3) integer array, got shape {faces.shape}")
    faces = faces.astype(np.int64)
    if len(faces) == 0:
        raise MeshError(f"{path}: not written, the mesh has no faces")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{path}: not written, faces refer to vertices that do not exist")

    input_path = Path(input_path) if input_path is not None else None
    if input_path is not None and same_file(path, input_path) and not overwrite:
        raise MeshError(f"{path}: this is the input mesh; choose another output name or pass --overwrite")
    if path.exists() and not overwrite:
        raise MeshError(f"{path}: already exists; choose another output name or pass --overwrite")
    if path.is_dir():
        raise MeshError(f"{path}: is a folder; give an output file name")

    result = SaveResult(path=path, format=extension.lstrip("."))
    carry = _can_carry(source, vertices, faces, result)

    if extension == ".obj" and carry and input_path is not None and input_path.suffix.lower() == ".obj" and input_path.is_file():
        text = _rewrite_obj(input_path, source, vertices, result)
        if text is not None:
            atomic_write(path, text)
            _bring_materials(input_path, path, text, overwrite, result)
            _report(result)
            return result

    mesh = _output_trimesh(vertices, faces, source if carry else None)
    if extension == ".obj":
        _save_obj_with_trimesh(path, mesh, carry, overwrite, result)
    elif extension == ".ply":
        from trimesh.exchange.ply import export_ply

        data = export_ply(mesh, encoding="binary", vertex_normal=True)
        atomic_write(path, data)
        result.carried.append("normals recomputed")
        if carry and _has_uv(mesh):
            result.carried.append("UVs")
    elif extension == ".glb":
        from trimesh.exchange.gltf import export_glb

        data = export_glb(mesh.scene(), include_normals=True)
        atomic_write(path, data)
        result.carried.append("normals recomputed")
        if carry and _has_uv(mesh):
            result.carried.append("UVs")
        if carry and getattr(mesh.visual, "material", None) is not None:
            result.carried.append("material (embedded)")
    elif extension == ".stl":
        from trimesh.exchange.stl import export_stl

        atomic_write(path, export_stl(mesh))
        if source is not None and _has_uv(source):
            result.notes.append("STL holds geometry only: UVs and materials are not in the output")
    else:  # .off
        from trimesh.exchange.off import export_off

        atomic_write(path, export_off(mesh))
        if source is not None and _has_uv(source):
            result.notes.append("OFF holds geometry only: UVs and materials are not in the output")
    _report(result)
    return result


def _report(result: SaveResult) -> None:
    for note in result.notes:
        log.warning("%s: %s", result.path.name, note)


def _has_uv(mesh: Any) -> bool:
    uv = getattr(getattr(mesh, "visual", None), "uv", None)
    return uv is not None and len(uv) == len(mesh.vertices)


def _can_carry(source: Any, vertices: np.ndarray, faces: np.ndarray, result: SaveResult) -> bool:
    """Whether the output has the source's layout, so its UVs/material still fit."""
    if source is None:
        return False
    source_faces = np.asarray(source.faces)
    if len(source.vertices) == len(vertices) and source_faces.shape == faces.shape and np.array_equal(source_faces, faces):
        return True
    if _has_uv(source) or getattr(source.visual, "material", None) is not None:
        result.notes.append(
            f"output layout ({len(vertices)} vertices, {len(faces)} faces) differs from the input's "
            f"({len(source.vertices)} vertices, {len(source_faces)} faces): UVs and materials are not carried over; "
            "pass positions for the input's vertices (PreparedMesh.source_positions) to keep them"
        )
    return False


def _output_trimesh(vertices: np.ndarray, faces: np.ndarray, source: Any):
    import trimesh

    visual = None
    if source is not None and source.visual is not None:
        visual = source.visual.copy()
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, visual=visual, process=False, validate=False)
    # Normals for the new shape, never the input's (the shape changed).
    mesh.vertex_normals = vertex_normals(vertices, faces)
    return mesh


def _save_obj_with_trimesh(path: Path, mesh: Any, carry: bool, overwrite: bool, result: SaveResult) -> None:
    from trimesh.exchange.obj import export_obj

    if carry and _has_uv(mesh):
        mtl_name = f"{path.stem}.mtl"
        text, files = export_obj(
            mesh, include_normals=True, include_texture=True, return_texture=True, mtl_name=mtl_name
        )
        for name, data in files.items():
            target = path.parent / name
            if target.exists() and not overwrite:
                result.notes.append(f"kept the existing {name} beside the output (not overwritten)")
                continue
            atomic_write(target, data)
            result.extra_files.append(target)
        atomic_write(path, text)
        result.carried += ["UVs", f"material (mtllib {mtl_name})", "normals recomputed"]
    else:
        atomic_write(path, export_obj(mesh, include_normals=True, include_texture=False))
        result.carried.append("normals recomputed")


# --------------------------------------------------------------------------------------------
# OBJ → OBJ: rewrite the input's own text


def _rewrite_obj(input_path: Path, source: Any, vertices: np.ndarray, result: SaveResult) -> str | None:
    """The input OBJ's text with new ``v`` positions and recomputed ``vn``; None if it can't map.

    Input ``v`` lines are matched to the source's vertices by their exact parsed coordinates
    (trimesh splits vertices at UV seams, so several source vertices may share one ``v`` line).
    ``f`` lines are kept verbatim, so the output loads back with the source's exact layout, and
    every ``vn`` line is replaced in place by the normal of the new shape over the face corners
    that use it (area-weighted): smooth stays smooth and hard edges stay hard. An input without
    normals gets none (Blender then computes them from the shape).
    """
    try:
        lines = input_path.read_text(encoding="utf-8", errors="surrogateescape").splitlines()
    except OSError as error:
        result.notes.append(f"could not re-read the input {input_path.name} ({error}); wrote a plain OBJ")
        return None

    file_positions: list[tuple[float, float, float]] = []
    for number, line in enumerate(lines):
        if _keyword(line) == "v":
            parts = line.split()
            try:
                file_positions.append((float(parts[1]), float(parts[2]), float(parts[3])))
            except (IndexError, ValueError):
                result.notes.append(f"{input_path.name}:{number + 1}: unreadable vertex line; wrote a plain OBJ")
                return None
    if not file_positions:
        return None

    # source vertex -> file vertex (first with the same coordinates)
    first_index: dict[tuple[float, float, float], int] = {}
    for index, position in enumerate(file_positions):
        first_index.setdefault(position, index)
    source_vertices = np.asarray(source.vertices, dtype=np.float64)
    source_to_file = np.empty(len(source_vertices), dtype=np.int64)
    for index, position in enumerate(map(tuple, source_vertices.tolist())):
        found = first_index.get(position)
        if found is None:
            result.notes.append(
                f"{input_path.name}: vertices do not match the loaded mesh; wrote a plain OBJ "
                "(UVs kept, material groups merged)"
            )
            return None
        source_to_file[index] = found

    # New position of each file vertex: the mean over the source vertices that came from it
    # (they are equal after preparation merged seam vertices). Unused lines keep their place.
    key_of_file = np.array([first_index[p] for p in file_positions], dtype=np.int64)
    total = np.zeros((len(file_positions), 3))
    count = np.zeros(len(file_positions))
    np.add.at(total, source_to_file, vertices)
    np.add.at(count, source_to_file, 1)
    mean = total / np.maximum(count, 1)[:, None]
    new_positions = np.asarray(file_positions, dtype=np.float64)
    used = count[key_of_file] > 0
    new_positions[used] = mean[key_of_file[used]]
    spread = np.linalg.norm(vertices - mean[source_to_file], axis=1)
    if spread.max() > 1e-9 * max(1.0, float(np.abs(vertices).max())):
        result.notes.append("input vertices that share a position were moved apart; wrote their mean position")

    normals, keep = _obj_normals(lines, new_positions)
    if normals is None:
        result.notes.append(f"{input_path.name}: unreadable face line; wrote a plain OBJ")
        return None

    out: list[str] = [f"# written by allorules from {input_path.name}: positions scaled, normals recomputed"]
    vertex_count = normal_count = 0
    had_uv = False
    for line in lines:
        keyword = _keyword(line)
        if keyword == "v":
            parts = line.split()
            x, y, z = new_positions[vertex_count]
            vertex_count += 1
            out.append(" ".join(["v", _number(x), _number(y), _number(z), *parts[4:]]))
        elif keyword == "vn":
            if keep[normal_count]:
                out.append(line)  # no face uses it, or its faces cancel: leave it as it was
            else:
                a, b, c = normals[normal_count]
                out.append(f"vn {_number(a)} {_number(b)} {_number(c)}")
            normal_count += 1
        else:
            had_uv = had_uv or keyword == "vt"
            out.append(line)
    if normal_count:
        result.carried.append("normals recomputed (hard and smooth edges as in the input)")
    else:
        result.notes.append("the input OBJ has no normals; none written (Blender computes them from the shape)")
    if had_uv:
        result.carried.append("UVs")
    result.carried.append("OBJ groups, smoothing and usemtl kept")
    return "\n".join(out) + "\n"


def _keyword(line: str) -> str:
    stripped = line.lstrip()
    end = 0
    while end < len(stripped) and not stripped[end].isspace():
        end += 1
    return stripped[:end]


def _obj_normals(lines: list[str], positions: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """Recomputed ``vn`` values: n_k ∝ Σ over face corners using normal k of the face's
    (fan-triangulated) area vector. Returns (normals, keep) where ``keep`` marks normals no face
    determines (unused, or faces that cancel out) — those stay as in the input."""
    triangles: list[tuple[int, int, int]] = []
    corner_normals: list[tuple[int, int, int]] = []
    vertex_count = normal_count = 0
    for line in lines:
        keyword = _keyword(line)
        if keyword == "v":
            vertex_count += 1
        elif keyword == "vn":
            normal_count += 1
        elif keyword == "f":
            corners = []
            try:
                for token in line.split()[1:]:
                    pieces = token.split("/")
                    vertex = int(pieces[0])
                    vertex = vertex - 1 if vertex > 0 else vertex_count + vertex
                    normal = -1
                    if len(pieces) > 2 and pieces[2]:
                        normal = int(pieces[2])
                        normal = normal - 1 if normal > 0 else normal_count + normal
                    corners.append((vertex, normal))
            except ValueError:
                return None, np.zeros(0, dtype=bool)
            for k in range(1, len(corners) - 1):  # fan triangulation
                triangle = (corners[0], corners[k], corners[k + 1])
                triangles.append(tuple(corner[0] for corner in triangle))
                corner_normals.append(tuple(corner[1] for corner in triangle))
    normals = np.zeros((normal_count, 3))
    if normal_count == 0 or not triangles:
        return normals, np.ones(normal_count, dtype=bool)
    triangles_array = np.asarray(triangles, dtype=np.int64)
    if triangles_array.min() < 0 or triangles_array.max() >= len(positions):
        return None, np.zeros(0, dtype=bool)
    area_vector = face_normals(positions, triangles_array)
    normal_index = np.asarray(corner_normals, dtype=np.int64)
    magnitude = np.zeros(normal_count)
    for k in range(3):
        valid = (normal_index[:, k] >= 0) & (normal_index[:, k] < normal_count)
        np.add.at(normals, normal_index[valid, k], area_vector[valid])
        np.add.at(magnitude, normal_index[valid, k], np.linalg.norm(area_vector[valid], axis=1))
    length = np.linalg.norm(normals, axis=1)
    determined = length > 1e-6 * np.maximum(magnitude, 1e-300)
    normals[determined] /= length[determined, None]
    return normals, ~determined


def _number(value: float) -> str:
    return f"{value:.9g}"




def _bring_materials(input_path: Path, output_path: Path, text: str, overwrite: bool, result: SaveResult) -> None:
    """Make the output's ``mtllib`` resolve as the input's did; say so when it cannot."""
    libraries = [match.group(1) for match in map(MTLLIB.match, text.splitlines()) if match]
    input_folder, output_folder = input_path.parent.resolve(), output_path.parent.resolve()
    for library in libraries:
        source_library = input_folder / library
        target_library = output_folder / library
        if not source_library.is_file():
            result.notes.append(
                f"the input refers to material library {library!r}, which is missing beside it "
                f"({input_folder}); the output refers to it too, put it next to the output to see the materials"
            )
            continue
        result.carried.append(f"materials (mtllib {library})")
        if input_folder == output_folder:
            continue
        if not target_library.exists():
            _copy_atomic(source_library, target_library)
            result.extra_files.append(target_library)
        # Textures are referenced; copy only the ones the output's folder would miss.
        for line in source_library.read_text(encoding="utf-8", errors="replace").splitlines():
            match = TEXTURE_MAP.match(line)
            if not match:
                continue
            texture = texture_name(match)
            if Path(texture).is_absolute() or (output_folder / texture).exists():
                continue
            original = (input_folder / texture)
            if original.is_file():
                _copy_atomic(original, output_folder / texture)
                result.extra_files.append(output_folder / texture)
            else:
                result.notes.append(f"texture {texture!r} named in {library} is missing beside the input")


def _copy_atomic(source: Path, target: Path) -> None:
    with atomic_path(target) as temporary:
        shutil.copyfile(source, temporary)
