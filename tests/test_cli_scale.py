"""``allorules scale`` as users run it: outputs in the input's layout, --png, never the input."""
from __future__ import annotations

import numpy as np
import trimesh

from allorules.cli import main


def test_scale_writes_mesh_report_and_before_after_picture(tmp_path):
    source = tmp_path / "bone.obj"
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[16, 16]).export(source)
    before = source.read_bytes()
    output, picture, report = tmp_path / "thick.obj", tmp_path / "thick.png", tmp_path / "thick.json"
    code = main(["scale", str(source), "--global", "--alpha", "0.05", "--modes", "40", "-o", str(output),
                 "--png", str(picture), "--report", str(report)])
    assert code == 0
    assert source.read_bytes() == before                      # the input is untouched
    loaded = trimesh.load(output, process=False)
    original = trimesh.load(source, process=False)
    assert np.array_equal(loaded.faces, original.faces)       # connectivity kept
    assert np.all(np.isfinite(loaded.vertices)) and not np.allclose(loaded.vertices, original.vertices)
    assert picture.stat().st_size > 5_000 and report.exists()


def test_scale_refuses_to_write_over_its_input(tmp_path, capsys):
    source = tmp_path / "bone.obj"
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[16, 16]).export(source)
    before = source.read_bytes()
    assert main(["scale", str(source), "--global", "--alpha", "0.05", "--modes", "40", "-o", str(source)]) != 0
    assert "input" in capsys.readouterr().err
    assert source.read_bytes() == before
