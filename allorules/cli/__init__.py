"""The ``allorules`` command line.

Each sub-command lives in its own module of this package and exposes
``register(subcommands)``, which adds an ``argparse`` parser whose default ``run`` is a function
``run(arguments) -> int``. :func:`main` wires them together and turns every
:class:`~allorules.errors.AllorulesError` into one line on stderr and a non-zero exit status
(a traceback only with ``--debug``).

Only the module of the command being run is imported (``allorules --help`` imports none), and
each command module imports the numerical stages inside its ``run``: the command line answers
``--help`` at once. :data:`COMMANDS` holds each command's one-line description for the top-level
help. Every command runs inside :func:`allorules.files.protection_scope`, so the inputs it names
stay protected from its writes.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import sys

from allorules import __version__
from allorules.errors import AllorulesError

# Sub-commands in the order ``--help`` lists them: name -> (module of this package, one line).
COMMANDS: dict[str, tuple[str, str]] = {
    "spectrum": ("spectrum", "the power law of a mesh's harmonic spectrum: slope α and R (docs/method.md)"),
    "experiment": ("experiment", "1-D experiments with the cosine transform as basis (docs/method.md)"),
    "scale": ("scale", "scale a mesh allometrically (--ruleset for biology-aware scaling, --global, or --region)"),
    "rulesets": ("rulesets", "list the rulesets that can be named, with their descriptions"),
    "ruleset": ("rulesets", "show, check or print the schema of rulesets (show NAME|FILE, check FILE, schema)"),
    "plugins": ("plugins", "list plugins: what each provides and where it came from"),
    "segment": ("segment", "label head, neck, chest, abdomen, forelimbs, hindlimbs (automatic, a plugin's "
                           "segmenter, or patches + merge file)"),
    "measure": ("measure", "measure body mass, peak limb stress and the region quantities of a ruleset"),
    "demo": ("demo", "scale the built-in quadruped globally and biology-aware; write meshes, gallery and reports"),
    "batch": ("batch", "run many meshes × ratios × rulesets from a manifest, in parallel; resumes where it stopped"),
    "generate": ("generate", "write a generated quadruped (closed mesh with known regions and measurements)"),
    "cache": ("cache", "where the harmonic-basis cache is, how big, how many entries; 'cache clear' empties it"),
}

log = logging.getLogger("allorules")


def command_help(name: str) -> str:
    """The one-line description of sub-command ``name`` (for the module that registers it)."""
    return COMMANDS[name][1]


def _chosen_command(argv: list[str]) -> str | None:
    """The sub-command named on the command line (the first word that is not an option)."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser; with ``argv``, only the module of the command it names is imported (the other
    commands are listed by name and description)."""
    parser = argparse.ArgumentParser(
        prog="allorules",
        description="Scale quadruped meshes the way biology scales animals. Run 'allorules COMMAND --help' "
                    "for a command's options; the docs/ folder explains each (start with README.md).",
    )
    parser.add_argument("--version", action="version", version=f"allorules {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    verbosity = parser.add_mutually_exclusive_group()
    verbosity.add_argument("-q", "--quiet", action="store_true", help="print only results and errors")
    verbosity.add_argument("-v", "--verbose", action="store_true", help="print what each step does")
    subcommands = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = _chosen_command(argv) if argv is not None else None
    registered: set[str] = set()
    for name, (module, description) in COMMANDS.items():
        if name in registered:
            continue
        if argv is None or COMMANDS.get(chosen, (None,))[0] == module:
            importlib.import_module(f"{__name__}.{module}").register(subcommands)
            registered.update(other for other, (owner, _) in COMMANDS.items() if owner == module)
        else:
            subcommands.add_parser(name, help=description, add_help=False)
            registered.add(name)
    return parser


def configure_logging(arguments: argparse.Namespace) -> None:
    """allorules' own messages at the level asked for; the libraries' (trimesh, matplotlib, ...)
    only when they warn. Numerical warnings (overflow in a NumPy expression) are not shown: what
    they lead to is checked and said in words; --debug shows them."""
    level = logging.WARNING if arguments.quiet else logging.DEBUG if arguments.verbose else logging.INFO
    logging.basicConfig(level=logging.WARNING, format="%(message)s", stream=sys.stderr, force=True)
    log.setLevel(level)
    if not arguments.debug:
        import warnings

        warnings.filterwarnings("ignore", category=RuntimeWarning)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser(argv)
        arguments = parser.parse_args(argv)
    except BrokenPipeError:   # 'allorules --help | true'
        return _quiet_broken_pipe()
    if arguments.command is None:
        parser.print_help()
        return 2
    configure_logging(arguments)
    where = f"allorules {arguments.command}"
    from allorules.files import protection_scope

    try:
        with protection_scope(), _terminate_cleanly():
            code = int(arguments.run(arguments) or 0)
        sys.stdout.flush()
        return code
    except Terminated:   # kill PID: files being written are removed, finished ones stay
        print(f"{where}: terminated", file=sys.stderr)
        return 143
    except BrokenPipeError:   # the reader went away ('... | head', '... | true'): nothing to say
        return _quiet_broken_pipe()
    except AllorulesError as error:
        if arguments.debug:
            raise
        print(f"{where}: error: {error}", file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        print(f"{where}: interrupted", file=sys.stderr)
        return 130
    except MemoryError:
        if arguments.debug:
            raise
        print(f"{where}: error: ran out of memory; try fewer --modes, a smaller mesh, or close other programs",
              file=sys.stderr)
        return 1
    except OSError as error:   # the file system said no where allorules did not expect it
        if arguments.debug:
            raise
        name = f" {error.filename}" if error.filename else ""
        print(f"{where}: error: cannot use{name}: {error.strerror or error}", file=sys.stderr)
        return 1
    except Exception as error:  # a bug: still one line, the traceback with --debug
        if arguments.debug:
            raise
        first = (str(error).strip().splitlines() or [""])[0]
        print(f"{where}: internal error ({type(error).__name__}: {first}); this is a bug in allorules: "
              "run the command again with --debug and report what it prints", file=sys.stderr)
        return 70


class Terminated(BaseException):
    """SIGTERM arrived: unwinds the command like Ctrl-C, so that atomic writes remove their
    temporary files and nothing half-written is left."""


@contextlib.contextmanager
def _terminate_cleanly():
    """Turn SIGTERM into :class:`Terminated` in this process while the command runs (a process
    forked from it gets the default behaviour back)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    owner = os.getpid()

    def terminated(signum, frame):
        if os.getpid() != owner:   # a forked worker: die as SIGTERM says
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _quiet_broken_pipe() -> int:
    """Point stdout at /dev/null so that Python's own flush at exit does not complain again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return 141   # as a program ended by SIGPIPE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
