"""Girths (METHOD §3): heart girth, the largest closed section of the chest across the torso axis
behind the forelimbs, and the girth of any other region.
"""
from __future__ import annotations

import numpy as np

from allorules.body import Body, HeartGirthTape
from allorules.errors import MeasurementError
from allorules.measure.cache import measured
from allorules.measure.length import region_skeleton
from allorules.measure.limbs import limb_sections
from allorules.measure.parts import (
    LIMB_REGIONS,
    SECTION_COUNT,
    TORSO_REGIONS,
    RegionPart,
    region_parts,
    torso_axis,
)
from allorules.measure.sections import (
    Loop,
    area_quantiles,
    isocontour_loops,
    isocontour_stack,
)
from allorules.mesh.geometry import face_areas
from allorules.mesh.topology import face_parts, faces_mostly_in, submesh

# Heart girth's last candidate lies this share of the chest's length behind the forelimbs, clear of
# the armpit's flare: on the real horse the chest's sections rise by 2.5 % over the last 5 % of its
# length before the forelimbs, so the section at a margin of 0.01 was that flare's, and it differed
# by 1.2 % between two tessellations of one horse (a margin of 0.06: 0.3 %). Where no section lies
# behind that (a chest that hardly reaches behind the forelimbs), the next margin is tried.
CHEST_LIMIT_MARGINS = (0.06, 0.01)


def _torso_loops(body: Body, region: str, axis: np.ndarray, targets: np.ndarray | None = None,
                 around_torso: bool | str = False, check: bool = True) -> tuple[list[Loop], np.ndarray]:
    """Closed plane sections of a region's largest part across ``axis`` that go around the trunk
    (one per level).

    Levels at the part's area quantiles ``targets`` (default: ``(k + ½)/SECTION_COUNT``).
    ``around_torso``: where the loops are cut: ``"part"`` (or False) the region's part alone,
    ``"torso"`` (or True) the whole torso piece around it (:func:`_torso_piece`), ``"body"`` the
    whole body. With ``check``, a level counts only where the piece's longest loop is the trunk's
    section (:func:`_trunk_section`): a closed loop of a region that does not reach all round the
    body is no girth. Without (an optimiser's trial bodies, carried from a checked reference), the
    piece's longest loop. Returns the loops and the quantile of each (levels without such a loop
    are left out).
    """
    piece = {False: "part", True: "torso"}.get(around_torso, around_torso)
    part = region_parts(body, region)[0]
    field = part.vertices @ axis
    if targets is None:
        targets = (np.arange(SECTION_COUNT) + 0.5) / SECTION_COUNT
    levels = area_quantiles(part.vertices, part.faces, field, targets)
    cut = _section_piece(body, region, piece)
    cut_field = cut.vertices @ axis
    # levels at the field's ends are no cross-sections (see area_quantile_levels)
    inside = [(target, level) for target, level in zip(np.asarray(targets).tolist(), levels.tolist())
              if field.min() < level < field.max()]
    stack = isocontour_stack(cut.vertices, cut.faces, cut_field, [level for _, level in inside])
    loops, kept = [], []
    for (target, level), found in zip(inside, stack):
        if found and (not check or _trunk_section(body, found[0], axis, level)):
            loops.append(found[0])
            kept.append(target)
    return loops, np.asarray(kept)


def _section_piece(body: Body, region: str, piece: str) -> RegionPart:
    """Where sections are cut: the region's largest part, the torso piece around it, or the body."""
    if piece == "part":
        return region_parts(body, region)[0]
    if piece == "torso":
        return _torso_piece(body, region)
    cache = measured(body).parts
    if "body" not in cache:   # a list of parts, as every entry (carried to a moved body as such)
        cache["body"] = [RegionPart("body", body.vertices, body.faces, np.arange(len(body.vertices)),
                                    float(face_areas(body.vertices, body.faces).sum()))]
    return cache["body"][0]


MIN_TRUNK_LEVELS = 4        # a chest or torso piece measures heart girth only where it gives the trunk's section at this many levels
TRUNK_COVER = 0.5           # and behind the forelimbs at this share of the levels where the whole body gives it, or more
TRUNK_SECTION_MATCH = 0.05   # a region's loop is the trunk's section when its girth is within this of it


def _trunk_section(body: Body, loop: Loop, axis: np.ndarray, level: float) -> bool:
    """Whether ``loop`` (across ``axis`` at ``level``) is the trunk's section there: as long, within
    TRUNK_SECTION_MATCH, as the whole body's longest loop at that level (a leg's or the neck's
    are shorter and apart from it). Where the body has no closed section (holes), it is."""
    sections = isocontour_loops(body.vertices, body.faces, body.vertices @ axis, level)
    if not sections:
        return True
    return abs(loop.girth - sections[0].girth) <= TRUNK_SECTION_MATCH * sections[0].girth


# The regions a tape around the trunk may cross: the torso's, and the neck's where its region reaches
# down over the withers (the giraffe 390: its neck's base cut slants, so the chest's sections in
# front of its middle run over neck; without it the torso piece closed at the chest's back only, 5
# levels on the input and 3 at ×1.54, and heart girth jumped by a third to the whole body's sections).
TAPE_REGIONS = (*TORSO_REGIONS, "neck")


def _torso_piece(body: Body, region: str) -> RegionPart:
    """The connected piece of the trunk (faces mostly of TAPE_REGIONS: chest, abdomen, neck) that
    holds ``region``'s largest part: what a tape measure goes around when the region's own sections
    do not close."""
    cache = measured(body).parts
    if "torso" not in cache:
        in_torso = np.zeros(len(body.vertices), dtype=bool)
        for name in TAPE_REGIONS:
            if body.has_region(name):
                in_torso |= body.region_mask(name)
        faces = body.faces[faces_mostly_in(body.faces, in_torso)]
        pieces = []
        for face_index in face_parts(faces):
            vertices, local_faces, vertex_index = submesh(body.vertices, faces, face_index)
            pieces.append(RegionPart("torso", vertices, local_faces, vertex_index, float(face_areas(vertices, local_faces).sum())))
        cache["torso"] = pieces
    first = region_parts(body, region)[0].vertex_index[0]
    return next(piece for piece in cache["torso"] if np.isin(first, piece.vertex_index))


def _forelimb_limit(body: Body, axis: np.ndarray) -> float | None:
    """Position along ``axis`` of the rearmost point where the forelimbs meet the chest (``None``
    without forelimbs): the front end of where heart girth may be taken."""
    if not (body.has_region("forelimbs") and body.region_mask("forelimbs").any()):
        return None
    forelimb_faces = body.faces[body.region_face_mask("forelimbs")]
    junction = body.vertices[np.intersect1d(np.unique(forelimb_faces), np.flatnonzero(body.region_mask("chest")))]
    return float((junction @ axis).min() if len(junction) else (body.vertices[body.region_mask("forelimbs")] @ axis).min())


def chest_girth(body: Body) -> float:
    """Heart girth: the largest closed section of the chest across the torso axis behind the forelimbs.

    "Behind the forelimbs" means every point of the section lies at least a margin (the first of
    ``CHEST_LIMIT_MARGINS`` that leaves a section there) of the chest's length behind (along the
    torso axis) the rearmost point where the forelimbs meet the body; without forelimbs, any
    section. The candidates are the sections at fixed area quantiles of the chest that lie behind
    that limit, plus the section at the limit: where the chest still widens towards the forelimbs
    (real horses) the largest is that last one, and it moves with the forelimbs continuously
    instead of jumping from one quantile to the next. When no
    section of the chest alone goes around the body there (its boundary with the abdomen zigzags
    across the large faces of a low-poly mesh, or the neck's region reaches over the withers), the
    same levels are cut around the whole torso, and failing that around the whole body: a tape goes
    round the trunk whatever the labels. Only the trunk's own section counts (:func:`_trunk_section`),
    and a piece is used only where it gives it at MIN_TRUNK_LEVELS levels or more.
    On a carried body (:func:`carry_fields`) the quantile levels, where they were cut and the
    margin are the reference's (and the trunk check is not repeated on them).
    """
    axis = torso_axis(body)
    part = region_parts(body, "chest")[0]
    field = part.vertices @ axis
    junction = _forelimb_limit(body, axis)

    def candidates(targets: np.ndarray | None, piece: str, margin: float, check: bool = True) -> tuple[list[Loop], np.ndarray]:
        check = check and piece != "body"   # the body's longest loop is the trunk's section by definition
        loops, kept = _torso_loops(body, "chest", axis, targets, piece, check)
        if junction is None:
            return loops, kept
        limit = junction - margin * (field.max() - field.min())
        # every candidate behind the limit, and the section at the limit itself: so a candidate
        # crossing the limit leaves or joins where it equals that last section (no jump)
        loops = [loop for loop in loops if (loop.points @ axis).max() <= limit]
        if field.min() < limit < field.max():
            cut = _section_piece(body, "chest", piece)
            at_limit = isocontour_loops(cut.vertices, cut.faces, cut.vertices @ axis, limit)[:1]
            loops += [loop for loop in at_limit if not check or _trunk_section(body, loop, axis, limit)]
        return loops, kept

    cache = measured(body)
    carried = cache.carried.chest_candidates if cache.carried else None
    if carried is None and body.tape is not None:     # the tape a reference body chose (a labels file's)
        carried = (np.asarray(body.tape.levels, dtype=float), body.tape.piece, body.tape.margin)
    loops: list[Loop] = []
    if carried is not None:
        kept, piece, margin = carried
        loops, _ = candidates(kept, piece, margin, check=False)
    else:
        for margin in CHEST_LIMIT_MARGINS if junction is not None else CHEST_LIMIT_MARGINS[:1]:
            whole = candidates(None, "body", margin)
            for piece in ("part", "torso", "body"):
                loops, kept = whole if piece == "body" else candidates(None, piece, margin)
                # a piece whose sections are the trunk's at a few levels only is a strip or a patch:
                # which levels pass would change with the smallest deformation (from step to step);
                # one that closes behind the forelimbs at fewer than TRUNK_COVER of the levels the
                # body does gives the back of the chest's girth, not heart girth
                enough = len(kept) >= MIN_TRUNK_LEVELS and len(loops) >= TRUNK_COVER * len(whole[0])
                if loops and (piece == "body" or enough):
                    cache.chest_candidates = (kept, piece, margin)
                    break
            if loops:
                break
    if not loops:
        raise MeasurementError(
            "no closed section around the chest behind the forelimbs, not even of the whole body: the mesh "
            "may have holes there, or the forelimbs' labels reach along the whole trunk; check the segmentation"
        )
    return max(loop.girth for loop in loops)


def heart_girth_tape(body: Body) -> HeartGirthTape | None:
    """Where :func:`chest_girth` puts its tape on ``body`` (carried, given or chosen here, measuring
    it if need be), to be kept with the regions; None where heart girth cannot be measured."""
    cache = measured(body)
    choice = cache.carried.chest_candidates if cache.carried and cache.carried.chest_candidates else None
    if choice is None and body.tape is not None:
        return body.tape
    if choice is None:
        try:
            chest_girth(body)
        except (MeasurementError, KeyError, IndexError):
            return None
        choice = cache.chest_candidates
    if choice is None:
        return None
    levels, piece, margin = choice
    return HeartGirthTape(tuple(float(level) for level in np.atleast_1d(levels)), str(piece), float(margin))


def region_girth(body: Body, region: str) -> float:
    """Girth of a region, taken where docs/measurements.md says.

    chest: heart girth (:func:`chest_girth`); abdomen: its largest section across the torso
    axis; limbs: the section at mid-length, mean over the limbs; any other region: the longest
    closed isocontour of its own Fiedler vector (the base of a neck, the widest part of a head).
    """
    cache = measured(body).girths
    if region in cache:
        return cache[region]
    if region == "chest":
        girth = chest_girth(body)
    elif region == "abdomen":
        axis = torso_axis(body)
        loops = _torso_loops(body, region, axis)[0] or _torso_loops(body, region, axis, around_torso="torso")[0]
        if not loops:
            raise MeasurementError("no closed section across the abdomen; check the segmentation")
        girth = max(loop.girth for loop in loops)
    elif region in LIMB_REGIONS:
        girth = float(np.mean([limb.section_at(0.5).girth for limb in limb_sections(body, region)]))
    else:
        girths = []
        for part_skeleton in region_skeleton(body, region):
            section_loops = [loop for loop, kind in zip(part_skeleton.loops, part_skeleton.kinds) if kind == "section"]
            if section_loops:
                girths.append(max(loop.girth for loop in section_loops))
        if not girths:
            raise MeasurementError(f"no closed cross-section found on region {region!r}; check the segmentation")
        girth = float(np.mean(girths))
    cache[region] = girth
    return girth
