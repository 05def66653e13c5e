"""A compiled eigensolver for the small symmetric matrices of canonical pi, many matrices at a time.

Householder reduction to tridiagonal form and implicit QL with accumulated transformations (EISPACK's
tred2/tql2, the algorithm LAPACK's dsyevd itself uses below 25 rows), with a square root in place of
hypot and the transformations kept in rows (contiguous). One matrix alone is slow on two counts: QL's
rotations are a serial chain of one square root and two divisions each, which the CPU cannot overlap
within one matrix, and every loop runs over at most n elements, too few for the compiler to vectorise.
`symmetric_eigh_lanes` therefore decomposes up to LANES matrices of the same size together, stored
lane-innermost: each scalar of the one-matrix solver becomes a vector over the lanes, the lanes' chains
overlap and every loop vectorises over the lanes, while each matrix's own operations stay those of
`symmetric_eigh` (QL on a uniform schedule; see its docstring). `symmetric_eigh` decomposes one matrix
(the rare matrix the lanes leave out, and the tests).
Measured on this machine (benchmarks/bench_msa.py): one matrix at a time about 2x faster than a LAPACK
call at 9-19 rows and 3x at 3-5, where the call and its workspace allocation dominate; cyclic Jacobi, tried
first, was 1.4-3x slower than LAPACK from 9 rows on. Accurate to a few ulp of |C|: since the canonical
form fixes what solvers leave open (signs, bases of repeated eigenvalues; canonical.py), which
backward-stable solver runs does not change canonical pi beyond its rounding bound. Not used for the
reference pi, whose keyframes depend on LAPACK's own eigenvectors.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


MAX_SWEEPS = 60  # QL sweeps per eigenvalue, so that non-finite input cannot loop forever
EPS = 2.0 ** -52


@njit(cache=True)
def symmetric_eigh(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int) -> None:  # pragma: no cover
    """Eigen-decomposition of the symmetric n x n matrix held in v (both triangles) on entry: v's
    columns are the eigenvectors on exit, d the eigenvalues ascending; e is scratch of length n.
    QL iterations are capped (MAX_SWEEPS per eigenvalue) so non-finite input cannot loop forever.

    The matrix is first scaled by a power of two to unit size (exact: the same eigenvectors, the
    eigenvalues scaled back exactly), so that QL's rotations can use a plain square root where
    EISPACK calls hypot against overflow: hypot is a library call on the rotations' serial chain
    and cost a third of the solver's time. EISPACK's steps run with v's indices swapped (v is
    symmetric on entry), so the transformations build up in rows, contiguous in memory, and are
    transposed at the end: the same arithmetic, 10-20 % faster."""
    exponent = _to_unit(v, n)
    _tridiagonalise(v, d, e, n)
    l, m, tst1 = _next_sweep(d, e, n, 0, 0.0, 0.0)
    _ql(v, d, e, n, l, m, 0.0, tst1, 0)
    _finish(v, d, n, exponent)


@njit(cache=True, inline="always")
def _unit_exponent(top: float) -> int:  # pragma: no cover
    """The power of two that brings a matrix with largest entry `top` into [0.5, 1) (0 for 0 or non-finite)."""
    return math.frexp(top)[1] if top > 0.0 and np.isfinite(top) else 0


@njit(cache=True, inline="always")
def _to_unit(v: np.ndarray, n: int) -> int:  # pragma: no cover
    """Scale v by the power of two that brings its largest entry into [0.5, 1); returns the exponent."""
    top = 0.0
    for i in range(n):
        for j in range(n):
            top = max(top, abs(v[i, j]))
    exponent = _unit_exponent(top)
    unit = math.ldexp(1.0, -exponent)
    for i in range(n):
        for j in range(n):
            v[i, j] *= unit
    return exponent


@njit(cache=True, inline="always")
def _tridiagonalise(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int) -> None:  # pragma: no cover
    """Householder reduction (EISPACK tred2, indices swapped) and accumulation of the transformations
    in v's rows; d, e: the diagonal and the subdiagonal (e[n - 1] = 0) on exit."""
    for j in range(n):
        d[j] = v[j, n - 1]
    for i in range(n - 1, 0, -1):  # Householder reduction to tridiagonal form (EISPACK tred2)
        scale = 0.0
        h = 0.0
        for k in range(i):
            scale += abs(d[k])
        if scale == 0.0:
            e[i] = d[i - 1]
            for j in range(i):
                d[j] = v[j, i - 1]
                v[j, i] = 0.0
                v[i, j] = 0.0
        else:
            for k in range(i):
                d[k] /= scale
                h += d[k] * d[k]
            f = d[i - 1]
            g = np.sqrt(h)
            if f > 0:
                g = -g
            e[i] = scale * g
            h -= f * g
            d[i - 1] = f - g
            for j in range(i):
                e[j] = 0.0
            for j in range(i):
                f = d[j]
                v[i, j] = f
                g = e[j] + v[j, j] * f
                for k in range(j + 1, i):
                    g += v[j, k] * d[k]
                    e[k] += v[j, k] * f
                e[j] = g
            f = 0.0
            for j in range(i):
                e[j] /= h
                f += e[j] * d[j]
            hh = f / (h + h)
            for j in range(i):
                e[j] -= hh * d[j]
            for j in range(i):
                f = d[j]
                g = e[j]
                for k in range(j, i):
                    v[j, k] -= f * e[k] + g * d[k]
                d[j] = v[j, i - 1]
                v[j, i] = 0.0
        d[i] = h
    for i in range(n - 1):  # accumulate the transformations
        v[i, n - 1] = v[i, i]
        v[i, i] = 1.0
        h = d[i + 1]
        if h != 0.0:
            for k in range(i + 1):
                d[k] = v[i + 1, k] / h
            for j in range(i + 1):
                g = 0.0
                for k in range(i + 1):
                    g += v[i + 1, k] * v[j, k]
                for k in range(i + 1):
                    v[j, k] -= g * d[k]
        for k in range(i + 1):
            v[i + 1, k] = 0.0
    for j in range(n):
        d[j] = v[j, n - 1]
        v[j, n - 1] = 0.0
    v[n - 1, n - 1] = 1.0
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0


@njit(cache=True, inline="always")
def _next_sweep(d: np.ndarray, e: np.ndarray, n: int, l: int, f: float, tst1: float):  # pragma: no cover
    """From eigenvalue l on, the first l whose subdiagonal is not negligible and the end m of its
    unreduced block (EISPACK tql2 finds m once per l); eigenvalues on the way are final. l = n: done."""
    while l < n:
        tst1 = max(tst1, abs(d[l]) + abs(e[l]))
        m = l
        while m < n - 1 and not abs(e[m]) <= EPS * tst1:
            m += 1
        if m > l:
            return l, m, tst1
        l = _deflate(d, e, l, f)
    return n, n, tst1


@njit(cache=True, inline="always")
def _deflate(d: np.ndarray, e: np.ndarray, l: int, f: float) -> int:  # pragma: no cover
    """Eigenvalue l is final: undo the accumulated shift; returns the next l."""
    d[l] += f
    e[l] = 0.0
    return l + 1


@njit(cache=True, inline="always")
def _sweep_start(d: np.ndarray, e: np.ndarray, n: int, l: int, f: float, unshifted: bool):  # pragma: no cover
    """Wilkinson-type shift of a QL sweep on the block from l (none when `unshifted`, see _ql): returns the
    accumulated shift and d[l + 1]."""
    if unshifted:
        return f, d[l + 1]
    g = d[l]
    p = (d[l + 1] - g) / (2.0 * e[l])
    r = np.sqrt(p * p + 1.0) if abs(p) < 1e150 else abs(p)  # no overflow of p * p
    if p < 0:
        r = -r
    d[l] = e[l] / (p + r)
    d[l + 1] = e[l] * (p + r)
    h = g - d[l]
    for i in range(l + 2, n):
        d[i] -= h
    return f + h, d[l + 1]


@njit(cache=True, inline="always")
def _rotation(d: np.ndarray, e: np.ndarray, i: int, c: float, s: float, p: float):  # pragma: no cover
    """One plane rotation of the sweep (rows i, i + 1): the new cosine, sine and p."""
    g = c * e[i]
    h = c * p
    r = np.sqrt(p * p + e[i] * e[i])
    if r == 0.0 or not r < np.inf:  # squares out of range: only with a 1e150 spread in C
        r = np.hypot(p, e[i])
    e[i + 1] = s * r
    s = e[i] / r
    c = p / r
    p = c * d[i] - s * g
    d[i + 1] = h + s * (c * g + s * d[i])
    return c, s, p


@njit(cache=True, inline="always")
def _rotate_rows(v: np.ndarray, n: int, i: int, c: float, s: float) -> None:  # pragma: no cover
    """Apply the rotation to the accumulated transformations (rows i and i + 1 of v)."""
    for k in range(n):
        h = v[i + 1, k]
        v[i + 1, k] = s * v[i, k] + c * h
        v[i, k] = c * v[i, k] - s * h


@njit(cache=True, inline="always")
def _sweep_end(d: np.ndarray, e: np.ndarray, l: int, c: float, s: float, s2: float, c3: float, el1: float,
               dl1: float, tst1: float, p: float, unshifted: bool) -> bool:  # pragma: no cover
    """Close a sweep; True when e[l] is negligible (eigenvalue l converged). tql2 closes a shifted sweep
    with a formula that rests on its shift's 2 x 2 set-up; an unshifted one ends with the chase's own p
    (the 1968 tql2's ending)."""
    if not unshifted:
        p = -s * s2 * c3 * el1 * e[l] / dl1
    e[l] = s * p
    d[l] = c * p
    return not abs(e[l]) > EPS * tst1


@njit(cache=True)
def _ql(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, l: int, m: int, f: float, tst1: float,
        it: int) -> None:  # pragma: no cover
    """Implicit QL (EISPACK tql2) from the state (l, m, f, tst1, sweeps done on l) to the end.

    The first sweep on eigenvalue 0 is unshifted: canonical pi's C has an exact null vector (the rows of
    numpy.gradient's stencil sum to zero), so an unshifted sweep, which converges at the top to the
    eigenvalue of smallest magnitude, takes that null eigenvalue out first. Measured on the benchmark's
    candidates (m = 10-16), QL then needs 19-22 % fewer rotations than with tql2's shift from the first
    sweep (which starts far from any eigenvalue, 5-6 sweeps on eigenvalue 0). On a matrix without a zero
    eigenvalue the sweep still converges; it is only not as quick."""
    while l < n:
        unshifted = l == 0 and it == 0
        f, dl1 = _sweep_start(d, e, n, l, f, unshifted)
        p = d[m]
        c = c2 = c3 = 1.0
        el1 = e[l + 1]
        s = s2 = 0.0
        for i in range(m - 1, l - 1, -1):
            c3, c2, s2 = c2, c, s
            c, s, p = _rotation(d, e, i, c, s, p)
            _rotate_rows(v, n, i, c, s)
        it += 1
        if _sweep_end(d, e, l, c, s, s2, c3, el1, dl1, tst1, p, unshifted) or it == MAX_SWEEPS:
            l, m, tst1 = _next_sweep(d, e, n, _deflate(d, e, l, f), f, tst1)
            it = 0


@njit(cache=True, inline="always")
def _finish(v: np.ndarray, d: np.ndarray, n: int, exponent: int) -> None:  # pragma: no cover
    """Scale the eigenvalues back, sort them ascending with their vectors, vectors into columns."""
    scale = math.ldexp(1.0, exponent)
    for j in range(n):
        d[j] *= scale
    for i in range(1, n):  # insertion sort, ascending, columns along
        j = i
        while j > 0 and d[j - 1] > d[j]:
            d[j - 1], d[j] = d[j], d[j - 1]
            for r in range(n):
                v[j - 1, r], v[j, r] = v[j, r], v[j - 1, r]
            j -= 1
    for i in range(n):  # eigenvectors from rows to columns
        for j in range(i + 1, n):
            v[i, j], v[j, i] = v[j, i], v[i, j]


LANES = 32  # matrices decomposed together by symmetric_eigh_lanes: measured 1.6x (reduction) and 1.7x (QL) per
# matrix at 13 rows over one at a time, 2.2-2.7x at 6 rows; 8 lanes were too few for the compiler to vectorise


@njit(cache=True, error_model="numpy")
def symmetric_eigh_lanes(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, count: int,
                         work: np.ndarray) -> None:  # pragma: no cover
    """Eigen-decomposition of `count` symmetric n x n matrices held lane-innermost, v[i, j, lane] (both
    triangles): each scalar of the one-matrix solver becomes a vector over the lanes, so every loop
    has the lanes innermost, independent and contiguous, and the compiler vectorises it (a matrix's
    own operations stay in their order). On exit v[i, :, lane] is the eigenvector of eigenvalue
    d[i, lane] (not sorted), e is scratch like d, work (LANE_WORK, lanes) scratch; work[0, lane] != 0
    marks a lane this solver does not take (an exactly zero column in the reduction: symmetric_eigh).

    The reduction and scaling are symmetric_eigh's operations lane by lane; QL runs a uniform
    schedule: every lane sweeps the whole trailing block from l (the one-matrix solver stops at the
    first negligible subdiagonal entry; rotating across it changes nothing beyond rounding), and a
    lane whose e[l] has converged keeps its values exactly while the others go on, so each lane's
    result depends on its own matrix only, not on the other lanes or their number. IEEE division
    (error_model="numpy"): a flagged lane's divisions by zero give inf or nan instead of raising, and
    no division carries a zero test, which would keep the loops from vectorising."""
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
    return np.empty((width, width, LANES)), np.empty((width, LANES)), np.empty((width, LANES)), \
        np.empty((LANE_WORK, LANES))


@njit(cache=True, error_model="numpy")
def _tridiagonalise_lanes(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, count: int,
                          work: np.ndarray) -> None:  # pragma: no cover
    """_tridiagonalise on every lane (the same operations per lane); a lane whose reduction meets an
    exactly zero column is marked in work[0] (its values are then meaningless)."""
    bad, scale, h, f, g, hh = work[0], work[3], work[4], work[5], work[6], work[7]
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
                e[j, lane] /= h[lane]
                f[lane] += e[j, lane] * d[j, lane]
        for lane in range(count):
            hh[lane] = f[lane] / (h[lane] + h[lane])
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
        for k in range(i + 1):
            for lane in range(count):
                d[k, lane] = v[i + 1, k, lane] / d[i + 1, lane]
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
def _ql_lanes(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, count: int,
              work: np.ndarray) -> None:  # pragma: no cover
    """Implicit QL (_ql's sweeps, _sweep_start, _rotation, _sweep_end) on every lane, uniform schedule:
    at eigenvalue l, every lane whose e[l] is not yet negligible (and that has done fewer than
    MAX_SWEEPS sweeps on l) sweeps rows n-1 down to l; the others keep their values exactly."""
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
            unshifted = l == 0 and sweep == 0  # see _ql
            busy = 0.0
            for lane in range(count):
                flag = 1.0 if abs(e[l, lane]) > EPS * tst1[lane] else 0.0
                active[lane] = flag
                busy += flag
            if busy == 0.0:
                break
            for lane in range(count):  # _sweep_start
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
                for lane in range(count):  # _rotation; the identity (s = 0, c = 1) on inactive lanes
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
                    p[lane] = pn if on else p[lane]
                    s[lane] = sn
                    c[lane] = cn
                for k in range(n):  # _rotate_rows (the identity leaves nonzero entries exactly as they are)
                    for lane in range(count):
                        below, here = v[i + 1, k, lane], v[i, k, lane]
                        v[i + 1, k, lane] = s[lane] * here + c[lane] * below
                        v[i, k, lane] = c[lane] * here - s[lane] * below
            for lane in range(count):  # _sweep_end
                on = active[lane] != 0.0
                pe = p[lane] if unshifted else \
                    -s[lane] * s2[lane] * c3[lane] * el1[lane] * e[l, lane] / (dl1[lane] if on else 1.0)
                e[l, lane] = s[lane] * pe if on else e[l, lane]
                d[l, lane] = c[lane] * pe if on else d[l, lane]
        for lane in range(count):  # _deflate
            d[l, lane] += f[lane]
            e[l, lane] = 0.0
    for lane in range(count):
        d[n - 1, lane] += f[lane]
        e[n - 1, lane] = 0.0
