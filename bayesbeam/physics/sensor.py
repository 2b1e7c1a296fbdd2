"""The sensor's band: what an anti-alias-filtered sensor records of a free vibration.

A sensor records the beam through an anti-alias filter; with a ``bandwidth`` the forward
model's output is what an ideal linear-phase low-pass with that cut-off would record once
it has settled: every free-vibration eigen-solution ``e^{λt}`` of ``z' = A z`` with
``|λ| <= 2π·bandwidth`` passes unchanged and every other one is removed (see
:mod:`bayesbeam.physics.forward`, and data/README.md "Sensor band" for the trial key).

:func:`band_limit` applies it to a batch of modal state-space systems by three routes,
each exact for what it covers:

* classically damped sets: the eigen-solutions of mode k are those of its own 2x2 block,
  so the modes above the band are cut out of the system;
* coupled sets (spatial hysteresis, non-proportional damping): the system restricted to
  the invariant subspace of the kept modes, from two block Riccati equations solved by
  iteration (:func:`_invariant_reduction`: mode-decoupled Sylvester steps where the
  coupling is weak, else a plain fixed-point iteration); a small real system of the
  kept modes' dimension, no eigendecomposition;
* where that iteration does not converge (a mode too close to the band edge) or the
  band splits a mode's two roots: the spectral projection from left and right
  eigenvectors (:func:`_eigen_projection`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from bayesbeam._util import compiled_kernel
from bayesbeam.physics.propagate import _pick_backend
from bayesbeam.physics.sensor_kernel import _decoupled_kernel_py, _riccati_kernel_py

__all__ = ["band_limit", "check_bandwidth"]


def check_bandwidth(bandwidth: object, error: type[Exception] = ValueError) -> float | None:
    """Return a sensor bandwidth in Hz (None for an unlimited band), or raise ``error``.

    Parameters
    ----------
    bandwidth : object
        None, inf (unlimited) or a positive number of Hz.
    error : type of Exception
        Raised with a message saying what is wrong.

    Returns
    -------
    float or None
    """
    if bandwidth is None:
        return None
    if isinstance(bandwidth, bool) or not isinstance(bandwidth, (int, float, np.number)):
        raise error(f"bandwidth must be a number of Hz or None, got {bandwidth!r}")
    b = float(bandwidth)
    if np.isnan(b) or b <= 0:
        raise error(f"bandwidth must be > 0 Hz (inf or None: unlimited), got {b}")
    return None if np.isinf(b) else b


def band_limit(
    A: np.ndarray, z0: np.ndarray, h: np.ndarray, omega: np.ndarray, C: np.ndarray,
    w_band: float, *, backend: str = "auto",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep only the eigen-solutions of z' = A z with ``|λ| <= w_band`` (ideal low-pass).

    Parameters
    ----------
    A : ndarray, shape (B, 2m, 2m)
        Modal state matrices, state ``z = [Ω q; q']``.
    z0 : ndarray, shape (B, 2m) or (B, 2m, p)
        Initial states; with a last axis, ``p`` initial states of each system (the
        responses to each of ``p`` linear amplitudes), reduced with one reduction.
    h : ndarray, shape (B, 2m)
        Output rows.
    omega : ndarray, shape (B, m)
        Undamped modal frequencies (rad/s), ascending in each row.
    C : ndarray, shape (B, m, m)
        Modal damping matrices (1/s).
    w_band : float
        Cut-off in rad/s.
    backend : {"auto", "numba", "numpy"}
        Route of the coupled sets' iteration (:func:`_invariant_reduction`): compiled
        (:mod:`bayesbeam.physics.sensor_kernel`; "auto" where numba imports) or batched
        numpy; the same results to rounding.

    Returns
    -------
    A, z0, h : ndarray
        For a batch whose damping does not couple kept and dropped modes (classical
        damping, to 1e-10), the system reduced to its lowest
        ``m'`` modes (``m'`` the largest number of modes any set keeps; the coordinates
        of a set's dropped modes are zero); otherwise the same matrices with ``z0``
        replaced by its spectral projection ``P z0`` onto the kept eigen-solutions.
        Rows of sets with non-finite input are returned unchanged (the caller flags them).
    """
    B, m = omega.shape
    cols = (1,) * (z0.ndim - 2)  # trailing axis of several initial states, if any
    diag = np.diagonal(C, axis1=1, axis2=2)
    # Mode k's two roots: -c/2 ± sqrt(c²/4 - ω²); underdamped roots have |λ| = ω.
    disc = 0.25 * diag**2 - omega**2
    over = disc > 0
    root = np.sqrt(np.where(over, disc, 0.0))
    fast = np.where(over, 0.5 * diag + root, omega)
    slow = np.where(over, 0.5 * diag - root, omega)
    keep = fast <= w_band
    # Zeroing a mode's coordinates removes exactly its eigen-solutions when the damping
    # does not couple it to a kept mode. A coupling C_ij tilts the eigenvectors by about
    # C_ij / |ω_i - ω_j|; below 1e-10 (round-off of Φᵀ D Φ is ~1e-16 of the largest
    # entry) the sets take the fast route, with the dropped modes cut out of the system.
    # Otherwise (spatial hysteresis, non-proportional damping), or for an overdamped
    # mode with one root in the band and one out, the eigenvector route.
    # Only rows of kept modes enter (a prefix of the modes up to the highest kept one:
    # 16x fewer pairs than all m x m at 2 of 32 modes kept).
    upto = int(np.max(np.flatnonzero(keep.any(axis=0)), initial=-1)) + 1
    with np.errstate(divide="ignore", invalid="ignore"):
        gap = np.abs(omega[:, :upto, None] - omega[:, None, :])
        ratio = np.abs(C[:, :upto]) / gap
    cross = keep[:, :upto, None] & ~keep[:, None, :]
    coupling = np.max(np.where(cross, ratio, 0.0), axis=(1, 2), initial=0.0)
    classical = (coupling <= 1e-10) & ~((slow <= w_band) & ~keep).any(axis=1)
    finite = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(z0).reshape(B, -1).all(axis=1)
    # z0 with the dropped modes' coordinates zeroed (both halves of z = [Ω q; q']).
    zc = np.where(np.concatenate([keep, keep], axis=1).reshape(B, 2 * m, *cols), z0, 0.0)
    if np.all(classical | ~finite):
        z0 = zc
        k = int(np.max(np.count_nonzero(keep & finite[:, None], axis=1), initial=0))
        k = max(k, 1)  # a set with no mode in band keeps a zero state of one mode
        sel = np.r_[0:k, m : m + k]
        return A[:, sel][:, :, sel], z0[:, sel], h[:, sel]
    # Coupled sets: the kept modes' invariant subspace (:func:`_invariant_reduction`),
    # where the iteration converges and the band splits no mode; else the eigenvectors.
    coupled = finite & ~classical
    straddle = ((slow <= w_band) & ~keep).any(axis=1)
    red: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
    # Sets grouped by the modes they keep (np.unique(..., axis=0) on a bool matrix took
    # ~1.4 ms per batch of 64; a dict of row bytes a few µs).
    groups: dict[bytes, list[int]] = {}
    for b in np.flatnonzero(coupled & ~straddle):
        groups.setdefault(keep[b].tobytes(), []).append(int(b))
    for members in groups.values():
        kept = np.flatnonzero(keep[members[0]])
        if kept.size == 0:
            continue
        rows = np.asarray(members)
        K = np.r_[kept, m + kept]
        # Every set in one group (the usual case): no copy of the whole batch.
        sub = slice(None) if rows.size == B else rows
        M, a, g, P, ok = _invariant_reduction(A[sub], z0[sub], h[sub], K, w_band,
                                             backend=backend)
        for j in np.flatnonzero(ok):
            red[int(rows[j])] = (M[j], a[j], g[j], P[j])
    reducible = classical | ~finite
    reducible[list(red)] = True
    if np.all(reducible):
        k = max([int(np.count_nonzero(keep[b])) for b in np.flatnonzero(finite)] + [1])
        d = 2 * k
        Ar, zr, hr = np.zeros((B, d, d)), np.zeros((B, d, *z0.shape[2:])), np.zeros((B, d))
        cls = classical | ~finite
        sel = np.r_[0:k, m : m + k]
        Ar[cls], zr[cls], hr[cls] = A[cls][:, sel][:, :, sel], zc[cls][:, sel], h[cls][:, sel]
        for b, (M, a, g, _) in red.items():
            n = M.shape[0]
            # Zero padding: a block with A = 0, z0 = 0, h = 0 contributes nothing.
            Ar[b, :n, :n], zr[b, :n], hr[b, :n] = M, a, g
        return Ar, zr, hr
    z0 = z0.copy()
    for b in np.flatnonzero(finite):
        if classical[b]:
            z0[b] = zc[b]
        elif b in red:
            z0[b] = red[b][3]
        else:
            z0[b] = _eigen_projection(A[b], z0[b], w_band)
    return A, z0, h


def _eigen_projection(A: np.ndarray, z0: np.ndarray, w_band: float) -> np.ndarray:
    """Return ``P z0`` for one state matrix from its left and right eigenvectors.

    ``P z0 = Σ_k v_k (w_kᴴ z0) / (w_kᴴ v_k)`` over the eigenvalues with ``|λ| <= w_band``:
    each term is as well conditioned as its own eigenvalue, where solving with the whole
    eigenvector matrix would carry the condition number of the stiff (heavily damped)
    modes into the kept ones. About 1 ms for 32 modes: the fallback route.
    """
    lam, Wl, Vr = sla.eig(A, left=True, right=True)
    inband = np.abs(lam) <= w_band
    Wk, Vk = Wl[:, inband], Vr[:, inband]
    norm = np.einsum("ik,ik->k", Wk.conj(), Vk)
    coef = (Wk.conj().T @ z0) / norm.reshape(norm.shape + (1,) * (z0.ndim - 1))
    return (Vk @ coef).real


#: Iterations and relative tolerance of the invariant-subspace iteration.
MAX_ITERATIONS, TOLERANCE = 200, 1e-12
#: Steps of the mode-decoupled iteration, and the slowest contraction per step it keeps
#: going at. A step does the plain iteration's two products with the dense coupling
#: block plus the pairs' 4x4 solves and the kept block's products (up to ~3x a plain
#: step's work at 4 kept and 28 dropped modes, about 1x as the dropped block grows);
#: the plain iteration contracts by 0.3-0.6, so a decoupled one slower than 0.25 per
#: step would not pay for itself (a conservative bound, not tuned).
DECOUPLED_ITERATIONS, DECOUPLED_RATIO = 30, 0.25


def _invariant_reduction(
    A: np.ndarray, z0: np.ndarray, h: np.ndarray, K: np.ndarray, w_band: float, *,
    backend: str = "auto",
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exact reduction of z' = A z to the invariant subspace of the kept modes.

    With the state split into kept (``K``) and dropped coordinates, the subspace of the
    kept eigen-solutions is spanned by ``[I; X]`` and that of the dropped ones by
    ``[Y; I]``, where (block Riccati equations; Stewart & Sun 1990, Matrix Perturbation
    Theory, §V.2)::

        X = A22⁻¹ (X A11 + X A12 X - A21),    Y = (A11 Y + A12 - Y A21 Y) A22⁻¹.

    They are solved first by the mode-decoupled iteration
    (:func:`~bayesbeam.physics.sensor_kernel._decoupled_kernel_py`), which contracts
    by about |coupling| / |λ_dropped - λ_kept| per step: a point mass's rank-one
    viscous coupling on a whole aluminium record, 3 steps. The sets where it contracts
    slower than :data:`DECOUPLED_RATIO` take the plain fixed-point iterations above,
    which contract by about |λ|max(kept) / |λ|min(dropped) per step whatever the
    coupling (modes well inside and well outside the band: 0.3-0.6, 30-50 steps to
    1e-12). Measured on Al 60 cm #1 (16 elements, 4 of 32 modes kept, a point mass):
    the reduction 0.66 → 0.12 ms per set, the whole log density 1.40 → 0.74 ms.
    Writing ``z0 = [I; X] a + [Y; I] b`` gives ``a = (I - Y X)⁻¹ (z0_K - Y z0_D)``, and the
    kept part of the response is exactly that of the small real system
    ``a' = (A11 + A12 X) a``, ``y = (h_K + h_D X) a``: the projection of
    :func:`_eigen_projection` without an eigendecomposition of A, and a propagation of
    ``len(K)`` states instead of all. ``A22`` is the dropped modes' own modal state
    matrix, inverted in closed form (:func:`_modal_inverse_blocks`).

    Parameters
    ----------
    A : ndarray, shape (B, s, s)
        Modal state matrices (:func:`bayesbeam.physics.propagate.state_matrix` form).
    z0 : ndarray, shape (B, s) or (B, s, p)
    h : ndarray, shape (B, s)
    K : ndarray of int, shape (2k,)
        Kept state coordinates (``[Ω q; q']`` of the kept modes).
    w_band : float
        Cut-off in rad/s.
    backend : {"auto", "numba", "numpy"}
        As :func:`band_limit`'s.

    Returns
    -------
    M : ndarray, shape (B, 2k, 2k)
    a, g : ndarray, shape (B, 2k) (``a``: (B, 2k, p) for several initial states)
        Reduced initial state and output row.
    Pz0 : ndarray, shape (B, s) or (B, s, p)
        The projected full state (for the full-size route).
    ok : ndarray of bool, shape (B,)
        Converged, finite, and every eigenvalue of M inside the band (else the set
        takes :func:`_eigen_projection`).
    """
    m = A.shape[1] // 2
    dropped = np.ones(m, dtype=bool)
    dropped[K[: K.size // 2]] = False
    dm = np.flatnonzero(dropped)  # the dropped modes
    D = np.r_[dm, m + dm]
    # One gather per block, of that block only (chained fancy indexing copied the whole
    # state matrix twice: ~0.5 ms per set at 64 modes); A22 is never formed, only its
    # blocks -C_DD and Ω_D (A = [[0, Ω], [-Ω, -C]]).
    A11, A12, A21 = A[:, K[:, None], K], A[:, K[:, None], D], A[:, D[:, None], K]
    B, n = A.shape[0], K.size
    ok = np.ones(B, dtype=bool)
    with np.errstate(all="ignore"):
        if dm.size and np.all(np.diff(dm) == 1):  # the usual case: slices, no gather
            lo, hi = dm[0], dm[-1] + 1
            omega_d = np.diagonal(A[:, lo:hi, m + lo : m + hi], axis1=1, axis2=2)
            neg_c = A[:, m + lo : m + hi, m + lo : m + hi]
        else:
            omega_d, neg_c = A[:, dm, m + dm], A[:, (m + dm)[:, None], m + dm]
        numba = _use_numba(backend)
        # The mode-decoupled iteration first (a few steps where the coupling is weak
        # against the gap between kept and dropped modes); the sets it leaves take the
        # plain fixed-point iteration.
        blocks = [np.ascontiguousarray(v) for v in (omega_d, neg_c, A11, A12, A21)]
        if numba:
            X, Y, done = compiled_kernel(_decoupled_kernel_py, ("contract", "reassoc"))(
                *blocks, DECOUPLED_ITERATIONS, TOLERANCE, DECOUPLED_RATIO)
        else:
            X, Y, done = _decoupled_numpy(*blocks)
        rest = np.flatnonzero(~done)
        if rest.size:
            P, wi = _inverse_blocks(omega_d[rest], neg_c[rest])
            sub = [np.ascontiguousarray(v) for v in (P, wi, A11[rest], A12[rest], A21[rest])]
            if numba:
                out = compiled_kernel(_riccati_kernel_py, ("contract", "reassoc"))(
                    *sub, MAX_ITERATIONS, TOLERANCE)
            else:
                out = _riccati_numpy(*sub)
            X[rest], Y[rest], done[rest] = out
        ok &= done
        M = A11 + A12 @ X
        # z0 as columns (B, s, p): one or several initial states of each set.
        Z = z0 if z0.ndim == 3 else z0[..., None]
        rhs = Z[:, K] - Y @ Z[:, D]
        IYX = np.eye(n) - Y @ X
        # A set that did not converge (it diverged: huge or non-finite blocks, where
        # I - Y X can be exactly singular) is flagged and solved as the identity, so
        # that LAPACK does not stop the batch.
        ok &= np.isfinite(IYX).all(axis=(1, 2)) & np.isfinite(rhs).all(axis=(1, 2))
        IYX[~ok] = np.eye(n)
        a = np.linalg.solve(IYX, np.where(ok[:, None, None], rhs, 0.0))
        g = h[:, K] + np.einsum("bj,bjk->bk", h[:, D], X)
        Pz0 = np.zeros_like(Z)
        Pz0[:, K] = a
        Pz0[:, D] = X @ a
        ok &= np.isfinite(M).all(axis=(1, 2)) & np.isfinite(a).all(axis=(1, 2))
        if z0.ndim == 2:
            a, Pz0 = a[..., 0], Pz0[..., 0]
        ok &= np.isfinite(g).all(axis=1)
        lam = np.linalg.eigvals(np.where(ok[:, None, None], M, 0.0))
    ok &= (np.abs(lam) <= w_band).all(axis=1)
    return M, a, g, Pz0, ok





def _riccati_numpy(P: np.ndarray, wi: np.ndarray, A11: np.ndarray, A12: np.ndarray,
                   A21: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the iteration of :func:`~bayesbeam.physics.sensor_kernel._riccati_kernel_py`, batched.

    The route without numba (same arguments but the limits, which are the module's;
    same results to rounding).
    """
    B = P.shape[0]
    AiA21, A12Ai = _inverse_left(P, wi, A21), _inverse_right(P, wi, A12)
    X, Y = -AiA21, A12Ai.copy()  # updated in place below
    # The iteration in factored form: X A11 + X A12 X = X (A11 + A12 X) and
    # A11 Y - Y A21 Y = (A11 - Y A21) Y, so that each step multiplies A22⁻¹ by a thin
    # (s - 2k) x 2k block only (the state's full dimension never appears squared),
    # and through its blocks (_inverse_left/_right): one product with the dense
    # (s/2 - k)² block instead of the (s - 2k)² inverse, 4x fewer operations.
    # A set stops iterating once it has converged (or failed): its iterates do not
    # depend on when the other sets of its batch converge, and the remaining steps
    # cost only the sets still iterating.
    done = np.zeros(B, dtype=bool)
    act = np.arange(B)
    blocks = (P, wi, A11, A12, A21, AiA21, A12Ai)
    for _ in range(MAX_ITERATIONS):
        Pa, wa, A11a, A12a, A21a, AiA21a, A12Aia = (
            blocks if act.size == B else tuple(v[act] for v in blocks))
        Xa, Ya = X[act], Y[act]
        Xn = _inverse_left(Pa, wa, Xa) @ (A11a + A12a @ Xa) - AiA21a
        Yn = (A11a - Ya @ A21a) @ _inverse_right(Pa, wa, Ya) + A12Aia
        dx = _rel_change(Xn, Xa)
        dy = _rel_change(Yn, Ya)
        X[act], Y[act] = Xn, Yn
        conv = (dx <= TOLERANCE) & (dy <= TOLERANCE)
        done[act[conv]] = True
        act = act[~conv & np.isfinite(dx) & np.isfinite(dy)]
        if act.size == 0:
            break
    return X, Y, done


def _decoupled_numpy(wd: np.ndarray, ndd: np.ndarray, A11: np.ndarray, A12: np.ndarray,
                     A21: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run the iteration of :func:`~bayesbeam.physics.sensor_kernel._decoupled_kernel_py`, batched.

    The route without numba (the module's limits; same results to rounding). Each set
    stops on its own, as in :func:`_riccati_numpy`, so that its result does not depend
    on the batch it comes in.
    """
    B, r = wd.shape
    n = A11.shape[1]
    k = n // 2
    jj, ii = np.arange(k), np.arange(r)
    D11 = A11.copy()
    for p, q in ((jj, jj), (jj, k + jj), (k + jj, jj), (k + jj, k + jj)):
        D11[:, p, q] = 0.0
    off = ndd.copy()
    off[:, ii, ii] = 0.0
    a2 = np.zeros((B, r, 1, 2, 2))  # dropped modes' own blocks
    a2[..., 0, 0, 1], a2[..., 0, 1, 0] = wd, -wd
    a2[..., 0, 1, 1] = ndd[:, ii, ii]
    c2 = np.stack([np.stack([A11[:, jj, jj], A11[:, jj, k + jj]], -1),
                   np.stack([A11[:, k + jj, jj], A11[:, k + jj, k + jj]], -1)], -2)[:, None]
    eye = np.eye(2)

    def op(left: np.ndarray, right: np.ndarray) -> np.ndarray:
        # The 4x4 operator of  left z - z right  on a 2x2 block z (row-major entries).
        t = (np.einsum("...pu,qv->...pquv", left, eye)
             - np.einsum("pu,...vq->...pquv", eye, right))
        return t.reshape(t.shape[:-4] + (4, 4))

    X, Y = np.zeros((B, 2 * r, n)), np.zeros((B, n, 2 * r))
    done = np.zeros(B, dtype=bool)
    with np.errstate(all="ignore"):
        MX, MY = op(a2, c2), op(c2, a2)  # (B, r, k, 4, 4): the two terms broadcast
        good = (np.isfinite(MX).all(axis=(1, 2, 3, 4)) & np.isfinite(MY).all(axis=(1, 2, 3, 4))
                & (np.abs(np.linalg.det(MX)) > 0).all(axis=(1, 2))
                & (np.abs(np.linalg.det(MY)) > 0).all(axis=(1, 2)))
        TX, TY = np.zeros_like(MX), np.zeros_like(MY)
        TX[good], TY[good] = np.linalg.inv(MX[good]), np.linalg.inv(MY[good])
        act = np.flatnonzero(good)
        prev = np.full(B, np.inf)
        for it in range(DECOUPLED_ITERATIONS):
            Xa, Ya = X[act], Y[act]
            rx = Xa @ (A12[act] @ Xa + D11[act]) - A21[act]
            rx[:, r:] -= off[act] @ Xa[:, r:]
            ry = (Ya @ A21[act] - D11[act]) @ Ya - A12[act]
            ry[:, :, r:] += Ya[:, :, r:] @ off[act]
            # Blocks: X rows (p, i), columns (q, j); Y rows (p, j), columns (q, i).
            vx = rx.reshape(-1, 2, r, 2, k).transpose(0, 2, 4, 1, 3).reshape(-1, r, k, 4)
            vy = ry.reshape(-1, 2, k, 2, r).transpose(0, 4, 2, 1, 3).reshape(-1, r, k, 4)
            bx = np.einsum("brkpq,brkq->brkp", TX[act], vx).reshape(-1, r, k, 2, 2)
            by = np.einsum("brkpq,brkq->brkp", TY[act], vy).reshape(-1, r, k, 2, 2)
            Xn = bx.transpose(0, 3, 1, 4, 2).reshape(-1, 2 * r, n)
            Yn = by.transpose(0, 3, 2, 4, 1).reshape(-1, n, 2 * r)
            dx, dy = _rel_change(Xn, Xa), _rel_change(Yn, Ya)
            X[act], Y[act] = Xn, Yn
            conv = (dx <= TOLERANCE) & (dy <= TOLERANCE)
            done[act[conv]] = True
            d = np.maximum(dx, dy)
            going = ~conv & np.isfinite(d)
            if it >= 2:
                going &= d <= DECOUPLED_RATIO * prev[act]
            prev[act] = d
            act = act[going]
            if act.size == 0:
                break
    return X, Y, done


def _use_numba(backend: str) -> bool:
    """Whether the iteration runs compiled ('auto': where numba imports; 'numba', 'numpy')."""
    return _pick_backend(backend) == "numba"


def _rel_change(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Frobenius norm of ``new - old`` relative to that of ``new``, per batch entry."""
    d = new - old
    num = np.einsum("bij,bij->b", d, d)
    den = np.einsum("bij,bij->b", new, new)
    return np.sqrt(num / np.maximum(den, 1e-300))


def _modal_inverse_blocks(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the blocks of the inverse of modal state matrices ``A = [[0, Ω], [-Ω, -C]]``.

    ``A⁻¹ = [[-Ω⁻¹ C Ω⁻¹, -Ω⁻¹], [Ω⁻¹, 0]]`` (multiply out: the blocks give I, 0, 0, I),
    with Ω diagonal: no factorisation, and exact where an LU would lose the digits of the
    stiff modes. A zero ω gives non-finite entries, which the caller flags. Applied by
    :func:`_inverse_left` and :func:`_inverse_right` without forming ``A⁻¹``.

    Parameters
    ----------
    A : ndarray, shape (B, 2r, 2r)
        State matrices of :func:`bayesbeam.physics.propagate.state_matrix` form (here the
        dropped modes' block of one).

    Returns
    -------
    P : ndarray, shape (B, r, r)
        ``-Ω⁻¹ C Ω⁻¹``.
    wi : ndarray, shape (B, r)
        ``1/ω``.
    """
    r = A.shape[1] // 2
    return _inverse_blocks(np.diagonal(A[:, :r, r:], axis1=1, axis2=2), A[:, r:, r:])


def _inverse_blocks(omega: np.ndarray, neg_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``P = -Ω⁻¹ C Ω⁻¹`` and ``1/ω`` from ω (B, r) and ``-C`` (B, r, r)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        wi = 1.0 / omega
        P = wi[:, :, None] * neg_c * wi[:, None, :]
    return P, wi


def _inverse_left(P: np.ndarray, wi: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``A⁻¹ Z`` from the blocks of :func:`_modal_inverse_blocks`; Z of shape (B, 2r, n)."""
    r = wi.shape[1]
    top, bot = Z[:, :r], Z[:, r:]
    return np.concatenate([P @ top - wi[:, :, None] * bot, wi[:, :, None] * top], axis=1)


def _inverse_right(P: np.ndarray, wi: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``Z A⁻¹`` from the blocks of :func:`_modal_inverse_blocks`; Z of shape (B, n, 2r)."""
    r = wi.shape[1]
    left, right = Z[:, :, :r], Z[:, :, r:]
    return np.concatenate([left @ P + right * wi[:, None, :], -left * wi[:, None, :]], axis=2)
