"""The built-in plugin: the paper's measures, its limb-stress constraint and the segmenters.

Registered as plugin ``builtin`` through the same hooks as third-party plugins. The numerical
work lives in the stages and is imported when first called (so that listing plugins and reading
rulesets stay quick): measures in :mod:`allorules.measure`, segmenters in :mod:`allorules.segment`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from allorules.body import Body
from allorules.plugins.hookspecs import hookimpl
from allorules.plugins.specs import (
    ConstraintContext,
    ConstraintSpec,
    MeasureSpec,
    ParameterSpec,
    SegmenterSpec,
)


# -- measures (METHOD §3) -------------------------------------------------------------------
def _mass(body: Body, region: str | None) -> float:
    from allorules.measure.mass import body_mass, region_mass

    # Body mass M: enclosed volume of the capped body; region mass: volume of the region's
    # faces with every open boundary capped (density cancels in every ratio).
    return body_mass(body) if region is None else region_mass(body, region)


def _length(body: Body, region: str | None) -> float:
    from allorules.measure.length import region_length

    return region_length(body, region)


def _girth(body: Body, region: str | None) -> float:
    from allorules.measure.girth import region_girth

    return region_girth(body, region)


def _trunk_length(body: Body, region: str | None) -> float:
    from allorules.measure.length import trunk_length

    # point of the shoulder to point of the buttock: the torso's extent along its axis
    return trunk_length(body)


def _stress(body: Body, region: str | None) -> float:
    from allorules.measure.stress import peak_stress

    # σ = M / A with A the smallest load-bearing limb cross-section (paper §3.1, [Bie90]).
    return peak_stress(body)


MEASURES = [
    MeasureSpec("mass", "mass", 1.0, _mass,
                "volume enclosed by a region with its open boundaries capped; the whole body when no region is named",
                needs_region=False),
    MeasureSpec("length", "length", 1 / 3, _length,
                "length of a region: diameter of its skeleton, mean over the parts of a paired region"),
    MeasureSpec("girth", "girth", 1 / 3, _girth,
                "perimeter of a region's cross-section where it is measured (chest: largest behind the forelimbs)"),
    MeasureSpec("trunk-length", "length", 1 / 3, _trunk_length,
                "the trunk's length: extent of chest and abdomen along the torso's axis (shoulder to buttock)",
                needs_region=False, accepts_region=False),
    MeasureSpec("stress", "stress", 1 / 3, _stress,
                "peak limb stress M/A: body mass over the smallest load-bearing limb cross-section",
                needs_region=False, accepts_region=False),
]


# -- constraints (METHOD §6) ------------------------------------------------------------------
def terrestrial_limb_stress(context: ConstraintContext, parameters: Mapping[str, Any]) -> dict[str, float]:
    """Peak limb stress follows σ' = σ · r^exponent (exponent 0: stress kept, [Bie90]).

    Residual σ(candidate) / (σ(initial) · r^exponent) − 1, dimensionless, 0 when satisfied.
    """
    initial = context.measure("stress", context.initial, None)
    candidate = context.measure("stress", context.candidate, None)
    target = initial * context.mass_ratio ** float(parameters["exponent"])
    return {"stress": candidate / target - 1.0}


CONSTRAINTS = [
    ConstraintSpec(
        "terrestrial-limb-stress",
        "peak limb stress kept as it was (same safety factor, Biewener 1990); "
        "exponent e makes it follow r^e instead",
        terrestrial_limb_stress,
        {"exponent": ParameterSpec(0.0, "exponent of peak stress against body mass (0 keeps stress)",
                                   minimum=-1.0, maximum=1.0)},
    ),
]


# -- segmenters (METHOD §7) -------------------------------------------------------------------
def _auto_quadruped(body: Body, *, up=None, forward=None) -> Body:
    from allorules.segment.labeller import label_quadruped

    return label_quadruped(body, up=up, forward=forward)


def _merge_file(body: Body, *, path: Path, patches: int = 24, seed: int = 0) -> Body:
    from allorules.segment.labels_io import apply_merge_file
    from allorules.segment.patches import spectral_patches

    return apply_merge_file(body, spectral_patches(body.vertices, body.faces, patches, seed=seed), path)


SEGMENTERS = [
    SegmenterSpec("auto-quadruped", "automatic labelling of head, neck, chest, abdomen, forelimbs, "
                  "hindlimbs (and tail) of a quadruped", _auto_quadruped,
                  {"up": ParameterSpec(None, "the body's up direction (feet to back); detected when not given", kind=tuple),
                   "forward": ParameterSpec(None, "the body's forward direction (tail to head); detected when not given",
                                            kind=tuple)}),
    SegmenterSpec("merge-file", "the paper's path: over-segment into numbered patches, then merge them into "
                  "regions as a merge file says (allorules segment --patches N --png to choose them)", _merge_file,
                  {"path": ParameterSpec(None, "the merge file (YAML: region: [patch ids]), relative to the ruleset",
                                         kind=Path, required=True),
                   "patches": ParameterSpec(24, "how many patches (the N the patch picture was made with)", kind=int,
                                            minimum=1),
                   "seed": ParameterSpec(0, "seed of the patch clustering", kind=int)}),
]


@hookimpl
def allorules_measures() -> list[MeasureSpec]:
    return list(MEASURES)


@hookimpl
def allorules_segmenters() -> list[SegmenterSpec]:
    return list(SEGMENTERS)


@hookimpl
def allorules_constraints() -> list[ConstraintSpec]:
    return list(CONSTRAINTS)


@hookimpl
def allorules_ruleset_paths() -> list[Path]:
    return []   # built-in rulesets are found directly in the allorules.rulesets package
