"""Masses (METHOD §3) as volumes: the body's enclosed volume and each region's with its open
boundaries capped (density cancels in every ratio).
"""
from __future__ import annotations

import numpy as np

from allorules.body import Body
from allorules.errors import MeasurementError
from allorules.measure.cache import measured
from allorules.measure.parts import _region_faces
from allorules.mesh.geometry import enclosed_volume
from allorules.mesh.topology import cap_holes, hole_caps


def capped(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with every boundary loop closed by a fan around its centroid (measuring only)."""
    return cap_holes(vertices, faces)


def _capped_volume(body: Body, name: str, faces: np.ndarray) -> float:
    """Volume of ``faces`` capped; the capping plan is topology, kept in the cache under ``name``
    (and carried to trial meshes by :func:`carry_fields`)."""
    caps = measured(body).caps
    if name not in caps:
        caps[name] = hole_caps(faces, len(body.vertices))
    return enclosed_volume(*caps[name].apply(body.vertices))


def body_mass(body: Body) -> float:
    """Body mass M (as a volume): enclosed volume of the capped body surface."""
    cache = measured(body)
    if cache.body_mass is None:
        volume = _capped_volume(body, "body", body.faces)
        if not np.isfinite(volume) or volume <= 0:
            raise MeasurementError(
                f"volume cannot be determined even after capping: got {volume:.6g}; the surface is "
                "probably inside out or badly broken, run it through allorules.mesh.repair.prepare_mesh"
            )
        cache.body_mass = volume
    return cache.body_mass


def region_mass(body: Body, region: str) -> float:
    """Mass of a region (as a volume): its faces with every open boundary loop capped."""
    cache = measured(body).region_mass
    if region not in cache:
        volume = _capped_volume(body, f"region:{region}", body.faces[_region_faces(body, region)])
        if not np.isfinite(volume) or volume <= 0:
            raise MeasurementError(
                f"volume of region {region!r} cannot be determined even after capping (got "
                f"{volume:.6g}); check its labels cover a piece of surface, not scattered faces"
            )
        cache[region] = volume
    return cache[region]
