"""The command line under hostile conditions and as a new user meets it (issue 19): a closed pipe,
an unexpected failure, a plugin that exits mid-run; help that answers at once and names docs a
user can find."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from allorules.cli import COMMANDS, main

CLI = [sys.executable, "-c", "import sys; from allorules.cli import main; sys.exit(main(sys.argv[1:]))"]


def help_of(command: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as exited:
        main([*command, "--help"])
    assert exited.value.code == 0
    return capsys.readouterr().out


def test_the_top_level_help_lists_every_command_and_only_real_ones(capsys):
    text = help_of([], capsys)
    for name in COMMANDS:
        assert f"    {name}" in text
    assert "describe" not in text   # 'ruleset describe' does not exist


@pytest.mark.parametrize("command", [[name] for name in COMMANDS] + [["ruleset", "show"], ["ruleset", "check"]])
def test_help_names_docs_pages_not_paper_equations(command, capsys):
    text = help_of(command, capsys)
    for citation in ("Eq.", "Table 1", "METHOD", "Figure", "§"):
        assert citation not in text, f"'{' '.join(command)} --help' cites {citation!r}, which a user cannot look up"


def test_help_imports_no_numerical_library():
    """'allorules --help' and every 'allorules COMMAND --help' import only the command line."""
    script = (
        "import sys\n"
        "from allorules.cli import COMMANDS, main\n"
        "heavy = ('numpy', 'scipy', 'trimesh', 'matplotlib', 'pluggy', 'jsonschema', 'yaml')\n"
        "for command in [[]] + [[name] for name in COMMANDS]:\n"
        "    try:\n"
        "        main(command + ['--help'])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "    loaded = sorted({m.split('.')[0] for m in sys.modules} & set(heavy))\n"
        "    print(' '.join(command) or '-', ','.join(loaded), file=sys.stderr)\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    lines = [line.partition(" ")[::2] for line in result.stderr.strip().splitlines()]
    assert len(lines) == len(COMMANDS) + 1, result.stderr
    assert all(loaded.strip() == "" for _, loaded in lines), result.stderr


@pytest.mark.parametrize("command", [["ruleset", "show", "quadruped"], ["ruleset", "schema"], ["rulesets"], ["--help"]])
def test_a_closed_pipe_ends_quietly(command):
    """'allorules ruleset show quadruped | true': the reader is gone before anything is written."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run([*CLI, *command], stdout=write_end, stderr=subprocess.PIPE, timeout=120)
    finally:
        os.close(write_end)
    assert result.stderr == b""
    assert result.returncode in (0, 141)


def test_an_unexpected_failure_is_one_line_and_debug_shows_it(monkeypatch, capsys):
    from allorules.rules import schema

    def broken():
        raise TypeError("unsupported operand\nsecond line")

    monkeypatch.setattr(schema, "ruleset_schema", broken)
    assert main(["ruleset", "schema"]) == 70
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "TypeError: unsupported operand" in error and "--debug" in error
    with pytest.raises(TypeError):
        main(["--debug", "ruleset", "schema"])


def test_a_file_system_failure_is_one_line(monkeypatch, capsys):
    from allorules.rules import schema

    def unreadable():
        raise PermissionError(13, "Permission denied", "/somewhere/schema.json")

    monkeypatch.setattr(schema, "ruleset_schema", unreadable)
    assert main(["ruleset", "schema"]) == 1
    error = capsys.readouterr().err.strip()
    assert error == "allorules ruleset: error: cannot use /somewhere/schema.json: Permission denied"


def test_plugin_with_global_scaling_says_it_is_not_used(tmp_path, monkeypatch, capsys):
    import trimesh

    from allorules.errors import AllorulesError
    from allorules.runs import pipeline

    mesh = tmp_path / "bone.obj"
    trimesh.creation.capsule(height=3.0, radius=0.4, count=[12, 12]).export(mesh)
    plugin = tmp_path / "extra.py"
    plugin.write_text("from allorules.plugins import MeasureSpec, hookimpl\n\n\n@hookimpl\ndef allorules_measures():\n"
                      "    return [MeasureSpec(name='one', kind='length', isometric_exponent=1 / 3, "
                      "compute=lambda body, region: 1.0, description='one')]\n")

    def stop(*args, **kwargs):
        raise AllorulesError("stopped before the work")

    monkeypatch.setattr(pipeline, "run", stop)
    main(["scale", str(mesh), "--global", "--mass-ratio", "2", "-o", str(tmp_path / "out.obj"), "--plugin", str(plugin)])
    assert "--plugin: not used by global scaling" in capsys.readouterr().err


@pytest.mark.slow
def test_a_plugin_that_exits_mid_run_is_named_and_progress_was_shown(tmp_path):
    """A measure that calls sys.exit after a few trials, inside the solver of a real run: one line
    naming the plugin, a non-zero status that is not the plugin's; the run's progress lines came
    before it although stderr is not a terminal."""
    from allorules.mesh.quadruped import generate_quadruped

    animal = generate_quadruped("horse", 1000)
    mesh, labels = tmp_path / "horse.obj", tmp_path / "horse.labels.json"
    subprocess.run([*CLI, "generate", "-o", str(mesh), "--vertices", "1000", "--labels", str(labels)], check=True,
                   capture_output=True, timeout=300)
    assert json.loads(labels.read_text())["regions"] == list(animal.region_names)
    (tmp_path / "quits.py").write_text(
        "import sys\nfrom allorules.plugins import MeasureSpec, hookimpl\ncalls = [0]\n\n\n"
        "def quits(body, region):\n    calls[0] += 1\n    if calls[0] > 8:\n        sys.exit(7)\n"
        "    return 1.0 + 0.001 * calls[0]\n\n\n@hookimpl\ndef allorules_measures():\n"
        "    return [MeasureSpec(name='quits', kind='length', isometric_exponent=1 / 3, compute=quits,\n"
        "                        description='quits')]\n")
    (tmp_path / "rules.yaml").write_text("extends: quadruped\nname: quitting\nplugins: [quits.py]\nrules:\n"
                                         "  - {id: odd, region: head, measure: quits, exponent: 0.3}\n")
    result = subprocess.run([*CLI, "scale", str(mesh), "--segmentation", str(labels), "--ruleset",
                             str(tmp_path / "rules.yaml"), "--mass-ratio", "1.5", "--modes", "16", "-o",
                             str(tmp_path / "out.obj")], capture_output=True, text=True, timeout=600)
    assert result.returncode not in (0, 7)
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("allorules scale: error: plugin 'quits', measure 'quits', called sys.exit(7)")
    assert "scaling steps: step 1/" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "out.obj").exists()


def test_sigterm_mid_write_leaves_no_partial_file(tmp_path, monkeypatch, capsys):
    """kill PID while a picture is being written: the command says 'terminated' (status 143),
    the temporary file is removed and no half-written output appears."""
    import signal

    from allorules import files

    real_replace = files.os.replace

    def killed_before_the_rename(source, target):
        os.kill(os.getpid(), signal.SIGTERM)
        real_replace(source, target)

    monkeypatch.setattr(files.os, "replace", killed_before_the_rename)
    previous = signal.getsignal(signal.SIGTERM)
    assert main(["experiment", "global", "--length", "64", "--png", str(tmp_path / "plot.png")]) == 143
    assert capsys.readouterr().err.strip().endswith("allorules experiment: terminated")
    assert list(tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is previous   # the handler is the command's only
