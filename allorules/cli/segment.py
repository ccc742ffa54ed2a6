"""``allorules segment MESH``: label a mesh's anatomical regions, automatically or from patches.

* ``allorules segment horse.obj -o horse.labels.json --png regions.png`` — automatic quadruped
  labelling (``--up``/``--forward`` override the detected directions), ``--seg`` also writes a
  Princeton ``.seg``.
* ``allorules segment horse.obj --patches 24 --png patches.png`` — the paper's path: numbered
  patches (labels file ``<mesh>.patches.json`` unless ``-o``) and a picture to choose from; then
  ``allorules segment horse.obj --patches 24 --merge merge.yaml -o horse.labels.json``.

Labels refer to the vertices of the prepared mesh (see :mod:`allorules.preparation`), which is
what every other command works on. Existing output files are kept unless ``--force``.
"""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from ..body import Body
from ..errors import AllorulesError, SegmentationError

log = logging.getLogger("allorules")

_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def parse_direction(text: str) -> np.ndarray:
    """A direction from the command line: ``+y``, ``-z``, ``x`` or three numbers ``0,1,0``."""
    cleaned = text.strip().lower()
    sign = -1.0 if cleaned.startswith("-") else 1.0
    name = cleaned.lstrip("+-")
    if name in _AXES:
        return sign * np.array(_AXES[name])
    try:
        values = np.array([float(part) for part in cleaned.replace(" ", ",").split(",") if part], dtype=float)
    except ValueError:
        values = np.zeros(0)
    if values.shape != (3,) or not np.isfinite(values).all() or np.linalg.norm(values) == 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a direction; write +y, -z or three numbers like 0,1,0")
    return values / np.linalg.norm(values)


def add_direction_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--up", type=parse_direction, metavar="DIR",
                        help="the body's up direction (feet to back), e.g. +y or 0,0,1; detected when not given")
    parser.add_argument("--forward", type=parse_direction, metavar="DIR",
                        help="the body's forward direction (tail to head), e.g. +x; detected when not given")


def register(subcommands: argparse._SubParsersAction) -> None:
    parser = subcommands.add_parser(
        "segment",
        help="label head, neck, chest, abdomen, forelimbs, hindlimbs (automatic, or patches + merge file)",
        description="Automatic quadruped labelling, or (with --patches) the paper's over-segmentation into "
        "numbered patches that a merge file (YAML: region: [patch ids]) turns into regions.",
    )
    parser.add_argument("mesh", help="input mesh (OBJ, PLY, STL, OFF, GLB, GLTF)")
    parser.add_argument("-o", "--output", metavar="LABELS.json",
                        help="per-vertex labels file to write (default: <mesh name>.labels.json, "
                        "or <mesh name>.patches.json for patches)")
    parser.add_argument("--seg", metavar="FILE.seg", help="also write per-face labels (Princeton benchmark .seg)")
    parser.add_argument("--png", metavar="FILE.png", help="write a picture: regions in colour, or numbered patches")
    parser.add_argument("--patches", type=int, metavar="N", nargs="?", const=24,
                        help="over-segment into N connected patches (default 24) instead of labelling automatically")
    parser.add_argument("--seed", type=int, default=0, help="seed of the patch clustering (default 0)")
    parser.add_argument("--merge", metavar="MERGE.yaml",
                        help="with --patches: merge the patches into regions as this file says")
    add_direction_arguments(parser)
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    parser.set_defaults(run=run)


def load_body(path: str) -> Body:
    """The prepared body of a mesh file, with each repair logged."""
    from ..preparation import prepare_mesh

    prepared = prepare_mesh(path)
    for repair in prepared.repairs:
        log.info("prepare: %s", repair)
    return Body(prepared.vertices, prepared.faces)


def _check_output(path: Path, mesh: Path, force: bool) -> Path:
    if path.resolve() == mesh.resolve():
        raise SegmentationError(f"{path}: refusing to overwrite the input mesh; choose another output name")
    if path.exists() and not force:
        raise SegmentationError(f"{path}: already exists; use --force to overwrite it")
    if not path.parent.exists():
        raise SegmentationError(f"{path.parent}: folder does not exist")
    return path


def run(arguments: argparse.Namespace) -> int:
    from .. import segmentation

    mesh = Path(arguments.mesh)
    if arguments.merge and arguments.patches is None:
        raise SegmentationError("--merge needs --patches N (the same N the patch picture was made with)")
    default_suffix = ".patches.json" if arguments.patches is not None and not arguments.merge else ".labels.json"
    output = Path(arguments.output) if arguments.output else Path(mesh.name).with_suffix("").with_suffix(default_suffix)
    outputs = [_check_output(output, mesh, arguments.force)]
    for extra in (arguments.seg, arguments.png):
        if extra:
            outputs.append(_check_output(Path(extra), mesh, arguments.force))
    body = load_body(arguments.mesh)

    if arguments.patches is not None:
        patches = segmentation.spectral_patches(body.vertices, body.faces, arguments.patches, seed=arguments.seed)
        frame = _frame_or_none(body, arguments)
        body = Body(body.vertices, body.faces, frame=frame)
        if arguments.merge:
            labelled = segmentation.apply_merge_file(body, patches, arguments.merge)
            numbered = False
            what = f"{len(labelled.region_names)} regions from {int(patches.max()) + 1} patches"
        else:
            labelled = segmentation.patch_body(body, patches)
            numbered = True
            what = f"{int(patches.max()) + 1} patches"
    else:
        labelled = segmentation.label_quadruped(body, up=arguments.up, forward=arguments.forward)
        numbered = False
        what = "6 regions (automatic)"

    segmentation.write_labels(output, labelled)
    log.info("wrote %s: %s", output, what)
    if arguments.seg:
        segmentation.write_seg(arguments.seg, labelled)
        log.info("wrote %s", arguments.seg)
    if arguments.png:
        segmentation.write_preview(labelled, arguments.png, numbered=numbered, title=f"{mesh.name}: {what}")
        log.info("wrote %s", arguments.png)
    print(_summary(labelled))
    return 0


def _frame_or_none(body: Body, arguments: argparse.Namespace):
    """The body's frame for drawing patches: detected when possible, else the given/default one."""
    from ..body import Frame
    from ..labeller import label_quadruped

    try:
        return label_quadruped(body, up=arguments.up, forward=arguments.forward).frame
    except AllorulesError:
        if arguments.up is not None and arguments.forward is not None:
            return Frame(arguments.up, arguments.forward)
        return None


def _summary(body: Body) -> str:
    from ..laplacian import lumped_mass

    mass = lumped_mass(body.vertices, body.faces)
    total = mass.sum()
    shares = np.bincount(body.labels[body.labels >= 0], weights=mass[body.labels >= 0], minlength=len(body.region_names)) / total
    return ", ".join(f"{name} {100 * share:.1f}%" for name, share in zip(body.region_names, shares))
