"""Forward model: physical parameters → signal at the sensor, batched over parameter sets.

Data flow (physics.md §1, §4): beam description → FE matrices (:mod:`bayesbeam.physics.fem`) and
spatial-hysteresis operator (:mod:`bayesbeam.physics.hysteresis`) → undamped modal basis
(Φ M-orthonormal, Φᵀ K Φ = Ω²) → modal damping C = Φᵀ D Φ → exact response of
z' = A z, z = [Ω q; q'] (:mod:`bayesbeam.physics.propagate`) → sensor output.

The modal form keeps the state matrix well conditioned even with Kelvin–Voigt damping
(physics.md §4, "Conditioning").

Sensor band. A sensor records the beam through an anti-alias filter; with ``bandwidth`` the
output is what an ideal linear-phase low-pass with that cut-off would record once it has
settled: every free-vibration eigen-solution ``e^{λt}`` with ``|λ| <= 2π·bandwidth`` passes
unchanged and every other one is removed. This is exact for the ideal filter and needs no
truncation argument: the spectral projector ``P`` onto the kept eigen-solutions commutes
with the state matrix, so propagating ``P z0`` gives exactly the kept part of the response.
For classically damped sets (modal damping matrix diagonal) the eigen-solutions of mode k
are those of its own 2x2 block, so ``P`` zeroes the modal coordinates of the modes above
the band and they are dropped from the propagation altogether; other sets (spatial
hysteresis, non-proportional damping) use the eigenvectors of the state matrix. Without
``bandwidth`` no mode is dropped (a sensor of unlimited band).

Closed-form path. When every set of a batch is classically damped with shared mode shapes
(viscous and/or Kelvin–Voigt damping whose modal images are exactly diagonal, no spatial
hysteresis, no structural parameter or root spring: E only scales the frequencies), each
mode is an independent damped oscillator and :meth:`Forward.simulate` sums the modes in
closed form (:mod:`bayesbeam.physics.modal_closed`) instead of propagating the state: the
same response to rounding (checked to 1e-9 relative in the tests), at any stamps. The
choice is made in one place, :meth:`Forward._path_for`; ``path='full'`` forces the
propagation, and :attr:`Forward.last_path` says which path the last call took.

Band-modes path. With a sensor band and coupled damping (spatial hysteresis, damping not
proportional to M or K, any structure), the few eigen-solutions inside the band are found
directly from the modal quadratic eigenproblem and summed in closed form
(:mod:`bayesbeam.physics.modal_coupled`): the same kept eigen-solutions as the
state-space reduction of :func:`~bayesbeam.physics.sensor.band_limit` (to rounding,
1e-9 relative in the tests) without reducing or propagating the ``2n``-dimensional state.
Sets where that iteration does not apply (a mode at the band edge, strong coupling) are
propagated in full, and :attr:`Forward.last_path` then reads 'band-modes+full'. The
iteration is a compiled kernel: where numba does not import, the band takes the
state-space reduction (its numpy route) instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from bayesbeam._util import numba_available
from bayesbeam.physics import propagate
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.expm import expm_batched
from bayesbeam.physics.fem import FEModel, assemble, static_tip_shape
from bayesbeam.physics.hysteresis import HysteresisOperator
from bayesbeam.physics.inputs import (
    _LOWER,
    _UPPER,
    ForwardError,
    grid_with_holes,
    initial_names,
    parameter_columns,
)
from bayesbeam.physics.modal_closed import closed_form_response, terms_response
from bayesbeam.physics.modal_coupled import band_eigenpairs, band_terms
from bayesbeam.physics.models import Model, parse_model
from bayesbeam.physics.sensor import band_limit, check_bandwidth

__all__ = [
    "Forward",
    "ForwardError",
    "Response",
    "grid_with_holes",
    "initial_names",
    "modal_properties",
    "parameter_columns",
]


@dataclass(frozen=True)
class Response:
    """Batched sensor signal.

    Attributes
    ----------
    y : ndarray, shape (B, T), or (B, T, p) from :meth:`Forward.simulate_basis`
        Signal in SI units of the sensor's quantity (m, m/s or m/s^2); rows of
        invalid sets are zero.
    valid : ndarray of bool, shape (B,)
        False where the parameter set is outside its admissible range or the
        solution was not finite.
    """

    y: np.ndarray
    valid: np.ndarray


def _modal_image(X: np.ndarray, R: np.ndarray, r_diag: np.ndarray, phi: np.ndarray
                 ) -> np.ndarray:
    """``Φᵀ X Φ``; exactly ``c diag(r_diag)`` when ``X = c R`` to 1e-13 (``Φᵀ R Φ = diag``).

    ``phi`` holds the M-orthonormal eigenvectors of (K, M), so ``R`` = M has image I and
    ``R`` = K has image diag(ω²/E).
    """
    c = float(np.sum(X * R) / np.sum(R * R))
    if np.max(np.abs(X - c * R)) <= 1e-13 * np.max(np.abs(X)):
        return np.diag(c * r_diag)
    return phi.T @ X @ phi


def _is_diagonal(X: np.ndarray) -> bool:
    """Whether the square matrix ``X`` has exactly zero off-diagonal entries."""
    return not np.any(X - np.diag(np.diagonal(X)))


def _eigh_batched(X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched ``eigh`` that loses only the sets LAPACK fails on (finite but absurd scales).

    Returns eigenvalues (B, n), eigenvectors (B, n, n) and a (B,) mask of failed sets, whose
    results are replaced by those of the identity.
    """
    failed = np.zeros(X.shape[0], dtype=bool)
    try:
        w, V = np.linalg.eigh(X)
    except np.linalg.LinAlgError:
        n = X.shape[1]
        w, V = np.ones(X.shape[:2]), np.broadcast_to(np.eye(n), X.shape).copy()
        for k in range(X.shape[0]):
            try:
                w[k], V[k] = np.linalg.eigh(X[k])
            except np.linalg.LinAlgError:
                failed[k] = True  # flagged invalid by the caller
    return w, V, failed


class Forward:
    """Batched forward model of one trial: parameter sets → sensor signal.

    Parameters
    ----------
    beam : Beam
        Beam description, including sensor position and measured quantity.
    model : str or Model
        Damping laws and structural extensions, e.g. ``'viscous+sh'``.
    times : array_like, shape (T,)
        Sample times in s, strictly increasing; the initial condition holds at
        ``times[0]``. Uniform spacing (to 1e-9 relative) takes the fast propagator.
    n_elements : int
        Number of Hermite elements.
    initial : str
        'release' (static tip load released; parameter ``w0`` = tip deflection in m),
        'impulse' (tip impulse ``p0`` in N s from rest), 'modes:K' (displacement
        ``A_k`` and velocity/ω ``B_k`` of the first K modes at the sensor, m) or 'state'.
    initial_state : tuple of ndarray, optional
        ``(c0, v0)`` dof vectors (shape (n,)) for ``initial='state'``.
    t0 : float, optional
        Instant (s) at which the initial condition holds, ``t0 <= times[0]``; default
        ``times[0]`` (a decimated trial keeps its release instant in ``Trial.t0``).
    bandwidth : float, optional
        Sensor bandwidth in Hz (see the module docstring): eigen-solutions with
        ``|λ| > 2π·bandwidth`` are removed from the output. None or inf: all modes.
    path : {'auto', 'full'}, optional
        'auto' (default): classically damped models with a fixed structure take the
        closed-form modal sum, coupled models seen through a sensor band the band's
        eigen-solutions (see the module docstring), all others the full propagation;
        'full': always the full propagation (a reference for tests and the benchmark).
        Can be changed later through the attribute of the same name.

    Attributes
    ----------
    classical : bool
        Whether this model is classically damped with shared mode shapes (the closed-form
        path applies to every admissible set).
    last_path : str or None
        Path of the last :meth:`simulate` (or :meth:`simulate_basis`) call:
        'closed-form', 'band-modes', 'full', or 'closed-form+full' / 'band-modes+full'
        when some sets were propagated in full (a near-critical mode split by the band
        edge, a mode at the band edge, a set the fast path could not evaluate); None
        before the first call.
    """

    def __init__(
        self,
        beam: Beam,
        model: str | Model,
        times: np.ndarray,
        *,
        n_elements: int = 16,
        initial: str = "release",
        initial_state: tuple[np.ndarray, np.ndarray] | None = None,
        t0: float | None = None,
        bandwidth: float | None = None,
        path: str = "auto",
    ) -> None:
        if path not in ("auto", "full"):
            raise ForwardError(f"path must be 'auto' or 'full', got {path!r}")
        self.path = path
        self.last_path: str | None = None
        if not isinstance(beam, Beam):
            raise ForwardError("beam must be a bayesbeam.Beam")
        self.beam = beam
        self.model = parse_model(model)
        if self.model.nonlinear:
            raise ForwardError(
                f"model {self.model.name!r} is nonlinear; use bayesbeam.physics.nonlinear for "
                "amplitude-dependent damping"
            )
        t = np.asarray(times, dtype=float)
        if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)):
            raise ForwardError("times must be a 1-D array of at least 2 finite values in s")
        steps = np.diff(t)
        if np.any(steps <= 0):
            raise ForwardError("times must be strictly increasing (sort the samples, drop repeats)")
        self.times = t
        t0 = float(t[0]) if t0 is None else float(t0)
        if not np.isfinite(t0) or t0 > t[0]:
            raise ForwardError(f"t0 ({t0} s) must be finite and not after the first sample")
        self.t0 = t0
        self.bandwidth = check_bandwidth(bandwidth, ForwardError)
        self._lead = float(t[0] - t0)
        self._t = t - t[0]
        self._dt = float(np.mean(steps))
        self.uniform = bool(np.max(np.abs(steps - self._dt)) <= 1e-9 * self._dt)
        self._grid = None if self.uniform else grid_with_holes(self._t)
        self.initial = initial
        self._init_names = initial_names(initial)
        root_dof = beam.root_spring is not None or "root_spring" in self.model.structural
        self.fe: FEModel = assemble(beam, n_elements, root_dof=root_dof)
        n = self.fe.M.shape[0]
        if initial.startswith("modes:") and len(self._init_names) // 2 > n:
            raise ForwardError(
                f"initial={initial!r} asks for {len(self._init_names) // 2} modes but "
                f"{n_elements} elements have only {n}; use K <= {n}"
            )
        if initial == "state":
            if initial_state is None:
                raise ForwardError("initial='state' needs initial_state=(c0, v0)")
            c0, v0 = (np.asarray(v, dtype=float) for v in initial_state)
            if c0.shape != (n,) or v0.shape != (n,):
                raise ForwardError(f"initial_state vectors must have shape ({n},)")
            self._state = (c0, v0)
        self.sh = HysteresisOperator(self.fe.nodes, root_dof) if "sh" in self.model.laws else None
        self.sensor = self.fe.shape(np.array([beam.sensor_x]))[0]
        self.quantity = beam.quantity
        self.param_names: tuple[str, ...] = self.model.physical_params + self._init_names
        # Fast path: only E changes K, so the modal basis is fixed and ω ∝ sqrt(E).
        self._fixed = not self.model.structural and beam.root_spring is None
        if self._fixed:
            w2, phi = sla.eigh(self.fe.K, self.fe.M)
            self._w_unit = np.sqrt(np.maximum(w2, 0.0))
            self._phi = phi
            # Uniform beams: G ∝ M and KV ∝ K, so viscous and Kelvin–Voigt damping are
            # classical and their modal images diagonal. Computed as Φᵀ X Φ they carry
            # round-off off the diagonal (1e-10 relative for KV at 24 elements, from the
            # conditioning of K) that band_limit would read as coupling.
            self._G = _modal_image(self.fe.G, self.fe.M, np.ones_like(w2), phi)
            self._KV = _modal_image(self.fe.KV, self.fe.K, w2, phi)
            # Static tip-load shape by statics (fem.static_tip_shape: a few ulp, where a solve
            # with the ill-conditioned K loses ~1e-11), normalised to unit tip deflection.
            shape = static_tip_shape(self.fe, 1.0)
            self._release = shape / (self.fe.tip @ shape)
            # Modal images of the fixed initial-condition shapes (per unit w0 / p0), so that
            # a batch only scales them: q0 = Φᵀ M c0 and q0' = Φᵀ M M⁻¹ tip p0 = Φᵀ tip p0.
            self._q_release = phi.T @ (self.fe.M @ self._release)
            self._q_impulse = phi.T @ self.fe.tip
        # Structure that changes K only (root spring, stiffness gradient): M and so its
        # Cholesky inverse are the same for every set; factor once.
        self._Li = None
        self._modal_cache: tuple[tuple, tuple] | None = None  # modal_initial_state's
        if not self._fixed and not {"tip_mass", "added_mass"} & set(self.model.structural):
            self._Li = np.linalg.inv(np.linalg.cholesky(self.fe.M))
        # Classical damping with shared shapes: _modal_image returned exactly diagonal
        # images for the laws present (G ∝ M, KV ∝ K to 1e-13), and no law or structure
        # couples the modes.
        laws = set(self.model.laws)
        self.classical = bool(
            self._fixed
            and laws <= {"viscous", "kv"}
            and ("viscous" not in laws or _is_diagonal(self._G))
            and ("kv" not in laws or _is_diagonal(self._KV))
        )
        if self.classical:
            self._c_unit = {"gamma": np.diagonal(self._G).copy(),
                            "c_d": np.diagonal(self._KV).copy()}
            self._s_modal = self.sensor @ self._phi

    # -- helpers --------------------------------------------------------------------
    def _columns(self, theta: np.ndarray | dict) -> np.ndarray:
        return parameter_columns(theta, self.param_names)

    def check(self, theta: np.ndarray) -> np.ndarray:
        """Return the mask of admissible parameter sets.

        Parameters
        ----------
        theta : ndarray, shape (B, P)

        Returns
        -------
        ndarray of bool, shape (B,)
        """
        theta = self._columns(theta)
        ok = np.all(np.isfinite(theta), axis=1)
        for j, name in enumerate(self.param_names):
            lo, closed = _LOWER.get(name, (-np.inf, False))
            ok &= theta[:, j] >= lo if closed else theta[:, j] > lo
            if name in _UPPER:
                ok &= theta[:, j] < _UPPER[name]
            if name == "added_mass_position":  # on the span: [0, L]
                ok &= theta[:, j] <= self.fe.length
        return ok

    def _get(self, theta: np.ndarray, name: str, default: float = 0.0) -> np.ndarray:
        if name in self.param_names:
            return theta[:, self.param_names.index(name)]
        return np.full(theta.shape[0], default)

    def modal_system(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Modal frequencies, damping matrices and mode shapes for valid sets.

        Parameters
        ----------
        theta : ndarray, shape (B, P)
            Admissible parameter sets (see :meth:`check`).

        Returns
        -------
        omega : ndarray, shape (B, m)
            Undamped natural frequencies in rad/s.
        C : ndarray, shape (B, m, m)
            Modal damping matrices Φᵀ D Φ in 1/s.
        phi : ndarray, shape (B, n, m) or (n, m)
            M-orthonormal mode shapes (shared when the structure is fixed).
        """
        theta = self._columns(theta)
        B = theta.shape[0]
        E = self._get(theta, "E")
        if self._fixed:
            phi = self._phi
            omega = np.sqrt(E)[:, None] * self._w_unit[None, :]
            C = np.zeros((B,) + self._G.shape)
            if "viscous" in self.model.laws:
                C += self._get(theta, "gamma")[:, None, None] * self._G
            if "kv" in self.model.laws:
                C += self._get(theta, "c_d")[:, None, None] * self._KV
            if self.sh is not None:
                a = self._get(theta, "a")
                C += a[:, None, None] * self.sh.projected(self._get(theta, "b"), phi)
            return omega, C, phi
        fe = self.fe
        mt = self._get(theta, "tip_mass")
        kr = self._get(theta, "root_spring", self.beam.root_spring or 0.0)
        g = self._get(theta, "stiffness_gradient")
        M = fe.M[None] + mt[:, None, None] * fe.M_tip[None]
        if self._Li is not None:  # M is the beam's own (tip_mass is 0 here)
            M = np.broadcast_to(fe.M, (B,) + fe.M.shape)
        if "added_mass" in self.model.structural:
            # A point mass m at x adds m N(x)ᵀ N(x) (as fem.assemble does for Beam.masses).
            x = np.clip(self._get(theta, "added_mass_position"), 0.0, fe.length)
            rows = fe.shape(np.nan_to_num(x))
            M = M + self._get(theta, "added_mass")[:, None, None] * (
                rows[:, :, None] * rows[:, None, :])
        K = E[:, None, None] * (fe.K[None] + g[:, None, None] * fe.K_grad[None])
        K = K + kr[:, None, None] * fe.K_root[None]
        # Sets whose matrices overflow (e.g. a huge tip mass) would make LAPACK fail for the
        # whole batch: give them harmless matrices here and NaN frequencies below, so that
        # simulate() flags them invalid instead of raising.
        bad = ~(np.isfinite(M).all(axis=(1, 2)) & np.isfinite(K).all(axis=(1, 2)))
        if bad.any():
            if self._Li is None:
                M[bad] = fe.M
            K[bad] = fe.K + fe.K_root  # positive definite with or without a root dof
        # Generalised symmetric eigenproblem via Cholesky of M (positive definite: the beam's
        # own M plus a tip mass >= 0): K̃ = L⁻¹ K L⁻ᵀ.
        if self._Li is None:
            Li = np.linalg.inv(np.linalg.cholesky(M))
        else:
            Li = np.broadcast_to(self._Li, M.shape)
        Kt = Li @ K @ np.swapaxes(Li, 1, 2)
        Kt = 0.5 * (Kt + np.swapaxes(Kt, 1, 2))
        bad |= ~np.isfinite(Kt).all(axis=(1, 2))
        Kt[bad] = np.eye(Kt.shape[1])
        w2, V, failed = _eigh_batched(Kt)
        bad |= failed
        phi = np.swapaxes(Li, 1, 2) @ V
        omega = np.sqrt(np.maximum(w2, 0.0))
        omega[bad] = np.nan
        pt = np.swapaxes(phi, 1, 2)
        C = np.zeros((B, phi.shape[2], phi.shape[2]))
        if "viscous" in self.model.laws:
            C += self._get(theta, "gamma")[:, None, None] * (pt @ fe.G @ phi)
        if "kv" in self.model.laws:
            C += self._get(theta, "c_d")[:, None, None] * (pt @ fe.KV @ phi)
        if self.sh is not None:
            a, b = self._get(theta, "a"), self._get(theta, "b")
            # One batched S(b_k) per set (the mode shapes differ between sets).
            C += a[:, None, None] * self.sh.projected(b, phi)
        self._last_K, self._last_M = K, M
        return omega, C, phi

    def first_mode(self, theta: np.ndarray | dict) -> tuple[np.ndarray, np.ndarray]:
        """Each set's first natural frequency and M-orthonormal first mode shape.

        Parameters
        ----------
        theta : ndarray, shape (B, P), or dict
            Admissible parameter sets (see :meth:`check`).

        Returns
        -------
        omega1 : ndarray, shape (B,)
            Undamped first natural frequency in rad/s.
        phi1 : ndarray, shape (B, n)
            The first mode over the FE dofs, ``φ1ᵀ M φ1 = 1`` (``M`` of each set's own
            structure: attached masses included).
        """
        theta = self._columns(theta)
        omega, _, phi = self.modal_system(theta)
        phi1 = phi[..., 0]
        return omega[:, 0], np.broadcast_to(phi1, (theta.shape[0], phi1.shape[-1]))

    def _initial_state(
        self, theta: np.ndarray, omega: np.ndarray, phi: np.ndarray
    ) -> np.ndarray | None:
        """Return the initial modal state z0 = [Ω q0; q0'], shape (B, 2m)."""
        fe = self.fe
        B, m = omega.shape
        phi_b = np.broadcast_to(phi, (B,) + phi.shape[-2:])
        pt = np.swapaxes(phi_b, 1, 2)
        q0 = np.zeros((B, m))
        v0 = np.zeros((B, m))
        if self.initial == "release":
            w0 = self._get(theta, "w0")[:, None]
            if self._fixed:
                q0 = w0 * self._q_release[None, :]
            else:
                # (B, n, 1) right-hand side: numpy >= 2 reads a (B, n) one as a matrix.
                rhs = np.broadcast_to(fe.tip[:, None], (B, fe.tip.size, 1))
                try:
                    shape = np.linalg.solve(self._last_K, rhs)[..., 0]
                except np.linalg.LinAlgError:  # an exactly singular K: only that set is lost
                    shape = np.full((B, fe.tip.size), np.nan)
                    for k in range(B):
                        try:
                            shape[k] = np.linalg.solve(self._last_K[k], fe.tip)
                        except np.linalg.LinAlgError:
                            continue  # stays NaN: flagged invalid by simulate()
                shape = shape / (shape @ fe.tip)[:, None]
                c0 = w0 * shape
                Mc = np.einsum("bn,bnk->bk", c0, self._last_M)
                q0 = np.einsum("bmn,bn->bm", pt, Mc)
        elif self.initial == "impulse":
            p0 = self._get(theta, "p0")[:, None]
            if self._fixed:
                v0 = p0 * self._q_impulse[None, :]
            else:
                v0 = p0 * np.einsum("bmn,n->bm", pt, fe.tip)
        elif self.initial == "state":
            c0, vv = self._state
            if self._fixed:
                q0 = np.broadcast_to(self._phi.T @ fe.M @ c0, (B, m)).copy()
                v0 = np.broadcast_to(self._phi.T @ fe.M @ vv, (B, m)).copy()
            else:
                Mc = self._last_M @ c0
                Mv = self._last_M @ vv
                q0 = np.einsum("bmn,bn->bm", pt, Mc)
                v0 = np.einsum("bmn,bn->bm", pt, Mv)
        else:  # modes:K — amplitudes at the sensor
            s = np.einsum("n,bnm->bm", self.sensor, phi_b)
            k = len(self._init_names) // 2
            for i in range(k):
                A = self._get(theta, f"A{i + 1}")
                Bv = self._get(theta, f"B{i + 1}")
                q0[:, i] = A / s[:, i]
                v0[:, i] = Bv * omega[:, i] / s[:, i]
        return np.concatenate([omega * q0, v0], axis=1)

    def _output(self, omega: np.ndarray, C: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Output vectors h with y = h·z, shape (B, 2m)."""
        B, m = omega.shape
        s = np.einsum("n,...nm->...m", self.sensor, phi)
        s = np.broadcast_to(s, (B, m))
        if self.quantity == "displacement":
            return np.concatenate([s / omega, np.zeros((B, m))], axis=1)
        if self.quantity == "velocity":
            return np.concatenate([np.zeros((B, m)), s], axis=1)
        # q'' = -Ω (Ω q) - C q'
        return np.concatenate([-s * omega, -np.einsum("bm,bmk->bk", s, C)], axis=1)

    # -- public ------------------------------------------------------------------
    @property
    def dt(self) -> float:
        """Mean sample step in s (the step itself when :attr:`uniform`)."""
        return self._dt

    def modal_initial_state(
        self, theta: np.ndarray | dict
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Modal system and initial modal state of admissible parameter sets.

        The hook for models built on the linear one (e.g.
        :class:`bayesbeam.physics.nonlinear.NonlinearForward`): :meth:`modal_system` plus the
        initial state those modes start from.

        Parameters
        ----------
        theta : ndarray, shape (B, P), or dict
            Admissible parameter sets (see :meth:`check`), columns :attr:`param_names`.

        Returns
        -------
        omega, C, phi : ndarray
            As returned by :meth:`modal_system`.
        z0 : ndarray, shape (B, 2m)
            Initial modal state ``[Ω q0; q0']`` at :attr:`t0` (before any propagation to
            the first sample).
        """
        theta = self._columns(theta)
        # One-entry cache: an amplitude-dependent model asks for the modal system of the
        # very sets whose linear signal it has just computed (physics/nonlinear.py), and
        # with a structural parameter that is a batched eigensolve of the FE matrices.
        # The arrays are returned read-only, so that no caller can alter the cached copy.
        key = (theta.shape, theta.tobytes())
        if self._modal_cache is not None and self._modal_cache[0] == key:
            return self._modal_cache[1]
        omega, C, phi = self.modal_system(theta)
        # _initial_state needs the stiffness matrices of this very call (self._last_K).
        out = (omega, C, phi, self._initial_state(theta, omega, phi))
        for a in out:
            if a is not None:
                a.setflags(write=False)
        self._modal_cache = (key, out)
        return out

    def state_space(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First-order modal system of admissible parameter sets.

        Parameters
        ----------
        theta : ndarray, shape (B, P)
            Admissible sets (see :meth:`check`).

        Returns
        -------
        A : ndarray, shape (B, 2m, 2m)
            State matrix of z' = A z, z = [Ω q; q'].
        z0 : ndarray, shape (B, 2m)
            Initial state at :attr:`t0` (the instant the initial condition holds; equal to
            ``times[0]`` unless ``t0`` was given).
        h : ndarray, shape (B, 2m)
            Output row: the sensor signal is y = h·z (SI units of the quantity).
        """
        return self._state_space(self._columns(theta), check=True)

    def _state_space(
        self, theta: np.ndarray, *, check: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        omega, C, phi, z0 = self.modal_initial_state(theta)
        h = self._output(omega, C, phi)
        A = propagate.state_matrix(omega, C, check=check)
        if self.bandwidth is None:
            return A, z0, h
        return band_limit(A, z0, h, omega, C, 2 * np.pi * self.bandwidth)

    def _lead_state(self, A: np.ndarray, z0: np.ndarray) -> np.ndarray:
        """Propagate z0 from t0 to the first sample, exactly; NaN rows where that fails."""
        P = np.full(A.shape, np.nan)
        fin = np.flatnonzero(np.isfinite(A).all(axis=(1, 2)))
        try:
            P[fin] = expm_batched(A[fin] * self._lead)
        except propagate.PropagationError:
            # Some set overflows (absurd parameters): redo one by one so that only those
            # sets are lost, not the batch.
            for k in fin:
                try:
                    P[k] = expm_batched(A[k : k + 1] * self._lead)[0]
                except propagate.PropagationError:
                    continue  # stays NaN: flagged invalid by the caller
        return np.einsum("bij,bj->bi", P, z0)

    def simulate(self, theta: np.ndarray | dict) -> Response:
        """Sensor signal for a batch of parameter sets.

        Parameters
        ----------
        theta : ndarray, shape (B, P), or dict of name → array
            Parameter sets with columns :attr:`param_names` (SI units).

        Returns
        -------
        Response
            ``y`` of shape (B, T) and the ``valid`` mask; invalid sets are never NaN,
            they are flagged.
        """
        theta = self._columns(theta)
        B = theta.shape[0]
        valid = self.check(theta)
        if not np.any(valid):
            return Response(np.zeros((B, self._t.size)), valid)
        th = theta[valid]
        # Admissible but extreme sets can still overflow (e.g. E = 1e300): both paths
        # report them in a mask; they are flagged here and never raise for the whole
        # batch (emcee evaluates whole ensembles at once).
        with np.errstate(all="ignore"):
            path = self._path_for()
            if path == "full":
                yy, ok = self._full(th)
            else:
                fast = self._closed_form if path == "closed-form" else self._band_modes
                yy, ok = fast(th)
                rest = np.flatnonzero(~ok)
                if rest.size:  # propagate those sets in full (they may still be invalid)
                    yy[rest], ok[rest] = self._full(th[rest])
                    path = "full" if rest.size == ok.size else path + "+full"
            self.last_path = path
        # Both paths flag non-finite rows in `ok` themselves (return_valid of the
        # propagator, closed_form_response): no second scan of the output here.
        if ok.all() and valid.all():  # the common case: no row to scatter
            return Response(np.ascontiguousarray(yy), valid)
        yy[~ok] = 0.0
        y = np.zeros((B, self._t.size))
        idx = np.flatnonzero(valid)
        valid[idx[~ok]] = False
        y[idx[ok]] = yy[ok]
        return Response(y, valid)

    def _path_for(self) -> str:
        """Return the path :meth:`simulate` takes (the one choice).

        'closed-form' (classically damped, fixed structure), 'band-modes' (any other
        damping seen through a sensor band, where numba compiles its kernel) or 'full'.
        """
        if self.path != "auto":
            return "full"
        if self.classical:
            return "closed-form"
        # The band-modes iteration is a compiled kernel; run as plain Python it would cost
        # far more than the state-space reduction's numpy route.
        if self.bandwidth is None or not numba_available():
            return "full"
        return "band-modes"

    def simulate_basis(self, theta: np.ndarray, columns: list[int]) -> Response:
        """Responses to each of the initial condition's amplitudes alone, per set.

        The signal is linear in the amplitudes of the initial condition (``w0``, ``p0``,
        the modal ``A_k``/``B_k``): the response at ``theta`` is ``Σ_j theta_j y_j`` with
        ``y_j`` the response at amplitude ``j`` = 1 and the others 0. On the propagated
        path the ``p`` responses share one modal system, one band reduction and one
        stepping matrix per set (the per-set work that dominates a whole-record model
        with an attachment); only the initial states differ. Classically damped models
        (the closed form, whose cost is the per-sample sum itself) take one
        :meth:`simulate` per amplitude.

        Parameters
        ----------
        theta : ndarray, shape (B, P)
            Parameter sets, columns :attr:`param_names`; the amplitude columns' values
            are ignored.
        columns : list of int
            Columns of the amplitudes, ``p`` of them.

        Returns
        -------
        Response
            ``y`` of shape (B, T, p) (``y[..., j]`` the response to amplitude ``columns[j]``
            alone) and ``valid`` (B,).

        Raises
        ------
        ForwardError
            A column that is not an amplitude of the initial condition.
        """
        theta = self._columns(theta)
        columns = [int(j) for j in columns]
        amplitudes = {"w0", "p0"} | set(self._init_names)
        bad = [j for j in columns if not 0 <= j < len(self.param_names)
               or self.param_names[j] not in amplitudes]
        if bad:
            raise ForwardError(
                f"columns {bad} are not amplitudes of the initial condition "
                f"{self.initial!r} (parameters {self.param_names})")
        B, T, p = theta.shape[0], self._t.size, len(columns)
        probes = []
        for j in columns:
            th = theta.copy()
            th[:, columns] = 0.0
            th[:, j] = 1.0
            probes.append(th)
        if p == 0:
            return Response(np.zeros((B, T, 0)), self.check(theta))
        if p == 1 or self._path_for() == "closed-form":
            res = [self.simulate(th) for th in probes]
            return Response(np.stack([r.y for r in res], axis=-1),
                            np.logical_and.reduce([r.valid for r in res]))
        valid = np.logical_and.reduce([self.check(th) for th in probes])
        y = np.zeros((B, T, p))
        idx = np.flatnonzero(valid)
        if idx.size == 0:
            return Response(y, valid)
        th = [pr[idx] for pr in probes]
        n = idx.size
        path = self._path_for()
        with np.errstate(all="ignore"):
            omega, C, phi = self.modal_system(th[0])
            # _initial_state reads the stiffness matrices of this very modal_system call.
            Z0 = np.stack([self._initial_state(t, omega, phi) for t in th], axis=-1)
            yy = np.zeros((n, p, T))
            ok = np.zeros(n, dtype=bool)
            rest = np.arange(n)
            if path == "band-modes":
                yy, ok = self._band_modes_basis(omega, C, phi, Z0)
                rest = np.flatnonzero(~ok)
            if rest.size:
                phi_r = phi if phi.ndim == 2 else phi[rest]
                yy[rest], ok[rest] = self._basis_full(omega[rest], C[rest], phi_r, Z0[rest])
                path = "full" if rest.size == n else path + "+full"
        self.last_path = path
        y[idx[ok]] = np.moveaxis(yy[ok], 1, -1)
        valid[idx[~ok]] = False
        return Response(y, valid)

    def _full(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full propagation of admissible sets → (y (B, T), ok (B,))."""
        return self._propagate(*self._state_space(th, check=False))

    def _basis_full(self, omega: np.ndarray, C: np.ndarray, phi: np.ndarray,
                    Z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Full propagation of ``p`` initial states per set → (y (B, p, T), ok (B,))."""
        n, p, T = omega.shape[0], Z0.shape[-1], self._t.size
        h = self._output(omega, C, phi)
        A = propagate.state_matrix(omega, C, check=False)
        if self.bandwidth is not None:
            A, Z0, h = band_limit(A, Z0, h, omega, C, 2 * np.pi * self.bandwidth)
        # The p initial states as p sets of the same (reduced) system.
        d = A.shape[1]
        yy, ok = self._propagate(np.repeat(A, p, axis=0),
                                 np.moveaxis(Z0, -1, 1).reshape(n * p, d),
                                 np.repeat(h, p, axis=0))
        return yy.reshape(n, p, T), ok.reshape(n, p).all(axis=1)

    def _stamps(self) -> tuple[dict, np.ndarray | None]:
        """Stamps of the closed-form sums from t0 → (keyword arguments, index or None).

        The same grids as the full path: lead + uniform step (the mean step), a grid
        with holes simulated whole (then ``index`` picks the samples), or the stamps.
        """
        if self.uniform:
            return {"uniform": (self._lead, self._dt, self._t.size)}, None
        if self._grid is not None:
            step, index = self._grid
            return {"uniform": (self._lead, step, int(index[-1]) + 1)}, index
        return {"times": self._lead + self._t}, None

    def _band_modes(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Band-modes path of admissible sets → (y, ok); see the module docstring.

        ``ok`` is False for sets to propagate in full instead
        (:func:`bayesbeam.physics.modal_coupled.band_eigenpairs`).
        """
        omega, C, phi, z0 = self.modal_initial_state(th)
        y, ok = self._band_modes_basis(omega, C, phi, z0[..., None])
        return y[:, 0], ok

    def _band_modes_basis(self, omega: np.ndarray, C: np.ndarray, phi: np.ndarray,
                          Z0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Band-modes path of ``p`` initial states per set → (y (B, p, T), ok (B,)).

        One eigen-solution search per set; only the coefficients differ between the
        initial states.
        """
        n, p = omega.shape[0], Z0.shape[-1]
        lam, V, norm, keep, ok = band_eigenpairs(omega, C, 2 * np.pi * self.bandwidth)
        s = np.einsum("n,...nm->...m", self.sensor, phi)
        coef = band_terms(lam, V, norm, keep, omega, Z0, s, self.quantity)  # (B, J, p)
        J = lam.shape[1]
        kw, index = self._stamps()
        y, ok_sum, _ = terms_response(np.repeat(lam, p, axis=0),
                                     np.moveaxis(coef, -1, 1).reshape(n * p, J), **kw)
        if index is not None:
            y = y[:, index]
        return y.reshape(n, p, -1), ok & ok_sum.reshape(n, p).all(axis=1)

    def _propagate(self, A: np.ndarray, z0: np.ndarray,
                   h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signal of ``z' = A z``, ``z(t0) = z0``, ``y = h·z`` at the stamps → (y, ok)."""
        if self._lead > 0:
            # The state at the first sample: exact propagation over the lead time.
            z0 = self._lead_state(A, z0)
        if self.uniform:
            return propagate.response_uniform(
                A, z0, h, self._dt, self._t.size, return_valid=True
            )
        if self._grid is not None:  # a uniform grid with holes: simulate it whole
            step, index = self._grid
            yy, ok = propagate.response_uniform(
                A, z0, h, step, int(index[-1]) + 1, return_valid=True
            )
            return yy[:, index], ok
        return propagate.response_times(A, z0, h, self._t, return_valid=True)

    def _closed_form(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closed-form modal sum of admissible classically damped sets → (y, ok).

        ``ok`` is False for sets to propagate in full instead (see
        :func:`bayesbeam.physics.modal_closed.closed_form_response`).
        """
        omega = np.sqrt(self._get(th, "E"))[:, None] * self._w_unit[None, :]
        c = np.zeros_like(omega)
        for law, name in (("viscous", "gamma"), ("kv", "c_d")):
            if law in self.model.laws:
                c += self._get(th, name)[:, None] * self._c_unit[name][None, :]
        z0 = self._initial_state(th, omega, self._phi)
        m = omega.shape[1]
        q0, v0 = z0[:, :m] / omega, z0[:, m:]
        w_band = None if self.bandwidth is None else 2 * np.pi * self.bandwidth
        kw, index = self._stamps()
        yy, ok = closed_form_response(omega, c, q0, v0, self._s_modal, self.quantity,
                                      w_band=w_band, **kw)
        return (yy, ok) if index is None else (yy[:, index], ok)

    def modes(
        self, theta: np.ndarray | dict, *, return_overdamped: bool = False
    ) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, int]:
        """Natural frequencies and damping ratios of the underdamped modes of one set.

        An overdamped mode (damping above critical) has two real eigenvalues: it decays
        without oscillating and has no frequency, so it is not among the returned modes;
        ``return_overdamped=True`` also returns how many there are.

        Parameters
        ----------
        theta : ndarray, shape (P,) or dict
        return_overdamped : bool
            Also return the number of overdamped modes.

        Returns
        -------
        frequencies_hz : ndarray, shape (k,)
            |λ|/2π of each underdamped eigenvalue λ (Im λ > 0), sorted by |λ|.
        damping_ratios : ndarray, shape (k,)
            −Re λ / |λ|.
        n_overdamped : int
            Only with ``return_overdamped``: modes with real eigenvalues (half the count
            of real eigenvalues of the state matrix; critically damped ones included).
        """
        theta = self._columns(theta)[:1]
        if not self.check(theta)[0]:
            pairs = zip(self.param_names, theta[0], strict=True)
            values = ", ".join(f"{n}={v:g}" for n, v in pairs)
            raise ForwardError(
                f"parameters outside their admissible range ({values}): E, b and a root "
                "spring must be finite and > 0, damping coefficients and tip mass >= 0, "
                "stiffness_gradient in (-2, 2)"
            )
        omega, C, _ = self.modal_system(theta)
        lam_all = propagate.eigenvalues(propagate.state_matrix(omega, C))[0]
        lam = lam_all[lam_all.imag > 1e-9 * np.abs(lam_all)]
        order = np.argsort(np.abs(lam))
        lam = lam[order]
        f, zeta = np.abs(lam) / (2 * np.pi), -lam.real / np.abs(lam)
        if not return_overdamped:
            return f, zeta
        # Real eigenvalues come in pairs, one pair per overdamped mode; the rest are the
        # conjugate pairs of the underdamped ones.
        n_real = int(np.count_nonzero(np.abs(lam_all.imag) <= 1e-9 * np.abs(lam_all)))
        return f, zeta, n_real // 2


def modal_properties(
    beam: Beam, model: str | Model, params: dict[str, float], *, n_elements: int = 16,
    return_overdamped: bool = False,
) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, int]:
    """Natural frequencies (Hz) and modal damping ratios of a damped beam.

    Parameters
    ----------
    beam : Beam
    model : str or Model
    params : dict
        Physical parameters of the model (SI); E defaults to ``beam.E``.
    n_elements : int
    return_overdamped : bool
        Also return the number of overdamped modes (no frequency: not in the arrays).

    Returns
    -------
    frequencies_hz, damping_ratios : ndarray, shape (k,)
        Of the underdamped modes; see :meth:`Forward.modes`.
    n_overdamped : int
        Only with ``return_overdamped``.
    """
    fwd = Forward(beam, model, np.array([0.0, 1.0]), n_elements=n_elements)
    p = {"w0": 0.0, **params}
    if "E" not in p:
        if beam.E is None:
            raise ForwardError("give E (Pa): the beam description has no nominal E")
        p["E"] = beam.E
    missing = [n for n in fwd.model.physical_params if n not in p]
    if missing:
        raise ForwardError(
            f"model {fwd.model.name!r} needs parameters {missing} (SI units); "
            "give them, e.g. --set gamma=0.01"
        )
    # A misspelt or foreign name (e.g. c_d for 'viscous') would otherwise be ignored silently.
    extra = sorted(set(p) - set(fwd.param_names))
    if extra:
        raise ForwardError(
            f"{extra} are not parameters of model {fwd.model.name!r}; it takes "
            f"{list(fwd.model.physical_params)} (SI units)"
        )
    return fwd.modes(p, return_overdamped=return_overdamped)
