"""Manifold harmonic basis (MHB) and transform (MHT) of a mesh (METHOD §2).

The basis is the ``m`` smallest eigenpairs of ``L h = λ D h`` with ``Hᵀ D H = I``. The
transform of per-vertex coordinates ``x`` (n × 3) is ``x̃ = Hᵀ D x`` (m × 3), the reconstruction
``H x̃``, and the *detail* ``x − H x̃`` is what lies beyond the m-th mode: adding it back after an
edit makes the identity edit exact.

Bases are cached on disk (see :mod:`allorules.spectral.cache`), keyed by the mesh's exact content, the
number of modes and the solver version.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from allorules.errors import BasisError
from allorules.mesh.geometry import vertex_areas
from allorules.spectral import cache as basis_cache
from allorules.spectral.eigen import smallest_eigenpairs
from allorules.spectral.laplacian import cotangent_laplacian

DEFAULT_MODES = 1000


@dataclass(frozen=True)
class HarmonicBasis:
    """The m smallest eigenpairs of a mesh's Laplacian, D-orthonormal."""

    eigenvalues: np.ndarray   # (m,), ascending, eigenvalues[0] ≈ 0 on a connected mesh
    vectors: np.ndarray       # (n, m), vectors.T @ diag(mass) @ vectors = I
    mass: np.ndarray          # (n,), lumped mass diagonal D

    @property
    def modes(self) -> int:
        return len(self.eigenvalues)


def default_modes(vertex_count: int, requested: int | None = None) -> int:
    """Number of modes to use: the request (default 1000), at most n − 1."""
    wanted = DEFAULT_MODES if requested is None else int(requested)
    if wanted < 2:
        raise BasisError(f"--modes must be at least 2, got {wanted}")
    return max(2, min(wanted, vertex_count - 1))


def compute_basis(
    vertices: np.ndarray,
    faces: np.ndarray,
    modes: int | None = None,
    *,
    use_cache: bool = True,
    warm_start: HarmonicBasis | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> HarmonicBasis:
    """The harmonic basis of a mesh with ``modes`` eigenpairs (default 1000, at most n − 1)."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    count = default_modes(len(vertices), modes)
    key = basis_cache.basis_key(vertices, faces, count) if use_cache else None
    if key is not None:
        cached = basis_cache.load(key, len(vertices), count)
        if cached is not None:
            return HarmonicBasis(*cached)
    stiffness = cotangent_laplacian(vertices, faces)
    mass = vertex_areas(vertices, faces)
    if np.any(mass <= 0):
        raise BasisError(
            f"{int(np.sum(mass <= 0))} vertices have no surrounding area; prepare the mesh first "
            "(allorules.mesh.repair.prepare_mesh) to drop unreferenced vertices and degenerate faces"
        )
    initial = warm_start.vectors if warm_start is not None and warm_start.vectors.shape[0] == len(vertices) else None
    eigenvalues, vectors = smallest_eigenpairs(stiffness, mass, count, initial=initial, progress=progress)
    eigenvalues = np.maximum(eigenvalues, 0.0) if eigenvalues[0] > -1e-9 * max(eigenvalues[-1], 1.0) else eigenvalues
    basis = HarmonicBasis(eigenvalues, vectors, mass)
    if key is not None:
        basis_cache.store(key, basis.eigenvalues, basis.vectors, basis.mass)
    return basis


def transform(basis: HarmonicBasis, values: np.ndarray) -> np.ndarray:
    """MHT (paper Eq. 1): coefficients x̃ = Hᵀ D x, for values of shape (n,) or (n, k)."""
    return basis.vectors.T @ (basis.mass[:, None] * values if values.ndim == 2 else basis.mass * values)


def reconstruct(basis: HarmonicBasis, coefficients: np.ndarray) -> np.ndarray:
    """Inverse MHT (paper Eq. 2): x = H x̃."""
    return basis.vectors @ coefficients


def filter_coefficients(basis: HarmonicBasis, values: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """Spectral filter (paper Eq. 3): x = H F x̃ with F = diag(gains)."""
    coefficients = transform(basis, values)
    gains = np.asarray(gains, dtype=float)
    return reconstruct(basis, coefficients * (gains[:, None] if coefficients.ndim == 2 else gains))


def detail(basis: HarmonicBasis, values: np.ndarray) -> np.ndarray:
    """What lies beyond the m-th mode: d = x − H Hᵀ D x. ``reconstruct(transform(x)) + d == x``."""
    return values - reconstruct(basis, transform(basis, values))
