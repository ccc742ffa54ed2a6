"""Measurements of a body and its regions (METHOD §3): masses, lengths, girths, peak stress.

All quantities are used only as ratios (before/after a scaling step), so density cancels and a
mass is a volume. The public names the rules engine calls are :func:`body_mass`,
:func:`region_mass`, :func:`region_length`, :func:`region_girth` and :func:`peak_stress`.

- Volumes: divergence theorem on the surface with every open boundary loop capped by a fan
  around its centroid (caps exist for measuring only).
- Cross-sections: closed isocontour loops of a field that runs along the part
  (:mod:`allorules.measure.sections`): the part's own Fiedler vector for limbs and other regions, planes
  across the torso axis for the chest and abdomen.
- Lengths: diameter of the region's skeleton; mean over the parts of a paired region (a pair
  that comes out as one piece with two feet is split into its legs). Fields and skeletons are
  taken with the part's holes (holes of the body's surface, not cuts) capped.
- Peak stress σ = M / A with A the smallest limb cross-section away from the junction and the tip.

Expensive derived things (region parts, fields, sections) are kept in ``body.cache``, which is
valid only for the body's exact vertices. See docs/measurements.md for the definitions.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from allorules.body import Body
from allorules.errors import MeasurementError
from allorules.measure.cache import measured
from allorules.measure.parts import (
    LIMB_REGIONS,
    SECTION_COUNT,
    RegionPart,
    carry_fields,
    part_fields,
    region_parts,
)
from allorules.measure.sections import (
    Loop,
    area_quantile_levels,
    boundary_loops,
    isocontour_loops,
    isocontour_stack,
)
from allorules.mesh.geometry import (
    affine_misfit,
    rotation_between,
    similarity_fit,
    smoothstep,
    vertex_areas,
)

# Share of a limb's area at its far end (the foot: a hoof, a wide sole) that a limb's skeleton
# does not cut into sections: the field along the leg flattens across a sole, where its
# isocontours wander and split. The skeleton's tip reaches the foot's far end from the last
# section before it (sections.end_point).
FOOT_SHARE = 0.1

# A limb's reach (:func:`limb_reach`) below FOLDED_REACH[0] is folded (a hind leg under a sitting
# animal: 0.17-0.53 on the generated and shared animals), above FOLDED_REACH[1] straight (standing:
# 0.83-1.0); lying and rearing legs lie between (0.63-0.85). A folded leg's junction -> foot chord
# says nothing of its direction: the posture turns it by its whole centre line instead
# (allorules.solve.posture) and its tilt is its centre line's turn (:func:`posture_change`).
FOLDED_REACH = (0.5, 0.8)


# ---------------------------------------------------------------------------------------------
# Volumes


# ---------------------------------------------------------------------------------------------
# Region parts


# ---------------------------------------------------------------------------------------------
# Limbs and cross-sections


@dataclass
class Section:
    """A cross-section of a limb: a loop, how far along the limb it is, and where it was taken."""

    loop: Loop
    distance: float   # along the limb's skeleton from the junction
    fraction: float   # distance / limb length: 0 at the junction, 1 at the tip

    @property
    def area(self) -> float:
        return self.loop.area

    @property
    def girth(self) -> float:
        return self.loop.girth


@dataclass
class Limb:
    """One limb (a part of a limb region) cut across from its junction with the body to its tip."""

    region: str
    part: int
    sections: list[Section]   # ordered junction → tip
    junction: np.ndarray      # centroid of the junction (the part's largest open boundary)
    tip: np.ndarray           # vertex where the field is largest (the foot's tip)
    length: float             # junction → section centroids → tip
    field: np.ndarray         # per part vertex, grows from junction to tip
    levels: np.ndarray        # field level of each section
    mesh: RegionPart
    junction_loop: Loop | None = None   # the junction's open boundary (None: the field's lowest vertex)

    @property
    def clear_level(self) -> float:
        """The field level from which the limb is clear of its junction: the highest field value on
        the junction loop, which a slanted junction (an armpit, a groin) spreads over a range of
        levels (the Princeton horse 382's foreleg: a quarter of its length), else the field's lowest.
        Whatever moves the leg and not the body must be 0 up to here, or it tears the rim."""
        if self.junction_loop is not None and self.junction_loop.vertex_ids is not None:
            return float(self.field[self.junction_loop.vertex_ids].max())
        return float(self.field.min())

    @property
    def clear_fraction(self) -> float:
        """The share of the limb's length (from the junction's centroid) at :attr:`clear_level`."""
        return float(np.interp(self.clear_level, self.levels, [section.fraction for section in self.sections]))

    @property
    def centroids(self) -> np.ndarray:
        """The centroids of the cross-sections, junction to tip, (sections, 3): the leg's centre line."""
        return np.array([section.loop.centroid for section in self.sections])

    def moved(self, part: RegionPart) -> "Limb":
        """The same limb (same loops, junction and tip) on a moved copy ``part`` of its mesh."""
        loops = [section.loop.moved(part.vertices) for section in self.sections]
        junction_loop = None if self.junction_loop is None else self.junction_loop.moved(part.vertices)
        junction = part.vertices[int(np.argmin(self.field))] if junction_loop is None else junction_loop.centroid
        tip = part.vertices[int(np.argmax(self.field))]
        sections, length = _chain_sections(junction, loops, tip)
        return Limb(self.region, self.part, sections, junction, tip, length, self.field, self.levels, part, junction_loop)

    def offsets_across(self) -> tuple[np.ndarray, np.ndarray]:
        """Each part vertex's offset from the limb's centre line, across the line, and how far
        along the limb it is (0 up to where it is clear of its junction's rim, then the share of the
        length from there, 1 at the tip), as ((n, 3), (n,)).

        The centre line is the sections' centroids as a function of the field; a vertex's point on
        it is interpolated at the vertex's field value (held at the first or last section beyond
        them, the foot below the last) and the line's direction there is taken out of the offset,
        so that scaling the offsets thickens the limb without lengthening it. A limb with fewer
        than two sections has no line: zero offsets."""
        count = len(self.mesh.vertices)
        if len(self.sections) < 2:
            return np.zeros((count, 3)), np.zeros(count)
        levels, centroids = self.levels, self.centroids
        fractions = np.array([section.fraction for section in self.sections])
        on_line = np.column_stack([np.interp(self.field, levels, centroids[:, axis]) for axis in range(3)])
        direction = np.gradient(centroids, levels, axis=0)
        direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), np.finfo(float).tiny)
        along = np.column_stack([np.interp(self.field, levels, direction[:, axis]) for axis in range(3)])
        along /= np.maximum(np.linalg.norm(along, axis=1, keepdims=True), np.finfo(float).tiny)
        offsets = self.mesh.vertices - on_line
        offsets -= np.einsum("ij,ij->i", offsets, along)[:, None] * along
        # 0 up to where the limb is clear of its junction's rim, then the share of the length left
        # (a slanted rim can end a quarter of the way down; counted from the junction's centroid,
        # the share jumped by that much across the rim's last edges and tore the shoulder)
        clear = self.clear_fraction
        tip = max(float(self.field.max()), float(levels[-1]) + 1e-12)
        share = np.interp(self.field, np.append(levels, tip), np.append(fractions, 1.0))    # 1 at the tip
        along = np.clip((share - clear) / (1.0 - clear), 0.0, 1.0) if clear < 1.0 else np.zeros(count)
        return offsets, along

    def section_at(self, fraction: float) -> Section:
        """The cross-section at ``fraction`` of the limb's length (0 junction, 1 tip), recomputed exactly."""
        if not self.sections:
            raise MeasurementError(f"no closed cross-section found on {self.region!r} part {self.part}")
        fractions = np.asarray([section.fraction for section in self.sections])
        fraction = float(np.clip(fraction, fractions[0], fractions[-1]))
        level = float(np.interp(fraction, fractions, self.levels))
        loops = isocontour_loops(self.mesh.vertices, self.mesh.faces, self.field, level)
        if not loops:
            nearest = int(np.argmin(np.abs(fractions - fraction)))
            return self.sections[nearest]
        return Section(loops[0], fraction * self.length, fraction)


def _limb(part: RegionPart, index: int, field: np.ndarray) -> Limb:
    levels = area_quantile_levels(part.vertices, part.faces, field, SECTION_COUNT)
    loops, kept_levels = [], []
    for level, found in zip(levels, isocontour_stack(part.vertices, part.faces, field, levels)):
        if found:
            loops.append(found[0])   # the main cross-section (longest loop) at this level
            kept_levels.append(level)
    boundaries = boundary_loops(part.vertices, part.faces)
    tip = part.vertices[int(np.argmax(field))]
    junction_loop = max(boundaries, key=lambda loop: loop.girth) if boundaries else None
    junction = part.vertices[int(np.argmin(field))] if junction_loop is None else junction_loop.centroid
    sections, length = _chain_sections(junction, loops, tip)
    return Limb(part.region, index, sections, junction, tip, length, field, np.asarray(kept_levels), part, junction_loop)


def _chain_sections(junction: np.ndarray, loops: list[Loop], tip: np.ndarray) -> tuple[list[Section], float]:
    """Sections along the chain junction → loop centroids → tip, and the chain's length."""
    chain = [junction] + [loop.centroid for loop in loops] + [tip]
    steps = np.linalg.norm(np.diff(np.asarray(chain), axis=0), axis=1)
    distances = np.cumsum(steps)
    length = float(distances[-1])
    sections = [Section(loop, float(d), float(d / length) if length > 0 else 0.0) for loop, d in zip(loops, distances[:-1])]
    return sections, length


def limb_sections(body: Body, region: str) -> list[Limb]:
    """The limbs of a region (one per part), each cut into cross-sections from junction to tip.

    The field is the limb's own Fiedler vector (METHOD §3: a global Fiedler vector does not cut
    legs across), oriented to grow from the junction (the part's largest open boundary) to the
    tip. One loop per level, the longest where a level has several.
    """
    cache = measured(body)
    if region not in cache.limbs:
        parts = region_parts(body, region)
        carried = cache.carried.limbs.get(region) if cache.carried else None
        if carried is not None:   # the reference's limbs, re-measured on the moved parts
            cache.limbs[region] = [limb.moved(part) for limb, part in zip(carried, parts)]
        else:
            fields = part_fields(body, region)
            cache.limbs[region] = [_limb(part, index, field) for index, (part, field) in enumerate(zip(parts, fields))]
    return cache.limbs[region]


# ---------------------------------------------------------------------------------------------
# Posture: how the limbs stand


def stance_down(limbs: list[Limb], frame=None) -> np.ndarray:
    """'Down' for an animal standing on its legs, whatever the mesh's orientation: −``frame.up``
    when the body has a frame (the labeller's is the normal of the plane the feet stand on),
    else the direction the legs point, shoulders to feet (the sum of their junction → tip axes;
    tilted where the legs slant, as a dog's hind legs do)."""
    down = -np.asarray(frame.up, dtype=float) if frame is not None else np.sum([limb.tip - limb.junction for limb in limbs], axis=0)
    return down / np.linalg.norm(down)


def limb_reach(limb: Limb) -> float:
    """How far a limb reaches for its length: the straight distance from its junction to its last
    section's centroid over the centre line's length between them (1 for a straight leg; measured
    on the shared animals standing 0.83-1.0, lying or rearing 0.63-0.85, a hind leg folded under a
    sitting animal 0.17-0.53). 1 for a limb with no section."""
    if not limb.sections:
        return 1.0
    line = np.vstack([limb.junction, limb.centroids])
    length = float(np.linalg.norm(np.diff(line, axis=0), axis=1).sum())
    return float(np.linalg.norm(line[-1] - line[0]) / length) if length > 0 else 1.0


def limb_bend(limb: Limb) -> float:
    """How far a limb's centre line strays from straight: the largest distance of a section
    centroid from the line junction → last section's centroid, as a share of that line's length
    (0 for a straight leg; a uniform scaling or a turn leaves it as it is). The foot tip is left
    out: it is one vertex, at the toe, and a hoof's toe sits off the leg's line."""
    if len(limb.sections) < 2:
        return 0.0
    centroids = limb.centroids
    chord = centroids[-1] - limb.junction
    reach = float(np.linalg.norm(chord))
    if reach == 0.0:
        return 0.0
    offsets = centroids - limb.junction
    across = offsets - np.outer(offsets @ chord / reach ** 2, chord)
    return float(np.linalg.norm(across, axis=1).max() / reach)


def fold_turn(before: Limb, after: Limb) -> float:
    """How far a limb's fold opened or closed from ``before`` to ``after``, in degrees: the angle
    of its lower half's turn against its upper half's, each the best rotation of its sections'
    loops (the first half of the sections and the rest; their many points, so that a section that
    jumps at the fold, a level cutting thigh and shin at once, counts for little). 0 under any
    similarity and for a leg swung as a whole; a knee bent by 30° reads about 30°. 0 for a limb
    with fewer than four sections."""
    count = min(len(before.sections), len(after.sections))
    if count < 4:
        return 0.0

    def turn(sections: slice) -> np.ndarray:
        _, rotation, _ = similarity_fit(np.vstack([section.loop.points for section in before.sections[sections]]),
                                        np.vstack([section.loop.points for section in after.sections[sections]]))
        return rotation

    upper, lower = turn(slice(0, count // 2)), turn(slice(count // 2, count))
    return float(np.degrees(Rotation.from_matrix(upper.T @ lower).magnitude()))


def line_rotation(start: Limb, end: Limb) -> np.ndarray:
    """The rotation taking a limb's centre line (its junction and section centroids) on ``start``
    to the same limb's on ``end``: that of the best similarity between them (a folded leg's turn,
    where its short chord says nothing)."""
    _, rotation, _ = similarity_fit(np.vstack([start.junction, start.centroids]),
                                    np.vstack([end.junction, end.centroids]))
    return rotation


def straight_share(limb: Limb) -> float:
    """How much of a limb's turn is its chord's (junction → foot tip): 1 for a straight leg, 0 for
    a folded one, smooth between (its :func:`limb_reach` across :data:`FOLDED_REACH`).

    A folded leg's chord (sitting, lying) is short beside its length, so the smallest change of
    its fold turns the chord by degrees: turned back by its chord each step, the folded legs of
    the generated dog sitting at ×0.5 were pressed into the ground (hind leg length exponent
    −0.75 for 0.336). Its whole centre line's turn (:func:`line_rotation`) is a swing undone,
    not a change of the fold taken for one."""
    low, high = FOLDED_REACH
    return float(smoothstep(np.array((limb_reach(limb) - low) / (high - low))))


def limb_turn(before: Limb, after: Limb) -> np.ndarray:
    """The rotation, as a rotation vector, by which a limb turned from ``before`` to ``after``:
    the smallest rotation of its chord, that of its whole centre line (:func:`line_rotation`),
    blended by :func:`straight_share` of ``before``. The one measure of a leg's turn: the posture
    turns a leg back by it and the report's ``tilt_degrees`` is its angle."""
    share, turn = straight_share(before), np.zeros(3)
    if share > 0.0:
        chord = rotation_between(before.tip - before.junction, after.tip - after.junction)
        if chord is not None:
            turn += share * Rotation.from_matrix(chord).as_rotvec()
    if share < 1.0:     # (a limb with fewer than two sections reaches 1)
        turn += (1.0 - share) * Rotation.from_matrix(line_rotation(before, after)).as_rotvec()
    return turn


def girth_spread(before: Limb, after: Limb) -> float:
    """How unevenly a limb's girth changed along it: exp(P90 − P10) − 1 of log(girth after / girth
    before) over its cross-sections (0 when every section changed alike, as under any similarity;
    0.5: somewhere along the leg the girth grew 50 % more than elsewhere). The limbs' thickening
    faded in below the junction swells the leg below it when it is large: the Princeton pig 383 at
    ×0.5 with κ up to 0.3 a step came out with club legs at 1.3–1.45, the real horse at ×2 with
    broad hooves at 0.4–0.65, the cow 381 at ×2 at 0.65–0.75 with its hooves kept at Eq. 9's size
    (0.19–0.31 since they grow with the leg), where most outputs that look right measure 0.01–0.38
    (Eq. 9's leg α alone can do it too: the bull 386 at ×2, 1.2–1.6, without κ).
    The 10th and 90th percentiles, not the extremes: a single section at the junction's rim or the
    foot moves with the rim's or the hoof's shape."""
    count = min(len(before.sections), len(after.sections))
    if count < 3:
        return 0.0
    ratios = np.log(np.array([section.girth for section in after.sections[:count]])
                    / np.array([section.girth for section in before.sections[:count]]))
    low, high = np.percentile(ratios, [10, 90])
    return float(np.expm1(high - low))


def _shape_change(limb: Limb, before: np.ndarray, after: np.ndarray, areas: np.ndarray) -> float:
    """How far the limb's vertices clear of its junction (beyond :attr:`Limb.clear_level`; the rim
    where it joins the body moves with the body) are after from any affine image of themselves."""
    index = limb.mesh.vertex_index
    clear = limb.field > limb.clear_level
    if clear.sum() >= 4:
        index = index[clear]
    return affine_misfit(before[index], after[index], areas[index])


def posture_change(before: Body, after: Body) -> dict[str, dict[str, float]]:
    """How the limbs' stance and shape changed from ``before`` to ``after`` (same faces and labels).

    Per limb part (``"forelimbs[0]"`` …): ``tilt_degrees``, the angle of :func:`limb_turn` (its
    axis's turn, junction centroid → foot tip, for a straight leg, its centre line's for a folded
    one); ``foot_lift``, the change of the foot's height above the lowest foot, as a share of the
    leg's length; ``bend``, the change of :func:`limb_bend` (a leg that bows); ``fold_degrees``,
    :func:`fold_turn` (a fold opened or closed, a knee bent); ``girth_spread``,
    :func:`girth_spread` (a leg swollen along part of its length); ``shape_change``, how far the
    leg after, clear of its junction, is from any affine image of the leg before
    (:func:`allorules.mesh.geometry.affine_misfit`, area-weighted, in units of its size: a leg grown
    longer and thicker by its own factors is 0, one bent, curled or crumpled is not).
    Heights are taken along :func:`stance_down` of ``before``. Nothing rules ask for; the report
    shows it because an allometric edit can meet every rule yet leave the animal
    leaning or its legs bent.
    """
    limbs_before = [limb for region in LIMB_REGIONS if before.has_region(region) for limb in limb_sections(before, region)]
    if not limbs_before:
        return {}
    carried = carry_fields(before, after.with_vertices(after.vertices))
    limbs_after = [limb for region in LIMB_REGIONS if carried.has_region(region) for limb in limb_sections(carried, region)]

    down = stance_down(limbs_before, before.frame)

    def stance(limbs: list[Limb]) -> np.ndarray:
        heights = -np.array([limb.tip @ down for limb in limbs])
        lengths = np.array([limb.length for limb in limbs])
        return (heights - heights.min()) / lengths

    areas = vertex_areas(before.vertices, before.faces)
    lift_before, lift_after = stance(limbs_before), stance(limbs_after)
    change = {}
    for index, limb in enumerate(limbs_before):
        change[f"{limb.region}[{limb.part}]"] = {
            "tilt_degrees": float(np.degrees(np.linalg.norm(limb_turn(limb, limbs_after[index])))),
            "foot_lift": float(lift_after[index] - lift_before[index]),
            "bend": limb_bend(limbs_after[index]) - limb_bend(limb),
            "fold_degrees": fold_turn(limb, limbs_after[index]),
            "girth_spread": girth_spread(limb, limbs_after[index]),
            "shape_change": _shape_change(limb, before.vertices, after.vertices, areas),
        }
    return change


# ---------------------------------------------------------------------------------------------
# Lengths and girths


