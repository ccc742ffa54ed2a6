"""The animal stands where it stood (METHOD §10): place a scaled output on the input's ground.

Scaling acts about the body's area-weighted centroid (mode 0 of the harmonic basis stays put), so
a ×2 animal's feet sink below the input's floor and a ×0.5 one floats. :func:`place_on_ground`
moves the output rigidly so that its feet stand on the input's ground plane at the same place:
the scaling is then about the ground contact, the centroid of the feet's lowest points.

* The ground's normal is the body's up: ``body.frame.up`` (the labeller's, the normal of the plane
  its four feet stand on), else the legs' direction (:func:`allorules.measure.limbs.stance_down`).
* Each foot is the end of a limb part (the vertices beyond its last cross-section, as
  :class:`allorules.solve.posture.FootContact` takes them); its contact is its lowest vertex along up.
  A body without labelled limbs stands on its lowest vertices along up.
* The ground plane passes through the body's lowest point along up (on a standing animal, the
  lowest contact; Eq. 9 can bend a leg so that a point beside a foot's contact ends lowest, and
  nothing of the output may go below the input's floor); the anchor is the mean of the contacts,
  projected on that plane.

``anchor="centroid"`` keeps today's behaviour (the output as the scaling left it, centroid in
place).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from allorules.body import Body
from allorules.errors import AllorulesError

ANCHORS = ("ground", "centroid")
LOWEST_SHARE = 0.01    # without limbs: the lowest this share of vertices (along up) is the contact

__all__ = ["GroundContact", "ground_contact", "place_on_ground", "ANCHORS"]


class GroundError(AllorulesError):
    """The ground an animal stands on cannot be found (no up direction)."""


@dataclass(frozen=True)
class GroundContact:
    """Where a body touches the ground: ``up`` (unit, ground → back), the vertex sets of its
    ``feet``, each foot's lowest vertex ``contacts``, the ground's ``height`` (x·up of the body's lowest
    point) and the ``anchor`` (the contacts' mean, on the ground plane)."""

    up: np.ndarray
    feet: tuple[np.ndarray, ...]
    contacts: np.ndarray        # (feet, 3)
    height: float
    anchor: np.ndarray

    def as_dict(self) -> dict:
        return {"up": [float(v) for v in self.up], "height": float(self.height),
                "anchor": [float(v) for v in self.anchor], "feet": len(self.feet)}

    def at(self, vertices: np.ndarray) -> "GroundContact":
        """The same feet (vertex sets) and up on other positions of the same mesh."""
        return _contact(np.asarray(vertices, dtype=float), self.up, self.feet)


def _contact(vertices: np.ndarray, up: np.ndarray, feet: tuple[np.ndarray, ...]) -> GroundContact:
    contacts = np.array([vertices[foot[np.argmin(vertices[foot] @ up)]] for foot in feet])
    height = float((vertices @ up).min())
    mean = contacts.mean(axis=0)
    anchor = mean - (float(mean @ up) - height) * up
    return GroundContact(up, feet, contacts, height, anchor)


def _up_and_feet(body: Body, up=None) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    from allorules.measure.limbs import limb_sections, stance_down
    from allorules.measure.parts import LIMB_REGIONS

    limbs = []
    if body.labels is not None:
        for region in LIMB_REGIONS:
            if body.has_region(region) and body.region_mask(region).any():
                try:
                    limbs.extend(limb for limb in limb_sections(body, region) if limb.sections)
                except AllorulesError:
                    limbs = []
                    break
    if up is not None:
        up = np.asarray(up, dtype=float)
    elif body.frame is not None:
        up = np.asarray(body.frame.up, dtype=float)
    elif limbs:
        up = -stance_down(limbs, None)
    else:
        raise GroundError("cannot tell which way is up: label the body (allorules segment) or give --up, "
                          "or keep the centroid in place (--placement centroid)")
    up = up / np.linalg.norm(up)
    if limbs:
        feet = tuple(limb.mesh.vertex_index[limb.field >= limb.levels[-1]] for limb in limbs)
        feet = tuple(foot for foot in feet if len(foot))
    else:
        feet = ()
    if not feet:
        heights = body.vertices @ up
        count = max(1, int(LOWEST_SHARE * len(heights)))
        feet = (np.argsort(heights)[:count],)
    return up, feet


def ground_contact(body: Body, *, up=None) -> GroundContact:
    """Where ``body`` stands (see the module docstring); ``up`` overrides the body's up."""
    up, feet = _up_and_feet(body, up)
    return _contact(body.vertices, up, feet)


def place_on_ground(input_body: Body, output_vertices: np.ndarray, *, anchor: str = "ground",
                    contact: GroundContact | None = None) -> np.ndarray:
    """``output_vertices`` (a scaled version of ``input_body``, same vertex order) moved rigidly so
    that the output's feet stand on the input's ground plane at the same place: the output's
    ground contact (its feet's lowest points, the same feet as the input's) lands on the input's
    (height along up, and the anchor within the plane). ``anchor="centroid"`` returns the output
    unchanged (today's behaviour: scaled about the centroid). ``contact``: the input's
    :class:`GroundContact`, when already known."""
    output_vertices = np.asarray(output_vertices, dtype=float)
    if anchor not in ANCHORS:
        raise ValueError(f"anchor must be one of {', '.join(ANCHORS)}, not {anchor!r}")
    if output_vertices.shape != input_body.vertices.shape:
        raise ValueError(f"the output has {len(output_vertices)} vertices, the input {len(input_body.vertices)}")
    if anchor == "centroid":
        return output_vertices.copy()
    contact = contact or ground_contact(input_body)
    moved = contact.at(output_vertices)
    shift = contact.anchor - moved.anchor          # both anchors lie on their own ground planes
    return output_vertices + shift
