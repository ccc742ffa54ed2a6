"""Files written safely: atomic writes (temporary file in the destination folder, then
``os.replace``), JSON reports that never hold a bare NaN, and free output names beside an input.

Shared by every stage that writes (labels files, meshes, pictures, reports, batch summaries).
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; on success move it onto ``path``.

    On any exception the temporary file is removed and ``path`` is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(handle)
    temporary = Path(temporary)
    try:
        yield temporary
        # mkstemp creates owner-only files; outputs get the permissions any new file would get.
        os.chmod(temporary, 0o666 & ~_current_umask())
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: str | Path, write: Callable[[Any], None] | bytes | str) -> None:
    """Write ``path`` atomically: ``write`` is bytes/str, or a function given a binary file."""
    with atomic_path(path) as temporary:
        with open(temporary, "wb") as stream:
            if callable(write):
                write(stream)
            else:
                stream.write(write.encode("utf-8") if isinstance(write, str) else write)
            stream.flush()
            os.fsync(stream.fileno())


def jsonable(value: Any) -> Any:
    """A JSON-safe copy: numpy scalars and arrays to Python, paths to text, NaN/inf to None."""
    if isinstance(value, dict):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(item) for item in value]
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_json(path: str | Path, document: Any) -> None:
    """Write a report atomically as indented JSON; a report never holds a bare NaN."""
    atomic_write(path, json.dumps(jsonable(document), indent=2, allow_nan=False) + "\n")


def _same_file(first: Path, second: Path) -> bool:
    if first.resolve() == second.resolve():
        return True
    try:
        return first.exists() and second.exists() and os.path.samefile(first, second)
    except OSError:
        return False


def default_output_path(input_path: str | Path, *, suffix: str = "_scaled", extension: str | None = None) -> Path:
    """A name beside the input that does not exist yet: ``horse.obj`` → ``horse_scaled.obj``,
    then ``horse_scaled-2.obj``, ``horse_scaled-3.obj``, …"""
    input_path = Path(input_path)
    extension = extension or input_path.suffix
    candidate = input_path.with_name(f"{input_path.stem}{suffix}{extension}")
    number = 2
    while candidate.exists() or _same_file(candidate, input_path):
        candidate = input_path.with_name(f"{input_path.stem}{suffix}-{number}{extension}")
        number += 1
    return candidate
