"""Compiled-on-demand kernels of the invariant-subspace iterations of the sensor band.

The two iterations of :func:`bayesbeam.physics.sensor._invariant_reduction` (the
mode-decoupled one, :func:`_decoupled_kernel_py`, and the plain fixed point,
:func:`_riccati_kernel_py`, for the sets the first leaves), one parameter set at a
time, written as plain Python on numpy arrays so that numba can compile them
(:func:`bayesbeam._util.compiled_kernel`, done lazily by
:mod:`bayesbeam.physics.sensor`, with ``reassoc`` so that their dot products vectorise)
and so that they run, slowly, without numba (the tests check their logic that way). Nothing
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


def _decoupled_kernel_py(wd, ndd, A11, A12, A21, max_iter, tol, ratio):
    """Solve the two block Riccati equations of each set by mode-decoupled Sylvester steps.

    With each block split into its modes' own 2x2 blocks (``A11⁰``, ``A22⁰``: the
    frequencies and the diagonal of the damping) and the rest (``Δ11``, ``Δ22``: the
    damping's off-diagonal coupling), the equations of :func:`_riccati_kernel_py` read
    ``A22⁰ X - X A11⁰ = X A12 X - A21 - Δ22 X + X Δ11`` and
    ``A11⁰ Y - Y A22⁰ = Y A21 Y - A12 - Δ11 Y + Y Δ22``. Their left sides separate into
    one 2x2 Sylvester equation per (dropped, kept) pair of modes, solved exactly (the
    inverse of each pair's 4x4 operator, once per set); iterating on the right sides
    contracts by about |coupling| / |λ_dropped - λ_kept| per step (e.g. a point mass's
    rank-one viscous coupling: ~1e-6 on the aluminium records, 3 steps to 1e-12),
    where :func:`_riccati_kernel_py` contracts by |λ|max(kept) / |λ|min(dropped) whatever
    the coupling (0.3-0.6: 30-50 steps). A step costs up to ~3x one of that
    iteration's (:data:`bayesbeam.physics.sensor.DECOUPLED_RATIO`), so a set gives up
    (``done`` False, for that iteration to take over) once a step shrinks the change
    by less than ``ratio`` (from its third step), or on a singular pair.

    Parameters
    ----------
    wd : ndarray, shape (B, r)
        Dropped modes' frequencies (rad/s).
    ndd : ndarray, shape (B, r, r)
        The dropped modes' damping block of the state matrix, ``-C_DD``.
    A11 : ndarray, shape (B, n, n)
    A12 : ndarray, shape (B, n, 2r)
    A21 : ndarray, shape (B, 2r, n)
    max_iter : int
    tol : float
        As :func:`_riccati_kernel_py`'s.
    ratio : float
        Slowest contraction per step accepted.

    Returns
    -------
    X : ndarray, shape (B, 2r, n)
    Y : ndarray, shape (B, n, 2r)
    done : ndarray of bool, shape (B,)
    """
    B, r = wd.shape
    n = A11.shape[1]
    k = n // 2
    s = 2 * r
    X = np.zeros((B, s, n))
    Y = np.zeros((B, n, s))
    done = np.zeros(B, dtype=np.bool_)
    TX = np.empty((r, k, 4, 4))
    TY = np.empty((r, k, 4, 4))
    work = np.empty((4, 8))
    a2 = np.empty((2, 2))
    c2 = np.empty((2, 2))
    D11 = np.empty((n, n))
    off = np.empty((r, r))
    ax = np.empty((n, n))  # A12 X
    ya = np.empty((n, n))  # Y A21
    rx = np.empty((s, n))
    ry = np.empty((n, s))
    xn = np.empty((s, n))
    yn = np.empty((n, s))
    vec = np.empty(4)
    for b in range(B):
        for p in range(n):
            for q in range(n):
                D11[p, q] = A11[b, p, q]
        for j in range(k):
            D11[j, j] = 0.0
            D11[j, k + j] = 0.0
            D11[k + j, j] = 0.0
            D11[k + j, k + j] = 0.0
        for i in range(r):
            for m in range(r):
                off[i, m] = 0.0 if i == m else ndd[b, i, m]
        # The pairs' 4x4 operators on a block's entries (row-major), inverted by
        # Gauss-Jordan with partial pivoting: X-block  a x - x c  and Y-block  c y - y a,
        # a = A22⁰'s block of dropped mode i, c = A11⁰'s block of kept mode j.
        ok = True
        for i in range(r):
            a2[0, 0] = 0.0
            a2[0, 1] = wd[b, i]
            a2[1, 0] = -wd[b, i]
            a2[1, 1] = ndd[b, i, i]
            for j in range(k):
                c2[0, 0] = A11[b, j, j]
                c2[0, 1] = A11[b, j, k + j]
                c2[1, 0] = A11[b, k + j, j]
                c2[1, 1] = A11[b, k + j, k + j]
                for which in range(2):
                    for p in range(2):
                        for q in range(2):
                            for u in range(2):
                                for v in range(2):
                                    if which == 0:
                                        val = (a2[p, u] if q == v else 0.0) - (
                                            c2[v, q] if p == u else 0.0)
                                    else:
                                        val = (c2[p, u] if q == v else 0.0) - (
                                            a2[v, q] if p == u else 0.0)
                                    work[2 * p + q, 2 * u + v] = val
                    for p in range(4):
                        for q in range(4):
                            work[p, 4 + q] = 1.0 if p == q else 0.0
                    for col in range(4):
                        piv = col
                        big = abs(work[col, col])
                        for p in range(col + 1, 4):
                            if abs(work[p, col]) > big:
                                big = abs(work[p, col])
                                piv = p
                        if not (big > 0.0 and math.isfinite(big)):
                            ok = False
                            break
                        if piv != col:
                            for q in range(8):
                                tmp = work[col, q]
                                work[col, q] = work[piv, q]
                                work[piv, q] = tmp
                        inv = 1.0 / work[col, col]
                        for q in range(8):
                            work[col, q] *= inv
                        for p in range(4):
                            if p != col:
                                f = work[p, col]
                                if f != 0.0:
                                    for q in range(8):
                                        work[p, q] -= f * work[col, q]
                    for p in range(4):
                        for q in range(4):
                            if which == 0:
                                TX[i, j, p, q] = work[p, 4 + q]
                            else:
                                TY[i, j, p, q] = work[p, 4 + q]
        if not ok:
            continue
        prev = 1e300
        for it in range(max_iter):
            for p in range(n):
                for q in range(n):
                    sx = 0.0
                    sy = 0.0
                    for m in range(s):
                        sx += A12[b, p, m] * X[b, m, q]
                        sy += Y[b, p, m] * A21[b, m, q]
                    ax[p, q] = sx + D11[p, q]  # A12 X + Δ11
                    ya[p, q] = sy - D11[p, q]  # Y A21 - Δ11
            # Right sides: rx = X (A12 X + Δ11) - A21 - Δ22 X,
            # ry = (Y A21 - Δ11) Y - A12 + Y Δ22 (Δ22 is the off-diagonal -C_DD only).
            for m in range(s):
                for q in range(n):
                    acc = -A21[b, m, q]
                    for p in range(n):
                        acc += X[b, m, p] * ax[p, q]
                    if m >= r:
                        for e in range(r):
                            acc -= off[m - r, e] * X[b, r + e, q]
                    rx[m, q] = acc
            for p in range(n):
                for m in range(s):
                    acc = -A12[b, p, m]
                    for q in range(n):
                        acc += ya[p, q] * Y[b, q, m]
                    if m >= r:
                        for e in range(r):
                            acc += Y[b, p, r + e] * off[e, m - r]
                    ry[p, m] = acc
            for i in range(r):
                for j in range(k):
                    for which in range(2):  # the X block (i, j), then the Y block (j, i)
                        if which == 0:
                            r0, r1, c0, c1 = i, r + i, j, k + j
                            src, dst, T = rx, xn, TX
                        else:
                            r0, r1, c0, c1 = j, k + j, i, r + i
                            src, dst, T = ry, yn, TY
                        vec[0] = src[r0, c0]
                        vec[1] = src[r0, c1]
                        vec[2] = src[r1, c0]
                        vec[3] = src[r1, c1]
                        for p in range(4):
                            acc = 0.0
                            for q in range(4):
                                acc += T[i, j, p, q] * vec[q]
                            work[p, 0] = acc
                        dst[r0, c0] = work[0, 0]
                        dst[r0, c1] = work[1, 0]
                        dst[r1, c0] = work[2, 0]
                        dst[r1, c1] = work[3, 0]
            dx = 0.0
            nx = 0.0
            dy = 0.0
            ny = 0.0
            for m in range(s):
                for q in range(n):
                    dx += (xn[m, q] - X[b, m, q]) ** 2
                    nx += xn[m, q] ** 2
                    X[b, m, q] = xn[m, q]
                    dy += (yn[q, m] - Y[b, q, m]) ** 2
                    ny += yn[q, m] ** 2
                    Y[b, q, m] = yn[q, m]
            dx = math.sqrt(dx / max(nx, 1e-300))
            dy = math.sqrt(dy / max(ny, 1e-300))
            if dx <= tol and dy <= tol:
                done[b] = True
                break
            d = max(dx, dy)
            if not math.isfinite(d) or (it >= 2 and d > ratio * prev):
                break
            prev = d
    return X, Y, done
