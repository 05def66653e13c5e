"""A small MSA window shared by the tests that compare batched terms with their one-subset definitions."""

from __future__ import annotations

import numpy as np


def planar_window(n: int = 8, dim: int = 24, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) positions advancing in the plane (z = 0) and (n, dim) random-walk descriptors."""
    rng = np.random.default_rng(seed)
    t = np.zeros((n, 3))
    t[:, :2] = np.cumsum(rng.uniform(0.2, 1.0, (n, 2)), axis=0)
    return t, np.cumsum(rng.standard_normal((n, dim)), axis=0)
