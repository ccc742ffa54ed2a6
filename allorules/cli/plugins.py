"""CLI: ``allorules plugins`` lists every registered plugin, what it provides and its origin."""
from __future__ import annotations

import argparse

from allorules.cli.arguments import add_plugin_argument


def register(subcommands) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "plugins", help=command_help("plugins"),
        description="List the built-in plugin, installed plugins (entry-point group 'allorules') and "
                    "plugins given with --plugin. Plugins that failed are listed with the reason; the exit "
                    "status is 1 when any failed.")
    parser.add_argument("--details", action="store_true",
                        help="describe each measure, segmenter and constraint (with parameters)")
    add_plugin_argument(parser)
    parser.set_defaults(run=run)


def run(arguments: argparse.Namespace) -> int:
    from allorules.plugins.registry import registry_for

    registry = registry_for(arguments)
    infos = registry.describe()
    measures, segmenters, constraints = registry.measures(), registry.segmenters(), registry.constraints()
    for info in infos:
        print(f"{info.name}  ({info.origin}: {info.location})" if info.location else f"{info.name}  ({info.origin})")
        for kind, names in info.provides.items():
            print(f"  {kind}s: {', '.join(names)}")
            if not arguments.details:
                continue
            for name in names:
                if kind == "measure":
                    spec = measures[name]
                    region = "region required" if spec.needs_region else ("region optional" if spec.accepts_region
                                                                           else "whole body")
                    print(f"    {name}: {spec.description} [{spec.kind}, isometric exponent "
                          f"{spec.isometric_exponent:.4g}, {region}]")
                elif kind in ("segmenter", "constraint"):
                    spec = segmenters[name] if kind == "segmenter" else constraints[name]
                    print(f"    {name}: {spec.description}")
                    word = "option" if kind == "segmenter" else "parameter"
                    for parameter, parameter_spec in spec.parameter_specs().items():
                        given = "required" if parameter_spec.required else f"default {parameter_spec.default!r}"
                        print(f"      {word} {parameter} ({given}): {parameter_spec.description}")
        if not info.provides and not info.failed:
            print("  provides nothing")
        for message in info.failed:
            print(f"  FAILED: {message}")
    return 1 if registry.failures else 0
