"""A compiled eigensolver for the small symmetric matrices of canonical pi, called in place per candidate.

Householder reduction to tridiagonal form and implicit QL with accumulated transformations (EISPACK's
tred2/tql2, the algorithm LAPACK's dsyevd itself uses below 25 rows), with a square root in place of
hypot and the transformations kept in rows (contiguous). QL's rotations are a serial chain of one
square root and two divisions each, which the CPU cannot overlap within one matrix:
`symmetric_eigh_pair` runs the sweeps of two matrices rotation by rotation in one loop, so that their
chains overlap (each matrix's operations and their order unchanged: bit-identical results).
Measured on this machine (benchmarks/bench_msa.py): about 2x faster than a LAPACK call per matrix at 9-19 rows and 3x at 3-5,
where the call and its workspace allocation dominate; cyclic Jacobi, tried first, was 1.4-3x slower
than LAPACK from 9 rows on. Accurate to a few ulp of |C|: since the canonical form fixes what solvers
leave open (signs, bases of repeated eigenvalues; canonical.py), which backward-stable solver runs
does not change canonical pi beyond its rounding bound. Not used for the reference pi, whose keyframes
depend on LAPACK's own eigenvectors.
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


@njit(cache=True)
def symmetric_eigh_pair(va: np.ndarray, da: np.ndarray, ea: np.ndarray, vb: np.ndarray, db: np.ndarray,
                        eb: np.ndarray, n: int) -> None:  # pragma: no cover
    """symmetric_eigh of two n x n matrices (a and b), bit-identical to two calls, 1.1-1.2x faster at
    6-13 rows: their QL sweeps run side by side, one rotation of each per loop pass (each matrix keeps
    its own deflation, sweep count and convergence test); when one is done the other goes on alone."""
    xa = _to_unit(va, n)
    xb = _to_unit(vb, n)
    _tridiagonalise(va, da, ea, n)
    _tridiagonalise(vb, db, eb, n)
    la, ma, ta = _next_sweep(da, ea, n, 0, 0.0, 0.0)
    lb, mb, tb = _next_sweep(db, eb, n, 0, 0.0, 0.0)
    fa = fb = 0.0
    ita = itb = 0
    while la < n and lb < n:
        fa, dla = _sweep_start(da, ea, n, la, fa)
        fb, dlb = _sweep_start(db, eb, n, lb, fb)
        pa, pb = da[ma], db[mb]
        ca = ca2 = ca3 = cb = cb2 = cb3 = 1.0
        ela, elb = ea[la + 1], eb[lb + 1]
        sa = sa2 = sb = sb2 = 0.0
        ia, ib = ma - 1, mb - 1
        while ia >= la or ib >= lb:
            if ia >= la:
                ca3, ca2, sa2 = ca2, ca, sa
                ca, sa, pa = _rotation(da, ea, ia, ca, sa, pa)
                _rotate_rows(va, n, ia, ca, sa)
                ia -= 1
            if ib >= lb:
                cb3, cb2, sb2 = cb2, cb, sb
                cb, sb, pb = _rotation(db, eb, ib, cb, sb, pb)
                _rotate_rows(vb, n, ib, cb, sb)
                ib -= 1
        ita += 1
        if _sweep_end(da, ea, la, ca, sa, sa2, ca3, ela, dla, ta) or ita == MAX_SWEEPS:
            la, ma, ta = _next_sweep(da, ea, n, _deflate(da, ea, la, fa), fa, ta)
            ita = 0
        itb += 1
        if _sweep_end(db, eb, lb, cb, sb, sb2, cb3, elb, dlb, tb) or itb == MAX_SWEEPS:
            lb, mb, tb = _next_sweep(db, eb, n, _deflate(db, eb, lb, fb), fb, tb)
            itb = 0
    _ql(va, da, ea, n, la, ma, fa, ta, ita)
    _ql(vb, db, eb, n, lb, mb, fb, tb, itb)
    _finish(va, da, n, xa)
    _finish(vb, db, n, xb)


@njit(cache=True, inline="always")
def _to_unit(v: np.ndarray, n: int) -> int:  # pragma: no cover
    """Scale v by the power of two that brings its largest entry into [0.5, 1); returns the exponent."""
    top = 0.0
    for i in range(n):
        for j in range(n):
            top = max(top, abs(v[i, j]))
    exponent = math.frexp(top)[1] if top > 0.0 and np.isfinite(top) else 0
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
def _sweep_start(d: np.ndarray, e: np.ndarray, n: int, l: int, f: float):  # pragma: no cover
    """Wilkinson-type shift of a QL sweep on the block from l: returns the accumulated shift and d[l + 1]."""
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
               dl1: float, tst1: float) -> bool:  # pragma: no cover
    """Close a sweep; True when e[l] is negligible (eigenvalue l converged)."""
    p = -s * s2 * c3 * el1 * e[l] / dl1
    e[l] = s * p
    d[l] = c * p
    return not abs(e[l]) > EPS * tst1


@njit(cache=True)
def _ql(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int, l: int, m: int, f: float, tst1: float,
        it: int) -> None:  # pragma: no cover
    """Implicit QL (EISPACK tql2) from the state (l, m, f, tst1, sweeps done on l) to the end."""
    while l < n:
        f, dl1 = _sweep_start(d, e, n, l, f)
        p = d[m]
        c = c2 = c3 = 1.0
        el1 = e[l + 1]
        s = s2 = 0.0
        for i in range(m - 1, l - 1, -1):
            c3, c2, s2 = c2, c, s
            c, s, p = _rotation(d, e, i, c, s, p)
            _rotate_rows(v, n, i, c, s)
        it += 1
        if _sweep_end(d, e, l, c, s, s2, c3, el1, dl1, tst1) or it == MAX_SWEEPS:
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
