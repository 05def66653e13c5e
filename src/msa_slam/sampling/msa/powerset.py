"""The candidate subsets of a window as index tables, in the reference's order, for the batched paths.

terms.constrained_power_set is the same enumeration one subset at a time; these tables depend only on
the window size n, so they are built once per n and shared by every window.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np


@lru_cache(maxsize=64)
def subsets_by_size(n: int) -> tuple[np.ndarray, ...]:
    """All subsets of n window positions that start at 0, grouped by size m = 2..n-1 (one array each)."""
    groups = []
    for size in range(2, n):
        combos = np.array(list(itertools.combinations(range(1, n), size - 1)), dtype=np.intp)
        groups.append(np.hstack([np.zeros((len(combos), 1), dtype=np.intp), combos]))
    for g in groups:
        g.setflags(write=False)
    return tuple(groups)


@lru_cache(maxsize=64)
def padded_subsets(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The same subsets as one (K, n-1) table padded with -1, and their sizes (for compiled loops)."""
    groups = subsets_by_size(n)
    table = np.full((sum(len(g) for g in groups), n - 1), -1, dtype=np.int64)
    sizes = np.empty(len(table), dtype=np.int64)
    row = 0
    for g in groups:
        table[row:row + len(g), :g.shape[1]] = g
        sizes[row:row + len(g)] = g.shape[1]
        row += len(g)
    table.setflags(write=False)
    sizes.setflags(write=False)
    return table, sizes
