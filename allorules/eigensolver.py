"""Solvers for the smallest eigenpairs of the generalised problem L h = λ D h (METHOD §2).

``smallest_eigenpairs`` is the one entry point: given the cotangent stiffness ``L`` (sparse,
symmetric PSD) and the lumped mass ``D`` (its diagonal), it returns the ``count`` smallest
eigenvalues in ascending order and D-orthonormal eigenvectors (Hᵀ D H = I).

Reference implementation: dense LAPACK for small meshes, scipy's shift-invert Lanczos
otherwise. Correct, not fast; the fast solver replaces the large-mesh path.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.linalg
import scipy.sparse as sparse
import scipy.sparse.linalg

DENSE_LIMIT = 2500


def _normalise_signs(vectors: np.ndarray) -> np.ndarray:
    """Deterministic signs: the entry of largest magnitude of each eigenvector is positive."""
    index = np.argmax(np.abs(vectors), axis=0)
    signs = np.sign(vectors[index, np.arange(vectors.shape[1])])
    signs[signs == 0] = 1.0
    return vectors * signs


def smallest_eigenpairs(
    stiffness: sparse.spmatrix,
    mass: np.ndarray,
    count: int,
    *,
    initial: np.ndarray | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``count`` smallest eigenpairs of ``stiffness h = λ diag(mass) h``.

    ``initial`` (an earlier basis of a nearby mesh) may be used to speed up the solve;
    ``progress(done, total)`` is called as eigenpairs converge. Returns ``(eigenvalues,
    eigenvectors)`` with eigenvalues ascending and ``vectors.T @ diag(mass) @ vectors = I``.
    """
    n = stiffness.shape[0]
    if not 1 <= count <= n:
        raise ValueError(f"count must be between 1 and {n}, got {count}")
    if n <= DENSE_LIMIT or count >= n - 1:
        eigenvalues, vectors = scipy.linalg.eigh(
            stiffness.toarray(), np.diag(mass), subset_by_index=[0, count - 1]
        )
    else:
        # Shift slightly below zero so that the factorisation of L − σD is non-singular.
        sigma = -1e-8 * float(stiffness.diagonal().max() / mass.max())
        eigenvalues, vectors = scipy.sparse.linalg.eigsh(
            stiffness.tocsc(), k=count, M=sparse.diags(mass).tocsc(), sigma=sigma, which="LM"
        )
        order = np.argsort(eigenvalues)
        eigenvalues, vectors = eigenvalues[order], vectors[:, order]
    if progress is not None:
        progress(count, count)
    # Re-normalise in the D-inner product (eigsh/eigh already do; this guards round-off).
    norms = np.sqrt(np.einsum("ij,i,ij->j", vectors, mass, vectors))
    return eigenvalues, _normalise_signs(vectors / norms)
