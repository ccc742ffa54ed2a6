"""Reading mesh files: any format trimesh reads, every failure one clear line (METHOD §1).

trimesh reads the geometry; this module makes sure what it read is what the file says:

* text formats (OBJ, OFF) are decoded here, in UTF-8 or, failing that, as Latin-1/Windows-1252
  (only comments, names and material references can hold such bytes): trimesh would otherwise
  ask for a text-encoding detector it may not have, and say so instead of reading the file;
* a file that holds binary data where text belongs is refused as not an OBJ/OFF file;
* OBJ faces are checked before trimesh sees them: OBJ counts vertices from 1, so an index 0 is a
  file written by a program counting from 0 (trimesh would read it as "the last vertex" and give
  a wrong mesh without a word); an index past the vertices read is a damaged file;
* a file with vertices but no faces is a point cloud, not a surface, and says so.
"""
from __future__ import annotations

import io
import re
from pathlib import Path

from allorules.errors import MeshError

SUPPORTED_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
TEXT_SUFFIXES = (".obj", ".off")

# An OBJ face or line element ('f', 'l') and its vertex references 'v', 'v/vt', 'v//vn', 'v/vt/vn'.
_ELEMENT = re.compile(rb"^[ \t]*f[ \t]+([^\n#]*)", re.MULTILINE)
_VERTEX = re.compile(rb"^[ \t]*v[ \t]", re.MULTILINE)
# An index 0 in any position of a vertex reference ('0', '0/..', '../0', '../../0').
_ZERO = re.compile(rb"[ \t/][+]?0+(?=[ \t\r\n/#]|\Z)")


def load_mesh(path: str | Path):
    """Read a triangle mesh with trimesh; every failure becomes a one-line :class:`MeshError`."""
    import trimesh

    path = Path(path)
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    if path.is_dir():
        raise MeshError(f"{path}: is a folder, give a mesh file ({', '.join(SUPPORTED_SUFFIXES)})")
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise MeshError(
            f"{path}: unsupported format {path.suffix or '(no extension)'}; "
            f"use one of {', '.join(SUPPORTED_SUFFIXES)}"
        )
    try:
        raw = path.read_bytes()
    except OSError as error:
        raise MeshError(f"{path}: cannot read it ({error.strerror or error})") from None
    if not raw.strip():
        raise MeshError(f"{path}: the file is empty")
    try:
        if suffix in TEXT_SUFFIXES:
            text = _text(path, raw)
            if suffix == ".obj":
                _check_obj_faces(path, text)
            loaded = trimesh.load(io.BytesIO(text), file_type=suffix.lstrip("."), resolver=_resolver(path),
                                  force="mesh", process=False)
        else:
            loaded = trimesh.load(path, force="mesh", process=False)
    except MeshError:
        raise
    except IndexError as error:   # faces referring to vertices the file does not have
        problem = _missing_vertex(path, text) if suffix == ".obj" else None
        raise (problem or MeshError(f"{path}: faces refer to vertices the file does not have ({_reason(error)}); "
                                    "the file is damaged or cut short: export it again")) from None
    except Exception as error:  # trimesh raises many types for unreadable files
        raise MeshError(f"{path}: cannot read it as {suffix} ({_reason(error)}); check that the file is "
                        f"a complete {suffix.lstrip('.').upper()} file (export it again)") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{path}: holds no triangle mesh (only points, lines or an empty scene)")
    if len(loaded.faces) == 0:
        vertices = len(_VERTEX.findall(text)) if suffix == ".obj" else len(loaded.vertices)
        raise MeshError(f"{path}: holds {vertices} vertices but no faces (a point cloud, not a surface); "
                        "allorules needs a triangle mesh: export the surface with its faces")
    _check_coordinates(path, loaded.vertices)
    return loaded


# Areas and volumes are squares and cubes of lengths: beyond these sizes they overflow or vanish.
LARGEST_EXTENT, SMALLEST_EXTENT = 1e30, 1e-30


def _check_coordinates(path: Path, vertices) -> None:
    """Three coordinates per vertex, and a size whose areas and volumes are representable (NaN
    and infinite coordinates are left to preparation, which counts them)."""
    import numpy as np

    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        given = vertices.shape[1] if vertices.ndim == 2 else 1
        raise MeshError(f"{path}: its vertices have {given} coordinate{'s' * (given != 1)}, a 3-D mesh needs three "
                        "(x y z); the file is damaged or not a 3-D mesh")
    finite = vertices[np.isfinite(vertices).all(axis=1)]
    if len(finite) < 2:
        return
    with np.errstate(over="ignore", invalid="ignore"):
        extent = float(np.max(finite.max(axis=0) - finite.min(axis=0)))
    if not np.isfinite(extent) or extent > LARGEST_EXTENT or 0 < extent < SMALLEST_EXTENT:
        size = f"{extent:.3g} units across" if np.isfinite(extent) else \
            f"coordinates as large as {float(np.abs(finite).max()):.3g}"
        raise MeshError(f"{path}: the mesh has {size}; its areas and volumes cannot be computed at that size: "
                        "scale it to a usual unit (metres, centimetres) in your modelling tool")


def _reason(error: Exception) -> str:
    if isinstance(error, ModuleNotFoundError):   # trimesh wanting an optional reader for this data
        return "its contents are not in a form trimesh reads"
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0]}" if text else type(error).__name__


def _text(path: Path, raw: bytes) -> bytes:
    """The file as UTF-8 bytes: UTF-8 as it is, else read as Windows-1252/Latin-1 (every byte is a
    character); a file with NUL bytes or mostly non-text bytes is binary, not OBJ/OFF text."""
    sample = raw[:65536]
    control = sum(1 for byte in sample if byte < 32 and byte not in (9, 10, 12, 13))
    if b"\x00" in sample or control > len(sample) // 100:
        raise MeshError(f"{path}: holds binary data, not {path.suffix.lstrip('.').upper()} text; is it the right "
                        f"file? (export the mesh again as {path.suffix.lower()})")
    try:
        raw.decode("utf-8")
        return raw
    except UnicodeDecodeError:
        pass
    try:
        return raw.decode("cp1252").encode("utf-8")
    except UnicodeDecodeError:   # the five bytes cp1252 leaves undefined
        return raw.decode("latin-1").encode("utf-8")


def _resolver(path: Path):
    """trimesh's resolver for the files an OBJ names (material libraries, textures), with the
    material libraries decoded as :func:`_text` decodes the OBJ."""
    from trimesh.resolvers import FilePathResolver

    class TextResolver(FilePathResolver):
        def get(self, name: str) -> bytes:
            data = super().get(name)
            if str(name).lower().endswith(".mtl"):
                try:
                    data.decode("utf-8")
                except UnicodeDecodeError:
                    data = data.decode("latin-1").encode("utf-8")
            return data

    return TextResolver(path)


def _check_obj_faces(path: Path, text: bytes) -> None:
    """OBJ indices count from 1 (negative ones back from the last vertex read): refuse an index 0,
    which trimesh would read silently as a wrong mesh (one regular-expression pass over the faces,
    a tenth of trimesh's own reading time)."""
    start = max(text.find(b"f "), 0)
    for match in _ZERO.finditer(text, start):
        line = text[text.rfind(b"\n", 0, match.start()) + 1:match.start()].lstrip()
        if line[:1] == b"f" and line[1:2] in (b"", b" ", b"\t") and b"#" not in line:
            raise MeshError(f"{path}: a face refers to vertex index 0, but OBJ counts vertices from 1; the program "
                            "that wrote it counted from 0: export it again from a program that writes standard OBJ")


def _missing_vertex(path: Path, text: bytes) -> MeshError | None:
    """The error for faces referring to vertices the OBJ does not have (looked for only when
    trimesh failed to index them)."""
    vertex_count = len(_VERTEX.findall(text))
    joined = b" ".join(_ELEMENT.findall(text))
    references = [int(value) for value in re.findall(rb"(?:^|\s)([+-]?\d+)", joined)]
    bad = [index for index in references if index > vertex_count or -index > vertex_count]
    if not bad:
        return None
    return MeshError(f"{path}: a face refers to vertex {bad[0]}, but the file has {vertex_count} vertices; the file "
                     "is damaged or cut short: export it again")
