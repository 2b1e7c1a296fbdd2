"""Compiled-on-demand kernel of :func:`bayesbeam.physics.modal_coupled.band_eigenpairs`.

Plain Python on numpy arrays, one parameter set and one mode at a time, so that numba can
compile it (:func:`bayesbeam._util.compiled_kernel`, done lazily by
:mod:`bayesbeam.physics.modal_coupled`) and so that it runs, slowly, without numba (the
tests check its logic that way). Nothing here imports numba.
"""

from __future__ import annotations

import cmath
import math

import numpy as np


def _eigenpairs_kernel_py(omega, C, tried, max_iter, tol):
    """Eigenpairs of ``(λ² I + λ C + Ω²) v = 0`` started from each of the first modes.

    For mode ``j`` (``j < tried``) of each set: ``v_j = 1`` and, alternately, λ from the
    Rayleigh functional ``vᵀ(λ² I + λ C + Ω²) v = 0`` (the root nearer the current λ)
    and, for ``i ≠ j``, the Jacobi update ``v_i ← -λ Σ_{l≠i} C_il v_l / (λ² + λ C_ii +
    ω_i²)``. A fixed point satisfies every row ``i ≠ j`` by the update and row ``j`` by
    the functional (``vᵀ T v = (T v)_j`` once the other rows vanish): an exact eigenpair.
    The start is the mode's own uncoupled root ``-C_jj/2 + i sqrt(ω_j² - C_jj²/4)``.

    Parameters
    ----------
    omega : ndarray, shape (B, n)
        Undamped modal frequencies, rad/s.
    C : ndarray, shape (B, n, n)
        Symmetric modal damping matrices, 1/s.
    tried : int
        Modes to start from (the first ``tried``), each underdamped on its diagonal.
    max_iter : int
        Most iterations per mode.
    tol : float
        Stop once the largest change of ``v`` (``v_j = 1``) and the relative change of λ
        are both at most ``tol``.

    Returns
    -------
    lam : ndarray of complex, shape (B, tried)
        Eigenvalues (1/s), ``Im λ > 0``.
    V : ndarray of complex, shape (B, tried, n)
        Eigenvectors in modal coordinates, ``V[b, j, j] = 1``.
    norm : ndarray of complex, shape (B, tried)
        ``vᵀ T'(λ) v = 2 λ vᵀv + vᵀ C v`` (no conjugation), from the last step's product.
    iters : ndarray of int64, shape (B, tried)
        Iterations used; ``max_iter + 1`` where the mode did not converge (or a value
        was not finite).

    Notes
    -----
    The real and imaginary parts of ``v`` are held in separate real arrays so that the
    product ``C v`` (real C), the cost of a step, vectorises.
    """
    B, n = omega.shape
    lam = np.zeros((B, tried), dtype=np.complex128)
    V = np.zeros((B, tried, n), dtype=np.complex128)
    norm = np.zeros((B, tried), dtype=np.complex128)
    iters = np.zeros((B, tried), dtype=np.int64)
    ur = np.zeros(n)
    ui = np.zeros(n)
    vr = np.zeros(n)
    vi = np.zeros(n)
    w2 = np.zeros(n)
    for b in range(B):
        Cb = C[b]
        for i in range(n):
            w2[i] = omega[b, i] * omega[b, i]
        for j in range(tried):
            for i in range(n):
                vr[i] = 0.0
                vi[i] = 0.0
            vr[j] = 1.0
            s = 0.5 * Cb[j, j]
            x = -s + 1j * math.sqrt(max(w2[j] - s * s, 0.0))
            vv = 1.0 + 0.0j
            vcv = 0.0j
            done = max_iter + 1
            for it in range(max_iter):
                # u = C v: the cost of a step, 2 n² multiply-adds.
                vv_r = 0.0
                vv_i = 0.0
                cv_r = 0.0
                cv_i = 0.0
                wv_r = 0.0
                wv_i = 0.0
                for i in range(n):
                    row = Cb[i]
                    ar = 0.0
                    ai = 0.0
                    for k in range(n):
                        ar += row[k] * vr[k]
                        ai += row[k] * vi[k]
                    ur[i] = ar
                    ui[i] = ai
                    sq_r = vr[i] * vr[i] - vi[i] * vi[i]
                    sq_i = 2.0 * vr[i] * vi[i]
                    vv_r += sq_r
                    vv_i += sq_i
                    cv_r += vr[i] * ar - vi[i] * ai
                    cv_i += vr[i] * ai + vi[i] * ar
                    wv_r += w2[i] * sq_r
                    wv_i += w2[i] * sq_i
                vv = vv_r + 1j * vv_i
                vcv = cv_r + 1j * cv_i
                vwv = wv_r + 1j * wv_i
                # Rayleigh functional vv x² + vcv x + vwv = 0: both roots without
                # cancellation, the one nearer the current λ.
                disc = cmath.sqrt(vcv * vcv - 4.0 * vv * vwv)
                if (vcv.real * disc.real + vcv.imag * disc.imag) >= 0.0:
                    q = -0.5 * (vcv + disc)
                else:
                    q = -0.5 * (vcv - disc)
                r1 = q / vv
                r2 = vwv / q
                x_new = r1 if abs(r1 - x) <= abs(r2 - x) else r2
                # Jacobi step in real arithmetic (numba's complex division takes a
                # branchy scaled route; |g| is far from overflow here): it vectorises.
                dv2 = 0.0
                xr = x_new.real
                xi = x_new.imag
                x2r = xr * xr - xi * xi
                x2i = 2.0 * xr * xi
                for i in range(n):
                    cii = Cb[i, i]
                    pr = ur[i] - cii * vr[i]
                    pi = ui[i] - cii * vi[i]
                    nr = -(xr * pr - xi * pi)
                    ni = -(xr * pi + xi * pr)
                    gr = x2r + xr * cii + w2[i]
                    gi = x2i + xi * cii
                    den = gr * gr + gi * gi
                    if i == j:  # g ≈ 0 there; the coordinate stays 1 (below)
                        den = 1.0
                    inv = 1.0 / den
                    zr = (nr * gr + ni * gi) * inv
                    zi = (ni * gr - nr * gi) * inv
                    if i == j:
                        zr = 1.0
                        zi = 0.0
                    d2 = (zr - vr[i]) ** 2 + (zi - vi[i]) ** 2
                    dv2 = max(dv2, d2)
                    vr[i] = zr
                    vi[i] = zi
                dv = math.sqrt(dv2)
                dl = abs(x_new - x) / abs(x_new)
                x = x_new
                if not (dv == dv and dl == dl):  # NaN: give up on this mode
                    break
                if dv <= tol and dl <= tol:
                    done = it + 1
                    break
            lam[b, j] = x
            norm[b, j] = 2.0 * x * vv + vcv
            for i in range(n):
                V[b, j, i] = vr[i] + 1j * vi[i]
            iters[b, j] = done
    return lam, V, norm, iters
