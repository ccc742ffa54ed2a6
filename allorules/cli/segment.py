"""``allorules segment MESH``: label a mesh's regions with a segmenter, or over-segment it into patches.

* ``allorules segment horse.obj -o horse.labels.json --png regions.png`` — the automatic quadruped
  labeller (``--up``/``--forward`` override the detected directions); ``--segmenter NAME
  [--option KEY=VALUE] [--plugin PATH]`` uses another segmenter (a plugin's), ``--ruleset NAME``
  the ruleset's; ``--seg`` also writes a Princeton ``.seg``.
* ``allorules segment horse.obj --patches 24 --png patches.png`` — the paper's path: numbered
  patches (labels file ``<mesh>.patches.json`` unless ``-o``) and a picture to choose from; then
  ``allorules segment horse.obj --patches 24 --merge merge.yaml -o horse.labels.json`` (the
  ``merge-file`` segmenter).

Labels refer to the vertices of the prepared mesh (:mod:`allorules.mesh.repair`), which is what
every other command works on, and keep every region the segmenter found. Existing output files
are kept unless ``--force``.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from allorules.cli.arguments import (
    add_direction_arguments,
    add_plugin_argument,
    add_png_argument,
    add_working_vertices_argument,
)
from allorules.errors import AllorulesError, SegmentationError

if TYPE_CHECKING:  # pragma: no cover
    from allorules.body import Body

log = logging.getLogger("allorules")


def register(subcommands: argparse._SubParsersAction) -> None:
    from allorules.cli import command_help

    parser = subcommands.add_parser(
        "segment",
        help=command_help("segment"),
        description="Label the regions with a segmenter (the automatic quadruped labeller by default), or (with "
        "--patches) over-segment into numbered patches that a merge file (YAML: region: [patch ids]) turns into "
        "regions. See docs/segmentation.md.",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    parser.add_argument("-o", "--output", metavar="LABELS.json",
                        help="per-vertex labels file to write (default: <mesh name>.labels.json, "
                        "or <mesh name>.patches.json for patches)")
    parser.add_argument("--seg", metavar="FILE.seg", help="also write per-face labels (Princeton benchmark .seg)")
    add_png_argument(parser, "regions in colour, or numbered patches")
    parser.add_argument("--segmenter", metavar="NAME", help="the segmenter to label with (default: the ruleset's, "
                        "else auto-quadruped); 'allorules plugins' lists them and their options")
    parser.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                        help="an option of the segmenter, e.g. --option patches=24 (repeatable)")
    parser.add_argument("--ruleset", metavar="NAME|FILE", help="label with this ruleset's segmenter and options")
    parser.add_argument("--patches", type=int, metavar="N", nargs="?", const=24,
                        help="over-segment into N connected patches (default 24) instead of labelling")
    parser.add_argument("--seed", type=int, default=0, help="seed of the patch clustering (default 0)")
    parser.add_argument("--merge", metavar="MERGE.yaml",
                        help="with --patches: merge the patches into regions as this file says")
    add_direction_arguments(parser)
    add_plugin_argument(parser)
    add_working_vertices_argument(parser)
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files (never an input: mesh, merge file, ruleset, plugin)")
    parser.set_defaults(run=run)


def segmenter_use(name: str, option_texts: list[str], registry):
    """The segmenter ``name`` with the command line's ``--option KEY=VALUE`` values, checked."""
    import yaml

    from allorules.plugins.specs import parameter_problems
    from allorules.rules.model import SegmenterUse

    specs = registry.segmenter(name).parameter_specs()
    options = {}
    for text in option_texts:
        key, sep, value = text.partition("=")
        key = key.strip()
        if not sep or not key:
            raise SegmentationError(f"--option {text!r}: write KEY=VALUE, e.g. --option patches=24")
        try:
            parsed = yaml.safe_load(value) if value.strip() else ""
        except yaml.YAMLError:
            parsed = value
        options[key] = Path(value).expanduser().resolve() if key in specs and specs[key].kind is Path else parsed
    for key, problem in parameter_problems(options, specs, word="option"):
        raise SegmentationError(f"--option {key}: segmenter {name!r}: {problem}")
    return SegmenterUse(name, options)


def run(arguments: argparse.Namespace) -> int:
    from allorules.body import Body
    from allorules.cli.arguments import plugin_files
    from allorules.files import JSON, PNG, Output, check_outputs
    from allorules.mesh.working import check_working_vertices
    from allorules.output.render import render_regions
    from allorules.plugins.registry import registry_for
    from allorules.rules.model import SegmenterUse
    from allorules.runs.pipeline import label, prepare, working
    from allorules.segment.labels_io import write_labels, write_seg
    from allorules.segment.patches import spectral_patches
    from allorules.segment.regions import patch_body

    mesh = Path(arguments.mesh)
    if arguments.merge and arguments.patches is None:
        raise SegmentationError("--merge needs --patches N (the same N the patch picture was made with)")
    if arguments.patches is not None and (arguments.segmenter or arguments.ruleset or arguments.option):
        raise SegmentationError("--patches makes patches (with --merge: the merge-file segmenter); leave out "
                                "--segmenter, --option and --ruleset")
    default_suffix = ".patches.json" if arguments.patches is not None and not arguments.merge else ".labels.json"
    output = Path(arguments.output) if arguments.output else Path(mesh.name).with_suffix("").with_suffix(default_suffix)
    registry = registry_for(arguments)
    ruleset_path = None
    if arguments.ruleset:
        from allorules.rules.resolve import load_ruleset

        ruleset = load_ruleset(arguments.ruleset, registry)
        ruleset_path, use = ruleset.path, ruleset.segmenter
        if arguments.segmenter or arguments.option:
            use = segmenter_use(arguments.segmenter or use.name, arguments.option, registry)
    elif arguments.merge:
        use = SegmenterUse("merge-file", {"path": Path(arguments.merge).resolve(), "patches": arguments.patches,
                                          "seed": arguments.seed})
    else:
        use = segmenter_use(arguments.segmenter or "auto-quadruped", arguments.option, registry)
    check_outputs([Output.of(output, "-o" if arguments.output else "the labels file", JSON),
                   Output.of(arguments.seg, "--seg", (".seg",)), Output.of(arguments.png, "--png", PNG)],
                  {"input mesh": mesh, "merge file": arguments.merge, "ruleset": ruleset_path,
                   "segmenter's file": [value for value in use.options.values() if isinstance(value, Path)],
                   "plugin": plugin_files(registry, arguments)}, force=arguments.force)
    check_working_vertices(arguments.working_vertices)
    prepared = prepare(arguments.mesh)
    work = working(prepared, arguments.working_vertices)    # as a run labels: on the working mesh
    body = work.body()

    numbered = False
    if arguments.patches is not None and not arguments.merge:
        patches = spectral_patches(body.vertices, body.faces, arguments.patches, seed=arguments.seed)
        on_working = patch_body(body, patches)
        numbered = True
        what = f"{int(patches.max()) + 1} patches"
    else:
        # every region the segmenter found is kept: a run folds what its ruleset does not list
        on_working = label(body, registry=registry, segmenter=use, up=arguments.up, forward=arguments.forward,
                           regions=())
        what = f"{len(on_working.region_names)} regions ({on_working.labelling.source})"
    labelled = work.labels_to_user(on_working, Body(prepared.vertices, prepared.faces))   # the file is the user's

    write_labels(output, labelled)
    log.info("wrote %s: %s", output, what)
    if arguments.seg:
        write_seg(arguments.seg, labelled)
        log.info("wrote %s", arguments.seg)
    if arguments.png:
        picture = on_working if on_working.frame is not None else on_working.with_labels(
            on_working.labels, on_working.region_names, frame=_frame_or_none(body, arguments))
        render_regions(picture, arguments.png, numbered=numbered, title=f"{mesh.name}: {what}")
        log.info("wrote %s", arguments.png)
    print(_summary(labelled))
    return 0


def _frame_or_none(body: Body, arguments: argparse.Namespace):
    """The body's frame for drawing patches: detected when possible, else the given/default one."""
    from allorules.body import Frame
    from allorules.segment.labeller import label_quadruped

    try:
        return label_quadruped(body, up=arguments.up, forward=arguments.forward).frame
    except AllorulesError:
        if arguments.up is not None and arguments.forward is not None:
            return Frame(arguments.up, arguments.forward)
        return None


def _summary(body: Body) -> str:
    import numpy as np

    from allorules.mesh.geometry import vertex_areas

    mass = vertex_areas(body.vertices, body.faces)
    total = mass.sum()
    shares = np.bincount(body.labels[body.labels >= 0], weights=mass[body.labels >= 0], minlength=len(body.region_names)) / total
    return ", ".join(f"{name} {100 * share:.1f}%" for name, share in zip(body.region_names, shares))
