"""The lane eigensolver (sampling/msa/eigen.py) on matrices whose Householder reduction meets an exactly
zero column: canonical pi's C has one when a candidate's first two or last two members have the same
descriptor (a standstill), and the lane solver is the only solver, so it must decompose them as well."""

from __future__ import annotations

import numpy as np
import pytest

from msa_slam.sampling.msa.eigen import LANE_WORK, LANES, symmetric_eigh, symmetric_eigh_lanes


def zero_column_matrices(m: int, seed: int) -> list[np.ndarray]:
    """C = 0, diagonals, and random X X^T with a zero row and column (first, middle, last) or an exact block split."""
    rng = np.random.default_rng(seed)
    mats = [np.zeros((m, m)), np.diag(rng.standard_normal(m)), np.eye(m)]
    for row in (0, m // 2, m - 1):
        x = rng.standard_normal((m, m + 2))
        c = x @ x.T
        c[row, :] = c[:, row] = 0.0
        mats.append(c)
    x = rng.standard_normal((m, m + 2))
    split = x @ x.T
    split[: m // 2, m // 2 :] = split[m // 2 :, : m // 2] = 0.0
    mats.append(split)
    return mats


@pytest.mark.parametrize("m", [3, 6, 10, 13])
def test_matrices_with_a_zero_column_are_decomposed_accurately(m):
    for c in zero_column_matrices(m, m):
        vec, lam = c.copy(), np.empty(m)
        symmetric_eigh(vec, lam, np.empty(m), m)
        scale = max(np.abs(c).max(), 1.0)
        np.testing.assert_allclose(lam, np.linalg.eigvalsh(c), rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(vec.T @ vec, np.eye(m), rtol=0, atol=1e-13)
        np.testing.assert_allclose((vec * lam) @ vec.T, c, rtol=0, atol=1e-13 * scale)


def test_a_zero_column_lane_gets_the_bits_of_the_same_matrix_alone():
    """Flagged lanes share a batch with ordinary ones: each keeps the values it gets as a batch of one."""
    m = 8
    rng = np.random.default_rng(3)
    mats = zero_column_matrices(m, 4)
    while len(mats) < LANES:
        x = rng.standard_normal((m, m + 2))
        mats.append(x @ x.T)
    v = np.stack(mats, axis=-1)
    d, e, work = np.empty((m, LANES)), np.empty((m, LANES)), np.empty((LANE_WORK, LANES))
    symmetric_eigh_lanes(v, d, e, m, LANES, work)
    flagged = np.flatnonzero(work[0])  # all but the zero middle row, which earlier steps fill in
    assert flagged.tolist() == [0, 1, 2, 3, 5, 6]
    for lane, c in enumerate(mats):
        alone_v, alone_d, alone_work = c[:, :, None].copy(), np.empty((m, 1)), np.empty((LANE_WORK, 1))
        symmetric_eigh_lanes(alone_v, alone_d, np.empty((m, 1)), m, 1, alone_work)
        assert np.array_equal(alone_d[:, 0], d[:, lane]) and np.array_equal(alone_v[:, :, 0], v[:, :, lane])
