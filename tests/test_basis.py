"""The harmonic basis against analytic answers: sphere eigenvalues, orthonormality, exact round trips."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from allorules.mesh.geometry import vertex_areas
from allorules.spectral.basis import compute_basis, detail, reconstruct, transform
from allorules.spectral.cache import basis_key, cache_directory, load
from allorules.spectral.laplacian import cotangent_laplacian


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=4, radius=2.0)


@pytest.fixture(scope="module")
def sphere_basis(sphere):
    return compute_basis(sphere.vertices, sphere.faces, 49, use_cache=False)


def test_laplacian_is_symmetric_and_annihilates_constants(sphere):
    stiffness = cotangent_laplacian(sphere.vertices, sphere.faces)
    assert abs(stiffness - stiffness.T).max() < 1e-12
    assert np.abs(stiffness @ np.ones(len(sphere.vertices))).max() < 1e-10
    assert vertex_areas(sphere.vertices, sphere.faces).sum() == pytest.approx(sphere.area)


def test_sphere_eigenvalues_and_multiplicities(sphere_basis):
    # Eigenvalues of the Laplace–Beltrami operator on a sphere of radius R: l(l+1)/R², 2l+1 times.
    expected = np.concatenate([np.full(2 * l + 1, l * (l + 1) / 4.0) for l in range(7)])
    assert sphere_basis.eigenvalues[0] == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(sphere_basis.eigenvalues, expected, rtol=0.02, atol=1e-9)


def test_basis_is_mass_orthonormal_with_small_residuals(sphere, sphere_basis):
    vectors, mass = sphere_basis.vectors, sphere_basis.mass
    assert np.abs(vectors.T @ (mass[:, None] * vectors) - np.eye(49)).max() < 1e-10
    stiffness = cotangent_laplacian(sphere.vertices, sphere.faces)
    residual = stiffness @ vectors - mass[:, None] * vectors * sphere_basis.eigenvalues
    assert np.linalg.norm(residual, axis=0).max() < 1e-8 * max(1.0, sphere_basis.eigenvalues.max())


def test_identity_round_trip_is_exact(sphere, sphere_basis):
    coefficients = transform(sphere_basis, sphere.vertices)
    rebuilt = reconstruct(sphere_basis, coefficients) + detail(sphere_basis, sphere.vertices)
    assert np.abs(rebuilt - sphere.vertices).max() < 1e-12


def test_reconstruction_error_falls_as_modes_grow():
    mesh = trimesh.creation.capsule(height=3.0, radius=0.5, count=[24, 24])
    basis = compute_basis(mesh.vertices, mesh.faces, 200, use_cache=False)
    errors = []
    for modes in (10, 50, 200):
        truncated = basis.vectors[:, :modes]
        coefficients = truncated.T @ (basis.mass[:, None] * mesh.vertices)
        errors.append(np.abs(truncated @ coefficients - mesh.vertices).max())
    assert errors[0] > errors[1] > errors[2]


def test_cache_hit_is_identical_and_corrupt_file_is_recomputed(sphere, tmp_path, monkeypatch):
    monkeypatch.setenv("ALLORULES_CACHE_DIR", str(tmp_path))
    first = compute_basis(sphere.vertices, sphere.faces, 20)
    files = list(tmp_path.glob("*.npz"))
    assert len(files) == 1
    second = compute_basis(sphere.vertices, sphere.faces, 20)
    assert np.array_equal(first.vectors, second.vectors)
    # Corrupt the stored file: it must be detected, deleted and recomputed, never trusted.
    data = bytearray(files[0].read_bytes())
    data[len(data) // 2] ^= 0xFF
    files[0].write_bytes(bytes(data))
    key = basis_key(sphere.vertices, sphere.faces, 20)
    assert load(key, len(sphere.vertices), 20) is None
    third = compute_basis(sphere.vertices, sphere.faces, 20)
    assert np.allclose(third.eigenvalues, first.eigenvalues, rtol=1e-8, atol=1e-10)
    # Same subspace (the sphere's eigenspaces are degenerate, so compare projectors).
    projector = lambda basis: basis.vectors @ (basis.mass[:, None] * basis.vectors).T
    assert np.abs(projector(third)[:, :50] - projector(first)[:, :50]).max() < 1e-6
    assert len(list(tmp_path.glob("*.npz"))) == 1


def test_stale_cache_entry_for_other_mesh_is_not_used(sphere, tmp_path, monkeypatch):
    monkeypatch.setenv("ALLORULES_CACHE_DIR", str(tmp_path))
    compute_basis(sphere.vertices, sphere.faces, 20)
    moved = sphere.vertices * 1.01
    assert basis_key(moved, sphere.faces, 20) != basis_key(sphere.vertices, sphere.faces, 20)
    # A file whose stored key does not match its name is rejected.
    stored = next(tmp_path.glob("*.npz"))
    wrong = tmp_path / f"{basis_key(moved, sphere.faces, 20)}.npz"
    stored.rename(wrong)
    assert load(basis_key(moved, sphere.faces, 20), len(sphere.vertices), 20) is None


def test_cache_can_be_switched_off(sphere, tmp_path, monkeypatch):
    monkeypatch.setenv("ALLORULES_CACHE_DIR", "off")
    assert cache_directory() is None
    compute_basis(sphere.vertices, sphere.faces, 10)
    assert not list(tmp_path.glob("*.npz"))
