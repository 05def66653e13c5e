"""A compiled eigensolver for the small symmetric matrices of canonical pi, called in place per candidate.

Householder reduction to tridiagonal form and implicit QL with accumulated transformations (EISPACK's
tred2/tql2, the algorithm LAPACK's dsyevd itself uses below 25 rows). Measured on this machine
(benchmarks/bench_msa.py): 10-25 % faster than a LAPACK call per matrix at 9-19 rows and 5x at 3,
where the call and its workspace allocation dominate; cyclic Jacobi, tried first, was 1.4-3x slower
than LAPACK from 9 rows on. Accurate to a few ulp of |C|: since the canonical form fixes what solvers
leave open (signs, bases of repeated eigenvalues; canonical.py), which backward-stable solver runs
does not change canonical pi beyond its rounding bound. Not used for the reference pi, whose keyframes
depend on LAPACK's own eigenvectors.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def symmetric_eigh(v: np.ndarray, d: np.ndarray, e: np.ndarray, n: int) -> None:  # pragma: no cover
    """Eigen-decomposition of the symmetric n x n matrix held in v (both triangles) on entry: v's
    columns are the eigenvectors on exit, d the eigenvalues ascending; e is scratch of length n.
    QL iterations are capped (60 per eigenvalue) so non-finite input cannot loop forever."""
    for j in range(n):
        d[j] = v[n - 1, j]
    for i in range(n - 1, 0, -1):  # Householder reduction to tridiagonal form (EISPACK tred2)
        scale = 0.0
        h = 0.0
        for k in range(i):
            scale += abs(d[k])
        if scale == 0.0:
            e[i] = d[i - 1]
            for j in range(i):
                d[j] = v[i - 1, j]
                v[i, j] = 0.0
                v[j, i] = 0.0
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
                v[j, i] = f
                g = e[j] + v[j, j] * f
                for k in range(j + 1, i):
                    g += v[k, j] * d[k]
                    e[k] += v[k, j] * f
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
                    v[k, j] -= f * e[k] + g * d[k]
                d[j] = v[i - 1, j]
                v[i, j] = 0.0
        d[i] = h
    for i in range(n - 1):  # accumulate the transformations
        v[n - 1, i] = v[i, i]
        v[i, i] = 1.0
        h = d[i + 1]
        if h != 0.0:
            for k in range(i + 1):
                d[k] = v[k, i + 1] / h
            for j in range(i + 1):
                g = 0.0
                for k in range(i + 1):
                    g += v[k, i + 1] * v[k, j]
                for k in range(i + 1):
                    v[k, j] -= g * d[k]
        for k in range(i + 1):
            v[k, i + 1] = 0.0
    for j in range(n):
        d[j] = v[n - 1, j]
        v[n - 1, j] = 0.0
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
                r = np.hypot(p, 1.0)
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
                    r = np.hypot(p, e[i])
                    e[i + 1] = s * r
                    s = e[i] / r
                    c = p / r
                    p = c * d[i] - s * g
                    d[i + 1] = h + s * (c * g + s * d[i])
                    for k in range(n):
                        h = v[k, i + 1]
                        v[k, i + 1] = s * v[k, i] + c * h
                        v[k, i] = c * v[k, i] - s * h
                p = -s * s2 * c3 * el1 * e[l] / dl1
                e[l] = s * p
                d[l] = c * p
                if not abs(e[l]) > eps * tst1:
                    break
        d[l] += f
        e[l] = 0.0
    for i in range(1, n):  # insertion sort, ascending, columns along
        j = i
        while j > 0 and d[j - 1] > d[j]:
            d[j - 1], d[j] = d[j], d[j - 1]
            for r in range(n):
                v[r, j - 1], v[r, j] = v[r, j], v[r, j - 1]
            j -= 1
