"""The generated quadruped: a closed, smooth animal surface that knows its own true measurements.

Owns :func:`generate_quadruped`, its :class:`QuadrupedParameters` and :data:`PRESETS`, and the
:class:`QuadrupedTruth` every measurement test checks against.

Construction. The animal is an implicit solid: the smooth union (polynomial smooth-min) of signed
distance functions of ellipsoids (chest, abdomen, head) and tapered capsules ("round cones": neck,
four legs, tail, optional snout/trunk). It is polygonised with marching cubes on a grid fine
enough to resolve the thinnest part, brought to the requested vertex count by edge collapses,
and its vertices are relaxed tangentially and projected back onto the implicit surface, so every
vertex lies on the analytic solid and triangles are well shaped.

Canonical frame: +Y up (feet towards y = 0), +X forward (tail → head), Z across the body (left
legs at z > 0). Units are whatever the parameters are in; presets are roughly metres.

Regions are PLANAR CUTS in space, all of them planes that contain the Z direction (their normals
have no Z component); a point's region is the first that claims it, in this order:

- tail:      beyond a plane perpendicular to the tail axis, placed where the whole tail section
             is behind x = x_tail (the tangent plane at the rear-most point of the abdomen) by
             at least the blend radius: a clean circular cut outside the rump's fillet;
- head:      beyond the plane through the neck's head end, perpendicular to the neck axis;
- neck:      beyond the tangent plane of the chest where the neck leaves it (perpendicular to the
             neck axis; the chest lies wholly behind it);
- forelimbs: below y = y_fore and in front of x = x_fore_back (just behind the forelegs), within
             the leg's reach of its axis and connected to its foot (:func:`free_legs`);
- hindlimbs: below y = y_hind and behind x = x_hind_front (just in front of the hind legs), likewise;
- chest:     in front of the vertical plane x = x_split (half way between chest and abdomen centres);
- abdomen:   the rest.

Each leg cut y_fore / y_hind is the leg's saddle (armpit / groin) on the implicit solid: the
highest horizontal plane below which the leg is its own piece (:func:`leg_saddle_height`), where
the segmentation says a leg starts (docs/segmentation.md). Truth is measured on the polygonised
mesh itself (see :class:`QuadrupedTruth`); region volumes are exact volumes of the mesh's solid
inside each region.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.csgraph  # noqa: F401  (sparse.csgraph)
import trimesh
from skimage.measure import marching_cubes

from allorules.body import Body, Frame
from allorules.errors import AllorulesError
from allorules.mesh.geometry import (
    enclosed_volume,
    face_normals,
    plane_section,
    vertex_normals,
)
from allorules.mesh.topology import corner_edges, directed_edges, vertex_adjacency

REGION_NAMES: tuple[str, ...] = ("head", "neck", "chest", "abdomen", "forelimbs", "hindlimbs", "tail")
LIMB_REGIONS = ("forelimbs", "hindlimbs")
LEG_BAND = 0.05   # leg radii average the section area over ± this fraction of the leg's length

MIN_VERTICES = 500
MAX_VERTICES = 200_000


class QuadrupedParameterError(AllorulesError, ValueError):
    """Parameters of the generated quadruped are inconsistent (e.g. legs outside the body)."""


# --------------------------------------------------------------------------------------------
# Parameters and presets
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class QuadrupedParameters:
    """Shape of a generated quadruped. Lengths in one arbitrary unit, angles in degrees.

    Torso: two ellipsoids, chest in front and abdomen behind; ``*_length/height/width`` are their
    full diameters along X/Y/Z and ``torso_length`` is from the front of the chest to the back of
    the abdomen. Legs are vertical tapered capsules; ``foreleg_length``/``hindleg_length`` run
    from the foot tip (y = 0) to the underside of the chest/abdomen at the leg. ``*_offset`` place
    the legs: forelegs ahead of the chest centre, hind legs behind the abdomen centre, as a
    fraction of that ellipsoid's half length. ``leg_spacing``: distance between left and right
    leg axes. Neck: a tapered capsule of ``neck_length`` (between its two cut planes) rising at
    ``neck_angle`` above horizontal. Head: an ellipsoid pointing ``head_angle`` above
    horizontal (negative: down). Snout: optional tapered capsule from the front of the head
    (``snout_length = 0`` for none), e.g. an elephant's trunk. Tail: tapered capsule leaving
    the rear of the abdomen ``tail_angle`` below horizontal. ``torso_blend``/``limb_blend``:
    smooth-union radii.
    """

    torso_length: float = 1.65
    chest_length: float = 0.95
    chest_height: float = 0.72
    chest_width: float = 0.50
    abdomen_length: float = 1.05
    abdomen_height: float = 0.66
    abdomen_width: float = 0.54
    neck_length: float = 0.55
    neck_radius: float = 0.16
    neck_head_radius: float = 0.10
    neck_angle: float = 50.0
    head_length: float = 0.55
    head_height: float = 0.24
    head_width: float = 0.20
    head_angle: float = -40.0
    snout_length: float = 0.0
    snout_radius: float = 0.0
    snout_angle: float = -70.0
    foreleg_length: float = 0.88
    hindleg_length: float = 0.84
    foreleg_radius_top: float = 0.085
    foreleg_radius_bottom: float = 0.05
    hindleg_radius_top: float = 0.095
    hindleg_radius_bottom: float = 0.05
    foreleg_offset: float = 0.6
    hindleg_offset: float = 0.45
    leg_spacing: float = 0.26
    tail_length: float = 0.55
    tail_radius: float = 0.055
    tail_angle: float = 35.0
    torso_blend: float = 0.20
    limb_blend: float = 0.05
    horn_length: float = 0.0      # issue 18: two horns on the head (0: none), a small feature to keep
    horn_radius: float = 0.0      # radius at the horn's root; it tapers to 0.35 of that at the tip
    horn_angle: float = 30.0      # outward tilt of the horns from the head's up, degrees

    def replace(self, **overrides: float) -> "QuadrupedParameters":
        """A copy with some parameters changed; unknown names are an error."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise QuadrupedParameterError(
                f"unknown quadruped parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
        return dataclasses.replace(self, **{k: float(v) for k, v in overrides.items()})

    def as_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)


_LENGTH_FIELDS = tuple(
    name for name in (f.name for f in dataclasses.fields(QuadrupedParameters))
    if not name.endswith(("_angle", "_offset")))


PRESETS: dict[str, QuadrupedParameters] = {
    "horse": QuadrupedParameters(),
    "elephant": QuadrupedParameters(
        torso_length=3.1, chest_length=1.9, chest_height=1.85, chest_width=1.55,
        abdomen_length=2.0, abdomen_height=1.75, abdomen_width=1.5,
        neck_length=0.45, neck_radius=0.45, neck_head_radius=0.40, neck_angle=20.0,
        head_length=1.0, head_height=0.95, head_width=0.85, head_angle=-35.0,
        snout_length=1.3, snout_radius=0.17, snout_angle=-80.0,
        foreleg_length=1.3, hindleg_length=1.25,
        foreleg_radius_top=0.27, foreleg_radius_bottom=0.22,
        hindleg_radius_top=0.28, hindleg_radius_bottom=0.22,
        foreleg_offset=0.6, hindleg_offset=0.45, leg_spacing=0.80,
        tail_length=0.9, tail_radius=0.08, tail_angle=45.0,
        torso_blend=0.45, limb_blend=0.08),
    "giraffe": QuadrupedParameters(
        torso_length=1.9, chest_length=1.2, chest_height=1.05, chest_width=0.64,
        abdomen_length=1.1, abdomen_height=0.8, abdomen_width=0.58,
        neck_length=1.8, neck_radius=0.18, neck_head_radius=0.09, neck_angle=62.0,
        head_length=0.6, head_height=0.22, head_width=0.2, head_angle=-35.0,
        foreleg_length=1.85, hindleg_length=1.7,
        foreleg_radius_top=0.10, foreleg_radius_bottom=0.055,
        hindleg_radius_top=0.11, hindleg_radius_bottom=0.055,
        foreleg_offset=0.6, hindleg_offset=0.45, leg_spacing=0.30,
        tail_length=0.8, tail_radius=0.05, tail_angle=60.0,
        torso_blend=0.25, limb_blend=0.06),
    "dog": QuadrupedParameters(
        torso_length=0.62, chest_length=0.36, chest_height=0.26, chest_width=0.22,
        abdomen_length=0.36, abdomen_height=0.20, abdomen_width=0.21,
        neck_length=0.14, neck_radius=0.065, neck_head_radius=0.05, neck_angle=45.0,
        head_length=0.24, head_height=0.11, head_width=0.11, head_angle=-10.0,
        foreleg_length=0.34, hindleg_length=0.36,
        foreleg_radius_top=0.03, foreleg_radius_bottom=0.018,
        hindleg_radius_top=0.035, hindleg_radius_bottom=0.018,
        foreleg_offset=0.6, hindleg_offset=0.45, leg_spacing=0.10,
        tail_length=0.25, tail_radius=0.02, tail_angle=-20.0,
        torso_blend=0.08, limb_blend=0.018),
}


def _jitter(parameters: QuadrupedParameters, seed: int) -> QuadrupedParameters:
    """Seed 0: the parameters as given. Other seeds: every length times a factor in [0.92, 1.08],
    except that leg spacing and top leg radii grow no more than the body's width, and the limb
    blend no more than the radii it rounds (so a variant still fits together)."""
    if seed == 0:
        return parameters
    rng = np.random.default_rng(seed)
    factor = {name: rng.uniform(0.92, 1.08) for name in _LENGTH_FIELDS}
    # keep what must fit inside something else fitting: legs under the body, blends under radii
    width = min(factor["chest_width"], factor["abdomen_width"])
    for name in ("leg_spacing", "foreleg_radius_top", "hindleg_radius_top"):
        factor[name] = min(factor[name], width)
    factor["limb_blend"] = min(factor["limb_blend"], factor["foreleg_radius_top"],
                               factor["hindleg_radius_top"], factor["tail_radius"])
    values = parameters.as_dict()
    for name, f in factor.items():
        values[name] = float(values[name] * f)
    return QuadrupedParameters(**values)


# --------------------------------------------------------------------------------------------
# Signed distance functions (negative inside)
# --------------------------------------------------------------------------------------------

def ellipsoid_distance(points: np.ndarray, centre: np.ndarray, radii: np.ndarray,
                       axes: np.ndarray | None = None) -> np.ndarray:
    """Approximate signed distance to an ellipsoid (exact on its surface and along its axes).

    d = k0 (k0 − 1) / k1 with k0 = |q / r|, k1 = |q / r²|, q the point in the ellipsoid's frame
    (columns of ``axes``); Quilez's bound, good near the surface, which is all the blend needs.
    """
    local = points - centre
    if axes is not None:
        local = local @ axes
    k0 = np.linalg.norm(local / radii, axis=-1)
    k1 = np.linalg.norm(local / (radii * radii), axis=-1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-300)


def round_cone_distance(points: np.ndarray, start: np.ndarray, end: np.ndarray,
                        start_radius: float, end_radius: float) -> np.ndarray:
    """Exact signed distance to a tapered capsule: the convex hull of two spheres (Quilez)."""
    axis = end - start
    l2 = float(axis @ axis)
    rr = start_radius - end_radius
    a2 = l2 - rr * rr
    il2 = 1.0 / l2
    pa = points - start
    y = pa @ axis
    z = y - l2
    perpendicular = pa * l2 - np.outer(y, axis)
    x2 = np.einsum("ij,ij->i", perpendicular, perpendicular)
    y2 = y * y * l2
    z2 = z * z * l2
    k = math.copysign(1.0, rr) * rr * rr * x2 if rr != 0 else np.zeros_like(x2)
    near_end = np.sign(z) * a2 * z2 > k
    near_start = np.sign(y) * a2 * y2 < k
    side = (np.sqrt(np.maximum(x2 * a2 * il2, 0.0)) + y * rr) * il2 - start_radius
    return np.where(near_end, np.sqrt(x2 + z2) * il2 - end_radius,
                    np.where(near_start, np.sqrt(x2 + y2) * il2 - start_radius, side))


def smooth_union(a: np.ndarray, b: np.ndarray, blend: float) -> np.ndarray:
    """Polynomial smooth minimum: h = clamp(½ + ½(b − a)/k), mix(b, a, h) − k h (1 − h).

    Equal to min(a, b) wherever |a − b| ≥ k; otherwise up to k/4 lower (the fillet).
    """
    h = np.clip(0.5 + 0.5 * (b - a) / blend, 0.0, 1.0)
    return b + (a - b) * h - blend * h * (1.0 - h)


@dataclass(frozen=True)
class _Primitive:
    name: str
    distance: Callable[[np.ndarray], np.ndarray]
    lower: np.ndarray          # bounding box of the primitive itself
    upper: np.ndarray
    blend: float               # smooth-union radius with everything before it


@dataclass(frozen=True)
class HalfSpace:
    """The points p with normal · p ≤ offset. All cut normals lie in the XY plane."""

    normal: np.ndarray
    offset: float

    def contains(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal <= self.offset


def _below(normal, point) -> HalfSpace:
    normal = np.asarray(normal, dtype=float)
    return HalfSpace(normal, float(normal @ np.asarray(point, dtype=float)))


def _beyond(normal, point) -> HalfSpace:
    normal = -np.asarray(normal, dtype=float)
    return HalfSpace(normal, float(normal @ np.asarray(point, dtype=float)))


@dataclass(frozen=True)
class CutPlane:
    """One planar region boundary: the plane through ``point`` with unit ``normal``."""

    name: str
    point: np.ndarray
    normal: np.ndarray

    def as_dict(self) -> dict:
        return {"name": self.name, "point": [float(v) for v in self.point],
                "normal": [float(v) for v in self.normal]}


@dataclass(frozen=True)
class _Layout:
    parameters: QuadrupedParameters
    primitives: tuple[_Primitive, ...]
    cuts: tuple[CutPlane, ...]
    cells: dict[str, tuple[tuple[HalfSpace, ...], ...]]   # region -> disjoint convex cells
    leg_axes: dict[str, tuple[np.ndarray, ...]]           # region -> (x, z) of each leg axis
    leg_cut_height: dict[str, float]
    leg_reach: dict[str, float]                           # horizontal reach of a leg below its cut
    leg_cell_bound: dict[str, float]                      # x_fore_back, x_hind_front
    split_x: float
    thinnest_radius: float

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        field_ = None
        for primitive in self.primitives:
            d = primitive.distance(points)
            field_ = d if field_ is None else smooth_union(field_, d, primitive.blend)
        return field_

    @property
    def lower(self) -> np.ndarray:
        return np.min([p.lower for p in self.primitives], axis=0)

    @property
    def upper(self) -> np.ndarray:
        return np.max([p.upper for p in self.primitives], axis=0)


def _unit(angle_degrees: float) -> np.ndarray:
    a = math.radians(angle_degrees)
    return np.array([math.cos(a), math.sin(a), 0.0])


def _ellipsoid_primitive(name, centre, radii, blend, axes=None) -> _Primitive:
    centre = np.asarray(centre, float)
    radii = np.asarray(radii, float)
    if axes is None:
        extent = radii
    else:  # half extents of the rotated ellipsoid's bounding box
        extent = np.sqrt((axes * axes) @ (radii * radii))
    return _Primitive(name, lambda p: ellipsoid_distance(p, centre, radii, axes),
                      centre - extent, centre + extent, blend)


def _cone_primitive(name, start, end, start_radius, end_radius, blend) -> _Primitive:
    start = np.asarray(start, float)
    end = np.asarray(end, float)
    r = max(start_radius, end_radius)
    return _Primitive(name, lambda p: round_cone_distance(p, start, end, start_radius, end_radius),
                      np.minimum(start, end) - r, np.maximum(start, end) + r, blend)


SADDLE_GRID = 8       # grid points per top leg radius in the slices that find a leg's saddle


def leg_saddle_height(solid: Callable[[np.ndarray], np.ndarray], torso: Callable[[np.ndarray], np.ndarray],
                      x_leg: float, z_leg: float, radius: float, top: float, box) -> tuple[float, float]:
    """Height of a leg's saddle (armpit or groin): the lowest horizontal slice of the solid in
    which the leg's own piece (the slice's connected part around the leg axis at (x_leg, z_leg))
    reaches the torso (a point inside the torso's own ellipsoids), the other leg of the pair
    (at (x_leg, −z_leg)) or the edge of ``box`` = (x_min, x_max, |z|_max), which lies several leg
    radii away. Below it the leg hangs free: every slice of it is its own piece.

    Bisection on the height, each slice sampled on a grid of spacing radius / SADDLE_GRID;
    accurate to about that spacing times the slope of the fillet. Returns (height, reach): the
    largest horizontal distance from the leg axis of the leg's piece just below the saddle (plus
    one grid spacing), which separates the leg from belly hanging lower than the saddle.
    """
    from scipy import ndimage

    spacing = radius / SADDLE_GRID
    xs = np.arange(box[0], box[1] + spacing, spacing)
    zs = np.arange(-box[2], box[2] + spacing, spacing)
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    leg = (int(np.argmin(np.abs(xs - x_leg))), int(np.argmin(np.abs(zs - z_leg))))
    other = (leg[0], int(np.argmin(np.abs(zs + z_leg))))

    def leg_piece(y: float):
        """The leg's piece of the slice at height y and whether it is joined to something."""
        points = np.column_stack([gx.ravel(), np.full(gx.size, y), gz.ravel()])
        inside = (solid(points) <= 0).reshape(gx.shape)
        parts, _ = ndimage.label(inside)
        mine = parts[leg]
        if mine == 0:
            return None, False
        piece = parts == mine
        edge = piece[0].any() or piece[-1].any() or piece[:, 0].any() or piece[:, -1].any()
        return piece, bool(edge or piece[other] or (piece & (torso(points) <= 0).reshape(gx.shape)).any())

    low, high = radius, top
    if leg_piece(low)[1] or not leg_piece(high)[1]:
        raise QuadrupedParameterError("a leg does not hang free below the body: check the leg and torso sizes")
    while high - low > 1e-3 * radius:
        middle = 0.5 * (low + high)
        if leg_piece(middle)[1]:
            high = middle
        else:
            low = middle
    piece, _ = leg_piece(low)
    reach = float(np.hypot(gx[piece] - x_leg, gz[piece] - z_leg).max()) + spacing
    return float(low), reach


def _layout(p: QuadrupedParameters) -> _Layout:
    """Place the primitives and the cut planes; raise if the parameters make no animal."""
    for f in dataclasses.fields(p):
        value = getattr(p, f.name)
        if not math.isfinite(value):
            raise QuadrupedParameterError(f"quadruped parameter {f.name} must be finite, got {value}")
        if f.name in _LENGTH_FIELDS and f.name not in ("snout_length", "snout_radius", "horn_length", "horn_radius") \
                and value <= 0:
            raise QuadrupedParameterError(f"quadruped parameter {f.name} must be positive, got {value}")
    if p.snout_length < 0 or p.snout_radius < 0:
        raise QuadrupedParameterError("snout_length and snout_radius must be ≥ 0")
    if p.horn_length < 0 or p.horn_radius < 0 or (p.horn_length > 0) != (p.horn_radius > 0):
        raise QuadrupedParameterError("horn_length and horn_radius must both be > 0 (horns) or both 0 (none)")

    chest_semi = np.array([p.chest_length, p.chest_height, p.chest_width]) / 2
    abdomen_semi = np.array([p.abdomen_length, p.abdomen_height, p.abdomen_width]) / 2
    centre_distance = p.torso_length - chest_semi[0] - abdomen_semi[0]
    if not 0 < centre_distance < chest_semi[0] + abdomen_semi[0]:
        raise QuadrupedParameterError(
            "torso_length must exceed half the chest plus half the abdomen length and stay below their sum")
    x_chest, x_abdomen = centre_distance / 2, -centre_distance / 2
    x_fore = x_chest + p.foreleg_offset * chest_semi[0]
    x_hind = x_abdomen - p.hindleg_offset * abdomen_semi[0]
    z_leg = p.leg_spacing / 2

    def underside_depth(semi, dx):   # depth of the ellipsoid's underside below its centre
        s = 1 - (dx / semi[0]) ** 2 - (z_leg / semi[2]) ** 2
        return semi[1] * math.sqrt(s) if s > 0 else -1.0

    fore_depth = underside_depth(chest_semi, x_fore - x_chest)
    hind_depth = underside_depth(abdomen_semi, x_hind - x_abdomen)
    if fore_depth < 0.3 * chest_semi[1] or hind_depth < 0.3 * abdomen_semi[1]:
        raise QuadrupedParameterError("legs stand outside the torso: reduce leg_spacing or the leg offsets")
    if z_leg + max(p.foreleg_radius_top, p.hindleg_radius_top) >= 0.95 * min(chest_semi[2], abdomen_semi[2]):
        raise QuadrupedParameterError("legs are wider apart than the body: reduce leg_spacing or leg radii")
    y_chest = p.foreleg_length + fore_depth
    y_abdomen = p.hindleg_length + hind_depth
    chest_centre = np.array([x_chest, y_chest, 0.0])
    abdomen_centre = np.array([x_abdomen, y_abdomen, 0.0])

    k_torso, k_limb = p.torso_blend, p.limb_blend
    thinnest = min(p.foreleg_radius_bottom, p.hindleg_radius_bottom, 0.55 * p.tail_radius, p.neck_head_radius,
                   min(p.head_length, p.head_height, p.head_width) / 2)
    if p.snout_length > 0:
        thinnest = min(thinnest, 0.6 * p.snout_radius)
    if p.horn_length > 0:
        thinnest = min(thinnest, 0.35 * p.horn_radius)
    if k_limb >= 0.9 * min(p.foreleg_radius_top, p.hindleg_radius_top, p.tail_radius * 1.5):
        raise QuadrupedParameterError("limb_blend must be smaller than the leg and tail radii")

    chest = _ellipsoid_primitive("chest", chest_centre, chest_semi, 0.0)
    abdomen = _ellipsoid_primitive("abdomen", abdomen_centre, abdomen_semi, k_torso)

    def torso_distance(points):
        return smooth_union(chest.distance(points), abdomen.distance(points), k_torso)

    # Neck leaves the chest where the chest's outward normal is the neck direction u:
    # on an ellipsoid with semi-axes A that point is c + A² u / |A u|; its tangent plane ⟂ u.
    u = _unit(p.neck_angle)
    neck_base = chest_centre + chest_semi ** 2 * u / np.linalg.norm(chest_semi * u)
    neck_end = neck_base + p.neck_length * u
    neck = _cone_primitive("neck", neck_base - u * p.neck_radius, neck_end,
                           p.neck_radius, p.neck_head_radius, k_limb)
    v = _unit(p.head_angle)
    head_axes = np.column_stack([v, np.cross([0.0, 0.0, 1.0], v), [0.0, 0.0, 1.0]])
    head_semi = np.array([p.head_length, p.head_height, p.head_width]) / 2
    head_centre = neck_end + 0.6 * head_semi[0] * v + 0.5 * head_semi[1] * u
    head = _ellipsoid_primitive("head", head_centre, head_semi, k_limb, head_axes)
    primitives = [chest, abdomen, neck, head]
    if p.snout_length > 0 and p.snout_radius > 0:
        w = _unit(p.snout_angle)
        snout_root = head_centre + 0.75 * head_semi[0] * v
        primitives.append(_cone_primitive("snout", snout_root, snout_root + p.snout_length * w,
                                          p.snout_radius, 0.6 * p.snout_radius, k_limb))

    primitives.extend(_horn_primitives(p, head_centre, head_semi, head_axes, k_limb))

    legs: dict[str, tuple[np.ndarray, ...]] = {}
    for region, x, top_y, r_top, r_bottom in (
            ("forelimbs", x_fore, y_chest, p.foreleg_radius_top, p.foreleg_radius_bottom),
            ("hindlimbs", x_hind, y_abdomen, p.hindleg_radius_top, p.hindleg_radius_bottom)):
        legs[region] = (np.array([x, z_leg]), np.array([x, -z_leg]))
        for side, z in (("left", z_leg), ("right", -z_leg)):
            primitives.append(_cone_primitive(f"{region}-{side}", [x, r_bottom, z], [x, top_y, z],
                                              r_bottom, r_top, k_limb))

    # Tail: leaves the rear of the abdomen; its cut is the tangent plane at the rear-most point.
    x_tail = x_abdomen - abdomen_semi[0]
    t = _unit(180.0 + p.tail_angle)   # backwards, tail_angle below horizontal
    tail_root = np.array([x_tail + 1.5 * p.tail_radius, y_abdomen + 0.3 * abdomen_semi[1], 0.0])
    tail_tip = tail_root + t * (p.tail_length + 1.5 * p.tail_radius)
    primitives.append(_cone_primitive("tail", tail_root, tail_tip, p.tail_radius,
                                      0.55 * p.tail_radius, k_limb))
    # the tail cut ⟂ t at distance s along the axis, where the section (radius ≤ r, reaching
    # r sin γ forwards) lies behind x_tail by k: x_root − s cos γ + r sin γ ≤ x_tail − k
    gamma = math.radians(p.tail_angle)
    tail_cut_distance = (tail_root[0] - x_tail + p.tail_radius * abs(math.sin(gamma)) + k_limb) / math.cos(gamma) \
        if math.cos(gamma) > 1e-6 else math.inf
    if not tail_cut_distance <= 0.7 * (p.tail_length + 1.5 * p.tail_radius):
        raise QuadrupedParameterError("the tail hangs too steeply to be cut off cleanly: lower tail_angle")
    tail_cut = tail_root + tail_cut_distance * t
    if tail_tip[1] - 0.55 * p.tail_radius <= 0.05 * p.hindleg_length:
        raise QuadrupedParameterError("the tail reaches the ground: shorten it or lower tail_angle")

    # Leg cells: in front of / behind the legs and their fillets.
    fore_back = x_fore - (p.foreleg_radius_top + 2.5 * k_limb)
    hind_front = x_hind + (p.hindleg_radius_top + 2.5 * k_limb)
    split_x = 0.5 * (x_chest + x_abdomen)
    if not hind_front < split_x < fore_back:
        raise QuadrupedParameterError("fore and hind legs are too close together: increase torso_length or leg offsets")
    if x_hind - p.hindleg_radius_top - 2.5 * k_limb <= x_tail:
        raise QuadrupedParameterError("hind legs stand behind the rump: reduce hindleg_offset")

    # Leg cuts: at the leg's saddle (armpit / groin), docs/segmentation.md "Where a leg starts".
    field_so_far = tuple(primitives)

    def solid(points):
        value = None
        for primitive in field_so_far:
            d = primitive.distance(points)
            value = d if value is None else smooth_union(value, d, primitive.blend)
        return value

    width = max(chest_semi[2], abdomen_semi[2]) + k_torso

    def saddle(x_leg, radius, top):
        reach = 4 * radius + 2 * k_limb
        return leg_saddle_height(solid, torso_distance, x_leg, z_leg, radius, top,
                                 (x_leg - reach, x_leg + reach, width))

    y_fore, fore_reach = saddle(x_fore, p.foreleg_radius_top, y_chest)
    y_hind, hind_reach = saddle(x_hind, p.hindleg_radius_top, y_abdomen)
    if y_fore < 0.4 * p.foreleg_length or y_hind < 0.4 * p.hindleg_length:
        raise QuadrupedParameterError("the belly hangs too low between the legs: shorten the torso heights")

    x_axis, y_axis = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    cuts = (
        CutPlane("tail", tail_cut, t),
        CutPlane("tail-rump", np.array([x_tail, 0, 0]), -x_axis),
        CutPlane("head", neck_end, u),
        CutPlane("neck", neck_base, u),
        CutPlane("forelimbs", np.array([0, y_fore, 0]), -y_axis),
        CutPlane("forelimbs-back", np.array([fore_back, 0, 0]), x_axis),
        CutPlane("hindlimbs", np.array([0, y_hind, 0]), -y_axis),
        CutPlane("hindlimbs-front", np.array([hind_front, 0, 0]), -x_axis),
        CutPlane("chest", np.array([split_x, 0, 0]), x_axis),
    )
    # Disjoint convex cells of each region (intersections of half-spaces), in precedence order.
    not_tail = _beyond(x_axis, [x_tail, 0, 0])
    not_head = _below(u, neck_end)
    not_neck = _below(u, neck_base)
    trunk = (not_tail, not_head, not_neck)
    cells = {
        "tail": ((_below(x_axis, [x_tail, 0, 0]), _beyond(t, tail_cut)),),
        "head": ((not_tail, _beyond(u, neck_end)),),
        "neck": ((not_tail, not_head, _beyond(u, neck_base)),),
        "forelimbs": (trunk + (_below(y_axis, [0, y_fore, 0]), _beyond(x_axis, [fore_back, 0, 0])),),
        "hindlimbs": (trunk + (_below(y_axis, [0, y_hind, 0]), _below(x_axis, [hind_front, 0, 0])),),
        "chest": (trunk + (_beyond(x_axis, [split_x, 0, 0]), _beyond(y_axis, [0, y_fore, 0])),
                  trunk + (_beyond(x_axis, [split_x, 0, 0]), _below(x_axis, [fore_back, 0, 0]),
                           _below(y_axis, [0, y_fore, 0]))),
        "abdomen": (trunk + (_below(x_axis, [split_x, 0, 0]), _beyond(y_axis, [0, y_hind, 0])),
                    trunk + (_below(x_axis, [split_x, 0, 0]), _beyond(x_axis, [hind_front, 0, 0]),
                             _below(y_axis, [0, y_hind, 0])),
                    (_below(x_axis, [x_tail, 0, 0]), _below(t, tail_cut))),   # the tail's root
    }
    return _Layout(p, tuple(primitives), cuts, cells, legs,
                   {"forelimbs": y_fore, "hindlimbs": y_hind}, {"forelimbs": fore_reach, "hindlimbs": hind_reach},
                   {"forelimbs": fore_back, "hindlimbs": hind_front}, split_x, thinnest)


def _horn_primitives(p: QuadrupedParameters, head_centre, head_semi, head_axes, blend) -> list[_Primitive]:
    """Two horns (issue 18): tapered capsules rising from the top of the head, tilted outwards by
    ``horn_angle``, their roots sunk a root radius into the head so they join it smoothly."""
    if p.horn_length <= 0:
        return []
    horns = []
    up, across = head_axes[:, 1], head_axes[:, 2]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        on_head = head_centre + 0.75 * head_semi[1] * up + sign * 0.45 * head_semi[2] * across - 0.15 * head_semi[0] * head_axes[:, 0]
        tilt = math.radians(p.horn_angle)
        direction = math.cos(tilt) * up + sign * math.sin(tilt) * across
        root = on_head - p.horn_radius * direction
        horns.append(_cone_primitive(f"horn-{side}", root, on_head + p.horn_length * direction,
                                     p.horn_radius, 0.35 * p.horn_radius, blend))
    return horns


def horn_vertices(generated: "GeneratedQuadruped") -> list[np.ndarray]:
    """Vertex indices of each horn of a generated animal (issue 18's test of small features): the
    vertices nearer the horn's surface than the head's, beyond the blend (empty without horns)."""
    layout = _layout(generated.parameters)
    by_name = {primitive.name: primitive for primitive in layout.primitives}
    if "horn-left" not in by_name:
        return []
    head = by_name["head"].distance(generated.vertices)
    blend = generated.parameters.limb_blend
    return [np.flatnonzero((by_name[name].distance(generated.vertices) < 0.25 * blend) & (head > blend))
            for name in ("horn-left", "horn-right")]


def label_points(layout: _Layout, points: np.ndarray) -> np.ndarray:
    """Region index (into REGION_NAMES) of each point, by the planar cuts."""
    labels = np.full(len(points), -1, dtype=np.int64)
    for region in ("tail", "head", "neck", "forelimbs", "hindlimbs", "chest", "abdomen"):
        inside = np.zeros(len(points), dtype=bool)
        for cell in layout.cells[region]:
            in_cell = np.ones(len(points), dtype=bool)
            for half_space in cell:
                in_cell &= half_space.contains(points)
            inside |= in_cell
        labels[(labels < 0) & inside] = REGION_NAMES.index(region)
    return labels


# --------------------------------------------------------------------------------------------
# Polygonisation
# --------------------------------------------------------------------------------------------

def _sample_field(layout: _Layout, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The smooth-union field on a regular grid; each primitive evaluated only near itself.

    Outside a primitive's box grown by 2k (k its blend) its distance exceeds 2k, so wherever the
    field is within k of zero it cannot change the smooth union: the zero set is exact.
    """
    margin = 3 * spacing
    origin = layout.lower - margin
    shape = np.ceil((layout.upper + margin - origin) / spacing).astype(int) + 1
    axes = [origin[i] + spacing * np.arange(shape[i]) for i in range(3)]
    big = float(np.max(layout.upper - layout.lower)) * 10
    values = np.full(tuple(shape), big)
    for primitive in layout.primitives:
        grow = 2 * primitive.blend + 2 * spacing
        lo = np.maximum(np.floor((primitive.lower - grow - origin) / spacing).astype(int), 0)
        hi = np.minimum(np.ceil((primitive.upper + grow - origin) / spacing).astype(int) + 1, shape)
        gx, gy, gz = np.meshgrid(axes[0][lo[0]:hi[0]], axes[1][lo[1]:hi[1]], axes[2][lo[2]:hi[2]],
                                 indexing="ij")
        points = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
        d = primitive.distance(points).reshape(gx.shape)
        block = values[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        if primitive.blend > 0:
            block[...] = smooth_union(block, d, primitive.blend)
        else:
            block[...] = np.minimum(block, d)
    # keep grid values off the level itself, so marching cubes makes no zero-length edges
    tiny = 1e-6 * spacing
    values[np.abs(values) < tiny] = tiny
    return values, origin


def _marching_cubes(layout: _Layout, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    values, origin = _sample_field(layout, spacing)
    vertices, faces, _, _ = marching_cubes(values, level=0.0, spacing=(spacing,) * 3)
    vertices = vertices + origin
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if mesh.volume < 0:
        mesh.invert()
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _project(layout: _Layout, points: np.ndarray, step: float, iterations: int = 4) -> np.ndarray:
    """Newton steps p ← p − f ∇f / |∇f|² onto the zero set of the field (finite differences)."""
    offsets = np.eye(3) * step
    for _ in range(iterations):
        value = layout.signed_distance(points)
        gradient = np.column_stack([(layout.signed_distance(points + o) - value) / step for o in offsets])
        norm2 = np.maximum(np.einsum("ij,ij->i", gradient, gradient), 1e-12)
        points = points - (value / norm2)[:, None] * gradient
    return points


def _relax(layout: _Layout, vertices: np.ndarray, faces: np.ndarray, spacing: float,
           iterations: int) -> np.ndarray:
    """Tangential Laplacian relaxation, each step followed by projection onto the surface."""
    adjacency = vertex_adjacency(faces, len(vertices))
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    for _ in range(iterations):
        average = (adjacency @ vertices) / degree[:, None]
        normals = vertex_normals(vertices, faces)
        move = average - vertices
        move -= np.einsum("ij,ij->i", move, normals)[:, None] * normals
        vertices = _project(layout, vertices + 0.5 * move, 1e-3 * spacing, iterations=1)
    return _project(layout, vertices, 1e-3 * spacing, iterations=3)


# --------------------------------------------------------------------------------------------
# Exact measurement on the polygonised solid
# --------------------------------------------------------------------------------------------

def _clip_triangles(triangles: np.ndarray, half_space: HalfSpace) -> np.ndarray:
    """The parts of oriented triangles (m, 3, 3) inside a half-space, as oriented triangles."""
    s = triangles @ half_space.normal - half_space.offset
    inside = s <= 0
    count = inside.sum(axis=1)
    result = [triangles[count == 3]]

    def rolled(mask, first):
        tris, values, flags = triangles[mask], s[mask], inside[mask]
        start = np.argmax(flags if first else ~flags, axis=1)
        order = (start[:, None] + np.arange(3)) % 3
        rows = np.arange(len(tris))[:, None]
        return tris[rows, order], values[rows, order]

    def cut(p, q, sp, sq):   # point where the edge p→q crosses s = 0
        return p + (q - p) * (sp / (sp - sq))[:, None]

    if np.any(count == 1):   # A inside, B, C outside: triangle (A, AB*, AC*)
        tris, values = rolled(count == 1, first=True)
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab = cut(a, b, values[:, 0], values[:, 1])
        ac = cut(a, c, values[:, 0], values[:, 2])
        result.append(np.stack([a, ab, ac], axis=1))
    if np.any(count == 2):   # C outside then A, B inside (cyclic C, A, B): quad CA*, A, B, BC*
        tris, values = rolled(count == 2, first=False)
        c, a, b = tris[:, 0], tris[:, 1], tris[:, 2]
        ca = cut(a, c, values[:, 1], values[:, 0])
        bc = cut(b, c, values[:, 2], values[:, 0])
        result.append(np.stack([ca, a, b], axis=1))
        result.append(np.stack([ca, b, bc], axis=1))
    return np.concatenate(result) if result else np.zeros((0, 3, 3))


def clipped_volume(vertices: np.ndarray, faces: np.ndarray, cell: tuple[HalfSpace, ...]) -> float:
    """Exact volume of (closed mesh's solid) ∩ (intersection of half-spaces with normal_z = 0,
    or the half-spaces z ≤ 0 / z ≥ 0).

    Divergence theorem with F = (0, 0, z): V = ∮ z n_z dA. Every cap the half-spaces would add
    has n_z = 0 (or lies in z = 0, where F = 0) and contributes nothing, so only the clipped
    surface is integrated; per triangle
    ∫ z n_z dA = z̄ · ½((b − a) × (c − a))_z.
    """
    triangles = vertices[faces]
    for half_space in cell:
        n = half_space.normal
        if abs(n[2]) > 1e-12 and not (abs(n[0]) < 1e-12 and abs(n[1]) < 1e-12 and half_space.offset == 0):
            raise ValueError("clipped_volume needs half-spaces whose normals have no z component (or z = 0)")
        triangles = _clip_triangles(triangles, half_space)
        if len(triangles) == 0:
            return 0.0
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    area_z = 0.5 * np.cross(b - a, c - a)[:, 2]
    return float(np.sum((a[:, 2] + b[:, 2] + c[:, 2]) / 3.0 * area_z))


# --------------------------------------------------------------------------------------------
# Truth
# --------------------------------------------------------------------------------------------

@dataclass
class QuadrupedTruth:
    """True measurements of a generated quadruped, measured on its polygonised mesh.

    - ``leg_length[region]``: per leg, the leg region's extent along its (vertical) axis, from
      the region's cut plane down to the lowest vertex of the foot; mean of the two legs.
    - ``leg_radius[region]``: equivalent radius √(A/π) of the horizontal (axis-normal) section
      of the mesh at mid-length of the leg region, with A the mean section area over the middle
      tenth of the length (the exact volume of the leg between the planes at fractions 0.45 and
      0.55, divided by their distance): a single slice of a mesh whose triangles are long
      compared with the leg's radius wobbles by a few percent with the height of the cut,
      the band average does not. Mean of the two legs. :meth:`leg_radius_at` gives it at any
      fraction of the length.
    - ``region_volume[region]``: exact volume of the mesh's solid on that region's side of the
      cuts; they add up to ``body_volume``, the volume enclosed by the mesh.
    - ``neck_length``: distance between the neck's two parallel cut planes (along the neck axis).
    - ``chest_girth``: perimeter of the mesh's vertical (X-normal) section of the torso where it
      is largest behind the forelimbs: for x between the chest/abdomen split and the back of the
      forelimb region. ``chest_girth_x`` is where; ``torso_height`` the section's height there.
    - ``height``: max − min y of the mesh; ``cuts``: the planes that define the regions.
    """

    leg_length: dict[str, float]
    leg_radius: dict[str, float]
    region_volume: dict[str, float]
    body_volume: float
    neck_length: float
    chest_girth: float
    chest_girth_x: float
    torso_height: float
    height: float
    cuts: tuple[CutPlane, ...]
    leg_cut_height: dict[str, float]
    _vertices: np.ndarray = field(repr=False, compare=False, default=None)
    _faces: np.ndarray = field(repr=False, compare=False, default=None)
    _leg_cells: dict = field(repr=False, compare=False, default=None)
    _leg_lengths: dict = field(repr=False, compare=False, default=None)

    def leg_radius_at(self, region: str, fraction: float) -> float:
        """Equivalent radius √(A/π) of the leg section at ``fraction`` of the leg region's length,
        0 at the cut plane (top), 1 at the foot tip; A is averaged over fraction ± 0.05.
        Mean of the two legs of ``region``."""
        if region not in LIMB_REGIONS:
            raise KeyError(f"{region!r} is not a limb region ({', '.join(LIMB_REGIONS)})")
        if not LEG_BAND <= fraction <= 1.0 - LEG_BAND:
            raise ValueError(f"fraction must be in [{LEG_BAND}, {1 - LEG_BAND}]: 0 is the cut, 1 the foot tip")
        cut = self.leg_cut_height[region]
        return float(np.mean([
            _leg_band_radius(self._vertices, leg_faces, cut - (fraction + LEG_BAND) * length,
                             cut - (fraction - LEG_BAND) * length)
            for leg_faces, length in zip(self._leg_cells[region], self._leg_lengths[region])]))

    def as_dict(self) -> dict:
        """JSON-ready summary (what ``allorules generate --truth`` writes)."""
        profile = {region: {f"{f:.2f}": self.leg_radius_at(region, f) for f in (0.1, 0.25, 0.5, 0.75, 0.9)}
                   for region in LIMB_REGIONS}
        return {
            "format": "allorules-quadruped-truth", "version": 1,
            "leg_length": self.leg_length, "leg_radius": self.leg_radius,
            "leg_radius_profile": profile,
            "region_volume": self.region_volume, "body_volume": self.body_volume,
            "neck_length": self.neck_length, "chest_girth": self.chest_girth,
            "chest_girth_x": self.chest_girth_x, "torso_height": self.torso_height,
            "height": self.height, "leg_cut_height": self.leg_cut_height,
            "cuts": [c.as_dict() for c in self.cuts],
        }


def volume_below(vertices: np.ndarray, faces: np.ndarray, height: float) -> float:
    """Exact volume of the solid below y = ``height`` bounded by ``faces``: a piece of a closed
    surface that, clipped at that height, is closed by its planar cap there (one leg).

    Divergence theorem with F = (0, y − height, 0): the cap lies in y = height, where F = 0, so
    only the clipped surface is integrated; per triangle ∫ (y − height) n_y dA =
    (ȳ − height) · ½((b − a) × (c − a))_y.
    """
    triangles = _clip_triangles(vertices[faces], HalfSpace(np.array([0.0, 1.0, 0.0]), height))
    if len(triangles) == 0:
        return 0.0
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    area_y = 0.5 * np.cross(b - a, c - a)[:, 1]
    return float(np.sum(((a[:, 1] + b[:, 1] + c[:, 1]) / 3.0 - height) * area_y))


def _leg_band_radius(vertices, leg_faces, low, high) -> float:
    """√(A/π) with A the mean horizontal section area of one leg between heights low and high."""
    volume = volume_below(vertices, leg_faces, high) - volume_below(vertices, leg_faces, low)
    return math.sqrt(max(volume, 0.0) / (high - low) / math.pi)


def _feet(vertices: np.ndarray, layout: "_Layout", region: str) -> list[int]:
    """The lowest vertex of each leg of ``region``: among the vertices nearer (in x, z) to that
    leg's axis than to any other leg's."""
    axes = np.array([axis for name in LIMB_REGIONS for axis in layout.leg_axes[name]])
    nearest = np.argmin(np.hypot(vertices[:, [0]] - axes[:, 0], vertices[:, [2]] - axes[:, 1]), axis=1)
    feet = []
    for axis in layout.leg_axes[region]:
        index = int(np.flatnonzero((axes == axis).all(axis=1))[0])
        mine = np.flatnonzero(nearest == index)
        feet.append(int(mine[np.argmin(vertices[mine, 1])]))
    return feet


def free_legs(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, layout: "_Layout") -> list:
    """Keep as leg only each foot's own piece below its cut; return the faces of each leg.

    The leg cells (below the saddle height, on the leg's side of the body) also hold pieces of
    belly hanging lower than the saddle between or behind the legs. A leg is the part of its
    cell within the leg's reach of its axis (see :func:`leg_saddle_height`) connected to its
    foot; the rest goes to the chest (forelimb cells) or the abdomen (hindlimb cells). (At the
    saddle the leg and the belly touch, so the polygon mesh may join them just below it: the
    reach, not the mesh's connectivity, separates them.) ``labels`` is changed in place.
    Returns [(region, faces of one leg), ...].
    """
    adjacency = vertex_adjacency(faces, len(vertices))
    pieces = []
    for region, rest in (("forelimbs", "chest"), ("hindlimbs", "abdomen")):
        index = REGION_NAMES.index(region)
        reach = np.min([np.hypot(vertices[:, 0] - axis[0], vertices[:, 2] - axis[1])
                        for axis in layout.leg_axes[region]], axis=0) <= layout.leg_reach[region]
        members = np.flatnonzero((labels == index) & reach)
        _, part = sparse.csgraph.connected_components(adjacency[members][:, members], directed=False)
        kept = np.zeros(len(vertices), dtype=bool)
        position = np.full(len(vertices), -1)
        position[members] = np.arange(len(members))
        for foot in _feet(vertices, layout, region):
            if position[foot] < 0:
                raise QuadrupedParameterError(f"a foot of the {region} lies outside its leg: check the leg sizes")
            mine = members[part == part[position[foot]]]
            if kept[mine].any():
                raise QuadrupedParameterError("two legs touch below their cut: move the legs apart")
            kept[mine] = True
            leg_faces = np.flatnonzero(np.isin(faces, mine).any(axis=1))
            pieces.append((region, faces[leg_faces]))
        labels[(labels == index) & ~kept] = REGION_NAMES.index(rest)
    return pieces


def _torso_section(vertices, faces, x) -> tuple[float, float]:
    start, end, _ = plane_section(vertices, faces, np.array([x, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    perimeter = float(np.linalg.norm(end - start, axis=1).sum())
    ys = np.concatenate([start[:, 1], end[:, 1]])
    return perimeter, float(ys.max() - ys.min()) if len(ys) else 0.0


def _measure_truth(layout: _Layout, vertices: np.ndarray, faces: np.ndarray,
                   labels: np.ndarray, legs: list) -> QuadrupedTruth:
    p = layout.parameters
    leg_length, leg_radius, leg_cells, lengths = {}, {}, {}, {}
    for region in LIMB_REGIONS:
        cut = layout.leg_cut_height[region]
        cells = [leg_faces for name, leg_faces in legs if name == region]
        per_leg = [cut - float(vertices[np.unique(leg_faces), 1].min()) for leg_faces in cells]
        leg_cells[region], lengths[region] = cells, per_leg
        leg_length[region] = float(np.mean(per_leg))
        leg_radius[region] = float(np.mean([
            _leg_band_radius(vertices, leg_faces, cut - (0.5 + LEG_BAND) * length, cut - (0.5 - LEG_BAND) * length)
            for leg_faces, length in zip(cells, per_leg)]))

    region_volume = {region: sum(clipped_volume(vertices, faces, cell) for cell in layout.cells[region])
                     for region in REGION_NAMES}
    # The legs are each foot's own piece below the cut (free_legs); what else their cells hold
    # (belly hanging lower than the saddle) belongs to the chest or abdomen.
    for region, rest in (("forelimbs", "chest"), ("hindlimbs", "abdomen")):
        legs_volume = sum(volume_below(vertices, leg_faces, layout.leg_cut_height[region])
                          for leg_faces in leg_cells[region])
        region_volume[rest] += region_volume[region] - legs_volume
        region_volume[region] = legs_volume
    body_volume = float(trimesh.Trimesh(vertices, faces, process=False).volume)

    # chest girth: largest perimeter of X-normal sections between the split and the forelimbs
    lo, hi = layout.split_x, layout.leg_cell_bound["forelimbs"]
    xs = np.linspace(lo, hi, 25)
    perimeters = [_torso_section(vertices, faces, x)[0] for x in xs]
    best = int(np.argmax(perimeters))
    a, b = xs[max(best - 1, 0)], xs[min(best + 1, len(xs) - 1)]
    golden = (math.sqrt(5) - 1) / 2
    for _ in range(30):   # golden-section search for the maximum in the bracket
        c, d = b - golden * (b - a), a + golden * (b - a)
        if _torso_section(vertices, faces, c)[0] >= _torso_section(vertices, faces, d)[0]:
            b = d
        else:
            a = c
    girth_x = 0.5 * (a + b)
    girth, torso_height = _torso_section(vertices, faces, girth_x)

    truth = QuadrupedTruth(
        leg_length=leg_length, leg_radius=leg_radius, region_volume=region_volume,
        body_volume=body_volume, neck_length=float(p.neck_length), chest_girth=girth,
        chest_girth_x=float(girth_x), torso_height=torso_height,
        height=float(vertices[:, 1].max() - vertices[:, 1].min()), cuts=layout.cuts,
        leg_cut_height=dict(layout.leg_cut_height))
    truth._vertices, truth._faces = vertices, faces
    truth._leg_cells, truth._leg_lengths = leg_cells, lengths
    return truth


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------

@dataclass
class GeneratedQuadruped:
    """A generated animal: closed mesh, per-vertex region labels, parameters and truth."""

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray
    parameters: QuadrupedParameters
    truth: QuadrupedTruth
    preset: str = "custom"
    region_names: tuple[str, ...] = REGION_NAMES
    pose: "object | None" = None        # the quadruped_poses.Pose the vertices were moved into (None: standing)

    def body(self) -> Body:
        """The animal as a :class:`~allorules.body.Body` in the canonical frame (+Y up, +X forward)."""
        return Body(self.vertices.copy(), self.faces.copy(), self.labels.copy(), self.region_names,
                    Frame(up=np.array([0.0, 1.0, 0.0]), forward=np.array([1.0, 0.0, 0.0])))

    def to_trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices.copy(), self.faces.copy(), process=False)

    def labels_document(self) -> dict:
        """The per-vertex labels in the ``allorules-labels`` JSON format (version 1)."""
        return {"format": "allorules-labels", "version": 1, "regions": list(self.region_names),
                "labels": [int(v) for v in self.labels]}


def _spacing_for(area: float, vertices: int) -> float:
    # Marching cubes puts a vertex on every grid edge the surface crosses: about
    # (|n_x| + |n_y| + |n_z|) / h² ≈ 1.5 / h² per unit area, so h ≈ √(1.5 A / N).
    return math.sqrt(1.5 * area / vertices)


def generate_quadruped(preset: str = "horse", vertices: int = 8000, *, seed: int = 0, pose=None,
                       **overrides: float) -> GeneratedQuadruped:
    """Generate a closed, smooth quadruped of about ``vertices`` vertices, with labels and truth.

    ``preset`` names an entry of :data:`PRESETS`; ``overrides`` replace single parameters
    (see :class:`QuadrupedParameters`); ``seed`` ≠ 0 varies every length by up to ±8 %
    (deterministically). The result is watertight, consistently wound, outward, one piece.

    ``pose`` (a name of :data:`allorules.mesh.quadruped_poses.POSES` or a ``Pose``) moves the
    standing animal's vertices like a rig (legs swung and bent, neck, head, tail turned or curled);
    faces and labels stay those of the standing animal, which are the truth in every pose. The
    truth's leg lengths, radii and region volumes are the standing animal's (the legs below their
    saddles move rigidly unless a knee bends); ``body_volume`` and ``height`` are measured on the
    posed mesh.
    """
    if preset not in PRESETS:
        raise QuadrupedParameterError(f"unknown preset {preset!r}; choose one of {', '.join(PRESETS)}")
    vertices = int(vertices)
    if not MIN_VERTICES <= vertices <= MAX_VERTICES:
        raise QuadrupedParameterError(
            f"vertex count must be between {MIN_VERTICES} and {MAX_VERTICES}, got {vertices}")
    parameters = _jitter(PRESETS[preset], int(seed))
    if overrides:
        parameters = parameters.replace(**overrides)
    layout = _layout(parameters)

    # Coarse pass to learn the surface area, then the spacing for the requested count; never
    # coarser than what resolves the thinnest part (decimated down to the count afterwards).
    extent = float(np.max(layout.upper - layout.lower))
    coarse_vertices, coarse_faces = _marching_cubes(layout, min(extent / 60, layout.thinnest_radius))
    area = float(trimesh.Trimesh(coarse_vertices, coarse_faces, process=False).area)
    spacing = min(_spacing_for(area, vertices), layout.thinnest_radius / 1.2)
    for attempt in range(3):
        mesh_vertices, mesh_faces = _marching_cubes(layout, spacing)
        if len(mesh_vertices) > 1.05 * vertices:
            mesh_vertices, mesh_faces = _decimate(
                mesh_vertices, mesh_faces, vertices,
                settle=lambda v, f: _relax(layout, v, f, spacing, iterations=1))
        mesh_vertices = _project(layout, mesh_vertices, 1e-3 * spacing)
        mesh_vertices = _relax(layout, mesh_vertices, mesh_faces, spacing, iterations=8)
        problem = _closed_surface_problem(mesh_vertices, mesh_faces)
        if problem is None:
            break
        spacing /= 1.5    # a part too thin for the grid: resolve it finer, decimate further
    else:
        raise QuadrupedParameterError(
            f"these parameters make no closed one-piece surface ({problem}); thicken the thinnest part")

    labels = label_points(layout, mesh_vertices)
    legs = free_legs(mesh_vertices, mesh_faces, labels, layout)
    truth = _measure_truth(layout, mesh_vertices, mesh_faces, labels, legs)
    if pose is None:
        return GeneratedQuadruped(mesh_vertices, mesh_faces, labels, parameters, truth, preset)
    from allorules.mesh.quadruped_poses import POSES, pose_vertices

    if isinstance(pose, str):
        if pose not in POSES:
            raise QuadrupedParameterError(f"unknown pose {pose!r}; choose one of {', '.join(POSES)}")
        pose = POSES[pose]
    posed = pose_vertices(layout, mesh_vertices, pose, labels, REGION_NAMES)
    truth = dataclasses.replace(truth, body_volume=float(trimesh.Trimesh(posed, mesh_faces, process=False).volume),
                                height=float(np.ptp(posed[:, 1])))
    # (the private fields are copied: leg radius profiles are measured on the standing legs)
    return GeneratedQuadruped(posed, mesh_faces, labels, parameters, truth, preset, pose=pose)


def _flip_free(vertices, faces, incidence, a, b, middle) -> np.ndarray:
    """For each edge (a, b) collapsing to ``middle``: does every surviving face around it keep
    its orientation (its normal turns by less than ~70°)?"""
    normals = face_normals(vertices, faces)
    worst = np.ones(len(a))
    for end in (a, b):
        per_vertex = np.diff(incidence.indptr)[end]
        edge_index = np.repeat(np.arange(len(a)), per_vertex)
        starts = np.repeat(incidence.indptr[end], per_vertex)
        within = np.arange(len(edge_index)) - np.repeat(np.cumsum(per_vertex) - per_vertex, per_vertex)
        face_index = incidence.indices[starts + within]
        tris = faces[face_index]
        moving = (tris == a[edge_index, None]) | (tris == b[edge_index, None])
        corners = vertices[tris]
        corners[moving] = middle[np.broadcast_to(edge_index[:, None], tris.shape)[moving]]
        new = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        old = normals[face_index]
        cosine = np.einsum("ij,ij->i", new, old) / np.maximum(
            np.linalg.norm(new, axis=1) * np.linalg.norm(old, axis=1), 1e-300)
        cosine[moving.sum(axis=1) == 2] = 1.0      # the two faces the collapse removes
        np.minimum.at(worst, edge_index, cosine)
    return worst > 0.3


def _closed_surface_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """None if the mesh is closed, consistently wound, outward and one piece; else what is wrong."""
    if not np.isfinite(vertices).all():
        return "non-finite vertices"
    directed = directed_edges(faces)
    keys = directed[:, 0] * len(vertices) + directed[:, 1]
    reverse = directed[:, 1] * len(vertices) + directed[:, 0]
    if len(np.unique(keys)) != len(keys):
        return "inconsistent winding or a non-manifold edge"
    if not np.isin(reverse, keys).all():
        return "holes"
    adjacency = vertex_adjacency(faces, len(vertices))
    parts, _ = sparse.csgraph.connected_components(adjacency, directed=False)
    if parts != 1:
        return f"{parts} separate pieces"
    if enclosed_volume(vertices, faces) <= 0:
        return "inward-facing"
    return None


def _decimate(vertices: np.ndarray, faces: np.ndarray, target: int,
              settle: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
              ) -> tuple[np.ndarray, np.ndarray]:
    """Collapse short edges to their midpoints until about ``target`` vertices remain.

    Collapses run in batches of independent edges: rounds of taking every edge that is the
    shortest candidate within the 1-rings of both its ends, then locking those 1-rings, so no
    two collapses of a batch touch the same faces. An edge (a, b) is collapsed only if a and b
    have exactly two common neighbours (the link condition: the surface stays a closed
    2-manifold), both have more than three neighbours, and no surviving face around it flips.
    ``settle(vertices, faces)`` runs after every batch (relaxation onto the true surface).
    """
    vertices = vertices.copy()
    faces = faces.copy()
    while len(vertices) > target:
        count = len(vertices)
        all_edges = corner_edges(faces)
        keys = np.unique(all_edges[:, 0] * count + all_edges[:, 1])
        a, b = keys // count, keys % count
        adjacency = vertex_adjacency(faces, count)
        degree = np.diff(adjacency.indptr)
        common = np.asarray((adjacency @ adjacency)[a, b]).ravel()
        candidate = (common == 2) & (degree[a] > 3) & (degree[b] > 3)
        lengths = np.linalg.norm(vertices[a] - vertices[b], axis=1)
        rank = np.empty(len(a))
        rank[np.argsort(lengths, kind="stable")] = np.arange(len(a))

        incidence = sparse.csr_matrix(
            (np.ones(faces.size), (faces.ravel(), np.repeat(np.arange(len(faces)), 3))),
            shape=(count, len(faces)))
        locked = np.zeros(count, dtype=bool)
        chosen_parts, needed = [], count - target
        while candidate.any() and needed > 0:
            r = np.where(candidate, rank, np.inf)
            best_at = np.full(count, np.inf)          # shortest candidate edge at each vertex
            np.minimum.at(best_at, a, r)
            np.minimum.at(best_at, b, r)
            best_near = best_at.copy()                # ... and within its 1-ring
            np.minimum.at(best_near, a, best_at[b])
            np.minimum.at(best_near, b, best_at[a])
            chosen = np.flatnonzero(candidate & (r == np.minimum(best_near[a], best_near[b])))
            chosen = chosen[np.argsort(rank[chosen])][:needed]
            safe = _flip_free(vertices, faces, incidence, a[chosen], b[chosen],
                              0.5 * (vertices[a[chosen]] + vertices[b[chosen]]))
            candidate[chosen[~safe]] = False
            chosen = chosen[safe]
            chosen_parts.append(chosen)
            needed -= len(chosen)
            ends = np.zeros(count, dtype=bool)
            ends[a[chosen]] = ends[b[chosen]] = True
            locked |= ends | (adjacency @ ends.astype(float) > 0)
            candidate &= ~(locked[a] | locked[b])
        chosen = np.concatenate(chosen_parts) if chosen_parts else np.zeros(0, dtype=int)
        if len(chosen) == 0:
            break
        middle = 0.5 * (vertices[a[chosen]] + vertices[b[chosen]])
        keep_of = np.arange(count)
        keep_of[b[chosen]] = a[chosen]
        vertices[a[chosen]] = middle
        faces = keep_of[faces]
        faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
        used = np.zeros(count, dtype=bool)
        used[faces.ravel()] = True
        vertices, faces = vertices[used], (np.cumsum(used) - 1)[faces]
        if settle is not None:
            vertices = settle(vertices, faces)
    return vertices, faces
