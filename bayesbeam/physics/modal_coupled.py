"""Band-limited response of coupled modes from the eigen-solutions in band, batched.

With a sensor band (:mod:`bayesbeam.physics.sensor`) the output keeps only the
eigen-solutions ``e^{λt}`` of ``z' = A z`` with ``|λ| <= w_band``. When the damping
couples the modes (spatial hysteresis, damping that is not proportional to M or K, an
attachment), those few eigen-solutions are found here directly, without reducing the
whole state-space system: in undamped modal coordinates (``Φᵀ M Φ = I``,
``Φᵀ K Φ = Ω²``, ``C = Φᵀ D Φ`` symmetric) an eigen-solution ``q(t) = v e^{λt}`` solves
the quadratic eigenproblem

    T(λ) v = (λ² I + λ C + Ω²) v = 0,

and in the state ``z = [Ω q; q']`` of :mod:`bayesbeam.physics.propagate` its right
eigenvector is ``ψ = [Ω v; λ v]`` and its left one ``w = [-Ω v / λ; v]`` (``Aᵀ w = λ w``
because C and Ω are symmetric; Tisseur & Meerbergen 2001, §3.4). The spectral projection
of the initial state onto it gives the signal

    y(t) = Re Σ_{|λ_j| <= w_band, Im λ_j > 0} a_j e^{λ_j t},
    a_j = 2 (s·v_j) λ_j^p (v_jᵀ q0' - v_jᵀ Ω (Ω q0) / λ_j) / (v_jᵀ T'(λ_j) v_j),
    T'(λ) = 2 λ I + C,

with ``s`` the sensor's modal row and ``p`` = 0, 1, 2 for displacement, velocity and
acceleration (``λ² v = -(Ω² + λ C) v`` is the acceleration output row applied to ψ); the
factor 2 adds each root's conjugate. Nothing is truncated: every mode's coordinate of
``v_j`` (the dropped modes' share of a kept eigen-solution, the "residual flexibility")
enters, and the result equals the state-space reduction of :func:`~bayesbeam.physics.
sensor.band_limit` to rounding (tests: 1e-9 relative).

The eigenpairs come from a fixed-point iteration per mode (the kernel
:func:`~bayesbeam.physics.modal_coupled_kernel._eigenpairs_kernel_py`): λ from the
Rayleigh functional ``vᵀ T(λ) v = 0`` and the other coordinates by a Jacobi step, from
the mode's own uncoupled root. It converges when the coupling ``|λ C_ij|`` is small
against the gaps ``|λ² + λ C_ii + ω_i²|`` (lightly damped beams with distinct modes: ~10
steps); a set where it does not, or where the band might split a mode (a mode's
uncoupled roots within :data:`MARGIN` of the band edge, or an in-band mode damped beyond
ζ = 0.9 on its diagonal), is returned with ``ok = False`` and the caller reduces it
exactly the other way. Cost per set: ``2 n²`` multiply-adds per step and mode tried,
against the full reduction's Riccati iteration on the ``2n``-dimensional state.
"""

from __future__ import annotations

import numpy as np

from bayesbeam._util import compiled_kernel
from bayesbeam.physics.modal_coupled_kernel import _eigenpairs_kernel_py
from bayesbeam.physics.propagate import _pick_backend

__all__ = ["MARGIN", "band_eigenpairs", "band_terms"]

#: Relative distance to the band edge below which a mode's uncoupled roots make a set
#: ambiguous (``ok = False``): the coupling moves an eigenvalue by far less (second order
#: in ``C_ij / gap``), so a mode outside the margin is in or out of band as its own roots.
MARGIN = 0.05

#: Largest diagonal damping ratio ``C_jj / (2 ω_j)`` of a mode tried (in or near the band):
#: the iteration starts from the mode's underdamped root.
MAX_ZETA = 0.9

#: Iteration limits of the kernel: changes ≤ 1e-14 (v relative to ``v_j = 1``, λ
#: relative), at most 200 steps.
TOL = 1e-14
MAX_ITER = 200

#: Try this path only when at most this fraction of the modes is tried: beyond it the
#: per-mode iteration costs more than one reduction of the whole system.
MAX_TRIED_FRACTION = 0.5


def _roots_magnitudes(omega: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|λ|`` of the slow and fast uncoupled root of each mode (both ω when underdamped)."""
    sigma = 0.5 * c
    gap = np.abs(omega - sigma) * (omega + sigma)
    over = sigma > omega
    root = np.sqrt(gap)
    with np.errstate(divide="ignore", invalid="ignore"):
        slow = np.where(over, omega**2 / (sigma + root), omega)
    fast = np.where(over, sigma + root, omega)
    return slow, fast


def band_eigenpairs(
    omega: np.ndarray, C: np.ndarray, w_band: float, *, backend: str = "auto"
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eigen-solutions of the modal system inside the band, per set.

    Parameters
    ----------
    omega : ndarray, shape (B, n)
        Undamped modal frequencies (rad/s), ascending in each row.
    C : ndarray, shape (B, n, n)
        Symmetric modal damping matrices (1/s).
    w_band : float
        Band edge in rad/s, > 0.
    backend : {"auto", "numba", "numpy"}
        The compiled kernel ("auto": where numba imports) or the same kernel run as
        plain Python ("numpy"; slow, for tests and platforms without numba).

    Returns
    -------
    lam : ndarray of complex, shape (B, J)
        Eigenvalues (1/s, ``Im λ > 0``) of the modes tried (the first ``J`` modes);
        padding and out-of-band entries have ``keep = False``.
    V : ndarray of complex, shape (B, J, n)
        Their eigenvectors in modal coordinates.
    norm : ndarray of complex, shape (B, J)
        ``vᵀ T'(λ) v = 2 λ vᵀv + vᵀ C v`` of each (the projection's denominator).
    keep : ndarray of bool, shape (B, J)
        ``|λ| <= w_band``.
    ok : ndarray of bool, shape (B,)
        False where the path does not apply (module docstring): the caller reduces those
        sets another way. Their other outputs are meaningless.
    """
    B, n = omega.shape
    diag = np.diagonal(C, axis1=1, axis2=2)
    finite = np.isfinite(omega).all(axis=1) & np.isfinite(C).all(axis=(1, 2))
    slow, fast = _roots_magnitudes(np.where(finite[:, None], omega, 1.0),
                                   np.where(finite[:, None], diag, 0.0))
    edge_lo, edge_hi = w_band * (1 - MARGIN), w_band * (1 + MARGIN)
    # Tried: modes whose uncoupled roots reach below the upper margin.
    near = slow <= edge_hi
    J = int(np.max(np.flatnonzero(near.any(axis=0)), initial=-1)) + 1
    ok = finite.copy()
    # A mode with a root within MARGIN of the band edge: in or out is not clear-cut.
    ok &= ~(((slow > edge_lo) & (slow <= edge_hi)) | ((fast > edge_lo) & (fast <= edge_hi))
            ).any(axis=1)
    # Every tried mode underdamped on its diagonal (fast = slow = ω) with ζ <= MAX_ZETA.
    ok &= (diag[:, :J] <= 2 * MAX_ZETA * omega[:, :J]).all(axis=1)
    if J == 0 or J > MAX_TRIED_FRACTION * n or not ok.any():
        return (np.zeros((B, J), complex), np.zeros((B, J, n), complex),
                np.ones((B, J), complex), np.zeros((B, J), bool),
                np.zeros(B, bool) if J > 0 else ok)
    rows = np.flatnonzero(ok)
    args = (np.ascontiguousarray(omega[rows], dtype=float),
            np.ascontiguousarray(C[rows], dtype=float), J, MAX_ITER, TOL)
    kernel = (compiled_kernel(_eigenpairs_kernel_py, ("contract", "reassoc"))
              if _pick_backend(backend) == "numba" else _eigenpairs_kernel_py)
    lam_r, V_r, norm_r, iters = kernel(*args)
    lam = np.zeros((B, J), complex)
    V = np.zeros((B, J, n), complex)
    norm = np.ones((B, J), complex)
    lam[rows], V[rows], norm[rows] = lam_r, V_r, norm_r
    converged = np.zeros(B, bool)
    converged[rows] = (iters <= MAX_ITER).all(axis=1) & np.isfinite(lam_r).all(axis=1)
    ok &= converged
    # Two starts that found the same eigenpair (strongly coupled close modes).
    if J > 1:
        d = np.abs(lam[:, :, None] - lam[:, None, :])
        d[:, np.arange(J), np.arange(J)] = np.inf
        ok &= (d.min(axis=(1, 2)) > 1e-8 * np.abs(lam).max(axis=1))
    keep = (np.abs(lam) <= w_band) & ok[:, None]
    return lam, V, norm, keep, ok


def band_terms(
    lam: np.ndarray, V: np.ndarray, norm: np.ndarray, keep: np.ndarray, omega: np.ndarray,
    z0: np.ndarray, s: np.ndarray, quantity: str,
) -> np.ndarray:
    """Coefficients ``a_j`` of the kept eigen-solutions (module docstring).

    Parameters
    ----------
    lam, V, norm, keep : ndarray
        From :func:`band_eigenpairs`, shapes (B, J), (B, J, n), (B, J), (B, J).
    omega : ndarray, shape (B, n)
        Undamped modal frequencies (rad/s).
    z0 : ndarray, shape (B, 2n, p)
        ``p`` initial modal states ``[Ω q0; q0']`` per set.
    s : ndarray, shape (B, n) or (n,)
        Sensor modal row.
    quantity : {'displacement', 'velocity', 'acceleration'}

    Returns
    -------
    ndarray of complex, shape (B, J, p)
        ``a_j`` (units of the output) of each initial state; 0 where ``keep`` is False.
    """
    n = omega.shape[1]
    power = {"displacement": 0, "velocity": 1, "acceleration": 2}[quantity]
    s = np.broadcast_to(s, omega.shape)
    with np.errstate(all="ignore"):
        safe = np.where(keep, lam, 1.0)
        norm = np.where(keep, norm, 1.0)
        Vk = np.where(keep[..., None], V, 0.0)
        out_row = np.einsum("bjn,bn->bj", Vk, s) * safe**power
        top, bot = z0[:, :n], z0[:, n:]
        proj = np.einsum("bjn,bnp->bjp", Vk, bot) - np.einsum(
            "bjn,bnp->bjp", Vk, omega[..., None] * top) / safe[..., None]
        return np.where(keep[..., None], (2 * out_row / norm)[..., None] * proj, 0.0)
