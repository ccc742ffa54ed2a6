"""A body modelled as separate overlapping parts, made one closed surface (METHOD §1, issue 17).

Game and cartoon animals are often built of pieces: a trunk, four legs, a neck and a head, each a
closed shell pushed into the next, never welded. The method needs one surface that encloses the
animal (its regions, volumes and basis are of that surface), and keeping the largest piece would
keep a legless trunk. :func:`join_parts` makes the surface of the solid the pieces enclose
together: the generalised winding number of the whole soup (Jacobson et al. 2013, libigl's fast
approximation, Barill et al. 2018) sampled on a grid and contoured at ½ by marching cubes
(scikit-image), so pieces that overlap are joined and an inside wall disappears; a piece that is
an open sheet (an ear, a horn's skin) encloses nothing and is left out of the solid.

The surface made is the *body* only: the user's own vertices are bound to it and carried with
its deformation (:mod:`allorules.mesh.transfer`), so every piece keeps its vertices, faces and
UVs (:class:`allorules.mesh.repair.PreparedMesh`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from allorules.errors import MeshError
from allorules.mesh.geometry import enclosed_volume
from allorules.mesh.topology import face_parts

log = logging.getLogger(__name__)

# Grid cells along the pieces' longest side. The thinnest piece the surface keeps is a few cells
# across: at 192 cells a leg of 1/40 of the animal's length is 5 cells wide.
JOIN_CELLS = 192
# A mesh whose largest piece holds less than this share of the surface is joined (prepare_mesh);
# above it the other pieces are eyes, teeth and such, carried along by the body.
JOIN_BELOW = 0.8
WINDING_LEVEL = 0.5   # inside the solid: winding number above ½
# A piece's face whose corners all lie deeper inside the joined surface than this many grid cells
# is buried (a leg's top inside the trunk): nobody sees it, and it may fold unseen.
BURIED_CELLS = 2
# The winding number is smooth away from the pieces' surfaces: it is computed exactly on a grid
# COARSE times coarser, and on the fine grid only in the coarse cells next to a surface.
COARSE = 4


@dataclass(frozen=True)
class JoinedSurface:
    """The surface of the solid the pieces enclose together, oriented outward, and the size of the
    grid cell it was contoured on (the detail it keeps)."""

    vertices: np.ndarray
    faces: np.ndarray
    cell: float


def join_parts(vertices: np.ndarray, faces: np.ndarray, cells: int = JOIN_CELLS) -> JoinedSurface:
    """The outer surface of the solid that the mesh's pieces enclose together (every connected part
    of it; the body is the largest). Raises :class:`MeshError` where the pieces enclose nothing
    (open sheets only)."""
    from skimage.measure import marching_cubes

    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = _pieces_outward(vertices, faces)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    spacing = float((high - low).max()) / cells
    # whole coarse cells, with one empty coarse cell beyond the pieces on every side
    coarse_shape = np.ceil((high - low) / (COARSE * spacing)).astype(int) + 3
    origin = low - COARSE * spacing
    winding = _winding_on_grid(vertices, faces, origin, spacing, coarse_shape)
    if winding.max() <= WINDING_LEVEL:
        raise MeshError("its pieces enclose no volume (open sheets only); join them into one closed "
                        "surface in your modelling tool")
    joined_vertices, joined_faces, _, _ = marching_cubes(winding, level=WINDING_LEVEL, spacing=(spacing,) * 3)
    joined_vertices = joined_vertices + origin
    # scikit-image's triangles turn inward for a field that grows inward: flip them outward
    joined_faces = np.ascontiguousarray(joined_faces[:, ::-1], dtype=np.int64)
    log.debug("joined %d vertices of pieces into a %d-vertex surface (grid %s, cell %.4g)",
              len(vertices), len(joined_vertices), winding.shape, spacing)
    return JoinedSurface(joined_vertices, joined_faces, spacing)


def _pieces_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The faces with every piece that encloses a negative volume turned outward (a piece modelled
    inside out would cancel its neighbour's winding number where they overlap)."""
    faces = np.array(faces, dtype=np.int64)
    for piece in face_parts(faces):
        if enclosed_volume(vertices, faces[piece]) < 0:
            faces[piece] = faces[piece][:, ::-1]
    return np.ascontiguousarray(faces)


def _winding_on_grid(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, spacing: float,
                     coarse_shape: np.ndarray) -> np.ndarray:
    """The soup's winding number on the fine grid (``spacing``, COARSE × ``coarse_shape`` points
    from ``origin``): exact in the coarse cells a surface passes through and their neighbours,
    trilinear from the coarse grid's exact values elsewhere."""
    import igl
    from scipy.ndimage import binary_dilation, map_coordinates

    coarse_axes = [origin[k] + COARSE * spacing * np.arange(coarse_shape[k]) for k in range(3)]
    coarse_points = np.stack(np.meshgrid(*coarse_axes, indexing="ij"), axis=-1).reshape(-1, 3)
    coarse = igl.fast_winding_number(vertices, faces, coarse_points).reshape(coarse_shape)
    shape = COARSE * (coarse_shape - 1) + 1
    index = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=0)
    fine = map_coordinates(coarse, index.reshape(3, -1) / COARSE, order=1).reshape(tuple(shape))
    # coarse cells a surface passes through: those holding a sample of every triangle
    near = np.zeros(tuple(coarse_shape - 1), dtype=bool)
    samples = _surface_samples(vertices, faces, spacing)
    cell = np.clip(((samples - origin) // (COARSE * spacing)).astype(int), 0, coarse_shape - 2)
    near[tuple(cell.T)] = True
    near = binary_dilation(near)   # and their neighbours: the field is exact wherever it may cross ½
    in_band = np.repeat(np.repeat(np.repeat(near, COARSE, 0), COARSE, 1), COARSE, 2)
    in_band = np.pad(in_band, [(0, 1)] * 3, mode="edge")
    band = np.flatnonzero(in_band)
    points = origin + spacing * np.stack(np.unravel_index(band, tuple(shape)), axis=1)
    fine.flat[band] = igl.fast_winding_number(vertices, faces, points)
    return fine


def _surface_samples(vertices: np.ndarray, faces: np.ndarray, gap: float) -> np.ndarray:
    """Points on every triangle no farther than about ``gap`` apart: the vertices, and where a
    triangle is longer than the gap, its points on a grid of k² pieces (k from its longest edge)."""
    corners = vertices[faces]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    splits = np.maximum(1, np.ceil(longest / gap).astype(int))
    points = [vertices]
    for k in np.unique(splits[splits > 1]):      # a triangle shorter than the gap: its corners
        chosen = corners[splits == k]
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = i + j <= k
        a, b = i[keep] / k, j[keep] / k
        weights = np.stack([1 - a - b, a, b], axis=1)          # (m, 3) barycentric
        points.append(np.einsum("mc,fcd->fmd", weights, chosen).reshape(-1, 3))
    return np.concatenate(points)


def buried_faces(faces: np.ndarray, depth: np.ndarray, cell: float) -> np.ndarray:
    """Per face of the pieces, whether it is buried in the joined solid: each of its corners deeper
    inside the joined surface than BURIED_CELLS grid cells of size ``cell`` (``depth``: per vertex,
    how far inside the surface it lies, negative outside)."""
    return np.all(np.asarray(depth)[np.asarray(faces, dtype=np.int64)] > BURIED_CELLS * cell, axis=1)
