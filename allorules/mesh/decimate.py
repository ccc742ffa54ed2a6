"""Decimation of a large mesh to a vertex budget, by quadric edge collapse (fast-simplification).
"""
from __future__ import annotations

import numpy as np

from allorules.errors import MeshError


def decimate(vertices: np.ndarray, faces: np.ndarray, target_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        import fast_simplification
    except ImportError:  # pragma: no cover - it is a declared dependency
        raise MeshError("decimation needs the fast-simplification package: pip install fast-simplification") from None
    # a closed mesh has two faces per vertex: aim at twice the vertex budget in faces
    new_vertices, new_faces = fast_simplification.simplify(vertices, faces, target_count=2 * int(target_vertices))
    return np.asarray(new_vertices, dtype=np.float64), np.asarray(new_faces, dtype=np.int64)
