"""Small features of an animal surface (horns, ears, hooves, a tail tip, eyes) and how much their
shape changed (METHOD §10: "small features keep their shape").

Owns :func:`find_small_features` (found from the geometry alone, independent of the region
labeller) and :func:`feature_shape_change` (shape difference after removing the best similarity
transform, in units of the feature's size).

**Protrusions.** The average geodesic distance (AGD) is largest at the tips of protrusions. Each
local maximum of the AGD, swept downwards, grows a component of the super-level set until it
meets the component of a more prominent tip (topological persistence, the elder rule); the
component just before it merges is the protrusion: the horn from its tip down to where it meets
the head. A protrusion is *small* when its area is at most ``MAX_AREA_SHARE`` of the body's
surface (legs, the neck with the head are larger) and it stands out by at least
``MIN_PERSISTENCE`` of the AGD's range (smaller maxima are surface noise).

**Ends.** A longer protrusion (persistence above ``MAX_PERSISTENCE``: a leg, a tail, the neck
with the head) is not small, but its end is: the super-level component within ``END_DEPTH`` of
the AGD's range below its tip (a hoof, the tail's tip, the muzzle) is a feature of kind
``"end"``.

**Detached parts.** Separate connected pieces of the mesh (eyes, teeth, a loose horn) with at
most ``MAX_AREA_SHARE`` of the surface.

Everything is measured in units of the mesh's own size (√area, AGD range), so the features found
do not depend on the mesh's units, position or orientation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sparse
from scipy.sparse.csgraph import connected_components

from allorules.mesh.geometry import similarity_fit, vertex_areas
from allorules.mesh.topology import vertex_graph
from allorules.segment.body_plan import average_geodesic_distance, persistent_maxima

MAX_AREA_SHARE = 0.03       # a small feature covers at most this share of the body's surface
MIN_PERSISTENCE = 0.02      # of the AGD range: smaller protrusions are surface noise
MAX_PERSISTENCE = 0.35      # of the AGD range: longer protrusions are limbs, tails, necks
END_DEPTH = 0.08            # of the AGD range: the end of a limb or tail (a hoof, the tail tip)
MIN_VERTICES = 8            # fewer vertices carry no measurable shape

__all__ = [
    "SmallFeature",
    "FeatureShapeChange",
    "find_small_features",
    "feature_shape_change",
]


@dataclass(frozen=True)
class SmallFeature:
    """A small part of the surface that should keep its shape.

    ``kind``: ``"protrusion"`` (a persistent tip and the surface around it down to where it meets
    the body), ``"end"`` (the end of a limb, tail or head: a hoof, the tail's tip) or
    ``"detached"`` (a separate piece of the mesh). ``vertices``: its vertex indices.
    ``tip``: the tip vertex of a protrusion (None for a detached part). ``area_share``: its share
    of the whole surface. ``persistence``: how far the AGD falls from the tip before the
    protrusion meets the body, as a share of the AGD's range (0 for a detached part).
    """

    kind: str
    vertices: np.ndarray
    tip: int | None
    area_share: float
    persistence: float

    @property
    def name(self) -> str:
        where = f"tip {self.tip}" if self.tip is not None else f"{len(self.vertices)} vertices"
        return f"{self.kind} at {where}"

    def as_dict(self) -> dict:
        return {"kind": self.kind, "tip": None if self.tip is None else int(self.tip),
                "vertices": int(len(self.vertices)), "area_share": float(self.area_share),
                "persistence": float(self.persistence)}


def _super_level_component(values: np.ndarray, graph: sparse.csr_matrix, tip: int, level: float) -> np.ndarray:
    """Vertices of the connected part of {values > level} that holds ``tip``."""
    inside = np.flatnonzero(values > level)
    if tip not in set(inside.tolist()):
        return np.array([tip])
    sub = graph[inside][:, inside]
    _, parts = connected_components(sub, directed=False)
    return inside[parts == parts[np.searchsorted(inside, tip)]]


def find_small_features(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    max_area_share: float = MAX_AREA_SHARE,
    min_persistence: float = MIN_PERSISTENCE,
    max_persistence: float = MAX_PERSISTENCE,
) -> list[SmallFeature]:
    """Small protrusions and small detached parts of a mesh, largest persistence first.

    See the module docstring for the rules. Protrusions nested in another small protrusion (a
    bump on a horn) are dropped: the outer one is the feature. Detached parts come last.
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    mass = vertex_areas(vertices, faces)
    total = float(mass.sum())
    if not total > 0:
        return []
    graph = vertex_graph(vertices, faces)
    _, parts = connected_components(graph, directed=False)
    part_area = np.bincount(parts, weights=mass)
    main = int(np.argmax(part_area))
    features: list[SmallFeature] = []

    index = np.flatnonzero(parts == main)
    if len(index) > 3 * MIN_VERTICES:
        sub_graph = graph[index][:, index].tocsr()
        agd = average_geodesic_distance(sub_graph, mass[index])
        span = float(agd.max() - agd.min())
        if span > 0:
            tips, persistence = persistent_maxima(agd, sub_graph)
            taken = np.zeros(len(index), dtype=bool)
            order = np.argsort(-persistence, kind="stable")
            candidates = []
            for k in order:
                tip, share_persistence = int(tips[k]), float(persistence[k]) / span
                if share_persistence < min_persistence:
                    continue   # noise
                kind, depth = "protrusion", float(persistence[k])
                if share_persistence > max_persistence:
                    kind, depth = "end", END_DEPTH * span
                component = _super_level_component(agd, sub_graph, tip, float(agd[tip] - depth))
                share = float(mass[index[component]].sum()) / total
                candidates.append((share, tip, share_persistence, component, kind))
            # outer features first (largest area), so a bump on a horn is dropped as nested
            for share, tip, share_persistence, component, kind in sorted(candidates, key=lambda c: -c[0]):
                if share > max_area_share or len(component) < MIN_VERTICES or taken[component].mean() > 0.5:
                    continue
                taken[component] = True
                features.append(SmallFeature(kind, index[component], int(index[tip]), share, share_persistence))
            features.sort(key=lambda feature: -feature.persistence)

    for part in np.argsort(-part_area):
        if part == main:
            continue
        members = np.flatnonzero(parts == part)
        share = float(part_area[part]) / total
        if share <= max_area_share and len(members) >= MIN_VERTICES:
            features.append(SmallFeature("detached", members, None, share, 0.0))
    return features


# ---------------------------------------------------------------------------------------------
# Shape change


@dataclass(frozen=True)
class FeatureShapeChange:
    """How much a small feature's shape changed, the best similarity transform removed.

    ``size``: the feature's RMS distance from its centroid before (mesh units). ``scale``: the
    similarity's scale factor (how much the feature grew). ``shape_change``: the RMS distance
    between the after-shape and the best similarity image of the before-shape, over ``scale ×
    size`` (0: the same shape; 0.1: off by a tenth of its size on average). ``largest_change``: the
    largest such distance, in the same units.
    """

    feature: str
    kind: str
    region: str | None
    vertices: int
    size: float
    scale: float
    shape_change: float
    largest_change: float

    def as_dict(self) -> dict:
        return {"feature": self.feature, "kind": self.kind, "region": self.region, "vertices": self.vertices,
                "size": float(self.size), "scale": float(self.scale), "shape_change": float(self.shape_change),
                "largest_change": float(self.largest_change)}


def feature_shape_change(before: np.ndarray, after: np.ndarray, feature: SmallFeature,
                         region: str | None = None, weights: np.ndarray | None = None) -> FeatureShapeChange:
    """Shape difference of ``feature`` between two positions of the same mesh (METHOD §10).

    The before-shape is mapped onto the after-shape by the best similarity (scale, rotation,
    translation; :func:`allorules.mesh.geometry.similarity_fit`, weighted by ``weights``, e.g. vertex areas); what is
    left, RMS over the feature's vertices, is divided by the feature's size after (its RMS
    distance from its centroid before, times the fitted scale)."""
    members = feature.vertices
    p, q = np.asarray(before, dtype=float)[members], np.asarray(after, dtype=float)[members]
    w = np.ones(len(members)) if weights is None else np.asarray(weights, dtype=float)[members]
    w = w / w.sum()
    scale, rotation, shift = similarity_fit(p, q, w)
    residual = np.linalg.norm(q - (scale * p @ rotation.T + shift), axis=1)
    size = float(np.sqrt(w @ np.sum((p - w @ p) ** 2, axis=1)))
    unit = max(scale * size, np.finfo(float).tiny)
    return FeatureShapeChange(feature.name, feature.kind, region, int(len(members)), size, scale,
                              float(np.sqrt(w @ residual ** 2)) / unit, float(residual.max()) / unit)


def feature_region(feature: SmallFeature, labels: np.ndarray | None, region_names) -> str | None:
    """The region most of a feature's vertices are labelled with (None without labels)."""
    if labels is None:
        return None
    own = np.asarray(labels)[feature.vertices]
    own = own[own >= 0]
    if not len(own):
        return None
    return str(region_names[int(np.bincount(own).argmax())])
