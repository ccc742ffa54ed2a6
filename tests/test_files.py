"""files.check_outputs and the protection of a command's inputs: an output never replaces an
input (same real path, symbolic link, hard link, another spelling), ``--force`` or not; every
output is checked (extension, folder, permissions, existing file) before any work."""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from allorules import files
from allorules.errors import OutputError
from allorules.files import (
    JSON,
    PNG,
    Output,
    atomic_write,
    check_outputs,
    protection_scope,
)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(autouse=True)
def fresh_protection():
    with protection_scope():
        yield


@pytest.fixture
def unwritable_folder(tmp_path):
    """A folder nobody can write into: a chmod 555 folder, or for root (who ignores that) a
    folder of a read-only file system such as /sys."""
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        probe = folder / "probe"
        probe.touch()
        probe.unlink()
    except OSError:
        yield folder
        folder.chmod(0o755)
        return
    folder.chmod(0o755)
    if Path("/sys").is_dir() and _cannot_create_in(Path("/sys")):
        yield Path("/sys")
        return
    pytest.skip("no folder here refuses writes (root on a system without /sys)")


def _cannot_create_in(folder: Path) -> bool:
    try:
        handle, name = tempfile.mkstemp(dir=folder)
    except OSError:
        return True
    os.close(handle)
    os.unlink(name)
    return False


def test_an_output_that_is_an_input_is_refused_even_with_force(tmp_path):
    mesh = tmp_path / "horse.obj"
    mesh.write_text("v 0 0 0\n")
    for force in (False, True):
        with pytest.raises(OutputError, match="input mesh .*never overwritten"):
            check_outputs([Output.of(mesh, "--png")], {"input mesh": mesh}, force=force)


def test_inputs_are_recognised_through_links_and_other_spellings(tmp_path):
    labels = tmp_path / "horse.labels.json"
    labels.write_text("{}")
    hard = tmp_path / "hard.json"
    os.link(labels, hard)
    soft = tmp_path / "soft.json"
    soft.symlink_to(labels)
    (tmp_path / "sub").mkdir()
    spelled = tmp_path / "sub" / ".." / "horse.labels.json"
    for output in (hard, soft, spelled):
        with pytest.raises(OutputError, match="labels file"):
            check_outputs([Output.of(output, "--report", JSON)], {"labels file": labels}, force=True)


def test_every_output_is_checked_before_the_work(tmp_path, unwritable_folder):
    existing = tmp_path / "old.png"
    existing.write_bytes(b"picture")
    cases = [
        (Output.of(existing, "--png", PNG), False, "already exists.*--force"),
        (Output.of(tmp_path / "picture.jpg", "--png", PNG), True, "must end in .png"),
        (Output.of(tmp_path / "report", "--report", JSON), True, r"must end in .json, not \(no extension\)"),
        (Output.of(tmp_path, "-o", (".obj",)), True, "must end in .obj"),
        (Output.of(tmp_path / "folder.obj", "-o", (".obj",)), True, "is a folder"),
        (Output.of(tmp_path / "missing" / "out.obj", "-o", (".obj",)), True, "does not exist"),
        (Output.of(unwritable_folder / "out.obj", "-o", (".obj",)), True, "cannot write into the folder"),
    ]
    (tmp_path / "folder.obj").mkdir()
    for output, force, message in cases:
        with pytest.raises(OutputError, match=message):
            check_outputs([output], force=force)
    assert existing.read_bytes() == b"picture"
    check_outputs([Output.of(existing, "--png", PNG)], force=True)   # replacing an output is what --force is for


def test_a_read_only_file_is_not_replaced(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root may write any file")
    output = tmp_path / "out.png"
    output.write_bytes(b"keep")
    output.chmod(0o444)
    with pytest.raises(OutputError, match="read-only"):
        check_outputs([Output.of(output, "--png", PNG)], force=True)


def test_two_outputs_naming_the_same_file_are_refused(tmp_path):
    with pytest.raises(OutputError, match="--png and --report name the same file"):
        check_outputs([Output.of(tmp_path / "a.png", "--png"), Output.of(tmp_path / "a.png", "--report")])


def test_a_protected_input_is_never_replaced_by_a_later_write(tmp_path):
    """A name a later stage derives (OUT.unconverged.obj, a texture beside the output, a batch
    summary) goes through atomic_path, which refuses a protected input too."""
    manifest = tmp_path / "summary.json"
    manifest.write_text("precious")
    check_outputs([], {"manifest": manifest})
    with pytest.raises(OutputError, match="manifest"):
        atomic_write(manifest, "results")
    assert manifest.read_text() == "precious"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["summary.json"]   # no temporary file left


def test_protection_ends_with_the_command(tmp_path):
    mesh = tmp_path / "horse.obj"
    mesh.write_text("v 0 0 0\n")
    with protection_scope():
        check_outputs([], {"input mesh": mesh})
        assert files.protected_as(mesh) == f"input mesh {mesh}"
    assert files.protected_as(mesh) is None


def test_a_folder_output_must_be_writable(tmp_path, unwritable_folder):
    check_outputs([Output.of(tmp_path / "new" / "deeper", "-o", folder=True)])   # created later: the parent is writable
    with pytest.raises(OutputError, match="cannot create folders"):
        check_outputs([Output.of(unwritable_folder / "results", "-o", folder=True)])
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(OutputError, match="is a file; give a folder"):
        check_outputs([Output.of(afile, "-o", folder=True)])


# ---------------------------------------------------------------------------------------------
# Property: whatever the combination of inputs, outputs, links and --force, no input changes


INPUT_NAMES = ["horse.obj", "horse.labels.json", "merge.yaml", "rules.yaml", "plugin.py"]
# ways an output can name a file: the input itself, through a link, another spelling, a new file
SPELLINGS = ["same", "dot", "parent", "symlink", "hardlink", "new", "existing-output"]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    outputs=st.lists(st.tuples(st.sampled_from(INPUT_NAMES), st.sampled_from(SPELLINGS),
                               st.sampled_from([".png", ".json", ".obj", ""])), min_size=1, max_size=4),
    force=st.booleans(),
)
def test_no_combination_of_outputs_changes_an_input(outputs, force):
    with tempfile.TemporaryDirectory() as folder, protection_scope():
        root = Path(folder)
        (root / "sub").mkdir()
        inputs = {}
        for name in INPUT_NAMES:
            (root / name).write_text(f"the bytes of {name}\n")
            inputs[f"input {name}"] = root / name
        before = {name: sha256(root / name) for name in INPUT_NAMES}
        planned = []
        for index, (name, spelling, extension) in enumerate(outputs):
            target = root / name
            if spelling == "dot":
                path = root / "." / name
            elif spelling == "parent":
                path = root / "sub" / ".." / name
            elif spelling == "symlink":
                path = root / f"link{index}{extension}"
                path.symlink_to(target)
            elif spelling == "hardlink":
                path = root / f"hard{index}{extension}"
                os.link(target, path)
            elif spelling == "existing-output":
                path = root / f"old{index}{extension}"
                path.write_text("an earlier output\n")
            else:
                path = root / (f"new{index}" + extension) if spelling == "new" else target
            planned.append(Output.of(path, f"--out{index}"))
        names_an_input = any(spelling not in ("new", "existing-output") for _, spelling, _ in outputs)
        try:
            check_outputs(planned, inputs, force=force)
            accepted = True
        except OutputError:
            accepted = False
        assert not (accepted and names_an_input), "an output naming an input was accepted"
        # whatever was accepted or not, a stage that writes every output anyway changes no input
        for output in planned:
            try:
                atomic_write(output.path, b"written by the command\n")
            except OutputError:
                pass
        assert {name: sha256(root / name) for name in INPUT_NAMES} == before
