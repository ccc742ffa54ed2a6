"""``allorules demo [-o DIR]``: the whole method on the built-in generated quadruped.

Generates a horse (or ``--preset``), labels its regions automatically, scales it globally and
biology-aware (``quadruped`` ruleset) to mass ratios 0.5 and 2, and writes the meshes, a gallery
picture, JSON reports and an offline HTML report into a fresh folder (see
:mod:`allorules.runs.demo` and docs/demo.md). Prints the rule table and where everything is.
"""
from __future__ import annotations

import argparse
import logging

log = logging.getLogger("allorules")


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help
    from allorules.runs.demo import (
        DEFAULT_FOLDER,
        DEFAULT_MODES,
        DEFAULT_PRESET,
        DEFAULT_VERTICES,
        QUICK_MODES,
        QUICK_VERTICES,
    )

    parser = subcommands.add_parser(
        "demo",
        help=command_help("demo"),
        description="Generate the built-in quadruped, label its regions, scale it globally and with the "
        "'quadruped' ruleset to mass ratios 0.5 and 2, and write the meshes (OBJ), a gallery picture, "
        "JSON reports and an offline HTML report (docs/demo.md).",
    )
    parser.add_argument("-o", "--output", metavar="DIR",
                        help=f"folder to write into (default: {DEFAULT_FOLDER}/, or {DEFAULT_FOLDER}-2/, -3/, … "
                        "when it already holds a previous demo)")
    parser.add_argument("--preset", default=DEFAULT_PRESET, metavar="NAME",
                        help=f"which generated animal (default {DEFAULT_PRESET}; see 'allorules generate --help')")
    parser.add_argument("--vertices", type=int, metavar="N",
                        help=f"about how many vertices the animal has (default {DEFAULT_VERTICES}, "
                        f"{QUICK_VERTICES} with --quick)")
    parser.add_argument("--modes", type=int, metavar="M",
                        help=f"harmonic basis size (default {DEFAULT_MODES}, {QUICK_MODES} with --quick)")
    parser.add_argument("--quick", action="store_true", help="a coarser animal and fewer modes")
    parser.add_argument("--force", action="store_true", help="write into -o DIR even if it holds files (overwriting them)")
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    from pathlib import Path

    from allorules.files import Output, check_outputs
    from allorules.runs.demo import format_rule_table, run_demo

    # the folder (or, for the default folder, the folder it is made in) can be written to
    check_outputs([Output.of(Path(arguments.output) if arguments.output else Path.cwd(), "-o", folder=True)],
                  force=True)

    demo = run_demo(arguments.output, preset=arguments.preset, vertices=arguments.vertices, modes=arguments.modes,
                    quick=arguments.quick, force=arguments.force)
    print(format_rule_table(demo.rule_rows()))
    print()
    failed = [run for run in demo.runs if run.error]
    for item in demo.runs:
        state = "FAILED" if item.error else "converged" if item.result.get("converged") else "not converged"
        mass = item.result.get("mass_ratio")
        stress = item.result.get("stress_ratio")
        print(f"{item.name:<14} mass ×{mass:.4f}" if mass is not None else f"{item.name:<14} mass   n/a  ", end="")
        print(f", stress ×{stress:.4f}" if stress is not None else "", end="")
        warnings = len(item.result.get("warnings", []))
        print(f", {state} ({item.seconds:.0f} s)" + (f", {warnings} warning{'s' * (warnings > 1)}: see the report"
                                                       if warnings else ""))
    print()
    print(f"wrote {len(demo.files)} files to {demo.folder}/ in {demo.seconds:.0f} s:")
    width = max(len(what) for what, _ in demo.files)
    for what, path in demo.files:
        print(f"  {what:<{width}}  {path}")
    print(f"open {demo.folder / 'report.html'} in a browser to see everything together")
    return 1 if failed else 0
