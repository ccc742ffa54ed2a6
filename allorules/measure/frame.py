"""The animal's frame (up, forward) read off its regions, for a body whose regions came without
one: a Princeton ``.seg``, regions painted in Blender, a merge file, an older labels file, a
plugin's segmenter. The automatic labeller finds its frame from the feet it chose; this finds it
the same way from the regions:

* **up** is the normal of the plane the four feet (each leg's tip) stand on, where they stand on
  one (:func:`allorules.segment.body_plan.ground_plane`), else of a plane three feet rest on that
  nothing lies below, nearest the legs' direction (:func:`allorules.segment.labeller.up_from_legs`),
  as the labeller finds it;
* **forward** runs from the abdomen's centroid to the chest's (area-weighted), square to up.

Measured on the shared animals labelled automatically, their labeller's frame put aside: within
1.8° of the labeller's up and forward on 14 of 15 (9.3° on the 389, whose hind legs are one
piece), where the regions' centroids alone (head and neck against abdomen, torso against legs)
were 8-50° off (the giraffe 390: 50°), which tilted the per-axis power law, the heart girth's tape
and the ground (docs/measurements.md).
"""
from __future__ import annotations

import numpy as np

from allorules.body import Body, Frame
from allorules.errors import AllorulesError
from allorules.measure.limbs import limb_sections
from allorules.measure.parts import LIMB_REGIONS
from allorules.mesh.geometry import vertex_areas
from allorules.segment.body_plan import ground_plane
from allorules.segment.labeller import up_from_legs


def regions_frame(body: Body) -> Frame | None:
    """The body's up and forward read off its regions (legs, chest, abdomen); None where it has
    not those regions or they give no direction."""
    def present(region: str) -> bool:
        return body.has_region(region) and bool(body.region_mask(region).any())

    if body.labels is None or not (present("chest") and present("abdomen")):
        return None
    try:
        limbs = [limb for region in LIMB_REGIONS if present(region)
                 for limb in limb_sections(body, region) if limb.sections]
    except (AllorulesError, ValueError, IndexError):   # regions no leg can be cut from: no frame from them
        return None
    if not limbs:
        return None
    area = vertex_areas(body.vertices, body.faces)
    feet = [int(limb.mesh.vertex_index[int(np.argmax(limb.field))]) for limb in limbs]
    legs = {foot: (limb.junction - limb.tip) / max(float(np.linalg.norm(limb.junction - limb.tip)), 1e-300)
            for foot, limb in zip(feet, limbs)}
    centroid = np.average(body.vertices, axis=0, weights=area)
    up = ground_plane(body.vertices[feet], body.vertices, centroid, None) if len(feet) == 4 else None
    if up is None:       # not on four feet in a plane: as the labeller does, a plane three feet rest on
        up = up_from_legs(body.vertices, area, feet, legs)
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)

    def region_centroid(region: str) -> np.ndarray:
        mask = body.region_mask(region)
        return (body.vertices[mask] * area[mask, None]).sum(axis=0) / max(float(area[mask].sum()), 1e-300)

    forward = region_centroid("chest") - region_centroid("abdomen")
    forward = forward - (forward @ up) * up
    length = float(np.linalg.norm(forward))
    if not np.isfinite(length) or length <= 1e-12 * float(np.ptp(body.vertices, axis=0).max()):
        return None
    return Frame(up=up, forward=forward / length)


__all__ = ["regions_frame"]
