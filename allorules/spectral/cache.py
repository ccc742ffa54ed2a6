"""On-disk cache of harmonic bases.

A basis is stored as ``<key>.npz`` in the cache directory: ``$ALLORULES_CACHE_DIR`` if set,
else ``$XDG_CACHE_HOME/allorules/bases``, else ``~/.cache/allorules/bases``. The key is a hash
of the exact vertex and face arrays, the number of modes and :data:`SOLVER_VERSION`, so a
changed mesh or solver never hits an old entry.

**Verified on load.** Every file carries a checksum of its arrays; a file that does not load
(truncated, a folder, not ours), does not match its key or checksum, has the wrong shapes,
values that are not finite, or a mass that is not positive everywhere, is never trusted: the
basis is recomputed, with a notice, and the entry deleted when the cache can be written to (a
read-only cache is only read).

**Bounded.** The cache holds at most :data:`DEFAULT_LIMIT` bytes (``ALLORULES_CACHE_MAX``, e.g.
``500M``, ``10G``, ``0`` for no limit); after each new entry the least recently used entries
are removed until it fits. Writes are atomic (temporary file, then rename); a temporary file
left by a killed write is removed once it is an hour old (a younger one may be another
process writing). ``allorules cache`` shows where the cache is and how big; ``allorules cache
clear`` empties it.
"""
from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SOLVER_VERSION = "1"
DEFAULT_LIMIT = 2 * 1024**3          # 2 GiB
TEMPORARY_SUFFIX = ".npz.tmp"
STALE_TEMPORARY_SECONDS = 3600.0

log = logging.getLogger("allorules")
_warned: set[str] = set()


def cache_directory() -> Path | None:
    """Where bases are cached, or ``None`` when caching is switched off (ALLORULES_CACHE_DIR=off)."""
    configured = os.environ.get("ALLORULES_CACHE_DIR")
    if configured is not None:
        if configured.strip().lower() in {"", "0", "off", "none", "false"}:
            return None
        return Path(configured).expanduser()
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(root) / "allorules" / "bases"


_SIZE = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*([kmgt]?)i?b?\s*$", re.IGNORECASE)


def size_limit() -> int | None:
    """The most bytes the cache holds (``ALLORULES_CACHE_MAX``: bytes, or ``500M``, ``2G``; ``0``
    for no limit); :data:`DEFAULT_LIMIT` when unset or unreadable (with a notice)."""
    text = os.environ.get("ALLORULES_CACHE_MAX")
    if text is None or not text.strip():
        return DEFAULT_LIMIT
    match = _SIZE.match(text)
    if not match:
        _notice_once(f"limit:{text}", f"ALLORULES_CACHE_MAX={text!r} is not a size (write e.g. 500M or 2G); "
                     f"the basis cache keeps its default limit of {DEFAULT_LIMIT / 1024**3:g} GB")
        return DEFAULT_LIMIT
    value = float(match.group(1)) * 1024 ** " kmgt".index((match.group(2) or " ").lower())
    return None if value == 0 else int(value)


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


def _notice_once(what: str, message: str) -> None:
    if what not in _warned:
        _warned.add(what)
        log.warning("note: %s", message)


def _problem(stored, key: str, vertex_count: int, modes: int) -> str | None:
    """What makes a stored entry untrustworthy, or None."""
    if str(stored["key"]) != key:
        return "it belongs to another mesh"
    eigenvalues, vectors, mass = stored["eigenvalues"], stored["vectors"], stored["mass"]
    if eigenvalues.shape != (modes,) or vectors.shape != (vertex_count, modes) or mass.shape != (vertex_count,):
        return "its arrays have the wrong shapes"
    if str(stored["checksum"]) != _checksum(eigenvalues, vectors, mass):
        return "its checksum does not match (a damaged file)"
    if not (np.isfinite(eigenvalues).all() and np.isfinite(vectors).all() and np.isfinite(mass).all()):
        return "it holds values that are not finite (NaN or infinite)"
    if not (mass > 0).all():
        return "its mass is not positive everywhere"
    return None


def load(key: str, vertex_count: int, modes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The cached (eigenvalues, vectors, mass) for ``key``, or ``None`` if absent or not trustworthy
    (then the entry is removed when the cache can be written to, and a notice says so)."""
    directory = cache_directory()
    if directory is None:
        return None
    path = directory / f"{key}.npz"
    try:
        if not path.exists() and not path.is_symlink():
            return None
    except OSError:
        return None
    problem = None
    try:
        if path.is_dir():
            problem = "it is a folder, not a file"
        else:
            with np.load(path, allow_pickle=False) as stored:
                problem = _problem(stored, key, vertex_count, modes)
                if problem is None:
                    result = (np.array(stored["eigenvalues"]), np.array(stored["vectors"]), np.array(stored["mass"]))
    except Exception as error:  # a truncated, unreadable or foreign file: not ours to trust
        problem = f"it cannot be read ({type(error).__name__})"
    if problem is not None:
        _discard(path, problem)
        return None
    with contextlib.suppress(OSError):
        os.utime(path)   # recently used: evicted last
    return result


def _discard(path: Path, problem: str) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            path.rmdir()   # only an empty folder; anything else in it is not ours to delete
        else:
            path.unlink()
        what = "removed it"
    except OSError as error:
        what = f"could not remove it: {error.strerror or error}"
    log.warning("note: the cached harmonic basis %s is not used: %s; recomputing the basis (%s)",
                path.name[:12] + "…", problem, what)


def store(key: str, eigenvalues: np.ndarray, vectors: np.ndarray, mass: np.ndarray) -> Path | None:
    """Write a basis atomically, then keep the cache under its size limit; caching failures
    (read-only disk, full disk, ...) are not fatal: a notice, once."""
    directory = cache_directory()
    if directory is None:
        return None
    temporary = None
    try:
        directory.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=directory, prefix=".partial-", suffix=TEMPORARY_SUFFIX)
        with os.fdopen(handle, "wb") as stream:
            np.savez(stream, key=key, checksum=_checksum(eigenvalues, vectors, mass),
                     eigenvalues=eigenvalues, vectors=vectors, mass=mass)
        path = directory / f"{key}.npz"
        os.replace(temporary, path)
        temporary = None
    except OSError as error:
        _notice_once(f"store:{directory}", f"the harmonic basis is not cached: cannot write into {directory} "
                     f"({error.strerror or error})")
        return None
    finally:
        if temporary is not None:   # failed or interrupted: leave nothing behind
            with contextlib.suppress(OSError):
                os.unlink(temporary)
    _keep_within_limit(directory, keep=path)
    return path


# ---------------------------------------------------------------------------------------------
# Size, eviction, clearing


@dataclass(frozen=True)
class CacheInfo:
    """What ``allorules cache`` shows."""

    directory: Path | None
    entries: int = 0
    bytes: int = 0
    temporaries: int = 0          # leftovers of interrupted writes (and writes in progress)
    limit: int | None = DEFAULT_LIMIT


def _entries(directory: Path) -> list[tuple[Path, os.stat_result]]:
    found = []
    try:
        listing = list(os.scandir(directory))
    except OSError:
        return []
    for item in listing:
        if item.name.endswith(".npz") and not item.name.startswith("."):
            with contextlib.suppress(OSError):
                if item.is_file(follow_symlinks=False):
                    found.append((Path(item.path), item.stat(follow_symlinks=False)))
    return found


def _temporaries(directory: Path) -> list[Path]:
    try:
        return [Path(item.path) for item in os.scandir(directory) if item.name.endswith(TEMPORARY_SUFFIX)]
    except OSError:
        return []


def remove_stale_temporaries(directory: Path, older_than: float = STALE_TEMPORARY_SECONDS) -> int:
    """Remove temporary files of writes that were killed (older than ``older_than`` seconds)."""
    removed = 0
    now = time.time()
    for path in _temporaries(directory):
        with contextlib.suppress(OSError):
            if now - path.stat().st_mtime >= older_than:
                path.unlink()
                removed += 1
    return removed


def _keep_within_limit(directory: Path, keep: Path | None = None) -> None:
    remove_stale_temporaries(directory)
    limit = size_limit()
    if limit is None:
        return
    entries = sorted(_entries(directory), key=lambda entry: entry[1].st_mtime)   # least recently used first
    total = sum(status.st_size for _, status in entries)
    for path, status in entries:
        if total <= limit:
            break
        if keep is not None and path == keep:
            continue
        with contextlib.suppress(OSError):
            path.unlink()
            total -= status.st_size
            log.debug("basis cache: removed %s (least recently used) to stay under %d MB", path.name, limit // 1024**2)


def cache_info() -> CacheInfo:
    """Where the cache is, how many entries and bytes it holds, and its limit."""
    directory = cache_directory()
    if directory is None:
        return CacheInfo(None, limit=size_limit())
    entries = _entries(directory)
    return CacheInfo(directory, len(entries), sum(status.st_size for _, status in entries),
                     len(_temporaries(directory)), size_limit())


def clear_cache() -> tuple[int, int]:
    """Remove every entry and temporary file; returns (files removed, bytes freed)."""
    directory = cache_directory()
    if directory is None:
        return 0, 0
    removed, freed = 0, 0
    for path, status in _entries(directory):
        with contextlib.suppress(OSError):
            path.unlink()
            removed, freed = removed + 1, freed + status.st_size
    removed += remove_stale_temporaries(directory, older_than=0.0)
    return removed, freed
