"""The basis cache (issues 16 and 19): verified on load (finite values, positive mass, shapes),
a bad entry recomputed with a notice and never a traceback, a size limit with least-recently-used
eviction, leftovers of killed writes cleaned, and ``allorules cache``."""
from __future__ import annotations

import logging
import os
import time

import numpy as np
import pytest
import trimesh

from allorules.cli import main
from allorules.spectral import cache
from allorules.spectral.basis import compute_basis


@pytest.fixture
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture
def cache_folder(tmp_path, monkeypatch):
    folder = tmp_path / "bases"
    monkeypatch.setenv("ALLORULES_CACHE_DIR", str(folder))
    monkeypatch.delenv("ALLORULES_CACHE_MAX", raising=False)
    return folder


def forge(path, key, eigenvalues, vectors, mass):
    """An entry with a valid checksum (as a careless tool or an attacker could write one)."""
    np.savez(path, key=key, checksum=cache._checksum(eigenvalues, vectors, mass), eigenvalues=eigenvalues,
             vectors=vectors, mass=mass)


MODES = 20


@pytest.fixture
def reference(sphere, cache_folder):
    """The true basis, and the entry's path, key and arrays as stored."""
    vertices, faces = sphere
    truth = compute_basis(vertices, faces, MODES, use_cache=False)
    key = cache.basis_key(vertices, faces, MODES)
    return truth, cache_folder / f"{key}.npz", key


def bad_entries(truth):
    eigenvalues, vectors, mass = truth.eigenvalues.copy(), truth.vectors.copy(), truth.mass.copy()
    nan_eigenvalues = eigenvalues.copy()
    nan_eigenvalues[3] = np.nan
    return {
        "NaN eigenvalues": (nan_eigenvalues, vectors, mass, "not finite"),
        "zero mass": (eigenvalues, vectors, np.zeros_like(mass), "mass is not positive"),
        "negative mass": (eigenvalues, vectors, -mass, "mass is not positive"),
        "infinite vectors": (eigenvalues, np.where(vectors > 0, np.inf, vectors), mass, "not finite"),
        "wrong shapes": (eigenvalues[:-1], vectors[:, :-1], mass, "wrong shapes"),
    }


@pytest.mark.parametrize("case", ["NaN eigenvalues", "zero mass", "negative mass", "infinite vectors", "wrong shapes"])
def test_a_forged_entry_is_recomputed_with_a_notice(sphere, reference, caplog, case):
    truth, path, key = reference
    eigenvalues, vectors, mass, said = bad_entries(truth)[case]
    path.parent.mkdir(parents=True)
    forge(path, key, eigenvalues, vectors, mass)
    with caplog.at_level(logging.WARNING, logger="allorules"):
        basis = compute_basis(*sphere, MODES)
    assert np.allclose(basis.eigenvalues, truth.eigenvalues) and np.all(basis.mass > 0)
    assert any(said in record.getMessage() and "recomputing" in record.getMessage() for record in caplog.records)
    assert cache.load(key, len(sphere[0]), MODES) is not None   # the recomputed basis replaced it


def test_a_folder_in_place_of_an_entry_is_not_a_traceback(sphere, reference, caplog):
    truth, path, key = reference
    path.mkdir(parents=True)
    (path / "something").write_text("not ours")
    with caplog.at_level(logging.WARNING, logger="allorules"):
        basis = compute_basis(*sphere, MODES)
    assert np.allclose(basis.eigenvalues, truth.eigenvalues)
    assert any("is a folder" in record.getMessage() for record in caplog.records)
    assert (path / "something").read_text() == "not ours"   # a folder with files is not ours to delete


def test_a_corrupt_entry_in_a_read_only_cache_is_recomputed(sphere, reference, monkeypatch, caplog):
    truth, path, key = reference
    path.parent.mkdir(parents=True)
    path.write_bytes(b"PK\x03\x04 truncated")

    def read_only(*args, **kwargs):
        raise PermissionError(13, "Read-only file system")

    monkeypatch.setattr(cache.Path, "unlink", read_only)
    monkeypatch.setattr(cache.tempfile, "mkstemp", read_only)
    monkeypatch.setattr(cache, "_warned", set())
    with caplog.at_level(logging.WARNING, logger="allorules"):
        basis = compute_basis(*sphere, MODES)
    assert np.allclose(basis.eigenvalues, truth.eigenvalues)
    messages = " ".join(record.getMessage() for record in caplog.records)
    assert "cannot be read" in messages and "could not remove it" in messages and "not cached" in messages


def test_the_command_line_says_it_and_prints_a_finite_slope(sphere, reference, tmp_path, capsys):
    truth, path, key = reference
    mesh_path = tmp_path / "sphere.obj"
    trimesh.Trimesh(*sphere, process=False).export(mesh_path)
    from allorules.mesh.repair import prepare_mesh

    prepared = prepare_mesh(mesh_path)
    key = cache.basis_key(prepared.vertices, prepared.faces, MODES)
    path.parent.mkdir(parents=True, exist_ok=True)
    forge(path.parent / f"{key}.npz", key, truth.eigenvalues, truth.vectors, np.zeros_like(truth.mass))
    assert main(["spectrum", str(mesh_path), "--modes", str(MODES), "--json"]) == 0
    captured = capsys.readouterr()
    assert "NaN" not in captured.out and "mass is not positive" in captured.err and "Traceback" not in captured.err


def sizes(folder):
    return {path.name: path.stat().st_size for path in folder.glob("*.npz")}


def test_the_cache_keeps_under_its_limit_removing_the_least_recently_used(cache_folder, monkeypatch):
    rng = np.random.default_rng(0)
    entry = lambda: (rng.random(10), rng.random((1000, 10)), rng.random(1000) + 1)   # ~90 kB each
    first = cache.store("a" * 64, *entry())
    one = first.stat().st_size
    monkeypatch.setenv("ALLORULES_CACHE_MAX", str(3 * one + one // 2))   # room for three
    cache.store("b" * 64, *entry())
    cache.store("c" * 64, *entry())
    past = time.time() - 100
    for name, age in (("a", 30), ("b", 20), ("c", 10)):   # a is the oldest ...
        os.utime(cache_folder / f"{name * 64}.npz", (past - age, past - age))
    assert cache.load("a" * 64, 1000, 10) is not None         # ... but was just used
    cache.store("d" * 64, *entry())
    assert sorted(name[0] for name in sizes(cache_folder)) == ["a", "c", "d"]   # b went first
    assert sum(sizes(cache_folder).values()) <= 3 * one + one // 2


@pytest.mark.parametrize("text, expected", [("500M", 500 * 1024**2), ("2G", 2 * 1024**3), ("1.5g", int(1.5 * 1024**3)),
                                            ("123456", 123456), ("0", None), ("lots", cache.DEFAULT_LIMIT)])
def test_the_limit_is_read_from_the_environment(monkeypatch, text, expected):
    monkeypatch.setenv("ALLORULES_CACHE_MAX", text)
    assert cache.size_limit() == expected


def test_a_killed_writes_leftover_is_removed_once_stale(cache_folder):
    cache_folder.mkdir(parents=True)
    stale, fresh = cache_folder / ".partial-old.npz.tmp", cache_folder / ".partial-new.npz.tmp"
    stale.write_bytes(b"half a basis")
    fresh.write_bytes(b"another process, writing now")
    hours_ago = time.time() - 2 * 3600
    os.utime(stale, (hours_ago, hours_ago))
    cache.store("e" * 64, np.ones(3), np.ones((5, 3)), np.ones(5))
    assert not stale.exists() and fresh.exists()


def test_an_interrupted_store_leaves_no_temporary_file(cache_folder, monkeypatch):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cache.np, "savez", interrupted)
    with pytest.raises(KeyboardInterrupt):
        cache.store("f" * 64, np.ones(3), np.ones((5, 3)), np.ones(5))
    assert list(cache_folder.iterdir()) == []


def test_cache_command_shows_and_clears(cache_folder, capsys):
    cache.store("g" * 64, np.ones(3), np.ones((5, 3)), np.ones(5))
    assert main(["cache"]) == 0
    shown = capsys.readouterr().out
    assert str(cache_folder) in shown and "1 entry" in shown and "limit 2.0 GB" in shown
    assert main(["cache", "clear"]) == 0
    assert "removed 1 file" in capsys.readouterr().out
    assert cache.cache_info().entries == 0
