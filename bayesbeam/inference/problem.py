"""The posterior of one model on one trial: parameters, default priors and log density.

Sampled parameters (columns of ``U``, each through its prior's transform, see
:mod:`bayesbeam.stats.priors`):

* the forward model's physical parameters (:mod:`bayesbeam.physics.models`), except that
  spatial hysteresis is sampled as ``(eta, b)`` instead of ``(a, b)``:
  ``eta = a s1(b)`` [N s m²], where ``s1(b) = φ1ᵀ S(b) φ1 / (φ1ᵀ KV φ1 / I)`` is the
  first clamped-beam mode's hysteresis damping per unit ``a`` divided by its
  Kelvin–Voigt damping per unit ``c_d I`` (``I = beam.I``, φ1 the first mode of the
  nominal FE beam, rigid clamp). So ``eta`` is the ``c_d I`` of the Kelvin–Voigt law
  that gives the first mode the same damping, i.e. the hysteresis part of the
  first-mode damping ratio is ``eta ω1 / (2 E I)`` for every ``b``: the quantity the
  data identify best. For a narrow kernel ``eta → a b²/2`` (physics.md §2; only this
  product is identified), for a kernel much wider than the beam ``eta ∝ a/b``.
  The long-beam formula ``a (1 - exp(-k1² b²/2)) / k1²`` used before is wrong on a
  cantilever by a boundary layer of relative size ≈ 3 b/L (10 % at b = 1 cm on a
  0.3 m beam) and by a factor ~40 for b ≈ 3 L; its ridge in (eta, b) was curved
  enough that the sampler missed the narrow-kernel tail of the posterior. ``a`` is
  reported as a derived quantity so the (a, b) ridge stays visible in the corner plot;
* the initial-condition amplitudes (``w0`` for a release);
* ``sigma`` (noise sd, SI units of the signal), and ``rho`` (AR(1) correlation) or
  ``offset`` (constant sensor offset) when the model has ``ar1_noise`` /
  ``sensor_offset``.

Default priors (all proper, documented in :func:`default_priors`) are set on quantities a
user can judge: modal damping ratios of the first mode between 1e-6 and 0.2, E within a
factor 4 of a reference value, and so on.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from bayesbeam.physics.fem import assemble
from bayesbeam.physics.forward import Forward, Response, initial_names
from bayesbeam.physics.models import Model, parse_model
from bayesbeam.stats.families import LogUniform, Normal, Prior, PriorError, Uniform
from bayesbeam.stats.likelihood import ar1_loglik, ar1_pointwise, iid_loglik, iid_pointwise
from bayesbeam.stats.priors import PriorSet
from bayesbeam.trials.trial import _SI_UNIT, Trial

__all__ = [
    "BETA1", "POINTWISE_BATCH", "Problem", "amplitude_names", "default_priors",
    "first_frequency", "record_f1",
    "reference_modulus",
]

#: First root of 1 + cos βL cosh βL = 0 (physics.md §4).
BETA1 = 1.875104069

#: Points per forward-model run of :meth:`Problem.log_likelihood_pointwise` (bounds the
#: forward model's working memory to a few POINTWISE_BATCH x T arrays for any number of
#: draws).
POINTWISE_BATCH = 256

#: Range of first-mode damping ratios the default damping priors span.
ZETA_RANGE = (1e-6, 0.2)


def _mode1_amplitude(trial: Trial, order: int, n_elements: int) -> float:
    """Estimate the initial first-mode tip-displacement amplitude of a record, m.

    Band-pass + Hilbert envelope around the measured first frequency
    (:func:`bayesbeam.trials.modal_id.band_modal_estimate`), extrapolated back over the trimmed
    start with the fitted decay rate, divided by ω^order for velocity/acceleration
    records and scaled from the sensor to the tip by the nominal first mode shape (rigid
    clamp). The record's peak is no substitute: the acceleration of a release is
    dominated by the higher modes (on an 8-element 0.4 m strip its first sample is 27
    times the mode-1 amplitude). Falls back to the peak when no envelope can be fitted.
    """
    from bayesbeam.trials.modal_id import band_modal_estimate

    t = np.asarray(trial.times, dtype=float)
    y = np.asarray(trial.values, dtype=float)
    f1 = record_f1(trial)
    w = 2 * np.pi * f1
    trim = 0.1
    est = band_modal_estimate(t, y, f1, trim=trim)
    if est is None or not (np.isfinite(est.amplitude) and np.isfinite(est.decay_rate)):
        amp = float(np.max(np.abs(y)))
    else:
        amp = float(est.amplitude * np.exp(max(est.decay_rate, 0.0) * trim * (t[-1] - t[0])))
    beam = trial.beam
    fe = assemble(beam, n_elements, root_dof=False)
    phi1 = sla.eigh(fe.K, fe.M, subset_by_index=[0, 0])[1][:, 0]
    x_s = beam.length if beam.sensor_position is None else beam.sensor_position
    ratio = abs(float(fe.tip @ phi1) / float(fe.shape([x_s])[0] @ phi1))
    return amp / w**order * ratio


def first_frequency(times: np.ndarray, values: np.ndarray, f_min: float = 0.5,
                    near: float | None = None) -> float:
    """First natural frequency in Hz seen in a record's spectrum.

    The lowest local maximum above ``f_min`` whose height exceeds 10 % of the
    largest peak (for acceleration records the largest peak may be a higher mode), of
    a zero-padded Hann-windowed periodogram, refined by a parabola through the log of
    the three bins around it; with ``near``, the largest peak within a factor 2 of it
    (a measured record may hold lines below the first bending mode: the test stand,
    the clamp, a slow drift). Non-uniform stamps are interpolated to their mean step
    (only to locate the peak).

    Parameters
    ----------
    times, values : ndarray, shape (T,)
        Time stamps (s) and signal.
    f_min : float
        Lowest frequency considered, Hz (at least 3 / record length: the Hann
        window's main lobe).
    near : float, optional
        Expected first frequency in Hz (e.g. the nominal beam's, :func:`record_f1`).

    Returns
    -------
    float
    """
    from bayesbeam.trials.modal_id import uniform_grid

    t = np.asarray(times, dtype=float)
    # A uniform grid: interpolated for jittered stamps; the holes of a resampled record
    # (a grid with samples dropped around gaps) hold the mean, as a straight line across
    # 0.1 s would put a spurious low "mode" in the spectrum.
    _, y, dt = uniform_grid(t, np.asarray(values, dtype=float))
    y = y - np.mean(y)
    nfft = 8 * int(2 ** np.ceil(np.log2(y.size)))
    spec = np.abs(np.fft.rfft(y * np.hanning(y.size), nfft))
    f = np.fft.rfftfreq(nfft, dt)
    # The Hann window's main lobe is 2/T wide on each side: below ~3/T a constant
    # offset (e.g. the mean of an acceleration record that starts with a release
    # spike) leaks into a spurious low "peak" stronger than 10 % of the first mode.
    spec[f < max(f_min, 3.0 / (t[-1] - t[0]))] = 0.0
    if near is not None and np.any((f > near / 2) & (f < 2 * near) & (spec > 0)):
        spec = np.where((f > near / 2) & (f < 2 * near), spec, 0.0)
        peaks = np.array([int(np.argmax(spec))])
    else:
        peaks = np.flatnonzero((spec[1:-1] > spec[:-2]) & (spec[1:-1] >= spec[2:])) + 1
        peaks = peaks[spec[peaks] > 0.1 * spec.max()]
    i = int(peaks[0]) if peaks.size else int(np.argmax(spec))
    if not 0 < i < spec.size - 1:
        return float(f[i])
    a, b, c = np.log(spec[i - 1 : i + 2] + 1e-300)
    denom = a - 2 * b + c
    shift = 0.5 * (a - c) / denom if denom != 0 else 0.0
    return float(f[i] + shift * (f[1] - f[0]))


def record_f1(trial: Trial) -> float:
    """First bending frequency of a record (Hz), sought near the nominal beam's.

    :func:`first_frequency` with ``near`` = the first natural frequency of the trial's
    beam at its nominal E (rigid clamp, declared masses); without a nominal E, the
    lowest strong peak.

    Parameters
    ----------
    trial : Trial

    Returns
    -------
    float
    """
    from bayesbeam.trials.preprocess import nominal_f1

    return first_frequency(trial.times, trial.values, near=nominal_f1(trial))


def reference_modulus(trial: Trial, *, n_elements: int = 16) -> float:
    """E (Pa) that puts the beam's first frequency on the data's first spectral peak.

    Used to centre the E prior when the beam gives no nominal E, and to start the
    optimiser. A fixed root spring makes K non-proportional to E; E is then found by
    bisection on the first frequency.

    Parameters
    ----------
    trial : Trial
    n_elements : int

    Returns
    -------
    float
    """
    beam = trial.beam
    fe = assemble(beam, n_elements, root_dof=beam.root_spring is not None)
    w_data = 2 * np.pi * first_frequency(trial.times, trial.values)
    if beam.root_spring is None:
        w_unit = np.sqrt(sla.eigh(fe.K, fe.M, eigvals_only=True)[0])
        return float((w_data / w_unit) ** 2)
    lo, hi = 1e6, 1e13
    for _ in range(100):  # bisection in log E: 100 halvings of 7 decades reach 1e-15
        mid = np.sqrt(lo * hi)
        w1 = np.sqrt(sla.eigh(mid * fe.K + beam.root_spring * fe.K_root, fe.M,
                              eigvals_only=True)[0])
        lo, hi = (mid, hi) if w1 < w_data else (lo, mid)
    return float(np.sqrt(lo * hi))


def amplitude_names(names: tuple[str, ...] | list[str]) -> list[str]:
    """Initial-condition amplitudes among sampled names (``w0``, ``p0``, ``A_k``, ``B_k``).

    The forward response is linear in them (a free vibration scales with its initial
    state), which :func:`bayesbeam.inference.fit.profile_linear` and the marginal
    likelihood of :mod:`bayesbeam.inference.joint` use.

    Parameters
    ----------
    names : sequence of str

    Returns
    -------
    list of str
        In the order of ``names``.
    """
    return [n for n in names if n in ("w0", "p0") or (n[:1] in "AB" and n[1:].isdigit())]


def _sampled_names(fwd_names: tuple[str, ...], model: Model) -> tuple[str, ...]:
    names = ["eta" if n == "a" else n for n in fwd_names]
    names.append("sigma")
    names += list(model.noise_params)
    return tuple(names)


def default_priors(
    trial: Trial, model: Model | str, *, E_ref: float | None = None, n_elements: int = 16,
    initial: str = "release",
) -> PriorSet:
    """Documented default priors for a model on a trial.

    ``E_ref`` is ``beam.E`` when given, else :func:`reference_modulus` (the data's first
    spectral peak; an empirical choice of the prior's centre whose width, a factor 16,
    dwarfs the uncertainty of that estimate). With ``w1 = BETA1² sqrt(E_ref I/(rhoA L⁴))``:

    ========================  ==================================================
    parameter                 prior
    ========================  ==================================================
    E                         LogUniform(E_ref/4, 4 E_ref)
    gamma                     LogUniform: ζ1 = gamma/(2 rhoA w1) in [1e-6, 0.2]
    c_d                       LogUniform: ζ1 = c_d w1/(2 E_ref) in [1e-6, 0.2]
    eta (SH strength)         LogUniform: SH part of ζ1 = eta w1/(2 E_ref I) in [1e-6, 0.2]
    b                         LogUniform(1e-3 L, 3 L)
    tip_mass                  LogUniform(1e-3, 0.5) × beam mass
    added_mass                LogUniform(1e-3, 0.5) × beam mass
    added_mass_position       Uniform(0, L) (m from the clamp)
    root_spring               LogUniform: κ = k L/(E_ref I) in [1, 1e4]
    stiffness_gradient        Uniform(-1, 1)
    drag, friction            LogUniform: equivalent ζ1 at the data's amplitude in [1e-7, 0.05]
    f1_slope                  Uniform(-s, s), s = 0.1 f1 / A: f1 may move by up to 10 % at
                              the data's mode-1 tip amplitude A (Hz per m)
    k2                        Uniform(-s, s), s = 0.1 / max |y - median y|: the sensor's
                              quadratic term up to 10 % of the record's largest value
    w0, p0, A_k, B_k          Uniform(-s, s), s generous (10× the data's scale)
    sigma                     LogUniform(1e-4 σ_y, 2 σ_y), σ_y = sd of the data
    rho                       Uniform(0, 0.995)
    offset                    Normal(0, σ_y)
    ========================  ==================================================

    Parameters
    ----------
    trial : Trial
    model : Model or str
    E_ref : float, optional
        Reference modulus in Pa.
    n_elements : int
    initial : str
        Initial-condition kind (see :class:`bayesbeam.physics.forward.Forward`).

    Returns
    -------
    PriorSet
    """
    model = parse_model(model)
    beam = trial.beam
    if E_ref is None:
        E_ref = beam.E if beam.E is not None else reference_modulus(trial, n_elements=n_elements)
    L, inertia, rhoA = beam.length, beam.I, beam.rhoA
    w1 = BETA1**2 * np.sqrt(E_ref * inertia / (rhoA * L**4))
    zlo, zhi = ZETA_RANGE
    sd_y = float(np.std(trial.values))
    # The priors' scales come from the record: name the record's fault, not a bound's.
    if not sd_y > 0:
        raise PriorError(f"the record of {trial.name!r} is constant (sd 0): no scale for the "
                         "priors and no motion to fit; check the value column and its unit")
    if not (np.isfinite(E_ref) and E_ref > 0):
        raise PriorError(f"no positive E to centre the E prior on (E_ref = {E_ref!r} Pa from "
                         f"the record of {trial.name!r}, which shows no first mode); give "
                         "the nominal E in [beam] or check the record's time and value columns")
    # Displacement scale of the signal: divide by ω1 per time derivative.
    order = {"displacement": 0, "velocity": 1, "acceleration": 2}[trial.quantity]
    disp_scale = float(np.max(np.abs(trial.values))) / w1**order
    out: dict[str, Prior] = {}
    fwd_names = model.physical_params + initial_names(initial)
    for n in _sampled_names(fwd_names, model):
        if n == "E":
            out[n] = LogUniform(E_ref / 4, 4 * E_ref)
        elif n == "gamma":
            out[n] = LogUniform(2 * rhoA * w1 * zlo, 2 * rhoA * w1 * zhi)
        elif n == "c_d":
            out[n] = LogUniform(2 * E_ref * zlo / w1, 2 * E_ref * zhi / w1)
        elif n == "eta":
            out[n] = LogUniform(2 * E_ref * inertia * zlo / w1, 2 * E_ref * inertia * zhi / w1)
        elif n == "b":
            out[n] = LogUniform(1e-3 * L, 3 * L)
        elif n in ("tip_mass", "added_mass"):
            out[n] = LogUniform(1e-3 * beam.beam_mass, 0.5 * beam.beam_mass)
        elif n == "added_mass_position":
            out[n] = Uniform(0.0, L)
        elif n == "root_spring":
            out[n] = LogUniform(E_ref * inertia / L, 1e4 * E_ref * inertia / L)
        elif n == "stiffness_gradient":
            out[n] = Uniform(-1.0, 1.0)
        elif n in ("w0",) or n.startswith(("A", "B")):
            s = max(10 * disp_scale, 1e-9)
            out[n] = Uniform(-s, s)
        elif n == "p0":
            s = max(10 * disp_scale * w1 * beam.beam_mass, 1e-12)
            out[n] = Uniform(-s, s)
        elif n in ("drag", "friction"):
            # Equivalent first-mode damping ratio per unit coefficient at the record's
            # initial mode-1 amplitude (bayesbeam.physics.nonlinear); the prior spans ζ 1e-7 ..
            # 0.05. The peak of an acceleration release is set by the higher modes, so
            # it would overstate the mode-1 amplitude (8x on a 0.4 m strip) and shift
            # both ends. The lower end is far below what a record can see: friction's ζ
            # grows as 1/amplitude while the record decays, and "no friction" must stay
            # within reach. Each is present only when its part (``drag``, ``friction``)
            # is in the model.
            from bayesbeam.physics.nonlinear import nonlinear_damping_scales

            amp = max(_mode1_amplitude(trial, order, n_elements), 1e-9)
            k = dict(zip(("drag", "friction"), nonlinear_damping_scales(
                beam, E_ref, amp, n_elements=n_elements), strict=True))[n]
            out[n] = LogUniform(1e-7 / k, 0.05 / k)
        elif n == "f1_slope":
            # A natural frequency that moves by 10 % with amplitude is far beyond what a
            # release test of a metal beam shows (geometric stiffening of a cantilever:
            # ~1e-3 at a tip deflection of a tenth of its length); both signs.
            amp = max(_mode1_amplitude(trial, order, n_elements), 1e-9)
            s_max = 0.1 * (w1 / (2 * np.pi)) / amp
            out[n] = Uniform(-s_max, s_max)
        elif n == "k2":
            # A sensor whose quadratic term reaches 10 % of the record's largest value is
            # far beyond any transducer in use (an accelerometer's K2 is specified in
            # 0.1-1 % of full scale, IEEE Std 1293); both signs.
            peak = float(np.max(np.abs(trial.values - np.median(trial.values))))
            k_max = 0.1 / max(peak, 1e-300)
            out[n] = Uniform(-k_max, k_max)
        elif n == "sigma":
            out[n] = LogUniform(1e-4 * sd_y, 2 * sd_y)
        elif n == "rho":
            out[n] = Uniform(0.0, 0.995)
        elif n == "offset":
            out[n] = Normal(0.0, max(sd_y, 1e-300))
        else:  # pragma: no cover - every name of models.py is handled above
            raise ValueError(f"no default prior for parameter {n!r}")
    return PriorSet(out)


class _EtaReference:
    """``s1(b)`` of the module docstring for one beam and mesh (``eta = a s1(b)``)."""

    def __init__(self, beam: Any, n_elements: int) -> None:
        from bayesbeam.physics.hysteresis import HysteresisOperator

        # Nominal beam on a rigid clamp: a fixed reference shape, so the map (eta, b) <->
        # (a, b) does not depend on other sampled parameters (E, tip mass, root spring).
        fe = assemble(beam, n_elements, root_dof=False)
        _, phi = sla.eigh(fe.K, fe.M, subset_by_index=[0, 0])
        self.phi1 = np.ascontiguousarray(phi[:, :1])
        self.op = HysteresisOperator(fe.nodes, False)
        self.kv1 = float(phi[:, 0] @ fe.KV @ phi[:, 0]) / beam.I

    def __call__(self, b: np.ndarray) -> np.ndarray:
        return self.op.projected(b, self.phi1)[:, 0, 0] / self.kv1


@dataclass(frozen=True)
class _Layout:
    """Column indices linking sampled names to forward parameters."""

    fwd: np.ndarray  # index into U columns for each forward name ('a' maps to eta)
    eta: int | None
    b: int | None
    sigma: int
    rho: int | None
    offset: int | None


class Problem:
    """Log posterior of one model on one trial, vectorised over parameter sets.

    Parameters
    ----------
    trial : Trial
        The measured signal (SI units).
    model : str or Model
        Damping laws, structural extensions and noise extensions.
    priors : PriorSet or mapping, optional
        Overrides of :func:`default_priors` (name → Prior or dict).
    n_elements : int
        Hermite elements of the forward model.
    initial : str
        Initial-condition kind (see :class:`bayesbeam.physics.forward.Forward`).
    """

    def __init__(
        self,
        trial: Trial,
        model: str | Model,
        priors: PriorSet | Mapping[str, Any] | None = None,
        *,
        n_elements: int = 16,
        initial: str = "release",
    ) -> None:
        self.trial = trial
        self.model = parse_model(model)
        self.n_elements = n_elements
        self.initial = initial
        physical = parse_model("+".join(p for p in self.model.parts if p not in
                                        ("ar1_noise", "sensor_offset")))
        if self.model.nonlinear:
            from bayesbeam.physics.nonlinear import NonlinearForward

            self.forward = NonlinearForward(trial.beam, physical, trial.times, t0=trial.t0,
                                            n_elements=n_elements, initial=initial,
                                            bandwidth=trial.sensor_band)
        else:
            self.forward = Forward(trial.beam, physical, trial.times, t0=trial.t0,
                                   n_elements=n_elements, initial=initial,
                                   bandwidth=trial.sensor_band)
        defaults = default_priors(trial, self.model, n_elements=n_elements, initial=initial)
        names = _sampled_names(self.forward.param_names, self.model)
        if priors is not None:
            unknown = sorted(set(priors) - set(names))
            if unknown:
                raise ValueError(
                    f"priors given for {unknown}, which model {self.model.name!r} does not "
                    f"have; its parameters are {list(names)}"
                )
            merged = {n: (priors[n] if n in priors else defaults[n]) for n in names}
            self.priors = PriorSet(merged)
        else:
            self.priors = defaults
        self.names = names
        idx = {n: i for i, n in enumerate(names)}
        self._lay = _Layout(
            fwd=np.array([idx["eta" if n == "a" else n] for n in self.forward.param_names]),
            eta=idx.get("eta"),
            b=idx.get("b"),
            sigma=idx["sigma"],
            rho=idx.get("rho"),
            offset=idx.get("offset"),
        )
        self._eta_ref = _EtaReference(trial.beam, n_elements) if self._lay.eta is not None else None
        self.data = np.asarray(trial.values, dtype=float)
        self.n_calls = 0

    @property
    def ndim(self) -> int:
        """Number of sampled parameters."""
        return len(self.names)

    def with_mesh(self, n_elements: int) -> Problem:
        """Return the same trial, model, priors and initial condition on another mesh.

        Parameters
        ----------
        n_elements : int

        Returns
        -------
        Problem
            ``self`` when the mesh is already ``n_elements``. The priors are kept, so
            both problems share the sampling space.
        """
        if int(n_elements) == self.n_elements:
            return self
        return Problem(self.trial, self.model, self.priors, n_elements=int(n_elements),
                       initial=self.initial)

    # -- parameter maps ---------------------------------------------------------------
    def theta(self, U: np.ndarray) -> np.ndarray:
        """Physical values of the sampled parameters (eta, not a), shape (k, ndim)."""
        return self.priors.to_theta(np.atleast_2d(U))

    def forward_params(self, X: np.ndarray) -> np.ndarray:
        """Forward-model parameters (with ``a``) from physical sampled values.

        Parameters
        ----------
        X : ndarray, shape (k, ndim)
            Output of :meth:`theta`.

        Returns
        -------
        ndarray, shape (k, P)
            Columns ``forward.param_names``.
        """
        X = np.atleast_2d(X)
        P = X[:, self._lay.fwd].copy()
        if self._lay.eta is not None:
            j = self.forward.param_names.index("a")
            b = X[:, self._lay.b]
            ok = np.isfinite(b) & (b > 0)
            s1 = np.ones_like(b)
            if np.any(ok):
                s1[ok] = self.eta_per_a(b[ok])
            # b <= 0 is invalid in the forward model anyway; a = 0 keeps the row finite.
            P[:, j] = np.where(ok, X[:, self._lay.eta] / s1, 0.0)
        return P

    def eta_per_a(self, b: np.ndarray) -> np.ndarray:
        """Ratio ``eta / a = s1(b)`` of the spatial-hysteresis parameterisation (m²).

        See the module docstring: ``s1(b) = φ1ᵀ S(b) φ1 / (φ1ᵀ KV φ1 / I)``; it tends
        to ``b²/2`` for a narrow kernel.

        Parameters
        ----------
        b : array_like, shape (k,)
            Kernel widths in m, each > 0.

        Returns
        -------
        ndarray, shape (k,)

        Raises
        ------
        ValueError
            If the model has no spatial hysteresis.
        """
        if self._eta_ref is None:
            raise ValueError(f"model {self.model.name!r} has no spatial hysteresis (sh)")
        return self._eta_ref(np.atleast_1d(np.asarray(b, dtype=float)))

    def derived(self, X: np.ndarray) -> dict[str, np.ndarray]:
        """Quantities reported besides the sampled ones (``a`` for spatial hysteresis).

        Parameters
        ----------
        X : ndarray, shape (k, ndim)

        Returns
        -------
        dict of str to ndarray, shape (k,)
        """
        if self._lay.eta is None:
            return {}
        P = self.forward_params(X)
        return {"a": P[:, self.forward.param_names.index("a")]}

    # -- densities ---------------------------------------------------------------------
    def predict(self, X: np.ndarray) -> Response:
        """Model signal (with offset) for physical sampled values, shape (k, T)."""
        X = np.atleast_2d(X)
        res = self.forward.simulate(self.forward_params(X))
        y = res.y
        if self._lay.offset is not None:
            y = y + X[:, self._lay.offset][:, None]
        return Response(y, res.valid)

    def predict_basis(self, X: np.ndarray, columns: list[int]) -> Response:
        """Signal's response to each initial-condition amplitude alone, shape (k, T, p).

        Parameters
        ----------
        X : ndarray, shape (k, ndim)
            Physical sampled values; the amplitude columns' values are ignored.
        columns : list of int
            Columns of :attr:`names` that are amplitudes (:func:`amplitude_names`).

        Returns
        -------
        Response
            :meth:`~bayesbeam.physics.forward.Forward.simulate_basis`'s: ``y`` (k, T, p)
            without the offset (the signal is ``offset + y @ amplitudes``).
        """
        X = np.atleast_2d(X)
        fwd = self._lay.fwd.tolist()
        return self.forward.simulate_basis(self.forward_params(X), [fwd.index(j) for j in columns])

    def _pointwise(self, X: np.ndarray, valid: np.ndarray, y: np.ndarray) -> np.ndarray:
        r = self.data[None, :] - y
        sigma = X[:, self._lay.sigma]
        if self._lay.rho is not None:
            rho = X[:, self._lay.rho]
            t = None if self.trial.is_uniform else self.trial.times
            return ar1_pointwise(r, sigma, rho, times=t)
        return iid_pointwise(r, sigma)

    def log_likelihood(self, U: np.ndarray) -> np.ndarray:
        """Log likelihood, shape (k,); -inf for invalid sets."""
        return self.log_likelihood_theta(self.theta(np.atleast_2d(U)))

    def log_likelihood_theta(self, X: np.ndarray) -> np.ndarray:
        """Log likelihood at physical sampled values (output of :meth:`theta`), shape (k,).

        Parameters
        ----------
        X : ndarray, shape (k, ndim)

        Returns
        -------
        ndarray, shape (k,)
            ``-inf`` for sets the forward model marks invalid.
        """
        X = np.atleast_2d(X)
        res = self.predict(X)
        self.n_calls += X.shape[0]
        out = np.full(X.shape[0], -np.inf)
        v = res.valid
        if np.any(v):
            r = self.data[None, :] - res.y[v]
            sigma = X[v, self._lay.sigma]
            if self._lay.rho is not None:
                t = None if self.trial.is_uniform else self.trial.times
                out[v] = ar1_loglik(r, sigma, X[v, self._lay.rho], times=t)
            else:
                out[v] = iid_loglik(r, sigma)
        return out

    def log_likelihood_pointwise(self, U: np.ndarray) -> np.ndarray:
        """Pointwise log likelihood, shape (k, T) (AR(1): conditional on the previous sample).

        The one home of the pointwise terms of every output (the ArviZ ``log_likelihood``
        group of :meth:`bayesbeam.inference.results.FitResult.to_inference_data`, LOO and
        WAIC of :func:`bayesbeam.comparison.scoring.evaluate`). The forward model runs on
        at most :data:`POINTWISE_BATCH` points at a time, so thousands of draws need
        memory for the (k, T) output only. Each row sums to :meth:`log_likelihood` of
        its point (the same residuals; only the order of the summation differs).
        Evaluations are not counted in :attr:`n_calls`.

        Parameters
        ----------
        U : ndarray, shape (k, ndim)
            Points in the sampling space.

        Returns
        -------
        ndarray, shape (k, T)
            Log densities in nats; ``-inf`` rows for points with an invalid model.
        """
        U = np.atleast_2d(np.asarray(U, dtype=float))
        out = np.full((U.shape[0], self.data.size), -np.inf)
        for i in range(0, U.shape[0], POINTWISE_BATCH):
            X = self.theta(U[i : i + POINTWISE_BATCH])
            res = self.predict(X)
            v = res.valid
            if np.any(v):
                out[i : i + POINTWISE_BATCH][v] = self._pointwise(X[v], v[v], res.y[v])
        return out

    @property
    def signal_unit(self) -> str:
        """SI unit of the trial's measured quantity: ``"m"``, ``"m/s"`` or ``"m/s^2"``.

        The unit of the data, of the model signal and of ``sigma`` and ``offset``
        (:func:`bayesbeam.physics.models.parameter_units`).
        """
        return _SI_UNIT[self.trial.quantity]

    def log_prob(self, U: np.ndarray) -> np.ndarray:
        """Unnormalised log posterior in the sampling space, shape (k,).

        ``log_prior_u(U) + log_likelihood(U)``; its integral over u is the evidence.
        """
        return self.priors.log_posterior_u(U, self.log_likelihood)

    __call__ = log_prob
