"""Region lengths (METHOD §3): the diameter of a region's skeleton, the mean over the parts of a
paired region. Leg length is measured here.
"""
from __future__ import annotations

import numpy as np

from allorules.body import Body
from allorules.errors import MeasurementError
from allorules.measure.cache import measured
from allorules.measure.limbs import FOOT_SHARE
from allorules.measure.parts import (
    LIMB_REGIONS,
    SECTION_COUNT,
    TORSO_REGIONS,
    _closed_fields,
    region_parts,
    torso_axis,
)
from allorules.measure.sections import (
    Skeleton,
    area_quantiles,
    skeleton,
)


def region_skeleton(body: Body, region: str) -> list[Skeleton]:
    """Skeleton of each part of a region, from the part's own Fiedler vector."""
    cache = measured(body)
    carried = cache.carried.skeletons.get(region) if cache.carried else None
    if region not in cache.skeletons and carried is not None:   # the reference's skeletons, re-measured
        cache.skeletons[region] = [part_skeleton.moved(part.closed()[0])
                                   for part_skeleton, part in zip(carried, region_parts(body, region))]
    if region not in cache.skeletons:
        skeletons = []
        for part, field in zip(region_parts(body, region), _closed_fields(body, region)):
            vertices, faces = part.closed()
            levels = None
            if region in LIMB_REGIONS:   # no sections in the foot: its end is the tip's end point
                targets = (np.arange(SECTION_COUNT) + 0.5) / SECTION_COUNT
                levels = np.unique(area_quantiles(vertices, faces, field, targets[targets <= 1.0 - FOOT_SHARE]))
                levels = levels[(levels > field.min()) & (levels < field.max())]
            skeletons.append(skeleton(vertices, faces, field, levels, count=SECTION_COUNT, by_level=region in LIMB_REGIONS))
        cache.skeletons[region] = skeletons
    return cache.skeletons[region]


def region_length(body: Body, region: str) -> float:
    """Length of a region: diameter of its skeleton; the mean over the parts of a paired region."""
    cache = measured(body).lengths
    if region not in cache:
        lengths = [part_skeleton.diameter for part_skeleton in region_skeleton(body, region)]
        length = float(np.mean(lengths))
        if not length > 0:
            raise MeasurementError(f"region {region!r} has no measurable length (its skeleton is a point)")
        cache[region] = length
    return cache[region]


def trunk_length(body: Body) -> float:
    """The trunk's length: the extent of the torso (chest and abdomen) along the torso axis, from
    the point of the shoulder to the point of the buttock, as animal scientists measure body length.
    (The regions' own skeletons run across a short, thick torso region as readily as along it: the
    bull 386 drawn out to exponent 0.6 along its back measured 0.35 by them.)"""
    torso = np.zeros(len(body.vertices), dtype=bool)
    for region in TORSO_REGIONS:
        if body.has_region(region):
            torso |= body.region_mask(region)
    if not torso.any():
        raise MeasurementError("the body has no chest or abdomen region: its trunk's length is unknown")
    return float(np.ptp(body.vertices[torso] @ torso_axis(body)))
