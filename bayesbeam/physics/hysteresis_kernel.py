"""Compiled-on-demand kernel of the Gaussian moments of :mod:`bayesbeam.physics.hysteresis`.

Plain Python on numpy arrays, one kernel width, one piece and one panel at a time, so that
numba can compile it (:func:`bayesbeam._util.compiled_kernel`, done lazily by
:mod:`bayesbeam.physics.hysteresis`) and so that it runs, slowly, without numba (the tests
check its logic that way). Nothing here imports numba.

Why a kernel: the batched numpy route (``HysteresisOperator._moments_panels``) expands
every (width, piece) pair into its panels and nodes through ~25 array operations on
temporaries of a few thousand numbers; measured ~5-8 µs per width on the 16-element
benchmark beam, the largest share of the modal damping's assembly once the sensor band
no longer reduces the whole system (:mod:`bayesbeam.physics.modal_coupled`).
"""

from __future__ import annotations

import math

import numpy as np


def _panel_moments_kernel_py(b, lo, wpiece, length, cut, panel, u_x, u_w, n_act, ncoef):
    """Gaussian moments of the piece bases by composite Gauss–Legendre panels.

    The same sums as ``HysteresisOperator._moments_panels`` (its docstring): for width
    ``b_k`` and piece ``p`` (start ``lo[p]``, width ``wpiece[p]``), the span below
    ``min(L, cut b_k)`` is split into ``ceil(span / (panel b_k))`` equal panels with the
    Gauss–Legendre nodes ``u_x`` and weights ``u_w`` on [0, 1]; each node adds
    ``2 g_b(u) w B_pj(u)`` with the Chebyshev basis ``T_j(2s - 1)`` (times ``s²`` on the
    first piece), ``s`` the node's place in its piece.

    Parameters
    ----------
    b : ndarray, shape (B,)
        Kernel widths in m, > 0.
    lo, wpiece : ndarray, shape (P,)
        Piece starts and widths in m (P ≥ n_act).
    length, cut, panel : float
        Beam length L (m), the Gaussian's cut-off and the widest panel, both in units of b.
    u_x, u_w : ndarray, shape (Q,)
        Gauss–Legendre nodes and weights on [0, 1].
    n_act : int
        Pieces to integrate.
    ncoef : int
        Chebyshev coefficients per piece.

    Returns
    -------
    ndarray, shape (B, n_act, ncoef)
    """
    n_b = b.shape[0]
    nq = u_x.shape[0]
    out = np.zeros((n_b, n_act, ncoef))
    t = np.zeros(ncoef)
    c0 = 2.0 / math.sqrt(2.0 * math.pi)
    for k in range(n_b):
        bk = b[k]
        reach = min(length, cut * bk)
        for p in range(n_act):
            span = min(lo[p] + wpiece[p], reach) - lo[p]
            if span <= 0.0:
                continue
            count = int(math.ceil(span / (panel * bk)))
            w_r = wpiece[p] / bk
            frac = span / (count * bk * w_r)
            lo_r = lo[p] / bk
            scale = c0 * frac * w_r
            for i in range(ncoef):
                t[i] = 0.0
            for j in range(count):
                for q in range(nq):
                    s = frac * (j + u_x[q])
                    r = lo_r + w_r * s
                    wg = scale * u_w[q] * math.exp(-0.5 * r * r)
                    if p == 0:
                        wg *= s * s
                    tau = 2.0 * s - 1.0
                    t0 = wg
                    t1 = wg * tau
                    t[0] += t0
                    t[1] += t1
                    for i in range(2, ncoef):  # Chebyshev recurrence, weighted
                        t2 = 2.0 * tau * t1 - t0
                        t[i] += t2
                        t0 = t1
                        t1 = t2
            for i in range(ncoef):
                out[k, p, i] = t[i]
    return out
