"""The 1-D experiments: exact slope change (Fig. 8) and local vs arithmetic scaling (Fig. 12/14)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.fft import dct

from allorules.cli import main
from allorules.spectral.experiments import (
    dct_eigenvalues,
    global_experiment,
    local_experiment,
    plot_global,
    plot_local,
    power_law_signal,
    spectral_fit,
)
from allorules.spectral.power_laws import global_allometric


def test_signal_has_the_requested_power_law():
    signal = power_law_signal(2048, beta=1.0, seed=3)
    fit = spectral_fit(dct(signal, norm="ortho"), dct_eigenvalues(2048))
    # amplitude ∝ k^-1 = λ^-1/2 (with random Gaussian amplitudes around it)
    assert fit.slope == pytest.approx(-0.5, abs=0.03)
    assert fit.pearson < -0.5


@pytest.mark.parametrize("alpha", [0.1, 0.5, -0.5, 1.8])
def test_global_scaling_moves_the_slope_by_exactly_alpha(alpha):
    # The power law on the coefficients moves the fitted slope by exactly α (to round-off).
    eigenvalues = dct_eigenvalues(1024)
    coefficients = dct(power_law_signal(1024, seed=0), norm="ortho")
    scaled = global_allometric(coefficients, eigenvalues, alpha, 1.0)
    change = spectral_fit(scaled, eigenvalues).slope - spectral_fit(coefficients, eigenvalues).slope
    assert change == pytest.approx(alpha, abs=1e-12)
    # Through the signal and back (IDCT, DCT) the smallest coefficients carry the round-off of the
    # largest: at α = 1.8 they span (1023²)^1.8 ≈ 1e11, so the finest modes are off by ~1e-5
    # relative, which the fit averages down to ~2e-10 on the slope (numpy 2.4 / scipy 1.17).
    result = global_experiment(alpha, seed=0)
    assert result.slope_change == pytest.approx(alpha, abs=1e-9)
    assert result.predicted_slope_change == alpha


def test_global_scaling_keeps_mean_and_mode_one():
    result = global_experiment(0.7, seed=1)
    before, after = dct(result.signal, norm="ortho"), dct(result.scaled, norm="ortho")
    assert after[0] == pytest.approx(before[0], abs=1e-12)
    assert after[1] == pytest.approx(before[1], rel=1e-10)      # (λ_1/λ_1)^α = 1
    assert after[10] == pytest.approx(before[10] * 100 ** 0.7, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("alpha", [0.5, -0.5])
def test_local_power_law_changes_inside_more_and_does_not_jump(seed, alpha):
    result = local_experiment(alpha, seed=seed)
    pl, ar = result.power_law, result.arithmetic
    # same amount of change inside, by construction of the arithmetic factor
    assert ar.change_inside == pytest.approx(pl.change_inside, rel=1e-9)
    assert (result.arithmetic_factor < 1) == (alpha > 0)
    # the power law acts mostly inside the region
    assert pl.change_inside > 1.4 * pl.change_outside
    # arithmetic scaling tears the edge; the power law's jump is a clear factor smaller
    assert result.jump_ratio > 4.0
    assert ar.change_outside < 1e-12


def test_local_experiment_direction_of_alpha():
    """α > 0 shrinks the region's shared coefficients (|u| ≤ 1): the signal's spread inside drops."""
    shrink, grow = local_experiment(0.5), local_experiment(-0.5)
    region = slice(shrink.start, shrink.stop)
    assert np.std(shrink.power_law_signal[region]) < np.std(shrink.signal[region])
    assert np.std(grow.power_law_signal[region]) > np.std(grow.signal[region])


def test_local_experiment_refuses_bad_region():
    with pytest.raises(ValueError, match="region"):
        local_experiment(0.5, region=(0.6, 0.4))


def test_plots_are_written(tmp_path):
    assert plot_global(global_experiment(0.5, length=256), tmp_path / "g.png").stat().st_size > 1000
    assert plot_local(local_experiment(0.5, length=256), tmp_path / "l.png").stat().st_size > 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.png", "l.png"]     # no temp files left


def test_cli_experiment_json(capsys, tmp_path):
    assert main(["experiment", "global", "--alpha", "0.3", "--json", "--png", str(tmp_path / "g.png")]) == 0
    numbers = json.loads(capsys.readouterr().out)
    assert numbers["slope_change"] == pytest.approx(0.3, abs=1e-10)
    assert (tmp_path / "g.png").exists()
    assert main(["experiment", "local", "--json"]) == 0
    numbers = json.loads(capsys.readouterr().out)
    assert numbers["jump_ratio"] > 4


def test_cli_experiment_errors(capsys):
    assert main(["experiment", "local", "--alpha", "0"]) == 2
    assert "alpha" in capsys.readouterr().err
