"""Spectrum statistics of a mesh (paper §3, Table 1; METHOD §2).

The radial spectrum is r̃_i = ‖(x̃_i, ỹ_i, z̃_i)‖. A least-squares line through
(log λ_i, log r̃_i) for i = 1 … m−1 (the constant mode λ_0 = 0 excluded) gives the slope α, and
Pearson's correlation R between log r̃ and log λ says how well the spectrum follows a power law.
Both are independent of the mesh's size and orientation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from allorules.spectral.basis import HarmonicBasis, transform


@dataclass(frozen=True)
class SpectrumFit:
    """Power-law fit log r̃ = slope · log λ + intercept over modes 1 … m−1."""

    eigenvalues: np.ndarray
    radial: np.ndarray        # r̃_i for every mode, including mode 0
    slope: float
    intercept: float
    r: float                  # Pearson's R of (log λ_i, log r̃_i), i ≥ 1


def radial_spectrum(coefficients: np.ndarray) -> np.ndarray:
    """r̃_i = sqrt(x̃_i² + ỹ_i² + z̃_i²) for coefficients of shape (m, 3)."""
    return np.linalg.norm(coefficients, axis=1)


def fit_power_law(eigenvalues: np.ndarray, radial: np.ndarray) -> tuple[float, float, float]:
    """(slope, intercept, R) of log radial against log eigenvalue over modes 1 … m−1."""
    log_lambda = np.log(eigenvalues[1:])
    log_radial = np.log(radial[1:])
    slope, intercept = np.polyfit(log_lambda, log_radial, 1)
    r = float(np.corrcoef(log_lambda, log_radial)[0, 1])
    return float(slope), float(intercept), r


def spectrum_fit(basis: HarmonicBasis, vertices: np.ndarray) -> SpectrumFit:
    """Table 1's statistics of a mesh's coordinates in its harmonic basis."""
    if basis.modes < 3:
        raise ValueError("the spectrum fit needs at least 3 modes")
    radial = radial_spectrum(transform(basis, np.asarray(vertices, dtype=float)))
    slope, intercept, r = fit_power_law(basis.eigenvalues, radial)
    return SpectrumFit(basis.eigenvalues, radial, slope, intercept, r)
