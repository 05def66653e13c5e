"""A compiled eigensolver for the small symmetric matrices of canonical pi, called in place per candidate.

Householder reduction to tridiagonal form and implicit QL with accumulated transformations (EISPACK's
tred2/tql2, the algorithm LAPACK's dsyevd itself uses below 25 rows), with a square root in place of
hypot and the transformations kept in rows (contiguous). Measured on this machine
(benchmarks/bench_msa.py): about 2x faster than a LAPACK call per matrix at 9-19 rows and 3x at 3-5,
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


@njit(cache=True)
def symmetric_eigh(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int) -> None:  # pragma: no cover
    """Eigen-decomposition of the symmetric n x n matrix held in v (both triangles) on entry: v's
    columns are the eigenvectors on exit, d the eigenvalues ascending; e is scratch of length n.
    QL iterations are capped (60 per eigenvalue) so non-finite input cannot loop forever.

    The matrix is first scaled by a power of two to unit size (exact: the same eigenvectors, the
    eigenvalues scaled back exactly), so that QL's rotations can use a plain square root where
    EISPACK calls hypot against overflow: hypot is a library call on the rotations' serial chain
    and cost a third of the solver's time. EISPACK's steps run with v's indices swapped (v is
    symmetric on entry), so the transformations build up in rows, contiguous in memory, and are
    transposed at the end: the same arithmetic, 10-20 % faster."""
    top = 0.0
    for i in range(n):
        for j in range(n):
            top = max(top, abs(v[i, j]))
    exponent = math.frexp(top)[1] if top > 0.0 and np.isfinite(top) else 0
    unit = math.ldexp(1.0, -exponent)
    for i in range(n):
        for j in range(n):
            v[i, j] *= unit
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
    e[0] = 0.0
    for i in range(1, n):  # implicit QL on the tridiagonal matrix (EISPACK tql2)
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    f = 0.0
    tst1 = 0.0
    eps = 2.0 ** -52
    for l in range(n):
        tst1 = max(tst1, abs(d[l]) + abs(e[l]))
        m = l
        while m < n - 1 and not abs(e[m]) <= eps * tst1:
            m += 1
        if m > l:
            for _ in range(60):
                g = d[l]
                p = (d[l + 1] - g) / (2.0 * e[l])
                r = np.sqrt(p * p + 1.0) if abs(p) < 1e150 else abs(p)  # no overflow of p * p
                if p < 0:
                    r = -r
                d[l] = e[l] / (p + r)
                d[l + 1] = e[l] * (p + r)
                dl1 = d[l + 1]
                h = g - d[l]
                for i in range(l + 2, n):
                    d[i] -= h
                f += h
                p = d[m]
                c = c2 = c3 = 1.0
                el1 = e[l + 1]
                s = s2 = 0.0
                for i in range(m - 1, l - 1, -1):
                    c3 = c2
                    c2 = c
                    s2 = s
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
                    for k in range(n):
                        h = v[i + 1, k]
                        v[i + 1, k] = s * v[i, k] + c * h
                        v[i, k] = c * v[i, k] - s * h
                p = -s * s2 * c3 * el1 * e[l] / dl1
                e[l] = s * p
                d[l] = c * p
                if not abs(e[l]) > eps * tst1:
                    break
        d[l] += f
        e[l] = 0.0
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
