"""The spectral algebra of allorules.spectral.power_laws: equations, identity edits, unit independence."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import trimesh

from allorules.mesh.geometry import face_areas, vertex_areas
from allorules.spectral.basis import HarmonicBasis, compute_basis, transform
from allorules.spectral.laplacian import cotangent_laplacian
from allorules.spectral.power_laws import (
    apply_to_mesh,
    arithmetic_region_scaling,
    dimensionless,
    edited_coefficients,
    from_dimensionless,
    from_mode_magnitudes,
    geometric_mean_gate,
    global_allometric,
    local_power_law,
    mode_magnitudes,
    mode_shares,
    multi_region_power_law,
    relative_eigenvalues,
)


@pytest.fixture(autouse=True)
def _no_cache(monkeypatch):
    monkeypatch.setenv("ALLORULES_CACHE_DIR", "off")


def _blob(subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """An asymmetric bumpy ellipsoid (no repeated eigenvalues to make bases ambiguous)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    v = sphere.vertices * np.array([1.0, 0.6, 0.45])
    v = v + 0.08 * np.sin(3.0 * v[:, [1]] + 2.0 * v[:, [2]]) * sphere.vertices + np.array([0.2, 0.0, 0.1]) * v[:, [0]] ** 2
    return v, np.asarray(sphere.faces)


@pytest.fixture(scope="module")
def blob():
    vertices, faces = _blob()
    return vertices, faces, compute_basis(vertices, faces, modes=120, use_cache=False)


def _rotation(seed: int = 3) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def test_global_allometric_is_eq4_with_lambda_over_lambda1():
    rng = np.random.default_rng(0)
    coefficients = rng.normal(size=(6, 3))
    eigenvalues = np.array([0.0, 2.0, 3.0, 8.0, 9.0, 20.0])
    out = global_allometric(coefficients, eigenvalues, alpha=0.5, scale=2.0)
    expected = coefficients * (2.0 * np.sqrt(eigenvalues / 2.0))[:, None]
    expected[0] = coefficients[0]          # constant mode untouched
    np.testing.assert_allclose(out, expected, rtol=1e-14)
    # Mode 1 is multiplied by s exactly: (λ_1/λ_1)^α = 1.
    np.testing.assert_allclose(out[1], 2.0 * coefficients[1], rtol=1e-15)


def test_global_allometric_does_not_depend_on_eigenvalue_units():
    rng = np.random.default_rng(1)
    coefficients = rng.normal(size=(8, 3))
    eigenvalues = np.concatenate([[0.0], np.sort(rng.uniform(1, 50, size=7))])
    a = global_allometric(coefficients, eigenvalues, 0.3, 1.2)
    b = global_allometric(coefficients, eigenvalues * 1e-6, 0.3, 1.2)   # mesh 1000× larger
    np.testing.assert_allclose(a, b, rtol=1e-12)


def test_relative_eigenvalues_refuses_disconnected_spectrum():
    with pytest.raises(ValueError, match="not one connected"):
        relative_eigenvalues(np.array([0.0, 0.0, 1.0, 2.0]))


def test_identity_edits_return_input_exactly(blob):
    vertices, faces, basis = blob
    x = transform(basis, vertices)
    assert np.array_equal(global_allometric(x, basis.eigenvalues, 0.0, 1.0), x)
    u, c = dimensionless(x)
    u_region = dimensionless(transform(basis, vertices * (vertices[:, [0]] > 0)))[0]
    assert np.array_equal(local_power_law(u, u_region, 0.0), u)
    assert np.array_equal(multi_region_power_law(u, [u_region, u_region], [0.0, 0.0], 0.0, 1.0), u)
    np.testing.assert_allclose(from_dimensionless(u, c), x, rtol=1e-15, atol=0)
    # The mesh itself, bit for bit (the detail beyond mode m is kept).
    new = global_allometric(x, basis.eigenvalues, 0.0, 1.0)
    assert np.array_equal(apply_to_mesh(basis, vertices, new, 1.0), vertices)
    same = multi_region_power_law(u, [u_region], [0.0], 0.0, 1.0)
    assert np.array_equal(edited_coefficients(x, u, same, c), x)
    assert np.array_equal(apply_to_mesh(basis, vertices, edited_coefficients(x, u, same, c), 1.0), vertices)


def test_alpha_zero_is_isometric_scaling_about_the_surface_centroid(blob):
    vertices, faces, basis = blob
    x = transform(basis, vertices)
    centroid = (basis.mass[:, None] * vertices).sum(0) / basis.mass.sum()
    out = apply_to_mesh(basis, vertices, global_allometric(x, basis.eigenvalues, 0.0, 1.7), 1.7)
    np.testing.assert_allclose(out, centroid + 1.7 * (vertices - centroid), atol=1e-12)


def test_detail_beyond_the_basis_is_kept_and_scaled(blob):
    vertices, faces, basis = blob
    # A truncated basis (120 of 642 modes) cannot reconstruct the mesh; the edit must not smooth.
    x = transform(basis, vertices)
    assert np.abs(basis.vectors @ x - vertices).max() > 1e-3
    out = apply_to_mesh(basis, vertices, global_allometric(x, basis.eigenvalues, 0.0, 0.5), 0.5)
    centroid = (basis.mass[:, None] * vertices).sum(0) / basis.mass.sum()
    np.testing.assert_allclose(out, centroid + 0.5 * (vertices - centroid), atol=1e-12)


def test_global_scaling_of_mesh_is_unit_and_rotation_free():
    vertices, faces = _blob()
    rotation = _rotation()
    k = 1000.0
    moved = k * vertices @ rotation.T + np.array([5.0, -3.0, 2.0])
    results = []
    for verts in (vertices, moved):
        basis = compute_basis(verts, faces, modes=80, use_cache=False)
        x = transform(basis, verts)
        results.append(apply_to_mesh(basis, verts, global_allometric(x, basis.eigenvalues, 0.2, 1.1), 1.1))
    expected = k * results[0] @ rotation.T + np.array([5.0, -3.0, 2.0])
    np.testing.assert_allclose(results[1], expected, atol=1e-7 * k)
    # and the edit did something
    assert np.abs(results[0] - 1.1 * vertices).max() > 1e-3


def test_dimensionless_form():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(10, 3)) * np.array([1.0, 100.0, 1e-3])
    x[0] = [50.0, 50.0, 50.0]            # a big constant mode does not set c
    u, c = dimensionless(x)
    np.testing.assert_allclose(c, np.abs(x[1:]).max(0))
    assert np.abs(u[1:]).max() == pytest.approx(1.0)
    np.testing.assert_allclose(np.abs(u[1:]).max(0), 1.0)
    u2, c2 = dimensionless(x * 1e6)
    np.testing.assert_allclose(u2, u, rtol=1e-14)
    # a flat axis does not divide by zero
    flat = x.copy()
    flat[1:, 2] = 0
    u3, c3 = dimensionless(flat)
    assert np.all(np.isfinite(u3)) and c3[2] == 1.0


@pytest.mark.parametrize(
    "a, b, expected",
    [(4.0, 9.0, 6.0), (-4.0, -9.0, 6.0), (4.0, -9.0, 0.0), (-4.0, 9.0, 0.0), (0.0, 5.0, 0.0), (0.0, 0.0, 0.0),
     (0.25, 0.25, 0.25), (1e-12, 1.0, 1e-6)],
)
def test_geometric_mean_gate_eq7(a, b, expected):
    assert geometric_mean_gate(np.array([a]), np.array([b]))[0] == pytest.approx(expected, rel=1e-12, abs=0)


def test_geometric_mean_gate_is_symmetric_and_below_arithmetic_mean():
    rng = np.random.default_rng(4)
    a, b = rng.uniform(0, 1, 100), rng.uniform(0, 1, 100)
    g = geometric_mean_gate(a, b)
    np.testing.assert_array_equal(g, geometric_mean_gate(b, a))
    assert np.all(g <= (a + b) / 2 + 1e-15)


def test_local_power_law_eq6():
    u = np.array([[3.0], [0.5], [-0.5], [0.25], [0.8]])
    region = np.array([[1.0], [0.5], [0.5], [0.0], [-0.2]])
    out = local_power_law(u, region, alpha=1.0)
    assert out[0, 0] == 3.0                                     # constant mode left alone
    assert out[1, 0] == pytest.approx(0.5 ** 1.5)               # G = 0.5
    assert out[2, 0] == -0.5                                    # opposite signs: G = 0, unchanged
    assert out[3, 0] == 0.25                                    # region has no share: unchanged
    assert out[4, 0] == 0.8                                     # opposite signs again
    # α > 0 shrinks shared modes (|u| ≤ 1), α < 0 grows them, sign preserved
    grown = local_power_law(u, region, alpha=-0.5)
    assert grown[1, 0] == pytest.approx(0.5 ** 0.75) and grown[1, 0] > 0.5


def test_multi_region_power_law_eq9():
    rng = np.random.default_rng(5)
    u = rng.uniform(-1, 1, size=(20, 3))
    regions = [rng.uniform(-1, 1, size=(20, 3)) for _ in range(2)]
    alphas, alpha0, s = [0.3, -0.2], 0.05, 1.3
    out = multi_region_power_law(u, regions, alphas, alpha0, s)
    exponent = 1 + alpha0 + sum(a * geometric_mean_gate(u, r) for a, r in zip(alphas, regions))
    expected = s * np.sign(u) * np.abs(u) ** exponent
    np.testing.assert_allclose(out[1:], expected[1:], rtol=1e-13)
    np.testing.assert_array_equal(out[0], u[0])
    # one region with α_0 = 0, s = 1 is Eq. 6
    np.testing.assert_allclose(multi_region_power_law(u, regions[:1], [0.3], 0.0, 1.0), local_power_law(u, regions[0], 0.3))


def test_power_law_refuses_non_positive_exponent():
    u = np.array([[0.5], [0.5]])
    with pytest.raises(ValueError, match="positive"):
        multi_region_power_law(u, [u], [-3.0], 0.0, 1.0)


def test_arithmetic_region_scaling_is_scaling_the_vertex_set():
    # With a complete basis (all n modes) the MHT is invertible and the identity is exact.
    vertices, faces = _blob(subdivisions=2)
    stiffness, mass = cotangent_laplacian(vertices, faces), vertex_areas(vertices, faces)
    eigenvalues, vectors = scipy.linalg.eigh(stiffness.toarray(), np.diag(mass))
    basis = HarmonicBasis(eigenvalues, vectors, mass)
    inside = vertices[:, 0] > 0.3
    x = transform(basis, vertices)
    x_region = transform(basis, vertices * inside[:, None])
    out = apply_to_mesh(basis, vertices, arithmetic_region_scaling(x, x_region, 1.5), 1.0, coefficients=x)
    expected = vertices.copy()
    expected[inside] *= 1.5
    np.testing.assert_allclose(out, expected, atol=1e-10)


def test_local_scaling_of_mesh_is_unit_free():
    vertices, faces = _blob()
    inside = (vertices[:, 0] > 0.3).astype(float)[:, None]
    results = []
    for k in (1.0, 1e3):
        verts = k * vertices
        basis = compute_basis(verts, faces, modes=80, use_cache=False)
        x = transform(basis, verts)
        u, c = dimensionless(x)
        u_region = transform(basis, verts * inside) / c
        new = edited_coefficients(x, u, local_power_law(u, u_region, 0.4), c)
        results.append(apply_to_mesh(basis, verts, new, 1.0, coefficients=x))
    np.testing.assert_allclose(results[1], 1e3 * results[0], atol=1e-7 * 1e3)
    change = np.linalg.norm(results[0] - vertices, axis=1)
    assert change[inside[:, 0] > 0].mean() > change[inside[:, 0] == 0].mean()


def test_apply_to_mesh_refuses_nan(blob):
    vertices, faces, basis = blob
    x = transform(basis, vertices)
    x[3, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        apply_to_mesh(basis, vertices, x, 1.0)


def test_global_alpha_positive_amplifies_fine_modes(blob):
    """α > 0 multiplies mode i by (λ_i/λ_1)^α ≥ 1: fine detail grows relative to coarse shape."""
    vertices, faces, basis = blob
    x = transform(basis, vertices)
    out = global_allometric(x, basis.eigenvalues, 0.1, 1.0)
    gain = np.linalg.norm(out, axis=1)[1:] / np.linalg.norm(x, axis=1)[1:]
    assert np.all(np.diff(gain) >= -1e-12) and gain[-1] > 1.2 and gain[0] == pytest.approx(1.0)
    assert face_areas(apply_to_mesh(basis, vertices, out, 1.0), faces).sum() > face_areas(vertices, faces).sum()


# ---------------------------------------------------------------------------------------------
# The per-mode form: the power law on each mode's coefficient vector length


def test_per_mode_form_is_the_paper_power_law_in_one_dimension():
    """On coefficients along one axis (a 1-D signal) the per-mode and per-axis forms coincide,
    so the 1-D experiments of Figures 12 and 14 are the same in both."""
    rng = np.random.default_rng(7)
    signal = np.zeros((40, 3))
    signal[:, 1] = rng.normal(size=40) / (1 + np.arange(40))
    region = np.zeros((40, 3))
    region[:, 1] = signal[:, 1] * rng.uniform(-0.5, 1.0, size=40)
    u, c = dimensionless(signal)
    per_axis = edited_coefficients(signal, u, local_power_law(u, region / c, 0.4), c)
    rho, scalar_c = mode_magnitudes(signal)
    assert scalar_c == pytest.approx(c[1])
    np.testing.assert_allclose(rho, np.abs(u[:, 1]))
    shares = mode_shares(region, signal, scalar_c)
    np.testing.assert_allclose(shares, np.sign(u[:, 1]) * region[:, 1] / c[1])
    per_mode = from_mode_magnitudes(signal, rho, local_power_law(rho, shares, 0.4))
    np.testing.assert_allclose(per_mode, per_axis, rtol=1e-12, atol=1e-15)


def test_per_mode_form_does_not_depend_on_orientation_or_units():
    rng = np.random.default_rng(8)
    coefficients = rng.normal(size=(60, 3)) / (1 + np.arange(60))[:, None]
    region = coefficients * rng.uniform(-0.3, 1.0, size=(60, 1)) + 0.01 * rng.normal(size=(60, 3))

    def edit(x, x_region):
        rho, c = mode_magnitudes(x)
        return from_mode_magnitudes(x, rho, multi_region_power_law(rho, [mode_shares(x_region, x, c)], [0.5], 0.1, 1.2))

    rotation = _rotation(11)
    np.testing.assert_allclose(edit(coefficients @ rotation.T, region @ rotation.T), edit(coefficients, region) @ rotation.T,
                               rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(edit(1000 * coefficients, 1000 * region), 1000 * edit(coefficients, region), rtol=1e-12)
    # each mode keeps its direction; only its length changes
    edited = edit(coefficients, region)
    cosine = np.einsum("ij,ij->i", edited, coefficients) / np.linalg.norm(edited, axis=1) / np.linalg.norm(coefficients, axis=1)
    np.testing.assert_allclose(cosine, 1.0, atol=1e-12)
    # the per-axis form, by contrast, depends on the axes it works in (so it works in the animal's own)
    def per_axis(x, x_region):
        u, c = dimensionless(x)
        return edited_coefficients(x, u, local_power_law(u, x_region / c, 0.5), c)

    assert not np.allclose(per_axis(coefficients @ rotation.T, region @ rotation.T), per_axis(coefficients, region) @ rotation.T,
                           rtol=1e-3, atol=1e-6)


def test_per_mode_identity_edit_is_exact():
    rng = np.random.default_rng(9)
    coefficients = rng.normal(size=(30, 3))
    rho, _ = mode_magnitudes(coefficients)
    assert np.array_equal(from_mode_magnitudes(coefficients, rho, rho.copy()), coefficients)
