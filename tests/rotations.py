"""Random proper rotations for tests that turn a mesh (seeded, so a failure can be repeated)."""
from __future__ import annotations

import numpy as np


def random_rotation(seed: int) -> np.ndarray:
    """A 3×3 rotation (det +1) drawn uniformly for ``seed``."""
    rng = np.random.default_rng(seed)
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q
