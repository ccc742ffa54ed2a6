"""allorules plugin: the measure ``surface-area`` (skin area, for heat loss).

Heat leaves an animal through its skin, so heat loss goes with surface area while heat
production goes with metabolic rate (Kleiber 1932: ∝ M^0.75). Under uniform scaling area
grows as M^(2/3) (Meeh 1879 found about this for real mammals), slower than heat production:
big animals keep heat, small ones lose it (Bergmann's rule). A rule on ``surface-area``
lets a ruleset control that balance; see ``heat-balance.yaml`` next to this file.

The measure: the sum of the triangle areas of the whole surface (``region: null``) or of a
region's faces (faces with at least two vertices in the region). Holes in the mesh are not
capped: they are the same before and after scaling, and only ratios are used.
Isometric exponent 2/3; region optional.

Use it by installing this folder (``pip install plugins/allorules-surface-area``, entry point
``surface-area``) or by naming the file: ``--plugin path/to/allorules_surface_area.py`` or
``plugins: [allorules_surface_area.py]`` in a ruleset.
"""
from __future__ import annotations

import numpy as np

from allorules.errors import MeasurementError
from allorules.plugins import MeasureSpec, hookimpl


def surface_area(body, region: str | None) -> float:
    """Area of the whole surface, or of the faces of ``region``: Σ ½‖(b − a) × (c − a)‖."""
    faces = body.faces
    if region is not None:
        if not body.has_region(region) or body.labels is None:
            raise MeasurementError(f"surface-area: the body has no region {region!r}; segment it first "
                                   f"(regions: {', '.join(body.region_names) or 'none'})")
        faces = faces[body.region_face_mask(region)]
        if len(faces) == 0:
            raise MeasurementError(f"surface-area: region {region!r} has no faces; check the segmentation")
    corners = body.vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * float(np.linalg.norm(cross, axis=1).sum())
    if not np.isfinite(area) or area <= 0:
        raise MeasurementError("surface-area: the surface has no area (degenerate or NaN vertices)")
    return area


@hookimpl
def allorules_measures():
    return [MeasureSpec(
        name="surface-area",
        kind="area",
        isometric_exponent=2 / 3,
        compute=surface_area,
        description="skin area of the whole body (region null) or of a region; heat loss goes with it",
        needs_region=False,
    )]
