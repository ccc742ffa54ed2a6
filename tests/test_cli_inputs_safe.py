"""No command ever loses a user's file (issue 19): every input of a command is protected from
every output of it, --force or not, and outputs that cannot be written are refused before any
work. Each case compares the SHA-256 of every input before and after."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import trimesh

from allorules.cli import main


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


PLUGIN = """
from allorules.plugins import MeasureSpec, hookimpl


@hookimpl
def allorules_measures():
    return [MeasureSpec(name="one", kind="length", isometric_exponent=1 / 3, compute=lambda body, region: 1.0,
                        description="one")]
"""


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """A folder with a small mesh, a labels file, a merge file, a ruleset and a picture; the
    pipeline's work is replaced by a failure, so a test sees any command that starts working
    before it has checked its outputs."""
    monkeypatch.chdir(tmp_path)
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[12, 12]).export(tmp_path / "bone.obj")
    (tmp_path / "bone.labels.json").write_text(json.dumps({"regions": ["head"], "labels": [0]}))
    (tmp_path / "merge.yaml").write_text("head: [0]\n")
    (tmp_path / "rules.yaml").write_text("extends: quadruped\nname: mine\n")
    (tmp_path / "old.png").write_bytes(b"\x89PNG an earlier picture")
    (tmp_path / "plugin.py").write_text(PLUGIN)
    return tmp_path


@pytest.fixture
def no_work(monkeypatch):
    def started(*args, **kwargs):
        raise AssertionError("the work started before the outputs were checked")

    import allorules.api as api  # imported first, so that it keeps the real pipeline.run
    import allorules.mesh.repair as repair
    import allorules.runs.pipeline as pipeline

    monkeypatch.setattr(pipeline, "run", started)
    monkeypatch.setattr(api, "run", started)
    monkeypatch.setattr(pipeline, "prepare", started)
    monkeypatch.setattr(repair, "prepare_mesh", started)


def hashes(folder: Path) -> dict[str, str]:
    return {path.name: sha256(path) for path in sorted(folder.iterdir()) if path.is_file()}


CASES = [
    # (command line, what the one-line error must say)
    (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "out.obj", "--png", "bone.obj"], "input mesh"),
    (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "out.obj", "--png", "bone.obj", "--force"], "input mesh"),
    (["spectrum", "bone.obj", "--plot", "bone.obj"], "input mesh"),
    (["spectrum", "bone.obj", "--png", "bone.obj", "--force"], "input mesh"),
    (["spectrum", "bone.obj", "--plot", "old.png"], "already exists"),
    (["spectrum", "bone.obj", "--png", "rules.yaml"], "must end in .png"),
    (["scale", "bone.obj", "--global", "--mass-ratio", "2", "-o", "out.obj", "--segmentation", "bone.labels.json",
      "--report", "bone.labels.json", "--force"], "labels file"),
    (["scale", "bone.obj", "--ruleset", "rules.yaml", "--mass-ratio", "2", "-o", "rules.yaml", "--force"], "ruleset"),
    (["scale", "bone.obj", "--ruleset", "rules.yaml", "--mass-ratio", "2", "-o", "out.obj", "--report",
      "./sub/../rules.yaml", "--force"], "ruleset"),
    (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "out.obj", "--png", "old.png"], "already exists"),
    (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "out.obj", "--plugin", "plugin.py",
      "--report", "plugin.py", "--force"], "plugin"),
    (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "out.xyz"], "must end in .obj"),
    (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "missing/out.obj"], "does not exist"),
    (["segment", "bone.obj", "--patches", "4", "--merge", "merge.yaml", "-o", "merge.yaml", "--force"], "merge file"),
    (["segment", "bone.obj", "-o", "bone.obj", "--force"], "input mesh"),
    (["segment", "bone.obj", "--png", "old.png"], "already exists"),
    (["measure", "bone.obj", "--segmentation", "bone.labels.json", "--png", "bone.labels.json", "--force"],
     "labels file"),
    (["measure", "bone.obj", "--png", "old.png"], "already exists"),
    (["experiment", "global", "--png", "old.png"], "already exists"),
    (["experiment", "global", "--png", "plot.jpg"], "must end in .png"),
    (["generate", "-o", "g.obj", "--labels", "g.json", "--truth", "g.json"], "name the same file"),
    (["generate", "-o", "bone.obj"], "already exists"),
]


@pytest.mark.parametrize("command, message", CASES, ids=[" ".join(case[0]) for case in CASES])
def test_no_command_writes_over_an_input_or_an_unforced_output(folder, no_work, capsys, command, message):
    (folder / "sub").mkdir()
    before = hashes(folder)
    code = main(command)
    error = capsys.readouterr().err
    assert code != 0
    assert message in error
    lines = [line for line in error.strip().splitlines() if not line.startswith("note: --plot is deprecated")]
    assert len(lines) == 1 and "Traceback" not in error
    assert hashes(folder) == before                       # nothing changed, nothing added
    assert sorted(path.name for path in folder.iterdir()) == sorted([*before, "sub"])


def test_an_unwritable_folder_is_refused_before_the_work(folder, no_work, capsys):
    import os
    import tempfile

    try:   # root writes anywhere but in a read-only file system such as /sys
        os.close(tempfile.mkstemp(dir="/sys")[0])
        pytest.skip("/sys is writable here")
    except OSError:
        pass
    before = hashes(folder)
    for command in (["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "/sys/out.obj"],
                    ["scale", "bone.obj", "--global", "--alpha", "0.1", "-o", "out.obj", "--report", "/sys/r.json"],
                    ["spectrum", "bone.obj", "--png", "/sys/s.png"],
                    ["demo", "-o", "/sys/demo"]):
        assert main(command) != 0
        error = capsys.readouterr().err
        assert "cannot" in error and "/sys" in error and len(error.strip().splitlines()) == 1
    assert hashes(folder) == before


def test_a_batch_never_writes_its_summary_over_the_manifest(folder, capsys):
    manifest = folder / "summary.md"   # the name of a summary file, in the output folder
    manifest.write_text("output: .\nmeshes: [bone.obj]\nratios: [2]\nrulesets: [global]\n")
    before = hashes(folder)
    assert main(["batch", str(manifest)]) != 0
    error = capsys.readouterr().err
    assert "manifest" in error and "never overwritten" in error
    assert hashes(folder) == before


def test_spectrum_keeps_the_old_plot_spelling_with_a_note(folder, capsys):
    code = main(["spectrum", "bone.obj", "--modes", "20", "--plot", "spectrum.png"])
    assert code == 0 and (folder / "spectrum.png").stat().st_size > 1000
    assert "--plot is deprecated" in capsys.readouterr().err


def test_the_python_api_protects_its_inputs_too(folder, no_work):
    from allorules.api import OutputError, scale_mesh

    before = hashes(folder)
    for output, overwrite, message in (("bone.obj", True, "input mesh .*not even with overwrite=True"),
                                       ("old.png", False, "must end in .obj"),
                                       ("bone.labels.json", True, "labels file")):
        with pytest.raises(OutputError, match=message):
            scale_mesh(folder / "bone.obj", 2.0, ruleset=None, output=folder / output, overwrite=overwrite,
                       labels=folder / "bone.labels.json")
    assert hashes(folder) == before
