"""Reading mesh files: any format trimesh reads, every failure one clear line (METHOD §1).
"""
from __future__ import annotations

from pathlib import Path

from allorules.errors import MeshError

SUPPORTED_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


def load_mesh(path: str | Path):
    """Read a triangle mesh with trimesh; every failure becomes a one-line :class:`MeshError`."""
    import trimesh

    path = Path(path)
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    if path.is_dir():
        raise MeshError(f"{path}: is a folder, give a mesh file ({', '.join(SUPPORTED_SUFFIXES)})")
    if path.suffix.lower() not in SUPPORTED_SUFFIXES:
        raise MeshError(
            f"{path}: unsupported format {path.suffix or '(no extension)'}; "
            f"use one of {', '.join(SUPPORTED_SUFFIXES)}"
        )
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as error:  # trimesh raises many types for unreadable files
        raise MeshError(f"{path}: cannot read it as {path.suffix} ({type(error).__name__}: {error})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{path}: holds no triangle mesh (only points, lines or an empty scene)")
    return loaded
