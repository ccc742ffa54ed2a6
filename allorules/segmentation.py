"""Segmentation of a body into anatomical regions (paper §3.2, METHOD §7): the public entry point.

Three ways to get the six regions the scaling rules talk about
(head, neck, chest = upper torso, abdomen = lower torso, forelimbs, hindlimbs):

* automatically, for a standing quadruped: :func:`label_quadruped` (module :mod:`allorules.labeller`);
* the paper's user-assisted path: :func:`spectral_patches` over-segments the mesh into numbered
  connected patches (module :mod:`allorules.patches`), a person writes a merge file naming the
  patches of each region, :func:`apply_merge_file` turns patches into regions;
* from a file: per-vertex labels JSON or a Princeton ``.seg`` (module :mod:`allorules.labels_io`).

Where the parts that are not one of the six go (the automatic labeller and :func:`map_regions`):
a **tail** belongs to the **abdomen** (it grows from the rump, which is lower torso); ears, horns,
antlers, manes and trunks belong to the **head**.
"""
from __future__ import annotations

import numpy as np

from .body import UNLABELLED, Body
from .errors import SegmentationError
from .labeller import REGIONS as QUADRUPED_REGIONS
from .labeller import label_quadruped
from .labels_io import (
    MergeFileError,
    apply_merge_file,
    face_labels_from_vertices,
    read_labels,
    read_merge_file,
    read_seg,
    vertex_labels_from_faces,
    write_labels,
    write_seg,
)
from .patches import DEFAULT_PATCH_COUNT, spectral_patches

# Where regions outside the six go: the neighbour that carries them.
NEIGHBOUR_REGION = {"tail": "abdomen", "ears": "head", "ear": "head", "horns": "head", "horn": "head",
                    "trunk": "head", "antlers": "head", "mane": "neck"}

__all__ = [
    "QUADRUPED_REGIONS", "NEIGHBOUR_REGION", "DEFAULT_PATCH_COUNT", "MergeFileError",
    "label_quadruped", "spectral_patches", "apply_merge_file", "read_merge_file",
    "read_labels", "write_labels", "read_seg", "write_seg",
    "face_labels_from_vertices", "vertex_labels_from_faces", "map_regions",
]


def map_regions(body: Body, regions: tuple[str, ...] = QUADRUPED_REGIONS) -> Body:
    """The body relabelled onto ``regions``: extra regions (tail, ears, …) go to their neighbour.

    Regions not in ``regions`` and not in :data:`NEIGHBOUR_REGION` raise a SegmentationError.
    """
    if body.labels is None:
        raise SegmentationError("the body has no labels; segment it first")
    lookup = np.full(len(body.region_names) + 1, UNLABELLED, dtype=np.int64)  # last slot: unlabelled
    for index, name in enumerate(body.region_names):
        target = name if name in regions else NEIGHBOUR_REGION.get(name)
        if target not in regions:
            raise SegmentationError(
                f"region {name!r} is not one of {', '.join(regions)} and has no known neighbour to join"
            )
        lookup[index] = regions.index(target)
    labels = lookup[np.where(body.labels >= 0, body.labels, len(body.region_names))]
    return Body(body.vertices, body.faces, labels, tuple(regions), body.frame)


def patch_body(body: Body, patches: np.ndarray) -> Body:
    """The body with its patches as regions named ``patch0`` … (for labels files and pictures)."""
    patches = np.asarray(patches, dtype=np.int64)
    names = tuple(f"patch{i}" for i in range(int(patches.max()) + 1))
    return Body(body.vertices, body.faces, patches, names, body.frame)


def write_preview(body: Body, path, *, numbered: bool = False, title: str | None = None, views=None):
    """A PNG of the body with one colour per region, from several views.

    ``numbered`` prints each region's index on it (for patches: the ids a merge file uses), at
    the region's vertex nearest to its area centroid.
    """
    from . import render
    from .laplacian import lumped_mass

    if body.labels is None:
        raise SegmentationError("the body has no labels to draw; segment it first")
    views = tuple(views) if views else render.VIEWS
    colors = render.region_colors(body.labels, body.region_names)
    annotations = []
    if numbered:
        mass = lumped_mass(body.vertices, body.faces)
        for index in range(len(body.region_names)):
            members = np.flatnonzero(body.labels == index)
            if len(members) == 0:
                continue
            centre = np.average(body.vertices[members], axis=0, weights=mass[members] + 1e-300)
            nearest = members[np.argmin(np.linalg.norm(body.vertices[members] - centre, axis=1))]
            annotations.append((body.vertices[nearest], str(index)))
    legend = None if numbered else render.region_legend(body.labels, body.region_names)
    return render.render_views(body.vertices, body.faces, path=path, views=views, frame=body.frame,
                               vertex_colors=colors, annotations=annotations or None, title=title, legend=legend)


def labelled_body(body: Body, labels_path=None, *, up=None, forward=None) -> Body:
    """``body`` with regions: read from ``labels_path`` (labels JSON or Princeton ``.seg``; extra
    regions such as a tail folded into their neighbour) or, without a file, from the automatic
    labeller (honouring ``up``/``forward``)."""
    from pathlib import Path

    if labels_path is None:
        return label_quadruped(body, up=up, forward=forward)
    path = Path(labels_path)
    if path.suffix.lower() == ".seg":
        labelled = read_seg(path, body, QUADRUPED_REGIONS)
    else:
        labelled = read_labels(path, body)
    kept = tuple(name for name in labelled.region_names if name not in NEIGHBOUR_REGION)
    return map_regions(labelled, kept)

