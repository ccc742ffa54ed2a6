"""The ruleset model: what a resolved, validated ruleset holds (rules, body-mass term, constraints,
segmenter, solver settings), and its serialisation back to a document (``ruleset show``).

An exponent lives here: :class:`Rule` says ``measure(region) ∝ M^exponent`` (paper Eq. 10).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from allorules.errors import RulesetError

DEFAULT_SEGMENTER = "auto-quadruped"


@dataclass(frozen=True)
class Rule:
    """``measure(region)`` follows ``q' = q · r^exponent`` for a body-mass ratio r (paper Eq. 10)."""

    id: str
    region: str | None
    measure: str
    exponent: float
    weight: float = 1.0
    source: str = ""


@dataclass(frozen=True)
class BodyMassTerm:
    """How body mass M is measured; the energy term (M(x')/(r·M_0) − 1)² gets ``weight``."""

    measure: str = "mass"
    region: str | None = None
    weight: float = 1.0
    source: str = ""


@dataclass(frozen=True)
class ConstraintUse:
    """A constraint a plugin provides, with its (complete, checked) parameters and weight."""

    name: str
    parameters: Mapping[str, Any] = field(default_factory=dict)
    weight: float = 1.0
    source: str = ""


@dataclass(frozen=True)
class SolverSettings:
    """nlopt settings and stepping (METHOD §6).

    LN_BOBYQA is the default: derivative-free (the energy is measured on meshes, no
    gradients), respects the bounds, and builds a quadratic model, which suits a smooth sum
    of squares in a handful of variables (s, α_0 and one α per region).
    """

    step_ratio_up: float = 1.1
    step_ratio_down: float = 0.9
    algorithm: str = "LN_BOBYQA"
    relative_tolerance: float = 1e-6
    parameter_tolerance: float = 1e-4
    max_evaluations: int = 400
    scale_bounds: tuple[float, float] = (0.5, 2.0)
    alpha_bounds: tuple[float, float] = (-1.0, 1.0)
    transform: str = "per-axis"     # METHOD §5, in the animal's own axes; or "per-mode" (docs/biology-scaling.md)
    posture: str = "keep"           # legs upright, feet on the ground; "upright": legs only; "free" (allorules.solve.posture)
    detail_cutoff: float | None = None   # Eq. 9 on the base only, detail kept (power_laws.DetailLayer); None: every mode
    trunk_stretch: str = "when-needed"   # the trunk's length as one more variable: "on", "off", or "when-needed" (TRUNK_STRETCH)
    limb_thickness: str = "when-needed"  # the limbs' thickness as one more variable: "on", "off", or "when-needed" (LIMB_THICKNESS)
    trunk_hold: str = "when-needed"      # the trunk's length held isometric by a soft term, δ its lever (TRUNK_HOLD)
    ruled_shape: str = "hold"            # a head sized by its rule keeps its shape; "reshape": Eq. 9's α (RULED_SHAPES)


OPEN_REGION_SETTINGS = ("isometric", "free")
OPEN_REGION_HOLDS = ("shape", "soft")    # how an isometric open region is held (allorules/solve/held_regions.py)


@dataclass(frozen=True)
class OpenRegions:
    """What regions no rule measures do (METHOD §10): ``isometric`` (the default) holds each such
    region at its input proportions, which a rule of the ruleset on that region replaces; ``free``
    leaves the region's α to the solver (the paper). ``hold`` says how: ``shape`` (the default) gives
    the region its input shape scaled isometrically after Eq. 9 (allorules/solve/held_regions.py);
    ``soft`` holds its ``measures`` at their isometric exponents as soft energy terms of ``weight``
    (allorules/solve/open_regions.py; also the fallback for a part the shape cannot hold).
    ``regions`` overrides the default per region (appendages such as tail, ears, horns, trunk
    included, when a segmenter finds them)."""

    default: str = "isometric"
    hold: str = "shape"
    weight: float = 0.01
    measures: tuple[str, ...] = ("length", "mass")
    regions: Mapping[str, str] = field(default_factory=dict)
    source: str = ""

    def setting(self, region: str) -> str:
        return self.regions.get(region, self.default)


@dataclass(frozen=True)
class SegmenterUse:
    """The segmenter a ruleset labels bodies with, and its (complete, checked) options. Options
    that are files are absolute paths (given relative to the ruleset that names them)."""

    name: str = DEFAULT_SEGMENTER
    options: Mapping[str, Any] = field(default_factory=dict)

    def as_document(self) -> str | dict[str, Any]:
        """The YAML value: the bare name when there are no options."""
        if not self.options:
            return self.name
        return {"name": self.name, "options": {key: str(value) if isinstance(value, Path) else value
                                               for key, value in self.options.items()}}


@dataclass(frozen=True)
class Ruleset:
    """A resolved, validated ruleset (``extends`` already applied)."""

    name: str
    description: str
    path: Path | None
    regions: tuple[str, ...]
    rules: tuple[Rule, ...]
    body_mass: BodyMassTerm = BodyMassTerm()
    constraints: tuple[ConstraintUse, ...] = ()
    solver: SolverSettings = SolverSettings()
    plugins: tuple[Path, ...] = ()
    segmenter: SegmenterUse = SegmenterUse()
    extends: tuple[str, ...] = ()   # the chain of rulesets this one was built on, nearest first
    open_regions: OpenRegions = OpenRegions()

    def rule(self, rule_id: str) -> Rule:
        for rule in self.rules:
            if rule.id == rule_id:
                return rule
        raise RulesetError(f"ruleset {self.name!r} has no rule {rule_id!r}; its rules: "
                           f"{', '.join(r.id for r in self.rules) or 'none'}")


@dataclass(frozen=True)
class RulesetSummary:
    """One line of ``allorules rulesets``."""

    name: str
    description: str
    path: Path
    origin: str          # "built-in" or the plugin that provides the search path
    shadowed: tuple[Path, ...] = ()


def ruleset_to_dict(ruleset: Ruleset) -> dict[str, Any]:
    """The resolved ruleset as a document (no extends) that loads back into an equal ruleset."""
    document: dict[str, Any] = {"name": ruleset.name}
    if ruleset.description:
        document["description"] = ruleset.description
    if ruleset.plugins:
        document["plugins"] = [str(path) for path in ruleset.plugins]
    document["segmenter"] = ruleset.segmenter.as_document()
    document["regions"] = list(ruleset.regions)
    document["body_mass"] = {"measure": ruleset.body_mass.measure, "region": ruleset.body_mass.region,
                             "weight": ruleset.body_mass.weight}
    if ruleset.body_mass.source:
        document["body_mass"]["source"] = ruleset.body_mass.source
    document["rules"] = []
    for rule in ruleset.rules:
        entry: dict[str, Any] = {"id": rule.id, "region": rule.region, "measure": rule.measure,
                                 "exponent": rule.exponent, "weight": rule.weight}
        if rule.source:
            entry["source"] = rule.source
        document["rules"].append(entry)
    document["constraints"] = []
    for use in ruleset.constraints:
        entry = {"name": use.name, "parameters": dict(use.parameters), "weight": use.weight}
        if use.source:
            entry["source"] = use.source
        document["constraints"].append(entry)
    solver = ruleset.solver
    document["solver"] = {
        "step_ratio_up": solver.step_ratio_up, "step_ratio_down": solver.step_ratio_down,
        "algorithm": solver.algorithm, "relative_tolerance": solver.relative_tolerance,
        "parameter_tolerance": solver.parameter_tolerance, "max_evaluations": solver.max_evaluations,
        "scale_bounds": list(solver.scale_bounds), "alpha_bounds": list(solver.alpha_bounds),
        "transform": solver.transform, "posture": solver.posture, "detail_cutoff": solver.detail_cutoff,
        "trunk_stretch": solver.trunk_stretch, "limb_thickness": solver.limb_thickness, "trunk_hold": solver.trunk_hold,
        "ruled_shape": solver.ruled_shape,
    }
    opened = ruleset.open_regions
    document["open_regions"] = {"default": opened.default, "hold": opened.hold, "weight": opened.weight, "measures": list(opened.measures),
                                "regions": dict(opened.regions)}
    if opened.source:
        document["open_regions"]["source"] = opened.source
    return document


def dump_ruleset(ruleset: Ruleset) -> str:
    """The resolved ruleset as YAML text (what ``allorules ruleset show`` prints)."""
    header = f"# ruleset {ruleset.name}"
    if ruleset.extends:
        header += f", resolved (extends {' → '.join(ruleset.extends)})"
    if ruleset.path:
        header += f"\n# from {ruleset.path}"
    return header + "\n" + yaml.safe_dump(ruleset_to_dict(ruleset), sort_keys=False, allow_unicode=True, width=100)


TRANSFORM_FORMS = ("per-axis", "per-mode")


# solver.trunk_stretch of a ruleset (allorules/solve/transform.py, docs/method.md): the variable δ that
# lengthens the trunk along the animal's forward axis; "when-needed": only in a second run, when a
# run without it misses its targets with the open regions held by their shape (runs/pipeline.py).
TRUNK_STRETCH = ("when-needed", "on", "off")


# solver.limb_thickness of a ruleset (allorules/solve/limb_thickness.py): the variable κ that thickens
# the limbs across their centre lines; "when-needed": only in a further run, as trunk_stretch.
LIMB_THICKNESS = ("off", "when-needed", "on")


# solver.trunk_hold of a ruleset (allorules/runs/ruleset_run.py): the trunk's length (shoulder to
# buttock) held at its isometric exponent by a soft term, with δ, the trunk's stretch, as its lever,
# where no rule measures the trunk; "when-needed": only in a further run, after the run with κ missed
# and before δ free (runs/pipeline.py). Eq. 9 can meet every rule by drawing the trunk out (the bull 386).
TRUNK_HOLD = ("when-needed", "on", "off")


# solver.ruled_shape of a ruleset (allorules/solve/held_regions.py, rule_held_regions): a region that is
# neither torso nor limb and whose rules fix only its size (the head's mass) keeps its input shape at
# that size ("hold"), or Eq. 9's α_j reshapes it as the paper does ("reshape").
RULED_SHAPES = ("hold", "reshape")


# solver.posture of a ruleset: legs upright and feet on the ground; legs upright only; neither.
POSTURES = ("keep", "upright", "free")
