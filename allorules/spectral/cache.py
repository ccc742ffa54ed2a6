"""On-disk cache of harmonic bases.

A basis is stored as ``<key>.npz`` in the cache directory: ``$ALLORULES_CACHE_DIR`` if set,
else ``$XDG_CACHE_HOME/allorules/bases``, else ``~/.cache/allorules/bases``. The key is a hash
of the exact vertex and face arrays, the number of modes and :data:`SOLVER_VERSION`, so a
changed mesh or solver never hits an old entry. Every file carries a checksum of its arrays;
a file that does not load, does not match its key or checksum, or has the wrong shapes is
deleted and recomputed, never trusted. Writes are atomic (temporary file, then rename).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

SOLVER_VERSION = "1"


def cache_directory() -> Path | None:
    """Where bases are cached, or ``None`` when caching is switched off (ALLORULES_CACHE_DIR=off)."""
    configured = os.environ.get("ALLORULES_CACHE_DIR")
    if configured is not None:
        if configured.strip().lower() in {"", "0", "off", "none", "false"}:
            return None
        return Path(configured).expanduser()
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "allorules" / "bases"


def basis_key(vertices: np.ndarray, faces: np.ndarray, modes: int) -> str:
    digest = hashlib.sha256()
    digest.update(f"allorules-basis v{SOLVER_VERSION} modes={modes} n={len(vertices)} f={len(faces)}|".encode())
    digest.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return digest.hexdigest()


def _checksum(*arrays: np.ndarray) -> str:
    digest = hashlib.sha256()
    for array in arrays:
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


def load(key: str, vertex_count: int, modes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The cached (eigenvalues, vectors, mass) for ``key``, or ``None`` if absent or not trustworthy."""
    directory = cache_directory()
    if directory is None:
        return None
    path = directory / f"{key}.npz"
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as stored:
            eigenvalues, vectors, mass = stored["eigenvalues"], stored["vectors"], stored["mass"]
            valid = (
                str(stored["key"]) == key
                and str(stored["checksum"]) == _checksum(eigenvalues, vectors, mass)
                and eigenvalues.shape == (modes,)
                and vectors.shape == (vertex_count, modes)
                and mass.shape == (vertex_count,)
                and np.all(np.isfinite(vectors))
            )
    except Exception:  # a truncated or foreign file: not ours to trust
        valid = False
    if not valid:
        path.unlink(missing_ok=True)
        return None
    return eigenvalues, vectors, mass


def store(key: str, eigenvalues: np.ndarray, vectors: np.ndarray, mass: np.ndarray) -> Path | None:
    """Write a basis atomically; caching failures (read-only disk, ...) are not fatal."""
    directory = cache_directory()
    if directory is None:
        return None
    try:
        directory.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=directory, suffix=".npz.tmp")
        with os.fdopen(handle, "wb") as stream:
            np.savez(stream, key=key, checksum=_checksum(eigenvalues, vectors, mass),
                     eigenvalues=eigenvalues, vectors=vectors, mass=mass)
        path = directory / f"{key}.npz"
        os.replace(temporary, path)
        return path
    except OSError:
        return None
