"""Compiled-on-demand kernel of the invariant-subspace iteration of :mod:`bayesbeam.physics.sensor`.

The fixed-point iteration of :func:`bayesbeam.physics.sensor._invariant_reduction`, one
parameter set at a time, written as plain Python on numpy arrays so that numba can
compile it (:func:`bayesbeam.physics.modal_closed.compiled_kernel`, done lazily by
:mod:`bayesbeam.physics.sensor`) and so that it runs, slowly, without numba (the tests
check its logic that way). Nothing here imports numba.

Why a kernel: the iteration multiplies thin blocks (the dropped modes' ``2r x 2k``
coupling) ~30 times per set; the batched numpy route pays, per step, a pass over every
set's dense ``r x r`` block to gather the sets still iterating, and temporaries of the
whole batch, which measured ~4 ms per set on a 32-element beam with two modes in band.
Here each set's blocks stay in cache for all its steps.
"""

from __future__ import annotations

import math

import numpy as np


def _riccati_kernel_py(P, wi, A11, A12, A21, max_iter, tol):
    """Solve the two block Riccati equations of each set by fixed-point iteration.

    ``X = A22⁻¹ (X A11 + X A12 X - A21)`` and ``Y = (A11 Y + A12 - Y A21 Y) A22⁻¹``
    in the factored form of the numpy route, with ``A22⁻¹`` applied through its blocks
    ``P = -Ω⁻¹ C Ω⁻¹`` and ``wi = 1/ω`` (``A⁻¹ Z = [P Z_top - wi Z_bot; wi Z_top]``,
    ``Z A⁻¹ = [Z_left P + Z_right wi, -Z_left wi]``). A set stops once the relative
    Frobenius changes of both iterates are at most ``tol``, or when one is not finite.

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
    X = np.zeros((B, 2 * r, n))
    Y = np.zeros((B, n, 2 * r))
    done = np.zeros(B, dtype=np.bool_)
    for b in range(B):
        Pb = np.ascontiguousarray(P[b])
        w = wi[b]
        a11 = np.ascontiguousarray(A11[b])
        a12 = np.ascontiguousarray(A12[b])
        a21 = np.ascontiguousarray(A21[b])
        ax = np.empty((2 * r, n))
        ya = np.empty((n, 2 * r))
        # Step 0 applies A22⁻¹ to A21 and A12 (the constant terms) and starts the
        # iterates there; every later step applies it to the iterates.
        x = a21.copy()
        y = a12.copy()
        ai_a21 = np.empty((2 * r, n))
        a12_ai = np.empty((n, 2 * r))
        for it in range(max_iter + 1):
            # A22⁻¹ x and y A22⁻¹ through the blocks.
            ax[:r] = Pb @ x[:r]
            ya[:, :r] = np.ascontiguousarray(y[:, :r]) @ Pb
            for i in range(r):
                for j in range(n):
                    ax[i, j] -= w[i] * x[r + i, j]
                    ax[r + i, j] = w[i] * x[i, j]
                    ya[j, i] += y[j, r + i] * w[i]
                    ya[j, r + i] = -y[j, i] * w[i]
            if it == 0:
                ai_a21[:] = ax
                a12_ai[:] = ya
                x = -ai_a21
                y = a12_ai.copy()
                continue
            xn = ax @ (a11 + a12 @ x) - ai_a21
            yn = (a11 - y @ a21) @ ya + a12_ai
            dx = math.sqrt(np.sum((xn - x) ** 2) / max(np.sum(xn * xn), 1e-300))
            dy = math.sqrt(np.sum((yn - y) ** 2) / max(np.sum(yn * yn), 1e-300))
            x = xn
            y = yn
            if dx <= tol and dy <= tol:
                done[b] = True
                break
            if not (math.isfinite(dx) and math.isfinite(dy)):
                break
        X[b] = x
        Y[b] = y
    return X, Y, done
