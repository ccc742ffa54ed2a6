"""Table 1 statistics: invariant to units and orientation; the spectrum command as users run it."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from allorules.cli import main
from allorules.spectral.basis import compute_basis
from allorules.spectral.spectrum import fit_power_law, spectrum_fit


def test_fit_recovers_a_known_power_law():
    eigenvalues = np.r_[0.0, np.linspace(1.0, 500.0, 300)]
    radial = np.r_[10.0, 3.0 * eigenvalues[1:] ** -1.25]
    slope, intercept, r = fit_power_law(eigenvalues, radial)
    assert slope == pytest.approx(-1.25, abs=1e-12)
    assert intercept == pytest.approx(np.log(3.0), abs=1e-12)
    assert r == pytest.approx(-1.0, abs=1e-12)


def test_slope_and_r_unchanged_by_scale_and_rotation():
    # A lumpy capsule: without symmetry, every eigenvalue is simple and r̃_i is well defined.
    mesh = trimesh.creation.capsule(height=2.0, radius=0.4, count=[20, 20])
    rng = np.random.default_rng(3)
    bumps = 1.0 + 0.08 * np.sin(3.0 * mesh.vertices[:, [2]] + rng.random()) * np.cos(2.0 * mesh.vertices[:, [0]] + 1.0)
    vertices = mesh.vertices * bumps * [1.0, 0.8, 1.0] + [0.3, -0.2, 0.1]
    reference = spectrum_fit(compute_basis(vertices, mesh.faces, 120, use_cache=False), vertices)
    rotation = Rotation.from_euler("xyz", [0.4, 1.1, -0.7]).as_matrix()
    for transformed in (vertices * 1000.0, vertices @ rotation.T, vertices * 0.001 @ rotation.T):
        fit = spectrum_fit(compute_basis(transformed, mesh.faces, 120, use_cache=False), transformed)
        assert fit.slope == pytest.approx(reference.slope, abs=1e-6)
        assert fit.r == pytest.approx(reference.r, abs=1e-6)


def test_spectrum_command_prints_json(tmp_path, capsys):
    path = tmp_path / "capsule.ply"
    trimesh.creation.capsule(height=2.0, radius=0.4, count=[16, 16]).export(path)
    plot = tmp_path / "spectrum.png"
    assert main(["spectrum", str(path), "--modes", "60", "--json", "--plot", str(plot)]) == 0
    assert plot.stat().st_size > 10_000
    result = json.loads(capsys.readouterr().out)
    assert {"vertices", "modes", "slope", "r"} <= result.keys()
    assert result["modes"] == 60
    assert -1.0 <= result["r"] <= 0.0


@pytest.mark.parametrize("content, suffix, message", [
    (b"", ".obj", "empty"),
    (b"not a mesh", ".xyz", "unsupported format"),
])
def test_spectrum_command_refuses_bad_input_in_one_line(tmp_path, capsys, content, suffix, message):
    path = tmp_path / f"bad{suffix}"
    path.write_bytes(content)
    assert main(["spectrum", str(path)]) != 0
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in captured.err


@pytest.mark.slow
@pytest.mark.shared_meshes
@pytest.mark.parametrize("name", ["lion", "camel"])
def test_real_meshes_give_a_power_law_spectrum(shared_meshes, name, capsys):
    assert main(["spectrum", str(shared_meshes / f"{name}.obj"), "--modes", "300", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    # Table 1: natural meshes have slopes around −1.1 … −1.4 and R well below −0.5.
    assert -1.6 < result["slope"] < -0.9
    assert result["r"] < -0.8
