"""Compiled-on-demand kernels of the slow flow of the amplitude-dependent forward model.

Plain Python on numpy arrays, one parameter set at a time, so that numba can compile them
(:func:`bayesbeam._util.compiled_kernel`, done lazily by
:mod:`bayesbeam.physics.nonlinear`) and so that they run, slowly, without numba (the tests
check their logic that way). Nothing here imports numba. Two kernels:

* :func:`_rk4_grid_py`, the RK4 integration of the envelopes and phase. The vectorised
  route integrates a whole batch with one numpy call per RK4 stage on arrays of a few
  thousand numbers (sets × modes × drag points), so it is bound by numpy's per-call
  overhead (measured ~0.25 ms per stage on a 50 cm record, 16 sets, 5 modes, 32 drag
  points: 80 % of a drag model's forward time); compiled, a stage costs its arithmetic.
* :func:`_correction_py`, the interpolation of the flow to the sample times and the sum
  over modes, which the vectorised route forms from (sets × samples × modes) complex
  temporaries (~190 ns per sample and mode measured, against ~9 ns compiled).

Measured on the whole 50 cm record (9868 samples, 16 elements, 16 sets): a drag model
39 → 3.3 ms per set, friction 2.4 → 0.6, amplitude-dependent stiffness 3.8 → 1.0
(``studies/bench_nonlinear.py`` has the table against mesh and record length).
"""

from __future__ import annotations

import cmath
import math

import numpy as np


def _rk4_grid_py(sig, Bs, W2, wq, dcoef, fcoef, pcoef, k1, h, n_steps, N, gg, dg,
                 use_drag, use_phase):
    """Integrate the slow flow of every set with RK4 on its own grid.

    The rate is the vectorised ``rate`` of
    :meth:`bayesbeam.physics.nonlinear.NonlinearForward._slow_flow`, written out for one
    set (one function: numba compiles no calls to plain-Python helpers), with
    ``G(A, B)`` of :func:`bayesbeam.physics.nonlinear.two_tone_drag` inlined (its
    ``S = hypot(A_k, B_k)`` is ``sqrt(Σ_l B_l²)`` for every mode k, so it is taken once
    per drag point: equal to the vectorised route's to rounding).

    Parameters
    ----------
    sig : ndarray, shape (b, K)
        ``Re λ_k`` (1/s).
    Bs, W2 : ndarray, shape (b, K, nq)
        Velocity amplitude ``|c_k W_k|`` (m/s) and ``|W_k|²`` at the drag points (0 for
        inactive modes).
    wq : ndarray, shape (nq,)
        Quadrature weights (m).
    dcoef, fcoef : ndarray, shape (b, K)
        Drag and friction coefficients of the rate (``inf`` in ``fcoef``: a mode with no
        coefficient, stopped at once); a mode with ``dcoef`` 0 (no drag, or a passive
        mode) still enters the others' drag, its own is not evaluated.
    pcoef : ndarray, shape (b,)
        Phase-rate coefficient of the first mode (rad/s per unit ρ e^{στ}).
    k1 : ndarray of int64, shape (b,)
        Index of each set's first mode.
    h : ndarray, shape (b,)
        Step (s) of each set.
    n_steps : ndarray of int64, shape (b,)
        Steps of each set (``h n_steps`` = the record's end).
    N : int
        ``max(n_steps)``: rows of the grid.
    gg, dg : ndarray, shape (n + 1,)
        The drag table on ``B/S`` and its forward differences.
    use_drag, use_phase : bool

    Returns
    -------
    z_g, dz_g : ndarray, shape (N + 1, b, K + 1)
        ``(ρ_1..ρ_K, θ)`` and their derivatives at the grid nodes (rows past a set's own
        ``n_steps`` repeat its last node), as the vectorised route returns them.
    """
    b, K = sig.shape
    C = K + 1
    nq = wq.size
    nt = gg.size - 1
    z_g = np.empty((N + 1, b, C))
    dz_g = np.empty((N + 1, b, C))
    z = np.empty(C)
    ks = np.empty((4, C))  # the four RK4 stages
    arg = np.empty(C)
    r = np.empty(K)
    e = np.empty(K)
    bx = np.empty(K)
    acc = np.empty(K)
    for s in range(b):
        for k in range(K):
            z[k] = 1.0
        z[K] = 0.0
        n = n_steps[s]
        hs = h[s]
        for i in range(N + 1):
            if i > n:  # the set's grid has ended: its last node again
                for c in range(C):
                    z_g[i, s, c] = z_g[n, s, c]
                    dz_g[i, s, c] = dz_g[n, s, c]
                continue
            tau = i * hs
            for st in range(4):
                # Stage point: z, z + h/2 k1, z + h/2 k2, z + h k3.
                if st == 0:
                    ts = tau
                    for c in range(C):
                        arg[c] = z[c]
                else:
                    f = hs if st == 3 else 0.5 * hs
                    ts = tau + f
                    for c in range(C):
                        arg[c] = z[c] + f * ks[st - 1, c]
                out = ks[st]
                # --- the rate at (ts, arg)
                for k in range(K):
                    r[k] = max(arg[k], 0.0)
                    e[k] = math.exp(sig[s, k] * ts)
                    out[k] = 0.0
                    acc[k] = 0.0
                out[K] = 0.0
                if use_drag:
                    for q in range(nq):
                        tot = 0.0
                        for k in range(K):
                            bx[k] = Bs[s, k, q] * (e[k] * r[k])
                            tot += bx[k] * bx[k]
                        # G(A_k, B_k) depends on A_k only through S = hypot(A_k, B_k),
                        # and A_k² = tot - B_k²: S is the same for every mode.
                        sq = math.sqrt(tot)
                        for k in range(K):
                            if dcoef[s, k] == 0.0:  # no drag of its own (a passive mode)
                                continue
                            bb = abs(bx[k])
                            x = (bb / sq if sq > 0 else 1.0) * nt
                            j = min(int(x), nt - 1)
                            g = sq * (gg[j] + (x - j) * dg[j])
                            acc[k] += W2[s, k, q] * g * wq[q]
                    for k in range(K):
                        if dcoef[s, k] != 0.0:
                            out[k] -= r[k] * dcoef[s, k] * acc[k]
                for k in range(K):
                    if r[k] > 0 and fcoef[s, k] > 0:
                        out[k] -= fcoef[s, k] / e[k]
                if use_phase:
                    j1 = k1[s]
                    out[K] = pcoef[s] * math.exp(sig[s, j1] * ts) * r[j1]
                # --- end of the rate
                if st == 0:
                    for k in range(K):
                        if not z[k] > 0:
                            out[k] = 0.0
                    for c in range(C):
                        z_g[i, s, c] = z[c]
                        dz_g[i, s, c] = out[c]
                    if i == n:
                        break
            if i == n:
                continue
            for c in range(C):
                new = z[c] + hs / 6 * (ks[0, c] + 2 * ks[1, c] + 2 * ks[2, c] + ks[3, c])
                if c < K:
                    new = max(new, 0.0)
                if math.isnan(new):
                    new = 0.0
                z[c] = new
    return z_g, dz_g


#: Samples between two exact exponentials in :func:`_correction_py` (the products in
#: between add at most this many roundings, ~7e-15 relative; a direct exponential per
#: sample was measured 4x slower than the whole sum).
ANCHOR = 32


def _correction_py(z_g, dz_g, h, n_steps, k1, use_phase, lam_re, lam_im, X_re, X_im, p,
                   tau, dt):
    """Slow-flow correction of the signal at the sample times, set by set.

    What :meth:`bayesbeam.physics.nonlinear.NonlinearForward._interpolate` and the sum of
    ``_correction`` compute with arrays of shape (b, T, K): the cubic Hermite
    interpolation of ``ρ - 1``, ``ρ'``, ``θ``, ``θ'`` on each set's grid (a straight line
    in the step where friction stops a mode; ρ clipped at 0 after it) and the sum over
    modes of ``2 Re(X e^{λτ} [λ^p (ρ e^{iθ} - 1) + p λ^{p-1} (ρ' + iθ'ρ) e^{iθ}])``.

    Parameters
    ----------
    z_g, dz_g : ndarray, shape (N + 1, b, K + 1)
        The slow flow on the grid (:func:`_rk4_grid_py`).
    h : ndarray, shape (b,)
        Grid steps (s).
    n_steps : ndarray of int64, shape (b,)
    k1 : ndarray of int64, shape (b,)
        The mode that carries the phase θ.
    use_phase : bool
    lam_re, lam_im : ndarray, shape (b, K)
        Eigenvalues λ (1/s).
    X_re, X_im : ndarray, shape (b, K)
        Sensor weights (m; 0 for modes the sensor does not show).
    p : int
        0, 1, 2: displacement, velocity, acceleration.
    tau : ndarray, shape (T,)
        Sample times since the initial condition (s), increasing.
    dt : float
        The record's sampling step (s): across a step within ``1e-9 dt`` of it (the
        tolerance of :func:`bayesbeam.physics.forward.grid_with_holes`) ``e^{λτ}`` is the
        previous value times ``e^{λ dt}``, otherwise (a gap, every :data:`ANCHOR`-th
        sample, the first) an exact exponential.

    Returns
    -------
    ndarray, shape (b, T)
    """
    b, K = lam_re.shape
    T = tau.size
    N1 = z_g.shape[0]
    dy = np.zeros((b, T))
    cf = np.empty((N1, 4))  # envelope cubic per interval: ρ - 1, h ρ'_0, a2, a3
    cp = np.empty((N1, 4))  # phase cubic
    at = np.empty(T, dtype=np.int64)  # each sample's grid interval and place in it
    pos = np.empty(T)
    for s in range(b):
        n = n_steps[s]
        hs = h[s]
        inv_h = 1.0 / hs
        ij = 0
        for j in range(T):
            # tau increases, so the interval index only moves forward.
            sj = tau[j] * inv_h
            while ij < n - 1 and sj >= ij + 1:
                ij += 1
            at[j] = ij
            pos[j] = min(max(sj - ij, 0.0), 1.0)
        for k in range(K):
            phase = use_phase and k == k1[s]
            moves = False
            for i in range(n + 1):
                if z_g[i, s, k] != 1.0:
                    moves = True
                    break
            if not (moves or phase):
                continue  # ρ ≡ 1 and θ ≡ 0: the mode adds nothing
            for i in range(n):
                r0, r1 = z_g[i, s, k], z_g[i + 1, s, k]
                d0, d1 = dz_g[i, s, k] * hs, dz_g[i + 1, s, k] * hs
                cf[i, 0] = r0 - 1.0
                cf[i, 1] = d0
                if r0 > 0 and r1 <= 0:  # friction stops the mode in this step: a line
                    cf[i, 2] = 0.0
                    cf[i, 3] = 0.0
                else:
                    cf[i, 2] = 3 * (r1 - r0) - 2 * d0 - d1
                    cf[i, 3] = 2 * (r0 - r1) + d0 + d1
                if phase:
                    t0, t1 = z_g[i, s, K], z_g[i + 1, s, K]
                    e0, e1 = dz_g[i, s, K] * hs, dz_g[i + 1, s, K] * hs
                    cp[i, 0] = t0
                    cp[i, 1] = e0
                    cp[i, 2] = 3 * (t1 - t0) - 2 * e0 - e1
                    cp[i, 3] = 2 * (t0 - t1) + e0 + e1
            lam = complex(lam_re[s, k], lam_im[s, k])
            lp = lam**p
            ld = p * lam ** (p - 1) if p > 0 else 0j
            x2 = 2 * complex(X_re[s, k], X_im[s, k])
            step = cmath.exp(lam * dt)
            E = 0j
            for j in range(T):
                if j % ANCHOR == 0 or abs(tau[j] - tau[j - 1] - dt) > 1e-9 * dt:
                    E = cmath.exp(lam * tau[j])
                else:
                    E = E * step
                ij = at[j]
                u = pos[j]
                c0, c1, c2, c3 = cf[ij, 0], cf[ij, 1], cf[ij, 2], cf[ij, 3]
                U = c0 + u * (c1 + u * (c2 + u * c3))
                V = (c1 + u * (2 * c2 + 3 * u * c3)) * inv_h
                if U <= -1.0:  # stopped by friction
                    U = -1.0
                    V = 0.0
                P = x2 * E
                if phase:
                    TH = cp[ij, 0] + u * (cp[ij, 1] + u * (cp[ij, 2] + u * cp[ij, 3]))
                    DTH = (cp[ij, 1] + u * (2 * cp[ij, 2] + 3 * u * cp[ij, 3])) * inv_h
                    rot = complex(math.cos(TH), math.sin(TH))
                    term = (lp * (U + (1.0 + U) * (rot - 1.0))
                            + ld * (V * rot + 1j * DTH * (1.0 + U) * rot))
                    dy[s, j] += P.real * term.real - P.imag * term.imag
                else:
                    tr = lp.real * U + ld.real * V
                    ti = lp.imag * U + ld.imag * V
                    dy[s, j] += P.real * tr - P.imag * ti
    return dy
