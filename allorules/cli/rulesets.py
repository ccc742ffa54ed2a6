"""CLI: ``allorules rulesets`` (list) and ``allorules ruleset show|check|schema``."""
from __future__ import annotations

import argparse
import json
import sys
import textwrap

from allorules.cli.arguments import add_plugin_argument


def register(subcommands) -> None:
    from allorules.cli import command_help

    listing = subcommands.add_parser(
        "rulesets", help=command_help("rulesets"),
        description="List the built-in rulesets and those plugins provide; name any of them where a "
                    "ruleset is asked for, or give the path of your own .yaml file.")
    listing.add_argument("--paths", action="store_true", help="also show the file of each ruleset")
    add_plugin_argument(listing)
    listing.set_defaults(run=run_list)

    ruleset = subcommands.add_parser(
        "ruleset", help=command_help("ruleset"),
        description="Work with one ruleset. See docs/rulesets.md for the format.")
    actions = ruleset.add_subparsers(dest="action", metavar="ACTION")
    actions.required = True

    show = actions.add_parser("show", help="print a ruleset resolved (extends applied, defaults filled in)")
    show.add_argument("ruleset", metavar="NAME|FILE", help="built-in name (see 'allorules rulesets') or path")
    show.add_argument("--format", choices=("yaml", "json"), default="yaml", help="output format (default yaml)")
    add_plugin_argument(show)
    show.set_defaults(run=run_show)

    check = actions.add_parser("check", help="validate a ruleset; exit 0 when valid, 1 with every problem otherwise")
    check.add_argument("ruleset", metavar="FILE", help="path of the ruleset (a built-in name works too)")
    add_plugin_argument(check)
    check.set_defaults(run=run_check)

    schema = actions.add_parser("schema", help="print the ruleset JSON Schema (for editors)")
    schema.set_defaults(run=run_schema)


def run_list(arguments: argparse.Namespace) -> int:
    from allorules.plugins.registry import registry_for
    from allorules.rules.find import list_rulesets

    registry = registry_for(arguments)
    summaries = list_rulesets(registry)
    width = max((len(summary.name) for summary in summaries), default=0)
    for summary in summaries:
        origin = "" if summary.origin == "built-in" else f"[{summary.origin}] "
        text = textwrap.fill(origin + (summary.description or "(no description)"), width=100,
                             initial_indent=f"{summary.name:<{width}}  ", subsequent_indent=" " * (width + 2))
        print(text)
        if arguments.paths:
            print(" " * (width + 2) + str(summary.path))
        for other in summary.shadowed:
            print(" " * (width + 2) + f"(also {other}, hidden by the one above; load it by path)")
    return 0


def run_show(arguments: argparse.Namespace) -> int:
    from allorules.plugins.registry import registry_for
    from allorules.rules.model import dump_ruleset, ruleset_to_dict
    from allorules.rules.resolve import load_ruleset

    registry = registry_for(arguments)
    ruleset = load_ruleset(arguments.ruleset, registry)
    if arguments.format == "json":
        print(json.dumps(ruleset_to_dict(ruleset), indent=2, ensure_ascii=False))
    else:
        sys.stdout.write(dump_ruleset(ruleset))
    return 0


def run_check(arguments: argparse.Namespace) -> int:
    from allorules.errors import RulesetError, RulesetProblems
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset

    registry = registry_for(arguments)
    try:   # read once: every problem, or the ruleset
        ruleset = load_ruleset(arguments.ruleset, registry)
        problems: list = []
    except RulesetProblems as error:
        problems = error.problems
    except RulesetError as error:
        problems = [error]
    if problems:
        for problem in problems:
            print(f"error: {problem}", file=sys.stderr)
        print(f"{arguments.ruleset}: {len(problems)} problem{'s' if len(problems) != 1 else ''}", file=sys.stderr)
        return 1
    print(f"{arguments.ruleset}: valid (ruleset {ruleset.name!r}: {len(ruleset.regions)} regions, "
          f"{len(ruleset.rules)} rules, {len(ruleset.constraints)} constraints)")
    return 0


def run_schema(arguments: argparse.Namespace) -> int:
    from allorules.rules.schema import ruleset_schema

    print(json.dumps(ruleset_schema(), indent=2, ensure_ascii=False))
    return 0
