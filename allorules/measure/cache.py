"""What the measure stage derives from a body's exact vertices, kept on the body as named fields.

:func:`measured` gives a body's :class:`Measured` (made on first use, dropped when the body is
deformed through ``Body.with_vertices``). Topology (hole caps, region parts' faces, the fields
along parts) is the same for every deformation of one body; :func:`allorules.measure.parts.carry_fields`
carries it, and the reference's skeletons, limbs and chest candidates (:class:`Carried`), to a moved
copy so that trial meshes are measured along the same material curves.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from allorules.body import Body

if TYPE_CHECKING:  # pragma: no cover
    from allorules.measure.limbs import Limb
    from allorules.measure.parts import RegionPart
    from allorules.measure.sections import Skeleton
    from allorules.mesh.topology import HoleCaps


@dataclass
class Carried:
    """A reference body's measuring curves, to be re-measured on a moved copy of it."""

    limbs: dict[str, list["Limb"]] = field(default_factory=dict)            # by region
    skeletons: dict[str, list["Skeleton"]] = field(default_factory=dict)    # by region
    chest_candidates: tuple[np.ndarray, str, float] | None = None   # the heart-girth levels, where cut ("part", "torso", "body"), the margin


@dataclass
class Measured:
    """Everything measured or derived on one body; each dict is keyed by region name."""

    caps: dict[str, "HoleCaps"] = field(default_factory=dict)        # "body", or "region:<name>"
    body_mass: float | None = None
    region_mass: dict[str, float] = field(default_factory=dict)
    hole_edges: np.ndarray | None = None                              # the body surface's own boundary edges
    parts: dict[str, list["RegionPart"]] = field(default_factory=dict)   # also "torso"
    fields: dict[str, list[np.ndarray]] = field(default_factory=dict)
    limbs: dict[str, list["Limb"]] = field(default_factory=dict)
    skeletons: dict[str, list["Skeleton"]] = field(default_factory=dict)
    lengths: dict[str, float] = field(default_factory=dict)
    girths: dict[str, float] = field(default_factory=dict)
    chest_candidates: tuple[np.ndarray, str, float] | None = None
    peak_stress: dict[Any, float] = field(default_factory=dict)      # by section override (None: automatic)
    values: dict[tuple[str, str | None], float] = field(default_factory=dict)   # any registered measure, by (name, region)
    carried: Carried | None = None


def measured(body: Body) -> Measured:
    """The body's :class:`Measured`, made empty on first use."""
    if body.measured is None:
        body.measured = Measured()
    return body.measured
