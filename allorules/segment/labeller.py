"""Automatic labelling of a standing quadruped into head, neck, chest, abdomen, forelimbs, hindlimbs.

The rules (documented with their limits in ``docs/segmentation.md``):

1. **Extremities.** The average geodesic distance (AGD, from a farthest-point sample of sources)
   is largest at the tips of protrusions. Its local maxima, ranked by topological persistence
   (how far the AGD falls before the tip's super-level component meets a more prominent one),
   are the candidate tips: feet, muzzle, tail, ears, horns, trunk.
2. **Feet and up.** Four candidates are the feet if a plane through them is a supporting plane
   of the whole mesh (nothing lies clearly below it), they are nearly coplanar, and the
   surface's centroid projects inside their quadrilateral; of the valid sets the most
   persistent wins. Up is the plane's normal, towards the body. ``up`` overrides the normal.
3. **Legs.** Sweeping a plane upwards from the ground, each foot's connected part of the
   surface below the plane grows as a tube until it meets another substantial part (the belly,
   the other leg of the pair): the leg is cut there, by that horizontal plane (the armpit or
   groin). Two legs that only touch (knees) are not the body: the sweep goes on past them.
4. **Forward.** The feet pair into fore and hind (the pairing with the shorter in-pair
   distances); the head end of the body axis is the end with more surface beyond its pair of
   feet (head and neck outweigh a tail). ``forward`` overrides the sign (and the axis).
5. **Head, neck, chest, abdomen.** See :func:`_split_torso` and :func:`_neck_cuts`: from where
   the skeleton of the front part bends, the neck is followed down as a tube; the head ends at
   its throat (its narrowest section, or towards the bend as that section lies further down the
   neck) and the neck where the
   tube flares into the chest (the knee of its section radius).

Everything is measured in units of the mesh's own size (√area), along its own detected axes,
so the labels do not change under rotation, mirroring or uniform scaling.
"""
from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np
import scipy.sparse as sparse
from scipy.sparse.csgraph import dijkstra

from allorules.body import UNLABELLED, Body, Frame, Labelling
from allorules.errors import SegmentationError
from allorules.mesh.geometry import plane_section_loops, smoothstep, vertex_areas
from allorules.mesh.topology import (
    directed_edges,
    face_adjacency,
    faces_mostly_in,
    vertex_components,
    vertex_graph,
)
from allorules.segment import body_plan
from allorules.segment.body_plan import SUPPORT_TOLERANCE, _find
from allorules.segment.regions import QUADRUPED_REGIONS

REGIONS = QUADRUPED_REGIONS
HEAD, NECK, CHEST, ABDOMEN, FORELIMBS, HINDLIMBS = range(6)
# Regions found when the mesh has them, after the six (segmentation.NEIGHBOUR_REGION folds them).
APPENDAGES = ("tail", "ears", "horns", "trunk")
ALL_REGIONS = REGIONS + APPENDAGES

SUBSTANTIAL_PART = 0.01     # of the surface area: smaller sublevel parts are bumps, not the body
# A pool of the surface (≥ POOL_PART of it, not a leg) that a leg's sweep takes in within POOL_RISE
# of its height above the foot below its cut is body, not leg: the flat chest between the
# forelegs, level with the armpits (the cow 381: 0.7 % of its surface, taken in 0.2-1.2 % of the
# leg's height below its cut), which had joined the two forelegs by a strip of chest.
POOL_PART = 0.001
POOL_RISE = 0.03

# A four-legged animal's proportions, as shares of its surface, with wide margins: over the 15 real
# animals of shared/meshes and the generated horse, elephant, giraffe and dog in 8 poses each
# (labelled right) the head took 3.6-22 %, each pair of legs 4.9-25 %, chest and abdomen together
# 35-74 %. A labelling outside these is not of a quadruped (a cartoon standing on two legs, its
# ears taken for hind feet, had a head of 0.2 % and hind limbs of 51 %): refused, never handed on.
MIN_HEAD_SHARE = 0.01
MAX_LEGS_SHARE = 0.40       # each pair
MIN_TORSO_SHARE = 0.15      # chest and abdomen together

# The chest's top above the abdomen's, across the trunk (along up less its part along the chord from
# the hind legs' centre to the fore legs'), over the abdomen's own depth there: a head cut through and
# left with the chest rises far above the back. Over 46 real animals labelled right and the
# generated horse and dog in seven poses: -0.09 to 0.40 (the Princeton horse 382 and a held-out
# horse; a giraffe 0.34, Spot 0.32, the dog sitting 0.23); a cartoon kitten whose big round head
# sits on its body with no neck, its face alone labelled head and the rest of its head chest, 1.43
# (scaled at ×2, its head grew with the chest's girth: a bobblehead).
MAX_CHEST_RISE = 0.8


def label_quadruped(body: Body, *, up=None, forward=None, complete: bool = True) -> Body:
    """Label a standing quadruped's vertices with the six regions of :data:`REGIONS`.

    Returns a new :class:`Body` with ``labels``, ``region_names = REGIONS`` and ``frame`` set to
    the detected (or given) ``Frame(up, forward)``. Raises :class:`SegmentationError` with a
    one-line reason when the mesh does not look like a standing quadruped, and (with
    ``complete``, the default) when any region was not found. ``complete=False`` returns the
    partial labelling instead, for diagnosis only.
    """
    vertices, faces = body.vertices, body.faces
    if len(vertices) < 50 or len(faces) < 50:
        raise SegmentationError(f"the mesh has only {len(vertices)} vertices; too coarse to find a quadruped's regions")
    if not np.isfinite(vertices).all():
        raise SegmentationError("the mesh has NaN or infinite vertex coordinates; prepare it first")
    up = _unit_or_none(up, "up")
    forward = _unit_or_none(forward, "forward")
    graph = vertex_graph(vertices, faces)
    mass = vertex_areas(vertices, faces)
    parts = vertex_components(graph)
    main_part = int(np.argmax(np.bincount(parts, weights=mass)))
    main = parts == main_part
    index = np.flatnonzero(main)
    sub_graph = graph[index][:, index]
    sub_vertices = vertices[index]
    sub_mass = mass[index]
    scale = float(np.sqrt(sub_mass.sum()))
    if not scale > 0:
        raise SegmentationError("the mesh has no surface area")
    # Work in units of the mesh's own size: nothing below depends on its absolute scale.
    sub_vertices = (sub_vertices - np.average(sub_vertices, axis=0, weights=sub_mass)) / scale
    sub_graph = sub_graph / scale
    local = np.full(len(vertices), -1, dtype=np.int64)
    local[index] = np.arange(len(index))
    sub_faces = local[faces[main[faces].all(axis=1)]]
    labels_main, frame, plan = _label_connected(sub_vertices, sub_faces, sub_graph, sub_mass, up, forward)
    labels = np.full(len(vertices), UNLABELLED, dtype=np.int64)
    labels[index] = labels_main
    if not main.all():  # small separate parts (eyes, teeth) take the label of the nearest body vertex
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(vertices[index]).query(vertices[~main])
        labels[~main] = labels_main[nearest]
    # Never hand on a body with a region missing: every later measurement would fail on it, or worse.
    missing = [name for index_of, name in enumerate(REGIONS) if not np.any(labels == index_of)]
    # The six always, then the appendages found (tail, ears, horns, trunk), in that order.
    found = [index_of for index_of in range(len(REGIONS), len(ALL_REGIONS)) if np.any(labels == index_of)]
    names = REGIONS + tuple(ALL_REGIONS[index_of] for index_of in found)
    renumber = np.arange(len(ALL_REGIONS) + 1) - 1   # slot 0: unlabelled (−1)
    for new, old in enumerate(found, start=len(REGIONS)):
        renumber[old + 1] = new
    labels = renumber[labels + 1]
    if missing and complete:
        raise SegmentationError(
            f"found no {' and no '.join(missing)} on this mesh; give the regions with {body_plan.BY_HAND}"
            + ("" if up is not None and forward is not None else ", or try --up/--forward")
        )
    if complete:
        _check_proportions(labels, vertex_areas(vertices, faces))
        _check_chest_rise(vertices, labels, frame.up)
    notes = tuple(f"{name} {value:+.2f}" for name, value in plan.cues.items())
    labelling = Labelling("segmenter auto-quadruped", dict(plan.confidence), ("head-tail cues: " + ", ".join(notes),))
    return Body(vertices, faces, labels, names, frame, labelling)


def _check_proportions(labels: np.ndarray, area: np.ndarray) -> None:
    """Refuse regions whose shares of the surface no four-legged animal has (see MIN_HEAD_SHARE)."""
    share = np.bincount(labels[labels >= 0], weights=area[labels >= 0], minlength=len(REGIONS)) / area.sum()
    wrong = []
    if share[HEAD] < MIN_HEAD_SHARE:
        wrong.append(f"head {share[HEAD]:.1%}")
    wrong += [f"{REGIONS[pair]} {share[pair]:.0%}" for pair in (FORELIMBS, HINDLIMBS) if share[pair] > MAX_LEGS_SHARE]
    if share[CHEST] + share[ABDOMEN] < MIN_TORSO_SHARE:
        wrong.append(f"chest and abdomen {share[CHEST] + share[ABDOMEN]:.0%}")
    if wrong:
        raise SegmentationError(
            f"the regions found are not a four-legged animal's ({', '.join(wrong)} of the surface): the mesh may "
            f"not stand on four legs, or ears or arms were taken for feet; give the regions with {body_plan.BY_HAND}")


def chest_rise(vertices: np.ndarray, labels: np.ndarray, up: np.ndarray) -> float | None:
    """How far the chest's top rises above the abdomen's, across the trunk, over the abdomen's depth
    (see MAX_CHEST_RISE); None without both."""
    chest, abdomen = vertices[labels == CHEST], vertices[labels == ABDOMEN]
    fore, hind = vertices[labels == FORELIMBS], vertices[labels == HINDLIMBS]
    if min(len(chest), len(abdomen), len(fore), len(hind)) < 3:
        return None
    chord = fore.mean(axis=0) - hind.mean(axis=0)
    across = up - (up @ chord) / max(chord @ chord, 1e-300) * chord
    if not np.linalg.norm(across) > 1e-9:
        return None
    across = across / np.linalg.norm(across)
    heights = abdomen @ across
    depth = float(heights.max() - heights.min())
    return float(((chest @ across).max() - heights.max()) / depth) if depth > 0 else None


def _check_chest_rise(vertices: np.ndarray, labels: np.ndarray, up: np.ndarray) -> None:
    """Refuse a chest that rises far above the back (MAX_CHEST_RISE): a head cut through."""
    rise = chest_rise(vertices, labels, np.asarray(up, dtype=float))
    if rise is not None and rise > MAX_CHEST_RISE:
        raise SegmentationError(
            f"the chest found rises far above the back ({rise:.2f} of the trunk's depth): a big head sitting on the "
            f"body may have been cut through and left with the chest; give the regions with {body_plan.BY_HAND}")


def _unit_or_none(direction, name: str) -> np.ndarray | None:
    if direction is None:
        return None
    direction = np.asarray(direction, dtype=float).reshape(-1)
    if direction.shape != (3,) or not np.isfinite(direction).all() or np.linalg.norm(direction) == 0:
        raise SegmentationError(f"--{name} must be a non-zero direction like 0,1,0 or +y")
    return direction / np.linalg.norm(direction)


def _label_connected(vertices, faces, graph, mass, up, forward):
    extremities = body_plan.read_extremities(graph, mass, vertices, faces)
    choice = body_plan.choose_feet(extremities, vertices, faces, mass, up, forward)
    feet = np.array(choice.fore_pair + choice.other_pair)
    distance = extremities.distance
    # Each leg is followed up from its foot by geodesic rings (they stay across the leg around a
    # bent knee) to where it meets the body, and cut there across its upper part; on an animal
    # standing on its feet, across the ground's normal: at its armpit or groin (_follow_legs).
    ground = up if up is not None else choice.ground
    settle = body_plan.settle_feet(up, forward)
    legs, axes, leg_tops = _follow_legs(vertices, faces, graph, mass, choice, distance, ground, settle)
    _check_leg_pairs(mass, legs, (choice.fore_pair, choice.other_pair), settle)
    if body_plan.head_taken_for_a_leg(extremities, legs, feet, vertices, faces) is not None:
        raise SegmentationError(
            "a leg found carries a pair of ears or horns: a head was taken for a foot (legs stretched out beside "
            f"it, as in a leap?), so the four feet are not certain; give the regions with {body_plan.BY_HAND}")
    top = body_plan.leg_top_distances(graph, legs, feet)
    first, second = body_plan.read_ends(extremities, top, graph, legs, leg_tops, choice.fore_pair, choice.other_pair,
                                        vertices, faces, mass, ground)
    body_plan.check_ends(first, second, settle)
    ends = body_plan.decide_head(first, second, forward, vertices)
    fore, hind = list(ends.head.pair), list(ends.tail.pair)
    up_given = up is not None
    if up is None:
        up = choice.ground if choice.ground is not None else up_from_legs(vertices, mass, feet, axes)
    chord = ends.head.centre - ends.tail.centre
    if forward is not None:
        flat = forward - (forward @ up) * up
        if np.linalg.norm(flat) < 1e-6:
            raise SegmentationError("--forward must not be parallel to up")
    else:
        flat = chord - (chord @ up) * up
        if np.linalg.norm(flat) < 1e-9:
            flat = chord
    forward_axis = flat / np.linalg.norm(flat)
    labels = np.full(len(vertices), UNLABELLED, dtype=np.int64)
    for foot in fore:
        labels[legs == foot] = FORELIMBS
    for foot in hind:
        labels[legs == foot] = HINDLIMBS
    # The torso runs along the ground's forward direction for an animal standing on its feet (as the
    # generator's planes do), along the chord between the girdles where it has no ground (rearing,
    # lying), and rises with that chord as far as it sits (its feet on one ground, its girdles far
    # from level: body_plan.seated_share).
    if not np.linalg.norm(chord) > 0:
        torso_axis = forward_axis
    elif choice.ground is not None or up_given:
        spine = body_plan.spine_direction(chord, up, forward_axis)
        torso_axis = spine / np.linalg.norm(spine)
    else:
        torso_axis = chord / np.linalg.norm(chord)
    head_tip = ends.head.main_tip
    if head_tip is None:   # a head that does not stick out: its farthest point from the tail's girdle
        from_tail = dijkstra(graph, indices=ends.tail.girdle)
        head_tip = int(np.argmax(np.where(ends.head.region, from_tail, -np.inf)))
    _split_torso(vertices, faces, graph, mass, torso_axis, labels, ends, head_tip)
    _head_holds_its_features(vertices, faces, graph, mass, labels, ends, head_tip, distance)
    _cut_appendages(vertices, faces, graph, mass, labels, ends, head_tip, distance)
    # Ears or horns left in the chest or abdomen: the head not found whole, or head and tail swapped.
    # Given --forward, the ends are the user's: a pair at the tail end is the tail's (a low-poly
    # horse's tail of strands, two of them left in the abdomen beside the one cut out as its tail).
    torso = (labels == CHEST) | (labels == ABDOMEN)
    if forward is not None:
        torso &= ~ends.tail.region
    if body_plan.features_in(extremities, torso, vertices, faces) is not None:
        # (without forward, a tail of strands is one such pair: told forward, the horse of strands is labelled)
        settle_head = f"give the regions with {body_plan.BY_HAND}" if forward is not None else body_plan.SETTLE
        raise SegmentationError(
            "a pair of ears or horns was labelled chest or abdomen: the head was not found whole (a trunk or a "
            f"muzzle taken for it, or a tail of strands?); {settle_head}")
    plan = body_plan.BodyPlan(
        fore=tuple(fore), hind=tuple(hind), fore_girdle=ends.head.girdle, hind_girdle=ends.tail.girdle,
        head_tip=head_tip, tail_tip=ends.tail.main_tip, head_features=tuple(t for pair in ends.head.mirror_pairs for t in pair),
        distance=distance, cues=dict(ends.cues),
        confidence=body_plan.confidence(choice, ends, forward is not None))
    return labels, Frame(up=up, forward=forward_axis), plan


LEG_RINGS = 90          # geodesic rings followed up each leg


LEG_UPRIGHT = 30.0      # degrees: a leg of a standing animal within this of the ground's normal is cut level


def _follow_legs(vertices, faces, graph, mass, choice, distance, ground, settle: str):
    """Legs of an animal in any pose: (per-vertex foot id, each leg's upper axis, each leg's top).

    From each foot, the rings of geodesic distance s run across the leg, also around a bent knee.
    Their length P(s) stays near the leg's girth until they reach the body, where it grows fast:
    the junction is the knee of P's running maximum (past its narrowest ring), as for the neck.
    All of the leg below the junction's ring is leg (the core); from there the leg is swept along
    its upper part's axis (the direction of the rings' centres just below the junction) as a
    standing leg is swept upwards (:func:`_cut_legs`): it ends where it meets the body. On an
    animal standing on its feet (``ground``: the ground's normal), a leg whose upper part is within
    LEG_UPRIGHT of upright is swept along the normal: cut level at its armpit or groin, the
    convention of docs/segmentation.md. A foot whose leg cannot be followed is refused with
    ``settle`` (how to settle the feet).
    """
    feet = [int(f) for f in choice.fore_pair + choice.other_pair]
    axes, tops, cores, ring_centres = {}, {}, {}, {}
    for foot in feet:
        pair, other = (choice.fore_pair, choice.other_pair) if foot in choice.fore_pair else (choice.other_pair, choice.fore_pair)
        branch = int(np.argmin(distance[pair[0]] + distance[pair[1]] + 0.1 * (distance[other[0]] + distance[other[1]])))
        followed = _follow_tip(vertices, faces, graph, foot, distance[foot], 1.5 * float(distance[foot][branch]))
        if followed is None:
            raise SegmentationError("a leg could not be followed up from one of the four feet found, so they may not be "
                                    f"the animal's feet; {settle}")
        cores[foot], axis, ring_centres[foot] = followed[:3]
        if ground is not None and axis @ ground > np.cos(np.radians(LEG_UPRIGHT)):
            axis = np.asarray(ground, dtype=float)
        axes[foot] = axis
    cut = {}
    legs = _cut_legs(vertices, faces, graph, mass, np.array(feet), axes, cores, cut)
    for foot in feet:   # the top: the rings' centre line carried up to the cut
        origin = vertices[foot] @ axes[foot]
        tops[foot] = ring_centres[foot] + (origin + cut[foot] - ring_centres[foot] @ axes[foot]) * axes[foot]
    return legs, axes, tops


def _follow_tip(vertices, faces, graph, tip, field, span):
    """Follow a protrusion (leg, tail, ear, horn) up from its tip by the rings of the geodesic
    distance ``field`` from it, up to ``span``: (core, axis, ring centre, length) or None.

    The rings' length P(s) stays near the protrusion's girth until they reach what it grows from,
    where it grows fast: the junction is the knee of P's running maximum (:func:`_profile_knee`).
    The core is the tip's part below the ring one girth-radius before the junction; the axis the
    direction of the rings' centres over the last 40 % before it (pointing away from the tip);
    ``length`` the junction's distance from the tip in radii of its ring; ``root`` the point one
    radius along the axis past the last ring's centre and ``reach`` the distance from the tip within
    which the protrusion ends (the junction plus three radii).
    """
    levels = np.linspace(0.0, span, LEG_RINGS + 1)[1:]
    perimeter, centres = isocontour_profile(vertices, faces, field, levels)
    perimeter = _moving_average(perimeter, 3)
    junction = _profile_knee(levels, perimeter)
    if junction is None:
        return None
    radius = max(perimeter[junction] / (2 * np.pi), levels[0])
    below = max(int(np.searchsorted(levels, levels[junction] - radius)), 1)
    lower = max(int(np.searchsorted(levels, 0.6 * levels[below])), 0)
    axis = centres[below] - centres[lower]
    if not np.linalg.norm(axis) > 0:
        return None
    axis = axis / np.linalg.norm(axis)
    core = field < levels[below]
    parts = vertex_components(graph, core)
    root = centres[below] + radius * axis   # where the ring reaches what it grows from
    return core & (parts == parts[tip]), axis, centres[below], float(levels[junction] / radius), root, float(levels[junction] + 3 * radius)


def _profile_knee(track, values) -> int | None:
    """Index where a profile that stays level then grows fast starts to grow: past its narrowest
    value (before its largest), the point of its running maximum farthest below the chord to the
    running maximum's top (no threshold)."""
    values = np.asarray(values, dtype=float)
    if len(values) < 4 or not values.max() > 0:
        return None
    start = int(np.argmax(values > 0))
    widest = int(np.argmax(values))
    if widest <= start:
        return None
    narrowest = start + int(np.argmin(values[start:widest + 1]))
    grown = np.maximum.accumulate(values[narrowest:])
    top = int(np.argmax(grown))
    if top < 2:
        return None
    along = track[narrowest:] - track[narrowest]
    chord = grown[0] + along * ((grown[top] - grown[0]) / along[top])
    return narrowest + int(np.argmax((chord - grown)[:top + 1]))


LEG_PAIR_MISMATCH = 0.5   # two legs of a pair whose areas differ more than this (of the larger) are not a pair


def _check_leg_pairs(mass, legs, pairs, settle: str) -> None:
    """The two legs of a pair are mirror images: refuse when their areas are far apart (an ear or
    a trunk taken for a leg)."""
    for pair in pairs:
        areas = [float(mass[legs == foot].sum()) for foot in pair]
        if max(areas) <= 0 or abs(areas[0] - areas[1]) > LEG_PAIR_MISMATCH * max(areas):
            raise SegmentationError(
                f"the two legs found for a pair are not alike (areas {min(areas) / max(max(areas), 1e-300):.0%} of each "
                f"other), so the four feet are not certain; {settle}")




def up_from_legs(vertices, mass, feet, axes) -> np.ndarray:
    """Up for an animal not standing on all four feet: the normal of a plane through three feet
    that nothing lies below (the ground it rests on) closest to the legs' mean direction, or that
    direction itself."""
    rough = np.sum([axes[int(foot)] for foot in feet], axis=0)
    rough /= np.linalg.norm(rough)
    centroid = np.average(vertices, axis=0, weights=mass)
    best, best_cosine = rough, np.cos(np.radians(45.0))
    for three in itertools.combinations(feet, 3):
        points = vertices[list(three)]
        normal = np.cross(points[1] - points[0], points[2] - points[0])
        if np.linalg.norm(normal) < 1e-12:
            continue
        normal /= np.linalg.norm(normal)
        if (centroid - points[0]) @ normal < 0:
            normal = -normal
        heights = (vertices - points[0]) @ normal
        if heights.min() < -SUPPORT_TOLERANCE * heights.max():
            continue
        if normal @ rough > best_cosine:
            best, best_cosine = normal, normal @ rough
    return best


# ---------------------------------------------------------------- extremities

# ---------------------------------------------------------------- feet and up

# ---------------------------------------------------------------- legs

def _cut_legs(vertices, faces, graph, mass, feet, axes, cores=None, levels_out=None, strict=True) -> np.ndarray:
    """Per-vertex foot id (−1 off the legs): each foot's part of the surface below its cut plane.

    Each leg is swept along its own axis (``axes[foot]``, from the foot up the leg: up for a
    standing leg, slanted for a swung one): sub-level sets of the height along that axis,
    union–find. The foot's part stops growing at the first height where it meets another
    substantial part (area ≥ SUBSTANTIAL_PART of the surface, or holding another foot): that
    height is the leg's cut, a plane across the leg at its armpit or groin. A smaller pool it took
    in just below its cut is left out (:func:`_without_pools`). Two legs that only
    touch (knees, hocks) are not the body: when the foot's part meets another foot's and, just
    above the meeting, the section across the axis still shows them as two separate loops, the
    sweep goes on. Where two legs claim the same vertices (touching legs), each goes to the
    geodesically nearest foot.

    ``cores`` (foot → mask): a part of the leg known already (below a bent knee), joined to the
    foot's part before the sweep starts. ``levels_out`` (dict) receives each foot's cut height.
    ``strict=False``: a tip whose part never meets another is left out instead of refused.
    """
    n = len(vertices)
    substantial = SUBSTANTIAL_PART * mass.sum()
    indptr, indices = graph.indptr, graph.indices
    is_foot = np.zeros(n, dtype=bool)
    is_foot[feet] = True
    adjacency = None
    claimed = np.zeros((len(feet), n), dtype=bool)
    for k, foot in enumerate(int(f) for f in feet):
        axis = axes[foot]
        height = (vertices - vertices[foot]) @ axis
        order = np.argsort(height, kind="stable")
        parent = np.full(n, -1, dtype=np.int64)
        area = np.zeros(n)
        holds_foot = np.zeros(n, dtype=bool)
        level = None
        pools = []                  # (height, pool, the foot's part) where the foot's part took in a pool
        core = cores.get(foot) if cores else None
        if core is not None:
            members = np.flatnonzero(core)
            parent[members] = foot
            area[foot] = mass[members].sum()
            holds_foot[foot] = True
            order = order[~core[order]]
        for v in order:
            roots = list({_find(parent, u) for u in indices[indptr[v]:indptr[v + 1]] if parent[u] >= 0})
            mine = [r for r in roots if _find(parent, foot) == r] if parent[foot] >= 0 else []
            if mine:
                others = [r for r in roots if r != mine[0] and (holds_foot[r] or area[r] >= substantial)]
                if others:
                    if all(holds_foot[r] for r in others):
                        if adjacency is None:
                            adjacency = face_adjacency(faces)
                        touching = _legs_touch(vertices, faces, adjacency, height, axis, parent, mine + others, v)
                    else:
                        touching = False
                    if not touching:
                        level = height[v]
                        break
                taken = [r for r in roots if r != mine[0] and not holds_foot[r] and area[r] >= POOL_PART * mass.sum()]
                if taken:
                    processed, root_of = _processed_roots(parent)
                    pools.append((height[v], processed[np.isin(root_of, taken)], processed[root_of == mine[0]]))
            parent[v] = v
            area[v] = mass[v]
            holds_foot[v] = is_foot[v]
            for r in roots:
                parent[r] = v
                area[v] += area[r]
                holds_foot[v] |= holds_foot[r]
        if level is None:
            if not strict:
                continue
            raise SegmentationError("a leg could not be separated from the body (no level where it meets it); give "
                                    f"the regions with {body_plan.BY_HAND}")
        below = height < level
        if core is not None:
            below |= core
        parts = vertex_components(graph, below)
        claimed[k] = below & (parts == parts[foot])
        far = [pool for pool in pools if level - pool[0] > POOL_RISE * (level - height[foot])]
        grown = _pool_grown_into_body(graph, mass, claimed[k], far, substantial)
        if grown is not None:   # the leg met the body there: cut where it did
            level = far[grown][0]
            claimed[k] = np.zeros(n, dtype=bool)
            claimed[k][far[grown][2]] = True
            pools = [pool for pool in pools if pool[0] < level]
        near = [pool for pool in pools if level - pool[0] <= POOL_RISE * (level - height[foot])]
        if near:
            claimed[k] = _without_pools(graph, claimed[k], near)
        if levels_out is not None:
            levels_out[foot] = float(level)
    legs = np.full(n, -1, dtype=np.int64)
    count = claimed.sum(axis=0)
    for k, foot in enumerate(feet):
        legs[claimed[k] & (count == 1)] = int(foot)
    shared = np.flatnonzero(count > 1)
    if len(shared):   # legs that touch: the shared part goes to the geodesically nearest foot
        union = np.flatnonzero(count > 0)
        local = {int(v): i for i, v in enumerate(union)}
        distance = dijkstra(graph[union][:, union], indices=[local[int(f)] for f in feet])
        nearest = np.asarray(feet)[np.argmin(distance, axis=0)]
        legs[shared] = nearest[[local[int(v)] for v in shared]]
    return legs


def _processed_roots(parent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices a sweep has processed so far (``parent`` ≥ 0) and the root of each's part."""
    processed = np.flatnonzero(parent >= 0)
    return processed, np.array([_find(parent, u) for u in processed], dtype=np.int64)


def _without_pools(graph, claimed: np.ndarray, pools) -> np.ndarray:
    """``claimed`` without the pools a leg's sweep took in just below its cut: each claimed vertex
    goes to the nearer (along the surface) of the leg as it was before the first of them and the
    pools; the vertices of the leg's side are kept."""
    pool = np.zeros(len(claimed), dtype=bool)
    for _, members, _ in pools:
        pool[members] = True
    return _leg_side(graph, claimed, pools[0][2], pool)


def _leg_side(graph, claimed: np.ndarray, leg: np.ndarray, pool: np.ndarray) -> np.ndarray:
    """The vertices of ``claimed`` nearer (along the surface within it) to the ``leg`` vertices
    than to the ``pool`` mask's."""
    source = np.zeros(len(claimed), dtype=bool)
    source[leg] = True
    inside = np.flatnonzero(claimed)
    sources = np.flatnonzero((source | pool)[inside])
    _, _, nearest = dijkstra(graph[inside][:, inside], indices=sources, min_only=True, return_predecessors=True)
    kept = np.zeros(len(claimed), dtype=bool)
    reached = nearest >= 0
    kept[inside[reached]] = source[inside[nearest[reached]]]
    return kept


def _pool_grown_into_body(graph, mass, claimed: np.ndarray, pools, substantial: float) -> int | None:
    """The first pool a leg's sweep took in (a part smaller than ``substantial`` when the leg met it)
    that had grown into the body by the leg's cut: the part of ``claimed`` nearer to it than to the
    leg as it was when they met is ``substantial`` or more. None where every pool stayed small.

    How large a part is when the leg meets it depends on the tessellation (lumped vertex areas of
    a thin strip): the camel's belly met its forelegs at 1.25 % of the surface as it comes and at
    0.92 % subdivided, and the subdivided forelegs ran on along the belly to the hind legs."""
    for index, (_, members, leg) in enumerate(pools):
        pool = np.zeros(len(claimed), dtype=bool)
        pool[members] = True
        if mass[claimed & ~_leg_side(graph, claimed, leg, pool)].sum() >= substantial:
            return index
    return None


def _legs_touch(vertices, faces, adjacency, height, up, parent, foot_roots, v) -> bool:
    """Whether the feet's parts meeting at vertex v only touch: in sections across ``up`` (the
    sweep's axis; ``height`` is along it) a little
    (two typical edge heights) and one leg radius above v, the loops nearest each part's top are
    different loops (legs that go on separately), not one (the body that joins them)."""
    step = 2 * float(np.median(np.abs(height[faces[:, 0]] - height[faces[:, 1]])))
    processed, root_of = _processed_roots(parent)
    tops = []
    for root in foot_roots:
        mine = processed[root_of == root]
        band = mine[height[mine] >= min(height[v] - step, height[mine].max())]   # never empty
        tops.append((vertices[band].mean(axis=0), height[band].mean()))
    rise = step
    for _ in range(2):
        loops, radius = set(), 0.0
        for top, top_height in tops:
            point = top + (height[v] + rise - top_height) * up
            section = _section_loop(vertices, faces, adjacency, point, up)
            if section is None:
                return False
            loops.add(int(section[2].min()))   # loops are disjoint sets of faces: the smallest names one
            radius = max(radius, float(np.sqrt(section[0] / np.pi)))
        if len(loops) < len(tops):
            return False
        rise = max(radius, step)
    return True


# ---------------------------------------------------------------- torso

LEAK_SHARE = 0.01   # a head or neck cut with more of its area than this behind the middle plane leaks
MIN_HEAD_CUT = 0.025   # a head cut smaller than this share of the surface is a snout's tip: the neck's cut is the head's
NECK_BAND = 0.05       # but for this share of it at its base, the neck
SHORT_NECK_REACH = 1.2  # where both cuts were a snout's, the rings' neck ends 1.2 × the throat's distance from the tip


def _split_torso(vertices, faces, graph, mass, axis, labels, ends, head_tip) -> None:
    """Label the rest (not legs): head, neck, chest, abdomen. Fills ``labels`` in place.

    Chest/abdomen: the plane across ``axis`` (hind girdle → fore girdle) half way between the two
    girdles. Head and neck: the section loops of :func:`_neck_cuts`, followed from ``head_tip``,
    cut them off the front (each the part connected to the head tip beyond its loop, see
    :func:`_beyond_loop`); a cut with more than LEAK_SHARE of its area behind the middle plane
    leaks into the body and is not used. A head cut under MIN_HEAD_CUT of the surface is a snout's
    tip: what the neck's cut took off is the head, but for a band at its base (NECK_BAND); where
    both cuts together took off less than that, both were the muzzle's, and the rings decide the
    head, its neck kept short (SHORT_NECK_REACH). Where the cuts give no head or no neck, the rings
    from the head tip decide them (:func:`_ring_head_and_neck`). The tail (behind the hind legs)
    stays with the abdomen here; :func:`_cut_appendages` takes it out.
    """
    rest = np.flatnonzero(labels == UNLABELLED)
    along = vertices @ axis
    middle = 0.5 * (ends.head.centre + ends.tail.centre) @ axis
    in_rest = np.zeros(len(vertices), dtype=bool)
    in_rest[rest] = True
    labels[in_rest & (along >= middle)] = CHEST
    labels[in_rest & (along < middle)] = ABDOMEN
    head_cut, neck_cut = _neck_cuts(vertices, faces, graph, rest, head_tip, np.flatnonzero(labels == FORELIMBS))
    if head_cut is not None:
        adjacency = face_adjacency(faces)
        for (point, normal), region in ((neck_cut, NECK), (head_cut, HEAD)):
            beyond = _beyond_loop(vertices, faces, graph, adjacency, point, normal, in_rest, head_tip)
            if beyond is None or mass[beyond & (along < middle)].sum() > LEAK_SHARE * mass[beyond].sum():
                continue   # the loop does not cut the front off (or leaks into the body): leave it
            labels[beyond] = region
    front_cut = (labels == HEAD) | (labels == NECK)
    if front_cut.any() and mass[front_cut].sum() < MIN_HEAD_CUT * mass.sum():
        # both cuts took off a snout's tip (the pig 383 grazing, its head lowered: head and neck
        # 1.7 % of the surface, the rest of its head and its ears labelled chest): the bends were
        # the muzzle's; the rings from the head tip decide head and neck instead, the neck no
        # longer than a fifth of the head (SHORT_NECK_REACH): an animal whose neck the cuts did not
        # find shows little of it, and the rings alone made the pig's forequarters neck (15 % of
        # its surface, 4.8 % standing)
        labels[front_cut & (along >= middle)] = CHEST
        labels[front_cut & (along < middle)] = ABDOMEN
        _ring_head_and_neck(vertices, faces, graph, mass, labels, in_rest & ends.head.region, head_tip, along, middle,
                            neck_reach=SHORT_NECK_REACH)
    merged = bool((labels == HEAD).any() and (labels == NECK).any()
                  and mass[labels == HEAD].sum() < MIN_HEAD_CUT * mass.sum())
    if merged:
        # a head of a snout's tip: the bend was the muzzle's, and what the neck's cut took off is
        # the head itself on an animal with no visible neck (the pig 383 decimated to 6,000
        # vertices: head 1.1 % of the surface, "neck" 20 %; as it comes, its ears took the head
        # back to 21 %, neck 0.1 %); the rings would make its forequarters neck. The head is
        # what the neck's cut took off, but for its base (NECK_BAND of it, by area, along the
        # cut's normal): a neck as short as the animal shows
        point, normal = neck_cut
        neck = np.flatnonzero(labels == NECK)
        depth = (vertices[neck] - point) @ normal
        order = np.argsort(depth)
        base = np.cumsum(mass[neck][order]) <= NECK_BAND * mass[neck].sum()
        base[0] = True                     # a neck of a few faces at least, never none
        labels[neck[order[~base]]] = HEAD
    if not merged and not ((labels == HEAD).any() and (labels == NECK).any()):
        _ring_head_and_neck(vertices, faces, graph, mass, labels, in_rest & ends.head.region, head_tip, along, middle)


def _ring_head_and_neck(vertices, faces, graph, mass, labels, front, head_tip, along, middle,
                        neck_reach: float | None = None) -> None:
    """Head and neck when the skeleton's bend gave none (a head held low, a neck the tube-following
    loses): the rings of geodesic distance from the head tip over the front end (``front``, beyond
    the fore legs' plane). Their length grows over the head and narrows at the throat: the head is
    the tip's part within the narrowest ring past the head's widest (in the first 60 % of the way;
    without a narrowing, 40 % of the way), the neck the rest of the front end (with ``neck_reach``,
    only what lies within that many times the throat's distance from the tip; the rest stays as
    labelled)."""
    if not front[head_tip]:
        return
    index = np.flatnonzero(front)
    local = np.full(len(vertices), -1)
    local[index] = np.arange(len(index))
    field = np.full(len(vertices), np.inf)
    field[index] = dijkstra(graph[index][:, index], indices=local[head_tip])
    reach = float(field[np.isfinite(field)].max())
    levels = np.linspace(0.0, reach, PROFILE_LEVELS + 1)[1:]
    front_faces = faces[front[faces].all(axis=1)]
    perimeter, _ = isocontour_profile(vertices, front_faces, field, levels)
    perimeter = _moving_average(perimeter, 5)
    first = max(int(0.6 * len(levels)), 2)
    widest = int(np.argmax(perimeter[:first]))
    throat = widest + int(np.argmin(perimeter[widest:first]))
    if throat in (widest, first - 1):   # no narrowing after the head's widest ring
        throat = int(0.4 * len(levels))
    inside = front & (field < levels[throat])
    parts = vertex_components(graph, inside)
    head = inside & (parts == parts[head_tip])
    neck = front & ~head
    if neck_reach is not None:        # the neck ends this many times the throat's distance from the tip
        neck &= field < neck_reach * levels[throat]
    if not neck.any() or mass[front & (along < middle)].sum() > LEAK_SHARE * mass[front].sum():
        return
    labels[head] = HEAD
    labels[neck] = NECK


# An ear or horn is narrow beside its tip's distance from the head tip: the features followed on
# the shared and held-out animals have ring radii up to 0.22 of it, and roots up to 1.17 times as far
# from the head tip as their tips. A faceted bison's ears, its face sloping down into its hump, were
# followed up its face into the hump (radius 0.99 of it, root 2.2 times as far): the head taken back
# to that "root" took its throat and hump, 29 % of its surface. A feature that wide is taken to end
# ROOT_BEYOND_TIP times its tip's distance from the head tip.
FEATURE_RADIUS = 0.5
ROOT_BEYOND_TIP = 1.25
TWIN_ROOTS_APART = 1.25   # a mirrored pair's root reaches this far apart, or more: one was followed past its root


def features_reach(reaches: dict[int, float], mirror_pairs) -> float:
    """How far from the head tip the head reaches to hold its ears and horns, given each feature's
    root reach (its root's distance from the tip plus its radius): the farthest, where a mirrored
    pair whose reaches lie TWIN_ROOTS_APART or more apart counts at its nearer twin's. Twins' roots
    lie alike (the generated elephant's horns 0.42 and 0.44), but a flap lying against the body is
    followed past its root: a realistic elephant's ear hanging over its shoulder had its root found
    as far back as its fore legs' tops (reach 0.70 from the trunk's tip, its twin's 0.52), and its
    head and neck then ran on into its abdomen and it was refused. A twin that was not followed
    leaves the other its own reach; 0 without features."""
    paired: dict[int, float] = {}
    for a, b in mirror_pairs:
        if a in reaches and b in reaches:
            near, far = sorted((reaches[a], reaches[b]))
            counted = near if far >= TWIN_ROOTS_APART * near else far
            paired[a], paired[b] = max(paired.get(a, 0.0), counted), max(paired.get(b, 0.0), counted)
    return max((paired.get(tip, value) for tip, value in reaches.items()), default=0.0)


def _head_holds_its_features(vertices, faces, graph, mass, labels, ends, head_tip, distance) -> None:
    """Ears and horns grow from the head: when the head/neck cut left one of them in the neck (an
    animal with no visible neck, whose bend is the muzzle's), the head is taken back to just
    behind the farthest one's root: every vertex of the head or neck nearer (geodesically) to the
    head tip than that root plus the root's radius, and the features themselves (a horn bent back
    or down reaches farther from the head tip than its root). A feature whose rings ran into the
    head itself (FEATURE_RADIUS) ends ROOT_BEYOND_TIP times its tip's distance from the head tip.
    The neck keeps what lies behind, or, where nothing does, a band at its base.

    When the cut took only a trunk or a muzzle and left the ears in the chest behind it (the
    realistic elephant: its head and ears labelled chest, its trunk head), the head is taken back
    the same way out of the chest, and the neck is the band of the chest behind it, out to
    SHORT_NECK_REACH times the head's reach from its tip (an animal whose neck no cut found shows
    little of it), unless the two would reach the abdomen."""
    field = distance.get(head_tip)
    if field is None:
        return
    features = np.zeros(len(vertices), dtype=bool)
    twins = {t for pair in ends.head.mirror_pairs if (labels[list(pair)] == CHEST).all() for t in pair}
    reaches = {}
    for tip in ends.head.features:
        if not (labels[tip] == NECK or tip in twins) or tip not in distance:
            continue
        followed = _follow_tip(vertices, faces, graph, tip, distance[tip], float(distance[tip][ends.head.girdle]))
        if followed is None:
            continue
        core, axis, centre, length, root, _ = followed
        radius = float(np.linalg.norm(root - centre))
        if radius >= FEATURE_RADIUS * field[tip]:   # its rings ran into the head itself: its root lies
            reaches[tip] = ROOT_BEYOND_TIP * float(field[tip])   # about as far from the head tip as its tip
            continue
        nearest = int(np.argmin(np.linalg.norm(vertices - root, axis=1)))
        reaches[tip] = float(field[nearest]) + radius
        features |= core   # and the feature itself: a horn bent back reaches farther from the nose than its root
    reach = features_reach(reaches, ends.head.mirror_pairs)
    if reach <= 0:
        return
    front = np.isin(labels, (HEAD, NECK, CHEST) if twins else (HEAD, NECK)) & ((field < reach) | features)
    parts = vertex_components(graph, front)
    head = front & (parts == parts[head_tip])
    if (labels[head] == NECK).all():
        return
    if twins:
        chest = np.isin(labels, (NECK, CHEST))
        band = chest & ~head & (field < SHORT_NECK_REACH * reach)
        parts = vertex_components(graph, band | head)
        band &= parts == parts[head_tip]
        touching = np.asarray(graph @ (band | head).astype(float)).ravel() > 0
        if not band.any() or (touching & (labels == ABDOMEN)).any():
            return   # no neck behind it, or a head and neck that run on into the abdomen: left as cut
        labels[labels == NECK] = CHEST
        labels[head] = HEAD
        labels[band] = NECK
        return
    neck = np.flatnonzero(labels == NECK)
    if mass[(labels == NECK) & ~head].sum() < NECK_BAND * mass[neck].sum():
        # the features' roots lie behind (almost) all of the neck (the pig 383 rearing, its head
        # raised: its ears reach back past the neck's cut, and the head took every neck vertex, or
        # all but one on its working mesh; refused for "no neck", or a neck with no face that the
        # run could neither measure nor hold): the neck is the band at the base of what the cut
        # made neck, NECK_BAND of it by area, the farthest from the head tip, and the ring of neck
        # vertices next to it (a band one vertex wide has no face of its own)
        order = np.argsort(-field[neck])
        base = np.cumsum(mass[neck][order]) <= NECK_BAND * mass[neck].sum()
        base[0] = True
        band = np.zeros(len(labels), dtype=bool)
        band[neck[order[base]]] = True
        band |= (np.asarray(graph @ band.astype(float)).ravel() > 0) & (labels == NECK)
        head &= ~band
    labels[head] = HEAD


# A nose followed as a tube this many of its radii before the head is a trunk: the generated
# elephant's trunk is 7.2-9.1 of them long; a wolf's upper jaw, its mouth open, 3.3 (walking or
# galloping, its head turned: labelled a trunk with 3) and the legs 4.3-4.6.
TRUNK_LENGTH = 5.0
TUBE_LENGTH = 3.0         # a tail hanging against the rump is its tube, when that tube is this many of its radii long
APPENDAGE_SHARE = 0.4     # an ear or horn cut larger than this share of the head is not one
TRUNK_SHARE = 0.7         # nor a trunk larger than this share (the head is more than its nose)
TAIL_SHARE = 0.3          # nor a tail larger than this share of the torso
TAIL_TUBE_SHARE = 0.5     # ... but a tail its rings follow as a tube up to this (a fox's bushy tail: 0.39)
TAIL_ROOT_SPREAD = 2.0    # a tail's root reaches at most this many of its radii from its axis


def _cut_appendages(vertices, faces, graph, mass, labels, ends, head_tip, distance) -> None:
    """Take the tail out of the torso, ears, horns and a trunk out of the head (labels in place).

    Each is followed from its tip by geodesic rings to where it grows from (:func:`_follow_tip`)
    and cut by the plane across its root there: the tail end's most prominent tip when it sticks
    out prominently (not its main tip: a pig's curly tail is thinner than a bump on its rump, which
    the head-or-tail cues take as that end's protrusion); the head's features (flat: ears; thin
    tubes: horns); the head tip when it is the end of a tube at least TRUNK_LENGTH radii long (a
    trunk). A cut is kept only within the region it grows from (torso, head), and an ear or horn
    only when it is smaller than APPENDAGE_SHARE of the head, a trunk TRUNK_SHARE of what the ears
    and horns left of it, a tail TAIL_SHARE of the torso (its tube alone TAIL_TUBE_SHARE), and only
    while the body without them is still one piece (:func:`_a_leaf`).
    """
    tail_index, ears_index, horns_index, trunk_index = (ALL_REGIONS.index(name) for name in APPENDAGES)
    cuts = []
    tail = ends.tail
    if tail.protrudes:   # from the tail end's most prominent tip: the tail is what sticks out most there
        torso_area = mass[(labels == CHEST) | (labels == ABDOMEN)].sum()
        cuts.append((tail.prominent_tip, tail.girdle, (CHEST, ABDOMEN), tail_index, TAIL_SHARE * torso_area))
    head = labels == HEAD
    head_area = mass[head].sum()
    for tip, kind in ends.head.features.items():
        cuts.append((tip, ends.head.girdle, (HEAD,), ears_index if kind == "flat" else horns_index, APPENDAGE_SHARE * head_area))
    cuts.append((head_tip, ends.head.girdle, (HEAD,), trunk_index, None))   # its largest: when it is cut
    for tip, girdle, within, index, largest in cuts:
        if labels[tip] not in within:
            continue
        field = distance.get(tip)
        if field is None:
            continue
        followed = _follow_tip(vertices, faces, graph, tip, field, float(field[girdle]))
        if followed is None:
            continue
        core, axis, centre, length, root, reach = followed
        if index == trunk_index and length < TRUNK_LENGTH:
            continue
        # all of it below its junction's ring, and what the tip reaches below the plane across its
        # root (a sweep would run on into a body that is not below the root, as a leg's belly is);
        # a tail's within TAIL_ROOT_SPREAD of its radii of its axis: a raised tail's root plane
        # tilts, and on the tip's side of it lay the back of the bull 386's rump, a third of its
        # tail region (the head's features are bounded by APPENDAGE_SHARE: the pig 388's ears, held
        # to their axis, passed it with the cheeks under them)
        offset = vertices - root
        below = (field < reach) & (offset @ axis < 0)
        if index == tail_index:
            across = np.linalg.norm(offset - np.outer(offset @ axis, axis), axis=1)
            below &= across < TAIL_ROOT_SPREAD * np.linalg.norm(root - centre)
        candidate = core | below
        parts = vertex_components(graph, candidate)
        region = candidate & (parts == parts[tip])
        region &= np.isin(labels, within)
        if index == trunk_index:
            region &= head
            # against the head as the ears' and horns' cuts left it: a head whose ears are a third
            # of it must not become all trunk (the cow 381 Loop-subdivided, its muzzle a tube)
            largest = TRUNK_SHARE * mass[labels == HEAD].sum()
        # a tail tip followed for fewer than TUBE_LENGTH of its radii is a bump on the rump (a cow's
        # tailhead; real tails run 4.9-33 radii on the shared animals): what it reaches below its
        # root is the rump itself, not a tail (the cow 381 decimated to 4,164 vertices: 1.1 radii, a
        # "tail" of 16 % of its surface, where as it comes its 1.7 radii reached past TAIL_SHARE)
        bump = index == tail_index and length < TUBE_LENGTH
        if bump or (largest is not None and mass[region].sum() > largest):
            # what the tip reaches below its root ran on into the body (a tail hanging against the
            # rump, geodesically near all of it): the tail is its tube alone, if it has one
            region = _tube(vertices, faces, graph, tip, field, float(field[girdle])) if index == tail_index else None
            if region is None:
                continue
            region &= np.isin(labels, within)
            largest = TAIL_TUBE_SHARE * torso_area
        if not region.any() or (largest is not None and mass[region].sum() > largest):
            continue
        labels[region] = index
    # Appendages hang from the body: where the head's, taken together, would hold it on (the two
    # ears of the realistic elephant), they stay head, a kind at a time, both ears alike.
    for index in (ears_index, horns_index, trunk_index):
        if not _a_leaf(faces, graph, mass, np.isin(labels, (tail_index, ears_index, horns_index, trunk_index))):
            labels[labels == index] = HEAD


def _a_leaf(faces, graph, mass, region: np.ndarray) -> bool:
    """Whether the body without ``region`` (the appendages; as the measures and a run's held parts
    take it: every corner of its faces, those with most of their corners in it) is still one piece,
    LEAF_SHARE of its area in one part: ears, horns, a trunk and a tail hang from the body. The
    realistic elephant's ears, their roots wrapped round the back of its head, took the head's sides
    with them, so that the head hung on the neck through its two ears: a run held the ears as a
    neck between them (the head their "children", moved rigidly) and their mass missed isometric by
    0.04."""
    taken = np.zeros(len(region), dtype=bool)
    taken[faces[faces_mostly_in(faces, region)].ravel()] = True
    rest = ~(region | taken)
    if not rest.any():
        return False
    parts = vertex_components(graph, rest)
    shares = np.bincount(parts[rest], weights=mass[rest])
    return bool(shares.max() >= LEAF_SHARE * shares.sum())


LEAF_SHARE = 0.99   # the body without its appendages keeps this share of its area in one piece
TUBE_GROWTH = 2.0   # a tube ends where its rings grow to this many times its narrowest ring's radius


def _tube(vertices, faces, graph, tip, field, span) -> np.ndarray | None:
    """The tube that ends at ``tip`` (a mask), or None where the tip ends no tube.

    The rings of the geodesic distance ``field`` from the tip: past the tip's cap a tube's rings
    lie farther from the tip than twice their radius (on a cap, a bump or a flat surface they do
    not). The tube is the tip's side of the first ring, past the narrowest such ring (before the
    widest), whose radius is TUBE_GROWTH times the narrowest's; it is at least TUBE_LENGTH of
    its radii long. Tighter than :func:`_follow_tip`'s core where the rings spread onto the body
    gradually (a tail hanging against the rump), and nothing for a bump (a cow's tailhead).
    """
    levels = np.linspace(0.0, span, LEG_RINGS + 1)[1:]
    perimeter, _ = isocontour_profile(vertices, faces, field, levels)
    radius = perimeter / (2 * np.pi)
    widest = int(np.argmax(radius))
    along = np.flatnonzero((levels[:widest + 1] > 2 * radius[:widest + 1]) & (radius[:widest + 1] > 0))
    if not len(along):
        return None
    narrowest = int(along[np.argmin(radius[along])])
    grown = np.flatnonzero(radius[narrowest:] > TUBE_GROWTH * radius[narrowest])
    if not len(grown):
        return None
    end = levels[narrowest + int(grown[0]) - 1]
    if end < TUBE_LENGTH * radius[narrowest]:
        return None
    inside = field < end
    parts = vertex_components(graph, inside)
    return inside & (parts == parts[tip])


def _beyond_loop(vertices, faces, graph, adjacency, point, normal, allowed, tip):
    """Vertices on the tip's side of the section loop through ``point`` (⟂ ``normal``).

    Only the loop around ``point`` cuts, not the whole plane: the graph loses the edges that
    cross the plane inside that loop's faces, and the tip's connected part (within
    ``allowed``) is returned as a boolean mask, or None if the loop is not found.
    """
    section = _section_loop(vertices, faces, adjacency, point, normal)
    if section is None:
        return None
    side = (vertices - point) @ normal > 0
    loop_faces = faces[section[2]]
    edges = directed_edges(loop_faces)
    edges = edges[side[edges[:, 0]] != side[edges[:, 1]]]
    cut = sparse.coo_matrix((np.ones(2 * len(edges)), (np.concatenate([edges[:, 0], edges[:, 1]]),
                                                        np.concatenate([edges[:, 1], edges[:, 0]]))),
                            shape=graph.shape).tocsr()
    kept = (graph - graph.multiply(cut > 0)).tocsr()
    kept.eliminate_zeros()
    # On the plane's tip side only: where the loop does not close (a hole in the mesh), the cut
    # is the plane near it; a bulge in front of the plane elsewhere (a horse's breast) is only
    # reached across the plane, so it stays with the body.
    allowed = allowed & side
    if not allowed[tip]:
        return None
    parts = vertex_components(kept, allowed)
    return allowed & (parts == parts[tip])


def isocontour_profile(vertices, faces, field, levels):
    """Length and centroid of the isocontour of a per-vertex field at each level (marching
    triangles, :func:`allorules.segment.body_plan.isocontour_segments`)."""
    lengths = np.zeros(len(levels))
    centroids = np.zeros((len(levels), 3))
    for k, level in enumerate(levels):
        start, end = body_plan.isocontour_segments(vertices, faces, field, level)
        segment = np.linalg.norm(end - start, axis=1)
        lengths[k] = segment.sum()
        if lengths[k] > 0:
            centroids[k] = (0.5 * (start + end) * segment[:, None]).sum(axis=0) / lengths[k]
    return lengths, centroids


PROFILE_LEVELS = 160
BEND_SHARE = 6             # the bend is measured between chords of 1/BEND_SHARE of the profile
MIN_NECK_LENGTH = 1.0      # a neck runs at least one of its radii from the bend to its base
MIN_NARROWING = 0.25       # a neck that narrows over fewer of its radii does not count as narrowing
BEND_TIE = 0.9             # as sharp: at least this share of its turn


def _neck_cuts(vertices, faces, graph, rest, head_tip, forelimb):
    """(head cut, neck cut) as (point, normal) planes, normals towards the head tip, or
    (None, None) if no neck is found.

    1. The skeleton of the front part: centroids C(s) of the isocontours of the geodesic
       distance s from the head tip (the most forward non-leg vertex), up to where the
       isocontours reach the forelimbs.
    2. Head/neck: where that skeleton bends (the head's axis meets the neck's); the turn at s
       is the angle between the chords C(s) − C(s − w) and C(s + w) − C(s), w a fixed share
       (1/BEND_SHARE) of the profile; candidates are checked for a neck behind them.
    3. Neck base: the neck is followed as a tube from the bend (:func:`_follow_neck`); its
       section radius r(t) grows slowly (the taper) until the sections enter the chest. The
       base is the knee of r(t). The neck cut is the tube's section there.
    4. The head cut is the tube's section at the throat: its narrowest section when that lies
       well in the head's part of the neck (the throatlatch), the bend when it lies near the
       chest, and between the two in between (``THROAT_SHARE``).
    Only the section loops cut (see :func:`_beyond_loop`), so a bulge of the chest in front of
    a plane stays chest.
    """
    tip_local = int(np.flatnonzero(rest == head_tip)[0])
    sub = graph[rest][:, rest]
    distance_local = dijkstra(sub, indices=tip_local)
    distance = np.full(len(vertices), np.inf)
    distance[rest] = distance_local
    finite = np.isfinite(distance)
    faces = faces[finite[faces].all(axis=1)]
    near_forelimb = np.unique(graph[forelimb].indices)
    near_forelimb = near_forelimb[finite[near_forelimb]]
    span = float(distance[near_forelimb].min()) if len(near_forelimb) else float(distance[finite].max())
    shoulders = vertices[near_forelimb]   # where the forelimbs meet the body
    levels = np.linspace(0, span, PROFILE_LEVELS + 2)[1:-1]
    step = levels[1] - levels[0]
    field = np.where(finite, distance, np.inf)
    perimeter, centroids = isocontour_profile(vertices, faces, field, levels)
    if not perimeter.max() > 0:
        return None, None
    perimeter = _moving_average(perimeter, 5)
    centroids = _moving_average(centroids, 5)
    # The bend is measured between chords of a fixed share of the profile: the head and the
    # neck each span a good part of it, while the muzzle's stop or an ear bends the skeleton
    # only over a short stretch.
    w = max(2, len(levels) // BEND_SHARE)
    turn = np.zeros(len(levels))
    for k in range(w, len(levels) - w):
        before = centroids[k] - centroids[k - w]
        after = centroids[k + w] - centroids[k]
        norms = np.linalg.norm(before) * np.linalg.norm(after)
        if norms > 0:
            turn[k] = np.arccos(np.clip(before @ after / norms, -1.0, 1.0))
    # Candidate bends: the local maxima of the turn at least half as sharp as the sharpest, the
    # sharpest first, each followed down its neck (see _follow_neck): from the head/neck bend the
    # sections first narrow (from the back of the head into the neck) and the tube then runs at
    # least MIN_NECK_LENGTH of its radii before flaring into the chest. The sharpest bend with such
    # a long neck (else the sharpest) sets the bar; of the bends about as sharp (BEND_TIE), the one
    # whose neck narrows over the most radii wins, if over MIN_NARROWING (less is noise). A camel's
    # S-shaped neck bends sharply again where it enters the chest, and from there the sections only
    # grow: the camel Loop-subdivided to 200k has two bends equally sharp, 74.9° there and 74.1° at
    # the head, whose sections narrow over 0.13 and 1.6 radii. The pig 383's snout bends as sharply
    # as its head, and from the snout the whole head runs on as a "neck" 7 radii long that narrows
    # over 0.14-0.28 of them with the resolution, while from its head's bend the neck narrows over
    # 0.31-0.46 and runs half a radius. Decimated to 2,500 vertices its head's bend (72.9°, as
    # sharp as the snout's 76.5°) narrows over 0.31 radii; a short neck's narrowing counted only
    # where no long neck narrowed, and a less sharp bend's long one did (0.50), so the snout won
    # (head 0.205 of the surface, 0.123 as it comes); now the head's bend does (0.145). Where the
    # snout bends much more sharply (86° at 3,500 vertices, the head 72.5°) the snout still wins.
    # Where none narrows, the bar's bend.
    peaks = [k for k in range(1, len(levels) - 1)
             if turn[k] >= turn[k - 1] and turn[k] > turn[k + 1] and turn[k] >= 0.5 * turn.max()]
    peaks.sort(key=lambda k: -turn[k])
    adjacency = face_adjacency(faces)
    found = []
    for bend in peaks:
        neck_direction = centroids[bend + w] - centroids[bend]
        if not np.linalg.norm(neck_direction) > 0:
            continue
        neck_direction = neck_direction / np.linalg.norm(neck_direction)
        neck = _follow_neck(vertices, faces, adjacency, centroids[bend], neck_direction, step, span, shoulders)
        if neck is None:   # the plane at the bend may cut the back of the head too: start a little down the neck
            later = min(bend + w // 2, len(centroids) - 1)
            neck = _follow_neck(vertices, faces, adjacency, centroids[later], neck_direction, step, span, shoulders)
        if neck is None:
            continue
        found.append((bend, neck_direction, neck))
    if not found:
        return None, None
    # Where no bend's neck narrows over MIN_NARROWING, a narrowing below it is noise and does not
    # pick the bend either: the wolf grazing, its head hanging, bends 90° at the back of its head
    # into a thick neck that only widens (0.00), and a bend halfway down its face "narrowed" 0.04
    # into the back of its head, so its head was cut in two and its neck labelled chest.
    narrows = any(neck.narrowing >= MIN_NARROWING for _, _, neck in found)
    necks = [candidate for candidate in found
             if (candidate[2].narrowing > 0 or not narrows) and candidate[2].length >= MIN_NECK_LENGTH]
    if not necks and narrows:
        # No neck runs MIN_NECK_LENGTH, but one narrows: that bend, not the sharpest. A blocky fox
        # split twice at its edges' midpoints (the same surface) bends 49° at its muzzle, whose
        # "neck" never narrows, and 19° at the back of its head, whose neck narrows over 0.50 radii
        # and runs 0.99 of them (1.04 on the fox split once): the muzzle won, and its head was
        # labelled chest, ears and all.
        necks = [candidate for candidate in found if candidate[2].narrowing >= MIN_NARROWING]
    chosen = necks[0] if necks else found[0]
    as_sharp = [candidate for candidate in found if turn[candidate[0]] >= BEND_TIE * turn[chosen[0]]]
    narrowing = [candidate for candidate in as_sharp if candidate[2].narrowing >= MIN_NARROWING]
    if narrowing:
        chosen = max(narrowing, key=lambda candidate: candidate[2].narrowing)
        # Two bends that narrow into the same section (within its radius) lead into one neck: the
        # one nearer the tip counts the stretch of head between them as narrowing too, so the
        # farther is the head's end. The lion lying, its mane as thick as its head: a bend at its
        # muzzle narrowed over 1.51 radii, the one at the back of its head over 1.10 into the same
        # section; the muzzle's won and 0.6 of its head was labelled neck (walking, the back's).
        chosen = max((candidate for candidate in narrowing
                      if np.linalg.norm(candidate[2].narrowest - chosen[2].narrowest) <= chosen[2].narrowest_radius),
                     key=lambda candidate: candidate[0])
    bend, neck_direction, neck = chosen
    base_point, base_direction, throat = neck.base, neck.base_direction, neck.throat
    # The head cut: at the throat (the neck's narrowest section in its head half, else the bend;
    # see _follow_neck), across the neck's axis as the tube-following found it (the chord from
    # the bend to the base), not the first chord after the bend, which still leans into the head.
    axis = base_point - centroids[bend]
    if np.linalg.norm(axis) > 0:
        neck_direction = axis / np.linalg.norm(axis)
    return (throat, -neck_direction), (base_point, -base_direction)


THROAT_SHARE = (0.3, 0.7)   # the narrowest section this share of the neck from the bend: the throat; from here on: the bend
SHOULDER_SHARE = 0.25   # a neck base with more of the forelimbs' junction than this on its head side reaches over the shoulders


LOST_SECTION = 0.6   # a section under this share of the one before it is not the tube's (see _follow_neck)
LOST_STEPS = 3       # ... stepped over up to this many in a row; one more and the tube is lost


class _Neck(NamedTuple):
    """A neck followed from a bend (:func:`_follow_neck`); lengths in radii of its narrowest section."""

    base: np.ndarray             # the centre of the section where it enters the chest
    base_direction: np.ndarray   # the tube's direction there (away from the head)
    length: float                # from the bend to the base
    narrowing: float             # from the bend to the narrowest section
    throat: np.ndarray           # where the head is cut off
    narrowest: np.ndarray        # the centre of the narrowest section
    narrowest_radius: float


def _follow_neck(vertices, faces, adjacency, start, direction, step, span, shoulders=None) -> _Neck | None:
    """Follow a tube from ``start`` along ``direction``: the neck it finds (:class:`_Neck`), or None.

    Each step cuts the surface with the plane through the current axis point perpendicular to
    the current direction, takes the loop around the point (its equivalent radius r and its
    centre), and steps on from that centre; the direction is the chord from ``start`` (a point of
    the skeleton) to the current centre (beyond two radii), so the axis follows a gently bent neck
    without turning into the chest. (From the first section's centre instead, the chord turned the
    horse 387's axis by 46° at 200k vertices: that section, at the bend, ran round the back of the
    head, its centre far from the neck's axis; the sections then cut the neck lengthwise and its base
    was found a fifth of the way down.) r changes slowly along the neck (its taper) and fast where
    the sections enter the chest: the base is the knee of r(t), past the narrowest section, of r's
    running maximum: the point farthest below the chord to its top (no threshold).

    The neck ends where the forelimbs begin: when more than SHOULDER_SHARE of ``shoulders`` (the
    points where the forelimbs meet the body) lie on the head's side of the base's section, the
    neck has been followed over the shoulders into the chest (a pig's, a donkey's or a bull's thick
    neck widens into the forequarters with no knee before them), and the knee is sought again
    among the sections up to the first that has any of them on its head's side; where they show
    none, the neck ends at that section.
    """
    point = start
    travelled, radii, centres, directions = [], [], [], []
    distance_so_far = 0.0
    lost = 0
    for _ in range(4 * PROFILE_LEVELS):
        section = _section_loop(vertices, faces, adjacency, point, direction)
        if section is None:
            break
        area, centre, _ = section
        r = float(np.sqrt(area / np.pi))
        if radii and r < LOST_SECTION * radii[-1]:
            # not the tube's section: a step is a few hundredths of a radius, and no neck narrows by
            # two fifths over one; the plane has slipped into a gap or an open mouth (its loop,
            # nested in the head's, is the one around the point). Stepped over, up to LOST_STEPS.
            lost += 1
            if lost > LOST_STEPS:
                break
            point = point + step * direction
            distance_so_far += step
            continue
        lost = 0
        travelled.append(distance_so_far)
        radii.append(r)
        centres.append(centre)
        directions.append(direction)
        if distance_so_far > span:
            break
        chord = centre - start
        if np.linalg.norm(chord) > 2 * r:
            direction = chord / np.linalg.norm(chord)
        point = centre + step * direction
        distance_so_far += step
    if len(radii) < 3:
        return None
    radii, travelled = np.array(radii), np.array(travelled)
    found = _neck_knee(radii, travelled)
    head_on_chest = found is None
    if head_on_chest:   # no knee past the widest section: a head wider than the chest? (see _neck_knee)
        found = _neck_knee(radii, travelled, head_wider=True)
    if found is not None and shoulders is not None and len(shoulders):
        ahead = np.array([float(np.mean((shoulders - centre) @ axis < 0)) for centre, axis in zip(centres, directions)])
        clear = int(np.argmax(ahead > 0))   # the first section with a shoulder point on the head's side
        if ahead[found[0]] > SHOULDER_SHARE and clear > 0:
            found = _neck_knee(radii[:clear + 1], travelled[:clear + 1]) or (clear, int(np.argmin(radii[:clear + 1])))
        elif (travelled[found[1]] < MIN_NARROWING * radii[found[1]]
              and travelled[found[0]] < MIN_NECK_LENGTH * radii[found[1]] and clear > found[0]):
            # No narrowing and no knee a neck's length from the bend: the sections widen at once and
            # steadily, up to the chest's girth (the TOSCA horse standing, its head low: 0.048 to
            # 0.13 over 80 sections, then level), and the knee below the chord fell half a radius
            # from the bend. The neck ends where that widening levels off (the knee above the
            # chord), at the shoulders at the latest. (A neck that narrows first keeps its knee:
            # the low-poly dog's, 0.97 radii from its bend, ran on into its chest this way.)
            flare = _flare_end(radii[:clear + 1], travelled[:clear + 1], found[1])
            if flare is not None and travelled[flare] >= MIN_NECK_LENGTH * radii[found[1]]:
                found = (flare, found[1])
    if found is None:
        return None
    base, narrowest = found
    # The throat: the narrowest section when it lies well in the head's part of the neck, the
    # bend itself when it lies near the chest (a lion's, under its mane: no throat), and between
    # the two in between, so that the head's end moves smoothly with where the narrowest section
    # falls (a choice of one or the other at half the neck gave the dog 389 a head 0.129 of its
    # surface at 9k vertices and 0.073 at 200k: its narrowest section at 0.50 and 0.53 of the neck).
    share = travelled[narrowest] / max(travelled[base], np.finfo(float).tiny)
    weight = float(smoothstep((THROAT_SHARE[1] - share) / (THROAT_SHARE[1] - THROAT_SHARE[0])))
    if head_on_chest:   # all that narrows from the bend is the head's: it ends at the narrowest section
        weight = 1.0
    throat = weight * centres[narrowest] + (1.0 - weight) * np.asarray(start, dtype=float)
    return _Neck(centres[base], directions[base], travelled[base] / radii[narrowest],
                 travelled[narrowest] / radii[narrowest], throat, centres[narrowest], float(radii[narrowest]))


def _neck_knee(radii: np.ndarray, travelled: np.ndarray, head_wider: bool = False) -> tuple[int, int] | None:
    """(base, narrowest): indices of the neck's base (the knee of the section radius's running
    maximum past the narrowest section) and of its narrowest section, or None (no knee).

    The narrowest section is the narrowest before the widest (the chest). With ``head_wider``, a
    head wider than the chest sits on it with no neck between (a cartoon kitten's big round head,
    0.17 against its chest's 0.13): the sections only narrow from the bend to where it meets the
    chest, then grow a little, and the widest is the first; the chest is then where the sections
    have grown most over the narrowest before them."""
    if len(radii) < 3:
        return None
    chest = np.argmax(radii - np.minimum.accumulate(radii)) if head_wider else np.argmax(radii)
    narrowest = int(np.argmin(radii[:int(chest) + 1]))
    above = _above_chord(radii, travelled, narrowest)
    if above is None or radii[narrowest] <= 0:
        return None
    return narrowest + int(np.argmax(-above)), narrowest


def _above_chord(radii: np.ndarray, travelled: np.ndarray, narrowest: int) -> np.ndarray | None:
    """How far r's running maximum past the narrowest section (a dip where a plane slips between
    two bulges is not the neck again) lies above the chord from there to where it first reaches its
    top, at each section up to that top; None where it does not rise over two sections. Its knee
    (farthest below) is a neck's base, its farthest above where a widening levels off."""
    grown = np.maximum.accumulate(radii[narrowest:])
    top = int(np.argmax(grown))
    if top < 2:
        return None
    along = travelled[narrowest:] - travelled[narrowest]
    chord = grown[0] + along * ((grown[top] - grown[0]) / along[top])
    return (grown - chord)[:top + 1]


def _flare_end(radii: np.ndarray, travelled: np.ndarray, narrowest: int) -> int | None:
    """Where a widening that levels off does so: past the narrowest section, the point of r's
    running maximum farthest above its chord (:func:`_above_chord`; None where it does not rise)."""
    above = _above_chord(radii, travelled, narrowest)
    return None if above is None else narrowest + int(np.argmax(above))


def _section_loop(vertices, faces, adjacency, point, normal):
    """(area, centre, faces) of the loop of the plane section through ``point`` (⟂ ``normal``)
    nearest ``point``, or None where the plane misses the surface.

    The faces the plane crosses form one ring per loop (joined through shared edges,
    :func:`allorules.mesh.geometry.plane_section_loops`); the loop around ``point`` is taken (the
    smallest, if nested), else the loop whose length-weighted centre is nearest ``point``.
    Area = |½ Σ (p_k − o) × (q_k − o) · n| over its oriented segments p_k → q_k (o any point of
    the plane: ``point``).
    """
    normal = np.asarray(normal, dtype=float) / np.linalg.norm(normal)
    start, end, crossed, loop_of = plane_section_loops(vertices, faces, adjacency, point, normal)
    if len(crossed) < 3:
        return None
    length = np.linalg.norm(end - start, axis=1)
    middle = 0.5 * (start + end)
    loops = loop_of.max() + 1
    weight = np.bincount(loop_of, weights=length, minlength=loops)
    centre = np.column_stack([np.bincount(loop_of, weights=middle[:, i] * length, minlength=loops)
                              for i in range(3)]) / np.maximum(weight, 1e-300)[:, None]
    # The loop around the point (winding number ±1 about it in the plane), the smallest if
    # several are nested; else the loop whose centre is nearest (a point not inside the surface).
    u, w = start - point, end - point
    angle = np.arctan2(np.cross(u, w) @ normal, np.einsum("ij,ij->i", u, w))
    winding = np.abs(np.bincount(loop_of, weights=angle, minlength=loops)) / (2 * np.pi)
    areas = np.abs(0.5 * np.column_stack([np.bincount(loop_of, weights=np.cross(u, w)[:, i], minlength=loops)
                                          for i in range(3)]) @ normal)
    around = np.flatnonzero(winding > 0.5)
    if len(around):
        nearest = int(around[np.argmin(areas[around])])
    else:
        nearest = int(np.argmin(np.linalg.norm(centre - point, axis=1)))
    mine = loop_of == nearest
    area = float(areas[nearest])
    return area, centre[nearest], crossed[mine]


def _moving_average(values, width):
    """Centred moving average along the first axis, the ends padded with the end values."""
    values = np.asarray(values, dtype=float)
    pad = width // 2
    padded = np.concatenate([np.repeat(values[:1], pad, axis=0), values, np.repeat(values[-1:], pad, axis=0)])
    kernel = np.ones(width) / width
    if values.ndim == 1:
        return np.convolve(padded, kernel, mode="valid")
    return np.column_stack([np.convolve(padded[:, i], kernel, mode="valid") for i in range(values.shape[1])])
