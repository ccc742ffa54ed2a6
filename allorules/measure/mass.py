"""Masses (METHOD §3) as volumes: the body's enclosed volume and each region's with its open
boundaries capped (density cancels in every ratio). A region's mass counts what grows from it
(ears and horns on the head, a tail on the abdomen: :func:`allorules.segment.regions.appendages_of`),
as the paper's regions do, whether or not the labeller cut those apart.
"""
from __future__ import annotations

import numpy as np

from allorules.body import Body
from allorules.errors import MeasurementError
from allorules.measure.cache import measured
from allorules.measure.parts import _region_faces
from allorules.mesh.geometry import enclosed_volume
from allorules.mesh.topology import cap_holes, hole_caps
from allorules.segment.regions import appendages_of


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


def region_mass(body: Body, region: str, *, appendages: bool = True) -> float:
    """Mass of a region (as a volume): its faces and, unless ``appendages`` is False, those of the
    regions that grow from it (:func:`appendages_of`), with every open boundary loop capped.

    Ears and horns are cut from a head at one tessellation of an animal and left in it at another
    (the cow 381: its head's own mass moved by 20 % across four tessellations of one surface, with
    its ears and horns 2.4 %); the head's mass is the paper's head, ears and horns included.
    ``appendages=False``: the region's own faces only (shares of the body that add up to it)."""
    names = (region,) + (appendages_of(region, body.region_names) if appendages else ())
    key = "+".join(names) if appendages else f"{region} alone"
    cache = measured(body).region_mass
    if key not in cache:
        selection = _region_faces(body, region)
        if len(names) > 1:   # the faces of the regions as one (as Body.region_face_mask takes one region's)
            inside = np.logical_or.reduce([body.region_mask(name) for name in names])
            selection = inside[body.faces].sum(axis=1) >= 2
        volume = _capped_volume(body, f"region:{key}", body.faces[selection])
        if not np.isfinite(volume) or volume <= 0:
            raise MeasurementError(
                f"volume of region {region!r} cannot be determined even after capping (got "
                f"{volume:.6g}); check its labels cover a piece of surface, not scattered faces"
            )
        cache[key] = volume
    return cache[key]
