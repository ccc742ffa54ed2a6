"""The body plan of a quadruped, read from its extremities: which tips are the feet, which pair is
fore and which hind, which end is the head, with a named margin for every decision.

Everything here is intrinsic: geodesic distances on the surface (graph Dijkstra) and the average
geodesic distance (AGD), which a change of pose (a leg swung, a neck turned, a tail curled) leaves
nearly as they were, and which do not depend on the file's orientation, units or vertex order.

1. **Extremities.** Local maxima of the AGD ranked by persistence .
   The body-plan candidates are the prominent ones (persistence ≥ ``CANDIDATE_PERSISTENCE`` of the
   AGD range); the fainter ones (down to ``FEATURE_PERSISTENCE``) can still be features of the head.
2. **Feet** (:func:`_feet_hypotheses`). Any two disjoint pairs of candidates are a hypothesis. On a
   quadruped the four feet make a tree of geodesic distances: the two feet of a pair are closer to
   each other than to the other pair (the four-point condition; the gap is the spine between the
   girdles), the two legs of a pair are mirror images (equal length from the foot to where the pair
   branches, equal AGD), fore and hind legs are of a kind (lengths within a factor), and the feet
   are prominent tips. Each departure costs a penalty of about one where it
   is clearly wrong; a ground plane the four feet stand on (the common case) at the end of legs
   reaching down to it lowers the cost (a horn's tip may lie on such a plane too). Given the body's
   up and forward (``--up`` and ``--forward``: its own frame, feet to back and tail to head), feet
   lie below its centre (ears do not) and the two feet of a pair on either side of its midplane,
   whatever the pose (a nose and an ear beside it do not). The
   cheapest hypothesis wins; ``feet`` confidence is its cost margin over the next one.
3. **Fore or hind** (:func:`_head_tail_cues`). Of the two ends, the head end is decided by
   independent cues, each an evidence in [−1, 1]:
   * ``mass``: surface beyond each girdle (head and neck outweigh a tail and rump);
   * ``features``: tips beyond a girdle that form a mirror pair off the main protrusion (ears,
     horns, eyes) are found on a head, not on a tail;
   * ``thickness``: the end protrusion's girth part-way along it, against the torso's (a tail is
     thin; a head, even a cartoon's, is not);
   * ``presence``: an end with a prominent protrusion against an end with none (tails can be
     missing), graded by the protrusion's persistence (:attr:`End.presence`);
   * ``toes``: on an animal standing on its feet, paws and hooves reach forward of their legs
     (:func:`_toe_reach`); a weak cue (at most ``TOES_CUE``), silent below ``TOES_FAINT`` radii and
     never a veto (a fox's bushy tail is as thick and as heavy as its head: its ears and toes tell
     them apart).
   The sum decides; it is refused when it is small, when fewer than two cues speak for it, or
   when a strong cue disagrees with it.
"""
from __future__ import annotations

import collections
import itertools
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sparse
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from allorules.errors import SegmentationError
from allorules.mesh.geometry import (
    cone_directions,
    enclosed_volume,
    face_areas,
    plane_section_loops,
    ray_hits,
    smoothstep,
    vertex_normals,
)
from allorules.mesh.topology import (
    directed_edges,
    face_adjacency,
    vertex_components,
)

CANDIDATE_PERSISTENCE = 0.08   # of the AGD range: prominent tips (feet, head, tail, big horns)
FEATURE_PERSISTENCE = 0.01     # of the AGD range: faint tips (ears, small horns, the nose behind horns)
MAX_CANDIDATES = 10
MIN_CONTRAST = 0.2             # AGD range / mean below this: a blob or a tube, no limbs (quadrupeds: 0.5–0.9)

# Penalties: each about one where the hypothesis is clearly not a quadruped's feet.
PAIR_LENGTH_MISMATCH = 0.30    # relative difference of the two legs of a pair
PAIR_AGD_MISMATCH = 0.15       # of the AGD range
LEG_RATIO = 0.45               # shortest / longest leg below this costs
SPINE_RATIO = 0.35             # spine between the girdles / mean leg length below this costs
SIDES = 1.0                    # per pair whose feet are not mirrored across the midplane (directions given)
ABOVE = 0.25                   # a foot this share of the body's height above its centre costs one (directions given)
FLAT_LEG = 2.5                 # ring flatness (long / short extent) above this is not a leg's
GROUND_BONUS = 1.0             # four feet on a common supporting plane (standing), legs reaching straight down to it
GROUND_LEG_RATIO = 0.6         # ... in full where the shortest leg is at least this share of the longest
LEG_DOWN = 0.25                # cosine of a leg's direction to straight down below which its foot adds nothing
FEET_MARGIN = 0.25             # cost margin below which the feet are not certain

# Tips of an end.
APPENDAGE_RING = 0.35          # a tip whose ring is thinner than this share of the end's widest is a horn-like tube
FLAT_APPENDAGE = 2.0           # a tip whose ring is flatter than this is an ear-like sheet
FEATURE_RINGS = (0.075, 0.15)  # shares of its reach from the tip at which a feature's flatness is read (ear or horn)
MIRROR_PERSISTENCE = 0.03      # mirror features (ears, horns) are at least this prominent
MIRROR_AGD = 0.05              # of the AGD range
MIRROR_REACH = 0.1             # relative difference of their distances from the girdle
MIRROR_RING = 0.6              # twins unlike in prominence: the thinner one's ring (a tenth of its way to the girdle) is
MIRROR_ACROSS = 0.9            # at least this share of the other's, and they lie straight across the body (cosine)
MIRROR_SPACING = 0.15          # apart by at least this share of their reach (not two toes of one foot)
MUZZLE_SHARE = 0.15            # a tip nearer the main tip than this share of its reach (in space) is its end's, no feature
LEG_FEATURE_REACH = 0.5        # a mirror pair on a "leg" this share of its length or more from its "foot" is a head's
                               # (ears, horns: 0.56-0.95; a short leg's cloven hoof: 0.37-0.45)

# How far an animal sits, from the tilt of the chord between its girdles: level (standing) up to
# the first angle, sitting from the second, smoothstep between (:func:`seated_share`). Shared
# animals standing: 0.3-7.7 deg, the camel 13.1 and the dog 389 20.7 (both labelled right read as
# seated); seated by `repose`: 4-24 (four of eleven at 22.8-24.2); the generated horse and dog
# seated 32-34. A switch at 25 deg read the horse and the horse 387 seated at 24 deg as standing,
# their ears left behind a level fore girdle's plane: refused (head or tail).
SEATED_TILT = (8.0, 20.0)

# Head or tail.
HEAD_TAIL_MARGIN = 0.6         # summed evidence needed
STRONG_CUE = 0.5               # a cue this strong against the sum refuses
AGREEING_CUE = 0.25            # at least two cues this strong must speak for the chosen end
PRESENCE_FAINT = 0.04          # an end's most prominent tip at or below this: nothing sticks out
PRESENCE_FULL = 0.16           # ... at or above this: something surely does (the horse 387's stub of a
                               # tail is 0.075 as it comes, 0.084 Loop-subdivided: a step there refused it)
TOE_RING = 0.25                # a foot's toe is read against its leg's ring this share of the leg up from its tip
TOE_LIMIT = 3.0                # radii: a foot's reach counts up to this (one long foot does not outvote three)
TOE_UPRIGHT = 45.0             # degrees: toes are read only where every leg's lower half stands this near upright
TOES_FAINT = 0.5               # the four feet's mean reach (radii) up to which the toes say nothing
TOES_CLEAR = 1.5               # ... from which they say all they can: TOES_CUE
TOES_CUE = 0.5                 # a weak cue: it can be the second to agree, never refuse the others

BY_HAND = ("a labels file (--segmentation FILE), or allorules segment MESH --patches 24 --png patches.png and a "
           "merge file")
SETTLE = f"settle it with --forward DIR (tail to head), {BY_HAND}"   # head or tail (--forward decides it)


def settle_feet(up, forward) -> str:
    """How a refusal of the feet says to settle it: the feet are chosen with the body's directions
    when both are given (:func:`_feet_hypotheses`; forward alone chooses none), so those, unless
    they were given."""
    if up is not None and forward is not None:
        return f"the directions given did not settle it: give {BY_HAND}"
    return f"settle it with --up DIR and --forward DIR (the body's feet-to-back and tail-to-head), {BY_HAND}"


@dataclass
class BodyPlan:
    """Feet (vertex ids), which end is the head, and how sure each decision is."""

    fore: tuple[int, int]
    hind: tuple[int, int]
    fore_girdle: int                 # vertex where the fore pair branches (under the chest)
    hind_girdle: int
    head_tip: int | None
    tail_tip: int | None
    head_features: tuple[int, ...]   # tips of ears / horns on the head
    distance: dict[int, np.ndarray]  # geodesic distance field of each tip used
    confidence: dict[str, float] = field(default_factory=dict)
    cues: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


@dataclass
class _Tips:
    vertices: np.ndarray
    persistence: np.ndarray      # relative to the AGD range
    agd: np.ndarray              # AGD at the tip, relative: 0 at the AGD minimum, 1 at its maximum
    flatness: np.ndarray         # of the ring around the tip's protrusion: 1 round, more for a flat sheet
    pointing: np.ndarray         # unit direction from that ring's centre to the tip (n, 3)


def geodesic_fields(graph, sources) -> dict[int, np.ndarray]:
    """Graph-geodesic distance from each source vertex, as {vertex: field}."""
    sources = [int(s) for s in sources]
    if not sources:
        return {}
    rows = dijkstra(graph, indices=sources)
    return {s: rows[k] for k, s in enumerate(sources)}


def _gromov(d, x, y, z) -> float:
    """(y|z)_x = ½ (d(x,y) + d(x,z) − d(y,z)): distance from x to where the paths to y and z part."""
    return 0.5 * (d[x][y] + d[x][z] - d[y][z])


@dataclass
class _Hypothesis:
    pairs: tuple[tuple[int, int], tuple[int, int]]   # candidate indices
    cost: float
    terms: dict[str, float]
    legs: tuple[float, float, float, float]
    spine: float


def _mirrored(a: float, b: float) -> float:
    """How nearly two offsets from a plane are mirror images: 1 for a = −b, 0 with one on the
    plane, −1 for a = b."""
    return -a * b / max(0.5 * (a * a + b * b), 1e-30)


def _midplane_offsets(tips: _Tips, vertices, centroid, side) -> np.ndarray:
    """Each tip's offset from the body's midplane (through ``centroid``, across ``side``)."""
    return (vertices[tips.vertices] - centroid) @ side


def _feet_hypotheses(tips: _Tips, d, vertices, mass, up, side=None) -> list[_Hypothesis]:
    """Every pair of disjoint candidate pairs, with its cost (lowest first); ``side``, the body's
    unit side direction when its up and forward are given."""
    n = len(tips.vertices)
    hypotheses = []
    centroid = np.average(vertices, axis=0, weights=mass)
    if side is not None:     # each tip's height above the body's centre (of its height) and offset from its midplane
        above = np.clip((vertices[tips.vertices] - centroid) @ up / np.ptp(vertices @ up) / ABOVE, 0.0, 1.0)
        offset = _midplane_offsets(tips, vertices, centroid, side)
    for four in itertools.combinations(range(n), 4):
        a, b, c, e = four
        pairings = [((a, b), (c, e)), ((a, c), (b, e)), ((a, e), (b, c))]
        sums = [d[p][q] + d[r][s] for (p, q), (r, s) in pairings]
        order = np.argsort(sums)
        (p, q), (r, s) = pairings[order[0]]
        spine = 0.5 * (sums[order[1]] - sums[order[0]])
        legs = (
            np.mean([_gromov(d, p, q, o) for o in (r, s)]),
            np.mean([_gromov(d, q, p, o) for o in (r, s)]),
            np.mean([_gromov(d, r, s, o) for o in (p, q)]),
            np.mean([_gromov(d, s, r, o) for o in (p, q)]),
        )
        legs = tuple(max(value, 1e-9) for value in legs)
        mean_leg = float(np.mean(legs))
        terms = {}
        terms["pair-length"] = max(abs(legs[0] - legs[1]) / (0.5 * (legs[0] + legs[1])),
                                   abs(legs[2] - legs[3]) / (0.5 * (legs[2] + legs[3]))) / PAIR_LENGTH_MISMATCH
        terms["pair-agd"] = max(abs(tips.agd[p] - tips.agd[q]), abs(tips.agd[r] - tips.agd[s])) / PAIR_AGD_MISMATCH
        terms["leg-ratio"] = max(0.0, 1.0 - (min(legs) / max(legs)) / LEG_RATIO)
        terms["spine"] = max(0.0, 1.0 - (spine / mean_leg) / SPINE_RATIO)
        terms["persistence"] = 1.0 - tips.persistence[list(four)].sum() / np.sort(tips.persistence)[::-1][:4].sum()
        # Legs are tubes: a flat sheet (a big ear) is not a leg.
        terms["flat"] = sum(max(0.0, (tips.flatness[x] - FLAT_LEG) / FLAT_LEG) for x in four)
        ground = ground_plane(vertices[tips.vertices[list(four)]], vertices, centroid, up)
        # Feet stand on their ground at the end of legs reaching down to it, and the ground's bonus is
        # as large as they do (each foot's direction from the centre of the ring above it): a dog
        # grazing with long horns also rests on a plane through its horns' tips and its forefeet,
        # its horns reaching forward along it (0.24 of straight down; the feet of every shared
        # animal reach down at 0.56-1.0, a generated dog lying 0.33-0.7, one rearing on its hind
        # feet 0.92-0.94 with its forefeet folded 0.01-0.25).
        # Feet standing on one ground end legs of a kind: the bonus counts in full only where the
        # shortest leg is GROUND_LEG_RATIO of the longest or more (the shared animals' legs, posed or
        # not, 0.62-0.98, the camel's fused fore legs 0.43): a horse leaping, horns and fore feet all
        # reaching forward to one plane, had them for its feet, the horns' "legs" 0.35 of the others.
        terms["ground"] = 0.0
        if ground is not None:
            down = -(tips.pointing[list(four)] @ ground)
            alike = min(1.0, (min(legs) / max(legs)) / GROUND_LEG_RATIO)
            terms["ground"] = -GROUND_BONUS * alike * float(np.mean(np.clip((down - LEG_DOWN) / (1.0 - LEG_DOWN), 0.0, 1.0)))
        if side is not None:
            # Given the body's own frame (up alone may be the world's: Blender gives +Z, and a rearing
            # animal's fore feet rise above its centre there), feet are below the body's centre in any
            # pose; a donkey lying with its head down has its ears above it, mirrored like feet.
            terms["above"] = float(above[list(four)].sum())
            # The left and right feet of a pair stand on either side of the body's midplane in any
            # pose (one reaching forward and one back, the animal lying on its side): a donkey lying
            # with its head down has its nose on the midplane and an ear beside it (0.11: costs 0.39).
            terms["sides"] = SIDES * sum(max(0.0, 0.5 - _mirrored(offset[x], offset[y])) for x, y in ((p, q), (r, s)))
        cost = sum(terms.values())
        hypotheses.append(_Hypothesis(((p, q), (r, s)), cost, terms, legs, spine))
    hypotheses.sort(key=lambda h: h.cost)
    return hypotheses


PLANARITY_TOLERANCE = 0.12  # foot heights off their plane, relative to the feet's spread
SUPPORT_TOLERANCE = 0.06    # how far (relative to body height) the mesh may dip below the foot plane


def ground_plane(points, vertices, centroid, up):
    """Unit normal (towards the body) of a plane the four feet stand on, or None: the feet lie on
    it (height spread ≤ PLANARITY_TOLERANCE of their spread), nothing dips more than
    SUPPORT_TOLERANCE of the body height below it, and the centroid projects inside the feet."""
    normal = _support_normal(points, centroid, up)
    if normal is None:
        return None
    heights = (vertices - points.mean(axis=0)) @ normal
    foot_heights = (points - points.mean(axis=0)) @ normal
    spread = np.max(np.linalg.norm(points[:, None] - points[None], axis=2))
    if np.ptp(foot_heights) > PLANARITY_TOLERANCE * spread:
        return None
    if heights.min() < foot_heights.min() - SUPPORT_TOLERANCE * heights.max():
        return None
    if not _inside_quad(points, centroid, normal):
        return None
    return normal


# ---------------------------------------------------------------- extremities and feet

RING_SHARE = 0.25   # the ring whose shape is judged lies this share of the way to the nearest other tip


def isocontour_segments(vertices, faces, field, level):
    """Segments (start, end) of the isocontour of a per-vertex field at one level."""
    values = field[faces]
    above = values > level
    count = above.sum(axis=1)
    crossing = ((count == 1) | (count == 2)) & np.isfinite(values).all(axis=1)
    v, c, a = values[crossing], vertices[faces[crossing]], above[crossing]
    lone = np.where(a.sum(axis=1) == 1, np.argmax(a, axis=1), np.argmin(a, axis=1))
    rows = np.arange(len(v))
    points = []
    for step in (1, 2):
        other = (lone + step) % 3
        t = (level - v[rows, lone]) / (v[rows, other] - v[rows, lone])
        points.append(c[rows, lone] + t[:, None] * (c[rows, other] - c[rows, lone]))
    return points[0], points[1]


def _ring_length(vertices, faces, field, level) -> float:
    start, end = isocontour_segments(vertices, faces, field, level)
    return float(np.linalg.norm(end - start, axis=1).sum())


def ring_centre(vertices, faces, field, level) -> np.ndarray | None:
    """The length-weighted centre of the isocontour at ``level`` (None where it is empty)."""
    start, end = isocontour_segments(vertices, faces, field, level)
    length = np.linalg.norm(end - start, axis=1)
    if length.sum() <= 0:
        return None
    return (length / length.sum()) @ (0.5 * (start + end))


def _pointing(vertices, faces, field, level, tip: int) -> np.ndarray:
    """Unit direction from the centre of the ring at ``level`` to ``tip`` (zero without a ring)."""
    centre = ring_centre(vertices, faces, field, level)
    if centre is None or not np.linalg.norm(vertices[tip] - centre) > 0:
        return np.zeros(3)
    return (vertices[tip] - centre) / np.linalg.norm(vertices[tip] - centre)


def ring_flatness(vertices, faces, field, level) -> float:
    """How flat the isocontour at ``level`` is: √(λ1/λ2) of its length-weighted second moments
    (1 for a circle, large for the thin loop around a flat sheet such as an ear)."""
    start, end = isocontour_segments(vertices, faces, field, level)
    length = np.linalg.norm(end - start, axis=1)
    if length.sum() <= 0:
        return 1.0
    middle = 0.5 * (start + end)
    weights = length / length.sum()
    centred = middle - weights @ middle
    eigenvalues = np.sort(np.linalg.eigvalsh((centred * weights[:, None]).T @ centred))[::-1]
    return float(np.sqrt(eigenvalues[0] / max(eigenvalues[1], 1e-30)))


def feature_flatness(vertices, faces, field, reach: float) -> float:
    """How flat the feature whose tip ``field`` measures from is (its geodesic distance; ``reach`` to
    its end's girdle): the flatter of its rings at :data:`FEATURE_RINGS` of its reach; an ear-like
    sheet from :data:`FLAT_APPENDAGE` on. An ear is flattest near its tip, and one ring alone read
    differently at two tessellations of one animal (a game donkey's ears 2.6 and 2.6 as it comes,
    2.36 and 1.87 split to 136k vertices, one then taken for a horn; half-way to that ring 3.4 and
    2.3-2.5); the Princeton cow 381's horns read 1.05-1.29 at both."""
    return max(ring_flatness(vertices, faces, field, share * reach) for share in FEATURE_RINGS)


@dataclass
class Extremities:
    """Tips of protrusions (AGD maxima above the feature floor, most persistent first), their
    relative persistence and AGD, and the geodesic distance field of each."""

    vertices: np.ndarray
    persistence: np.ndarray
    agd: np.ndarray
    distance: dict[int, np.ndarray]
    contrast: float = 1.0        # AGD range / mean AGD: how far anything sticks out

    @property
    def candidates(self) -> np.ndarray:
        """Indices (into ``vertices``) of the prominent tips the feet, head and tail are chosen from."""
        return np.flatnonzero(self.persistence >= CANDIDATE_PERSISTENCE)[:MAX_CANDIDATES]

    @property
    def persistence_of(self) -> dict[int, float]:
        """Each tip's (vertex id's) relative persistence."""
        return dict(zip(self.vertices.tolist(), self.persistence.tolist()))

    @property
    def agd_of(self) -> dict[int, float]:
        """Each tip's (vertex id's) relative AGD."""
        return dict(zip(self.vertices.tolist(), self.agd.tolist()))


def _placed_as_twins(reach_1: float, reach_2: float, apart: float) -> bool:
    """Two tips placed as a pair of ears or horns are, from a point both reach: alike in reach
    (within MIRROR_REACH of the longer) and well apart (more than MIRROR_SPACING of it; not two
    toes of one foot)."""
    longer = max(reach_1, reach_2)
    return abs(reach_1 - reach_2) < MIRROR_REACH * longer and apart > MIRROR_SPACING * longer


def read_extremities(graph, mass, vertices, faces) -> Extremities:
    """The tips of the mesh's protrusions with their geodesic distance fields; the ends of its
    cavities (:func:`cavity_ends`) are none."""
    agd = average_geodesic_distance(graph, mass)
    span = float(np.ptp(agd)) or 1.0
    tips, persistence = persistent_maxima(agd, graph)
    keep = persistence >= FEATURE_PERSISTENCE * span
    tips, persistence = tips[keep], persistence[keep] / span
    fields = geodesic_fields(graph, tips)
    cavity = cavity_ends(vertices, faces, tips, fields)
    # A cavity's end yields its prominence to the protrusion it lies in (an open mouth's to the nose
    # above it: the TOSCA horse's 0.78 against its nose's 0.05), as if it were not there; a
    # prominent one only where that protrusion has a tip of its own (one nearer the cavity's end,
    # over the surface, than the cavity's persistence reaches), else it stays its protrusion's tip
    # (a mouth that is the whole end of a muzzle). A faint one always yields (the TOSCA cat's mouth,
    # 0.04: from inside it the neck's cut found a neck of 0.8 % of the surface, 7.7 % at 200k).
    others = tips[~cavity]
    cavities = [int(tip) for tip, prominence in zip(tips[cavity], persistence[cavity])
                if prominence < CANDIDATE_PERSISTENCE
                or (len(others) and float(fields[int(tip)][others].min()) <= prominence * span)]
    if cavities:
        tips, persistence = persistent_maxima(agd, graph, yielding=cavities)
        keep = (persistence >= FEATURE_PERSISTENCE * span) & ~np.isin(tips, cavities)
        tips, persistence = tips[keep], persistence[keep] / span
        fields.update(geodesic_fields(graph, [int(t) for t in tips if int(t) not in fields]))
    return Extremities(tips, persistence, (agd[tips] - agd.min()) / span, {int(t): fields[int(t)] for t in tips},
                       span / max(float(agd.mean()), 1e-300))


CAVITY_RAYS = 48           # rays cast from a tip over the cone of CAVITY_SPREAD degrees about its normal
CAVITY_SPREAD = 60.0
CAVITY_ENCLOSED = 0.9      # a tip whose rays meet the surface again at least this often is enclosed
CAVITY_RING = 0.05         # of sqrt(surface area): the geodesic radius of the ring around a tip
CAVITY_CONCAVE = 0.2       # the ring this far in front of the tip (along its normal, per radius) or more: a pocket's end


def cavity_ends(vertices, faces, tips, fields) -> np.ndarray:
    """Which ``tips`` end a cavity (a mask): the inside of an open mouth, a nostril, an ear canal.

    The AGD peaks there as it does at a protrusion's tip (the far end of a modelled mouth is as
    far, over the surface, from everything as a nose: the TOSCA horses' mouths, persistence 0.72
    and 0.78, were taken for the head's tip and their faces for a trunk). Such a tip is enclosed
    (rays cast from it over the cone about its normal meet the surface again, CAVITY_ENCLOSED of
    them) and concave (the ring of geodesic radius CAVITY_RING around it lies in front of it along
    its normal, as the bottom of a cup does; a protrusion's ring lies behind its tip). A foot tucked
    under a sitting animal's belly is enclosed but convex, and stays a tip. Nothing is dropped from
    a surface oriented inwards (its normals would make every tip look like a pocket)."""
    tips = np.asarray(tips, dtype=np.int64)
    ends = np.zeros(len(tips), dtype=bool)
    if len(tips) == 0 or enclosed_volume(vertices, faces) <= 0:
        return ends
    size = float(np.sqrt(face_areas(vertices, faces).sum()))
    normals = vertex_normals(vertices, faces)[tips]
    radius = CAVITY_RING * size
    concave = np.zeros(len(tips), dtype=bool)
    for k, tip in enumerate(tips):
        field = fields[int(tip)]
        ring = (field > 0.8 * radius) & (field < 1.2 * radius)
        concave[k] = ring.any() and float(np.mean((vertices[ring] - vertices[tip]) @ normals[k])) > CAVITY_CONCAVE * radius
    candidates = np.flatnonzero(concave)
    if len(candidates) == 0:
        return ends
    directions = np.concatenate([cone_directions(normals[k], CAVITY_RAYS, CAVITY_SPREAD) for k in candidates])
    origins = np.repeat(vertices[tips[candidates]] + 1e-4 * size * normals[candidates], CAVITY_RAYS, axis=0)
    met = np.isfinite(ray_hits(vertices, faces, origins, directions)).reshape(len(candidates), CAVITY_RAYS)
    ends[candidates] = met.mean(axis=1) >= CAVITY_ENCLOSED
    return ends


@dataclass
class FeetChoice:
    fore_pair: tuple[int, int]      # vertex ids; which pair is fore is decided later (ends)
    other_pair: tuple[int, int]
    margin: float
    ground: np.ndarray | None       # normal of the plane the feet stand on, if they do
    terms: dict[str, float]


PAIR_LEFT_OUT_LIKENESS = 0.8   # the two tips of a pair left out this alike in prominence, or more, are twins


def _legs_across(offset: np.ndarray, tips, pair, other) -> bool:
    """Two tips lie as a pair of feet does across the body's midplane (``offset``: each tip's offset
    from it): mirrored (as the feet's sides term asks, 0.5 or more) and at least half as far apart
    as the feet of the narrower pair chosen (``pair``, ``other``)."""
    a, b = tips
    narrower = min(abs(offset[pair[0]] - offset[pair[1]]), abs(offset[other[0]] - offset[other[1]]))
    return _mirrored(offset[a], offset[b]) >= 0.5 and abs(offset[a] - offset[b]) >= 0.5 * narrower


def _pair_left_out(tips: _Tips, d, pair, other, offset=None) -> tuple[float, float, float] | None:
    """A pair of tips no foot, twins (alike in prominence within PAIR_LEFT_OUT_LIKENESS, in AGD
    within MIRROR_AGD, no farther apart than 1.5 times the feet of a pair) and each more prominent
    than the least prominent foot chosen, as (their prominences, that foot's), or None. A pair that
    stands out more than a pair of feet is a pair of legs: a dog leaping with horns, horns and fore
    feet reaching forward to one plane, had them for its four feet and its hind legs (0.77 and
    0.77, the horn 0.34) for its head's ears. Ears and horns stand out less than legs, or are twins
    unlike in prominence (a horned dog's 0.86 and 0.41); a nose and a tail tip are a body apart.
    Where the body's side is known (``offset``: each tip's offset from its midplane, up and forward
    given), a pair of legs lies on either side of it as feet do (:func:`_legs_across`): a low-poly
    horse's tail of strands hanging to its hocks had two strands' tips for such a pair (0.79 and
    0.67, a hoof 0.67), and the directions the refusal asks for did not settle it. Legs are tubes
    (the feet's ``flat`` term): a pair of flat sheets, ring flatness beyond FLAT_LEG, is no pair of
    legs (a held-out elephant's big ears, 4.5 and 7.6, stood out more than its hind feet, 0.32 and
    0.31 against 0.28, and refused it)."""
    chosen = [int(x) for x in pair + other]
    least = float(min(tips.persistence[chosen]))
    spread = 1.5 * max(d[pair[0]][pair[1]], d[other[0]][other[1]])
    rest = [k for k in range(len(tips.vertices)) if k not in chosen]
    for a, b in itertools.combinations(rest, 2):
        if max(tips.flatness[a], tips.flatness[b]) > FLAT_LEG:
            continue
        low, high = sorted((float(tips.persistence[a]), float(tips.persistence[b])))
        if (low > PAIR_LEFT_OUT_LIKENESS * high and low > least and abs(tips.agd[a] - tips.agd[b]) < MIRROR_AGD
                and d[a][b] <= spread and (offset is None or _legs_across(offset, (a, b), pair, other))):
            return float(tips.persistence[a]), float(tips.persistence[b]), least
    return None


def choose_feet(extremities: Extremities, vertices, faces, mass, up=None, forward=None) -> FeetChoice:
    """The two pairs of feet (see the module's step 2), or a SegmentationError saying why not.
    ``up`` and ``forward`` are the body's directions where the user gave them."""
    index = extremities.candidates
    if extremities.contrast < MIN_CONTRAST:
        raise SegmentationError(
            "no legs or feet stick out of this mesh (it is too compact); it does not look like a quadruped "
            "(segment it by hand: allorules segment MESH --patches 24 --png patches.png and a merge file)")
    if len(index) < 4:
        raise SegmentationError(
            f"found only {len(index)} limb-like extremities where a quadruped has at least four feet; this mesh "
            "does not look like a quadruped (segment it by hand: allorules segment MESH --patches 24 --png patches.png "
            "and a merge file)")
    d = [[extremities.distance[int(a)][int(b)] for b in extremities.vertices[index]] for a in extremities.vertices[index]]
    levels = [RING_SHARE * min(d[k][j] for j in range(len(index)) if j != k) for k in range(len(index))]
    flatness = np.array([ring_flatness(vertices, faces, extremities.distance[int(t)], level)
                         for t, level in zip(extremities.vertices[index], levels)])
    pointing = np.array([_pointing(vertices, faces, extremities.distance[int(t)], level, int(t))
                         for t, level in zip(extremities.vertices[index], levels)]).reshape(-1, 3)
    tips = _Tips(extremities.vertices[index], extremities.persistence[index], extremities.agd[index], flatness, pointing)
    side = None if up is None or forward is None else np.cross(forward, up)
    side = side / np.linalg.norm(side) if side is not None and np.linalg.norm(side) > 0.1 else None
    hypotheses = _feet_hypotheses(tips, d, vertices, mass, up, side)
    best = hypotheses[0]
    margin = hypotheses[1].cost - best.cost if len(hypotheses) > 1 else np.inf
    (p, q), (r, s) = best.pairs
    # the directions' terms tell guesses apart; what a quadruped's feet cost is judged without them
    # (a bull galloping, a fore foot crossing its midplane: 0.27 more)
    cost = best.cost - best.terms.get("above", 0.0) - best.terms.get("sides", 0.0)
    if cost > 1.5:
        raise SegmentationError(
            "no four extremities make a quadruped's two pairs of legs on this mesh (the best guess costs "
            f"{cost:.2f}); {settle_feet(up, forward)}")
    if margin < FEET_MARGIN:
        raise SegmentationError(
            f"cannot tell which four extremities are the feet (two guesses within a margin of {margin:.2f}); "
            f"{settle_feet(up, forward)}")
    feet = tips.vertices[[p, q, r, s]]
    centroid = np.average(vertices, axis=0, weights=mass)
    offset = None if side is None else _midplane_offsets(tips, vertices, centroid, side)
    left_out = _pair_left_out(tips, d, (p, q), (r, s), offset)
    if left_out is not None:
        raise SegmentationError(
            f"cannot tell which four extremities are the feet: a pair left out (prominence {left_out[0]:.2f} and "
            f"{left_out[1]:.2f}) stands out more than a foot taken ({left_out[2]:.2f}), as only legs do (legs "
            f"stretched out beside horns, as in a leap, or a tail of strands?); {settle_feet(up, forward)}")
    ground = ground_plane(vertices[feet], vertices, centroid, up)
    return FeetChoice((int(feet[0]), int(feet[1])), (int(feet[2]), int(feet[3])), float(margin), ground,
                      dict(best.terms))


def head_taken_for_a_leg(extremities: Extremities, legs: np.ndarray, feet, vertices, faces) -> int | None:
    """The foot whose leg carries a head's features, or None: two tips on that leg (or within its
    length of its foot: the leg's cut may leave one out) shaped alike (:func:`_shaped_alike`),
    alike in their distance from its foot, well apart, and LEG_FEATURE_REACH of the leg's length
    or more from its foot (ears or horns, a head's length behind its nose, where toes lie within a
    paw's width of the foot's tip). A cat leaping with its fore legs stretched out, one beside its
    nose, had its nose taken for a foot, its head for that foot's leg, and its tail for its head:
    its ears were 0.87 of that "leg" from its "foot"; split twice, the cut left one ear out."""
    distance = extremities.distance
    persistence = extremities.persistence_of
    for foot in (int(f) for f in feet):
        on_leg = legs == foot
        length = float(distance[foot][on_leg].max(initial=0.0))
        tips = [int(t) for t in extremities.vertices
                if (on_leg[t] or distance[foot][t] <= length) and int(t) != foot
                and persistence[int(t)] >= MIRROR_PERSISTENCE
                and distance[foot][t] >= LEG_FEATURE_REACH * length]
        for t1, t2 in itertools.combinations(tips, 2):
            if (_placed_as_twins(distance[foot][t1], distance[foot][t2], distance[t1][t2])
                    and _shaped_alike(extremities, t1, t2, vertices, faces,
                                      0.1 * max(distance[foot][t1], distance[foot][t2]))):
                return foot
    return None


def _shaped_alike(extremities: Extremities, t1: int, t2: int, vertices, faces, level: float) -> bool:
    """Two tips alike as twins are: in prominence, or else (the younger of two twins keeps only what
    it stands above the saddle between them: a horned dog's 0.86 and 0.41) in girth, their rings
    ``level`` from each tip within MIRROR_RING of each other."""
    persistence = extremities.persistence_of
    if min(persistence[t1], persistence[t2]) > 0.5 * max(persistence[t1], persistence[t2]):
        return True
    rings = [_ring_length(vertices, faces, extremities.distance[t], level) for t in (t1, t2)]
    return min(rings) > MIRROR_RING * max(rings)


def features_in(extremities: Extremities, region: np.ndarray, vertices, faces) -> tuple[int, int] | None:
    """A pair of prominent tips (candidates, as feet are) inside ``region``, alike in AGD and shaped
    alike (:func:`_shaped_alike`, rings a tenth of their distance apart from each tip), as a head's
    ears or horns are, or None. Chest and abdomen carry none: the real elephant
    (a public mesh, its big ears hanging back over its shoulders, behind its fore girdle) told its
    forward direction had its trunk labelled head and its head, ears and all, chest (the ears'
    prominence 0.285 and 0.263, their AGD 0.55 and 0.54)."""
    tips = [int(extremities.vertices[k]) for k in extremities.candidates if region[int(extremities.vertices[k])]]
    agd = extremities.agd_of
    for t1, t2 in itertools.combinations(tips, 2):
        if abs(agd[t1] - agd[t2]) < MIRROR_AGD and _shaped_alike(
                extremities, t1, t2, vertices, faces, 0.1 * extremities.distance[t1][t2]):
            return t1, t2
    return None


# ---------------------------------------------------------------- ends: head or tail

@dataclass
class End:
    """One end of the body: its pair of feet, its girdle (the vertex where the pair branches off
    the spine), the non-leg surface beyond it and the tips there."""

    pair: tuple[int, int]
    girdle: int
    centre: np.ndarray          # centre of the pair's leg tops (inside the body)
    region: np.ndarray          # boolean: non-leg vertices beyond the girdle
    area: float
    tips: list[int]             # tips beyond the girdle, not on a leg
    main_tip: int | None        # the end protrusion's tip (nose or tail tip)
    mirror_pairs: list[tuple[int, int]]
    thickness: float            # girth of the end protrusion part-way along it (0 without one)
    prominence: float = 0.0     # persistence of its most prominent tip (0 without tips)
    prominent_tip: int | None = None   # that tip (a pig's curly tail, thinner than a bump on its rump beside it)
    features: dict[int, str] = field(default_factory=dict)   # tip → "flat" (ear-like) or "thin" (horn-like)
    toes: float | None = None   # how far the pair's toes reach towards this end, in leg radii (standing only)

    @property
    def protrudes(self) -> bool:
        """A prominent tip (not a bump) sticks out of this end."""
        return self.prominence >= CANDIDATE_PERSISTENCE

    @property
    def presence(self) -> float:
        """How surely something sticks out of this end, in [0, 1]: 0 up to ``PRESENCE_FAINT``, 1
        from ``PRESENCE_FULL``, log-linear between (a stub of a tail near ``CANDIDATE_PERSISTENCE``
        counts about half, whichever side of it a resolution puts it)."""
        if self.prominence <= PRESENCE_FAINT:
            return 0.0
        span = np.log(PRESENCE_FULL / PRESENCE_FAINT)
        return float(np.clip(np.log(self.prominence / PRESENCE_FAINT) / span, 0.0, 1.0))


def leg_top_distances(graph, legs: np.ndarray, feet) -> dict[int, np.ndarray]:
    """For each foot, the geodesic distance over the body without its legs from the top of that
    foot's leg (the ring of non-leg vertices next to it); legs that touch (knees) make no shortcut."""
    body = legs < 0
    index = np.flatnonzero(body)
    local = np.full(len(legs), -1)
    local[index] = np.arange(len(index))
    sub = graph[index][:, index]
    fields = {}
    for foot in feet:
        leg = np.flatnonzero(legs == foot)
        ring = np.unique(graph[leg].indices)
        ring = ring[body[ring]]
        field = np.full(len(legs), np.inf)
        if len(ring):
            field[index] = dijkstra(sub, indices=local[ring], min_only=True)
        fields[int(foot)] = field
    return fields


def _girdle(top, pair, other) -> int:
    """The body vertex between the pair's leg tops nearest the other pair (where the pair's legs
    branch off the spine)."""
    a, b = pair
    c, e = other
    score = top[a] + top[b] + 0.1 * (top[c] + top[e])
    return int(np.argmin(score))


def read_ends(extremities: Extremities, top, graph, legs, leg_tops, first_pair, second_pair, vertices, faces, mass,
              ground=None):
    """The two ends (:class:`End`), ``first_pair``'s first.

    Each girdle's plane passes through the centre of the pair's leg tops across the spine (the line
    between the two pairs' centres); an end is the body (without legs) beyond it: head, neck and
    breast at one end, rump and tail at the other. Cut along the longest loop of each plane, a
    piece that lies mostly beyond one plane is that end's even where it reaches across the other
    plane (a tail curled forward over the back stays with the rump). ``ground``: the normal of the
    plane the animal stands on, if it does; the spine is then taken level as far as the animal
    stands (:func:`spine_direction`).
    """
    girdles = (_girdle(top, first_pair, second_pair), _girdle(top, second_pair, first_pair))
    # The spine's direction: between the centres of the two pairs' leg tops (``leg_tops``: where
    # each leg joins the body; steadier than two points on the underside when the legs are spread).
    centres = [np.mean([leg_tops[foot] for foot in pair], axis=0) for pair in (first_pair, second_pair)]
    chord = centres[0] - centres[1]
    if ground is not None:
        chord = spine_direction(chord, ground)
    axis = chord / max(np.linalg.norm(chord), 1e-300)
    body = legs < 0
    body_faces = faces   # the whole section: the plane may run through the legs' tops
    adjacency = face_adjacency(body_faces)
    cut_edges = []
    sides = []
    for point, normal in ((centres[0], axis), (centres[1], -axis)):
        side = (vertices - point) @ normal > 0
        sides.append(side)
        loop = _torso_loop(vertices, body_faces, adjacency, point, normal)
        if loop is None:
            continue
        loop_faces = body_faces[loop]
        edges = directed_edges(loop_faces)
        cut_edges.append(edges[side[edges[:, 0]] != side[edges[:, 1]]])
    kept = graph
    if cut_edges:
        edges = np.concatenate(cut_edges)
        cut = coo_matrix((np.ones(2 * len(edges)), (np.concatenate([edges[:, 0], edges[:, 1]]),
                                                     np.concatenate([edges[:, 1], edges[:, 0]]))), shape=graph.shape).tocsr()
        kept = (graph - graph.multiply(cut > 0)).tocsr()
        kept.eliminate_zeros()
    parts = vertex_components(kept, body)
    # A piece cut free that lies mostly beyond one girdle belongs to that end, even where it
    # reaches across the other girdle's plane (a tail curled forward over the back); everything
    # else beyond a girdle's plane is that end's (also where a hole in the mesh leaves a loop open).
    owner = np.full(len(vertices), -1)
    for part in np.unique(parts[body]):
        members = parts == part
        total = mass[members].sum()
        beyond = [mass[members & sides[k]].sum() for k in range(2)]
        for k in range(2):   # (a piece reaching far beyond both planes is a loop left open: no owner)
            if beyond[k] > 0.5 * total and beyond[1 - k] < 0.25 * beyond[k]:
                owner[members] = k
    feet = set(first_pair) | set(second_pair)
    ends = []
    for k, pair in enumerate((first_pair, second_pair)):
        region = body & ((sides[k] & (owner != 1 - k)) | (owner == k))
        across = leg_tops[pair[0]] - leg_tops[pair[1]]
        lateral = across / max(np.linalg.norm(across), 1e-300)
        end = _read_end(extremities, top, pair, girdles[k], centres[k], region, vertices, faces, mass, feet, lateral)
        if ground is not None:   # toes say which way an animal stands on its feet, not how a leg folds
            towards = axis if k == 0 else -axis
            reaches = [_toe_reach(vertices, faces, extremities.distance[int(foot)], int(foot), legs == foot, ground,
                                  towards) for foot in pair]
            if all(reach is not None for reach in reaches):
                end = replace(end, toes=float(np.mean(reaches)))
        ends.append(end)
    return ends[0], ends[1]


def _toe_reach(vertices, faces, field, foot: int, leg: np.ndarray, ground: np.ndarray,
               towards: np.ndarray) -> float | None:
    """How far a foot's tip (``foot``; ``field`` measures from it) reaches along ``towards`` beyond its leg,
    level (⟂ ``ground``), in radii of the leg's ring TOE_RING of its length up from the tip, within
    ±TOE_LIMIT: paws and hooves point forward (of 36 animals standing, shared and held-out, 32 read
    0.37-2.8 radii towards the head, four under 0.3 either way; the generator's feet, with no toes,
    under 0.2). None where the leg's lower half does not stand within TOE_UPRIGHT of the ground's
    normal (a generated horse lying on its folded legs read 1.5 radii the wrong way)."""
    length = float(field[leg].max(initial=0.0))
    centre = ring_centre(vertices, faces, field, TOE_RING * length)
    above = ring_centre(vertices, faces, field, 0.5 * length)
    radius = _ring_length(vertices, faces, field, TOE_RING * length) / (2.0 * np.pi)
    if centre is None or above is None or not radius > 0:
        return None
    shank = above - centre
    if not shank @ ground >= np.cos(np.radians(TOE_UPRIGHT)) * np.linalg.norm(shank):
        return None
    reach = vertices[foot] - centre
    reach = reach - (reach @ ground) * ground
    return float(np.clip(reach @ towards / radius, -TOE_LIMIT, TOE_LIMIT))


def seated_share(chord: np.ndarray, up: np.ndarray) -> float:
    """How far an animal whose girdles lie along ``chord`` sits, in [0, 1]: 0 with the chord within
    ``SEATED_TILT[0]`` of level (standing), 1 beyond ``SEATED_TILT[1]``, smoothstep between, so
    that a small change of the mesh (its resolution) never flips how the body is read."""
    length = float(np.linalg.norm(chord))
    if not length > 0:
        return 0.0
    tilt = np.degrees(np.arcsin(min(1.0, abs(float(chord @ up)) / length)))
    low, high = SEATED_TILT
    return float(smoothstep(np.asarray((tilt - low) / (high - low))))


def spine_direction(chord: np.ndarray, up: np.ndarray, forward: np.ndarray | None = None) -> np.ndarray:
    """The spine's direction from the chord between the girdles: level for a standing animal (legs
    cut at different heights do not tilt it), the chord itself for a sitting one (its spine runs
    from one girdle to the other), the chord's rise kept in proportion between. ``forward``: the
    level direction to run along instead of the chord's own (the user's ``--forward``)."""
    rise = float(chord @ up)
    level = chord - rise * up
    if forward is not None:
        level = float(np.linalg.norm(level)) * np.asarray(forward, dtype=float)
    return level + seated_share(chord, up) * rise * up


def _torso_loop(vertices, faces, adjacency, point, normal):
    """Face indices of the longest loop of the plane section through ``point`` (⟂ ``normal``):
    the one around the torso, or None."""
    _, _, crossed, loop_of = plane_section_loops(vertices, faces, adjacency, point, normal)
    if len(crossed) < 3:
        return None
    corners = vertices[faces[crossed]]
    size = np.linalg.norm(corners.max(axis=1) - corners.min(axis=1), axis=1)   # a face's extent ~ its share of the loop
    length = np.bincount(loop_of, weights=size)
    return crossed[loop_of == int(np.argmax(length))]


def _read_end(extremities, top, pair, girdle, centre, region, vertices, faces, mass, feet, lateral) -> End:
    """One end (:class:`End`); ``lateral``: the unit direction across the body there (between the
    pair's leg tops)."""
    distance = extremities.distance
    area = float(mass[region].sum())
    a, b = pair
    tips = [int(t) for t in extremities.vertices if region[t] and int(t) not in feet]
    reach = {t: float(distance[t][girdle]) for t in tips}
    # Rings around each tip a tenth of its way to the girdle: a horn is a thin tube (its ring much
    # smaller than the others'), an ear a flat sheet; the end's main tip (a nose, a tail tip) is the
    # most prominent tip that is neither.
    ring = {t: _ring_length(vertices, faces, distance[t], 0.1 * reach[t]) for t in tips}
    widest = max(ring.values(), default=0.0)
    appendage = {t: ring[t] < APPENDAGE_RING * widest
                 or ring_flatness(vertices, faces, distance[t], 0.15 * reach[t]) >= FLAT_APPENDAGE for t in tips}
    persistence, agd = extremities.persistence_of, extremities.agd_of
    # Mirror pairs: two prominent tips alike in AGD and reach, well apart (ears, horns), and alike
    # in prominence or else in girth and lying straight across the body. Of two twins the elder
    # keeps what the pair stands above the body, the younger only what it stands above the saddle
    # between them (a dog's long horns: 0.74 and 0.30), so their prominence can differ; then they
    # are told from a nose and a bump behind it (alike in girth too) by lying across the body, as
    # the pair's leg tops do.
    mirror_pairs, across_pairs = [], []
    for t1, t2 in itertools.combinations(tips, 2):
        if min(persistence[t1], persistence[t2]) < MIRROR_PERSISTENCE:
            continue
        apart = vertices[t1] - vertices[t2]
        across = abs(apart @ lateral) >= MIRROR_ACROSS * np.linalg.norm(apart)
        placed_alike = abs(agd[t1] - agd[t2]) < MIRROR_AGD and _placed_as_twins(reach[t1], reach[t2], distance[t1][t2])
        shaped_alike = (min(persistence[t1], persistence[t2]) > 0.5 * max(persistence[t1], persistence[t2])
                        or (across and min(ring[t1], ring[t2]) > MIRROR_RING * max(ring[t1], ring[t2])))
        if placed_alike and shaped_alike:
            mirror_pairs.append((t1, t2))
            if across:
                across_pairs.append((t1, t2))
    partners = collections.Counter(t for pair_ in across_pairs for t in pair_)    # the tips with a twin across
    # The main tip lies on the animal's plane of symmetry: of the tips that are no appendage, the
    # most prominent without a twin straight across the body from it (a horn has one, a nose none:
    # a dog's long horns were taken for its nose). A pair not straight across (the bull 386's ear
    # and nose, its head turned: 0.80; ears and horns of the shared animals 0.98-1.00) keeps both.
    main_tip = None
    if tips:
        plain = [t for t in tips if not appendage[t]] or tips
        main_tip = max([t for t in plain if t not in partners] or plain, key=lambda t: persistence[t])
    # How thick the end's protrusion gets part-way along it: a tail stays thin, a head does not.
    # Measured from the main tip unless that is a faint bump (nothing sticks out there), then from
    # the most prominent tip (the realistic elephant's tail, a flat sheet taken for an appendage:
    # from a bump of 0.03 on its rump the rings were the rump's, and the tail end read as thicker
    # than the trunk end).
    prominent_tip = max(tips, key=lambda t: persistence[t], default=None)
    thickness = 0.0
    if main_tip is not None:
        measured = main_tip if persistence[main_tip] > PRESENCE_FAINT else prominent_tip
        thickness = max(_ring_length(vertices, faces, distance[measured], f * reach[measured]) for f in (0.1, 0.2, 0.3))
    prominence = 0.0 if prominent_tip is None else persistence[prominent_tip]
    # Features of the end (ears, horns): its appendages and mirror pairs, not its main tip nor a
    # tip beside it (MUZZLE_SHARE: the wolf's lower jaw, a flat sheet 0.08 of its reach from its
    # nose, was cut as its ears; every ear and horn we have lies 0.30 or more of it away).
    features = {}
    beside = {t for t in tips if main_tip is not None
              and np.linalg.norm(vertices[t] - vertices[main_tip]) < MUZZLE_SHARE * reach[main_tip]}
    chosen = [t for t in set([t for t in tips if appendage[t]] + [t for pair_ in mirror_pairs for t in pair_])
              if t != main_tip and t not in beside]
    flatness = {t: feature_flatness(vertices, faces, distance[t], reach[t]) for t in chosen}
    girth = {t: ring[t] / widest if widest > 0 else 1.0 for t in chosen}
    # Twins straight across the body are one kind, read as a pair: a TOSCA horse's two ears, each
    # near both lines, were named one ears and one horns.
    for t1, t2 in across_pairs:
        if t1 in flatness and t2 in flatness and partners[t1] == partners[t2] == 1:
            flatness[t1] = flatness[t2] = 0.5 * (flatness[t1] + flatness[t2])
            girth[t1] = girth[t2] = 0.5 * (girth[t1] + girth[t2])
    for t in chosen:
        features[t] = "thin" if girth[t] < APPENDAGE_RING and flatness[t] < FLAT_APPENDAGE else "flat"
    return End(tuple(pair), girdle, centre, region, area, tips, main_tip, mirror_pairs, thickness, prominence,
               prominent_tip, features)


# Beyond each pair of legs a quadruped's body goes on: its head, neck and breast at one end, its
# rump (and tail) at the other. The smaller end's surface over the larger's, over the 15 real
# animals of shared/ labelled right, the generated horse, elephant, giraffe and dog in eight poses
# and four cartoon styles in five: 0.17 (the Princeton 389) to 1.32 (a cartoon cow sitting, its
# head the smaller end). An upright teddy bear, its ears and arms taken for the four feet, had
# 0.028 beyond its "hind" pair (the top of its head), and a toy bear standing on its legs, its arms
# taken for fore legs, 0.007: nothing lay beyond its hips. Below this share: refused.
MIN_END_SHARE = 0.08


def check_ends(first: End, second: End, settle: str) -> None:
    """Refuse two ends of which one holds almost nothing beyond its legs (:data:`MIN_END_SHARE`):
    the four feet found are not a quadruped's (ears and arms, or a figure standing upright)."""
    share = min(first.area, second.area) / max(first.area, second.area, 1e-300)
    if share < MIN_END_SHARE:
        raise SegmentationError(
            f"almost nothing of the body lies beyond one pair of the feet found ({share:.1%} of what lies beyond the "
            "other), where a quadruped has its rump or its head: they may be ears or arms, or the figure may stand "
            f"upright on two legs; {settle}")


@dataclass
class EndsDecision:
    head: End
    tail: End
    cues: dict[str, float]          # evidence for the chosen head end, each in [−1, 1]
    margin: float                   # summed evidence (≥ 0 for the chosen end)


def decide_head(first: End, second: End, forward_hint=None, vertices=None) -> EndsDecision:
    """Which end is the head (module docstring, step 3); refuses when the cues do not agree.

    ``forward_hint`` (the user's ``--forward``): the end whose girdle lies further along it is the
    head, whatever the cues say (they are still reported).
    """
    cues = {}
    if first.area > 0 and second.area > 0:
        cues["mass"] = float(np.clip(np.log2(first.area / second.area), -1.0, 1.0))
    else:
        cues["mass"] = 1.0 if first.area > second.area else -1.0
    has_first, has_second = bool(first.mirror_pairs), bool(second.mirror_pairs)
    cues["features"] = float(has_first) - float(has_second)
    if first.protrudes and second.protrudes:
        cues["thickness"] = float(np.clip(np.log2(first.thickness / second.thickness), -1.0, 1.0))
    else:
        cues["thickness"] = 0.0
    cues["presence"] = first.presence - second.presence
    if first.toes is not None and second.toes is not None:
        reach = 0.5 * (first.toes - second.toes)    # the four feet's mean reach towards the first end
        cues["toes"] = float(TOES_CUE * np.sign(reach) * np.clip((abs(reach) - TOES_FAINT) / (TOES_CLEAR - TOES_FAINT),
                                                                 0.0, 1.0))
    total = sum(cues.values())
    if forward_hint is not None and vertices is not None:
        along = (first.centre - second.centre) @ np.asarray(forward_hint, dtype=float)
        head_first = along > 0
    else:
        if abs(total) < HEAD_TAIL_MARGIN:
            raise SegmentationError(
                f"cannot tell the head from the tail (cues {_cue_text(cues)}, summed {abs(total):.2f} < "
                f"{HEAD_TAIL_MARGIN}); {SETTLE}")
        against = [name for name, value in cues.items()
                   if value * total < 0 and abs(value) >= STRONG_CUE and name != "toes"]   # a weak cue
        agreeing = [name for name, value in cues.items() if value * total > 0 and abs(value) >= AGREEING_CUE]
        if len(agreeing) < 2:
            raise SegmentationError(
                f"cannot tell the head from the tail: only {', '.join(agreeing) or 'no'} cue speaks for one end "
                f"({_cue_text(cues)}), at least two must; {SETTLE}")
        if against:
            raise SegmentationError(
                f"head and tail cues disagree ({_cue_text(cues)}: {', '.join(against)} against the others); {SETTLE}")
        head_first = total > 0
    if head_first:
        return EndsDecision(first, second, cues, float(total))
    return EndsDecision(second, first, {name: -value for name, value in cues.items()}, float(-total))


def _cue_text(cues: dict[str, float]) -> str:
    return ", ".join(f"{name} {value:+.2f}" for name, value in cues.items())


SPINE_MIN = 0.2   # spine / mean leg below this: fore and hind pairs cannot be told apart


def confidence(choice: FeetChoice, ends: EndsDecision, forward_given: bool) -> dict[str, float]:
    """Named margins in [0, 1]: each decision's margin over twice its refusal threshold (so 0.5
    is exactly at the threshold, 1 twice as clear or more); 1 for a decision the user made."""
    def scaled(margin, threshold):
        return float(np.clip(margin / (2.0 * threshold), 0.0, 1.0))

    spine_ratio = 1.0 - choice.terms.get("spine", 0.0)   # 1 at SPINE_RATIO and above
    return {
        "feet": scaled(choice.margin, FEET_MARGIN),
        "fore-hind pairs": float(np.clip(spine_ratio, 0.0, 1.0)),
        "head-tail": 1.0 if forward_given else scaled(ends.margin, HEAD_TAIL_MARGIN),
    }


# ---------------------------------------------------------------- helpers shared with the labeller

AGD_SOURCES = 24            # farthest-point sources for the average geodesic distance


def average_geodesic_distance(graph: sparse.csr_matrix, mass: np.ndarray, sources: int = AGD_SOURCES) -> np.ndarray:
    """Mean graph-geodesic distance from a farthest-point sample of ``sources`` vertices."""
    n = graph.shape[0]
    start = int(np.argmax(mass))  # deterministic, independent of vertex order only up to ties
    chosen = [start]
    distance = dijkstra(graph, indices=start)
    rows = [distance]
    nearest = distance.copy()
    for _ in range(min(sources, n) - 1):
        nxt = int(np.argmax(nearest))
        chosen.append(nxt)
        distance = dijkstra(graph, indices=nxt)
        rows.append(distance)
        nearest = np.minimum(nearest, distance)
    return np.mean(rows, axis=0)


def persistent_maxima(values: np.ndarray, graph: sparse.csr_matrix, yielding=()) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of a vertex function and their persistence (super-level-set union–find).

    Sweeping downwards, each maximum starts a component; when two components meet at a
    vertex, the one born lower dies there and its persistence is birth − that value (elder rule).
    The global maximum's persistence is its value minus the global minimum. A component born at
    a ``yielding`` maximum dies at its first meeting with one that is not, however high it was
    born: the other carries on as if it had never been there.
    """
    yielding = set(int(v) for v in yielding)
    order = np.argsort(-values, kind="stable")
    parent = np.full(len(values), -1, dtype=np.int64)
    birth_vertex = {}
    persistence = {}
    indptr, indices = graph.indptr, graph.indices

    for v in order:
        roots = {_find(parent, u) for u in indices[indptr[v]:indptr[v + 1]] if parent[u] >= 0}
        if not roots:
            parent[v] = v
            birth_vertex[v] = v
            continue
        roots = sorted(roots, key=lambda r: (int(birth_vertex[r]) in yielding, -values[birth_vertex[r]]))
        survivor = roots[0]
        parent[v] = survivor
        for other in roots[1:]:
            tip = birth_vertex[other]
            persistence[tip] = values[tip] - values[v]
            parent[other] = survivor
    for root in {_find(parent, v) for v in range(len(values))}:
        tip = birth_vertex[root]
        persistence[tip] = values[tip] - values.min()
    tips = np.array(sorted(persistence, key=lambda t: -persistence[t]), dtype=np.int64)
    return tips, np.array([persistence[t] for t in tips])


def _find(parent: np.ndarray, x: int) -> int:
    """Root of x in a union–find forest stored in ``parent`` (path compression on the way)."""
    root = x
    while parent[root] != root:
        root = parent[root]
    while parent[x] != root:
        parent[x], x = root, parent[x]
    return root


def _support_normal(points, centroid, up):
    if up is not None:
        return up if (centroid - points.mean(axis=0)) @ up > 0 else None
    centred = points - points.mean(axis=0)
    _, singular, axes = np.linalg.svd(centred)
    if singular[1] < 1e-9:
        return None
    normal = axes[2]
    return normal if (centroid - points.mean(axis=0)) @ normal > 0 else -normal


def _inside_quad(points, centroid, normal) -> bool:
    """Whether the centroid projects inside the convex hull of the four feet (on their plane)."""
    basis_u = np.cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(basis_u) < 0.1:
        basis_u = np.cross(normal, [0.0, 1.0, 0.0])
    basis_u /= np.linalg.norm(basis_u)
    basis_v = np.cross(normal, basis_u)
    flat = np.column_stack([points @ basis_u, points @ basis_v])
    target = np.array([centroid @ basis_u, centroid @ basis_v])
    hull = flat[_convex_hull_2d(flat)]
    signs = []
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        edge, offset = b - a, target - a
        signs.append(edge[0] * offset[1] - edge[1] * offset[0])
    signs = np.array(signs)
    return bool(np.all(signs >= 0) or np.all(signs <= 0))


def _convex_hull_2d(points):
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))

    def cross(o, a, b):
        return (points[a][0] - points[o][0]) * (points[b][1] - points[o][1]) - (points[a][1] - points[o][1]) * (points[b][0] - points[o][0])

    lower, upper = [], []
    for i in order:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], i) <= 0:
            lower.pop()
        lower.append(i)
    for i in reversed(order):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], i) <= 0:
            upper.pop()
        upper.append(i)
    return lower[:-1] + upper[:-1]
