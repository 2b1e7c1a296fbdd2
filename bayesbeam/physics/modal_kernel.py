"""Compiled-on-demand kernels of :func:`bayesbeam.physics.modal_closed.term_sum_uniform`.

Plain Python on numpy arrays, one parameter set and one term at a time, so that numba can
compile them (``numba.njit``, done lazily by :mod:`bayesbeam.physics.modal_closed`) and so
that they run, slowly, without numba (the tests check their logic that way). Nothing here
imports numba.

Layout. Stepping a term by ``z ← z r`` is one chain of dependent complex products (~8
cycles each, measured 1.5 ns per term and stamp compiled, whether in one chain or in 8
interleaved ones: the compiler vectorises neither). The kernels use the numpy route's
baby-step/giant-step factorisation instead: a table ``r^k`` (k < :data:`BABY`) per term,
built by doubling, and per block of :data:`BABY` stamps one giant factor ``s``, so that the
per-stamp work ``y[k] += Re(s r^k)`` has no dependency between stamps and compiles to SIMD
(measured 0.4 ns per term and stamp on the 2-core development machine under load).
"""

from __future__ import annotations

import math

import numpy as np

#: Stamps per block: the length of each term's power table ``r^k`` (a compile-time
#: constant for numba). Its doubling costs ``log2 BABY`` short loops per term, amortised
#: over ``n / BABY`` blocks; its rounding grows like BABY (see the kernel's Notes).
BABY = 128

#: Blocks between two exact exponentials of a term's giant factor (one complex ``exp``
#: per GIANTS · BABY = 1,024 stamps; the products in between add ≤ GIANTS roundings).
GIANTS = 8


def _term_sum_kernel_py(lam_re, lam_im, coef_re, coef_im, steps, t_first, dt, n):
    """``Re Σ_j coef_j e^{λ_j (t_first + k dt)}`` for k < ``n``, term by term.

    Parameters
    ----------
    lam_re, lam_im : ndarray, shape (B, J)
        Roots λ (1/s), ``Re λ <= 0``.
    coef_re, coef_im : ndarray, shape (B, J)
        Coefficients (units of the output).
    steps : ndarray of int64, shape (B, J)
        Stamps each term contributes to, ``k < steps[b, j] <= n``: its lifetime cut-off
        (:func:`bayesbeam.physics.modal_closed._lifetimes`), 0 for padding terms.
    t_first : float
        First stamp in s, ≥ 0.
    dt : float
        Step in s, > 0.
    n : int
        Number of stamps.

    Returns
    -------
    ndarray, shape (B, n)

    Notes
    -----
    Block ``a`` (stamps ``a BABY + k``) adds ``Re(s_a p_k)`` with ``p_k = r^k``
    (``r = e^{λ dt}``, by doubling: relative error ≲ ``(k + log2 k) ε``, ε ≈ √5 u the
    rounding of a complex product) and ``s_a = coef e^{λ t_{a BABY}}``, taken from one
    exact exponential every :data:`GIANTS` blocks and otherwise from the previous block
    times ``e^{λ BABY dt}`` (≤ ``2 GIANTS ε`` more). Each stamp of a term is therefore
    within ``(BABY + 7 + 2 GIANTS + 3) ε`` ≈ 4e-14 of ``|coef_j|`` of its exact value at
    any record length, plus the conditioning of the exponential itself, ``u |λ| t`` (the
    rounding of λ, shared by every method); the sum is within that times
    ``Σ_j |coef_j|`` (measured ≤ 2e-14 on random terms at 1,280 and 10,240 stamps).
    """
    B, J = lam_re.shape
    y = np.zeros((B, n))
    pr = np.empty(BABY)
    pi = np.empty(BABY)
    for b in range(B):
        row = y[b]
        for j in range(J):
            stop = steps[b, j]
            if stop <= 0:
                continue
            a, w = lam_re[b, j], lam_im[b, j]
            cr, ci = coef_re[b, j], coef_im[b, j]
            g = math.exp(a * dt)
            rr, ri = g * math.cos(w * dt), g * math.sin(w * dt)
            # The table r^k, k < width, by doubling: block [h, 2h) is block [0, h) times
            # r^h (no dependency between its iterations), r^h squared once per block.
            width = min(BABY, stop)
            pr[0] = 1.0
            pi[0] = 0.0
            h = 1
            while h < width:
                span = min(h, width - h)
                for k in range(span):
                    pr[h + k] = pr[k] * rr - pi[k] * ri
                    pi[h + k] = pr[k] * ri + pi[k] * rr
                h += span
                x = rr * rr - ri * ri
                ri = 2.0 * rr * ri
                rr = x
            Gr = Gi = 0.0
            if stop > BABY:  # the giant factor e^{λ BABY dt}, exact
                g = math.exp(a * BABY * dt)
                Gr, Gi = g * math.cos(w * BABY * dt), g * math.sin(w * BABY * dt)
            sr = 0.0
            si = 0.0
            block = 0
            for k0 in range(0, stop, BABY):
                if block % GIANTS == 0:  # exact anchor: coef e^{λ t_k0}
                    t = t_first + k0 * dt
                    g = math.exp(a * t)
                    er, ei = g * math.cos(w * t), g * math.sin(w * t)
                    sr, si = cr * er - ci * ei, cr * ei + ci * er
                else:
                    x = sr * Gr - si * Gi
                    si = sr * Gi + si * Gr
                    sr = x
                block += 1
                seg = row[k0 : min(stop, k0 + BABY)]
                for k in range(seg.size):
                    seg[k] += sr * pr[k] - si * pi[k]
    return y


def _rotations_kernel_py(rot_re, rot_im, n):
    """Sum ``Re Σ_j r_j^k`` for k < ``n`` and nothing else: the benchmark's bare loop.

    The ``m × T`` complex rotations in the layout of :func:`_term_sum_kernel_py` (power
    table, giant factor, one multiply-add per stamp) without coefficients, lifetimes or
    exact anchors: the practical limit of any per-sample method
    (:mod:`bayesbeam.jobs.bench`).

    Parameters
    ----------
    rot_re, rot_im : ndarray, shape (B, m)
        One-step factors ``r_j`` of the modes.
    n : int
        Number of stamps.

    Returns
    -------
    ndarray, shape (B, n)
    """
    B, m = rot_re.shape
    y = np.zeros((B, n))
    pr = np.empty(BABY)
    pi = np.empty(BABY)
    for b in range(B):
        row = y[b]
        for j in range(m):
            rr, ri = rot_re[b, j], rot_im[b, j]
            # The same doubling as _term_sum_kernel_py; rr + i ri ends as r^BABY when
            # n >= BABY (the giant factor).
            width = min(BABY, n)
            pr[0] = 1.0
            pi[0] = 0.0
            h = 1
            while h < width:
                span = min(h, width - h)
                for k in range(span):
                    pr[h + k] = pr[k] * rr - pi[k] * ri
                    pi[h + k] = pr[k] * ri + pi[k] * rr
                h += span
                x = rr * rr - ri * ri
                ri = 2.0 * rr * ri
                rr = x
            Gr, Gi = rr, ri
            sr = 1.0
            si = 0.0
            for k0 in range(0, n, BABY):
                seg = row[k0 : min(n, k0 + BABY)]
                for k in range(seg.size):
                    seg[k] += sr * pr[k] - si * pi[k]
                x = sr * Gr - si * Gi
                si = sr * Gi + si * Gr
                sr = x
    return y
