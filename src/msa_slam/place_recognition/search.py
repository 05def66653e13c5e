"""Two-stage loop-candidate search of the Scan Context paper (Kim & Kim, IROS 2018).

Stage 1: nearest neighbours of the query's rotation-invariant key (ring key: mean of each ring) in a
scipy cKDTree. Stage 2: the exact (all-shift) similarity on those candidates only. Like the authors'
implementation the tree is rebuilt every `rebuild_every` additions; keys added since the last build
are always passed to stage 2, so nothing is ever unsearchable.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class RingKeyIndex:
    """Stage-1 index over the search keys of stored descriptors (row i = keyframe i)."""

    def __init__(self, n_candidates: int = 10, rebuild_every: int = 50) -> None:
        self.n_candidates = int(n_candidates)
        self.rebuild_every = int(rebuild_every)
        self._tree: cKDTree | None = None
        self._tree_size = 0

    def candidates(
        self, keys: np.ndarray, query_key: np.ndarray, eligible: np.ndarray, n_candidates: int | None = None
    ) -> np.ndarray:
        """Indices (ascending) of the stage-2 candidates among rows of `keys` where `eligible` is True."""
        wanted = self.n_candidates if n_candidates is None else int(n_candidates)
        n = len(keys)
        if self._tree is None or n - self._tree_size >= self.rebuild_every or n < self._tree_size:
            self._tree = cKDTree(keys) if n else None
            self._tree_size = n
        picked = np.zeros(0, dtype=np.int64)
        if self._tree is not None and wanted > 0:
            blocked = int(self._tree_size - eligible[: self._tree_size].sum())
            k = min(self._tree_size, wanted + blocked)
            _, idx = self._tree.query(query_key, k=[*range(1, k + 1)])
            idx = np.asarray(idx, dtype=np.int64).ravel()
            picked = idx[eligible[idx]][:wanted]
        fresh = np.arange(self._tree_size, n)
        return np.union1d(picked, fresh[eligible[fresh]])
