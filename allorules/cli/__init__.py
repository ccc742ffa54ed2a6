"""The ``allorules`` command line.

Each sub-command lives in its own module of this package and exposes
``register(subcommands)``, which adds an ``argparse`` parser whose default ``run`` is a function
``run(arguments) -> int``. :func:`main` wires them together and turns every
:class:`~allorules.errors.AllorulesError` into one line on stderr and a non-zero exit status
(a traceback only with ``--debug``).
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from allorules import __version__
from allorules.errors import AllorulesError

# Modules of this package that define sub-commands, in the order ``--help`` lists them.
COMMAND_MODULES = [
    "spectrum",
    "experiment",
    "scale",
    "rulesets",
    "plugins",
    "segment",
    "measure",
    "demo",
    "batch",
    "generate",
]

log = logging.getLogger("allorules")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="allorules",
        description="Scale quadruped meshes the way biology scales animals.",
    )
    parser.add_argument("--version", action="version", version=f"allorules {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    verbosity = parser.add_mutually_exclusive_group()
    verbosity.add_argument("-q", "--quiet", action="store_true", help="print only results and errors")
    verbosity.add_argument("-v", "--verbose", action="store_true", help="print what each step does")
    subcommands = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name.replace('-', '_')}").register(subcommands)
    return parser


def configure_logging(arguments: argparse.Namespace) -> None:
    level = logging.WARNING if arguments.quiet else logging.DEBUG if arguments.verbose else logging.INFO
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr, force=True)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    arguments = parser.parse_args(argv)
    if arguments.command is None:
        parser.print_help()
        return 2
    configure_logging(arguments)
    try:
        return int(arguments.run(arguments) or 0)
    except AllorulesError as error:
        if arguments.debug:
            raise
        print(f"allorules {arguments.command}: error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print("allorules: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
