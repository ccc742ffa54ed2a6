"""The animal's stance through a run: legs upright and every foot on the ground (``solver.posture``).

Eq. 9 changes a limb's modes by other factors than the body's, so a step can meet every rule and
still leave a leg leaning, or a pair of feet off the ground (docs/biology-scaling.md, posture).
No rule measures a direction or a height, so this module keeps them, without touching what the
rules measure:

* :class:`FootContact` is part of each step's transform (:class:`allorules.solve.transform.StepTransform`):
  after Eq. 9, the feet are put back at the heights above one another they had at the step's
  start (scaled with the body), along the ground's normal. What a pair of legs (a limb region)
  moved together is undone by moving the pair rigidly, the rest of the body following in a
  harmonic blend (the torso tilts back fore and aft); what one leg moved against its mate (Eq. 9
  shortened the two unequally) is undone by stretching that leg below its junction, which stays
  where it is (moved rigidly, the leg dragged the chest down around it like a sleeve: the
  Princeton horse 382 at ×0.5). The solver measures, and so meets its targets on, the mesh with
  the feet put back.
* :class:`LimbFolds` gives a folded leg's fold back the shape it had at the step's start (Eq. 9
  opens or closes it); like the foot contact it is part of each step's transform, so the solver
  measures the leg with its fold kept.
* :func:`restore_limb_axes` turns each leg back to the direction it had at the step's start,
  after the step; the step's foot contact is then applied once more, since turning a slanted
  leg moves its foot (:func:`allorules.runs.ruleset_run.scale_with_ruleset`).
* :func:`restore_limb_lines` gives each leg's centre line, below its first cross-section, back
  the shape it had at the step's start (a leg Eq. 9 bowed is straightened), after every step but
  the last, so that the next step's carried-forward misses make up what it changed.

``posture: keep`` (the default) does all four, ``upright`` only the turn, ``free`` none (the
paper's behaviour). A folded leg (:func:`allorules.measure.limbs.straight_share`) is turned by
its whole centre line, not by its chord, and its line is given back by :class:`LimbFolds`, not
straightened along its chord.

The turn moves each leg as a rigid whole below a short blend at its top, and the foot contact
moves each pair rigidly, so a pair's length, girths and load-bearing section are what the step
made them (a leg stretched against its mate gains what its mate gives up); the third moves each
cross-section as a whole, across the leg.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.csgraph as csgraph
from scipy.sparse.linalg import splu
from scipy.spatial.transform import Rotation

from allorules.body import Body
from allorules.measure.sections import JoinedLoops
from allorules.mesh.geometry import rotation_between, similarity_fit, smoothstep
from allorules.mesh.topology import vertex_graph

POSTURE_BLEND = 0.25    # share of a limb's length, from its junction, over which the turn fades in


def _limbs(body: Body) -> list:
    """The limb parts of ``body`` (every part of every limb region it has), junction → tip."""
    from allorules.measure.limbs import limb_sections
    from allorules.measure.parts import LIMB_REGIONS

    return [limb for region in LIMB_REGIONS
            if body.has_region(region) and body.labels is not None and body.region_mask(region).any()
            for limb in limb_sections(body, region)]


def _limb_pairs(reference: Body, moved: Body) -> list[tuple]:
    """Each limb of ``reference`` with the same limb on ``moved`` (same faces and labels), measured
    on the same material loops (:func:`allorules.measure.parts.carry_fields`)."""
    from allorules.measure.parts import carry_fields

    limbs = _limbs(reference)        # before carrying: the same limbs
    return list(zip(limbs, _limbs(carry_fields(reference, moved.with_vertices(moved.vertices)))))



# ---------------------------------------------------------------------------------------------
# Feet on the ground


@dataclass(frozen=True)
class FootContact:
    """How to put a moved body's feet back at the heights above one another they had.

    ``feet[k]``: body vertices of leg k's foot (the leg beyond its last cross-section);
    ``weights[k]``: how much each body vertex follows leg k's rigid shift (1 on the leg, 0 on the
    other legs, a harmonic blend in between: see :meth:`of`);
    ``stretch[k]``: how much each body vertex follows leg k's stretch (0 at the leg's junction
    rising along the leg to 1 at its foot, 0 off the leg);
    ``pairs[k]``: the pair (limb region) leg k belongs to;
    ``heights[k]``: the foot's height above the feet's mean, along ``down``, at the start.
    """

    down: np.ndarray
    feet: tuple[np.ndarray, ...]
    weights: np.ndarray          # (legs, vertices)
    stretch: np.ndarray          # (legs, vertices)
    pairs: np.ndarray            # (legs,) pair number of each leg
    heights: np.ndarray          # (legs,)

    @classmethod
    def of(cls, body: Body) -> "FootContact | None":
        """The feet of ``body`` as they stand; ``None`` for a body with fewer than two legs.

        The rigid weights are harmonic over the rest of the body (:func:`_harmonic_weights`): 1 on
        leg k and 0 on the other legs, and in between the smoothest blend, so the torso follows the
        legs' shifts without a crease and the weights sum to 1 everywhere. Each piece hanging
        off the torso (the tail; the neck with the head) is one rigid node of that blend: it
        moves as one, and is not bent or sheared. The stretch weights rise linearly along the
        leg's field from its junction to its foot (:func:`_stretch_weights`).
        """
        from allorules.measure.limbs import stance_down
        from allorules.measure.parts import TORSO_REGIONS

        limbs = [limb for limb in _limbs(body) if limb.sections]
        if len(limbs) < 2:
            return None
        on_leg = np.full(len(body.vertices), -1)
        for k, limb in enumerate(limbs):
            on_leg[limb.mesh.vertex_index] = k
        torso = np.zeros(len(body.vertices), dtype=bool)
        for region in TORSO_REGIONS:
            if body.has_region(region):
                torso |= body.region_mask(region)
        torso &= on_leg < 0
        if not torso.any():                 # no torso labelled: everything but the legs blends
            torso = on_leg < 0
        weights = _harmonic_weights(_conductances(body.vertices, body.faces), on_leg, torso, len(limbs))
        feet = tuple(limb.mesh.vertex_index[limb.field >= limb.levels[-1]] for limb in limbs)
        down = stance_down(limbs, body.frame)
        _, pairs = np.unique([limb.region for limb in limbs], return_inverse=True)
        contact = cls(down, feet, weights, _stretch_weights(limbs, len(body.vertices)), pairs, np.zeros(len(limbs)))
        return replace(contact, heights=contact.foot_heights(body.vertices))

    def foot_heights(self, vertices: np.ndarray) -> np.ndarray:
        """Each foot's height above the feet's mean, along −``down`` (its vertices' mean)."""
        heights = np.array([-(vertices[foot] @ self.down).mean() for foot in self.feet])
        return heights - heights.mean()

    def apply(self, vertices: np.ndarray, scale: float) -> np.ndarray:
        """``vertices`` with the feet put back as they stood at the start, heights × ``scale`` (the
        step's isometric factor), along ``down``: each leg's shift δ_k = h_k(x) − scale · h_k(start)
        splits into its pair's mean δ_P, moved rigidly, and the rest δ_k − δ_P, stretched below
        the junction: x' = x + (Σ_k w_k(x) δ_P(k) + Σ_k t_k(x) (δ_k − δ_P(k))) · down. The shifts
        sum to zero, so the body does not sink."""
        shift = self.foot_heights(vertices) - scale * self.heights
        rigid = (np.bincount(self.pairs, shift) / np.bincount(self.pairs))[self.pairs]     # δ_P(k)
        moved = self.weights.T @ rigid + self.stretch.T @ (shift - rigid)
        return vertices + np.outer(moved, self.down)


def _stretch_weights(limbs: list, count: int) -> np.ndarray:
    """Per leg, 0 up to where it is clear of its junction (:attr:`Limb.clear_level`: every vertex
    of the junction's rim stays with the body) rising linearly along its field to 1 at its foot
    (the leg beyond its last section), 0 off the leg; a vertex two legs share (knees that touch)
    takes the mean of the two. Rising from the field's lowest value instead, the weights were
    0.48 on part of the Princeton horse 382's slanted foreleg rim and 0 beside it: its chest
    creased along the foreleg's top at ×2 (19 flipped faces, 0.43 of the input's dihedral angles)."""
    stretch = np.zeros((len(limbs), count))
    for k, limb in enumerate(limbs):
        lowest, foot = limb.clear_level, float(limb.levels[-1])
        rise = np.clip((limb.field - lowest) / (foot - lowest), 0.0, 1.0) if foot > lowest else np.ones(len(limb.field))
        stretch[k, limb.mesh.vertex_index] = rise
    shared = (stretch > 0).sum(axis=0) > 1
    stretch[:, shared] /= (stretch[:, shared] > 0).sum(axis=0)
    return stretch


def _harmonic_weights(conductance: sparse.csr_matrix, on_leg: np.ndarray, torso: np.ndarray, legs: int) -> np.ndarray:
    """Per leg k, a weight on every vertex: 1 on leg k (``on_leg == k``), 0 on the other legs,
    harmonic elsewhere (Σ_j c_ij (w_j − w_i) = 0, conductances c = 1 / edge length), with every
    connected piece of what is neither leg nor ``torso`` one node (it moves as one). The weights
    lie in [0, 1] (maximum principle) and sum to 1 wherever a leg can be reached; a piece that
    reaches no leg gets 0."""
    count = len(on_leg)
    free = on_leg < 0
    fixed = np.zeros((count, legs))
    fixed[~free, on_leg[~free]] = 1.0
    if not free.any():
        return fixed.T
    # the unknowns: one per torso vertex, one per piece hanging off it
    node = np.full(count, -1)
    node[torso] = np.arange(int(torso.sum()))
    hanging = free & ~torso
    if hanging.any():
        keep = sparse.diags(hanging.astype(float))          # only the edges between hanging vertices
        _, piece = csgraph.connected_components(keep @ conductance @ keep, directed=False)
        _, pieces = np.unique(piece[hanging], return_inverse=True)
        node[hanging] = int(torso.sum()) + pieces
    unknowns = int(node.max()) + 1
    rows = np.flatnonzero(free)
    gather = sparse.csr_matrix((np.ones(len(rows)), (rows, node[rows])), shape=(count, unknowns))
    laplacian = sparse.diags(np.asarray(conductance.sum(axis=1)).ravel()) - conductance
    # Gᵀ L G w = −Gᵀ L w_fixed; a diagonal 1e-12 of the smallest row's keeps every piece solvable
    # (one that reaches no leg gets 0) without leaking weight anywhere else (a zero-length edge's
    # huge conductance would make one relative to a typical row leak)
    system = (gather.T @ laplacian @ gather).tocsc()
    diagonal = system.diagonal()
    smallest = float(diagonal[diagonal > 0].min()) if np.any(diagonal > 0) else 1.0
    system = system + sparse.identity(unknowns, format="csc") * (1e-12 * smallest)
    right = -(gather.T @ (laplacian @ fixed))
    solved = splu(system).solve(np.ascontiguousarray(right))
    return (fixed + gather @ solved).T


def _conductances(vertices: np.ndarray, faces: np.ndarray) -> sparse.csr_matrix:
    """The mesh's edges as a symmetric sparse matrix of conductances 1 / edge length."""
    graph = vertex_graph(vertices, faces)
    graph.data = 1.0 / np.maximum(graph.data, 1e-6 * graph.data.mean())    # a zero-length edge joins firmly, finitely
    return graph


# ---------------------------------------------------------------------------------------------
# Legs upright


def restore_limb_axes(reference: Body, moved: Body) -> np.ndarray:
    """``moved``'s vertices with each limb turned back to the direction it had in ``reference``.

    Per limb part: R = the smallest rotation taking its axis on ``moved`` (junction centroid →
    foot tip) back to its axis on ``reference``, or for a folded leg the rotation of the best
    similarity taking its centre line (junction and section centroids) on ``moved`` to that on
    ``reference`` (between, the two blended as rotation vectors: :func:`allorules.measure.limbs.limb_turn`);
    vertices turn by R about the junction, x' = x + w·(J + R(x − J) − x), with w rising smoothly
    (smoothstep) from 0 where the limb is clear of its junction (:attr:`Limb.clear_level`) to 1 at
    ``POSTURE_BLEND`` of the limb's length along its own field (or half that beyond where it is
    clear, if later), so the shoulder stays joined to the body. Rigid below the blend: lengths,
    girths and the load-bearing section are kept.
    Bodies without limbs come back unchanged.
    """
    from allorules.measure.limbs import limb_turn

    moves = []
    for before, after in _limb_pairs(reference, moved):
        index = after.mesh.vertex_index
        moves.append((index, np.zeros((len(index), 3))))
        if not before.sections:
            continue
        turn = -limb_turn(before, after)        # rotation vector, back from after to before
        if not np.any(turn):
            continue
        rotation = Rotation.from_rotvec(turn).as_matrix()
        fractions = np.array([section.fraction for section in before.sections])
        lowest = before.clear_level            # the junction's rim does not turn (it would tear)
        blend_level = float(np.interp(max(POSTURE_BLEND, before.clear_fraction + POSTURE_BLEND / 2), fractions,
                                      before.levels))
        if blend_level <= lowest:
            continue
        weight = smoothstep((before.field - lowest) / (blend_level - lowest))
        turned = after.junction + (moved.vertices[index] - after.junction) @ rotation.T
        moves[-1] = (index, weight[:, None] * (turned - moved.vertices[index]))
    return moved.vertices + _mean_over_limbs(len(moved.vertices), moves)


def _mean_over_limbs(count: int, moves: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Per-vertex displacements, each limb part's ``(vertex ids, moves)``, averaged where parts share
    vertices: the seam where the two legs of a pair meet (one piece of a region split at its two
    feet) belongs to both, and moved by each in turn it was moved twice (the camel's forelegs touch
    at the knees: at ×2, 6 faces flipped there, 4 with the mean)."""
    total, parts = np.zeros((count, 3)), np.zeros(count)
    for index, move in moves:
        np.add.at(total, index, move)
        np.add.at(parts, index, 1.0)
    shared = parts > 1
    total[shared] /= parts[shared, None]
    return total


def restore_limb_lines(reference: Body, moved: Body) -> np.ndarray:
    """``moved``'s vertices with each limb's centre line given back the shape it had in
    ``reference``: a leg that Eq. 9 bowed is straightened, a leg that was bent (a hock) keeps
    its bend.

    Per limb part, the centre line is the chain of section centroids c_j, from the first section
    (just below the junction) to the last (above the foot); its chord runs from the first
    centroid to the last. On ``reference`` each centroid lies at a fraction t_j along the chord
    plus an offset r_j across it. On ``moved``, section j is moved by
    d_j = c_0 + t_j·chord + σ·Q r_j − c_j (σ the chord's change of length, Q the smallest rotation
    between the chords), the part of it along the chord dropped; between sections d is
    interpolated along the limb's field. d is 0 at the first and at the last section, and above
    and below them, so the body, the leg's top and the foot stay where they are and nothing is
    torn. The junction itself is left alone: moving it would move the body around the groin
    (tried: faces flipped there; docs/biology-scaling.md, posture). The shifts fade out on a
    folded leg (:func:`allorules.measure.limbs.straight_share`), whose chord says nothing of its
    line (:class:`LimbFolds` gives a folded leg its line back).
    Bodies without limbs come back unchanged.
    """
    from allorules.measure.limbs import straight_share

    moves = []
    for before, after in _limb_pairs(reference, moved):
        moves.append((after.mesh.vertex_index, np.zeros((len(after.mesh.vertex_index), 3))))
        kept = straight_share(before)
        if len(before.sections) < 2 or kept == 0.0:
            continue
        # the centroids from the second section on, relative to the first: the last is the chord
        centroids_start, centroids_now = before.centroids, after.centroids
        line_start, line_now = centroids_start[1:] - centroids_start[0], centroids_now[1:] - centroids_now[0]
        chord_start, chord_now = line_start[-1], line_now[-1]
        reach_start, reach_now = float(np.linalg.norm(chord_start)), float(np.linalg.norm(chord_now))
        if reach_start == 0.0 or reach_now == 0.0:
            continue
        across_start = line_start - np.outer(line_start @ chord_start / reach_start ** 2, chord_start)   # r_j
        rotation = rotation_between(chord_start, chord_now)
        if rotation is not None:
            across_start = across_start @ rotation.T                                                  # Q r_j
        target = np.outer(line_now @ chord_now / reach_now ** 2, chord_now) + (reach_now / reach_start) * across_start
        shift = target - line_now
        direction = chord_now / reach_now
        shift -= np.outer(shift @ direction, direction)                 # across the leg only
        shift *= kept
        shifts = np.vstack([np.zeros(3), shift])                        # d_0 = 0 (and d_last = 0)
        # interpolated along the field; 0 above the first and below the last section
        moves[-1] = (moves[-1][0], np.column_stack([np.interp(after.field, before.levels, shifts[:, axis], left=0.0,
                                                              right=0.0) for axis in range(3)]))
    return moved.vertices + _mean_over_limbs(len(moved.vertices), moves)


# ---------------------------------------------------------------------------------------------
# Folded legs keep their folds


@dataclass(frozen=True)
class _Fold:
    """One folded leg of a step's start body, as :class:`LimbFolds` gives a trial its fold back."""

    weight: float                 # how folded: 1 − straight_share
    vertex_index: np.ndarray      # body vertex of each part vertex
    field: np.ndarray             # the limb's field, per part vertex
    levels: np.ndarray            # each section's level, then the tip's (if beyond the last)
    loops: JoinedLoops            # the sections' loops, on body vertices
    tip: int                      # body vertex of the foot's tip; −1: the line ends at the last section
    line: np.ndarray              # the centroids (then the tip) at the start
    points: np.ndarray            # the loops' points at the start
    top: int                      # points of the sections the leg hangs from (its first quarter)

    def moves(self, vertices: np.ndarray) -> np.ndarray:
        """Per part vertex, the move giving the leg on ``vertices`` its fold (:class:`LimbFolds`)."""
        points = self.loops.points(vertices)
        line_now = self.loops.centroids(points)
        if self.tip >= 0:
            line_now = np.vstack([line_now, vertices[self.tip]])
        _, frame, _ = similarity_fit(self.points[:self.top], points[:self.top])           # G
        own = self.loops.rotations(self.points, points)                                    # R_j
        turns = Rotation.from_matrix(frame @ own.transpose(0, 2, 1)).as_rotvec()          # G R_jᵀ
        turns[0] = 0.0                                                 # the first section stays
        # the line rebuilt: the start's stretches turned by G, scaled to the leg's length now
        stretches = np.diff(self.line, axis=0)
        length_now = np.linalg.norm(np.diff(line_now, axis=0), axis=1).sum()
        stretches = stretches @ frame.T * (length_now / np.linalg.norm(stretches, axis=1).sum())
        target = line_now[0] + np.vstack([np.zeros(3), np.cumsum(stretches, axis=0)])
        if self.tip >= 0:          # the foot: its last section's turn, then its toe's
            last = Rotation.from_rotvec(turns[-1])
            toe = rotation_between(last.apply(line_now[-1] - line_now[-2]), target[-1] - target[-2])
            turns = np.vstack([turns, (last if toe is None else Rotation.from_matrix(toe) * last).as_rotvec()])

        def along(values: np.ndarray) -> np.ndarray:
            return np.column_stack([np.interp(self.field, self.levels, values[:, axis]) for axis in range(3)])

        mine = vertices[self.vertex_index]
        return along(target) + Rotation.from_rotvec(along(turns)).apply(mine - along(line_now)) - mine


@dataclass(frozen=True)
class LimbFolds:
    """How to give a moved body's folded legs back the folds they had, a part of each step's
    transform under ``posture: keep`` (:class:`allorules.solve.transform.StepTransform`).

    Eq. 9 opens or closes a folded leg's fold: the seated horse's hind legs at ×0.5 by 8-16° a
    step, 35-41° over the run, the hoof that was turned up under the belly laid flat. Per folded
    leg, weighted by how folded it is (1 − :func:`allorules.measure.limbs.straight_share`): the leg
    hangs from its top quarter (G, the best rotation of those sections' loops from the start);
    its centre line (section centroids, then the foot's tip) is rebuilt from the first section
    down, each stretch the start's turned by G and scaled by the line's change of length, so the
    line is a similarity of the start's and as long as the step made it; each cross-section moves
    rigidly onto it, turned by G·R_jᵀ, R_j the best rotation of its own loop (its many points,
    not the line's tangent: a fold's centroids turn by up to 130° from one section to the next);
    between sections the move is interpolated along the leg's field, and the first section and
    what is above it do not move. Girths and the line's length are kept; the turn of the whole
    leg is :func:`restore_limb_axes`'s.
    """

    folds: tuple[_Fold, ...]

    @classmethod
    def of(cls, body: Body) -> "LimbFolds | None":
        """The folded legs of ``body`` as they are; ``None`` when no leg is folded, even in part."""
        from allorules.measure.limbs import straight_share
        from allorules.measure.sections import join_loops

        folds = []
        for limb in _limbs(body):
            weight = 1.0 - straight_share(limb)
            if len(limb.sections) < 2 or weight <= 0.0:
                continue
            index = limb.mesh.vertex_index
            joined = join_loops([section.loop for section in limb.sections])
            loops = replace(joined, edge_start=index[joined.edge_start], edge_end=index[joined.edge_end])
            points = loops.points(body.vertices)
            line, levels = loops.centroids(points), np.asarray(limb.levels, dtype=float)
            tip = int(np.argmax(limb.field))
            if limb.field[tip] > levels[-1]:
                line, levels = np.vstack([line, body.vertices[index[tip]]]), np.append(levels, limb.field[tip])
                tip = int(index[tip])
            else:
                tip = -1
            # the sections the leg hangs from: its first quarter, at least two
            hanging = max(2, int(np.searchsorted([section.fraction for section in limb.sections], POSTURE_BLEND)))
            top = int(loops.starts[hanging]) if hanging < len(limb.sections) else len(points)
            folds.append(_Fold(weight, index, limb.field, levels, loops, tip, line, points, top))
        return cls(tuple(folds)) if folds else None

    def apply(self, vertices: np.ndarray) -> np.ndarray:
        """``vertices`` with each folded leg given its fold back."""
        return vertices + _mean_over_limbs(len(vertices), [(fold.vertex_index, fold.weight * fold.moves(vertices))
                                                           for fold in self.folds])
