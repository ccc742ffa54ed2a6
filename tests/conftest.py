"""Shared fixtures: an isolated basis cache, the real meshes folder (skipped where absent), a run
whose second step's output cannot be measured."""
from __future__ import annotations

from pathlib import Path

import pytest

SHARED_MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


@pytest.fixture(autouse=True, scope="session")
def isolated_basis_cache(tmp_path_factory):
    """Tests never read or write the user's basis cache; they share one cache per session."""
    patch = pytest.MonkeyPatch()
    patch.setenv("ALLORULES_CACHE_DIR", str(tmp_path_factory.mktemp("basis-cache")))
    yield
    patch.undo()


@pytest.fixture(scope="session")
def shared_meshes() -> Path:
    """The folder of real meshes beside the checkout; tests using it skip where it is absent."""
    if not SHARED_MESHES.is_dir():
        pytest.skip("../shared/meshes is not present")
    return SHARED_MESHES


@pytest.fixture(scope="session")
def generated_horse():
    """The generated horse (~3000 vertices) with labels and truth; made once per test session."""
    from allorules.mesh.quadruped import generate_quadruped

    return generate_quadruped("horse", 3000)


UNMEASURABLE = "no closed section around the chest behind the forelimbs"


@pytest.fixture
def second_output_unmeasurable(monkeypatch):
    """Ruleset runs whose second step's output a measure fails on (``MeasurementError(UNMEASURABLE)``
    where the run settles it), as the bull 386's refit at ×0.5 did: for the ways a stopped run ends."""
    from allorules.errors import MeasurementError
    from allorules.runs import ruleset_run

    settled, calls = ruleset_run._settled, []

    def failing(*arguments):
        calls.append(1)
        if len(calls) == 2:
            raise MeasurementError(UNMEASURABLE)
        return settled(*arguments)

    monkeypatch.setattr(ruleset_run, "_settled", failing)
