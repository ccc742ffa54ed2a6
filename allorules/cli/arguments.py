"""Options shared by several commands: ``--plugin PATH``, the ``--up``/``--forward`` directions,
``--relabel``, ``--working-vertices N`` and ``--png`` (with ``--plot``, its old spelling on ``spectrum``).
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger("allorules")


def add_plugin_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--plugin PATH`` (repeatable) to a command's parser."""
    parser.add_argument(
        "--plugin", dest="plugins", action="append", default=[], metavar="PATH", type=Path,
        help="load a plugin from a .py file or a package folder (repeatable); "
             "installed plugins (entry-point group 'allorules') are always loaded",
    )


def plugin_files(registry, arguments: argparse.Namespace) -> list:
    """The plugin files a command loaded by path (``--plugin``, a ruleset's ``plugins:``), and the
    paths as given: inputs of the command, protected from its outputs."""
    files = list(getattr(arguments, "plugins", None) or [])
    if registry is not None:
        from allorules.plugins.registry import ORIGIN_PATH

        files += [location for origin, location in registry.origins.values() if origin == ORIGIN_PATH and location]
    return files


_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def parse_direction(text: str):
    """A direction from the command line: ``+y``, ``-z``, ``x`` or three numbers ``0,1,0``."""
    import numpy as np

    cleaned = text.strip().lower()
    sign = -1.0 if cleaned.startswith("-") else 1.0
    name = cleaned.lstrip("+-")
    if name in _AXES:
        return sign * np.array(_AXES[name])
    try:
        values = np.array([float(part) for part in cleaned.replace(" ", ",").split(",") if part], dtype=float)
    except ValueError:
        values = np.zeros(0)
    if values.shape != (3,) or not np.isfinite(values).all() or np.linalg.norm(values) == 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a direction; write +y, -z or three numbers like 0,1,0")
    return values / np.linalg.norm(values)


def add_direction_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--up", type=parse_direction, metavar="DIR",
                        help="the body's up direction (feet to back), e.g. +y or 0,0,1; detected when not given")
    parser.add_argument("--forward", type=parse_direction, metavar="DIR",
                        help="the body's forward direction (tail to head), e.g. +x; detected when not given")


def add_relabel_argument(parser: argparse.ArgumentParser) -> None:
    """``--relabel``: ignore the mesh's own labels file (NAME.labels.json beside NAME.EXT)."""
    parser.add_argument("--relabel", action="store_true",
                        help="label the mesh afresh even where its own labels file sits beside it (NAME.labels.json, "
                        "which allorules scale writes beside its output and which is read, when it fits the mesh, "
                        "unless --segmentation is given; docs/segmentation.md)")


def labels_beside_input(arguments: argparse.Namespace) -> str | None:
    """The input mesh's own labels file the command will read (an input, protected from its
    outputs), or None (none there, --segmentation given, or --relabel)."""
    from allorules.segment.labels_io import labels_file_beside

    if getattr(arguments, "segmentation", None) or getattr(arguments, "relabel", False):
        return None
    beside = labels_file_beside(arguments.mesh)
    return str(beside) if beside.is_file() else None


def add_working_vertices_argument(parser: argparse.ArgumentParser) -> None:
    # the numbers are allorules.mesh.working's (not imported here, so that --help stays quick;
    # tests/test_working_mesh.py checks they agree)
    parser.add_argument("--working-vertices", type=int, metavar="N",
                        help="size of the working mesh the regions, the basis, the measures and the solve use "
                        "(default 8000, from 2000 to 100000); a mesh at or below it is used as it is, a larger one is "
                        "remeshed and the result carried back to every one of its vertices (docs/working-mesh.md)")


def add_png_argument(parser: argparse.ArgumentParser, what: str, *, old_spelling: str | None = None) -> None:
    """``--png FILE.png``, the one spelling of every command's picture; ``old_spelling`` (e.g.
    ``--plot``) still works, with a note that it is deprecated."""
    parser.add_argument("--png", metavar="FILE.png", help=f"write a picture: {what}")
    if old_spelling:
        parser.add_argument(old_spelling, dest="png_old_spelling", metavar="FILE.png", help=argparse.SUPPRESS)


def png_path(arguments: argparse.Namespace, old_spelling: str = "--plot") -> tuple[str | None, str]:
    """The picture the command line asks for and the option it was given with: ``--png``, or its
    old spelling (with a deprecation note)."""
    old = getattr(arguments, "png_old_spelling", None)
    if old and not arguments.png:
        log.warning("note: %s is deprecated, write --png %s (the same picture)", old_spelling, old)
        return old, old_spelling
    if old and arguments.png:
        from allorules.errors import AllorulesError

        raise AllorulesError(f"{old_spelling} is the old spelling of --png; give --png only")
    return arguments.png, "--png"
