"""Discrete Laplace–Beltrami operator of a triangle mesh (METHOD §2).

``L = diag(W·1) − W`` with cotangent weights ``w_ij = (cot a + cot b) / 2`` (positive
semi-definite), and the lumped (barycentric) mass ``D_ii`` = one third of the area of the faces
around vertex ``i``. Both are plain functions of vertex and face arrays.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sparse


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sparse.csr_matrix:
    """Cotangent stiffness matrix L (symmetric, positive semi-definite, rows sum to zero).

    For the edge opposite corner k of a triangle, the weight gains cot(angle at k) / 2; an
    interior edge collects (cot a + cot b) / 2 from its two triangles, a boundary edge cot a / 2
    (natural boundary condition).
    """
    n = len(vertices)
    rows, cols, weights = [], [], []
    for k in range(3):
        i = faces[:, (k + 1) % 3]
        j = faces[:, (k + 2) % 3]
        edge_a = vertices[i] - vertices[faces[:, k]]
        edge_b = vertices[j] - vertices[faces[:, k]]
        cross = np.linalg.norm(np.cross(edge_a, edge_b), axis=1)
        dot = np.einsum("ij,ij->i", edge_a, edge_b)
        # A degenerate triangle (zero area) contributes nothing rather than infinity.
        scale = np.maximum(np.einsum("ij,ij->i", edge_a, edge_a), np.einsum("ij,ij->i", edge_b, edge_b))
        safe = cross > 1e-12 * np.maximum(scale, np.finfo(float).tiny)
        cot = np.where(safe, dot / np.where(safe, cross, 1.0), 0.0)
        rows += [i, j]
        cols += [j, i]
        weights += [0.5 * cot, 0.5 * cot]
    rows = np.concatenate(rows)
    cols = np.concatenate(cols)
    weights = np.concatenate(weights)
    off_diagonal = sparse.coo_matrix((weights, (rows, cols)), shape=(n, n)).tocsr()
    degree = np.asarray(off_diagonal.sum(axis=1)).ravel()
    return (sparse.diags(degree) - off_diagonal).tocsr()
