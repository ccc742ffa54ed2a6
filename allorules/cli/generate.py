"""``allorules generate -o OUT.obj``: write the generated quadruped, its labels and its truth."""
from __future__ import annotations

import argparse
import json
import logging

log = logging.getLogger("allorules")


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "generate",
        help=command_help("generate"),
        description="Generate a smooth, closed quadruped (+Y up, +X forward, feet at y = 0) "
        "whose region labels and true measurements are known. See docs/quadruped.md.",
    )
    parser.add_argument("-o", "--output", required=True, metavar="OUT.obj",
                        help="mesh to write (.obj .ply .stl .off .glb)")
    parser.add_argument("--preset", default="horse", metavar="NAME",
                        help="animal to start from (default: horse; the others are listed in docs/quadruped.md, "
                        "and a wrong name lists them)")
    parser.add_argument("--vertices", type=int, default=8000, metavar="N",
                        help="about how many vertices (±20%%, default 8000)")
    parser.add_argument("--seed", type=int, default=0,
                        help="0: the preset exactly; other seeds vary every length by up to ±8%%")
    parser.add_argument("--pose", default=None, metavar="NAME",
                        help="stand it in a pose (walk, gallop, rear, graze, sit, lie, curl; default: standing); "
                        "its labels and truth stay the standing animal's (docs/quadruped.md, Poses)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", dest="overrides",
                        help="override one parameter, e.g. --set neck_length=0.9 (repeatable)")
    parser.add_argument("--labels", metavar="LABELS.json", help="also write per-vertex region labels")
    parser.add_argument("--truth", metavar="TRUTH.json", help="also write the true measurements")
    parser.add_argument("--force", action="store_true", help="replace existing output files")
    parser.set_defaults(run=run)


def _overrides(items: list[str]) -> dict[str, float]:
    from allorules.mesh.quadruped import QuadrupedParameterError

    values = {}
    for item in items:
        name, separator, text = item.partition("=")
        if not separator:
            raise QuadrupedParameterError(f"--set {item!r}: write NAME=VALUE, e.g. --set neck_length=0.9")
        try:
            values[name.strip()] = float(text)
        except ValueError:
            raise QuadrupedParameterError(f"--set {item!r}: {text!r} is not a number") from None
    return values


def run(arguments: argparse.Namespace) -> int:
    from allorules.files import JSON, Output, atomic_write, check_outputs
    from allorules.mesh.quadruped import generate_quadruped
    from allorules.output.export import SUPPORTED_FORMATS, save_mesh

    check_outputs([Output.of(arguments.output, "-o", SUPPORTED_FORMATS), Output.of(arguments.labels, "--labels", JSON),
                   Output.of(arguments.truth, "--truth", JSON)], force=arguments.force)

    animal = generate_quadruped(arguments.preset, arguments.vertices, seed=arguments.seed, pose=arguments.pose,
                                **_overrides(arguments.overrides))
    save_mesh(arguments.output, animal.vertices, animal.faces, overwrite=arguments.force)
    log.info("wrote %s: %s%s, %d vertices, %d faces", arguments.output, arguments.preset,
             f" ({arguments.pose})" if arguments.pose else "", len(animal.vertices), len(animal.faces))
    if arguments.labels:
        atomic_write(arguments.labels, json.dumps(animal.labels_document()))
        log.info("wrote %s", arguments.labels)
    if arguments.truth:
        document = animal.truth.as_dict()
        document.update(preset=arguments.preset, seed=arguments.seed, pose=arguments.pose or "stand",
                        vertices=len(animal.vertices), parameters=animal.parameters.as_dict())
        atomic_write(arguments.truth, json.dumps(document, indent=2))
        log.info("wrote %s", arguments.truth)
    return 0
