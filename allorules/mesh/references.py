"""The files a mesh file refers to: an OBJ's material libraries and the textures they name, a
glTF's external buffers and images.

A job sent to another machine (:mod:`allorules.runs.cluster`) carries them with the mesh so that
the output keeps its materials there as it does here; :mod:`allorules.output.export` reads the
same lines when it brings the materials beside an output.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

MTLLIB = re.compile(r"^\s*mtllib\s+(.+?)\s*$")
TEXTURE_MAP = re.compile(r"^\s*(map_\w+|bump|disp|decal|refl|norm)\s+(.+?)\s*$", re.IGNORECASE)


def texture_name(line_match: re.Match) -> str:
    """The file of a texture line (its last word: options such as ``-bm 0.5`` come first)."""
    return line_match.group(2).split()[-1]


def referenced_files(mesh: str | Path) -> list[str]:
    """Paths (relative to the mesh's folder, as written in the file) of the existing files the mesh
    refers to, in or below its folder; absolute paths and files elsewhere are left out."""
    mesh = Path(mesh)
    folder = mesh.parent.resolve()
    found: list[str] = []

    def add(name: str) -> Path | None:
        if not name or Path(name).is_absolute():
            return None
        target = (folder / name).resolve()
        if not target.is_file() or not target.is_relative_to(folder):
            return None
        relative = target.relative_to(folder).as_posix()
        if relative not in found:
            found.append(relative)
        return target

    suffix = mesh.suffix.lower()
    if suffix == ".obj":
        for match in map(MTLLIB.match, _lines(mesh)):
            library = add(match.group(1)) if match else None
            if library is None:
                continue
            for line in _lines(library):
                texture = TEXTURE_MAP.match(line)
                if texture:
                    add(texture_name(texture))
    elif suffix == ".gltf":
        try:
            document = json.loads(mesh.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return found
        for key in ("buffers", "images"):
            for entry in document.get(key) or []:
                uri = entry.get("uri") if isinstance(entry, dict) else None
                if isinstance(uri, str) and not uri.startswith("data:"):
                    from urllib.parse import unquote

                    add(unquote(uri))
    return found


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return []
