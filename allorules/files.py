"""Files written safely: every output path checked before any work, the inputs of a command
protected from its outputs, atomic writes (temporary file in the destination folder, then
``os.replace``), JSON reports that never hold a bare NaN, and free output names beside an input.

Shared by every stage that writes (labels files, meshes, pictures, reports, batch summaries).

**Inputs are never overwritten.** A command names its inputs (mesh, labels file, merge file,
ruleset, plugins, manifest) and its outputs to :func:`check_outputs` before it starts working:
an output that is an input (the same real path, or the same file through a hard link) is
refused, ``--force`` or not, and so is an output whose extension, folder or permissions would
only fail after the work. The inputs stay protected for the rest of the command
(:func:`protection_scope`): :func:`atomic_path`, through which every file is written, refuses
to replace one, whatever name a later stage derives.
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Union

from allorules.errors import OutputError

PathLike = Union[str, Path]


# ---------------------------------------------------------------------------------------------
# The inputs of the running command, protected from every write


_protected: dict[Any, str] = {}   # real path, or (device, inode), -> what the input is


def _identities(path: PathLike) -> list[Any]:
    """How a file is recognised: its real path (symbolic links followed) and, when it exists,
    its device and inode (a hard link or another spelling of the same file)."""
    found: list[Any] = [os.path.realpath(os.fspath(path))]
    with contextlib.suppress(OSError, ValueError):
        status = os.stat(path)
        found.append((status.st_dev, status.st_ino))
    return found


def _named(inputs: Mapping[str, PathLike | Iterable[PathLike] | None]) -> Iterator[tuple[str, Path]]:
    for what, value in inputs.items():
        if value is None or value == "":
            continue
        values = [value] if isinstance(value, (str, os.PathLike)) else list(value)
        for item in values:
            if item is not None and item != "":
                yield what, Path(item)


def protect(inputs: Mapping[str, PathLike | Iterable[PathLike] | None]) -> None:
    """Protect files from every write for the rest of the command: ``{"input mesh": path,
    "plugin": [paths], ...}`` (None values are skipped)."""
    for what, path in _named(inputs):
        for identity in _identities(path):
            _protected.setdefault(identity, f"{what} {path}")


def protected_as(path: PathLike) -> str | None:
    """What input ``path`` is (e.g. ``"input mesh horse.obj"``), or None when it is no input."""
    for identity in _identities(path):
        if identity in _protected:
            return _protected[identity]
    return None


@contextlib.contextmanager
def protection_scope() -> Iterator[None]:
    """Inputs protected inside the block are forgotten after it (one command of the CLI)."""
    saved = dict(_protected)
    try:
        yield
    finally:
        _protected.clear()
        _protected.update(saved)


# ---------------------------------------------------------------------------------------------
# Text files a user gives (rulesets, merge files, manifests): bounded

# A ruleset or merge file is a few kilobytes, a manifest of 10,000 meshes under 1 MB.
MAX_TEXT_BYTES = 2_000_000


def text_limit() -> int:
    """The largest YAML file read: :data:`MAX_TEXT_BYTES`, or ``ALLORULES_YAML_MAX_BYTES``."""
    text = os.environ.get("ALLORULES_YAML_MAX_BYTES")
    try:
        return max(1, int(text)) if text else MAX_TEXT_BYTES
    except ValueError:
        return MAX_TEXT_BYTES


def text_size_problem(size: int, kind: str) -> str | None:
    """Why a ``kind`` file of ``size`` bytes is not read (too large), or None."""
    largest = text_limit()
    if size <= largest:
        return None
    return (f"the {kind} is {size / 1e6:.1f} MB; allorules reads YAML files of at most {largest / 1e6:g} MB (a {kind} "
            "is usually a few kilobytes): is it the right file? (ALLORULES_YAML_MAX_BYTES raises the limit)")


# ---------------------------------------------------------------------------------------------
# Outputs checked before the work


@dataclass(frozen=True)
class Output:
    """One file (or folder) a command will write, as the user named it.

    ``option`` is how the user named it (``-o``, ``--png``, ``--report``), so a message points at
    it; ``extensions`` are the suffixes allowed (empty: any); ``folder`` marks a folder the command
    writes into (created when missing)."""

    path: Path
    option: str
    extensions: tuple[str, ...] = ()
    folder: bool = False

    @staticmethod
    def of(path: PathLike | None, option: str, extensions: Iterable[str] = (), *, folder: bool = False) -> "Output | None":
        if path is None or path == "":
            return None
        return Output(Path(path).expanduser(), option, tuple(e.lower() for e in extensions), folder)


PNG = (".png",)
JSON = (".json",)


def check_outputs(outputs: Iterable[Output | None], inputs: Mapping[str, PathLike | Iterable[PathLike] | None] = {},
                  *, force: bool = False, force_option: str = "--force") -> None:
    """Check every output a command will write, before it does any work, and protect its inputs.

    Refused with an :class:`OutputError` that names the option: an output that is one of the
    ``inputs`` (by real path or inode; ``force`` never applies to inputs), two outputs that are
    the same file, a wrong extension, a folder where a file is wanted (or a file where a folder
    is), an existing file without ``force``, a read-only file, and a folder that is missing or
    cannot be written to (tried by creating a file in it). ``force_option`` is how the caller's
    user says "replace" (``overwrite=True`` in the Python API).
    """
    protect(inputs)
    seen: dict[Any, Output] = {}
    for output in outputs:
        if output is None:
            continue
        _check_output(output, force, force_option)
        for identity in _identities(output.path)[:1]:
            if identity in seen:
                first = seen[identity]
                raise OutputError(f"{first.option} and {output.option} name the same file {output.path}; "
                                  "give each its own name")
            seen[identity] = output


def _check_output(output: Output, force: bool, force_option: str = "--force") -> None:
    path, option = output.path, output.option
    shown = f"{option} {path}"
    protected = protected_as(path)
    if protected is not None:
        raise OutputError(f"{shown}: that is the {protected}, an input of this command; an input is never "
                          f"overwritten (not even with {force_option}): choose another name")
    if output.extensions and not output.folder and path.suffix.lower() not in output.extensions:
        wanted = " or ".join(output.extensions)
        raise OutputError(f"{shown}: the name must end in {wanted}, not {path.suffix or '(no extension)'}; "
                          f"e.g. {path.with_suffix(output.extensions[0]).name}")
    if output.folder:
        if path.exists() and not path.is_dir():
            raise OutputError(f"{shown}: is a file; give a folder")
        _check_folder(path if path.exists() else _existing_ancestor(path), shown, creating=not path.exists())
        return
    if path.is_dir():
        raise OutputError(f"{shown}: is a folder; give a file name, e.g. {path / ('output' + (output.extensions or ('',))[0])}")
    if path.exists() or path.is_symlink():
        if not force:
            raise OutputError(f"{shown}: already exists; choose another name, or add {force_option} to replace it")
        if not os.access(path, os.W_OK, follow_symlinks=True) and path.exists():
            raise OutputError(f"{shown}: the file is read-only; make it writable or choose another name")
    folder = path.parent
    if not folder.exists():
        raise OutputError(f"{shown}: the folder {folder} does not exist; create it first (mkdir -p {folder})")
    if not folder.is_dir():
        raise OutputError(f"{shown}: {folder} is not a folder")
    _check_folder(folder, shown)


def _existing_ancestor(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _check_folder(folder: Path, shown: str, *, creating: bool = False) -> None:
    """A folder can be written to when a file can be made in it (permissions, read-only disks,
    quotas: only trying tells)."""
    if not folder.is_dir():
        raise OutputError(f"{shown}: {folder} is not a folder")
    try:
        handle, probe = tempfile.mkstemp(prefix=".allorules-probe-", dir=folder)
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        where = f"cannot create folders in {folder}" if creating else f"cannot write into the folder {folder}"
        raise OutputError(f"{shown}: {where} ({error.strerror or error}); choose a folder you can write to") from None


# ---------------------------------------------------------------------------------------------
# Atomic writes


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder; on success move it onto ``path``.

    On any exception the temporary file is removed and ``path`` is left untouched. A protected
    input (:func:`protect`) is never replaced: :class:`OutputError`. A failure of the file system
    (read-only folder, full disk) is an :class:`OutputError` too, one line, not a traceback.
    """
    path = Path(path)
    protected = protected_as(path)
    if protected is not None:
        raise OutputError(f"{path}: not written, it is the {protected}, an input of this command; choose "
                          "another output name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(handle)
    except OSError as error:
        raise _write_error(path, error) from None
    temporary = Path(temporary)
    try:
        yield temporary
        # mkstemp creates owner-only files; outputs get the permissions any new file would get.
        try:
            os.chmod(temporary, 0o666 & ~_current_umask())
            os.replace(temporary, path)
        except OSError as error:
            raise _write_error(path, error) from None
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def _write_error(path: Path, error: OSError) -> OutputError:
    return OutputError(f"cannot write {path}: {error.strerror or error}; choose a folder you can write to "
                       "(with free space)")


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
                try:
                    stream.write(write.encode("utf-8") if isinstance(write, str) else write)
                except OSError as error:   # a full disk
                    raise _write_error(Path(path), error) from None
            try:
                stream.flush()
                os.fsync(stream.fileno())
            except OSError as error:
                raise _write_error(Path(path), error) from None


def jsonable(value: Any) -> Any:
    """A JSON-safe copy: numpy scalars and arrays to Python, paths to text, NaN/inf to None."""
    import numpy as np

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


def same_file(first: Path, second: Path) -> bool:
    if first.resolve() == second.resolve():
        return True
    try:
        return first.exists() and second.exists() and os.path.samefile(first, second)
    except OSError:
        return False


def unconverged_path(path: str | Path) -> Path:
    """Where the mesh of a run that missed its targets goes instead of ``path``:
    ``big.obj`` → ``big.unconverged.obj`` (never under the name asked for)."""
    path = Path(path)
    return path.with_name(f"{path.stem}.unconverged{path.suffix}")


def default_output_path(input_path: str | Path, *, suffix: str = "_scaled", extension: str | None = None) -> Path:
    """A name beside the input that does not exist yet: ``horse.obj`` → ``horse_scaled.obj``,
    then ``horse_scaled-2.obj``, ``horse_scaled-3.obj``, …"""
    input_path = Path(input_path)
    extension = extension or input_path.suffix
    candidate = input_path.with_name(f"{input_path.stem}{suffix}{extension}")
    number = 2
    while candidate.exists() or same_file(candidate, input_path):
        candidate = input_path.with_name(f"{input_path.stem}{suffix}-{number}{extension}")
        number += 1
    return candidate
