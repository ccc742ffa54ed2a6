"""Geometry of triangle meshes as plain numpy: areas, normals, enclosed volume, flipped faces, the
best similarity between two point sets (Umeyama) and the rotation nearest each of many
cross-covariances (Kabsch), the smallest rotation between two directions, plane sections; and
the smoothstep every blend along a surface uses.

One home for each of these operations; every stage (repair, the Laplacian, measurement, export,
the generated quadruped) calls them from here.
"""
from __future__ import annotations

import numpy as np


def smoothstep(ramp: np.ndarray) -> np.ndarray:
    """3r² − 2r³ of ``ramp`` clipped to [0, 1]: 0 below 0, 1 above 1, flat at both ends (the blend
    of posture's turns, the held regions' zones, the limbs' thickening, the generated poses)."""
    ramp = np.clip(ramp, 0.0, 1.0)
    return ramp * ramp * (3.0 - 2.0 * ramp)


def turn_about_line(points: np.ndarray, pivot: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Each point turned about the line through ``pivot`` along the unit ``axis`` by its own
    ``angle`` (radians, right-handed; Rodrigues' formula): the joints of the posed animals."""
    offset = points - pivot
    cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return pivot + offset * cos + np.cross(axis, offset) * sin + np.outer(offset @ axis, axis) * (1.0 - cos)


def rotation_between(start: np.ndarray, end: np.ndarray) -> np.ndarray | None:
    """The smallest rotation (3×3) taking direction ``start`` to direction ``end`` (Rodrigues);
    ``None`` when they already agree (to 1e-12), or point opposite ways (no smallest rotation; a
    limb turned upside down is not a lean to straighten)."""
    start, end = start / np.linalg.norm(start), end / np.linalg.norm(end)
    axis, cosine = np.cross(start, end), float(start @ end)
    if (np.linalg.norm(axis) < 1e-12 and cosine > 0) or 1.0 + cosine < 1e-9:   # agree, or a half-turn
        return None
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + cross + cross @ cross / (1.0 + cosine)       # I + [v]× + [v]×² (1 − c)/s²


def near_line(points: np.ndarray, point: np.ndarray, direction: np.ndarray, radius: float, blend: float) -> np.ndarray:
    """1 within ``radius`` of the line through ``point`` along the unit ``direction``, 0 beyond
    radius + blend, smooth between (:func:`smoothstep`)."""
    offset = points - point
    across = offset - np.outer(offset @ direction, direction)
    return 1.0 - smoothstep((np.linalg.norm(across, axis=1) - radius) / blend)


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each triangle."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def corner_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) the angle of each triangle at each of its corners, in degrees."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    angles = np.empty((len(corners), 3))
    for k in range(3):
        a = corners[:, (k + 1) % 3] - corners[:, k]
        b = corners[:, (k + 2) % 3] - corners[:, k]
        cosine = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        angles[:, k] = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
    return angles


def vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """A third of the area of the faces around each vertex: the barycentric (lumped) mass matrix D
    of METHOD §2, D_ii = Σ_{faces ∋ i} area / 3, and every area weight per vertex."""
    areas = face_areas(vertices, faces) / 3.0
    mass = np.zeros(len(vertices))
    for k in range(3):
        np.add.at(mass, faces[:, k], areas)
    return mass


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals: n_i ∝ Σ_{faces f ∋ i} (b − a) × (c − a).

    A vertex with no (non-degenerate) face gets (0, 0, 1) rather than NaN.
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    corner = vertices[faces]
    face_normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])  # 2·area·n
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normal)
    length = np.linalg.norm(normals, axis=1)
    good = length > 0
    normals[good] /= length[good, None]
    normals[~good] = (0.0, 0.0, 1.0)
    return normals


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unnormalised face normals (b − a) × (c − a)."""
    corner = np.asarray(vertices)[faces]
    return np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])


# A face of ``before`` whose height is under this share of its longest edge (twice its area over the
# longest edge squared; 0.87 for an equilateral triangle) is a needle: its normal is round-off, it
# covers no pixels, and no fold of it is counted. The Princeton horse 387 has one at 0.003 that any
# deformation may turn over (its mesh's 0.1 % percentile is 0.08); faces that folded in real runs
# measured 0.08-0.43.
SLIVER_FLATNESS = 0.01


def flipped_face_mask(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces whose normal turned by more than 90° (n_before · n_after ≤ 0), a face of zero area or
    a needle (``SLIVER_FLATNESS``) in ``before`` excepted: it has no normal to turn."""
    normal_before = face_normals(before, faces)
    turned = np.einsum("ij,ij->i", normal_before, face_normals(after, faces)) <= 0
    candidates = np.flatnonzero(turned)             # few: the needle test only for them
    corners = np.asarray(before, dtype=float)[faces[candidates]]
    longest = np.max([np.sum((corners[:, k] - corners[:, k - 1]) ** 2, axis=1) for k in range(3)], axis=0,
                     initial=0.0)
    turned[candidates[np.linalg.norm(normal_before[candidates], axis=1) <= SLIVER_FLATNESS * longest]] = False
    return turned


def count_flipped_faces(before: np.ndarray, after: np.ndarray, faces: np.ndarray) -> int:
    """How many faces :func:`flipped_face_mask` finds."""
    return int(np.sum(flipped_face_mask(before, after, faces)))


def similarity_fit(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None
                   ) -> tuple[float, np.ndarray, np.ndarray]:
    """The similarity (scale σ, rotation R, translation t) that best maps ``source`` onto
    ``target`` in weighted least squares, min Σ w_i ‖σ R p_i + t − q_i‖² (Umeyama 1991).

    Returns (σ, R, t); R is a proper rotation (det +1)."""
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    weights = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    weights = weights / weights.sum()
    mean_source, mean_target = weights @ source, weights @ target
    p, q = source - mean_source, target - mean_target
    covariance = (q * weights[:, None]).T @ p              # Σ w q pᵀ
    rotation, singular = nearest_rotations(covariance[None])
    variance = float(weights @ np.einsum("ij,ij->i", p, p))
    scale = float(singular[0].sum() / variance) if variance > 0 else 1.0
    return scale, rotation[0], mean_target - scale * rotation[0] @ mean_source


def nearest_rotations(covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each cross-covariance Σ q pᵀ (n, 3, 3), the proper rotation R maximising tr(R Σᵀ), the
    best rotation of the points p onto the points q (Kabsch: U diag(1, 1, ±1) Vᵀ of Σ's SVD), and
    its singular values with the last one's sign corrected, (n, 3) (their sum over the
    variance of p is the best scale, :func:`similarity_fit`)."""
    u, singular, vt = np.linalg.svd(covariances)
    sign = np.sign(np.linalg.det(u @ vt))
    sign[sign == 0] = 1.0
    u = u.copy()
    u[:, :, 2] *= sign[:, None]
    singular = singular.copy()
    singular[:, 2] *= sign
    return u @ vt, singular


def affine_residuals(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """What is left of ``target`` (the points of ``source``, moved) beyond the best affine image of
    ``source``: q_i − (A p_i + t), A and t minimising Σ w_i ‖A p_i + t − q_i‖² (weights default 1).
    Zero for any stretch, shear, turn or move; a bend, hump or bulge is what is left."""
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    weights = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    root = np.sqrt(weights)[:, None]       # the map does not depend on the weights' sum
    homogeneous = np.hstack([source, np.ones((len(source), 1))])
    mapping = np.linalg.lstsq(homogeneous * root, target * root, rcond=None)[0]
    return target - homogeneous @ mapping


def affine_misfit(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> float:
    """How far ``target`` is from any affine image of ``source`` (same points, moved): the weighted
    RMS of :func:`affine_residuals` over the weighted RMS size of ``target`` about its centroid. 0
    for any stretch, shear, turn or move (a leg grown longer and thicker by different factors); a
    part bent or curled is not an affine image of itself."""
    target = np.asarray(target, dtype=float)
    weights = np.ones(len(target)) if weights is None else np.asarray(weights, dtype=float)
    weights = weights / weights.sum()
    left, spread = affine_residuals(source, target, weights), target - weights @ target
    size = float(weights @ np.einsum("ij,ij->i", spread, spread))
    return float(np.sqrt(weights @ np.einsum("ij,ij->i", left, left) / size)) if size > 0 else 0.0


def enclosed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Signed volume enclosed by a closed, outward-oriented triangle surface.

    Divergence theorem (Mirtich 1996): V = Σ_faces a · (b × c) / 6, taken about the vertex
    mean so that round-off does not grow with the distance from the origin.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return 0.0
    centred = vertices - vertices[faces.ravel()].mean(axis=0)     # any centre: the surface is closed
    a, b, c = (centred[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def ray_hits(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance along each ray (``origins`` + t · ``directions``, unit directions) to the first
    face it meets, ``inf`` where it meets none (libigl's AABB tree through gpytoolbox)."""
    import gpytoolbox

    if len(origins) == 0:
        return np.zeros(0)
    hit, _, _ = gpytoolbox.ray_mesh_intersect(np.asarray(origins, dtype=np.float64), np.asarray(directions, dtype=np.float64),
                                              np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int32))
    return np.asarray(hit, dtype=float)


def cone_directions(axis: np.ndarray, count: int, spread_degrees: float) -> np.ndarray:
    """``count`` unit directions spread evenly (a Fibonacci spiral) over the cap within
    ``spread_degrees`` of the unit ``axis``."""
    k = np.arange(count) + 0.5
    cos = 1.0 - k / count * (1.0 - np.cos(np.radians(spread_degrees)))
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    sin = np.sqrt(1.0 - cos ** 2)
    z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([sin * np.cos(phi), sin * np.sin(phi), cos]) @ np.vstack([x, np.cross(z, x), z])


def plane_section(vertices: np.ndarray, faces: np.ndarray, point: np.ndarray,
                  normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments where a closed mesh crosses a plane, oriented counter-clockwise about ``normal``.

    Returns (starts, ends, crossed): (k, 3) each, and the index of the face each segment lies on.
    A segment on a face with outward normal n is oriented along normal × n, so the segments of
    each loop run around the solid's section consistently.
    """
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    s = (vertices - point) @ normal
    sf = s[faces]
    above = sf > 0
    crossing = above.any(axis=1) & ~above.all(axis=1)
    crossed = np.flatnonzero(crossing)
    tri = vertices[faces[crossed]]
    st = sf[crossing]
    points = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        crosses = (st[:, i] > 0) != (st[:, j] > 0)
        t = np.where(crosses, st[:, i] / np.where(crosses, st[:, i] - st[:, j], 1.0), np.nan)
        points.append(tri[:, i] + (tri[:, j] - tri[:, i]) * t[:, None])
    points = np.stack(points, axis=1)                      # (k, 3 edges, 3), two of them finite
    valid = np.isfinite(points[:, :, 0])
    order = np.argsort(~valid, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(points))[:, None]
    pair = points[rows, order]
    start, end = pair[:, 0], pair[:, 1]
    flip = np.einsum("ij,ij->i", end - start, np.cross(normal, face_normals(vertices, faces[crossed]))) < 0
    start, end = np.where(flip[:, None], end, start), np.where(flip[:, None], start, end)
    return start, end, crossed


def plane_section_loops(vertices: np.ndarray, faces: np.ndarray, adjacency, point: np.ndarray,
                        normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`plane_section`'s segments grouped into loops: crossed faces that share an edge
    (``adjacency``: :func:`allorules.mesh.topology.face_adjacency` of ``faces``) are on one loop.

    Returns (starts, ends, crossed, loop_of): the segments, their faces, and each one's loop
    (ids 0 … k−1)."""
    from scipy.sparse.csgraph import connected_components

    start, end, crossed = plane_section(vertices, faces, point, normal)
    _, loop_of = connected_components(adjacency[crossed][:, crossed], directed=False)
    return start, end, crossed, loop_of
