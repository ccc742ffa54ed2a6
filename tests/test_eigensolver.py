"""The harmonic-basis eigensolver: exact against dense LAPACK, complete across band edges,
warm starts, progress reporting."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import trimesh

from allorules.mesh.geometry import vertex_areas
from allorules.spectral.eigen import smallest_eigenpairs
from allorules.spectral.laplacian import cotangent_laplacian

MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


def operators(vertices, faces):
    return cotangent_laplacian(vertices, faces), vertex_areas(vertices, faces)


def dense_reference(stiffness, mass, count):
    """Reference spectrum by LAPACK on the symmetric form D^-1/2 L D^-1/2."""
    scale = 1.0 / np.sqrt(mass)
    symmetric = stiffness.toarray() * scale[:, None] * scale[None, :]
    values, vectors = scipy.linalg.eigh(symmetric, subset_by_index=[0, count - 1])
    return values, vectors * scale[:, None]


def check_eigenpairs(stiffness, mass, values, vectors, reference, relative=1e-8):
    count = len(reference)
    assert values.shape == (count,) and vectors.shape == (len(mass), count)
    assert np.all(np.diff(values) >= 0)
    # Relative error against the smallest non-zero eigenvalue for the zero modes.
    nonzero = reference[np.abs(reference) > 1e-9 * np.abs(reference).max()]
    floor = nonzero[0] if len(nonzero) else 1.0
    assert np.max(np.abs(values - reference) / np.maximum(np.abs(reference), floor)) < relative
    gram = vectors.T @ (mass[:, None] * vectors)
    assert np.max(np.abs(gram - np.eye(count))) < 1e-8
    residual = stiffness @ vectors - mass[:, None] * vectors * values
    norms = np.sqrt(np.einsum("ij,i,ij->j", residual, 1.0 / mass, residual))
    assert np.max(norms / np.maximum(values, floor)) < 1e-7


def same_subspaces(vectors_a, vectors_b, mass, values, relative_gap=1e-6):
    """Eigenvectors agree up to rotations inside clusters of equal eigenvalues."""
    overlap = vectors_a.T @ (mass[:, None] * vectors_b)
    start = 0
    for stop in range(1, len(values) + 1):
        if stop == len(values) or values[stop] - values[stop - 1] > relative_gap * max(values[stop], 1e-12):
            block = overlap[start:stop, start:stop]
            singular = np.linalg.svd(block, compute_uv=False)
            assert np.min(singular) > 1 - 1e-6, (start, stop, singular)
            start = stop


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=2.0)
    return operators(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@pytest.fixture(scope="module")
def capsule():
    mesh = trimesh.creation.capsule(height=3.0, radius=0.7, count=[48, 32])
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return operators(vertices, faces)


@pytest.mark.parametrize("method", ["bands", "eigsh", "dense"])
def test_methods_match_dense_reference(capsule, method):
    stiffness, mass = capsule
    count = 120
    reference, _ = dense_reference(stiffness, mass, count)
    values, vectors = smallest_eigenpairs(stiffness, mass, count, method=method, band_size=40)
    check_eigenpairs(stiffness, mass, values, vectors, reference)
    assert abs(values[0]) < 1e-9 * values[-1]
    constant = vectors[:, 0]
    assert np.ptp(constant) < 1e-8 * np.abs(constant).max()


def test_sphere_multiplicities_across_tiny_bands(sphere):
    """Eigenvalues of the radius-2 sphere come in clusters of 2l+1 near l(l+1)/4. Bands of
    ~12 pairs cut through clusters of up to 15: none may be missed or duplicated."""
    stiffness, mass = sphere
    count = 81   # l = 0..8
    reference, reference_vectors = dense_reference(stiffness, mass, count)
    values, vectors = smallest_eigenpairs(stiffness, mass, count, method="bands", band_size=12)
    check_eigenpairs(stiffness, mass, values, vectors, reference)
    same_subspaces(vectors, reference_vectors, mass, reference, relative_gap=1e-3)
    start = 0
    for degree in range(9):
        cluster = values[start:start + 2 * degree + 1]
        exact = degree * (degree + 1) / 4.0
        # The icosphere's discretisation error grows with l (2 % at l = 8 here).
        assert np.allclose(cluster, exact, rtol=0.03, atol=1e-9), (degree, cluster)
        if start + len(cluster) < count:
            assert cluster.max() < 0.9 * values[start + len(cluster)]
        start += 2 * degree + 1
    assert start == count


def test_disconnected_mesh_has_one_zero_mode_per_part():
    first = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    second = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    vertices = np.vstack([first.vertices, second.vertices + [5.0, 0.0, 0.0]])
    faces = np.vstack([first.faces, second.faces + len(first.vertices)])
    stiffness, mass = operators(vertices, faces)
    reference, _ = dense_reference(stiffness, mass, 60)
    values, vectors = smallest_eigenpairs(stiffness, mass, 60, method="bands", band_size=20)
    check_eigenpairs(stiffness, mass, values, vectors, reference)
    assert np.sum(np.abs(values) < 1e-8) == 2


def test_warm_start_after_deformation_gives_the_cold_answer(capsule):
    stiffness, mass = capsule
    count = 100
    _, previous = smallest_eigenpairs(stiffness, mass, count, method="bands", band_size=40)
    mesh = trimesh.creation.capsule(height=3.0, radius=0.7, count=[48, 32])
    vertices = np.asarray(mesh.vertices) * 1.1
    # A smooth bump as in one scaling step.
    vertices[:, 0] *= 1.0 + 0.05 * np.exp(-vertices[:, 2] ** 2)
    new_stiffness, new_mass = operators(vertices, np.asarray(mesh.faces))
    reference, reference_vectors = dense_reference(new_stiffness, new_mass, count)
    values, vectors = smallest_eigenpairs(
        new_stiffness, new_mass, count, method="bands", band_size=40, initial=previous
    )
    check_eigenpairs(new_stiffness, new_mass, values, vectors, reference)
    same_subspaces(vectors, reference_vectors, new_mass, reference)


def test_signs_are_deterministic(capsule):
    stiffness, mass = capsule
    _, first = smallest_eigenpairs(stiffness, mass, 30, method="bands", band_size=40)
    _, second = smallest_eigenpairs(stiffness, mass, 30, method="bands", band_size=40)
    index = np.argmax(np.abs(first), axis=0)
    assert np.all(first[index, np.arange(30)] > 0)
    np.testing.assert_allclose(first[:, 1:4] @ (first[:, 1:4].T @ (mass[:, None] * second[:, 1:4])),
                               second[:, 1:4], atol=1e-7)


def test_progress_is_reported(capsule):
    stiffness, mass = capsule
    calls = []
    smallest_eigenpairs(stiffness, mass, 80, method="bands", band_size=30,
                        progress=lambda done, total: calls.append((done, total)))
    assert len(calls) >= 2
    assert calls[-1] == (80, 80)
    assert all(total == 80 for _, total in calls)
    assert [done for done, _ in calls] == sorted(done for done, _ in calls)


def test_invalid_arguments(capsule):
    stiffness, mass = capsule
    with pytest.raises(ValueError):
        smallest_eigenpairs(stiffness, mass, 0)
    with pytest.raises(ValueError):
        smallest_eigenpairs(stiffness, mass, 5, method="magic")


@pytest.mark.slow
@pytest.mark.shared_meshes
def test_real_horse_against_eigsh():
    path = MESHES / "horse.obj"
    if not path.exists():
        pytest.skip("shared meshes not available")
    mesh = trimesh.load(path, process=True)
    stiffness, mass = operators(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    count = 150
    reference, _ = smallest_eigenpairs(stiffness, mass, count, method="eigsh")
    values, vectors = smallest_eigenpairs(stiffness, mass, count, method="bands", band_size=60)
    check_eigenpairs(stiffness, mass, values, vectors, reference)


@pytest.mark.slow
def test_default_bands_on_an_animal_match_dense():
    """The default path (many bands of the default size, Lanczos without restarts) on an animal's
    Laplacian: every pair of the dense reference, none missing or duplicated."""
    from allorules.mesh.quadruped import generate_quadruped

    animal = generate_quadruped("horse", vertices=2800)
    stiffness, mass = operators(np.asarray(animal.vertices, dtype=float), np.asarray(animal.faces))
    count = 400
    reference, reference_vectors = dense_reference(stiffness, mass, count)
    values, vectors = smallest_eigenpairs(stiffness, mass, count, method="bands")
    check_eigenpairs(stiffness, mass, values, vectors, reference)
    same_subspaces(vectors, reference_vectors, mass, reference, relative_gap=1e-6)


def test_rounding_noise_is_not_a_new_krylov_direction():
    from allorules.spectral.eigen import _orthonormal_with_factor

    rng = np.random.default_rng(3)
    mass = rng.uniform(0.5, 2.0, 200)
    block = rng.standard_normal((200, 3))
    block[:, 2] = 1e-14 * rng.standard_normal(200)     # what cancellation leaves of a known direction
    orthonormal, factor = _orthonormal_with_factor(block, mass, scale=1.0)
    assert orthonormal.shape[1] == 2
    np.testing.assert_allclose(orthonormal.T @ (mass[:, None] * orthonormal), np.eye(2), atol=1e-12)
    np.testing.assert_allclose(orthonormal @ factor, block, atol=1e-12)


def test_accepted_vectors_are_put_in_order_in_place():
    """The store the bands write into gathers any subset of its columns, in any order."""
    from allorules.spectral.eigen import _ColumnStore

    rng = np.random.default_rng(11)
    for _ in range(100):
        rows, used = int(rng.integers(1, 6)), int(rng.integers(1, 12))
        store = _ColumnStore(rows, int(rng.integers(1, 12)))   # too small at times: it grows
        data = rng.standard_normal((rows, used))
        written = 0
        while written < used:
            width = int(rng.integers(1, used - written + 1))
            stored = store.append(data[:, written:written + width])
            np.testing.assert_array_equal(stored, data[:, written:written + width])
            written += width
        order = rng.permutation(used)[:int(rng.integers(1, used + 1))]
        np.testing.assert_array_equal(store.ordered(order), data[:, order])
