"""Compiled-on-demand kernel of :func:`bayesbeam.physics.propagate.response_uniform`.

The same algorithm as ``_expm_chain`` (:mod:`bayesbeam.physics.expm`) followed by the
baby-step/giant-step product of :mod:`bayesbeam.physics.propagate`, one parameter set per loop
iteration, written as plain Python on numpy arrays so that numba can compile it
(``numba.njit(nogil=True, cache=True)``, done lazily by :mod:`bayesbeam.physics.propagate`) and
so that it runs, slowly, without numba (tests check its logic that way). Nothing here
imports numba.
"""

from __future__ import annotations

import math

import numpy as np


def _uniform_kernel_py(A, z0, h, dt, n, k, theta, degrees, inv_fact, prescale, max_sq):
    B, s = z0.shape
    y = np.zeros((B, n))
    valid = np.zeros(B, dtype=np.bool_)
    nb = 2**k
    ng = (n + nb - 1) // nb
    for b in range(B):
        X = A[b] * dt
        norm = 0.0
        for j in range(s):
            col = 0.0
            for i in range(s):
                col += abs(X[i, j])
            norm = max(norm, col)
        if not np.isfinite(norm):
            continue
        s0 = 0
        if norm > prescale:
            s0 = int(math.ceil(math.log2(norm / prescale)))
            if s0 > max_sq:
                continue
            X = X * 2.0 ** (-s0)
        A2 = X @ X
        A3 = A2 @ X
        A4 = A2 @ A2
        n3 = 0.0
        n4 = 0.0
        for j in range(s):
            c3 = 0.0
            c4 = 0.0
            for i in range(s):
                c3 += abs(A3[i, j])
                c4 += abs(A4[i, j])
            n3 = max(n3, c3)
            n4 = max(n4, c4)
        alpha = max(n3 ** (1.0 / 3.0), n4**0.25)
        if not np.isfinite(alpha):
            continue
        m = degrees[degrees.size - 1]
        sq = 0
        if alpha > 0.0:
            sq = max(0, s0 + int(math.ceil(math.log2(alpha / theta[degrees.size - 1]))))
        if s0 == 0:
            for d in range(degrees.size - 1, -1, -1):
                if alpha <= theta[d]:
                    m = degrees[d]
        r = m // 4
        f = 2.0 ** (s0 - sq)
        coef = np.empty(m + 1)
        for i in range(m + 1):
            coef[i] = inv_fact[i] * f**i
        p = np.empty((s, s))
        for j in range(r - 1, -1, -1):
            top = coef[m] if j == r - 1 else 0.0
            if j < r - 1:
                p = p @ A4
            c1 = coef[4 * j + 1]
            c2 = coef[4 * j + 2]
            c3 = coef[4 * j + 3]
            for i in range(s):
                for q in range(s):
                    v = c1 * X[i, q] + c2 * A2[i, q] + c3 * A3[i, q] + top * A4[i, q]
                    if j < r - 1:
                        v += p[i, q]
                    p[i, q] = v
                p[i, i] += coef[4 * j]
        for _ in range(sq):
            p = p @ p
        pw = np.empty((k + 1, s, s))
        pw[0] = p
        for j in range(k):
            pw[j + 1] = pw[j] @ pw[j]
        L = np.empty((nb, s))
        L[0] = h[b]
        for j in range(k):
            w = 2**j
            L[w : 2 * w] = L[:w] @ pw[j]
        R = np.empty((ng, s))
        R[0] = z0[b]
        Q = pw[k]
        for a in range(1, ng):
            R[a] = Q @ R[a - 1]
        Y = R @ L.T
        ok = True
        for a in range(ng):
            for i in range(nb):
                idx = a * nb + i
                if idx < n:
                    v = Y[a, i]
                    if not np.isfinite(v):
                        ok = False
                    y[b, idx] = v
        valid[b] = ok
    return y, valid
