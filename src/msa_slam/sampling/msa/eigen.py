"""A compiled eigensolver for the small symmetric matrices of canonical pi, many matrices at a time.

Householder reduction to tridiagonal form and implicit QL with accumulated transformations (EISPACK's
tred2/tql2, the algorithm LAPACK's dsyevd itself uses below 25 rows), with a square root in place of
hypot and the transformations kept in rows (contiguous). One matrix alone is slow on two counts: QL's
rotations are a serial chain of one square root and two divisions each, which the CPU cannot overlap
within one matrix, and every loop runs over at most n elements, too few for the compiler to vectorise.
`symmetric_eigh_lanes` therefore decomposes up to LANES matrices of the same size together, stored
lane-innermost: each scalar of EISPACK's solver becomes a vector over the lanes, the lanes' chains
overlap and every loop vectorises over the lanes, while each matrix's own operations stay in their
order. It is the only solver body: `symmetric_eigh` decomposes one matrix as one lane (the tests and
the benchmark's one-at-a-time column), so that what is tested is what canonical pi runs.
Measured on this machine (benchmarks/bench_msa.py): cyclic Jacobi, tried first, was 1.4-3x slower than
LAPACK from 9 rows on. Accurate to a few ulp of |C|: since the canonical form fixes what solvers leave
open (signs, bases of repeated eigenvalues; canonical.py), which backward-stable solver runs does not
change canonical pi beyond its rounding bound. Not used for the reference pi, whose keyframes depend
on LAPACK's own eigenvectors.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

MAX_SWEEPS = 60  # QL sweeps per eigenvalue, so that non-finite input cannot loop forever
EPS = 2.0**-52


@njit(cache=True)
def symmetric_eigh(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int) -> None:  # pragma: no cover
    """Eigen-decomposition of the symmetric n x n matrix held in v (both triangles) on entry: v's
    columns are the eigenvectors on exit, d the eigenvalues ascending; e is scratch of length n.
    symmetric_eigh_lanes on one lane, then sort_lanes: a lane's bits do not depend on the other
    lanes, so these are the bits the batched candidate loop gets for the same matrix."""
    lane_v, lane_d, work = np.empty((n, n, 1)), np.empty((n, 1)), np.empty((LANE_WORK, 1))
    for i in range(n):
        for j in range(n):
            lane_v[i, j, 0] = v[i, j]
    symmetric_eigh_lanes(lane_v, lane_d, e.reshape((n, 1)), n, np.int64(1), work)
    lam, vec = np.empty((n, 1)), np.empty((n, n, 1))
    sort_lanes(lane_d, lane_v, lam, vec, n, np.int64(1))
    for i in range(n):
        d[i] = lam[i, 0]
        for j in range(n):
            v[i, j] = vec[i, j, 0]


@njit(cache=True)
def sort_lanes(
    d: np.ndarray, v: np.ndarray, lam: np.ndarray, vec: np.ndarray, m: int, count: int
) -> None:  # pragma: no cover
    """Every lane's eigen-pairs (d[i, lane], v[i, :, lane], as symmetric_eigh_lanes leaves them) ascending
    into lam[:, lane] and vec's columns (lane by lane: a sorting network's exchanges on all lanes at once
    measured 2-4x slower). Ties keep their order (an insertion sort)."""
    order = np.empty(m, dtype=np.int64)
    for lane in range(count):
        for j in range(m):
            order[j] = j
            k = j
            while k > 0 and d[order[k - 1], lane] > d[order[k], lane]:
                order[k - 1], order[k] = order[k], order[k - 1]
                k -= 1
        for j in range(m):
            lam[j, lane] = d[order[j], lane]
            for r in range(m):
                vec[r, j, lane] = v[order[j], r, lane]


@njit(cache=True, inline="always")
def _unit_exponent(top: float) -> int:  # pragma: no cover
    """The power of two that brings a matrix with largest entry `top` into [0.5, 1) (0 for 0 or non-finite)."""
    return math.frexp(top)[1] if top > 0.0 and np.isfinite(top) else 0


LANES = 32  # matrices decomposed together by symmetric_eigh_lanes: measured 1.6x (reduction) and 1.7x (QL) per
# matrix at 13 rows over one at a time, 2.2-2.7x at 6 rows; 8 lanes were too few for the compiler to vectorise


@njit(cache=True, error_model="numpy")
def symmetric_eigh_lanes(
    v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, count: int, work: np.ndarray
) -> None:  # pragma: no cover
    """Eigen-decomposition of `count` symmetric n x n matrices held lane-innermost, v[i, j, lane] (both
    triangles): each scalar of EISPACK's one-matrix solver becomes a vector over the lanes, so every
    loop has the lanes innermost, independent and contiguous, and the compiler vectorises it (a
    matrix's own operations stay in their order). On exit v[i, :, lane] is the eigenvector of
    eigenvalue d[i, lane] (not sorted: sort_lanes), e is scratch like d, work (LANE_WORK, lanes)
    scratch; work[0, lane] != 0 marks a lane whose reduction met an exactly zero column (C = 0, a
    diagonal C: its tridiagonal splits there; its values are still its eigen-pairs, and the flag only
    tells which path the reduction took).

    Each matrix is first scaled by a power of two to unit size (exact: the same eigenvectors, the
    eigenvalues scaled back exactly), so that QL's rotations can use a plain square root where
    EISPACK calls hypot against overflow: hypot is a library call on the rotations' serial chain.
    EISPACK's steps run with v's indices swapped (v is symmetric on entry), so the transformations
    build up in rows, contiguous in memory. QL runs a uniform schedule: every lane sweeps the whole
    trailing block from l (EISPACK stops at the first negligible subdiagonal entry; rotating across
    it changes nothing beyond rounding), and a lane whose e[l] has converged keeps its values exactly
    while the others go on, so each lane's result depends on its own matrix only, not on the other
    lanes or their number. IEEE division (error_model="numpy"): no division carries a zero test,
    which would keep the loops from vectorising; where EISPACK tests (a zero column) the divisor is
    chosen per lane before the loop."""
    bad, unit = work[0], work[1]
    for lane in range(count):
        bad[lane] = 0.0
        unit[lane] = 0.0
    for i in range(n):
        for j in range(n):
            for lane in range(count):
                unit[lane] = max(unit[lane], abs(v[i, j, lane]))
    exponents = work[2]
    for lane in range(count):
        exponent = _unit_exponent(unit[lane])
        exponents[lane] = exponent
        unit[lane] = math.ldexp(1.0, -exponent)
    for i in range(n):
        for j in range(n):
            for lane in range(count):
                v[i, j, lane] *= unit[lane]
    _tridiagonalise_lanes(v, d, e, n, count, work)
    _ql_lanes(v, d, e, n, count, work)
    for lane in range(count):
        unit[lane] = math.ldexp(1.0, int(exponents[lane]))
    for i in range(n):
        for lane in range(count):
            d[i, lane] *= unit[lane]


LANE_WORK = 15  # rows of symmetric_eigh_lanes' work array


@njit(cache=True)
def lane_buffers(width: int):  # pragma: no cover
    """v, d, e and work for symmetric_eigh_lanes on up to LANES matrices of up to `width` rows. Callers in
    other modules take the lane count from v.shape[2]: numba's cache does not see a change of LANES
    in their compiled code, only here."""
    return (
        np.empty((width, width, LANES)),
        np.empty((width, LANES)),
        np.empty((width, LANES)),
        np.empty((LANE_WORK, LANES)),
    )


@njit(cache=True, error_model="numpy")
def _tridiagonalise_lanes(
    v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, count: int, work: np.ndarray
) -> None:  # pragma: no cover
    """Householder reduction (EISPACK tred2, indices swapped) and accumulation of the transformations in
    v's rows, on every lane; d, e: the diagonal and the subdiagonal (e[n - 1] = 0) on exit. A lane whose
    reduction meets an exactly zero column is marked in work[0]: EISPACK skips that step (h = 0), and
    here the step's divisions by h run with 1 instead, which leaves that lane's values as the skip would
    (every product with the zero column is zero), up to the sign of a zero."""
    bad, scale, h, f, g, hh, divisor = work[0], work[3], work[4], work[5], work[6], work[7], work[8]
    for j in range(n):
        for lane in range(count):
            d[j, lane] = v[j, n - 1, lane]
    for i in range(n - 1, 0, -1):
        for lane in range(count):
            scale[lane] = 0.0
            h[lane] = 0.0
        for k in range(i):
            for lane in range(count):
                scale[lane] += abs(d[k, lane])
        for lane in range(count):
            if scale[lane] == 0.0:
                bad[lane] = 1.0
                scale[lane] = 1.0
        for k in range(i):
            for lane in range(count):
                d[k, lane] /= scale[lane]
                h[lane] += d[k, lane] * d[k, lane]
        for lane in range(count):
            fl = d[i - 1, lane]
            gl = np.sqrt(h[lane])
            gl = -gl if fl > 0 else gl
            e[i, lane] = scale[lane] * gl
            h[lane] -= fl * gl
            divisor[lane] = h[lane] if h[lane] != 0.0 else 1.0
            d[i - 1, lane] = fl - gl
        for j in range(i):
            for lane in range(count):
                e[j, lane] = 0.0
        for j in range(i):
            for lane in range(count):
                f[lane] = d[j, lane]
                v[i, j, lane] = f[lane]
                g[lane] = e[j, lane] + v[j, j, lane] * f[lane]
            for k in range(j + 1, i):
                for lane in range(count):
                    g[lane] += v[j, k, lane] * d[k, lane]
                    e[k, lane] += v[j, k, lane] * f[lane]
            for lane in range(count):
                e[j, lane] = g[lane]
        for lane in range(count):
            f[lane] = 0.0
        for j in range(i):
            for lane in range(count):
                e[j, lane] /= divisor[lane]
                f[lane] += e[j, lane] * d[j, lane]
        for lane in range(count):
            hh[lane] = f[lane] / (divisor[lane] + divisor[lane])
        for j in range(i):
            for lane in range(count):
                e[j, lane] -= hh[lane] * d[j, lane]
        for j in range(i):
            for k in range(j, i):
                for lane in range(count):
                    v[j, k, lane] -= d[j, lane] * e[k, lane] + e[j, lane] * d[k, lane]
            for lane in range(count):
                d[j, lane] = v[j, i - 1, lane]
                v[j, i, lane] = 0.0
        for lane in range(count):
            d[i, lane] = h[lane]
    for i in range(n - 1):  # accumulate the transformations
        for lane in range(count):
            v[i, n - 1, lane] = v[i, i, lane]
            v[i, i, lane] = 1.0
            divisor[lane] = d[i + 1, lane] if d[i + 1, lane] != 0.0 else 1.0  # 0: a skipped step (zero row)
        for k in range(i + 1):
            for lane in range(count):
                d[k, lane] = v[i + 1, k, lane] / divisor[lane]
        for j in range(i + 1):
            for lane in range(count):
                g[lane] = 0.0
            for k in range(i + 1):
                for lane in range(count):
                    g[lane] += v[i + 1, k, lane] * v[j, k, lane]
            for k in range(i + 1):
                for lane in range(count):
                    v[j, k, lane] -= g[lane] * d[k, lane]
        for k in range(i + 1):
            for lane in range(count):
                v[i + 1, k, lane] = 0.0
    for j in range(n):
        for lane in range(count):
            d[j, lane] = v[j, n - 1, lane]
            v[j, n - 1, lane] = 0.0
    for lane in range(count):
        v[n - 1, n - 1, lane] = 1.0
    for i in range(1, n):
        for lane in range(count):
            e[i - 1, lane] = e[i, lane]
    for lane in range(count):
        e[n - 1, lane] = 0.0


@njit(cache=True, error_model="numpy")
def _ql_lanes(
    v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, count: int, work: np.ndarray
) -> None:  # pragma: no cover
    """Implicit QL (EISPACK tql2) on every lane, uniform schedule: at eigenvalue l, every lane whose e[l]
    is not yet negligible (and that has done fewer than MAX_SWEEPS sweeps on l, so that non-finite
    input cannot loop forever) sweeps rows n-1 down to l; the others keep their values exactly.

    The first sweep on eigenvalue 0 is unshifted: canonical pi's C has an exact null vector (the rows of
    numpy.gradient's stencil sum to zero), so an unshifted sweep, which converges at the top to the
    eigenvalue of smallest magnitude, takes that null eigenvalue out first. Measured on the benchmark's
    candidates (m = 10-16), QL then needs 19-22 % fewer rotations than with tql2's shift from the first
    sweep (which starts far from any eigenvalue, 5-6 sweeps on eigenvalue 0). On a matrix without a zero
    eigenvalue the sweep still converges; it is only not as quick."""
    f, tst1, p, c, s = work[3], work[4], work[5], work[6], work[7]
    c2, c3, s2, el1, dl1 = work[8], work[9], work[10], work[11], work[12]
    active, h = work[13], work[14]
    for lane in range(count):
        f[lane] = 0.0
        tst1[lane] = 0.0
    for l in range(n - 1):
        for lane in range(count):
            tst1[lane] = max(tst1[lane], abs(d[l, lane]) + abs(e[l, lane]))
        for sweep in range(MAX_SWEEPS):
            unshifted = l == 0 and sweep == 0  # see the docstring
            busy = 0.0
            for lane in range(count):
                flag = 1.0 if abs(e[l, lane]) > EPS * tst1[lane] else 0.0
                active[lane] = flag
                busy += flag
            if busy == 0.0:
                break
            for lane in range(count):  # Wilkinson-type shift (none when unshifted); no overflow of pl * pl
                on = active[lane] != 0.0
                gl = d[l, lane]
                el = e[l, lane] if on else 1.0
                pl = (d[l + 1, lane] - gl) / (2.0 * el)
                rl = np.sqrt(pl * pl + 1.0) if abs(pl) < 1e150 else abs(pl)
                rl = -rl if pl < 0 else rl
                top = gl if unshifted else el / (pl + rl)
                below = d[l + 1, lane] if unshifted else el * (pl + rl)
                d[l, lane] = top if on else gl
                dl1[lane] = below if on else d[l + 1, lane]
                d[l + 1, lane] = dl1[lane]
                h[lane] = gl - top if on else 0.0
                f[lane] += h[lane]
            for i in range(l + 2, n):
                for lane in range(count):
                    d[i, lane] -= h[lane]
            for lane in range(count):
                p[lane] = d[n - 1, lane]
                c[lane] = c2[lane] = c3[lane] = 1.0
                el1[lane] = e[l + 1, lane]
                s[lane] = s2[lane] = 0.0
            for i in range(n - 2, l - 1, -1):
                for lane in range(count):  # one plane rotation; the identity (s = 0, c = 1) on inactive lanes
                    # and where p and e[i] are both zero (a split at the block's end)
                    on = active[lane] != 0.0
                    c3[lane] = c2[lane]
                    c2[lane] = c[lane]
                    s2[lane] = s[lane]
                    ei = e[i, lane]
                    g = c[lane] * ei
                    hl = c[lane] * p[lane]
                    r = np.sqrt(p[lane] * p[lane] + ei * ei)
                    on = on and r > 0.0
                    rs = r if on else 1.0
                    sn = ei / rs if on else 0.0
                    cn = p[lane] / rs if on else 1.0
                    e[i + 1, lane] = s[lane] * r if on else e[i + 1, lane]
                    pn = cn * d[i, lane] - sn * g
                    dn = hl + sn * (cn * g + sn * d[i, lane])
                    d[i + 1, lane] = dn if on else d[i + 1, lane]
                    p[lane] = pn if on or r == 0.0 else p[lane]  # r = 0: the identity, the chase starts at d[i]
                    s[lane] = sn
                    c[lane] = cn
                for k in range(n):  # on the transformations (the identity leaves nonzero entries as they are)
                    for lane in range(count):
                        below, here = v[i + 1, k, lane], v[i, k, lane]
                        v[i + 1, k, lane] = s[lane] * here + c[lane] * below
                        v[i, k, lane] = c[lane] * here - s[lane] * below
            for lane in range(count):  # close the sweep: tql2's formula after a shift, the chase's p without
                on = active[lane] != 0.0
                pe = (
                    p[lane]
                    if unshifted
                    else -s[lane] * s2[lane] * c3[lane] * el1[lane] * e[l, lane] / (dl1[lane] if on else 1.0)
                )
                e[l, lane] = s[lane] * pe if on else e[l, lane]
                d[l, lane] = c[lane] * pe if on else d[l, lane]
        for lane in range(count):  # eigenvalue l is final: undo the accumulated shift
            d[l, lane] += f[lane]
            e[l, lane] = 0.0
    for lane in range(count):
        d[n - 1, lane] += f[lane]
        e[n - 1, lane] = 0.0
