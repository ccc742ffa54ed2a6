"""allorules plugin: the constraint ``flight-wing-loading`` for flying animals.

A flier's weight is carried by its wings. Wing loading Q = M g / S (body mass over wing
area) sets the slowest speed it can fly at (lift = ½ ρ v² S C_L = M g gives
v_min ∝ √(M / S)) and so its take-off, landing and manoeuvring. Under uniform scaling
S ∝ M^(2/3), so Q ∝ M^(1/3): a bigger copy of a bat must fly faster. Bats and birds do show
wing loading rising with mass, roughly like isometry (Norberg & Rayner 1987 for bats), but a
designer who wants "the same flier, bigger" keeps Q.

Residual (dimensionless, 0 when met), per scaling step with body-mass ratio r::

    wing_loading(candidate) / (wing_loading(initial) · r^exponent) − 1,
    wing_loading = M / S_wing

with M the body mass (measure ``mass``) and S_wing the area of the faces of the region
``wing_region`` (default ``forelimbs``: a bat's wing is its forelimb's skin membrane).
Parameters: ``wing_region`` (text), ``exponent`` (0 keeps wing loading; 1/3 is isometric).
The area counts both sides of a membrane; only ratios are used, so that cancels.

Use: ``pip install plugins/allorules-flight`` (entry point ``flight``), or
``--plugin path/to/allorules_flight.py``, or ``plugins: [allorules_flight.py]`` in a ruleset
(see ``bat.yaml`` next to this file).
"""
from __future__ import annotations

import numpy as np

from allorules.errors import MeasurementError
from allorules.plugins import ConstraintSpec, ParameterSpec, hookimpl


def wing_area(body, region: str) -> float:
    """Area of the faces of ``region`` (Σ ½‖(b − a) × (c − a)‖)."""
    if body.labels is None or not body.has_region(region):
        raise MeasurementError(f"flight-wing-loading: the body has no region {region!r} for the wings; set the "
                               f"parameter wing_region to one of: {', '.join(body.region_names) or 'none'}")
    faces = body.faces[body.region_face_mask(region)]
    corners = body.vertices[faces]
    area = 0.5 * float(np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                                      axis=1).sum())
    if not np.isfinite(area) or area <= 0:
        raise MeasurementError(f"flight-wing-loading: region {region!r} has no area; check the segmentation")
    return area


def wing_loading_residuals(context, parameters) -> dict[str, float]:
    region = parameters["wing_region"]
    # Q = M / S_wing; target Q' = Q · r^exponent (exponent 0 keeps wing loading).
    initial = context.measure("mass", context.initial, None) / wing_area(context.initial, region)
    candidate = context.measure("mass", context.candidate, None) / wing_area(context.candidate, region)
    target = initial * context.mass_ratio ** float(parameters["exponent"])
    return {"wing-loading": candidate / target - 1.0}


@hookimpl
def allorules_constraints():
    return [ConstraintSpec(
        name="flight-wing-loading",
        description="wing loading M/S_wing follows r^exponent (0: kept, same slowest flight speed)",
        residuals=wing_loading_residuals,
        parameters={
            "wing_region": ParameterSpec("forelimbs", "region whose faces are the wings", kind=str),
            "exponent": ParameterSpec(0.0, "exponent of wing loading against body mass (0 keeps it, 1/3 is isometric)",
                                      minimum=-1.0, maximum=1.0),
        },
    )]
