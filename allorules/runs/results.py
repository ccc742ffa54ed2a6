"""What a scaling run returns: per-step figures and the whole run's outcome (mass and stress
ratios, each rule's achieved exponent, convergence), JSON-ready for reports.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from allorules.body import Body


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
    result; :class:`allorules.runs.results.BiologyScalingResult` adds a ruleset run's figures."""

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


EXPONENT_TOLERANCE = 0.02


MASS_TOLERANCE = 0.01


CONSTRAINT_TOLERANCE = 0.02


# A run with the trunk's stretch (solver.trunk_stretch) converges only with the trunk's length (chest
# and abdomen along their skeletons) within this of isometric's exponent 1/3: the real horse at ×2
# needed 0.384; unchecked, the stretch drew the Princeton donkey's trunk out to 1.43 with every rule met.
TRUNK_LENGTH_TOLERANCE = 0.1

# A run that converged with its trunk's length further than this from 1/3 (where no rule measures it)
# is made again with the trunk held isometric by a soft term (solver.trunk_hold: when-needed) and the
# held run kept if it converges nearer without its trunk humping more (runs/pipeline.py). Within
# ±0.1 the real horse at ×2 came out at 0.419 with its chest rising into its neck, giraffe-like,
# where held (0.38) it is the same horse heavier; at ×0.5 the Princeton horse 382's 0.240 is a trunk
# 7 % longer than isometric's.
TRUNK_LENGTH_RETRY = 0.05


def trunk_longer(exponent: float, mass_ratio: float) -> bool:
    """Whether a trunk grown at length ``exponent`` over mass ratio R is longer than isometric
    scaling makes it: (e − 1/3)·log R > 0, above 1/3 when growing, below it when shrinking (the
    bull 386 at ×0.5, 0.498, came out short)."""
    return (exponent - 1.0 / 3.0) * math.log(mass_ratio) > 0


# The kinds of target a ruleset run can miss (BiologyScalingResult.missed): a rule's exponent, the
# mass ratio, a constraint's residual, the trunk's length beyond TRUNK_LENGTH_TOLERANCE, its shape
# beyond TRUNK_SHAPE_LIMIT where its length missed too (a trunk drawn out or shortened humps or sags
# with it), and a distorted output (allorules/measure/quality.py). What is tried next depends on it
# (runs/pipeline.py).
MISSES = ("rule", "mass", "constraint", "trunk", "trunk-shape", "distorted")


def trunk_only(missed: tuple[str, ...]) -> bool:
    """Whether a run missed nothing but its trunk: its length, and with it perhaps its shape. Such a
    run is made again with the trunk's length held first (runs/pipeline.py)."""
    return "trunk" in missed and set(missed) <= {"trunk", "trunk-shape"}


@dataclass
class RulesetStep:
    """One step: what the solver chose and what the step did (fresh measurements of its output)."""

    target_mass_ratio: float
    scale: float
    alpha0: float
    alphas: dict[str, float]
    residuals: dict[str, float]      # relative residual of every term at the solver's optimum
    energy: float
    evaluations: int
    status: str
    mass_ratio: float                # M_out / M_in of this step
    stress_ratio: float | None
    flipped_faces: int
    modes: int
    basis_seconds: float = 0.0       # wall time of the step's basis
    solve_seconds: float = 0.0       # wall time of the step's solve (trial meshes and their measures)
    trunk_stretch: float | None = None   # δ of the step, when solver.trunk_stretch was on
    limb_thickness: float | None = None  # κ of the step, when solver.limb_thickness was on
    sizes: dict[str, float] = field(default_factory=dict)   # each region held at its rule's size: its size − 1

    def as_dict(self) -> dict:
        return {
            "target_mass_ratio": float(self.target_mass_ratio),
            "scale": float(self.scale),
            "alpha0": float(self.alpha0),
            "alphas": {key: float(value) for key, value in self.alphas.items()},
            "trunk_stretch": None if self.trunk_stretch is None else float(self.trunk_stretch),
            "limb_thickness": None if self.limb_thickness is None else float(self.limb_thickness),
            "sizes": {key: float(value) for key, value in self.sizes.items()},
            "residuals": {key: float(value) for key, value in self.residuals.items()},
            "energy": float(self.energy),
            "evaluations": int(self.evaluations),
            "status": self.status,
            "mass_ratio": float(self.mass_ratio),
            "stress_ratio": None if self.stress_ratio is None else float(self.stress_ratio),
            "flipped_faces": int(self.flipped_faces),
            "modes": int(self.modes),
            "basis_seconds": round(float(self.basis_seconds), 3),
            "solve_seconds": round(float(self.solve_seconds), 3),
        }


@dataclass
class RuleOutcome:
    """A rule over the whole run: target exponent against achieved e' = log(q_f/q_0)/log R."""

    id: str
    region: str | None
    measure: str
    exponent: float
    initial: float
    final: float
    achieved_exponent: float

    @property
    def error(self) -> float:
        return self.achieved_exponent - self.exponent

    def as_dict(self) -> dict:
        return {"id": self.id, "region": self.region, "measure": self.measure, "exponent": float(self.exponent),
                "achieved_exponent": float(self.achieved_exponent), "error": float(self.error),
                "initial": float(self.initial), "final": float(self.final)}


@dataclass
class BiologyScalingResult(ScalingResult):
    """A ruleset run. Ratios are final/initial, measured afresh on the output and the input."""

    mode: ClassVar[str] = "ruleset"

    ruleset: str = ""
    rules: list[RuleOutcome] = field(default_factory=list)
    constraints: dict[str, float] = field(default_factory=dict)   # whole-run residuals
    stress_ratio: float | None = None
    transform: str = "per-axis"      # the power law's form (solver.transform of the ruleset)
    posture: dict[str, dict[str, float]] = field(default_factory=dict)   # per limb: tilt, foot lift, bend
    posture_setting: str = "keep"    # solver.posture of the ruleset (allorules.solve.posture)
    warnings: list[str] = field(default_factory=list)   # what the output shows that no rule measures
    open_regions: list = field(default_factory=list)    # OpenRegionOutcome per open region and measure
    trunk_length_exponent: float | None = None   # the trunk's length over the run (checked unless a rule measures it)
    trunk_shape: float | None = None   # the trunk's shape change beyond a stretch (measure.quality.trunk_shape_change)
    missed: tuple[str, ...] = ()     # the kind of each target missed, in order: MISSES
    mass_budget: str | None = None   # a run that missed: where the rules leave the mass (ruleset_run.mass_budget)

    def settle_trunk(self) -> str | None:
        """How to settle a run whose one miss is the trunk's length (every rule, the mass and every
        constraint met): the ruleset asks the trunk for more mass (or less) than its heart girth and
        an isometric trunk allow, so accepting it means saying so with a rule on ``trunk-length``,
        after looking: the galloping real horse at ×2 misses so (0.568) after every try, and ruled at
        0.5 it converges with its rump shrunk and its back hunched (docs/rulesets.md, "When the
        trunk is the one miss"). None for any other run."""
        if self.missed != ("trunk",) or self.trunk_length_exponent is None:
            return None
        exponent = round(self.trunk_length_exponent, 2)
        return (f"every rule and the mass were met, only the trunk's length strayed: if the animal looks right "
                f"to you {'that long' if trunk_longer(exponent, self.target_mass_ratio) else 'that short'}, "
                f"give its trunk a rule (a ruleset with extends: {self.ruleset} and the rule {{id: trunk-length, "
                f"measure: trunk-length, exponent: {exponent:g}}}, docs/rulesets.md)")

    def settle(self) -> str | None:
        """How to settle a run that missed: :meth:`settle_trunk` where the trunk's length is the one
        miss; where the rules leave the regions they do not fix by mass far from the body's ratio
        (:attr:`mass_budget`), the mass rules held isometric instead (after the trunk's rule, as its
        alternative, where both apply). A head or an abdomen drawn larger than a real animal's (a
        cartoon) takes its share at M^0.70 or M^0.74 and leaves the chest and legs ×0.35 at ×0.5
        (the real shared animals: ×0.39-0.46), and the chest folds: a generated big-headed dog and a
        neckless pig at ×0.5 were refused after every try, and with ``--rule head-mass=1 --rule
        abdomen-mass=1`` converge (74 s and 10 s; trunk shape 0.18 and 0.06); for ``quadruped`` the
        built-in ruleset ``cartoon`` is that. A faceted bison at ×2, its hump labelled neck, missed
        by its trunk alone (0.63), its chest and legs left ×3.5, and was told only of a trunk rule;
        with ``cartoon`` it converges in 28 s. None for a converged run or one the budget does not
        explain."""
        trunk = self.settle_trunk()
        if self.converged or not self.mass_budget:
            return trunk
        held = " ".join(f"--rule {rule.id}=1" for rule in self.rules if rule.measure == "mass" and rule.region is not None)
        if self.ruleset == "quadruped":     # the built-in ruleset that is quadruped with those rules isometric
            held = f"the built-in ruleset cartoon does: --ruleset cartoon, or {held}"
        ease = (f"if its head or abdomen is a larger share of it than the mammals' these rules come from (a "
                f"cartoon's head, a capybara's or an elephant's belly), their rules ask the rest of the body for "
                f"that: hold their mass isometric ({held}) or give a ruleset of your own (docs/rulesets.md), and "
                f"look at the picture")
        if trunk:          # the trunk's verdict has said where the rules leave the mass
            return f"{trunk}; or, {ease}"
        if self.messages and self.mass_budget in self.messages[0]:
            # said once: a trunk drawn out and a distorted output (a held-out elephant at ×2, its
            # chest and legs left ×3.0) had the budget in the trunk's verdict and again here. Only
            # the first message counts: the one-line refusal shows it alone (Run.missed), and a
            # cartoon kitten whose trunk's verdict came second was told neither budget nor verdict
            return ease[0].upper() + ease[1:]
        return f"{self.mass_budget}; {ease}"

    def details(self) -> dict:
        return {
            "ruleset": self.ruleset,
            "transform": self.transform,
            "posture_setting": self.posture_setting,
            "rules": [rule.as_dict() for rule in self.rules],
            "constraints": {key: float(value) for key, value in self.constraints.items()},
            "posture": self.posture,
            "warnings": list(self.warnings),
            "open_regions": [outcome.as_dict() for outcome in self.open_regions],
            "trunk_length_exponent": self.trunk_length_exponent,
            "missed": list(self.missed),
            "settle": self.settle(),
            "tolerances": {"exponent": EXPONENT_TOLERANCE, "mass": MASS_TOLERANCE, "constraint": CONSTRAINT_TOLERANCE,
                           "trunk_length": TRUNK_LENGTH_TOLERANCE, "trunk_length_retry": TRUNK_LENGTH_RETRY},
        }


@dataclass
class RawGlobalResult:
    """Eq. 4 applied once with the user's α and s (no measuring, no stress constraint)."""

    mode: ClassVar[str] = "global-raw"

    body: Body
    alpha: float
    scale: float
    mass_ratio: float
    flipped_faces: int
    converged: bool = True
    messages: list[str] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"mode": self.mode, "alpha": float(self.alpha), "scale": float(self.scale),
                "mass_ratio": float(self.mass_ratio), "flipped_faces": int(self.flipped_faces),
                "faces": int(len(self.body.faces)), "converged": True, "messages": list(self.messages)}


@dataclass
class LocalResult:
    """Local scaling of one region (Eq. 5-7), or the arithmetic variant, and how its seam held."""

    body: Body
    region: str
    alpha: float
    arithmetic_factor: float | None
    form: str
    seam: dict[str, float]
    flipped_faces: int
    converged: bool = True
    messages: list[str] = field(default_factory=list)

    @property
    def mode(self) -> str:
        return "arithmetic" if self.arithmetic_factor is not None else "local"

    def as_dict(self) -> dict:
        return {"mode": self.mode, "region": self.region, "transform": self.form, "alpha": float(self.alpha),
                "arithmetic_factor": self.arithmetic_factor, "seam": dict(self.seam),
                "flipped_faces": int(self.flipped_faces), "faces": int(len(self.body.faces)), "converged": True,
                "messages": list(self.messages)}
