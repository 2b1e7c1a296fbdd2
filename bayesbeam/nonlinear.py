"""Amplitude-dependent damping: quadratic air drag and dry clamp friction (physics.md §3).

The ``amplitude_damping`` extension (:data:`bayesbeam.models.NONLINEAR`) adds two
parameters to a linear model:

``drag`` (c_q, kg/m²)
    Quadratic air drag, a distributed force per unit length ``-c_q |w_t| w_t`` (N/m).
    For a strip of width b vibrating flat-on, ``c_q = ½ rho_air C_D b``; a 50.8 mm strip
    in air (rho_air = 1.2 kg/m³) gives ``c_q ≈ 0.03 C_D``. Oscillating flat plates at the
    small Keulegan–Carpenter numbers of a release test (KC = 2π a/b ~ 1–5) have drag
    coefficients of several units (C_D ~ 3–10, Graham 1980, J. Fluid Mech. 97, 331), so
    ``c_q`` of order 0.05–0.3 kg/m² is physical.
``friction`` (F_c, N)
    Dry (Coulomb) friction at the clamp. A rigid clamp has no rotation for a Coulomb
    moment to act on, and fitting a friction moment on a root spring would tie the
    parameter to the root-spring extension; so the clamp's friction is represented, for
    every clamp, by its effect on the fundamental mode: a Coulomb generalised force
    ``-F_c |s_1| sign(q_1')`` on the first undamped modal coordinate ``q_1``
    (Φ M-orthonormal, ``s_1 = φ_1(L)`` its tip deflection per unit ``q_1``). In dof
    space this is the force vector ``F_c |s_1| sign(φ_1ᵀ M c') M φ_1``. It dissipates,
    per cycle, ``4 F_c`` times the tip amplitude of the first mode, as a Coulomb slider
    of force F_c on the first-mode tip deflection would: the tip amplitude then falls by
    ``4 F_c / k_1`` per cycle, ``k_1 = ω_1² / s_1²`` the modal tip stiffness
    (``≈ 3.09 EI/L³`` for a uniform cantilever). A few mN is physical for a vise-clamped
    strip (0.1–0.2 mm per cycle on a 0.4 m aluminium strip, k_1 ≈ 115 N/m).

Signatures: the drag's energy loss per cycle grows as the cube of the amplitude, so the
decay rate grows with amplitude; Coulomb friction's grows only linearly, so the
amplitude falls linearly in time and the decay rate grows as the amplitude falls.

Simulation (slow flow, Krylov–Bogoliubov averaging)
----------------------------------------------------
Both forces are small compared with the elastic ones, so each lightly damped mode keeps
its linear frequency and shape and only its amplitude decays faster. The linear
response (exact, :class:`bayesbeam.forward.Forward`) is written as a sum over the complex
modes of the modal system ``z' = A z``; for the ``K`` lowest underdamped modes
(``n_modes``) the contribution ``2 Re(X_k e^{λ_k τ})`` (τ = t − t0) is multiplied by a
slowly varying factor ``ρ_k(τ)`` (ρ_k(0) = 1) obeying the averaged energy balance

    ρ_k' / ρ_k = - P_k / R_k²,      ½ R_k² = cycle-mean energy of mode k,

where ``P_k`` is the cycle-mean power the nonlinear forces take from mode k:

* drag: ``P_k = c_q ∫ B_k(x)² G(A_k(x), B_k(x)) dx``, ``B_k(x)`` the velocity amplitude
  of mode k at x, ``A_k² = Σ_{l≠k} B_l²`` that of the other modes (treated as one tone of
  independent phase), ``G(A, B) = ⟨|v| v sin β⟩ / B`` for ``v = A sin α + B sin β``
  averaged over independent phases (:func:`two_tone_drag`; ``G(0, B) = 4B/(3π)``,
  ``G(A, 0) = 2A/π``). A single mode thus loses energy at ``(4/3π) c_q ∫ |B|³``;
* friction (only on the complex mode that is mostly ``q_1``):
  ``P = (2/π) F_c |s_1| Q``, Q the amplitude of ``q_1'``.

Drag and Coulomb forces are odd in the velocity and in phase with it, so to first order
they change no frequency. ``ρ`` is integrated with a fixed-step RK4 scheme on a per-set
grid (``steps_per_period`` steps per period of the first mode; the step depends only on
the set, so a set's result does not depend on the other sets in its batch), clipped at 0
(a mode stopped by friction stays at rest), and interpolated to the sample times with
cubic Hermite polynomials. The signal is the linear one plus
``Σ_k 2 Re(X_k e^{λ_k τ} [λ_k^p (ρ_k - 1) + p λ_k^{p-1} ρ_k'])`` with p = 0, 1, 2 for
displacement, velocity and acceleration (the exact derivatives of ``ρ_k e^{λ_k τ}``
except the O(ε²) ρ'' term). With ``drag = friction = 0`` the correction is exactly zero
and the result is bit-for-bit the linear :class:`~bayesbeam.forward.Forward`.

Approximations (checked against a direct Radau integration of the full nonlinear FE
system in tests/test_nonlinear.py):

* first-order averaging: the amplitude's ripple within a cycle and the harmonics the
  forces generate (the third harmonic of ``|v| v``, the square wave of friction) are left
  out, errors O(ε) with ε the nonlinear damping ratio (energy lost per cycle / 4π E);
* modes above the ``n_modes`` lowest underdamped ones keep their linear decay and do not
  enter the drag of the others; the other modes are lumped into one tone in ``G``;
* a mode stopped by friction ends at rest at zero, whereas a real Coulomb oscillator
  sticks anywhere within ``|w_tip| ≤ F_c / k_1`` (one quarter of the last decrement);
* the drag uses the complex mode's velocity amplitude and ignores the O(ζ) variation of
  its phase along the span; mode shapes of the nonlinear-mode set are computed from the
  ``n_modes + 8`` lowest undamped modes (couplings to higher modes through non-proportional
  damping change them at O(ζ²)).

:func:`decay_vs_amplitude` measures the local decay rate against amplitude in a record
(band-pass around f1, Hilbert envelope, windowed log-slope).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.signal as sps

from bayesbeam.beam import Beam
from bayesbeam.forward import Forward, ForwardError, Response
from bayesbeam.models import NONLINEAR, Model, parse_model

__all__ = [
    "NonlinearError",
    "NonlinearForward",
    "decay_vs_amplitude",
    "two_tone_drag",
]

# Gauss–Legendre points per element for the drag integrals ∫ B² G(A, B) dx: the velocity
# amplitudes are piecewise cubic moduli, smooth inside an element; 3 points integrate the
# single-mode ∫|φ|³ of a 16-element model to ~1e-5 relative (checked in the tests), far
# below the O(ε) error of the averaging.
_DRAG_GAUSS = 3
# Extra undamped modes kept beyond n_modes when computing the complex modes whose
# amplitudes are modulated (see module docstring).
_EXTRA_MODES = 8


class NonlinearError(ForwardError):
    """The nonlinear forward model was set up or called with invalid input."""


# --------------------------------------------------------------------------- drag average


def _tone_mean(A: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Return the closed form of ``mean_α |A sin α + c| (A sin α + c)`` for α uniform on [0, 2π).

    For ``|c| ≥ A`` the sign is fixed and the mean is ``sign(c)(A²/2 + c²)``. Otherwise
    ``u = A sin α + c`` is positive on (α0, π - α0), α0 = arcsin(-c/A), and the mean is
    ``(2 ∫_{α0}^{π-α0} u² dα - 2π(A²/2 + c²)) / 2π`` with the integral in closed form.
    """
    A, c = np.broadcast_arrays(np.asarray(A, dtype=float), np.asarray(c, dtype=float))
    out = np.sign(c) * (0.5 * A**2 + c**2)
    inside = np.abs(c) < A
    if np.any(inside):
        a, cc = A[inside], c[inside]
        a0 = np.arcsin(-cc / a)
        span = np.pi - 2 * a0
        J = a**2 * (0.5 * span + 0.5 * np.sin(2 * a0)) + 4 * a * cc * np.cos(a0) + cc**2 * span
        out[inside] = (2 * J - 2 * np.pi * (0.5 * a**2 + cc**2)) / (2 * np.pi)
    return out


@lru_cache(maxsize=1)
def _drag_table() -> tuple[np.ndarray, np.ndarray]:
    """Table of g(t) = G(A, B) / S on t = B / S ∈ [0, 1], S = sqrt(A² + B²).

    G(A, B) = mean_β [mean_α |v| v] sin β / B (see :func:`two_tone_drag`): the α mean in
    closed form (:func:`_tone_mean`), the β mean by the trapezoid rule on 4096 points
    (periodic integrand, C² with a square-root singularity in the third derivative: error
    below 1e-10). 1025 table points make the linear interpolation error < 2e-7 · max|g''|.
    """
    t = np.linspace(0.0, 1.0, 1025)
    beta = 2 * np.pi * np.arange(4096) / 4096
    sb = np.sin(beta)
    g = np.empty_like(t)
    A = np.sqrt(1.0 - t**2)
    for i in range(t.size):
        if t[i] == 0.0:
            g[i] = 2.0 / np.pi  # limit B → 0: mean 2|A sin α| B sin²β / B = 2A/π
            continue
        H = np.mean(_tone_mean(A[i], t[i] * sb) * sb)
        g[i] = H / t[i]
    return t, g


def two_tone_drag(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Cycle-averaged quadratic drag seen by one tone in the presence of another.

    For a velocity ``v = A sin α + B sin β`` with independent uniform phases α, β (two
    modes of incommensurate frequencies), returns ``G(A, B) = ⟨|v| v sin β⟩ / B``: the
    mean drag power per unit ``c_q`` taken from the B tone is ``B² G(A, B) / 1`` (times
    ``c_q``, per unit length). ``G`` is homogeneous of degree 1, ``G(0, B) = 4B/(3π)``
    (one tone) and ``G(A, 0) = 2A/π`` (a weak tone damped by a strong one).

    Parameters
    ----------
    A, B : array_like
        Non-negative velocity amplitudes (m/s), broadcast together.

    Returns
    -------
    ndarray
        ``G`` in m/s, shape of the broadcast inputs; 0 where ``A = B = 0``.
    """
    A, B = np.broadcast_arrays(np.abs(np.asarray(A, float)), np.abs(np.asarray(B, float)))
    tg, gg = _drag_table()
    S = np.hypot(A, B)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(S > 0, B / np.where(S > 0, S, 1.0), 1.0)
    return S * np.interp(t, tg, gg)


# --------------------------------------------------------------------------- forward model


def _gauss_points(nodes: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss–Legendre points (m) and weights (m) with k points per element."""
    xi, wi = np.polynomial.legendre.leggauss(k)
    a, h = nodes[:-1], np.diff(nodes)
    x = a[:, None] + 0.5 * h[:, None] * (xi[None, :] + 1.0)
    w = 0.5 * h[:, None] * wi[None, :]
    return x.ravel(), w.ravel()


class NonlinearForward:
    """Batched forward model with amplitude-dependent damping (drag and clamp friction).

    Same interface as :class:`bayesbeam.forward.Forward`; the physics and the slow-flow
    approximation are described in the module docstring.

    Parameters
    ----------
    beam : Beam
        Beam description, including sensor position and measured quantity.
    model : str or Model
        A model with the ``amplitude_damping`` extension, e.g. ``'viscous+kv+amplitude_damping'``.
    times : array_like, shape (T,)
        Sample times in s, strictly increasing.
    t0 : float, optional
        Instant (s) at which the initial condition holds (default ``times[0]``); the
        nonlinear slow flow starts there.
    n_elements : int
        Number of Hermite elements.
    initial : str
        Initial condition, as for :class:`~bayesbeam.forward.Forward` ('release',
        'impulse', 'modes:K', 'state').
    initial_state : tuple of ndarray, optional
        ``(c0, v0)`` for ``initial='state'``.
    n_modes : int
        Number of lowest underdamped modes whose amplitudes the nonlinear damping
        modulates (default 3); higher modes stay linear.
    steps_per_period : float
        RK4 steps of the slow flow per period of the first mode (default 2).

    Attributes
    ----------
    param_names : tuple of str
        ``model.physical_params`` (E, law parameters, structural parameters, ``drag``,
        ``friction``) followed by the initial-condition names.
    linear : Forward
        The linear part (the model without ``amplitude_damping``).
    """

    def __init__(
        self,
        beam: Beam,
        model: str | Model,
        times: np.ndarray,
        *,
        t0: float | None = None,
        n_elements: int = 16,
        initial: str = "release",
        initial_state: tuple[np.ndarray, np.ndarray] | None = None,
        n_modes: int = 3,
        steps_per_period: float = 2.0,
    ) -> None:
        self.model = parse_model(model)
        if "amplitude_damping" not in self.model.nonlinear:
            raise NonlinearError(
                f"model {self.model.name!r} has no amplitude-dependent damping; use "
                "bayesbeam.forward.Forward for linear models or add '+amplitude_damping'"
            )
        linear = parse_model("+".join(p for p in self.model.parts if p not in NONLINEAR))
        self.linear = Forward(beam, linear, times, n_elements=n_elements, initial=initial,
                              initial_state=initial_state, t0=t0)
        if isinstance(n_modes, bool) or not isinstance(n_modes, (int, np.integer)) or n_modes < 1:
            raise NonlinearError(f"n_modes must be a positive integer, got {n_modes!r}")
        spp = float(steps_per_period)
        if not (np.isfinite(spp) and spp > 0):
            raise NonlinearError(
                f"steps_per_period must be a positive number, got {steps_per_period!r}"
            )
        self.beam = beam
        self.fe = self.linear.fe
        self.times = self.linear.times
        self.t0 = self.linear.t0
        self.initial = initial
        self.quantity = self.linear.quantity
        m = self.fe.n_dof
        self.n_modes = int(min(n_modes, m))
        self.steps_per_period = spp
        self._m_sub = int(min(m, self.n_modes + _EXTRA_MODES))
        self.param_names: tuple[str, ...] = self.model.physical_params + tuple(
            n for n in self.linear.param_names if n not in self.linear.model.physical_params
        )
        self._lin_idx = np.array([self.param_names.index(n) for n in self.linear.param_names])
        self._i_drag = self.param_names.index("drag")
        self._i_fric = self.param_names.index("friction")
        self._tau = self.times - self.t0  # (T,) s since the initial condition
        xq, wq = _gauss_points(np.asarray(self.fe.nodes), _DRAG_GAUSS)
        self._Nq = self.fe.shape(xq)  # (nq, n) displacement rows at the drag points
        self._wq = wq
        self._order = {"displacement": 0, "velocity": 1, "acceleration": 2}[self.quantity]

    # -- parameter handling ---------------------------------------------------------------
    def _columns(self, theta: np.ndarray | dict) -> np.ndarray:
        if isinstance(theta, dict):
            missing = [p for p in self.param_names if p not in theta]
            if missing:
                raise NonlinearError(
                    f"missing parameters {missing}; need {list(self.param_names)}"
                )
            cols = [np.atleast_1d(np.asarray(theta[p], dtype=float)) for p in self.param_names]
            theta = np.column_stack(np.broadcast_arrays(*cols))
        theta = np.asarray(theta, dtype=float)
        if theta.ndim == 1:
            theta = theta[None, :]
        if theta.ndim != 2 or theta.shape[1] != len(self.param_names):
            raise NonlinearError(
                f"theta must have shape (B, {len(self.param_names)}) with columns "
                f"{list(self.param_names)}, got {theta.shape}"
            )
        return theta

    def check(self, theta: np.ndarray | dict) -> np.ndarray:
        """Return the mask of admissible parameter sets.

        ``drag`` (kg/m²) and ``friction`` (N) must be finite and ≥ 0; the other
        parameters as in :meth:`bayesbeam.forward.Forward.check`.

        Parameters
        ----------
        theta : ndarray, shape (B, P), or dict

        Returns
        -------
        ndarray of bool, shape (B,)
        """
        theta = self._columns(theta)
        ok = self.linear.check(theta[:, self._lin_idx])
        for j in (self._i_drag, self._i_fric):
            ok &= np.isfinite(theta[:, j]) & (theta[:, j] >= 0)
        return ok

    def modes(self, theta: np.ndarray | dict) -> tuple[np.ndarray, np.ndarray]:
        """Natural frequencies (Hz) and damping ratios of the linear part of one set.

        Parameters
        ----------
        theta : ndarray, shape (P,) or dict

        Returns
        -------
        frequencies_hz, damping_ratios : ndarray, shape (k,)
            See :meth:`bayesbeam.forward.Forward.modes`.
        """
        theta = self._columns(theta)[:1]
        if not self.check(theta)[0]:
            raise NonlinearError(f"parameters outside their admissible range: {theta[0]}")
        return self.linear.modes(theta[:, self._lin_idx])

    # -- complex modes ------------------------------------------------------------------
    def _complex_modes(self, th_lin: np.ndarray) -> dict[str, np.ndarray]:
        """Lowest underdamped complex modes, their weights and shapes, for valid sets.

        Returns a dict of arrays (b = sets, K = n_modes): ``lam`` (b, K) eigenvalues (1/s);
        ``X`` (b, K) displacement weights at the sensor (signal ``2 Re(X e^{λτ})``, m);
        ``xtip`` (b, K) ``|φ(L)·q|`` per unit coefficient (tip amplitude ``2|c| xtip``);
        ``W`` (b, K, nq) complex velocity amplitude per unit modal coefficient at the drag
        points (the mode's velocity field is ``Re(c W e^{λτ})``); ``c`` (b, K) modal
        coefficients; ``v2`` (b, K) squared state norms ``|v|²`` (cycle-mean energy
        ``|c|² |v|² e^{2 Re λ τ}``); ``q1`` (b, K) ``|λ q[0]|`` per unit coefficient (half
        the amplitude of q1' per |c|); ``s1`` (b,) ``|φ_1(L)|``; ``active`` (b, K) bool.
        """
        lin = self.linear
        omega, C, phi = lin.modal_system(th_lin)
        z0 = lin._initial_state(th_lin, omega, phi)  # at t0 (before any lead propagation)
        b, m = omega.shape
        ms = self._m_sub
        K = self.n_modes
        om = omega[:, :ms]
        # Truncated modal state matrix A = [[0, Ω], [-Ω, -C]] on the ms lowest modes.
        A = np.zeros((b, 2 * ms, 2 * ms))
        idx = np.arange(ms)
        A[:, idx, ms + idx] = om
        A[:, ms + idx, idx] = -om
        A[:, ms:, ms:] = -C[:, :ms, :ms]
        lam = np.full((b, 2 * ms), np.nan + 0j)
        V = np.full((b, 2 * ms, 2 * ms), np.nan + 0j)
        good = np.all(np.isfinite(A), axis=(1, 2))
        try:
            lam[good], V[good] = np.linalg.eig(A[good])
        except np.linalg.LinAlgError:  # one set's QR iteration failed: do them one by one
            for i in np.flatnonzero(good):
                try:
                    lam[i], V[i] = np.linalg.eig(A[i])
                except np.linalg.LinAlgError:
                    continue  # stays NaN: the set is reported invalid
        # The K underdamped eigenvalues (Im λ > 0) of smallest modulus.
        under = lam.imag > 1e-9 * np.abs(lam)
        key = np.where(under, np.abs(lam), np.inf)
        sel = np.argsort(key, axis=1, kind="stable")[:, :K]
        active = np.take_along_axis(under, sel, axis=1)
        lamk = np.take_along_axis(lam, sel, axis=1)
        Vk = np.take_along_axis(V, sel[:, None, :], axis=2)  # (b, 2ms, K)
        Vk = np.swapaxes(Vk, 1, 2)  # (b, K, 2ms)
        # Right eigenvector v = [Ω q; λ q]; left eigenvector J v with J = diag(I, -I), since
        # J A J = Aᵀ. Modal coefficient c = vᵀ J z0 / vᵀ J v (unconjugated).
        with np.errstate(all="ignore"):
            q = Vk[:, :, ms:] / lamk[:, :, None]
            z0s = np.concatenate([z0[:, :ms], z0[:, m:m + ms]], axis=1)
            JV = np.concatenate([Vk[:, :, :ms], -Vk[:, :, ms:]], axis=2)
            c = np.einsum("bki,bi->bk", JV, z0s) / np.einsum("bki,bki->bk", JV, Vk)
            phis = phi[..., :ms]
            s_q = np.einsum("n,...nm->...m", lin.sensor, phis)
            s_q = np.broadcast_to(s_q, (b, ms))
            X = c * np.einsum("bm,bkm->bk", s_q, q)
            NqPhi = np.einsum("qn,...nm->...qm", self._Nq, phis)
            NqPhi = np.broadcast_to(NqPhi, (b,) + NqPhi.shape[-2:])
            W = 2 * lamk[:, :, None] * np.einsum("bqm,bkm->bkq", NqPhi, q)
            v2 = np.sum(np.abs(Vk) ** 2, axis=2)
            q1 = np.abs(lamk * q[:, :, 0])
            tip_phi = np.einsum("n,...nm->...m", np.asarray(self.fe.tip), phis)
            xtip = np.abs(np.einsum("bm,bkm->bk", np.broadcast_to(tip_phi, (b, ms)), q))
            s1 = np.abs(np.einsum("n,...n->...", np.asarray(self.fe.tip), phi[..., 0]))
            s1 = np.broadcast_to(s1, (b,))
        return {"lam": lamk, "X": X, "W": W, "c": c, "v2": v2, "q1": q1,
                "s1": s1, "active": active, "xtip": xtip}

    # -- slow flow ----------------------------------------------------------------------
    def _slow_flow(self, cm: dict[str, np.ndarray], drag: np.ndarray, fric: np.ndarray,
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Envelope factors ρ and ρ' at the sample times, shape (b, K, T) each."""
        lam, W, c, v2 = cm["lam"], cm["W"], cm["c"], cm["v2"]
        act = cm["active"]
        b, K = lam.shape
        sig = lam.real  # (b, K) < 0
        ac = np.abs(c)
        wq = self._wq
        # Drag: rate_k = c_q Σ_x w |W_k|² G(A_k, B_k) / (2 |v_k|²), B_k = |c_k W_k| e^{στ} ρ_k.
        W2 = np.where(act[:, :, None], np.abs(W) ** 2, 0.0)  # (b, K, nq)
        Bs = np.sqrt(W2) * ac[:, :, None]
        dcoef = drag[:, None] / (2 * v2)  # (b, K)
        use_drag = bool(np.any(drag > 0))
        # Friction on the complex mode that is mostly q1 (the largest |q[0]| share):
        # ρ' = -F |s1| (2/π) |λ q0| / (|c| |v|² e^{στ}).
        share = np.where(act, cm["q1"] ** 2 / v2, -1.0)
        k1 = np.argmax(share, axis=1)
        fcoef = np.zeros((b, K))
        rows = np.arange(b)
        with np.errstate(all="ignore"):
            f1 = fric * cm["s1"] * (2 / np.pi) * cm["q1"][rows, k1] / (ac[rows, k1] * v2[rows, k1])
        fcoef[rows, k1] = np.where((fric > 0) & act[rows, k1], f1, 0.0)
        fcoef = np.where(np.isfinite(fcoef), fcoef, np.inf)  # c = 0: the mode is not excited

        def rate(tau: np.ndarray, rho: np.ndarray) -> np.ndarray:
            """ρ' at times tau (b,) for ρ (b, K)."""
            r = np.maximum(rho, 0.0)
            e = np.exp(sig * tau[:, None])  # (b, K)
            out = np.zeros_like(r)
            if use_drag:
                Bx = Bs * (e * r)[:, :, None]  # (b, K, nq)
                tot = np.sum(Bx**2, axis=1, keepdims=True)
                Ax = np.sqrt(np.maximum(tot - Bx**2, 0.0))
                G = two_tone_drag(Ax, Bx)
                out -= r * dcoef * np.einsum("bkq,q->bk", W2 * G, wq)
            with np.errstate(over="ignore", invalid="ignore"):
                fr = np.where(fcoef > 0, fcoef / e, 0.0)
            out -= np.where(r > 0, fr, 0.0)
            return out

        tau_end = float(self._tau[-1])
        f_set = np.abs(lam[rows, 0].imag) / (2 * np.pi)  # first complex mode, Hz
        n_steps = np.ceil(self.steps_per_period * tau_end * np.where(np.isfinite(f_set),
                                                                     f_set, 1.0))
        n_steps = np.clip(n_steps, 8, 100_000).astype(int)  # (b,)
        h = tau_end / n_steps  # (b,) per-set step: a set's grid ignores the batch
        N = int(n_steps.max())
        rho_g = np.empty((N + 1, b, K))
        drho_g = np.empty((N + 1, b, K))
        rho = np.ones((b, K))
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            for i in range(N + 1):
                tau = np.minimum(i, n_steps) * h
                d = rate(tau, rho)
                rho_g[i], drho_g[i] = rho, np.where(rho > 0, d, 0.0)
                if i == N:
                    break
                hh = h[:, None]
                k2 = rate(tau + 0.5 * h, rho + 0.5 * hh * d)
                k3 = rate(tau + 0.5 * h, rho + 0.5 * hh * k2)
                k4 = rate(tau + h, rho + hh * k3)
                new = np.maximum(rho + hh / 6 * (d + 2 * k2 + 2 * k3 + k4), 0.0)
                new = np.where(np.isnan(new), 0.0, new)
                rho = np.where((i < n_steps)[:, None], new, rho)
        # Cubic Hermite interpolation to the sample times on each set's own grid.
        s = self._tau[None, :] / h[:, None]  # (b, T)
        j = np.clip(np.floor(s).astype(int), 0, n_steps[:, None] - 1)
        u = np.clip(s - j, 0.0, 1.0)[:, None, :]
        rg = np.transpose(rho_g, (1, 2, 0))  # (b, K, N+1)
        dg = np.transpose(drho_g, (1, 2, 0)) * h[:, None, None]
        jj = np.broadcast_to(j[:, None, :], (b, K, j.shape[1]))
        r0 = np.take_along_axis(rg, jj, 2)
        r1 = np.take_along_axis(rg, jj + 1, 2)
        d0 = np.take_along_axis(dg, jj, 2)
        d1 = np.take_along_axis(dg, jj + 1, 2)
        h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
        h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
        rho_t = h00 * r0 + h10 * d0 + h01 * r1 + h11 * d1
        drho_t = ((6 * u**2 - 6 * u) * r0 + (3 * u**2 - 4 * u + 1) * d0
                  + (-6 * u**2 + 6 * u) * r1 + (3 * u**2 - 2 * u) * d1) / h[:, None, None]
        stopped = rho_t <= 0
        return np.where(stopped, 0.0, rho_t), np.where(stopped, 0.0, drho_t)

    def _correction(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nonlinear correction to the linear signal, (b, T), and its validity (b,)."""
        th_lin = theta[:, self._lin_idx]
        drag = theta[:, self._i_drag]
        fric = theta[:, self._i_fric]
        with np.errstate(all="ignore"):
            cm = self._complex_modes(th_lin)
            lam, X = cm["lam"], np.where(cm["active"], cm["X"], 0.0)
            rho, drho = self._slow_flow(cm, drag, fric)
            p = self._order
            lp = lam[:, :, None]
            fac = lp**p * (rho - 1.0) + (p * lp ** (p - 1) * drho if p else 0.0)
            E = np.exp(lp * self._tau[None, None, :])
            dy = 2 * np.sum((X[:, :, None] * E * fac).real, axis=1)
        ok = np.all(np.isfinite(dy), axis=1)
        return np.where(ok[:, None], dy, 0.0), ok

    # -- public ---------------------------------------------------------------------------
    def simulate(self, theta: np.ndarray | dict) -> Response:
        """Sensor signal for a batch of parameter sets.

        Parameters
        ----------
        theta : ndarray, shape (B, P), or dict of name → array
            Parameter sets with columns :attr:`param_names` (SI units).

        Returns
        -------
        Response
            ``y`` (B, T) in SI units of the sensor's quantity and the ``valid`` mask (B,);
            rows of invalid sets are zero (never NaN).
        """
        theta = self._columns(theta)
        valid = self.check(theta)
        y = np.zeros((theta.shape[0], self._tau.size))
        if not np.any(valid):
            return Response(y, valid)
        lin = self.linear.simulate(np.where(valid[:, None], theta, 1.0)[:, self._lin_idx])
        valid &= lin.valid
        y[valid] = lin.y[valid]
        nl = valid & ((theta[:, self._i_drag] > 0) | (theta[:, self._i_fric] > 0))
        if np.any(nl):
            dy, ok = self._correction(theta[nl])
            idx = np.flatnonzero(nl)
            y[idx[ok]] += dy[ok]
            y[idx[~ok]] = 0.0
            valid[idx[~ok]] = False
        return Response(y, valid)

    def equivalent_damping(self, theta: np.ndarray | dict, amplitude: float,
                           ) -> tuple[np.ndarray, np.ndarray]:
        """Equivalent damping ratios of drag and friction on the first mode alone.

        The nonlinear decay rate of the first complex mode, ``-ρ'/ρ``, divided by ``|λ_1|``,
        when that mode alone vibrates with tip amplitude ``amplitude``: drag
        ``ζ = (4/3π) c_q ∫|B|³ dx / (|λ| R²)`` grows with amplitude, friction
        ``ζ = (2/π) F_c |s_1| Q / (|λ| R²)`` falls as 1/amplitude. Useful to set priors
        and to report sizes.

        Parameters
        ----------
        theta : ndarray, shape (B, P) or (P,), or dict
        amplitude : float
            Tip displacement amplitude of the first mode, m.

        Returns
        -------
        zeta_drag, zeta_friction : ndarray, shape (B,)
            NaN for invalid sets.
        """
        theta = self._columns(theta)
        amp = float(amplitude)
        if not (np.isfinite(amp) and amp > 0):
            raise NonlinearError(
                f"amplitude must be a positive tip amplitude in m, got {amplitude!r}"
            )
        valid = self.check(theta)
        zd = np.full(theta.shape[0], np.nan)
        zf = np.full(theta.shape[0], np.nan)
        if not np.any(valid):
            return zd, zf
        th = theta[valid]
        with np.errstate(all="ignore"):
            cm = self._complex_modes(th[:, self._lin_idx])
            lam = cm["lam"][:, 0]
            # The mode alone: tip displacement amplitude 2 |c| |φ(L)·q| = amplitude fixes |c|.
            cabs = amp / (2 * cm["xtip"][:, 0])
            B = cabs[:, None] * np.abs(cm["W"][:, 0])  # velocity amplitude at the drag points
            R2 = 2 * cabs**2 * cm["v2"][:, 0]  # twice the cycle-mean energy
            P_d = th[:, self._i_drag] * (4 / (3 * np.pi)) * np.sum(self._wq * B**3, axis=1)
            P_f = th[:, self._i_fric] * cm["s1"] * (2 / np.pi) * 2 * cabs * cm["q1"][:, 0]
            zd[valid] = P_d / R2 / np.abs(lam)
            zf[valid] = P_f / R2 / np.abs(lam)
        return zd, zf


# --------------------------------------------------------------------------- signature


def decay_vs_amplitude(
    times: np.ndarray,
    values: np.ndarray,
    f1: float,
    n_windows: int = 8,
    *,
    band: float = 0.3,
    trim_cycles: float = 3.0,
    floor: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Local decay rate of the first mode against its amplitude in a free-decay record.

    The record (interpolated to its mean step if the stamps are not uniform) is
    band-passed around ``f1`` (4th-order zero-phase Butterworth, ``f1 (1 ± band)``), its
    Hilbert envelope taken, ``trim_cycles`` periods cut at both ends (filter and Hilbert
    end effects), and the rest split into ``n_windows`` equal windows. In each window a
    straight line is fitted to the log envelope: the decay rate is minus its slope and
    the amplitude the envelope's geometric mean. A linear filter maps
    ``e^{-σt} sin ωt`` to a sinusoid of the same σ, so for linear damping the rate is the
    same in every window (σ = ζ ω); drag makes it grow with amplitude, Coulomb friction
    makes it grow as the amplitude falls.

    Parameters
    ----------
    times : array_like, shape (T,)
        Sample times, s, strictly increasing.
    values : array_like, shape (T,)
        Signal (any quantity; the amplitude is in its units).
    f1 : float
        First natural frequency, Hz (e.g. :func:`bayesbeam.problem.first_frequency`).
    n_windows : int
        Number of windows (≥ 2).
    band : float
        Relative half-width of the pass band, in (0, 1).
    trim_cycles : float
        Periods of 1/f1 cut at each end.
    floor : float
        Windows whose envelope falls below ``floor`` times the largest envelope are
        dropped (noise floor, a mode stopped by friction).

    Returns
    -------
    amplitude : ndarray, shape (k,)
        Geometric-mean envelope of each kept window, units of ``values``, in time order.
    decay_rate : ndarray, shape (k,)
        σ in 1/s (divide by 2π f1 for a damping ratio).

    Raises
    ------
    ValueError
        For non-finite or mismatched input, a band outside (0, Nyquist) or a record too
        short for the windows.
    """
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float)
    if t.ndim != 1 or y.shape != t.shape or t.size < 16:
        raise ValueError("times and values must be 1-D arrays of the same length (>= 16 samples)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise ValueError("times and values must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("times must be strictly increasing")
    if not (isinstance(n_windows, (int, np.integer)) and n_windows >= 2):
        raise ValueError(f"n_windows must be an integer >= 2, got {n_windows!r}")
    if not 0 < band < 1:
        raise ValueError(f"band must lie in (0, 1) (relative half-width), got {band!r}")
    dt = (t[-1] - t[0]) / (t.size - 1)
    fs = 1.0 / dt
    f1 = float(f1)
    if not (np.isfinite(f1) and f1 > 0 and f1 * (1 + band) < 0.5 * fs):
        raise ValueError(
            f"f1 = {f1} Hz with band {band} must lie below the Nyquist frequency {0.5 * fs} Hz"
        )
    grid = t[0] + dt * np.arange(t.size)
    y = np.interp(grid, t, y)
    sos = sps.butter(2, [f1 * (1 - band), f1 * (1 + band)], btype="bandpass", fs=fs,
                     output="sos")
    env = np.abs(sps.hilbert(sps.sosfiltfilt(sos, y - np.mean(y))))
    keep = (grid >= grid[0] + trim_cycles / f1) & (grid <= grid[-1] - trim_cycles / f1)
    tk, ek = grid[keep], env[keep]
    if tk.size < 4 * n_windows:
        raise ValueError(
            f"record too short: {tk.size} samples remain after trimming {trim_cycles} cycles "
            f"at each end; need at least {4 * n_windows} for {n_windows} windows"
        )
    top = float(ek.max())
    amps, rates = [], []
    for tw, ew in zip(np.array_split(tk, n_windows), np.array_split(ek, n_windows),
                      strict=True):
        if top <= 0 or np.min(ew) <= floor * top:
            continue
        le = np.log(ew)
        slope = np.polyfit(tw - tw.mean(), le, 1)[0]
        amps.append(float(np.exp(le.mean())))
        rates.append(float(-slope))
    return np.array(amps), np.array(rates)
