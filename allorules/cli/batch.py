"""``allorules batch MANIFEST.yaml``: many meshes × mass ratios × rulesets, in parallel, resumable.

Runs every job of the manifest that is not finished yet (see :mod:`allorules.runs.batch` and
docs/batch.md) with one worker per core (``--jobs N``), or on a Dask cluster (``--scheduler``,
:mod:`allorules.runs.cluster`), then writes ``summary.json``, ``summary.csv`` and ``summary.md``
in the output folder. Interrupt it at any time: running the same command again skips the
finished jobs. Exit status 1 when a job failed.
"""
from __future__ import annotations

import argparse
from pathlib import Path


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "batch",
        help=command_help("batch"),
        description="Scale every mesh of a manifest by every mass ratio with every ruleset ('global' for "
        "global scaling), one job per core or on a Dask cluster (--scheduler), skipping jobs finished by an "
        "earlier run with the same inputs (docs/batch.md).",
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
    from allorules.files import Output, check_outputs
    from allorules.runs.batch import load_manifest, run_batch_command

    # The manifest and every file it names are inputs: no result or summary may replace one; the
    # output folder must be writable before the first job starts.
    manifest = load_manifest(arguments.manifest)
    summaries = [Output.of(manifest.output / f"summary.{kind}", "the batch summary") for kind in ("json", "csv", "md")
                 if manifest.output.is_dir()]   # a folder still to be made holds no input
    check_outputs([Output.of(manifest.output, "the manifest's output folder", folder=True), *summaries],
                  {"manifest": manifest.path, "input mesh": [mesh.path for mesh in manifest.meshes],
                   "labels file": [mesh.segmentation for mesh in manifest.meshes if mesh.segmentation],
                   "ruleset": [Path(name) for name in manifest.rulesets if name.endswith((".yaml", ".yml"))],
                   "plugin": list(manifest.plugins)}, force=True)
    return run_batch_command(arguments)
