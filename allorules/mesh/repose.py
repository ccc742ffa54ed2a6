"""Any labelled animal put into the generated quadruped's poses: test animals from real meshes.

:mod:`allorules.mesh.quadruped_poses` poses the generated animal from its own layout; this module
poses a real mesh from its labels (a body whose labels are right, such as a shared mesh the
labeller is tested on), so that the labeller and a whole run can be tried on real surfaces
walking, galloping, rearing or grazing, with the standing labels as the truth (the faces and
each vertex's label are kept). The same :class:`~allorules.mesh.quadruped_poses.Pose` and signs:
positive swings move a foot forward, positive knee bends fold the lower leg back, positive neck,
head and tail angles turn them up.

Each joint is read off the labels: a part's **joint** is the ring of its vertices next to the rest
of the body (a leg's at the armpit or groin, the neck's at the withers, the head's at the throat,
the tail's at its root); its pivot is the ring's centroid, its radius the ring's mean radius, its
direction from the pivot to the part's centroid. A part turns about the line through its pivot
along the animal's side axis, blended from 0 to 1 over ± one radius of the joint, and the surface
of its parent region around the joint (a leg's torso, the neck's chest) is blended with it. A
**knee** lies half way down a leg's length. The whole body pitches about its hips (the centre of
the hind legs' joints) as the generated animal's does (:func:`~allorules.mesh.quadruped_poses.pitched`:
a seated pose turns it up until its fore feet reach its folded hind legs' ground). A rough rig,
not an animator's: the surface stays closed and smooth, but a deep bend squeezes the skin at the
joint.
"""
from __future__ import annotations

import math

import numpy as np

from allorules.body import Body
from allorules.errors import AllorulesError
from allorules.mesh.geometry import near_line, smoothstep, turn_about_line
from allorules.mesh.quadruped_poses import Pose, pitched
from allorules.mesh.topology import vertex_components, vertex_graph

# The regions whose surface around a part's joint turns with the part (blended).
PARENTS = {"forelimbs": ("chest", "abdomen"), "hindlimbs": ("chest", "abdomen"), "neck": ("chest",),
           "head": ("neck",), "tail": ("abdomen", "chest")}


class _Joint:
    """A part's joint: the pivot, radius and direction of the ring where it meets the body."""

    def __init__(self, vertices: np.ndarray, graph, part: np.ndarray):
        outside = ~part
        touching = np.asarray(graph[:, outside].sum(axis=1)).ravel() > 0
        ring = part & touching
        if not ring.any():
            raise AllorulesError("a part to pose does not touch the rest of the body")
        self.pivot = vertices[ring].mean(axis=0)
        self.radius = float(np.linalg.norm(vertices[ring] - self.pivot, axis=1).mean())
        direction = vertices[part].mean(axis=0) - self.pivot
        self.direction = direction / np.linalg.norm(direction)
        self.length = float(((vertices[part] - self.pivot) @ self.direction).max())


def _weights(vertices: np.ndarray, joint: _Joint, part: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """1 on the part beyond its joint, 0 behind it, blended over ± the joint's radius; the parent's
    surface within two radii of the joint's line blended alike."""
    along = (vertices - joint.pivot) @ joint.direction
    ramp = smoothstep((along + joint.radius) / (2.0 * joint.radius))
    near = near_line(vertices, joint.pivot, joint.direction, joint.radius, 2.0 * joint.radius)
    return np.where(part, ramp, np.where(parent & (along < 2.0 * joint.radius), ramp * near, 0.0))


def _mask(body: Body, names: tuple[str, ...]) -> np.ndarray:
    mask = np.zeros(len(body.vertices), dtype=bool)
    for name in names:
        if body.has_region(name):
            mask |= body.region_mask(name)
    return mask


def _legs(body: Body, graph, side: np.ndarray) -> dict[str, tuple[str, np.ndarray]]:
    """Each leg's name (fore-left, ...) → its region and vertex mask; left is the +side one."""
    legs = {}
    centre = body.vertices.mean(axis=0)
    for region in ("forelimbs", "hindlimbs"):
        mask = _mask(body, (region,))
        components = vertex_components(graph, mask)
        pieces = sorted(np.unique(components[mask]), key=lambda piece: -np.count_nonzero(components == piece))[:2]
        if len(pieces) != 2:
            raise AllorulesError(f"the {region} are not two separate legs; they cannot be posed")
        parts = [components == piece for piece in pieces]
        parts.sort(key=lambda part: -float((body.vertices[part].mean(axis=0) - centre) @ side))
        for part, name in zip(parts, ("left", "right")):
            legs[f"{region[:4]}-{name}"] = (region, part)
    return legs


def repose(body: Body, pose: Pose) -> np.ndarray:
    """``body``'s vertices moved into ``pose`` (faces and labels unchanged). ``body`` must be
    labelled with its frame (as the labeller returns it) and have four separate legs; the neck,
    head and tail turn where the body has them. Raises :class:`AllorulesError` otherwise."""
    if body.labels is None or body.frame is None:
        raise AllorulesError("only a labelled body with its frame (up, forward) can be posed")
    vertices = body.vertices
    if pose.is_rest():
        return vertices.copy()
    forward, up = np.asarray(body.frame.forward, dtype=float), np.asarray(body.frame.up, dtype=float)
    side = np.cross(forward, up)
    side /= np.linalg.norm(side)
    graph = vertex_graph(vertices, body.faces)
    legs = _legs(body, graph, side)
    joints = {name: _Joint(vertices, graph, part) for name, (_, part) in legs.items()}
    hips = np.mean([joints[name].pivot for name in ("hind-left", "hind-right")], axis=0)
    return pitched(lambda pitch: _turned_at_joints(body, pose, graph, legs, joints, pitch, side, forward), pose, hips,
                   side=side, up=up, fore=_mask(body, ("forelimbs",)), hind=_mask(body, ("hindlimbs",)),
                   rest=vertices)


def _turned_at_joints(body: Body, pose: Pose, graph, legs, joints, pitch: float, side: np.ndarray,
                      forward: np.ndarray) -> np.ndarray:
    """The legs, head, neck and tail turned at their joints; each leg's swing less ``pitch``."""
    vertices = body.vertices
    moved = vertices.copy()
    # Legs: the knee first (in the standing leg's frame), then the swing about the leg's joint.
    for name, (region, part) in legs.items():
        swing = math.radians(pose.swing.get(name, 0.0) - pitch)
        knee = math.radians(pose.knee.get(name, 0.0))
        joint = joints[name]
        if knee:
            along = (vertices - joint.pivot) @ joint.direction
            middle = part & (np.abs(along - 0.5 * joint.length) < 0.5 * joint.radius)
            pivot = vertices[middle].mean(axis=0) if middle.any() else joint.pivot + 0.5 * joint.length * joint.direction
            band = 0.5 * joint.radius
            weight = np.where(part, smoothstep((along - 0.5 * joint.length + band) / (2.0 * band)), 0.0)
            moved = turn_about_line(moved, pivot, side, -knee * weight)
        if swing:
            weight = _weights(vertices, joint, part, _mask(body, PARENTS[region]))
            moved = turn_about_line(moved, joint.pivot, side, swing * weight)
    # The head about its joint with the neck, then the neck (carrying the head) about its base.
    for region, angle, carried in (("head", pose.head, ("head", "ears", "horns", "trunk")),
                                   ("neck", pose.neck, ("neck", "head", "ears", "horns", "trunk")),
                                   ("tail", pose.tail, ("tail",))):
        if not angle or not body.has_region(region) or not body.region_mask(region).any():
            continue
        part = _mask(body, carried)
        joint = _Joint(vertices, graph, part)
        weight = _weights(vertices, joint, part, _mask(body, PARENTS[region]))
        up_sign = 1.0 if joint.direction @ forward >= 0 else -1.0      # +side raises a forward-pointing part
        moved = turn_about_line(moved, joint.pivot, side, up_sign * math.radians(angle) * weight)
    return moved

