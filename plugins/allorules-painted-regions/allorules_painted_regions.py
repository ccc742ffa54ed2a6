"""allorules plugin: the segmenter ``painted-regions``, regions an artist painted as vertex colours.

Paint each region in one colour (Blender: Vertex Paint), export the painted mesh as PLY (or any
format trimesh reads with vertex colours), and name it in a ruleset::

    segmenter:
      name: painted-regions
      options: {path: horse-painted.ply}

Each vertex of the body takes the colour of the nearest painted vertex, and the region whose
colour is nearest to it (``colors``: region name → ``#rrggbb``; by default allorules' own region
palette, the colours of ``allorules segment --png``). A colour farther than ``tolerance`` (0..1,
RGB distance) from every region's is left unlabelled, and a painted mesh that does not cover the
body (farther than 2 % of its size) is refused: a wrong file must not label silently.

The worked example of a segmenter plugin (docs/plugins.md): it receives the prepared body and
returns it labelled; allorules checks the options against ``parameters`` before anything runs.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from allorules.body import UNLABELLED, Labelling
from allorules.errors import SegmentationError
from allorules.plugins import ParameterSpec, SegmenterSpec, hookimpl

DEFAULT_COLORS = {"head": "#D55E00", "neck": "#E69F00", "chest": "#0072B2", "abdomen": "#56B4E9",
                  "forelimbs": "#009E73", "hindlimbs": "#CC79A7", "tail": "#F0E442"}


def _rgb(text: str) -> np.ndarray:
    text = str(text).lstrip("#")
    if len(text) != 6:
        raise SegmentationError(f"painted-regions: colour {text!r} is not #rrggbb")
    return np.array([int(text[k:k + 2], 16) for k in (0, 2, 4)], dtype=float) / 255.0


def segment(body, *, path: Path, colors: dict | None = None, tolerance: float = 0.25):
    import trimesh
    from scipy.spatial import cKDTree

    try:
        painted = trimesh.load(path, force="mesh", process=False)
    except Exception as error:
        raise SegmentationError(f"painted-regions: cannot read {path} ({type(error).__name__}: {error})") from None
    vertex_colors = getattr(getattr(painted, "visual", None), "vertex_colors", None)
    if vertex_colors is None or len(vertex_colors) != len(painted.vertices) or painted.visual.kind != "vertex":
        raise SegmentationError(f"painted-regions: {path} has no vertex colours; paint the regions (Blender: "
                                "Vertex Paint) and export with colours (PLY)")
    palette = {name: _rgb(value) for name, value in (colors or DEFAULT_COLORS).items()}
    names = tuple(palette)
    distance, nearest = cKDTree(np.asarray(painted.vertices)).query(body.vertices)
    size = float(np.linalg.norm(np.ptp(body.vertices, axis=0)))
    if np.percentile(distance, 99) > 0.02 * size:
        raise SegmentationError(f"painted-regions: {path} does not lie on this mesh (1 % of the vertices are over "
                                f"{np.percentile(distance, 99) / size:.0%} of its size away); paint this same mesh")
    rgb = np.asarray(vertex_colors, dtype=float)[nearest, :3] / 255.0
    gaps = np.linalg.norm(rgb[:, None, :] - np.array([palette[name] for name in names])[None], axis=2)
    labels = np.argmin(gaps, axis=1)
    labels[gaps.min(axis=1) > tolerance * np.sqrt(3)] = UNLABELLED
    found = np.unique(labels[labels >= 0])
    if len(found) == 0:
        raise SegmentationError(f"painted-regions: no vertex of {path} has a region's colour; "
                                "give the colours you painted with (option colors)")
    painted_share = float(np.mean(labels >= 0))
    return body.with_labels(labels, names, Labelling("painted-regions", {"painted": round(painted_share, 4)}))


@hookimpl
def allorules_segmenters():
    return [SegmenterSpec(
        "painted-regions", "regions an artist painted as vertex colours on the same mesh", segment,
        {"path": ParameterSpec(None, "the painted mesh (PLY with vertex colours), relative to the ruleset",
                               kind=Path, required=True),
         "colors": ParameterSpec(None, "region name -> #rrggbb (default: allorules' region palette)", kind=object),
         "tolerance": ParameterSpec(0.25, "how far (0..1) a painted colour may be from a region's", minimum=0.0,
                                    maximum=1.0)},
    )]
