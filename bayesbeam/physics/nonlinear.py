"""Amplitude-dependent models: drag, clamp friction, amplitude stiffness, a quadratic sensor.

The extensions of :data:`bayesbeam.physics.models.NONLINEAR` (physics.md §3), each a cause
of the diagnosis catalogue adding one parameter to a linear model; a model may have
several (``viscous+kv+drag``, ``viscous+kv+drag+friction``,
``viscous+kv+drag+sensor_quadratic``), and a missing one counts as zero:

``drag`` (c_q, kg/m²)
    Quadratic air drag, a distributed force per unit length ``-c_q |w_t| w_t`` (N/m).
    For a strip of width b vibrating flat-on, ``c_q = ½ rho_air C_D b``; a 50.8 mm strip
    in air (rho_air = 1.2 kg/m³) gives ``c_q ≈ 0.03 C_D``. Oscillating flat plates at the
    small Keulegan–Carpenter numbers of a release test (KC = 2π a/b ~ 1–5) have drag
    coefficients of several units (C_D ~ 3–10, Graham 1980, J. Fluid Mech. 97, 331), so
    ``c_q`` of order 0.05–0.3 kg/m² is physical.
``friction`` (F_c, N)
    Dry (Coulomb) friction at the clamp, acting on the first mode only. A rigid clamp
    has no rotation for a Coulomb moment to act on, and fitting a friction moment on a
    root spring would tie the parameter to the root-spring extension; so the clamp's
    friction is represented, for every clamp, by its effect on the fundamental mode: a
    Coulomb generalised force
    ``-F_c |s_1| sign(q_1')`` on the first undamped modal coordinate ``q_1``
    (Φ M-orthonormal, ``s_1 = φ_1(L)`` its tip deflection per unit ``q_1``). In dof
    space this is the force vector ``F_c |s_1| sign(φ_1ᵀ M c') M φ_1``. It dissipates,
    per cycle, ``4 F_c`` times the tip amplitude of the first mode, as a Coulomb slider
    of force F_c on the first-mode tip deflection would: the tip amplitude then falls by
    ``4 F_c / k_1`` per cycle, ``k_1 = ω_1² / s_1²`` the modal tip stiffness
    (``≈ 3.09 EI/L³`` for a uniform cantilever). A few mN is physical for a vise-clamped
    strip (0.1–0.2 mm per cycle on a 0.4 m aluminium strip, k_1 ≈ 115 N/m).

``amplitude_stiffness`` (f1_slope, Hz/m)
    A first natural frequency that moves with the amplitude of the first mode,
    ``f_1(A) = f_1 + s A`` with A its tip amplitude (negative s: softening, e.g. a
    clamp that gives under load; positive: hardening, e.g. the geometric stiffening of
    large deflections). The first-order (linear in A) term of the backbone curve over a
    record's amplitude range; reported in Hz per mm. An odd restoring force
    ``-k_a |q_1| q_1`` on the first M-orthonormal modal coordinate has, to first order,
    ``s = 2 k_a / (3 π² |s_1| ω_1)`` (harmonic balance: its first harmonic is
    ``(8/3π) k_a a q_1`` for ``q_1 = a cos φ``), which is how the direct integration
    of the tests produces it.

``sensor_quadratic`` (k2, 1/signal unit)
    A sensor whose reading is quadratic in what it measures: it reads ``y + k2 y²``
    for the signal ``y`` of the dynamics above (then, in the trial's model, plus any
    constant offset). This is the second-order term ``K2`` of the accelerometer model
    of IEEE Std 1293-2018 (indicated = K0 + a + K2 a² + K3 a³ + ..., in g/g² there; SI
    here, 1/(m/s²) for an acceleration record), and the leading term of any smooth
    nonlinearity of a transducer. Its signature is a line at twice each frequency of
    the signal (and at sums and differences of two), in phase with the square of the
    response and decaying twice as fast, plus a slowly decaying shift of the mean,
    ``k2`` times the mean square. Even harmonics distinguish it from the dynamics'
    nonlinearities of a symmetric beam (odd in the response). Applied to the signal
    as the model sees it (after the sensor band): the squares of components above
    the band, which a real sensor squares before its anti-alias filter, are left out.

Signatures: the drag's energy loss per cycle grows as the cube of the amplitude, so the
decay rate grows with amplitude; Coulomb friction's grows only linearly, so the
amplitude falls linearly in time and the decay rate grows as the amplitude falls. The
two signatures are opposite, so the diagnosis names them as separate causes.

Simulation (slow flow, Krylov–Bogoliubov averaging)
----------------------------------------------------
Both forces are small compared with the elastic ones, so each lightly damped mode keeps
its linear frequency and shape and only its amplitude decays faster. The linear
response (exact, :class:`bayesbeam.physics.forward.Forward`) is written as a sum over the complex
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
they change no frequency. The amplitude-dependent frequency adds a slow phase to the
first complex mode (the one that is mostly ``q_1``): its contribution is multiplied by
``ρ_1 e^{iθ}`` with ``θ' = 2π s A(τ)``, ``A = 2 |c_1| |φ(L)·q_1| e^{Re λ_1 τ} ρ_1``
its current tip amplitude, integrated with ρ.

``ρ`` (and θ) are integrated with a fixed-step RK4 scheme on a per-set grid
(``steps_per_period`` steps per period of the first mode, default one step per two
periods: the slow flow changes by O(2π ε) per period, so the RK4 error, O((4π ε)⁵), and the
interpolation error stay far below the O(ε) averaging error; the step depends only on
the set, so a set's result does not depend on the other sets in its batch), clipped at 0
(a mode stopped by friction stays at rest), and interpolated to the sample times with
cubic Hermite polynomials (linear in the step where friction stops a mode); with numba
(a dependency) the integration, the interpolation and the modal sum below run compiled,
one set at a time (:mod:`bayesbeam.physics.slow_flow_kernel`), and the vectorised numpy
route stays for platforms without it (``backend``; the two agree to 1e-12 of the
signal's peak, tests/physics/test_slow_flow_kernel.py). The signal
is the linear one plus

    Σ_k 2 Re(X_k e^{λ_k τ} [λ_k^p (ρ_k e^{iθ_k} - 1)
                             + p λ_k^{p-1} (ρ_k' + i θ_k' ρ_k) e^{iθ_k}])

with p = 0, 1, 2 for displacement, velocity and acceleration (the exact derivatives of
``ρ_k e^{iθ_k} e^{λ_k τ}`` except the O(ε²) terms in ρ'', θ'' and θ'²; θ_k = 0 but for
the first mode with ``f1_slope``). With ``drag = friction = f1_slope = 0`` (or the
parameters absent from the model) the correction is exactly zero and the result is
bit-for-bit the linear :class:`~bayesbeam.physics.forward.Forward`; the sensor's
``k2 y²`` is added last, to that sum.

Approximations (checked against a direct LSODA integration, rtol 1e-10, of the full
nonlinear FE system in tests/test_nonlinear.py):

* first-order averaging: the amplitude's ripple within a cycle and the harmonics the
  forces generate (the third harmonic of ``|v| v``, the square wave of friction) are left
  out, errors O(ε) with ε the nonlinear damping ratio (energy lost per cycle / 4π E,
  :meth:`NonlinearForward.equivalent_damping`). They are quadrature (phase-like) terms:
  for a single oscillator released from rest the exact solution lags the averaged one by
  a constant 0.83 ε(a0) rad (drag) and carries a quadrature term 1.5 ε(a)·a (friction:
  the ±F/k centres of the Coulomb half-cycles); on the 0.4 m strip the signal differs
  from the direct integration by 0.6–1.6 ε of its peak, while the envelope (window
  amplitudes and decay rates) agrees to ~1e-5, i.e. O(ε²);
* modes above the ``n_modes`` lowest underdamped ones keep their linear decay and do not
  enter the drag of the others; the other modes are lumped into one tone in ``G``;
* a mode the sensor does not show (above its band) whose velocity amplitude stays below
  :data:`PASSIVE` (1e-3) of the largest mode's also keeps its linear decay, but still
  enters the drag of the others (a relative change of ~1e-6 in their drag);
* friction acts on the first mode only (the clamp's friction on the higher modes, and a
  power-law damping in amplitude on every mode, are not modelled);
* a mode stopped by friction ends at rest at zero, whereas a real Coulomb oscillator
  sticks anywhere within ``|w_tip| ≤ F_c / k_1`` (one quarter of the last decrement);
* the drag uses the complex mode's velocity amplitude and ignores the O(ζ) variation of
  its phase along the span; mode shapes of the nonlinear-mode set are computed from the
  ``n_modes + 8`` lowest undamped modes (couplings to higher modes through non-proportional
  damping change them at O(ζ²)); the drag coefficient c_q is uniform along the span.

The decay rate against amplitude of a record is measured in
:mod:`bayesbeam.trials.modal_id` (:func:`~bayesbeam.trials.modal_id.envelope_decay_vs_amplitude`
compares these signals with a direct integration in tests/physics/test_nonlinear.py);
:func:`nonlinear_damping_scales` converts drag and friction to first-mode damping ratios
(for priors).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import numpy as np

from bayesbeam._util import compiled_kernel
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward, Response
from bayesbeam.physics.inputs import ForwardError, grid_with_holes, parameter_columns
from bayesbeam.physics.models import NONLINEAR, Model, parse_model
from bayesbeam.physics.propagate import _pick_backend
from bayesbeam.physics.slow_flow_kernel import _correction_py, _rk4_grid_py

__all__ = [
    "NonlinearError",
    "NonlinearForward",
    "nonlinear_damping_scales",
    "two_tone_drag",
]

# Gauss–Legendre points per element for the drag integrals ∫ B² G(A, B) dx: the velocity
# amplitudes are moduli of piecewise cubics, smooth inside an element; 2 points give the
# first-mode drag of a uniform 16-element (8-element) cantilever to 4e-7 (7e-6) of the
# analytic ∫|ψ|³ (test_nonlinear), far below the O(ε) error of the averaging.
_DRAG_GAUSS = 2
# A mode the sensor does not show whose velocity amplitude stays below this fraction of
# the largest mode's feels no drag of its own (NonlinearForward._passive): it changes the
# shown modes' drag by ~PASSIVE² relative, far below the O(ε) error of the averaging.
PASSIVE = 1e-3
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
    below 1e-10). 1025 table points make the linear interpolation error < 2e-7 · max|g''|
    (g has a kink at t = 1/√2, A = B, where the tone B starts to dominate the sign of v).
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
    modes of incommensurate frequencies), returns ``G(A, B) = ⟨|v| v sin β⟩ / B``: a drag
    force ``-c_q |v| v`` per unit length takes the mean power ``c_q B² G(A, B)`` (W/m) from
    the B tone. ``G`` is homogeneous of degree 1, ``G(0, B) = 4B/(3π)`` (one tone) and
    ``G(A, 0) = 2A/π`` (a weak tone damped by a strong one).

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
    gg, dg = _drag_lerp()
    n = gg.size - 1
    S = np.hypot(A, B)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.where(S > 0, B / S, 1.0) * n
    # Linear interpolation on the uniform table by direct indexing (a search, as in
    # np.interp, would dominate the cost of the slow flow).
    i = np.minimum(x.astype(np.intp), n - 1)
    return S * (np.take(gg, i) + (x - i) * np.take(dg, i))


@lru_cache(maxsize=1)
def _drag_lerp() -> tuple[np.ndarray, np.ndarray]:
    """Table values g and forward differences (last one repeated) for the interpolation."""
    _, g = _drag_table()
    return g, np.append(np.diff(g), 0.0)


# --------------------------------------------------------------------------- forward model


def _gauss_points(nodes: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss–Legendre points (m) and weights (m) with k points per element."""
    xi, wi = np.polynomial.legendre.leggauss(k)
    a, h = nodes[:-1], np.diff(nodes)
    x = a[:, None] + 0.5 * h[:, None] * (xi[None, :] + 1.0)
    w = 0.5 * h[:, None] * wi[None, :]
    return x.ravel(), w.ravel()


def _sampling_step(tau: np.ndarray) -> float:
    """Return the step (s) by which the compiled correction advances its exponentials.

    On a uniform grid with or without holes
    (:func:`bayesbeam.physics.forward.grid_with_holes`) the span over the grid count, so
    that 32 products of ``e^{λ dt}`` stay within the stamps' own rounding; else the
    smallest step (every other step then takes an exact exponential).
    """
    if tau.size < 2:
        return 1.0
    grid = grid_with_holes(tau - tau[0])
    if grid is None:
        return float(np.min(np.diff(tau)))
    _, k = grid
    return float((tau[-1] - tau[0]) / (k[-1] - k[0]))


class NonlinearForward:
    """Batched forward model with the amplitude-dependent extensions (module docstring).

    Same interface as :class:`bayesbeam.physics.forward.Forward`; the physics and the slow-flow
    approximation are described in the module docstring.

    Parameters
    ----------
    beam : Beam
        Beam description, including sensor position and measured quantity.
    model : str or Model
        A model with at least one of ``drag``, ``friction``, ``amplitude_stiffness``
        and ``sensor_quadratic``, e.g. ``'viscous+kv+drag'`` or
        ``'viscous+kv+drag+friction'``.
    times : array_like, shape (T,)
        Sample times in s, strictly increasing.
    t0 : float, optional
        Instant (s) at which the initial condition holds (default ``times[0]``); the
        nonlinear slow flow starts there.
    n_elements : int
        Number of Hermite elements.
    initial : str
        Initial condition, as for :class:`~bayesbeam.physics.forward.Forward` ('release',
        'impulse', 'modes:K', 'state').
    initial_state : tuple of ndarray, optional
        ``(c0, v0)`` for ``initial='state'``.
    n_modes : int, optional
        Number of lowest underdamped modes whose amplitudes the nonlinear damping
        modulates; higher modes stay linear. Default 3 for displacement, 4 for velocity
        and 5 for acceleration sensors (each time derivative weights higher modes by ω;
        on a 0.4 m strip the truncation then changes the signal by < 1e-5, 1e-4 and
        5e-4 of its peak, below the O(ε) averaging error).
    steps_per_period : float
        RK4 steps of the slow flow per period of the first mode (default 0.5).
    bandwidth : float, optional
        Sensor bandwidth in Hz (ideal anti-alias filter, as for
        :class:`~bayesbeam.physics.forward.Forward`): modes with ``|λ|`` above it still
        take part in the drag (the air sees them) but are removed from the output.
    backend : {'auto', 'numba', 'numpy'}
        Integration of the slow flow: compiled set by set
        (:mod:`bayesbeam.physics.slow_flow_kernel`; 'auto' where numba is installed) or
        vectorised over the batch with numpy. The two agree to rounding (tested).

    Attributes
    ----------
    param_names : tuple of str
        ``model.physical_params`` (E, law parameters, structural parameters, then
        ``drag`` and/or ``friction``, whichever the model has) followed by the
        initial-condition names.
    linear : Forward
        The linear part (the model without ``drag`` and ``friction``).
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
        n_modes: int | None = None,
        steps_per_period: float = 0.5,
        bandwidth: float | None = None,
        backend: str = "auto",
    ) -> None:
        self.model = parse_model(model)
        if not self.model.nonlinear:
            raise NonlinearError(
                f"model {self.model.name!r} has no amplitude-dependent part "
                f"({', '.join(NONLINEAR)}); use bayesbeam.physics.forward.Forward for "
                "linear models or add one, e.g. '+drag'"
            )
        linear = parse_model("+".join(p for p in self.model.parts if p not in NONLINEAR))
        self.linear = Forward(beam, linear, times, n_elements=n_elements, initial=initial,
                              initial_state=initial_state, t0=t0, bandwidth=bandwidth)
        if n_modes is None:
            n_modes = {"displacement": 3, "velocity": 4, "acceleration": 5}[self.linear.quantity]
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
        self.bandwidth = self.linear.bandwidth  # Hz or None, as Forward's
        m = self.fe.n_dof
        self.n_modes = int(min(n_modes, m))
        self.steps_per_period = spp
        try:
            self.backend = _pick_backend(backend)
        except ValueError as err:
            raise NonlinearError(str(err)) from None
        self._m_sub = int(min(m, self.n_modes + _EXTRA_MODES))
        self.param_names: tuple[str, ...] = self.model.physical_params + tuple(
            n for n in self.linear.param_names if n not in self.linear.model.physical_params
        )
        self._lin_idx = np.array([self.param_names.index(n) for n in self.linear.param_names])
        # Column of each nonlinear parameter, None when the model lacks it (counts as 0).
        self._i_drag = self.param_names.index("drag") if "drag" in self.param_names else None
        self._i_fric = (self.param_names.index("friction") if "friction" in self.param_names
                        else None)
        self._i_slope = (self.param_names.index("f1_slope") if "f1_slope" in self.param_names
                         else None)
        self._i_k2 = self.param_names.index("k2") if "k2" in self.param_names else None
        self._tau = self.times - self.t0  # (T,) s since the initial condition
        self._step = _sampling_step(self._tau)
        xq, wq = _gauss_points(np.asarray(self.fe.nodes), _DRAG_GAUSS)
        self._Nq = self.fe.shape(xq)  # (nq, n) displacement rows at the drag points
        self._wq = wq
        self._order = {"displacement": 0, "velocity": 1, "acceleration": 2}[self.quantity]

    # -- parameter handling ---------------------------------------------------------------
    def _columns(self, theta: np.ndarray | dict) -> np.ndarray:
        return parameter_columns(theta, self.param_names, NonlinearError)

    def _forces(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Columns ``drag`` (kg/m²), ``friction`` (N), ``f1_slope`` (Hz/m); 0 where absent."""
        zero = np.zeros(theta.shape[0])
        drag = theta[:, self._i_drag] if self._i_drag is not None else zero
        fric = theta[:, self._i_fric] if self._i_fric is not None else zero
        slope = theta[:, self._i_slope] if self._i_slope is not None else zero
        return drag, fric, slope

    def check(self, theta: np.ndarray | dict) -> np.ndarray:
        """Return the mask of admissible parameter sets.

        ``drag`` (kg/m²) and ``friction`` (N), where the model has them, must be finite
        and ≥ 0, ``f1_slope`` (Hz/m) and ``k2`` finite; the other parameters as in
        :meth:`bayesbeam.physics.forward.Forward.check`.

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
            if j is not None:
                ok &= np.isfinite(theta[:, j]) & (theta[:, j] >= 0)
        for j in (self._i_slope, self._i_k2):
            if j is not None:
                ok &= np.isfinite(theta[:, j])
        return ok

    def first_mode(self, theta: np.ndarray | dict) -> tuple[np.ndarray, np.ndarray]:
        """Return the linear part's first frequency and mode (:meth:`.Forward.first_mode`)."""
        return self.linear.first_mode(self._columns(theta)[:, self._lin_idx])

    def modes(self, theta: np.ndarray | dict) -> tuple[np.ndarray, np.ndarray]:
        """Natural frequencies (Hz) and damping ratios of the linear part of one set.

        Parameters
        ----------
        theta : ndarray, shape (P,) or dict
            One parameter set, columns :attr:`param_names`; ``drag`` and ``friction`` are
            checked but change no linear mode.

        Returns
        -------
        frequencies_hz, damping_ratios : ndarray, shape (k,)
            See :meth:`bayesbeam.physics.forward.Forward.modes`.
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
        omega, C, phi, z0 = lin.modal_initial_state(th_lin)  # z0 at t0, before any lead
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
        shown = active
        if lin.bandwidth is not None:  # the sensor's filter removes these modes
            shown = shown & (np.abs(lamk) <= 2 * np.pi * lin.bandwidth)
        return {"lam": lamk, "X": X, "W": W, "c": c, "v2": v2, "q1": q1,
                "s1": s1, "active": active, "shown": shown, "xtip": xtip}

    # -- slow flow ----------------------------------------------------------------------
    def _slow_flow(self, cm: dict[str, np.ndarray], drag: np.ndarray, fric: np.ndarray,
                   slope: np.ndarray) -> tuple[Any, ...]:
        """Envelopes and phases of the modes on each set's RK4 grid.

        Returns ``z_g``, ``dz_g`` (N + 1, b, K + 1): ``(ρ_1..ρ_K, θ)`` and their
        derivatives at the nodes; the steps ``h`` (b,) in s and ``n_steps`` (b,); the
        mode ``k1`` (b,) that carries θ, its phase-rate coefficient ``pcoef`` (b,) and
        whether any set has one (``use_phase``).
        """
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
        # Passive modes (see _passive) keep ρ = 1 but stay in the other modes' tone.
        dcoef = np.where(self._passive(cm, Bs), 0.0, dcoef)
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
        # Phase of that mode: θ' = 2π s A, A = 2 |c| |φ(L)·q| e^{στ} ρ its tip amplitude.
        pcoef = np.where(act[rows, k1], 2 * np.pi * slope * 2 * ac[rows, k1]
                         * cm["xtip"][rows, k1], 0.0)  # (b,)
        use_phase = bool(np.any(pcoef != 0))
        sig1 = sig[rows, k1]

        def rate(tau: np.ndarray, z: np.ndarray) -> np.ndarray:
            """Return the derivative at times tau (b,) of z = (ρ_1..ρ_K, θ), (b, K + 1)."""
            r = np.maximum(z[:, :K], 0.0)
            e = np.exp(sig * tau[:, None])  # (b, K)
            out = np.zeros_like(z)
            if use_drag:
                Bx = Bs * (e * r)[:, :, None]  # (b, K, nq)
                tot = np.sum(Bx**2, axis=1, keepdims=True)
                Ax = np.sqrt(np.maximum(tot - Bx**2, 0.0))
                G = two_tone_drag(Ax, Bx)
                out[:, :K] -= r * dcoef * np.einsum("bkq,q->bk", W2 * G, wq)
            with np.errstate(over="ignore", invalid="ignore"):
                fr = np.where(fcoef > 0, fcoef / e, 0.0)
            out[:, :K] -= np.where(r > 0, fr, 0.0)
            if use_phase:
                out[:, K] = pcoef * np.exp(sig1 * tau) * r[rows, k1]
            return out

        tau_end = float(self._tau[-1])
        f_set = np.abs(lam[rows, 0].imag) / (2 * np.pi)  # first complex mode, Hz
        n_steps = np.ceil(self.steps_per_period * tau_end * np.where(np.isfinite(f_set),
                                                                     f_set, 1.0))
        # The drag's decay rate per unit ρ is largest at the start (it grows with the
        # amplitude); at most 0.5 of it per step keeps RK4 accurate where the default
        # grid of two periods per step would not be (strong drag or large amplitudes:
        # the scheme's error grows as (h ρ'/ρ)⁵ and its stability ends at 2.8).
        z = np.concatenate([np.ones((b, K)), np.zeros((b, 1))], axis=1)
        with np.errstate(all="ignore"):
            r_init = np.abs(rate(np.zeros(b), z)[:, :K])
        r_init = np.max(np.where(np.isfinite(r_init), r_init, 0.0), axis=1)
        n_steps = np.maximum(n_steps, np.ceil(2.0 * tau_end * r_init))
        n_steps = np.clip(n_steps, 8, 100_000).astype(int)  # (b,)
        h = tau_end / n_steps  # (b,) per-set step: a set's grid ignores the batch
        N = int(n_steps.max())
        pcoef = np.broadcast_to(pcoef, (b,))
        if self.backend == "numba":
            gg, dg = _drag_lerp()
            f64 = np.ascontiguousarray
            z_g, dz_g = compiled_kernel(_rk4_grid_py)(
                f64(sig), f64(Bs), f64(W2), f64(wq), f64(dcoef), f64(fcoef),
                f64(pcoef, dtype=float), k1.astype(np.int64), f64(h),
                n_steps.astype(np.int64), N, gg, dg, use_drag, use_phase)
        else:
            z_g, dz_g = self._rk4_numpy(rate, K, h, n_steps, N)
        return z_g, dz_g, h, n_steps, k1, pcoef, use_phase

    def _passive(self, cm: dict[str, np.ndarray], Bs: np.ndarray) -> np.ndarray:
        """Modes whose own drag the slow flow may leave out, (b, K) bool.

        A mode is passive where the sensor does not show it (``shown``: above the band)
        and its largest velocity amplitude at the drag points stays below
        :data:`PASSIVE` of the largest mode's, at the start and at the end of the record
        (amplitudes are exponentials in τ, so their ratios are extreme at the ends).
        Such a mode keeps its linear decay (ρ ≡ 1) but still enters the other modes'
        drag as part of their other tone, so what it changes is only the other tone's
        share of its own drag loss: a relative change of at most ~PASSIVE² in the shown
        modes' drag (``G(A, B) = 4B/3π (1 + O(A²/B²))``), and nothing in the signal,
        which does not show it. On a whole record the hidden modes are excited only
        through the damping's coupling (steel, round 3: velocity amplitudes 1e-6 to
        1.4e-5 of mode 1's), and their drag was 60 % of a drag set's time.
        """
        amp0 = np.max(Bs, axis=2)  # (b, K) at τ = 0
        ampT = amp0 * np.exp(cm["lam"].real * float(self._tau[-1]))
        with np.errstate(invalid="ignore"):
            small = ((amp0 <= PASSIVE * np.max(amp0, axis=1, keepdims=True))
                     & (ampT <= PASSIVE * np.max(ampT, axis=1, keepdims=True)))
        return ~cm["shown"] & small

    @staticmethod
    def _rk4_numpy(rate: Callable, K: int, h: np.ndarray, n_steps: np.ndarray, N: int,
                   ) -> tuple[np.ndarray, np.ndarray]:
        """RK4 grid of the slow flow, vectorised over the batch (the route without numba)."""
        b = h.size
        z = np.concatenate([np.ones((b, K)), np.zeros((b, 1))], axis=1)
        z_g = np.empty((N + 1, b, K + 1))
        dz_g = np.empty((N + 1, b, K + 1))
        with np.errstate(over="ignore", invalid="ignore", under="ignore"):
            for i in range(N + 1):
                tau = np.minimum(i, n_steps) * h
                d = rate(tau, z)
                d[:, :K] = np.where(z[:, :K] > 0, d[:, :K], 0.0)
                z_g[i], dz_g[i] = z, d
                if i == N:
                    break
                hh = h[:, None]
                k2 = rate(tau + 0.5 * h, z + 0.5 * hh * d)
                k3 = rate(tau + 0.5 * h, z + 0.5 * hh * k2)
                k4 = rate(tau + h, z + hh * k3)
                new = z + hh / 6 * (d + 2 * k2 + 2 * k3 + k4)
                new[:, :K] = np.maximum(new[:, :K], 0.0)
                new = np.where(np.isnan(new), 0.0, new)
                z = np.where((i < n_steps)[:, None], new, z)
        return z_g, dz_g

    def _interpolate(self, z_g: np.ndarray, dz_g: np.ndarray, h: np.ndarray,
                     n_steps: np.ndarray, k1: np.ndarray, pcoef: np.ndarray,
                     use_phase: bool) -> tuple[np.ndarray, ...]:
        """Envelopes and phases at the sample times from the RK4 grid (numpy route).

        Returns ``ρ - 1``, ``ρ'`` (1/s), ``θ`` (rad) and ``θ'`` (rad/s), each of shape
        (b, T, K'), for the K' modes whose envelope or phase moves in some set of the
        batch, and their indices (K',).
        """
        b = h.size
        N = z_g.shape[0] - 1
        K = z_g.shape[2] - 1
        rows = np.arange(b)
        # Cubic Hermite interpolation to the sample times on each set's own grid, as one
        # cubic per interval, z = a0 + u (a1 + u (a2 + u a3)) with u the position in the
        # interval (coefficients formed on the grid, gathered once). Only the modes whose
        # envelope moves in some set need it (friction alone moves one), and the phase.
        moving = np.flatnonzero(np.any(z_g[:, :, :K] != 1.0, axis=(0, 1)))
        if use_phase:
            moving = np.union1d(moving, k1[pcoef != 0])
        cols = np.append(moving, K) if use_phase else moving
        Km = moving.size
        if cols.size == 0:  # nothing moves (forces too weak to change ρ in float)
            empty = np.zeros((b, self._tau.size, 0))
            return empty, empty, empty, empty, moving
        z_g, dz_g = z_g[:, :, cols], dz_g[:, :, cols]
        r0, r1 = z_g[:-1], z_g[1:]  # (N, b, C)
        d0, d1 = dz_g[:-1] * h[None, :, None], dz_g[1:] * h[None, :, None]
        a2 = 3 * (r1 - r0) - 2 * d0 - d1
        a3 = 2 * (r0 - r1) + d0 + d1
        # In the step where friction stops a mode (ρ reaches 0) the envelope has a kink: a
        # cubic through it would bulge by up to a quarter of the step's decrement, so use
        # the straight line from the last positive node there (near the stop ρ' ≈ -b(τ),
        # independent of ρ, and the line is accurate to O(h² b')).
        kink = (r0 > 0) & (r1 <= 0)
        kink[:, :, Km:] = False  # the phase column has no kink
        a2 = np.where(kink, 0.0, a2)
        a3 = np.where(kink, 0.0, a3)
        base = r0.copy()
        base[:, :, :Km] -= 1.0  # ρ - 1 for the envelopes, θ itself for the phase
        C = cols.size
        coef = np.concatenate([base, d0, a2, a3], axis=2)  # (N, b, 4C)
        coef = np.ascontiguousarray(np.swapaxes(coef, 0, 1)).reshape(b * N, 4 * C)
        sj = self._tau[None, :] / h[:, None]  # (b, T)
        j = np.clip(np.floor(sj).astype(np.intp), 0, n_steps[:, None] - 1)
        u = np.clip(sj - j, 0.0, 1.0)  # (b, T)
        cj = np.take(coef, (j + N * np.arange(b)[:, None]).ravel(), axis=0)
        cj = cj.reshape(b, -1, 4, C)  # (b, T, 4, C)
        c0, c1, c2, c3 = cj[:, :, 0], cj[:, :, 1], cj[:, :, 2], cj[:, :, 3]
        u = u[:, :, None]
        Z = c0 + u * (c1 + u * (c2 + u * c3))
        D = (c1 + u * (2 * c2 + 3 * u * c3)) / h[:, None, None]
        U, V = Z[:, :, :Km], D[:, :, :Km]  # ρ - 1, ρ'
        stopped = U <= -1.0
        U[stopped] = -1.0
        V[stopped] = 0.0
        TH = np.zeros_like(U)
        DTH = np.zeros_like(U)
        if use_phase:
            at = np.searchsorted(moving, k1)  # column of each set's first mode
            TH[rows, :, at] = Z[:, :, Km]
            DTH[rows, :, at] = D[:, :, Km]
        return U, V, TH, DTH, moving

    def _modal_exponentials(self, lam: np.ndarray) -> np.ndarray:
        """``exp(λ τ)`` at the sample times, shape (b, T, K), complex.

        On uniform stamps as products of a coarse and a fine table (one complex product
        per sample instead of a complex exponential; rounding ~1e-16 per factor).
        """
        tau = self._tau
        T = tau.size
        b, K = lam.shape
        if not self.linear.uniform:
            return np.exp(tau[None, :, None] * lam[:, None, :])
        dt = self.linear.dt
        nf = int(np.ceil(np.sqrt(T)))
        nc = -(-T // nf)
        fine = np.exp((dt * np.arange(nf))[None, :, None] * lam[:, None, :])  # (b, nf, K)
        coarse = np.exp((tau[0] + dt * nf * np.arange(nc))[None, :, None] * lam[:, None, :])
        E = coarse[:, :, None, :] * fine[:, None, :, :]  # (b, nc, nf, K)
        return E.reshape(b, nc * nf, K)[:, :T]

    def _correction(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nonlinear correction to the linear signal, (b, T), and its validity (b,)."""
        th_lin = theta[:, self._lin_idx]
        drag, fric, slope = self._forces(theta)
        with np.errstate(all="ignore"):
            cm = self._complex_modes(th_lin)
            lam = cm["lam"]
            X = np.where(cm["shown"], cm["X"], 0.0)
            grid = self._slow_flow(cm, drag, fric, slope)
            if self.backend == "numba":
                z_g, dz_g, h, n_steps, k1, _, use_phase = grid
                dy = compiled_kernel(_correction_py)(
                    z_g, dz_g, h, n_steps.astype(np.int64), k1.astype(np.int64), use_phase,
                    np.ascontiguousarray(lam.real), np.ascontiguousarray(lam.imag),
                    np.ascontiguousarray(X.real), np.ascontiguousarray(X.imag), self._order,
                    self._tau, self._step)
                ok = np.all(np.isfinite(dy), axis=1)
                return np.where(ok[:, None], dy, 0.0), ok
            U, V, TH, DTH, moving = self._interpolate(*grid)
            lam, X = lam[:, moving], X[:, moving]
            # Mode k adds 2 Re(X e^{λτ} [λ^p (ρ e^{iθ} - 1) + p λ^{p-1} (ρ' + iθ'ρ) e^{iθ}])
            # (p-th derivative of ρ e^{iθ} e^{λτ} without the O(ε²) ρ'', θ'', θ'² terms).
            # Written so that θ = 0 gives exactly the envelope-only terms U and V.
            p = self._order
            Pm = (2 * X)[:, None, :] * self._modal_exponentials(lam)  # (b, T, K)
            lp = lam**p
            ld = p * lam ** (p - 1) if p else np.zeros_like(lam)
            rot = np.exp(1j * TH)
            Zc = U + (1.0 + U) * (rot - 1.0)
            Dc = V * rot + 1j * DTH * (1.0 + U) * rot
            term = lp[:, None, :] * Zc + ld[:, None, :] * Dc
            dy = np.sum(Pm.real * term.real - Pm.imag * term.imag, axis=2)
        ok = np.all(np.isfinite(dy), axis=1)
        return np.where(ok[:, None], dy, 0.0), ok

    # -- public ---------------------------------------------------------------------------
    def simulate(self, theta: np.ndarray | dict) -> Response:
        """Sensor signal for a batch of parameter sets: linear signal plus slow-flow correction.

        Parameters
        ----------
        theta : ndarray, shape (B, P), or dict of name → array
            Parameter sets, columns :attr:`param_names` (SI units: ``drag`` in kg/m²,
            ``friction`` in N, ``k2`` in 1/(signal unit), where the model has them).

        Returns
        -------
        Response
            As from :meth:`bayesbeam.physics.forward.Forward.simulate`: ``y`` (B, T) in SI units
            of the sensor's quantity and the ``valid`` mask (B,); rows of invalid sets are
            zero (never NaN).
        """
        theta = self._columns(theta)
        valid = self.check(theta)
        y = np.zeros((theta.shape[0], self._tau.size))
        if not np.any(valid):
            return Response(y, valid)
        lin = self.linear.simulate(theta[:, self._lin_idx])
        valid &= lin.valid
        y[valid] = lin.y[valid]
        drag, fric, slope = self._forces(theta)
        nl = valid & ((drag > 0) | (fric > 0) | (slope != 0))
        if np.any(nl):
            dy, ok = self._correction(theta[nl])
            idx = np.flatnonzero(nl)
            y[idx[ok]] += dy[ok]
            y[idx[~ok]] = 0.0
            valid[idx[~ok]] = False
        if self._i_k2 is not None:  # the sensor's reading, y + k2 y² (module docstring)
            k2 = np.where(valid, theta[:, self._i_k2], 0.0)
            with np.errstate(over="ignore", invalid="ignore"):
                y += k2[:, None] * y * y
            bad = valid & ~np.all(np.isfinite(y), axis=1)
            y[bad] = 0.0
            valid &= ~bad
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
            Dimensionless; 0 for a force the model lacks, NaN for invalid sets.
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
        drag, fric, _ = self._forces(th)
        with np.errstate(all="ignore"):
            cm = self._complex_modes(th[:, self._lin_idx])
            lam = cm["lam"][:, 0]
            # The mode alone: tip displacement amplitude 2 |c| |φ(L)·q| = amplitude fixes |c|.
            cabs = amp / (2 * cm["xtip"][:, 0])
            B = cabs[:, None] * np.abs(cm["W"][:, 0])  # velocity amplitude at the drag points
            R2 = 2 * cabs**2 * cm["v2"][:, 0]  # twice the cycle-mean energy
            P_d = drag * (4 / (3 * np.pi)) * np.sum(self._wq * B**3, axis=1)
            P_f = fric * cm["s1"] * (2 / np.pi) * 2 * cabs * cm["q1"][:, 0]
            zd[valid] = P_d / R2 / np.abs(lam)
            zf[valid] = P_f / R2 / np.abs(lam)
        return zd, zf


def nonlinear_damping_scales(
    beam: Beam, E: float, amplitude: float, *, n_elements: int = 16
) -> tuple[float, float]:
    """First-mode damping ratio per unit drag and per unit friction at a tip amplitude.

    The equivalent damping ratios of :meth:`NonlinearForward.equivalent_damping` are
    linear in ``drag`` and ``friction``; this returns their coefficients for the beam as
    described (its tip mass, root spring and spanwise factors included), for setting
    priors on quantities a user can judge: e.g. ``drag`` such that
    ``ζ_drag ∈ [1e-7, 0.05]`` at the record's amplitude is
    ``LogUniform(1e-7 / k_d, 0.05 / k_d)``.

    Parameters
    ----------
    beam : Beam
    E : float
        Young's modulus, Pa.
    amplitude : float
        Tip displacement amplitude of the first mode, m.
    n_elements : int

    Returns
    -------
    k_drag : float
        ζ per unit ``drag``, m²/kg (ζ_drag = k_drag · drag).
    k_friction : float
        ζ per unit ``friction``, 1/N (ζ_friction = k_friction · friction).
    """
    fwd = NonlinearForward(beam, "viscous+drag+friction", np.array([0.0, 1.0]),
                           n_elements=n_elements)
    p = {"E": E, "gamma": 0.0, "drag": 1.0, "friction": 1.0, "w0": 0.0}
    zd, zf = fwd.equivalent_damping(p, amplitude)
    if not (np.isfinite(zd[0]) and np.isfinite(zf[0])):
        raise NonlinearError(f"E = {E!r} Pa is not an admissible Young's modulus")
    return float(zd[0]), float(zf[0])
