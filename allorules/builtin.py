"""The built-in plugin: the paper's measures, its limb-stress constraint and the segmenters.

Registered as plugin ``builtin`` through the same hooks as third-party plugins. The numerical
work lives elsewhere and is imported lazily (so the rules engine loads even where those
modules are still missing): measures in :mod:`allorules.measures`, segmenters in
:mod:`allorules.segmentation`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from .body import Body
from .hookspecs import hookimpl
from .specs import ConstraintContext, ConstraintSpec, MeasureSpec, ParameterSpec, SegmenterSpec


# -- measures (METHOD §3) -------------------------------------------------------------------
def _mass(body: Body, region: str | None) -> float:
    from . import measures

    # Body mass M: enclosed volume of the capped body; region mass: volume of the region's
    # faces with every open boundary capped (density cancels in every ratio).
    return measures.body_mass(body) if region is None else measures.region_mass(body, region)


def _length(body: Body, region: str | None) -> float:
    from . import measures

    return measures.region_length(body, region)


def _girth(body: Body, region: str | None) -> float:
    from . import measures

    return measures.region_girth(body, region)


def _stress(body: Body, region: str | None) -> float:
    from . import measures

    # σ = M / A with A the smallest load-bearing limb cross-section (paper §3.1, [Bie90]).
    return measures.peak_stress(body)


MEASURES = [
    MeasureSpec("mass", "mass", 1.0, _mass,
                "volume enclosed by a region with its open boundaries capped; the whole body when no region is named",
                needs_region=False),
    MeasureSpec("length", "length", 1 / 3, _length,
                "length of a region: diameter of its skeleton, mean over the parts of a paired region"),
    MeasureSpec("girth", "girth", 1 / 3, _girth,
                "perimeter of a region's cross-section where it is measured (chest: largest behind the forelimbs)"),
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
def _auto_quadruped(body: Body, **options: Any) -> Body:
    from . import segmentation

    return segmentation.label_quadruped(body, **options)


def _merge_file(body: Body, **options: Any) -> Body:
    from . import segmentation

    return segmentation.apply_merge_file(body, options.get("patches"), options["path"])


SEGMENTERS = [
    SegmenterSpec("auto-quadruped", "automatic labelling of head, neck, chest, abdomen, forelimbs, "
                  "hindlimbs (and tail) of a quadruped", _auto_quadruped),
    SegmenterSpec("merge-file", "the paper's path: over-segment into patches, then merge them into "
                  "regions as a merge file says (options: path, patches)", _merge_file),
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
