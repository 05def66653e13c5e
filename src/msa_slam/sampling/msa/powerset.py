"""The candidate subsets of a window in the reference's order, for the batched paths.

terms.constrained_power_set is the same enumeration one subset at a time. Exact mode takes index
tables grouped by size (they depend only on n: built once per n); the Gram path streams the feasible
subsets as bit masks (bounded memory up to n = 20).
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np
from numba import njit


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


@njit(cache=True)
def feasible_subsets(dist: np.ndarray, sim: np.ndarray, dmin: float, dmax: float):  # pragma: no cover
    """The candidates of eq. (7) as bit masks of their positions (bit 0 = position 0), in the reference's
    order, and their rho (eq. 3); terms.constrained_power_set without the fallback.

    A depth-first walk over increasing position sequences, one size after another, visits the
    subsets in itertools.combinations order and skips every extension of an infeasible prefix: no
    table of all 2^(n-1) subsets is built, so memory follows the feasible candidates only.
    """
    n = dist.shape[0]
    masks = np.empty(256, dtype=np.int64)
    rho = np.empty(256)
    count = 0
    choice = np.zeros(n, dtype=np.int64)
    prefix = np.zeros(n)  # similarity summed along the chosen prefix, left to right
    for size in range(2, n):
        depth = 1
        choice[1] = 0
        while depth > 0:
            choice[depth] += 1
            if choice[depth] > n - size + depth:  # too few positions left to complete the subset
                depth -= 1
                continue
            a, b = choice[depth - 1], choice[depth]
            if dist[a, b] < dmin or dist[a, b] > dmax:
                continue
            prefix[depth] = prefix[depth - 1] + sim[b, a]
            if depth < size - 1:
                depth += 1
                choice[depth] = choice[depth - 1]
                continue
            if count == len(masks):
                masks = np.concatenate((masks, np.empty(count, dtype=np.int64)))
                rho = np.concatenate((rho, np.empty(count)))
            mask = 1
            for k in range(1, size):
                mask |= 1 << choice[k]
            masks[count] = mask
            rho[count] = prefix[depth] / (size - 1)
            count += 1
    return masks[:count], rho[:count]
