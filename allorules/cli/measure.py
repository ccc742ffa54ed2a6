"""``allorules measure MESH``: body mass, peak stress and every region quantity a ruleset uses.

The regions come from ``--segmentation FILE`` (an allorules labels ``.json``, or a Princeton
``.seg`` whose segment ids 0…5 are head, neck, chest, abdomen, forelimbs, hindlimbs), from the
mesh's own labels file beside it (``NAME.labels.json``, as ``allorules scale`` writes beside its
output: an output is measured with the regions and axes its run measured) unless ``--relabel``, or
from the ruleset's segmenter (the automatic quadruped labeller by default). Quantities are in the
mesh's own units (mass = volume, density 1); only their ratios mean anything to the scaler.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path

from allorules.cli.arguments import (
    add_direction_arguments,
    add_png_argument,
    add_relabel_argument,
    add_working_vertices_argument,
    labels_beside_input,
)
from allorules.errors import AllorulesError, MeasurementError, SegmentationError

log = logging.getLogger("allorules")

DEFAULT_RULESET = "quadruped"


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help
    from allorules.cli.arguments import add_plugin_argument

    parser = subcommands.add_parser(
        "measure",
        help=command_help("measure"),
        description="Prepare the mesh, label its regions (from --segmentation, or automatically) and print "
        "body mass, peak stress and each rule's quantity of the ruleset (docs/measurements.md).",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    parser.add_argument("--segmentation", metavar="FILE",
                        help="labels file (.json from 'allorules segment' or 'generate') or Princeton .seg; "
                        "automatic quadruped labelling when not given")
    parser.add_argument("--ruleset", default=DEFAULT_RULESET, metavar="NAME",
                        help=f"ruleset whose quantities to measure (default {DEFAULT_RULESET}); a name or a .yaml path")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_png_argument(parser, "the regions in colour and the load-bearing section marked")
    parser.add_argument("--force", action="store_true", help="replace an existing picture (never an input)")
    add_relabel_argument(parser)
    add_direction_arguments(parser)
    add_plugin_argument(parser)
    add_working_vertices_argument(parser)
    parser.set_defaults(run=run)


def segmented_body(arguments: argparse.Namespace, ruleset, registry):
    """The working body (the prepared body itself up to the working size, or the working mesh its
    labels file recorded) with regions from the given file or the ruleset's segmenter: what a run
    measures; where its regions came from; and the working mesh (``None``: the body itself)."""
    from allorules.mesh.working import check_working_vertices
    from allorules.runs.pipeline import labelled_working, prepare, wanted_regions

    check_working_vertices(arguments.working_vertices)
    prepared = prepare(arguments.mesh)
    work, labelled = labelled_working(prepared, registry=registry, working_vertices=arguments.working_vertices,
                                   segmenter=ruleset.segmenter, labels=arguments.segmentation or None, up=arguments.up,
                                   forward=arguments.forward, regions=wanted_regions(ruleset),
                                   labels_beside=not arguments.relabel)
    mesh = None if work.binding is None else work.mesh
    if arguments.segmentation:
        return labelled, str(arguments.segmentation), mesh
    beside = labels_beside_input(arguments)     # read where it fits the mesh (pipeline.labelled_working)
    source = labelled.labelling.source if labelled.labelling is not None else ""
    return labelled, beside if beside is not None and source.startswith(f"labels file {beside}") else "automatic", mesh


def run(arguments: argparse.Namespace) -> int:
    from allorules.cli.arguments import plugin_files
    from allorules.files import PNG, Output, check_outputs
    from allorules.measure.mass import body_mass
    from allorules.measure.stress import peak_stress
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset

    registry = registry_for(arguments)
    ruleset = load_ruleset(arguments.ruleset, registry)
    check_outputs([Output.of(arguments.png, "--png", PNG)],
                  {"input mesh": arguments.mesh, "labels file": arguments.segmentation,
                   "input's labels file": labels_beside_input(arguments), "ruleset": ruleset.path,
                   "plugin": plugin_files(registry, arguments)}, force=arguments.force)
    body, source, working_mesh = segmented_body(arguments, ruleset, registry)
    missing = [rule.region for rule in ruleset.rules if rule.region and rule.region not in body.region_names]
    if missing:
        raise SegmentationError(
            f"the segmentation has no region {', '.join(sorted(set(missing)))} that ruleset {ruleset.name!r} "
            f"needs (it has: {', '.join(body.region_names)})"
        )
    result = {
        "mesh": str(arguments.mesh),
        "segmentation": source,
        "labels": body.labelling.as_dict() if body.labelling else None,
        "ruleset": ruleset.name,
        "vertices": int(body.vertex_count),
        "working_mesh": None if working_mesh is None else working_mesh.method,   # "recorded": its run's
        "frame": None if body.frame is None else {"up": [float(x) for x in body.frame.up],
                                                  "forward": [float(x) for x in body.frame.forward]},
        "body_mass": _finite(body_mass(body), "body mass"),
        "peak_stress": _finite(peak_stress(body), "peak stress"),
        "rules": [],
    }
    for rule in ruleset.rules:
        spec = registry.measure(rule.measure)
        try:
            value = _finite(spec.compute(body, rule.region), f"{rule.measure} of {rule.region or 'the body'}")
        except AllorulesError as error:
            raise MeasurementError(f"rule {rule.id!r}: {error}") from None
        result["rules"].append({"id": rule.id, "region": rule.region, "measure": rule.measure,
                                "exponent": rule.exponent, "value": value})
    if arguments.png:
        _write_picture(body, arguments.png, result)
        log.info("wrote %s", arguments.png)
    if arguments.json:
        print(json.dumps(result))
    else:
        print(f"{arguments.mesh} ({source} segmentation, ruleset {ruleset.name})")
        print(f"  body mass    {result['body_mass']:.6g}")
        print(f"  peak stress  {result['peak_stress']:.6g}")
        for item in result["rules"]:
            print(f"  {item['id']:<20} {item['measure']} of {item['region'] or 'body'}: {item['value']:.6g}")
    return 0


def _finite(value: float, what: str) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise MeasurementError(f"{what} came out as {value}; the mesh or its segmentation cannot be measured")
    return value


def _write_picture(body, path: str, result: dict) -> None:
    """Side and three-quarter views: regions in colour, the load-bearing section marked."""
    import numpy as np

    from allorules.measure.stress import load_bearing_section
    from allorules.output.render import region_colors, region_legend, render_views

    annotations = []
    try:
        chosen = load_bearing_section(body)
        annotations.append((np.asarray(chosen.section.loop.points).mean(axis=0), "load-bearing section"))
    except AllorulesError:
        pass
    render_views(
        body.vertices, body.faces, path=path, views=("side", "three-quarter"), frame=body.frame,
        vertex_colors=region_colors(body.labels, body.region_names),
        legend=region_legend(body.labels, body.region_names), annotations=annotations or None,
        title=f"{Path(result['mesh']).name}: body mass {result['body_mass']:.4g}, peak stress {result['peak_stress']:.4g}",
    )
