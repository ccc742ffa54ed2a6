"""Global allometric scaling runs: the bone of Figure 9, the generated quadruped, refusals."""
from __future__ import annotations

import math

import numpy as np
import pytest

from allorules.body import Body
from allorules.errors import ScalingError
from allorules.global_scaling import (
    check_mass_ratio,
    count_flipped_faces,
    scale_globally,
    scale_globally_raw,
    step_ratios,
)
from allorules.measures import enclosed_volume


@pytest.fixture(autouse=True)
def _no_cache(monkeypatch):
    monkeypatch.setenv("ALLORULES_CACHE_DIR", "off")


# ---------------------------------------------------------------------------------------------
# A bone (Galileo's, Figure 9): a closed surface of revolution with knobbly ends and a thin shaft.


def make_bone(rings: int = 30, around: int = 16, length: float = 10.0, radius: float = 1.0):
    """Vertices, faces and the vertex ring at mid-shaft of a bone along z (poles at both ends)."""
    theta = np.pi * np.arange(1, rings) / rings
    z = -0.5 * length * np.cos(theta)
    t = z / (0.5 * length)
    r = radius * (1 + 1.2 * t ** 8) * np.sin(theta) ** 0.25
    phi = 2 * np.pi * np.arange(around) / around
    rings_xyz = np.stack([np.outer(r, np.cos(phi)).ravel(), np.outer(r, np.sin(phi)).ravel(), np.repeat(z, around)], 1)
    vertices = np.concatenate([rings_xyz, [[0, 0, -0.5 * length], [0, 0, 0.5 * length]]])
    south, north, last = len(vertices) - 2, len(vertices) - 1, (rings - 2) * around
    faces = []
    for a in range(rings - 2):
        for b in range(around):
            p, q = a * around + b, a * around + (b + 1) % around
            faces += [[p, q, q + around], [p, q + around, p + around]]
    for b in range(around):
        faces += [[south, (b + 1) % around, b], [north, last + b, last + (b + 1) % around]]
    faces = np.asarray(faces)
    if enclosed_volume(vertices, faces) < 0:
        faces = faces[:, ::-1]
    middle = (rings // 2 - 1) * around + np.arange(around)
    return vertices, faces, middle


class BoneMeasures:
    """Mass, stress at the mid-shaft ring (the same vertices always), girth and length of a bone."""

    def __init__(self, middle: np.ndarray):
        self.middle = middle

    def mass(self, body: Body) -> float:
        return enclosed_volume(body.vertices, body.faces)

    def area(self, vertices: np.ndarray) -> float:
        ring = vertices[self.middle]
        centre = ring.mean(0)
        return float(np.linalg.norm(0.5 * np.cross(ring - centre, np.roll(ring, -1, 0) - centre).sum(0)))

    def stress(self, body: Body) -> float:
        return self.mass(body) / self.area(body.vertices)

    def girth_over_length(self, vertices: np.ndarray) -> float:
        ring = vertices[self.middle]
        girth = np.linalg.norm(np.roll(ring, -1, 0) - ring, axis=1).sum()
        return girth / np.linalg.norm(vertices[-1] - vertices[-2])


BONE_MODES = 80


@pytest.fixture(scope="module")
def bone():
    vertices, faces, middle = make_bone()
    return Body(vertices, faces), BoneMeasures(middle)


def _run(body, measures, ratio, **options):
    return scale_globally(body, ratio, modes=BONE_MODES, stress=measures.stress, mass=measures.mass, use_cache=False, **options)


def _check_output(result, body, measures):
    out = result.body
    assert np.array_equal(out.faces, body.faces)                       # connectivity kept
    assert np.all(np.isfinite(out.vertices))
    assert result.flipped_faces <= 0.001 * len(body.faces)
    assert count_flipped_faces(body.vertices, out.vertices, body.faces) == result.flipped_faces
    # the report's numbers are what an independent measurement of the output gives
    assert measures.mass(out) / measures.mass(body) == pytest.approx(result.mass_ratio, rel=1e-12)
    assert measures.stress(out) / measures.stress(body) == pytest.approx(result.stress_ratio, rel=1e-12)


def test_one_step_keeps_stress_and_reaches_mass(bone):
    body, measures = bone
    result = _run(body, measures, 1.1)
    assert len(result.steps) == 1 and result.converged
    assert result.mass_ratio == pytest.approx(1.1, rel=1e-6)
    assert result.stress_ratio == pytest.approx(1.0, rel=1e-6)
    step = result.steps[0]
    assert step.alpha > 0                  # heavier bone: α > 0 thickens the shaft (see docs/method.md)
    assert step.scale ** 3 < 1.1           # not isometric: part of the mass comes from α
    _check_output(result, body, measures)


def test_run_does_not_depend_on_units_or_orientation(bone):
    body, measures = bone
    q, _ = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))
    moved = Body(1000.0 * body.vertices @ q.T + 50.0, body.faces)
    a, b = _run(body, measures, 0.9), _run(moved, measures, 0.9)
    assert b.steps[0].alpha == pytest.approx(a.steps[0].alpha, rel=1e-6)
    assert b.steps[0].scale == pytest.approx(a.steps[0].scale, rel=1e-6)
    np.testing.assert_allclose(b.body.vertices, 1000.0 * a.body.vertices @ q.T + 50.0, atol=1e-6 * 1000)


@pytest.mark.slow
@pytest.mark.parametrize("ratio", [2.0, 0.5])
def test_bone_heavier_is_relatively_thicker(bone, ratio):
    """Figure 9 / Galileo: at unchanged peak stress a heavier bone is relatively thicker."""
    body, measures = bone
    result = _run(body, measures, ratio)
    assert result.converged
    assert len(result.steps) == len(step_ratios(ratio)) == (8 if ratio > 1 else 7)
    assert result.mass_ratio == pytest.approx(ratio, rel=0.01)
    assert result.stress_ratio == pytest.approx(1.0, abs=0.02)
    shape_change = measures.girth_over_length(result.body.vertices) / measures.girth_over_length(body.vertices)
    if ratio > 1:
        assert shape_change > 1.1
        assert all(step.alpha > 0 for step in result.steps)
    else:
        assert shape_change < 0.9
        assert all(step.alpha < 0 for step in result.steps)
    # the mid-shaft area grew like the mass (stress kept), i.e. faster than isometric (R^(2/3))
    area_ratio = measures.area(result.body.vertices) / measures.area(body.vertices)
    assert area_ratio == pytest.approx(result.mass_ratio, rel=0.02)
    _check_output(result, body, measures)


def test_unreachable_ratio_reports_closest(bone):
    body, measures = bone
    # A "stress" that any isometric factor cancels: ρ(α) ≡ 1, no α reaches 1.1.
    blind = lambda b: measures.mass(b) ** (1.0 / 3.0)
    with pytest.raises(ScalingError, match=r"no α in \[-1, 1\].*closest") as caught:
        scale_globally(body, 1.1, modes=BONE_MODES, stress=blind, mass=measures.mass, use_cache=False)
    closest = caught.value.closest
    assert closest is not None and closest.converged is False
    assert closest.mass_ratio == pytest.approx(1.0, rel=1e-9) and np.array_equal(closest.body.vertices, body.vertices)


@pytest.mark.parametrize("bad", [0.0, -2.0, float("nan"), float("inf"), 1001.0, 0.0009, "two"])
def test_absurd_ratios_are_refused(bad):
    with pytest.raises(ScalingError, match="mass ratio"):
        check_mass_ratio(bad)


def test_step_ratios():
    assert step_ratios(1.0) == []
    assert step_ratios(1.1) == [1.1]
    assert step_ratios(0.9) == [0.9]
    up = step_ratios(2.0)
    assert len(up) == 8 and math.prod(up) == pytest.approx(2.0) and up[0] <= 1.1
    down = step_ratios(0.5)
    assert len(down) == 7 and math.prod(down) == pytest.approx(0.5) and down[0] >= 0.9
    assert len(step_ratios(1000.0)) == math.ceil(math.log(1000) / math.log(1.1))


def test_raw_identity_and_direction_of_alpha(bone):
    body, measures = bone
    assert np.array_equal(scale_globally_raw(body, 0.0, 1.0, modes=BONE_MODES, use_cache=False).vertices, body.vertices)
    before = measures.girth_over_length(body.vertices)
    thicker = scale_globally_raw(body, 0.1, 1.0, modes=BONE_MODES, use_cache=False)
    thinner = scale_globally_raw(body, -0.1, 1.0, modes=BONE_MODES, use_cache=False)
    assert measures.girth_over_length(thicker.vertices) > 1.1 * before
    assert measures.girth_over_length(thinner.vertices) < 0.9 * before
    with pytest.raises(ScalingError):
        scale_globally_raw(body, 0.1, -1.0, modes=BONE_MODES, use_cache=False)


# ---------------------------------------------------------------------------------------------
# The generated quadruped (needs the generator, measures and labels; skipped until they exist)


def _generated(preset: str, vertices: int):
    quadruped = pytest.importorskip("allorules.quadruped")
    return quadruped.generate_quadruped(preset, vertices=vertices)
