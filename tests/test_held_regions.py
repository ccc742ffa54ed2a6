"""Open regions held as a similarity of themselves (allorules/solve/held_regions.py; issue 18 §1).

Known answers: a similarity of the whole body is left as it is; any other deformation leaves each
held part exactly its input shape × k, what hangs beyond it moved rigidly, the rest of the body
untouched beyond the blend zones, and no tear at an opening. Then the whole run on the generated
quadruped at ×2 and ×0.5: the neck (and the tail) isometric while every rule of ``quadruped`` is met."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from allorules.measure.quality import head_turn
from allorules.mesh.geometry import similarity_fit
from allorules.mesh.topology import unique_edges, vertex_graph
from allorules.solve import held_regions
from allorules.solve.held_regions import hold_regions

K = 1.05          # the isometric factor the tests hold at


def _similarity_residual(before: np.ndarray, after: np.ndarray) -> tuple[float, float]:
    """(scale, largest distance from the best similarity image of ``before``, in units of its size)."""
    scale, rotation, shift = similarity_fit(before, after)
    residual = np.linalg.norm(after - (scale * before @ rotation.T + shift), axis=1).max()
    size = np.sqrt(np.mean(np.sum((before - before.mean(axis=0)) ** 2, axis=1)))
    return scale, float(residual / (scale * size))


def _deformed(vertices: np.ndarray) -> np.ndarray:
    """A smooth deformation that is no similarity: anisotropic, sheared, bent (a step's worth)."""
    centre = vertices.mean(axis=0)
    linear = np.array([[1.15, 0.03, 0.0], [0.0, 0.92, 0.02], [0.0, 0.0, 1.05]])
    moved = (vertices - centre) @ linear.T + centre
    moved[:, 1] += 0.02 * np.sin(2.0 * vertices[:, 0])
    return moved


def _worst_stretch_jump(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per vertex, the largest ratio between the stretches (after/before length) of its edges: 1 where
    the surface around it is stretched evenly, large at a tear or a kink."""
    edges = unique_edges(faces)
    stretch = np.log(np.linalg.norm(after[edges[:, 0]] - after[edges[:, 1]], axis=1)
                     / np.linalg.norm(before[edges[:, 0]] - before[edges[:, 1]], axis=1))
    ends, values = edges.T.ravel(), np.concatenate([stretch, stretch])
    high, low = np.full(len(before), -np.inf), np.full(len(before), np.inf)
    np.maximum.at(high, ends, values)
    np.minimum.at(low, ends, values)
    return np.exp(high - low)


@pytest.fixture(scope="module")
def horse_held(generated_horse):
    body = generated_horse.body()
    return body, hold_regions(body, ("neck", "tail"))


def test_the_neck_carries_the_head_and_the_tail_hangs_free(horse_held, generated_horse):
    body, held = horse_held
    assert held.regions == ("neck", "tail") and not held.notes
    neck, tail = held.parts                                    # the part carrying others comes first
    head = body.region_mask("head")
    assert head[neck.children].all()                           # what the neck carries is the head, all of it
    assert np.isin(np.flatnonzero(head), np.concatenate([neck.children, neck.members])).all()
    assert len(neck.near) and len(neck.far) and len(neck.near_zone.vertices) and neck.far_zone is not None
    assert len(tail.near) and not len(tail.far) and not len(tail.children)
    # the zones lie beyond the part, weights from 1 at the opening falling to 0
    for zone in (neck.near_zone, neck.far_zone, tail.near_zone):
        assert not np.isin(zone.vertices, np.concatenate([neck.members, tail.members])).any()
        assert np.all((zone.weight > 0) & (zone.weight <= 1))


def test_a_similarity_of_the_whole_body_is_left_as_it_is(horse_held):
    body, held = horse_held
    rotation = Rotation.from_euler("xyz", [0.3, -0.7, 1.1]).as_matrix()
    moved = 1.7 * body.vertices @ rotation.T + np.array([0.4, -2.0, 3.0])
    assert np.allclose(held.apply(moved, 1.7), moved, rtol=0, atol=1e-9 * np.abs(moved).max())


def test_any_deformation_leaves_each_part_its_input_shape_times_k(horse_held):
    body, held = horse_held
    moved = _deformed(body.vertices)
    result = held.apply(moved, K)
    for part in held.parts:
        scale, residual = _similarity_residual(body.vertices[part.members], result[part.members])
        assert scale == pytest.approx(K, rel=1e-9) and residual < 1e-9, part.region
        # the near opening's centre stays where the deformation put it
        near = part.members[part.near]
        assert np.allclose(result[near].mean(axis=0), moved[near].mean(axis=0), atol=1e-12)
    neck = held.parts[0]
    # the head moves rigidly (by one shift) outside the far opening's blend zone
    rigid = np.setdiff1d(neck.children, neck.far_zone.vertices)
    assert len(rigid) >= 10                  # the head is about one opening radius long: most of it is zone
    shift = result[rigid] - moved[rigid]
    assert np.allclose(shift, shift[0], atol=1e-12) and np.linalg.norm(shift[0]) > 1e-3
    # nothing else moves
    touched = np.concatenate([np.concatenate([part.members, part.children, part.near_zone.vertices])
                              for part in held.parts] + [neck.far_zone.vertices])
    untouched = np.setdiff1d(np.arange(len(moved)), touched)
    assert np.array_equal(result[untouched], moved[untouched])


def test_the_blend_zones_leave_no_tear_at_an_opening(horse_held, monkeypatch):
    """Around every opening vertex the edges' stretches (against the deformed mesh) differ by at
    most 1.5× (measured: 1.30 with this deformation); the part pasted without zones tears (2.6×)."""
    body, held = horse_held
    moved = _deformed(body.vertices)
    openings = np.concatenate([part.members[np.concatenate([part.near, part.far]).astype(int)] for part in held.parts])
    jump = _worst_stretch_jump(moved, held.apply(moved, K), body.faces)
    assert jump[openings].max() < 1.5
    monkeypatch.setattr(held_regions, "ZONE", 0.0)
    pasted = hold_regions(body, ("neck", "tail")).apply(moved, K)
    assert _worst_stretch_jump(moved, pasted, body.faces)[openings].max() > 2.0


def _tube(around: int = 24, rows: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """An open unit cylinder of square-ish quads split in two, ``around`` vertices per ring."""
    turn = 2 * np.pi * np.arange(around) / around
    vertices = np.array([[np.cos(a), np.sin(a), row * 2 * np.pi / around] for row in range(rows) for a in turn])
    faces = []
    for row in range(rows - 1):
        for k in range(around):
            a, b = row * around + k, row * around + (k + 1) % around
            faces += [[a, b, b + around], [a, b + around, a + around]]
    return vertices, np.array(faces)


def test_a_zone_blends_its_openings_mismatch_instead_of_copying_one_vertexs():
    """A tube's first ring as the opening: a mismatch shared by the whole opening moves every zone
    vertex by its weight exactly; one that alternates from opening vertex to opening vertex (the
    vertex-to-vertex noise Eq. 9 leaves on a coarse opening) is blended away from it, where copying
    each zone vertex its nearest opening vertex's (as before) moved zone neighbours apart by 1.66 of
    it: a spike on the held-out bulldog's back beside its neck at ×2. Measured now: 0.58."""
    vertices, faces = _tube()
    opening = np.arange(24)
    side = np.ones(len(vertices), dtype=bool)
    side[opening] = False
    zone = held_regions.BlendZone.beyond(vertex_graph(vertices, faces).tocsr(), opening, side, vertices)
    assert len(zone.vertices) and np.allclose(zone.blend.sum(axis=1), 1.0)
    shift = np.zeros_like(vertices)
    zone.apply(shift, np.tile([0.0, 0.0, 1.0], (24, 1)))
    np.testing.assert_allclose(shift[zone.vertices, 2], zone.weight, atol=1e-12)
    noise = np.zeros((24, 3))
    noise[:, 2] = (-1.0) ** np.arange(24)
    moved = np.zeros_like(vertices)
    zone.apply(moved, noise)
    edges = unique_edges(faces)
    inside = np.isin(edges, zone.vertices).all(axis=1)
    assert np.abs(moved[edges[inside, 0]] - moved[edges[inside, 1]]).max() < 0.75


@pytest.mark.slow
@pytest.mark.parametrize("ratio", [2.0, 0.5])
def test_generated_quadruped_keeps_its_neck_and_tail_isometric_and_meets_every_rule(generated_horse, ratio):
    """The default (hold: shape) on the generated horse (3,000 vertices, 200 modes): every rule of
    ``quadruped`` met, the neck's and the tail's length and mass exponents within ±0.02 of 1/3 and 1
    (measured: 0.3333 and 1.0000 at both ratios; with hold: soft 0.397 at ×2 and 0.470 at ×0.5),
    each an exact similarity of its input, and no opening the worst kink of the body."""
    from allorules.plugins.registry import registry_for
    from allorules.rules.resolve import load_ruleset
    from allorules.runs.results import EXPONENT_TOLERANCE
    from allorules.runs.ruleset_run import scale_with_ruleset

    body = generated_horse.body()
    registry = registry_for(None)
    result = scale_with_ruleset(body, load_ruleset("quadruped", registry), ratio, registry=registry, modes=200,
                                use_cache=False)
    assert result.converged, result.messages
    assert all(abs(rule.error) <= EXPONENT_TOLERANCE for rule in result.rules), [rule.as_dict() for rule in result.rules]
    outcomes = {(o.region, o.measure): o for o in result.open_regions}
    for region in ("neck", "tail"):
        assert outcomes[(region, "length")].hold == "shape"
        assert abs(outcomes[(region, "length")].achieved_exponent - 1 / 3) <= 0.02
        assert abs(outcomes[(region, "mass")].achieved_exponent - 1.0) <= 0.02
    # neck and tail are exact similarities of their input at the isometric factor; the head, held
    # at its rule's size, is one too away from its base (which meets the neck), at the size the
    # solver gave it to meet its mass
    held = hold_regions(body, ("neck", "tail", "head"), {"head": 0.7})
    for part in held.parts:
        # beyond the base that bends where the part is turned back at the run's end (the neck), or
        # that meets the neck (the head)
        base = part.near_zone if part.ruled else part.base_zone
        members = part.members[~np.isin(part.members, base.vertices)]
        scale, residual = _similarity_residual(body.vertices[members], result.body.vertices[members])
        expected = ratio ** (0.7 / 3) if part.ruled else ratio ** (1 / 3)
        assert residual < 1e-6, (part.region, residual)
        assert scale == pytest.approx(expected, rel=0.05 if part.ruled else 1e-6), (part.region, scale, expected)
    assert result.steps[-1].sizes and "head" not in result.steps[-1].alphas
    # the neck turned back to its input direction at the run's end, the head with it (measured
    # 0.07° at both ratios; before, as Eq. 9 left the neck, 4.0° at ×2 and 6.7° at ×0.5)
    neck = held.parts[0]
    assert neck.region == "neck"
    beyond = neck.members[~np.isin(neck.members, neck.base_zone.vertices)]
    assert _turn_degrees(body.vertices[beyond], result.body.vertices[beyond]) < 1e-3
    assert head_turn(body, result.body.vertices) < 0.5
    # measured: openings' worst 1.50 / 1.83 (×2), 1.63 / 2.57 (×0.5); the body's own worst 1.91 / 3.26
    jump = _worst_stretch_jump(body.vertices, result.body.vertices, body.faces)
    openings = np.zeros(len(jump), dtype=bool)
    for part in held.parts:
        openings[part.members[np.concatenate([part.near, part.far]).astype(int)]] = True
    assert jump[openings].max() < 3.0 and jump[openings].max() <= jump[~openings].max()


def test_an_appendage_keeps_its_set_on_the_body_when_eq9_swings_it(horse_held):
    """A deformation that swings the tail 30° about its root (as Eq. 9 can bend a thin tail) leaves
    the held tail at its input set (its opening is where it was), not swung with it."""
    body, held = horse_held
    tail = held.parts[1]
    root = body.vertices[tail.members[tail.near]].mean(axis=0)
    swing = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    moved = body.vertices.copy()
    beyond = np.setdiff1d(tail.members, tail.members[tail.near])
    moved[beyond] = (moved[beyond] - root) @ swing.T + root
    result = held.apply(moved, 1.0)
    _, rotation, _ = similarity_fit(body.vertices[tail.members], result[tail.members])
    assert np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1))) < 1.0
    assert np.allclose(result[tail.members], body.vertices[tail.members], atol=1e-9)


def test_an_appendage_does_not_follow_a_twist_of_its_opening(horse_held):
    """Eq. 9 distorts the small ring where a thin tail joins the rump; the held tail turns as the body
    turned, not as that ring did (fitted on the ring, the camel's hanging tail turned up into its
    rump at ×2)."""
    body, held = horse_held
    tail = held.parts[1]
    ring = tail.members[tail.near]
    centre = body.vertices[ring].mean(axis=0)
    twist = Rotation.from_euler("xyz", [25, 40, -15], degrees=True).as_matrix()
    moved = body.vertices.copy()
    moved[ring] = (moved[ring] - centre) @ twist.T + centre
    result = held.apply(moved, 1.0)
    assert np.allclose(result[tail.members], body.vertices[tail.members], atol=1e-9)


def _turn_degrees(before: np.ndarray, after: np.ndarray) -> float:
    _, rotation, _ = similarity_fit(before, after)
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1))))


def test_a_neck_tilted_with_its_head_is_turned_back(horse_held):
    """Eq. 9 tilts a slanted neck (the demo horse's head nodded 8.6° at ×2): a neck and head swung
    12° about the neck's base, the neck's own base bending with them, are turned back to the
    direction they had, the head's shape kept exactly, and the chest (the body before the neck)
    not touched at all: bent there, the front of the trunk moved and its length with it."""
    body, held = horse_held
    neck = held.parts[0]
    base = body.vertices[neck.members[neck.near]].mean(axis=0)
    zone = neck.base_zone
    assert len(zone.vertices) and np.isin(zone.vertices, neck.members).all()
    moved = body.vertices.copy()
    swung = np.setdiff1d(np.union1d(neck.members, neck.children), zone.vertices)
    nod = Rotation.from_euler("y", 12, degrees=True).as_matrix()
    moved[swung] = (moved[swung] - base) @ nod.T + base
    for vertex, weight in zip(zone.vertices, zone.weight):     # none at the opening, all one zone width in
        bend = Rotation.from_euler("y", 12 * (1.0 - weight), degrees=True).as_matrix()
        moved[vertex] = (moved[vertex] - base) @ bend.T + base
    head = body.region_mask("head")
    assert _turn_degrees(body.vertices[head], moved[head]) == pytest.approx(12.0, abs=1e-6)
    result = held.turned_back(moved)
    assert _turn_degrees(body.vertices[head], result[head]) < 1e-3     # arccos's precision
    assert np.allclose(result, body.vertices, atol=1e-9)
    rest = np.setdiff1d(np.arange(len(moved)), np.union1d(neck.members, neck.children))
    assert np.array_equal(result[rest], moved[rest])
    # a neck that did not turn (the body scaled and moved) is left as it is
    scaled = 1.7 * body.vertices + np.array([0.4, -2.0, 3.0])
    assert np.allclose(held.turned_back(scaled), scaled, rtol=0, atol=1e-9 * np.abs(scaled).max())


def test_a_neck_bent_back_along_its_length_returns_the_head_and_keeps_the_neck_whole(horse_held):
    """Bent along its whole length instead of at its base (``faces`` given: as rigid as possible),
    the neck swung 20° about its base, its base bending with it, is turned back: the head lands
    where it was, the neck comes back to its input shape within a small share of its size (its
    base zone was bent, so not exactly), and nothing but the neck and what it carries moves."""
    body, held = horse_held
    neck = held.parts[0]
    base = body.vertices[neck.members[neck.near]].mean(axis=0)
    zone = neck.base_zone
    moved = body.vertices.copy()
    swung = np.setdiff1d(np.union1d(neck.members, neck.children), zone.vertices)
    nod = Rotation.from_euler("y", 20, degrees=True).as_matrix()
    moved[swung] = (moved[swung] - base) @ nod.T + base
    for vertex, weight in zip(zone.vertices, zone.weight):
        bend = Rotation.from_euler("y", 20 * (1.0 - weight), degrees=True).as_matrix()
        moved[vertex] = (moved[vertex] - base) @ bend.T + base
    result = held.turned_back(moved, faces=body.faces)
    assert np.allclose(result[neck.children], body.vertices[neck.children], atol=1e-9)   # the head, whole
    size = np.ptp(body.vertices[neck.members], axis=0).max()
    # (the bend its base had when swung is spread along the neck, not undone: 5.5 % at most)
    assert np.abs(result[neck.members] - body.vertices[neck.members]).max() < 0.08 * size
    rest = np.setdiff1d(np.arange(len(moved)), np.union1d(neck.members, neck.children))
    assert np.array_equal(result[rest], moved[rest])


def test_a_head_held_at_its_rules_size_is_turned_back_on_its_base(generated_horse):
    """The head, held at its rule's size, turns as Eq. 9 left it too (the cow 381's 1.7° at ×0.5
    with its neck turned back): a head swung 10° about its base, its base bent with it, is turned
    back to its input direction, the seam where it meets the neck left where it was."""
    body = generated_horse.body()
    held = hold_regions(body, ("neck", "head"), {"head": 0.7})
    head = next(part for part in held.parts if part.region == "head")
    assert head.ruled and len(head.near_zone.vertices)
    base = body.vertices[head.members[head.near]].mean(axis=0)
    zone = head.near_zone
    moved = body.vertices.copy()
    swung = np.setdiff1d(np.union1d(head.members, head.children), zone.vertices)
    nod = Rotation.from_euler("z", -10, degrees=True).as_matrix()
    moved[swung] = (moved[swung] - base) @ nod.T + base
    for vertex, weight in zip(zone.vertices, zone.weight):     # 1 at the seam: it stays
        bend = Rotation.from_euler("z", -10 * (1.0 - weight), degrees=True).as_matrix()
        moved[vertex] = (moved[vertex] - base) @ bend.T + base
    mask = body.region_mask("head")
    assert _turn_degrees(body.vertices[mask], moved[mask]) > 5.0
    result = held.turned_back(moved)
    assert np.allclose(result, body.vertices, atol=1e-9)
    # the head alone (neck=False) is turned back the same; the rest, the neck too, is left as it is
    alone = held.turned_back(moved, neck=False)
    assert np.allclose(alone, body.vertices, atol=1e-9)
    neck = next(part for part in held.parts if part.region == "neck")
    rest = np.setdiff1d(np.arange(len(moved)), np.union1d(head.members, head.children))
    tilted = moved.copy()
    tilted[rest] = (tilted[rest] - base) @ Rotation.from_euler("z", 5, degrees=True).as_matrix().T + base
    assert not np.allclose(held.turned_back(tilted)[neck.members], tilted[neck.members])
    assert np.array_equal(held.turned_back(tilted, neck=False)[rest], tilted[rest])


def test_touching_appendages_of_two_regions_are_one_part_and_both_keep_their_shape(generated_horse):
    """An ear and a horn that share a vertex are held as one part: held apart, the one applied
    second moved the first's shared vertices (the cow 381's ears came out at 0.9039 for 0.9). Here
    the tail's far half is named ears: two open appendages touching along a ring."""
    body = generated_horse.body()
    tail = body.region_mask("tail")
    root = body.vertices[tail & np.isin(np.arange(len(tail)), body.faces[~body.region_face_mask("tail")])].mean(axis=0)
    reach = np.linalg.norm(body.vertices - root, axis=1)
    far = tail & (reach > np.median(reach[tail]))
    labels = body.labels.copy()
    labels[far] = len(body.region_names)
    split = body.with_labels(labels, body.region_names + ("ears",))
    held = hold_regions(split, ("tail", "ears"))
    assert set(held.regions) == {"tail", "ears"} and len(held.parts) == 1
    assert held.parts[0].region == "tail" and held.parts[0].joined == ("ears",)
    result = held.apply(_deformed(split.vertices), K)
    for region in ("tail", "ears"):
        members = np.unique(split.faces[split.region_face_mask(region)])
        scale, residual = _similarity_residual(split.vertices[members], result[members])
        assert scale == pytest.approx(K, rel=1e-9) and residual < 1e-9, region


def test_a_run_the_shape_hold_cannot_meet_is_made_again_stretched_then_with_soft_terms(generated_horse, monkeypatch):
    """The pipeline's fallbacks (runs/pipeline.py): held by their shape the open regions left a
    target missed (the real horse at ×2), so the run is made again with the trunk's length held
    isometric, the trunk's stretch its lever (the bull 386 at ×2), kept when it meets every target;
    else with the stretch free, kept when it meets every target; else with ``hold: soft`` on the body
    folded as that setting folds it, kept only when it meets every target with every open region
    within the tolerance of isometric; when it misses, or meets the rules by letting the neck go
    (the real horse: neck length 0.515), the first run is kept and says so."""
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline
    from allorules.runs.results import BiologyScalingResult
    from allorules.solve.open_regions import OpenRegionOutcome

    body = generated_horse.body()                     # its labels keep the tail apart
    assert "tail" in body.region_names
    calls = []
    # case: (the stretched run converges, the soft run converges, the soft run's neck length exponent)
    cases = {"stretch meets": (True, True, 0.345), "stretch overdraws": (True, True, 0.345),
             "hold meets": (False, True, 0.345), "soft meets": (False, True, 0.345),
             "soft strays": (False, True, 0.515), "all miss": (False, False, 0.345)}

    def fake(labelled, ruleset, ratio, **options):
        hold, stretch, held_trunk = ruleset.open_regions.hold, ruleset.solver.trunk_stretch, ruleset.solver.trunk_hold
        calls.append((hold, stretch, held_trunk, labelled.region_names))
        stretch_meets, soft_meets, soft_neck = cases[case]
        outcome = OpenRegionOutcome("neck", "isometric", "length", 1 / 3, soft_neck if hold == "soft" else 1 / 3, True,
                                    0.02, hold)
        if held_trunk == "on" and case == "hold meets":
            return BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=True, messages=[],
                                        open_regions=[outcome], trunk_length_exponent=0.333)
        if stretch == "on":     # the trunk's length as the run's _finish checks it (the horse's 0.384; the donkey's 1.43)
            trunk = 1.43 if case == "stretch overdraws" else 0.384
            messages = [] if case == "stretch meets" else (
                ["the trunk's length reached exponent 1.430 with the trunk's stretch, beyond 0.333 ± 0.1"]
                if case == "stretch overdraws" else ["mass ratio 1.9212, target 2.0000"])
            return BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=not messages,
                                        messages=messages, open_regions=[outcome], trunk_length_exponent=trunk)
        converged = soft_meets if hold == "soft" else False
        return BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=converged,
                                    messages=[] if converged else ["mass ratio 1.9212, target 2.0000"],
                                    open_regions=[outcome])

    monkeypatch.setattr(pipeline, "scale_with_ruleset", fake)
    monkeypatch.setattr(pipeline, "BASIS_EVERY", 1)   # the tries alone (made again with a basis every step: test_biology_scaling)
    quadruped = load_ruleset("quadruped")   # the limbs' thickness off: its own try is tested below
    scaling = pipeline.RulesetScaling(replace(quadruped, solver=replace(quadruped.solver, limb_thickness="off")), 2.0)
    first, held, stretched = ("shape", "when-needed", "when-needed"), ("shape", "when-needed", "on"), ("shape", "on", "off")
    for case in cases:
        calls.clear()
        result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
        tried = [call[:3] for call in calls]
        if case == "stretch meets":
            assert tried == [first, held, stretched]
            assert result.converged and "the trunk's length along the body as one more variable (length exponent 0.384" in result.warnings[0]
            continue
        if case == "hold meets":
            assert tried == [first, held]
            assert result.converged and "held isometric by a soft term (length exponent 0.333" in result.warnings[0]
            continue
        assert tried == [first, held, stretched, ("soft", "when-needed", "when-needed")]
        # the soft run keeps the tail apart too (held by soft terms, and judged on it): folded into
        # the abdomen it followed the abdomen's rules (the camel's tail vanished into its rump at ×2)
        assert all("tail" in call[3] for call in calls)
        if case == "stretch overdraws":
            assert "trunk's length reached exponent 1.430" in " ".join(result.warnings)
        if case in ("soft meets", "stretch overdraws"):
            assert result.converged and result.open_regions[0].hold == "soft"
            assert "held by soft terms instead" in result.warnings[0]
        else:
            assert not result.converged and result.open_regions[0].hold == "shape"
            assert "did not help" in result.warnings[-2] and "did not help" in result.warnings[-1]
            assert ("length exponent 0.515" in result.warnings[-1]) == (case == "soft strays")
    # a ruleset that turns the stretch off goes straight to soft terms (the hold needs δ)
    calls.clear()
    case = "soft meets"
    off = replace(scaling.ruleset, solver=replace(scaling.ruleset.solver, trunk_stretch="off"))
    pipeline.scale(body, pipeline.RulesetScaling(off, 2.0), registry=pipeline.registry_for(None))
    assert [call[:2] for call in calls] == [("shape", "off"), ("soft", "off")]
    calls.clear()
    monkeypatch.setattr(pipeline, "scale_with_ruleset",
                        lambda labelled, ruleset, ratio, **options: calls.append(1) or BiologyScalingResult(
                            body=labelled, target_mass_ratio=ratio, converged=True))
    assert pipeline.scale(body, scaling, registry=pipeline.registry_for(None)).converged and calls == [1]


@pytest.mark.parametrize("stops", ["at a step", "measuring"])
def test_a_run_made_again_that_cannot_solve_a_step_is_one_more_miss_not_the_end(generated_horse, monkeypatch, stops):
    """A run made again whose step cannot be solved (the cow 381 sitting at ×2, held by soft terms:
    its folded horns' volume at step 6), or that cannot measure at all (the same, on a later working
    mesh: at the start), does not end the command with that error: it did not help, the first run
    is reported with what each try did. The first run's own failure still raises."""
    from allorules.errors import MeasurementError, ScalingError
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline
    from allorules.runs.results import BiologyScalingResult
    from allorules.solve.open_regions import OpenRegionOutcome

    body = generated_horse.body()
    calls = []

    def fake(labelled, ruleset, ratio, **options):
        calls.append(ruleset.open_regions.hold)
        outcome = OpenRegionOutcome("neck", "isometric", "length", 1 / 3, 1 / 3, True, 0.02, ruleset.open_regions.hold)
        missed = BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=False,
                                      messages=["rule 'foreleg-length' reached exponent 0.381, target 0.360"],
                                      open_regions=[outcome])
        if len(calls) == 1:
            return missed
        if stops == "measuring":
            raise MeasurementError("volume of region 'horns' could not be determined even after capping")
        stopped = BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=False, open_regions=[outcome],
                                       messages=["step 6 of 8 could not be solved: volume of region 'horns' cannot be determined"])
        raise ScalingError(stopped.messages[0], closest=stopped)

    monkeypatch.setattr(pipeline, "scale_with_ruleset", fake)
    monkeypatch.setattr(pipeline, "BASIS_EVERY", 1)   # the tries alone (made again with a basis every step: test_biology_scaling)
    result = pipeline.scale(body, pipeline.RulesetScaling(load_ruleset("quadruped"), 2.0), registry=pipeline.registry_for(None))
    assert len(calls) > 2 and calls[-1] == "soft"                        # every try was made
    assert not result.converged and result.messages[0].startswith("rule 'foreleg-length'")   # the first run's verdict
    assert sum("could not be" in warning for warning in result.warnings) == len(calls) - 1
    calls.clear()
    calls.append("first fails")   # the first run's own failure is the command's
    with pytest.raises(MeasurementError if stops == "measuring" else ScalingError, match="could not be"):
        pipeline.scale(body, pipeline.RulesetScaling(load_ruleset("quadruped"), 2.0), registry=pipeline.registry_for(None))


def test_a_head_whose_rule_fixes_its_size_is_held_at_that_size_unless_told(generated_horse):
    """rule_held_regions: quadruped's head (mass 0.70) is held at scale^0.70 (R^(0.7/3)); a head with
    a length rule that agrees is too; rules that ask two sizes, a torso or limb region, a measure of
    unknown dimension and solver.ruled_shape: reshape hold nothing."""
    from allorules.rules.model import Rule
    from allorules.rules.resolve import load_ruleset
    from allorules.solve.held_regions import rule_held_regions

    body = generated_horse.body()
    quadruped = load_ruleset("quadruped")
    assert rule_held_regions(quadruped, body) == {"head": 0.7}

    def with_rules(*extra):
        return replace(quadruped, rules=quadruped.rules + tuple(extra))

    agrees = Rule(id="head-length", region="head", measure="length", exponent=0.7 / 3)
    assert rule_held_regions(with_rules(agrees), body) == {"head": 0.7}
    disagrees = Rule(id="head-length", region="head", measure="length", exponent=0.3)
    assert rule_held_regions(with_rules(disagrees), body) == {}
    unknown = Rule(id="head-fur", region="head", measure="fur-depth", exponent=0.3)
    assert rule_held_regions(with_rules(unknown), body) == {}
    assert rule_held_regions(replace(quadruped, solver=replace(quadruped.solver, ruled_shape="reshape")), body) == {}
    held = hold_regions(body, ("neck", "head"), {"head": 0.7})
    assert {part.region: part.size_exponent for part in held.parts} == {"neck": 1.0, "head": 0.7}


def test_limb_thickness_when_needed_is_tried_before_the_trunks_stretch_and_kept_on(generated_horse, monkeypatch):
    """solver.limb_thickness: when-needed makes a missed run again with κ, then with κ and the trunk
    held, then with κ and δ (κ kept for the tries after it), then with soft terms; the first that
    meets is kept and says what it took."""
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline
    from allorules.runs.results import BiologyScalingResult
    from allorules.solve.open_regions import OpenRegionOutcome

    body = generated_horse.body()
    calls = []

    def fake(labelled, ruleset, ratio, **options):
        solver = ruleset.solver
        calls.append((ruleset.open_regions.hold, solver.limb_thickness, solver.trunk_stretch))
        converged = (solver.limb_thickness, solver.trunk_stretch) == ("on", meets)
        outcome = OpenRegionOutcome("neck", "isometric", "length", 1 / 3, 1 / 3, True, 0.02, ruleset.open_regions.hold)
        return BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=converged,
                                    messages=[] if converged else ["mass ratio 1.9212, target 2.0000"],
                                    open_regions=[outcome], trunk_length_exponent=0.35)

    monkeypatch.setattr(pipeline, "scale_with_ruleset", fake)
    quadruped = load_ruleset("quadruped")
    scaling = pipeline.RulesetScaling(replace(quadruped, solver=replace(quadruped.solver, limb_thickness="when-needed")), 2.0)
    meets = "when-needed"                   # κ alone meets
    result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
    assert calls == [("shape", "when-needed", "when-needed"), ("shape", "on", "when-needed")]
    assert result.converged and "the limbs' thickness as one more variable" in result.warnings[0]
    calls.clear()
    meets = "on"                            # κ and δ together meet
    result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
    assert calls == [("shape", "when-needed", "when-needed"), ("shape", "on", "when-needed"),
                     ("shape", "on", "when-needed"), ("shape", "on", "on")]        # κ; κ and the hold; κ and δ
    assert result.converged and "(length exponent 0.350" in result.warnings[0]


def test_a_run_that_missed_only_the_trunk_tries_the_hold_alone_first(generated_horse, monkeypatch):
    """A first run that met every target but the trunk's length (the real horse at ×2: 0.437) is
    made again with the trunk held alone (the real horse, the bull 386 and the donkey 385 at ×2
    converge so), then with κ and the trunk held together (the Princeton horse 382 at ×0.5), then
    with κ alone, then with δ free; one that missed a rule as well keeps the order κ, κ held, κ
    and δ free."""
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline
    from allorules.runs.results import BiologyScalingResult
    from allorules.solve.open_regions import OpenRegionOutcome

    body = generated_horse.body()
    calls = []

    def fake(labelled, ruleset, ratio, **options):
        solver = ruleset.solver
        calls.append((solver.limb_thickness, solver.trunk_hold, solver.trunk_stretch))
        converged = calls[-1] == meets
        outcome = OpenRegionOutcome("neck", "isometric", "length", 1 / 3, 1 / 3, True, 0.02, ruleset.open_regions.hold)
        missed = () if converged else first_missed
        return BiologyScalingResult(body=labelled, target_mass_ratio=ratio, converged=converged, missed=missed,
                                    messages=["a miss"] * len(missed), open_regions=[outcome],
                                    trunk_length_exponent=0.336 if converged else 0.437)

    monkeypatch.setattr(pipeline, "scale_with_ruleset", fake)
    scaling = pipeline.RulesetScaling(load_ruleset("quadruped"), 2.0)
    first = ("when-needed", "when-needed", "when-needed")
    both, held, thick, free = (("on", "on", "when-needed"), ("off", "on", "when-needed"), ("on", "off", "when-needed"),
                               ("on", "off", "on"))
    first_missed, meets = ("trunk",), held
    result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
    assert calls == [first, held]
    assert result.converged
    assert result.warnings[0].startswith("the open regions held by their shape, the rules were met only with the trunk's")
    calls.clear()
    meets = both
    result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
    assert calls == [first, held, both] and result.converged
    assert "the limbs' thickness and the trunk's length held" in result.warnings[0]
    calls.clear()
    meets = free                                    # held, κ held, κ alone miss; δ free meets
    result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
    assert calls == [first, held, both, thick, free] and result.converged
    calls.clear()
    first_missed, meets = ("rule", "trunk"), both
    result = pipeline.scale(body, scaling, registry=pipeline.registry_for(None))
    assert calls == [first, ("on", "when-needed", "when-needed"), both]      # κ, then κ held
    assert result.converged


@pytest.mark.parametrize("mesh, regions", [
    ("wolf.obj", {"neck", "tail"}),
    ("psb-fourleg/381.off", {"neck", "ears", "horns"}),
])
def test_every_held_appendage_of_a_real_wolf_keeps_its_shape_exactly(shared_meshes, mesh, regions):
    """A zone spreads its opening's mismatch over the body beside it, never over an appendage held
    before it, and parts that share a vertex are one part: the wolf's neck touched the zone of
    what was then cut as its ears (its lower jaw, since left in the head) and its tail had two
    pieces of 8 vertices touching it at a vertex, so a part applied later moved one applied before
    (the cow 381's ears shrank to length exponent 0.258 at ×0.5 so; its ears and horns touch, and
    held apart the horns moved the ears: scale 0.9039 for 0.9)."""
    from allorules.measure.features import similarity_fit
    from allorules.rules.resolve import load_ruleset
    from allorules.runs import pipeline
    from allorules.solve.open_regions import shape_held_regions

    ruleset = load_ruleset("quadruped")
    prepared = pipeline.prepare(shared_meshes / mesh)
    work = pipeline.working(prepared)
    body = pipeline.label_working(prepared, work, registry=pipeline.registry_for(None),
                                  regions=pipeline.wanted_regions(ruleset))
    held = hold_regions(body, shape_held_regions(ruleset, body))
    assert regions <= set(held.regions)
    for index, part in enumerate(held.parts):
        before = np.concatenate([other.members for other in held.parts[:index] if other.region != "neck"]
                                or [np.zeros(0, int)])
        for zone in (part.near_zone, part.far_zone):
            assert zone is None or not np.isin(zone.vertices, before).any()
    extent = np.ptp(body.vertices, axis=0).max()
    warp = 0.03 * extent * np.sin(body.vertices / extent * np.array([5.0, 7.0, 3.0]))[:, [1, 2, 0]]
    result = held.apply(body.vertices + warp, 0.9)
    for part in [part for part in held.parts if part.region != "neck"]:     # the appendages
        scale, _, offset = similarity_fit(part.reference, result[part.members])
        _, rotation, _ = similarity_fit(part.reference, result[part.members])
        fitted = scale * part.reference @ rotation.T + offset
        assert scale == pytest.approx(0.9, rel=1e-9)
        assert np.abs(fitted - result[part.members]).max() < 1e-9 * extent
    # the neck and the head (held at its rule's size) turned back at the run's end take every
    # appendage growing from them whole: the cow's ears and horns touch its neck, and turned with
    # the head only where they lay beyond it, its horns were torn (length exponent -0.92 at ×0.5)
    with_head = hold_regions(body, shape_held_regions(ruleset, body) + ("head",), {"head": 0.7})
    turned = with_head.turned_back(with_head.apply(body.vertices + warp, 0.9))
    for part in [part for part in with_head.parts if not len(part.far) and not part.ruled]:
        scale, rotation, offset = similarity_fit(part.reference, turned[part.members])
        assert scale == pytest.approx(0.9, rel=1e-9), part.region
        assert np.abs(scale * part.reference @ rotation.T + offset - turned[part.members]).max() < 1e-9 * extent
