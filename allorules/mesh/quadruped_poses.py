"""Poses of the generated quadruped: legs swung and bent, head up or down, tail raised or curled.

A pose moves the vertices of the standing animal (:func:`allorules.mesh.quadruped.generate_quadruped`)
the way a rig does, and keeps its faces and its per-vertex labels: **the labels of the standing
animal are the truth in every pose**. Every joint is a rotation about a line parallel to Z (the
animal's left–right axis) through a pivot, blended over a band around the joint so that the
surface stays smooth and closed:

- a **leg** swings about its saddle (armpit or groin: where the leg starts, docs/segmentation.md);
  the leg below the saddle moves rigidly (its length and volume are the standing truth), the blend
  lies above it, inside the torso's fillet. A **knee** half way down the leg bends the lower half
  (blend ± the leg's radius there);
- the **neck** turns about its base (the chest's tangent plane), the **head** about its joint with
  the neck; the blend is ± the neck's radius there;
- the **tail** turns about its root (its cut plane) and curls: bent like a rod into an arc of the
  given total angle over its length;
- the **whole body** pitches nose-up about its hips (``pitch``), the legs' swings then counted from
  the vertical so that a leg with no swing still stands upright. A **seated** pose solves the pitch:
  the body turns up until the fore feet stand on the ground the folded hind legs rest on, and is
  set down on the standing animal's ground (:func:`pitched`, shared with :mod:`allorules.mesh.repose`).

Angles are in degrees; positive swings move a foot forward (+X), positive knee bends fold the
lower leg backward, positive neck/head/tail angles turn up. :data:`POSES` names the ones the tests
use; ``generate_quadruped(..., pose="gallop")`` or ``pose=Pose(...)``.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from allorules.errors import AllorulesError
from allorules.mesh.geometry import near_line, smoothstep, turn_about_line

LEGS = ("fore-left", "fore-right", "hind-left", "hind-right")
SEAT_PITCH_LIMIT = 60.0   # degrees: a body turned up further does not sit (its fore legs are too long)


@dataclass(frozen=True)
class Pose:
    """Joint angles in degrees (see the module's docstring for the signs)."""

    swing: dict[str, float] = field(default_factory=dict)   # leg → swing about its saddle
    knee: dict[str, float] = field(default_factory=dict)    # leg → knee bend
    neck: float = 0.0
    head: float = 0.0
    tail: float = 0.0
    tail_curl: float = 0.0
    pitch: float = 0.0          # the whole body turned nose-up about its hips
    seated: bool = False        # the pitch solved: the fore feet down on the hind legs' ground

    def is_rest(self) -> bool:
        return not any(self.swing.values()) and not any(self.knee.values()) and not any(
            (self.neck, self.head, self.tail, self.tail_curl, self.pitch, self.seated))


def _legs(fore_left=0.0, fore_right=0.0, hind_left=0.0, hind_right=0.0) -> dict[str, float]:
    return dict(zip(LEGS, (fore_left, fore_right, hind_left, hind_right)))


POSES: dict[str, Pose] = {
    "stand": Pose(),
    "walk": Pose(swing=_legs(18, -14, -16, 14), knee=_legs(0, 25, 0, 0), neck=-8),
    "gallop": Pose(swing=_legs(38, 30, -36, -28), knee=_legs(20, 10, 0, 0), neck=-20, head=15, tail=30),
    "rear": Pose(swing=_legs(20, 24, 35, 35), knee=_legs(95, 85, 0, 0), neck=20, tail=-20),
    "graze": Pose(swing=_legs(6, -6, 0, 0), neck=-70, head=20, tail=-10),
    # the thighs forward, the shins folded back under them, the chest up on straight fore legs
    "sit": Pose(swing=_legs(0, 0, 85, 85), knee=_legs(0, 0, 160, 160), neck=-10, head=-15, tail=35, seated=True),
    "lie": Pose(swing=_legs(25, 30, 55, 50), knee=_legs(95, 100, 100, 95), neck=5, head=-10, tail=-20),
    "curl": Pose(swing=_legs(8, -8, -8, 8), tail=70, tail_curl=240, neck=10),
}


def _turn(points, pivot, angle):
    """Each point turned about the Z-parallel line through ``pivot`` by its own ``angle``."""
    return turn_about_line(points, pivot, np.array([0.0, 0.0, 1.0]), angle)


def pose_vertices(layout, vertices: np.ndarray, pose: Pose, labels: np.ndarray, region_names) -> np.ndarray:
    """The standing animal's vertices moved into ``pose`` (faces and labels unchanged).

    ``labels`` (the standing truth, indices into ``region_names``) confine each joint to its part:
    the neck and head turn what is labelled head or neck (and the chest's surface around the neck's
    root, blended), the tail what is labelled tail (and the rump around its root).
    """
    if pose.is_rest():
        return vertices.copy()
    named = {name: labels == index for index, name in enumerate(region_names)}
    hind_x = float(np.mean([axis[0] for axis in layout.leg_axes["hindlimbs"]]))
    hips = np.array([hind_x, layout.leg_cut_height["hindlimbs"], 0.0])
    return pitched(lambda pitch: _turned_at_joints(layout, vertices, pose, named, pitch), pose, hips,
                   side=np.array([0.0, 0.0, 1.0]), up=np.array([0.0, 1.0, 0.0]),
                   fore=named["forelimbs"], hind=named["hindlimbs"], rest=vertices)


def pitched(joints: Callable[[float], np.ndarray], pose: Pose, hips: np.ndarray, *, side: np.ndarray,
            up: np.ndarray, fore: np.ndarray, hind: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """The body posed at its joints (``joints(pitch)``: each leg's swing less the pitch, so that it
    is counted from the vertical) and turned nose-up by the pitch about the line through ``hips``
    along ``side`` (forward × up: a turn by +angle raises the head).

    A seated pose's pitch is solved: the one at which the fore feet (the lowest of ``fore`` along
    ``up``) come down to the level of the folded hind legs (the lowest of ``hind``; bisection, as
    the fore feet rise with the pitch and the hind legs turn about the hips with it), at most
    :data:`SEAT_PITCH_LIMIT` (beyond it the animal cannot sit: an error); the body is then set down
    on the standing animal's ground (the lowest point of ``rest``)."""
    def at(degrees: float) -> np.ndarray:
        moved = joints(degrees)
        if degrees == 0.0:
            return moved
        return turn_about_line(moved, hips, side, np.full(len(moved), math.radians(degrees)))

    if not pose.seated:
        return at(pose.pitch)

    def gap(moved: np.ndarray) -> float:
        return float((moved[fore] @ up).min() - (moved[hind] @ up).min())

    low, high = 0.0, SEAT_PITCH_LIMIT
    if gap(at(high)) < 0.0:
        raise AllorulesError(f"this animal cannot sit: its fore feet stay below its folded hind legs with its body "
                             f"turned up {SEAT_PITCH_LIMIT:.0f}° (fore legs too long for its body); choose another pose")
    while high - low > 0.05:
        middle = 0.5 * (low + high)
        low, high = (middle, high) if gap(at(middle)) < 0.0 else (low, middle)
    seated = at(high)
    return seated + ((rest @ up).min() - (seated @ up).min()) * up


def _turned_at_joints(layout, vertices: np.ndarray, pose: Pose, named: dict[str, np.ndarray], pitch: float) -> np.ndarray:
    """The legs, neck, head and tail turned at their joints; each leg's swing less ``pitch``."""
    p = layout.parameters
    rest = vertices
    moved = vertices.copy()
    # Legs: knee first (in the leg's standing frame), then the swing about the saddle.
    for region, r_top, r_bottom, length in (("forelimbs", p.foreleg_radius_top, p.foreleg_radius_bottom, p.foreleg_length),
                                            ("hindlimbs", p.hindleg_radius_top, p.hindleg_radius_bottom, p.hindleg_length)):
        saddle = layout.leg_cut_height[region]
        reach = layout.leg_reach[region]
        for (x, z), side in zip(layout.leg_axes[region], ("left", "right")):
            leg = f"{region[:4]}-{side}"
            swing = math.radians(pose.swing.get(leg, 0.0) - pitch)
            knee = math.radians(pose.knee.get(leg, 0.0))
            if swing == 0.0 and knee == 0.0:
                continue
            near = np.hypot(rest[:, 0] - x, rest[:, 2] - z)
            lateral = 1.0 - smoothstep((near - reach) / r_top)            # this leg's column
            if knee:
                knee_y = 0.5 * saddle
                knee_radius = 0.5 * (r_top + r_bottom)
                below = 1.0 - smoothstep((rest[:, 1] - (knee_y - knee_radius)) / (2 * knee_radius))
                weight = lateral * below
                # fore knees (carpus) fold the foot back, hind knees (hock) forward: one sign here
                moved = _turn(moved, np.array([x, knee_y, z]), -knee * weight)
            if swing:
                below = 1.0 - smoothstep((rest[:, 1] - saddle) / (2 * r_top))
                weight = lateral * below
                # a forward swing moves the foot to +X: turn by −angle about +Z at the pivot
                moved = _turn(moved, np.array([x, saddle, z]), -swing * weight * _forward_sign())
    # Neck about its base, head about its joint with the neck (beyond each plane, blended).
    cuts = {cut.name: cut for cut in layout.cuts}
    front = named["head"] | named["neck"]
    for name, angle, radius in (("neck", pose.neck, p.neck_radius), ("head", pose.head, p.neck_head_radius)):
        if angle:
            cut = cuts[name]
            along = (rest - cut.point) @ cut.normal
            part = np.where(front, 1.0, near_line(rest, cut.point, cut.normal, radius, 2 * p.limb_blend + radius))
            weight = smoothstep((along + radius) / (2 * radius)) * part
            moved = _turn(moved, cut.point, math.radians(angle) * weight * _up_sign(cut.normal))
    if pose.tail or pose.tail_curl:
        moved = _pose_tail(layout, rest, moved, pose, named["tail"])
    return moved


def _forward_sign() -> float:
    """A rotation by +a about +Z turns +Y towards −X: a foot below its pivot moves to +X."""
    return -1.0


def _up_sign(direction) -> float:
    """Sign of the turn about +Z that raises a part pointing along ``direction`` (x component)."""
    return 1.0 if direction[0] >= 0 else -1.0


def _pose_tail(layout, rest, moved, pose: Pose, labels_tail) -> np.ndarray:
    """Tail: bent like a rod into an arc of ``tail_curl`` degrees along its length, then turned
    by ``tail`` degrees about its root; blended over one tail radius at the root."""
    p = layout.parameters
    cut = {c.name: c for c in layout.cuts}["tail"]
    root, direction = cut.point, cut.normal / np.linalg.norm(cut.normal)
    length = p.tail_length
    side = np.cross([0.0, 0.0, 1.0], direction)          # in-plane, perpendicular to the tail
    up = 1.0 if side[1] >= 0 else -1.0                   # "up" curls towards +Y
    side = side * up
    offset = rest - root
    s = offset @ direction
    part = np.where(labels_tail, 1.0, near_line(rest, root, direction, p.tail_radius, 2 * p.limb_blend + p.tail_radius))
    weight = smoothstep((s + p.tail_radius) / (2 * p.tail_radius)) * part
    result = moved.copy()
    tail = weight > 0
    if pose.tail_curl:
        kappa = math.radians(pose.tail_curl) / length
        sa = np.clip(s[tail], 0.0, None)
        q_side = offset[tail] @ side
        q_z = offset[tail][:, 2]
        theta = kappa * sa
        axis = (root + np.outer(np.sin(theta) / kappa, direction) + np.outer((1 - np.cos(theta)) / kappa, side))
        bent = (axis + q_side[:, None] * (np.outer(np.cos(theta), side) - np.outer(np.sin(theta), direction))
                + np.outer(q_z, [0.0, 0.0, 1.0]))
        straight = rest[tail]
        w = weight[tail][:, None]
        result[tail] = moved[tail] + w * (bent - straight)
    if pose.tail:
        result = _turn(result, root, _up_sign(direction) * math.radians(pose.tail) * weight)
    return result
