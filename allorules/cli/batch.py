"""``allorules batch MANIFEST.yaml``: many meshes × mass ratios × rulesets, in parallel, resumable.

Runs every job of the manifest that is not finished yet (see :mod:`allorules.runs.batch` and
docs/batch.md) with one worker per core (``--jobs N``), or on a Dask cluster (``--scheduler``,
:mod:`allorules.runs.cluster`), then writes ``summary.json``, ``summary.csv`` and ``summary.md``
in the output folder. Interrupt it at any time: running the same command again skips the
finished jobs. Exit status 1 when a job failed.
"""
from __future__ import annotations

import argparse


def register(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "batch",
        help="run many meshes × ratios × rulesets from a manifest, in parallel; resumes where it stopped",
        description="Scale every mesh of a manifest by every mass ratio with every ruleset ('global' for "
        "global scaling), one job per core or on a Dask cluster (--scheduler), skipping jobs finished by an "
        "earlier run with the same inputs.",
    )
    parser.add_argument("manifest", help="manifest YAML (see docs/batch.md)")
    parser.add_argument("-j", "--jobs", type=int, metavar="N",
                        help="jobs run at the same time (default: number of cores; 1: one after another)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run the jobs on a Dask cluster: its scheduler's address (tcp://HOST:PORT) or scheduler "
                        "file (.json); needs pip install 'allorules[distributed]' (docs/batch.md)")
    parser.add_argument("--shared-files", action="store_true",
                        help="with --scheduler: the workers see the manifest's files and the output folder at the same "
                        "paths (a shared file system), so jobs carry paths instead of file contents")
    parser.add_argument("--redo", action="store_true", help="run finished jobs again too")
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    from allorules.runs.batch import run_batch_command

    return run_batch_command(arguments)
