"""Global allometric scaling runs (paper §3.1, METHOD §4): from a mass ratio to a mesh.

The user asks for a mass ratio R. Each step solves for the global allometric exponent α and the
isometric factor s of Eq. 4 (:func:`allorules.scaling.global_allometric`) so that the body's mass
changes by the step's ratio r and its peak stress σ = M/A stays as it was:

* For a trial α the mesh is reconstructed with s = 1 and measured: M(1, α), σ(1, α).
* Isometric scaling multiplies mass by s³ and stress by s (σ = s³M / s²A), so s = σ_0 / σ(1, α)
  keeps the stress, and the mass ratio reached is ρ(α) = s³·M(1, α) / M_0.
* One equation in one unknown remains, ρ(α) = r: bracketed by a widening search around α = 0
  (ρ(0) = 1) and solved with Brent's method.

A ratio beyond 1.1 up (0.9 down) goes in n equal steps r = R^(1/n), the harmonic basis recomputed
on each step's mesh (warm-started from the previous one), as in the paper.

**Where stress is measured.** The candidate load-bearing cross-sections are chosen ONCE, on the
input body, by the rule of :func:`allorules.measures.load_bearing_section` (every limb section
between the junction and tip margins; or only the user's
:class:`~allorules.measures.SectionChoice`), and then followed as material bands: the same
isocontour level of the same limb field on the same vertices (:class:`MaterialBand`). The mesh
keeps its connectivity, so each contour crosses the same edges at the same parameters and only
moves with them. A is the smallest band's area (:class:`StressGauge`). Stress before and after
every trial, step and run is therefore measured at the same places on the limbs, never
re-chosen from new contours; the peak may still move from one band to another if the shape
change moves it. (Re-choosing from scratch on the output is reported separately, as an
independent check.)

Mass is the enclosed volume of the capped body (:func:`allorules.measures.body_mass`).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable, ClassVar

import numpy as np
from scipy.optimize import brentq

from .basis import HarmonicBasis, compute_basis, transform
from .body import Body
from .errors import AllorulesError, BasisError, MeasurementError, ScalingError
from .progress import RunProgress
from .scaling import apply_to_mesh, global_allometric, relative_eigenvalues

log = logging.getLogger("allorules")

MAXIMUM_MASS_RATIO = 1000.0
MINIMUM_MASS_RATIO = 0.001
STEP_UP = 1.1
STEP_DOWN = 0.9
# The bracket search for α widens by doubling from ALPHA_LIMIT / 256 up to ALPHA_LIMIT either way.
ALPHA_LIMIT = 1.0
ALPHA_DOUBLINGS = 8
# A step whose solution folds more than this share of the faces over is refused, not returned.
MAXIMUM_FLIPPED_SHARE = 0.001
# Solve each step's mass ratio to this relative accuracy.
RATIO_TOLERANCE = 1e-7

StressMeasure = Callable[[Body], float]


# ---------------------------------------------------------------------------------------------
# Stress measured at a fixed material band


@dataclass(frozen=True)
class MaterialBand:
    """One limb cross-section fixed to the material.

    Chosen as a closed isocontour of a limb field on one body; kept as the mesh edges it crosses
    (``edge_start``, ``edge_end``: body vertex indices, in loop order) and where it crosses them
    (``t``). On a deformed body with the same connectivity, the same contour of the same frozen
    field crosses the same edges at the same parameters, so the band follows the same place on
    the limb: its points are p_k = v[edge_start_k] + t_k (v[edge_end_k] − v[edge_start_k]).
    """

    region: str
    part: int
    fraction: float               # along the limb when chosen (0 junction, 1 tip)
    edge_start: np.ndarray
    edge_end: np.ndarray
    t: np.ndarray

    @classmethod
    def from_loop(cls, region: str, part: int, fraction: float, loop, part_faces: np.ndarray,
                  part_vertex_index: np.ndarray, field: np.ndarray, part_vertices: np.ndarray) -> "MaterialBand":
        """Freeze a closed isocontour ``loop`` (of ``field`` at ``loop.level``) of a limb part."""
        faces = np.asarray(part_faces)[np.asarray(loop.faces)]
        starts, ends = [], []
        # Point k ends the segment through face k−1 and starts the one through face k: it lies on
        # the edge those two faces share.
        for previous, current in zip(np.roll(faces, 1, axis=0), faces):
            shared = np.intersect1d(previous, current)
            if len(shared) != 2:
                raise MeasurementError(f"a cross-section of {region!r} is not a simple loop; cannot follow it")
            starts.append(shared[0])
            ends.append(shared[1])
        starts, ends = np.asarray(starts), np.asarray(ends)
        t = (loop.level - field[starts]) / (field[ends] - field[starts])
        points = part_vertices[starts] + t[:, None] * (part_vertices[ends] - part_vertices[starts])
        scale = np.ptp(part_vertices, axis=0).max()
        if not np.allclose(points, loop.points, atol=1e-9 * scale, rtol=0):
            raise MeasurementError(f"a cross-section of {region!r} could not be frozen to the mesh edges")
        index = np.asarray(part_vertex_index)
        return cls(region, part, float(fraction), index[starts], index[ends], t)

    def points(self, vertices: np.ndarray) -> np.ndarray:
        start, end = vertices[self.edge_start], vertices[self.edge_end]
        return start + self.t[:, None] * (end - start)

    def area(self, vertices: np.ndarray) -> float:
        """‖½ Σ p_k × p_{k+1}‖ (METHOD §3), about the loop's mean point for round-off."""
        points = self.points(np.asarray(vertices))
        centred = points - points.mean(axis=0)
        return float(np.linalg.norm(0.5 * np.cross(centred, np.roll(centred, -1, axis=0)).sum(axis=0)))


@dataclass(frozen=True)
class StressGauge:
    """Peak stress σ = M / A measured at cross-sections frozen to the material.

    Without an override, the bands are every candidate of the automatic rule of
    :func:`allorules.measures.load_bearing_section` on the body it was chosen on (all limb
    sections between the junction and tip margins) and A is the smallest of their areas, so the
    peak moves along the limb if the scaling moves it, while every band stays the same material
    ring (a min of smooth functions of α, which the root find can bracket). With an override
    (:class:`allorules.measures.SectionChoice`) the single chosen section is followed.
    """

    bands: tuple[MaterialBand, ...]

    @classmethod
    def choose(cls, body: Body, override=None) -> "StressGauge":
        from . import measures

        def band(region, limb, section) -> MaterialBand:
            return MaterialBand.from_loop(region, limb.part, section.fraction, section.loop, limb.mesh.faces,
                                          limb.mesh.vertex_index, np.asarray(limb.field, dtype=float), limb.mesh.vertices)

        chosen = measures.load_bearing_section(body, override=override)   # raises the clear errors
        if override is not None:
            limb = measures.limb_sections(body, chosen.region)[chosen.part]
            return cls((band(chosen.region, limb, chosen.section),))
        bands = []
        for region in measures.LIMB_REGIONS:
            if not body.has_region(region) or not body.region_face_mask(region).any():
                continue
            for limb in measures.limb_sections(body, region):
                for section in limb.sections:
                    if measures.JUNCTION_SKIP <= section.fraction <= 1.0 - measures.TIP_SKIP:
                        bands.append(band(region, limb, section))
        return cls(tuple(bands))

    def areas(self, vertices: np.ndarray) -> np.ndarray:
        return np.asarray([band.area(vertices) for band in self.bands])

    def area(self, vertices: np.ndarray) -> float:
        return float(np.min(self.areas(vertices)))

    def stress(self, body: Body) -> float:
        """σ = M / A (density cancels; only ratios are used)."""
        from .measures import body_mass

        area = self.area(body.vertices)
        if not area > 0:
            raise MeasurementError("a load-bearing limb section collapsed to zero area")
        return body_mass(body) / area

    def describe(self, vertices: np.ndarray | None = None) -> dict:
        """Which band carries the peak (on ``vertices``, if given) and how many are followed."""
        index = int(np.argmin(self.areas(vertices))) if vertices is not None else 0
        band = self.bands[index]
        return {"region": band.region, "part": int(band.part), "fraction": round(band.fraction, 4),
                "bands_followed": len(self.bands)}


# ---------------------------------------------------------------------------------------------
# Results


@dataclass
class ScalingStep:
    """One step of a run: the solved α and s and what they did (measured on the step's output)."""

    alpha: float
    scale: float
    target_mass_ratio: float
    mass_ratio: float          # M_out / M_in of this step
    stress_ratio: float        # σ_out / σ_in of this step
    modes: int
    flipped_faces: int
    evaluations: int           # trial meshes measured by the root find

    def as_dict(self) -> dict:
        return {key: (float(value) if isinstance(value, (float, np.floating)) else value)
                for key, value in vars(self).items()}


@dataclass
class ScalingResult:
    """A scaling run. ``mass_ratio``/``stress_ratio`` are measured on the final body against the
    input body (stress at the same material section, see :class:`StressGauge`). The global run's
    result; :class:`allorules.biology_scaling.BiologyScalingResult` adds a ruleset run's figures."""

    mode: ClassVar[str] = "global"

    body: Body
    target_mass_ratio: float
    steps: list = field(default_factory=list)
    mass_ratio: float = 1.0
    stress_ratio: float | None = 1.0
    flipped_faces: int = 0
    converged: bool = False
    messages: list[str] = field(default_factory=list)
    section: dict | None = None

    def as_dict(self) -> dict:
        """The report (JSON-ready): the figures every run has, then :meth:`details`."""
        return {
            "mode": self.mode,
            "target_mass_ratio": float(self.target_mass_ratio),
            "mass_ratio": float(self.mass_ratio),
            "stress_ratio": None if self.stress_ratio is None else float(self.stress_ratio),
            "steps": len(self.steps),
            "step_details": [step.as_dict() for step in self.steps],
            "flipped_faces": int(self.flipped_faces),
            "faces": int(len(self.body.faces)),
            "converged": bool(self.converged),
            "messages": list(self.messages),
            "section": self.section,
            **self.details(),
        }

    def details(self) -> dict:
        """What only this kind of run reports: the global run's α and s per step."""
        return {"alphas": [float(step.alpha) for step in self.steps], "scales": [float(step.scale) for step in self.steps]}


# ---------------------------------------------------------------------------------------------
# Helpers


def check_mass_ratio(ratio: float) -> float:
    """Refuse mass ratios that are not positive, not finite or absurd (beyond 1000 or 1/1000)."""
    try:
        ratio = float(ratio)
    except (TypeError, ValueError):
        raise ScalingError(f"mass ratio must be a number, got {ratio!r}") from None
    if not math.isfinite(ratio) or ratio <= 0:
        raise ScalingError(f"mass ratio must be a positive number, got {ratio:g} (2 doubles the mass, 0.5 halves it)")
    if ratio > MAXIMUM_MASS_RATIO or ratio < MINIMUM_MASS_RATIO:
        raise ScalingError(
            f"mass ratio {ratio:g} is absurd for one character: give a ratio between "
            f"{MINIMUM_MASS_RATIO:g} and {MAXIMUM_MASS_RATIO:g}"
        )
    return ratio


def step_ratios(ratio: float, step_up: float = STEP_UP, step_down: float = STEP_DOWN) -> list[float]:
    """n equal steps r = R^(1/n), n the smallest with r ≤ step_up (up) or r ≥ step_down (down)."""
    if not step_up > 1.0 or not 0.0 < step_down < 1.0:
        raise ValueError(f"step_up must be > 1 and step_down in (0, 1), got {step_up}, {step_down}")
    if ratio == 1.0:
        return []
    limit = step_up if ratio > 1.0 else step_down
    count = max(1, math.ceil(math.log(ratio) / math.log(limit) - 1e-12))
    return [ratio ** (1.0 / count)] * count


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalised face normals (b − a) × (c − a)."""
    corner = np.asarray(vertices)[faces]
    return np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])


def count_flipped_faces(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> int:
    """Faces whose normal turned by more than 90° (n_before · n_after ≤ 0 on a non-degenerate face)."""
    normal_before, normal_after = face_normals(before, faces), face_normals(after, faces)
    dot = np.einsum("ij,ij->i", normal_before, normal_after)
    return int(np.sum(dot <= 0))


def _default_mass(body: Body) -> float:
    from .measures import body_mass

    return body_mass(body)


def step_basis(body: Body, modes: int | None, warm_start: HarmonicBasis | None, use_cache: bool,
               progress: Callable[[int, int], None] | None = None) -> HarmonicBasis:
    """A scaling step's basis on its start mesh, warm-started from the previous step's; refuses a
    mesh whose spectrum cannot be made dimensionless (λ_1 = 0: more than one piece)."""
    basis = compute_basis(body.vertices, body.faces, modes, use_cache=use_cache, warm_start=warm_start,
                          progress=progress)
    try:
        relative_eigenvalues(basis.eigenvalues)
    except ValueError as error:
        raise BasisError(f"cannot scale this mesh: {error}") from None
    return basis


# ---------------------------------------------------------------------------------------------
# One step: the 1-D root find


@dataclass
class _Trial:
    alpha: float
    scale: float
    mass_ratio: float
    stress_ratio: float


def _solve_step(
    body: Body,
    basis: HarmonicBasis,
    target: float,
    mass: Callable[[Body], float],
    stress: StressMeasure,
    alpha_limit: float,
    on_trial: Callable[[int, float], None] | None = None,
) -> tuple[np.ndarray, _Trial, int]:
    """Find α (and s) with ρ(α) = target; returns the new vertices, the solution, evaluations.
    ``on_trial(count, misfit)`` is told of every trial mesh (misfit: best log(ρ/r)² so far)."""
    vertices = body.vertices
    coefficients = transform(basis, vertices)
    mass_0, stress_0 = mass(body), stress(body)
    trials: list[_Trial] = []

    def trial(alpha: float) -> _Trial:
        shaped = body.with_vertices(apply_to_mesh(basis, vertices, global_allometric(coefficients, basis.eigenvalues, alpha, 1.0), 1.0,
                                                  coefficients=coefficients))
        mass_1, stress_1 = mass(shaped), stress(shaped)
        if not (np.isfinite(mass_1) and np.isfinite(stress_1) and mass_1 > 0 and stress_1 > 0):
            raise MeasurementError(f"α = {alpha:g} gives a mesh whose mass or stress cannot be measured")
        scale = stress_0 / stress_1                                  # σ(s, α) = s·σ(1, α) = σ_0
        result = _Trial(alpha, scale, scale ** 3 * mass_1 / mass_0, 1.0)  # M(s, α) = s³·M(1, α)
        trials.append(result)
        if on_trial is not None:
            on_trial(len(trials), min(math.log(t.mass_ratio / target) ** 2 for t in trials))
        return result

    def residual(alpha: float) -> float:
        return math.log(trial(alpha).mass_ratio / target)

    # Widening search for a sign change of log(ρ(α)/r), both sides of α = 0 in turn (ρ(0) = 1), so
    # that the root nearest to isometric scaling is the one found.
    zero = residual(0.0)
    bracket = None
    failures = []
    last = {1.0: (0.0, zero), -1.0: (0.0, zero)}
    alpha = alpha_limit / 2 ** ALPHA_DOUBLINGS
    while bracket is None and last and alpha <= alpha_limit * (1 + 1e-12):
        for direction in [d for d in (1.0, -1.0) if d in last]:
            previous_alpha, previous_value = last[direction]
            try:
                value = residual(direction * alpha)
            except AllorulesError as error:
                failures.append(f"α = {direction * alpha:g}: {error}")
                del last[direction]
                continue
            if np.sign(value) != np.sign(previous_value):
                bracket = sorted([(previous_alpha, previous_value), (direction * alpha, value)])
                break
            last[direction] = (direction * alpha, value)
        alpha *= 2.0
    if bracket is None:
        closest = min(trials, key=lambda t: abs(math.log(t.mass_ratio / target)))
        searched = f"[{-alpha_limit:g}, {alpha_limit:g}]"
        why = f" ({'; '.join(failures)})" if failures else ""
        raise ScalingError(
            f"no α in {searched} reaches a mass ratio of {target:.4g} at unchanged peak stress: the closest "
            f"was {closest.mass_ratio:.4g} at α = {closest.alpha:.4g}, s = {closest.scale:.4g}{why}; "
            "the load-bearing section may not respond to α (check the limb labels) — try a smaller ratio",
            closest=closest,
        )
    (low, _), (high, _) = bracket
    alpha = brentq(residual, low, high, xtol=1e-12, rtol=1e-10, maxiter=200)
    solution = trial(alpha)
    if abs(math.log(solution.mass_ratio / target)) > RATIO_TOLERANCE * 10:
        raise ScalingError(f"the root find for α did not converge (mass ratio {solution.mass_ratio:.6g} for {target:.6g})",
                           closest=solution)
    new_vertices = apply_to_mesh(basis, vertices, global_allometric(coefficients, basis.eigenvalues, alpha, solution.scale),
                                 solution.scale, coefficients=coefficients)
    flipped = count_flipped_faces(vertices, new_vertices, body.faces)
    if flipped > MAXIMUM_FLIPPED_SHARE * len(body.faces):
        raise ScalingError(
            f"the only α found ({alpha:.4g}, s = {solution.scale:.4g}) folds {flipped} of {len(body.faces)} faces over; "
            "refusing a broken mesh — use more harmonic modes (--modes) or a smaller ratio",
            closest=solution,
        )
    return new_vertices, solution, len(trials)


# ---------------------------------------------------------------------------------------------
# Runs


def scale_globally(
    body: Body,
    mass_ratio: float,
    *,
    modes: int | None = None,
    stress: StressMeasure | None = None,
    mass: Callable[[Body], float] | None = None,
    section=None,
    step_up: float = STEP_UP,
    step_down: float = STEP_DOWN,
    alpha_limit: float = ALPHA_LIMIT,
    use_cache: bool = True,
    progress: RunProgress | None = None,
) -> ScalingResult:
    """Scale ``body`` so that its mass changes by ``mass_ratio`` with peak stress unchanged.

    ``stress`` (Body → σ) replaces the default, which freezes the load-bearing limb section of
    the input (``section``: an optional :class:`allorules.measures.SectionChoice`) and follows it
    (:class:`StressGauge`); the default needs a labelled body with a limb region. ``mass``
    replaces :func:`allorules.measures.body_mass`. ``progress`` is told of the steps, each basis
    and each trial (:class:`allorules.progress.RunProgress`). Raises :class:`ScalingError` (with
    ``closest`` = the partial result) when a step's α cannot be found.
    """
    target = check_mass_ratio(mass_ratio)
    ratios = step_ratios(target, step_up, step_down)
    mass = mass or _default_mass
    gauge = None
    if stress is None:
        gauge = StressGauge.choose(body, override=section)
        stress = gauge.stress
    initial = body
    mass_initial, stress_initial = mass(initial), stress(initial)
    result = ScalingResult(body=initial, target_mass_ratio=target, section=gauge.describe(initial.vertices) if gauge else None)
    basis = None
    current = initial
    progress = progress or RunProgress()
    for index, ratio in enumerate(ratios):
        progress.step_started(index + 1, len(ratios))
        basis = step_basis(current, modes, basis, use_cache, progress.basis)
        try:
            new_vertices, solution, evaluations = _solve_step(current, basis, ratio, mass, stress, alpha_limit,
                                                              progress.trial)
        except ScalingError as error:
            result.body = current
            _finish(result, initial, mass_initial, stress_initial, mass, stress)
            result.messages.append(f"step {index + 1} of {len(ratios)}: {error}")
            raise ScalingError(
                f"step {index + 1} of {len(ratios)} failed after reaching a mass ratio of {result.mass_ratio:.4g} "
                f"of the requested {target:.4g}: {error}",
                closest=result,
            ) from None
        following = current.with_vertices(new_vertices)
        step = ScalingStep(
            alpha=solution.alpha,
            scale=solution.scale,
            target_mass_ratio=ratio,
            mass_ratio=mass(following) / mass(current),
            stress_ratio=stress(following) / stress(current),
            modes=basis.modes,
            flipped_faces=count_flipped_faces(current.vertices, following.vertices, current.faces),
            evaluations=evaluations,
        )
        result.steps.append(step)
        log.debug("step %d/%d: α = %.5f, s = %.5f, mass ×%.5f, stress ×%.5f", index + 1, len(ratios),
                  step.alpha, step.scale, step.mass_ratio, step.stress_ratio)
        current = following
        progress.step_finished(index + 1, len(ratios))
    result.body = current
    _finish(result, initial, mass_initial, stress_initial, mass, stress)
    result.converged = (abs(math.log(result.mass_ratio / target)) < 1e-4 and abs(math.log(result.stress_ratio)) < 1e-4)
    if not result.converged:
        result.messages.append(
            f"reached mass ratio {result.mass_ratio:.6g} (target {target:.6g}) and stress ratio {result.stress_ratio:.6g}"
        )
    return result


def _finish(result: ScalingResult, initial: Body, mass_initial: float, stress_initial: float, mass, stress) -> None:
    final = result.body
    result.mass_ratio = mass(final) / mass_initial
    result.stress_ratio = stress(final) / stress_initial
    result.flipped_faces = count_flipped_faces(initial.vertices, final.vertices, initial.faces)
    if not np.all(np.isfinite(final.vertices)):   # never hand back a NaN mesh as a result
        raise ScalingError("the scaled mesh has non-finite vertices; nothing was written")


def scale_globally_raw(
    body: Body,
    alpha: float,
    scale: float = 1.0,
    modes: int | None = None,
    *,
    use_cache: bool = True,
) -> Body:
    """Eq. 4 applied once with the user's α and s (no measuring, no stress constraint)."""
    if not (math.isfinite(alpha) and math.isfinite(scale)):
        raise ScalingError(f"alpha and scale must be finite numbers, got {alpha}, {scale}")
    if scale <= 0:
        raise ScalingError(f"scale must be positive, got {scale:g}")
    if abs(alpha) > ALPHA_LIMIT:
        raise ScalingError(f"|alpha| = {abs(alpha):g} is beyond {ALPHA_LIMIT:g}: the fine modes would be scaled "
                           "by absurd factors; typical values are within ±0.2")
    basis = step_basis(body, modes, None, use_cache)
    coefficients = transform(basis, body.vertices)
    vertices = apply_to_mesh(basis, body.vertices, global_allometric(coefficients, basis.eigenvalues, alpha, scale), scale,
                             coefficients=coefficients)
    return body.with_vertices(vertices)
