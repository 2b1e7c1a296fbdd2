"""Compiled-on-demand kernel of the invariant-subspace iteration of :mod:`bayesbeam.physics.sensor`.

The fixed-point iteration of :func:`bayesbeam.physics.sensor._invariant_reduction`, one
parameter set at a time, written as plain Python on numpy arrays so that numba can
compile it (:func:`bayesbeam._util.compiled_kernel`, done lazily by
:mod:`bayesbeam.physics.sensor`, with ``reassoc`` so that its dot products vectorise) and
so that it runs, slowly, without numba (the tests check its logic that way). Nothing
here imports numba.

Why a kernel: the iteration multiplies thin blocks (the dropped modes' ``2r x 2k``
coupling) ~30 times per set; the batched numpy route pays, per step, a pass over every
set's dense ``r x r`` block to gather the sets still iterating, and temporaries of the
whole batch, which measured ~4 ms per set on a 32-element beam with two modes in band.
Here each set's blocks stay in cache for all its steps, and a step allocates nothing:
a first version that called numpy's small products inside the compiled loop spent
~2.3x the arithmetic on their calls and temporaries.
"""

from __future__ import annotations

import math

import numpy as np


def _riccati_kernel_py(P, wi, A11, A12, A21, max_iter, tol):
    """Solve the two block Riccati equations of each set by fixed-point iteration.

    ``X = A22⁻¹ (X A11 + X A12 X - A21)`` and ``Y = (A11 Y + A12 - Y A21 Y) A22⁻¹``
    in the factored form of the numpy route, ``X ← A22⁻¹X (A11 + A12 X) - A22⁻¹A21``
    and ``Y ← (A11 - Y A21) Y A22⁻¹ + A12 A22⁻¹``, with ``A22⁻¹`` applied through its
    blocks ``P = -Ω⁻¹ C Ω⁻¹`` and ``wi = 1/ω`` (``A⁻¹ Z = [P Z_top - wi Z_bot; wi Z_top]``,
    ``Z A⁻¹ = [Z_left P + Z_right wi, -Z_left wi]``). A set stops once the relative
    Frobenius changes of both iterates are at most ``tol``, or when one is not finite.

    Written as explicit loops over preallocated work arrays: X is held transposed, so
    that both products with the dense ``P`` (``2 n r²`` multiply-adds per step, the
    cost of the iteration) run along contiguous rows, and a step allocates nothing
    (numpy's small products and temporaries cost ~2.3x the arithmetic, measured).

    Parameters
    ----------
    P : ndarray, shape (B, r, r)
    wi : ndarray, shape (B, r)
    A11 : ndarray, shape (B, n, n)
    A12 : ndarray, shape (B, n, 2r)
    A21 : ndarray, shape (B, 2r, n)
    max_iter : int
    tol : float

    Returns
    -------
    X : ndarray, shape (B, 2r, n)
    Y : ndarray, shape (B, n, 2r)
    done : ndarray of bool, shape (B,)
        Converged within ``max_iter`` steps.
    """
    B, r = wi.shape
    n = A11.shape[1]
    s = 2 * r
    X = np.zeros((B, s, n))
    Y = np.zeros((B, n, s))
    done = np.zeros(B, dtype=np.bool_)
    xt = np.empty((n, s))  # X transposed
    y = np.empty((n, s))
    axt = np.empty((n, s))  # (A22⁻¹ X) transposed
    ya = np.empty((n, s))  # Y A22⁻¹
    cx = np.empty((n, s))  # (A22⁻¹ A21) transposed
    cy = np.empty((n, s))  # A12 A22⁻¹
    a21t = np.empty((n, s))
    M = np.empty((n, n))  # A11 + A12 X
    N = np.empty((n, n))  # A11 - Y A21
    for b in range(B):
        Pb = P[b]
        w = wi[b]
        for q in range(n):
            for k in range(s):
                a21t[q, k] = A21[b, k, q]
                xt[q, k] = a21t[q, k]
                y[q, k] = A12[b, q, k]
        # Step 0 applies A22⁻¹ to A21 and A12 (the constant terms) and starts the
        # iterates there; every later step applies it to the iterates.
        for it in range(max_iter + 1):
            for j in range(n):
                for i in range(r):
                    acc = 0.0
                    for k in range(r):
                        acc += Pb[i, k] * xt[j, k]
                    axt[j, i] = acc - w[i] * xt[j, r + i]
                    axt[j, r + i] = w[i] * xt[j, i]
                    ya[j, i] = y[j, r + i] * w[i]
                    ya[j, r + i] = -y[j, i] * w[i]
                for k in range(r):
                    yk = y[j, k]
                    for i in range(r):
                        ya[j, i] += yk * Pb[k, i]
            if it == 0:
                for q in range(n):
                    for k in range(s):
                        cx[q, k] = axt[q, k]
                        cy[q, k] = ya[q, k]
                        xt[q, k] = -axt[q, k]
                        y[q, k] = ya[q, k]
                continue
            for p in range(n):
                for q in range(n):
                    sm = 0.0
                    sn = 0.0
                    for k in range(s):
                        sm += A12[b, p, k] * xt[q, k]
                        sn += y[p, k] * a21t[q, k]
                    M[p, q] = A11[b, p, q] + sm
                    N[p, q] = A11[b, p, q] - sn
            dx = 0.0
            nx = 0.0
            dy = 0.0
            ny = 0.0
            for q in range(n):
                for k in range(s):
                    vx = -cx[q, k]
                    vy = cy[q, k]
                    for p in range(n):
                        vx += M[p, q] * axt[p, k]
                        vy += N[q, p] * ya[p, k]
                    dx += (vx - xt[q, k]) ** 2
                    dy += (vy - y[q, k]) ** 2
                    nx += vx * vx
                    ny += vy * vy
                    xt[q, k] = vx
                    y[q, k] = vy
            dx = math.sqrt(dx / max(nx, 1e-300))
            dy = math.sqrt(dy / max(ny, 1e-300))
            if dx <= tol and dy <= tol:
                done[b] = True
                break
            if not (math.isfinite(dx) and math.isfinite(dy)):
                break
        for q in range(n):
            for k in range(s):
                X[b, k, q] = xt[q, k]
                Y[b, q, k] = y[q, k]
    return X, Y, done
