"""The 1-D experiments of the paper (Figures 8, 12, 14; METHOD §8).

The orthonormal DCT-II plays the manifold harmonic basis of a 1-D signal: it is orthonormal, its
k-th basis function is the k-th eigenvector of the 1-D Laplacian with natural (Neumann)
boundaries, and λ_k ∝ k² (we use λ_k = k²; only λ_k/λ_1 enters). The signals are synthetic
power-law noise: DCT coefficients ``x̃_k = g_k · k^(−β)`` with Gaussian ``g_k`` (seeded), i.e. an
*amplitude* spectrum 1/f^β (power spectrum 1/f^(2β)); β = 1 is the paper's "1/f" signal.

They are the cheapest exact checks of the spectral algebra in :mod:`allorules.spectral.power_laws`:

* **global** (Fig. 8): scaling by (λ_k/λ_1)^α adds α·log λ_k − α·log λ_1 to log|x̃_k|, so the
  least-squares slope of log|x̃| against log λ moves by exactly +α (by +2α against log k).
* **local** (Fig. 12/14): the dimensionless local power law (Eq. 6) with an indicator region
  changes the signal mostly inside the region and has no jump at its edges, where arithmetic
  scaling of the region's coefficients (= scaling the region's samples) jumps.

Each experiment returns a small dataclass of numbers (``as_dict()`` for JSON) and can plot a PNG.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.fft import dct, idct

from allorules.files import atomic_path
from allorules.spectral.power_laws import (
    arithmetic_region_scaling,
    dimensionless,
    edited_coefficients,
    global_allometric,
    local_power_law,
)

__all__ = [
    "dct_eigenvalues",
    "power_law_signal",
    "SpectralFit",
    "spectral_fit",
    "GlobalExperiment",
    "global_experiment",
    "LocalExperiment",
    "local_experiment",
    "plot_global",
    "plot_local",
]


def dct_eigenvalues(length: int) -> np.ndarray:
    """λ_k = k² for k = 0 … length−1: the 1-D Laplacian's spectrum up to a constant factor."""
    return np.arange(length, dtype=float) ** 2


def power_law_signal(length: int = 1024, beta: float = 1.0, seed: int = 0) -> np.ndarray:
    """Seeded noise with amplitude spectrum 1/f^β: x = IDCT(g_k k^(−β)), zero mean, unit std."""
    if length < 8:
        raise ValueError("length must be at least 8")
    rng = np.random.default_rng(seed)
    k = np.arange(length, dtype=float)
    coefficients = np.zeros(length)
    coefficients[1:] = rng.normal(size=length - 1) * k[1:] ** (-beta)
    signal = idct(coefficients, norm="ortho")
    return signal / signal.std()


@dataclass(frozen=True)
class SpectralFit:
    """Least-squares line log|x̃_k| = slope · log λ_k + intercept over k ≥ 1, and Pearson's R."""

    slope: float
    intercept: float
    pearson: float


def spectral_fit(coefficients: np.ndarray, eigenvalues: np.ndarray) -> SpectralFit:
    """Fit of the log-log spectrum over k ≥ 1 (λ_0 = 0 excluded), like Table 1 of the paper."""
    magnitude = np.abs(np.asarray(coefficients, dtype=float))
    if magnitude.ndim == 2:      # radial spectrum of (m, 3) coefficients
        magnitude = np.linalg.norm(magnitude, axis=1)
    magnitude, eigenvalues = magnitude[1:], np.asarray(eigenvalues, dtype=float)[1:]
    keep = (magnitude > 0) & (eigenvalues > 0)
    log_lambda, log_magnitude = np.log(eigenvalues[keep]), np.log(magnitude[keep])
    slope, intercept = np.polyfit(log_lambda, log_magnitude, 1)
    pearson = float(np.corrcoef(log_lambda, log_magnitude)[0, 1])
    return SpectralFit(float(slope), float(intercept), pearson)


@dataclass
class GlobalExperiment:
    """Figure 8: a power-law signal before and after global allometric scaling (Eq. 4)."""

    alpha: float
    before: SpectralFit                 # fit of the input signal's spectrum
    after: SpectralFit                  # fit of the spectrum of the scaled *signal* (re-transformed)
    signal: np.ndarray = field(repr=False)
    scaled: np.ndarray = field(repr=False)

    @property
    def slope_change(self) -> float:
        return self.after.slope - self.before.slope

    @property
    def predicted_slope_change(self) -> float:
        """With λ_k ∝ k²: log(|x̃_k| (λ_k/λ_1)^α) = log|x̃_k| + α log λ_k − α log λ_1 ⇒ Δslope = α."""
        return self.alpha

    def as_dict(self) -> dict:
        return {
            "experiment": "global",
            "alpha": self.alpha,
            "slope_before": self.before.slope,
            "slope_after": self.after.slope,
            "slope_change": self.slope_change,
            "predicted_slope_change": self.predicted_slope_change,
            "pearson_before": self.before.pearson,
            "pearson_after": self.after.pearson,
            "length": len(self.signal),
        }


def global_experiment(alpha: float = 1.8, *, length: int = 1024, beta: float = 1.0, seed: int = 0) -> GlobalExperiment:
    """Scale a 1/f^β signal globally (Eq. 4 with s = 1; α = 1.8 as in the paper's Figure 8)."""
    eigenvalues = dct_eigenvalues(length)
    signal = power_law_signal(length, beta, seed)
    coefficients = dct(signal, norm="ortho")
    scaled = idct(global_allometric(coefficients, eigenvalues, alpha, 1.0), norm="ortho")
    return GlobalExperiment(
        alpha=float(alpha),
        before=spectral_fit(coefficients, eigenvalues),
        after=spectral_fit(dct(scaled, norm="ortho"), eigenvalues),
        signal=signal,
        scaled=scaled,
    )


@dataclass(frozen=True)
class EditMeasures:
    """How an edit δ = x' − x of a 1-D signal is spread relative to the region [start, stop)."""

    change_inside: float     # RMS of δ inside the region
    change_outside: float    # RMS of δ outside
    edge_jump: float         # largest |δ[e] − δ[e−1]| at the region's two edges
    typical_step: float      # median |δ[k] − δ[k−1]| over the whole signal, for scale

    @classmethod
    def of(cls, change: np.ndarray, start: int, stop: int) -> "EditMeasures":
        inside = np.zeros(len(change), dtype=bool)
        inside[start:stop] = True
        edges = [e for e in (start, stop) if 0 < e < len(change)]
        return cls(
            change_inside=float(np.sqrt(np.mean(change[inside] ** 2))),
            change_outside=float(np.sqrt(np.mean(change[~inside] ** 2))),
            edge_jump=float(max(abs(change[e] - change[e - 1]) for e in edges)),
            typical_step=float(np.median(np.abs(np.diff(change)))),
        )


@dataclass
class LocalExperiment:
    """Figures 12/14: local power law (Eq. 6) vs arithmetic scaling of an indicator region.

    The arithmetic factor is chosen so that both edits change the region by the same RMS amount
    (and in the same direction: shrink for α > 0), so their edge jumps compare fairly.
    """

    alpha: float
    arithmetic_factor: float
    start: int
    stop: int
    power_law: EditMeasures
    arithmetic: EditMeasures
    signal: np.ndarray = field(repr=False)
    power_law_signal: np.ndarray = field(repr=False)
    arithmetic_signal: np.ndarray = field(repr=False)

    @property
    def inside_outside_ratio(self) -> float:
        return self.power_law.change_inside / self.power_law.change_outside

    @property
    def jump_ratio(self) -> float:
        """Arithmetic edge jump over power-law edge jump (same RMS change inside)."""
        return self.arithmetic.edge_jump / self.power_law.edge_jump

    def as_dict(self) -> dict:
        return {
            "experiment": "local",
            "alpha": self.alpha,
            "region": [self.start, self.stop],
            "length": len(self.signal),
            "arithmetic_factor": self.arithmetic_factor,
            "power_law": vars(self.power_law),
            "arithmetic": vars(self.arithmetic),
            "inside_outside_ratio": self.inside_outside_ratio,
            "jump_ratio": self.jump_ratio,
        }


def local_experiment(
    alpha: float = 0.5,
    *,
    length: int = 1024,
    beta: float = 1.0,
    region: tuple[float, float] = (0.4, 0.6),
    seed: int = 0,
) -> LocalExperiment:
    """Scale the samples in ``region`` (fractions of the length) of a 1/f^β signal locally."""
    start, stop = int(round(region[0] * length)), int(round(region[1] * length))
    if not 0 < start < stop < length:
        raise ValueError(f"region {region} must lie strictly inside (0, 1) and be non-empty")
    signal = power_law_signal(length, beta, seed)
    indicator = np.zeros(length)
    indicator[start:stop] = 1.0
    coefficients = dct(signal, norm="ortho")
    region_coefficients = dct(indicator * signal, norm="ortho")     # Eq. 5 in 1-D
    u, c = dimensionless(coefficients)
    u_region = region_coefficients / c                                # same c (METHOD §5)
    new = edited_coefficients(coefficients, u, local_power_law(u, u_region, alpha), c)
    power_law_result = idct(new, norm="ortho")
    power_law_measures = EditMeasures.of(power_law_result - signal, start, stop)
    # Arithmetic factor with the same RMS change inside: δ = (f − 1)·x on the region.
    region_rms = float(np.sqrt(np.mean(signal[start:stop] ** 2)))
    factor = 1.0 - np.sign(alpha) * power_law_measures.change_inside / region_rms
    arithmetic_result = idct(arithmetic_region_scaling(coefficients, region_coefficients, factor), norm="ortho")
    return LocalExperiment(
        alpha=float(alpha),
        arithmetic_factor=float(factor),
        start=start,
        stop=stop,
        power_law=power_law_measures,
        arithmetic=EditMeasures.of(arithmetic_result - signal, start, stop),
        signal=signal,
        power_law_signal=power_law_result,
        arithmetic_signal=arithmetic_result,
    )


def _save_figure_atomically(figure, path: str | os.PathLike) -> Path:
    path = Path(path)
    with atomic_path(path) as temporary:
        figure.savefig(temporary, format="png", dpi=110)
    return path


def plot_global(result: GlobalExperiment, path: str | os.PathLike) -> Path:
    """Figure 8 as a PNG: the signals (top) and their log-log spectra with fitted lines (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eigenvalues = dct_eigenvalues(len(result.signal))
    figure, axes = plt.subplots(2, 2, figsize=(10, 6))
    for column, (name, values, fit) in enumerate(
        [("input f", result.signal, result.before), (f"scaled g, α = {result.alpha:g}", result.scaled, result.after)]
    ):
        axes[0, column].plot(values, lw=0.7)
        axes[0, column].set_title(name)
        spectrum = np.abs(dct(values, norm="ortho"))[1:]
        axes[1, column].loglog(eigenvalues[1:], spectrum, ".", ms=2)
        axes[1, column].loglog(eigenvalues[1:], np.exp(fit.intercept) * eigenvalues[1:] ** fit.slope, "r-")
        axes[1, column].set_title(f"slope {fit.slope:.4f}, R {fit.pearson:.3f}")
        axes[1, column].set_xlabel("λ_k = k²")
    figure.tight_layout()
    try:
        return _save_figure_atomically(figure, path)
    finally:
        plt.close(figure)


def plot_local(result: LocalExperiment, path: str | os.PathLike) -> Path:
    """Figures 12/14 as a PNG: input, power-law and arithmetic results, region shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for axis in axes:
        axis.axvspan(result.start, result.stop, color="tab:green", alpha=0.15, label="region")
    axes[0].plot(result.signal, lw=0.7, color="gray", label="input")
    axes[0].plot(result.power_law_signal, lw=0.7, label=f"power law α = {result.alpha:g}")
    axes[0].plot(result.arithmetic_signal, lw=0.7, label=f"arithmetic ×{result.arithmetic_factor:.3f}")
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].plot(result.power_law_signal - result.signal, lw=0.7, label="power-law change")
    axes[1].plot(result.arithmetic_signal - result.signal, lw=0.7, label="arithmetic change")
    axes[1].legend(loc="upper right", fontsize=8)
    axes[1].set_title(f"edge jump: power law {result.power_law.edge_jump:.3g}, arithmetic {result.arithmetic.edge_jump:.3g}")
    figure.tight_layout()
    try:
        return _save_figure_atomically(figure, path)
    finally:
        plt.close(figure)
