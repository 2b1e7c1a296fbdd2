"""Show what a fitted model gets wrong: residual signatures of model discrepancy.

For a fitted model (a :class:`~bayesbeam.inference.results.FitResult` and its
:class:`~bayesbeam.inference.problem.Problem`) :func:`compute_signatures` measures, as numbers in a
frozen :class:`Signatures` record:

* the residual time series ``r = data - E[model]`` (posterior-mean prediction), its
  RMS, mean and low-frequency content (a sensor offset or drift shows here);
* the residual autocorrelation and the Ljung–Box whiteness test (Ljung & Box 1978,
  Biometrika 65, 297-303): ``Q = n (n+2) Σ_{k=1..h} ρ̂_k² / (n-k)``, χ²_h under
  whiteness. With the AR(1) noise model it is applied to the standardised innovations
  ``(r_t - ρ r_{t-1})`` (the model's own white part), else to ``r``;
* the residual and data spectra, with the model's modal frequencies;
* per mode, the frequency and decay rate measured from the DATA and, by the same
  damped-sinusoid fit (:func:`~bayesbeam.trials.modal_id.damped_sinusoids`) on the same
  window from the first sample (:func:`~bayesbeam.trials.modal_id.windowed_sinusoids`:
  the one that measures the mode best in the data), from the model's noise-free
  prediction: the estimator's bias then cancels in the comparison. The
  modal damping ratio of mode k is ``ζ_k = σ_k / sqrt(σ_k² + ω_dk²)``;
* the ratio f2/f1 of data and model (a tip mass raises it, a root spring raises it
  little, a stiffness falling toward the tip lowers it: physics.md §3 and
  :mod:`bayesbeam.diagnosis.diagnose`), and ζ2/ζ1 (viscous damping falls with frequency, KV
  rises: physics.md §2);
* the decay rate of the first mode against its amplitude
  (:func:`~bayesbeam.trials.modal_id.decay_rate_vs_amplitude`): a linear model decays at one
  rate, quadratic air drag faster at large amplitude, dry friction faster at small
  amplitude;
* the posterior-predictive coverage of the data: the fraction of samples inside the
  central 50 % and 90 % intervals of the predictive distribution (model + noise, draws
  evenly spaced along the chain:
  :func:`~bayesbeam.inference.predictive.posterior_predictive`).

:func:`plot_signatures` draws them on a :class:`matplotlib.figure.Figure` (object API,
no pyplot state).

The whiteness statistics are :mod:`bayesbeam.stats.whiteness`'s. The estimators on a
signal alone (spectra, modal and decay-vs-amplitude estimates) live in
:mod:`bayesbeam.trials.modal_id`; they are re-exported here, where they were first defined.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayesbeam._util import finite_or_none
from bayesbeam.inference.predictive import posterior_predictive
from bayesbeam.stats.whiteness import autocorrelation, ljung_box
from bayesbeam.trials.modal_id import (
    DecayAmplitude,
    ModalEstimate,
    SignatureError,
    damped_sinusoids,
    decay_rate_vs_amplitude,
    periodogram,
    uniform_grid,
    windowed_sinusoids,
)

__all__ = [
    "ModeComparison",
    "Signatures",
    "compute_signatures",
    "model_modes",
    "plot_signatures",
]


# --------------------------------------------------------------------------- model side


def model_modes(problem: Any, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequencies (Hz) and damping ratios of the linear part of a model.

    Parameters
    ----------
    problem : Problem
    x : ndarray, shape (ndim,)
        Physical sampled values (``problem.theta`` row).

    Returns
    -------
    frequencies_hz, damping_ratios : ndarray, shape (k,)
        Underdamped modes sorted by frequency; for a model with amplitude-dependent
        damping, those of its linear part (the small-amplitude limit).
    """
    from bayesbeam.physics.forward import Forward

    fwd = problem.forward
    P = problem.forward_params(np.atleast_2d(x))[0]
    if hasattr(fwd, "modes") and isinstance(fwd, Forward):
        return fwd.modes(P)
    model = problem.model
    lin_parts = [p for p in model.parts if p not in model.nonlinear and p not in model.noise]
    lin = Forward(problem.trial.beam, "+".join(lin_parts), problem.trial.times[:2],
                  n_elements=problem.n_elements, initial=problem.initial)
    vals = dict(zip(fwd.param_names, P, strict=True))
    return lin.modes(np.array([vals[n] for n in lin.param_names]))


# --------------------------------------------------------------------------- the record


@dataclass(frozen=True)
class ModeComparison:
    """One mode: measured from the data vs measured from the model's prediction.

    Attributes
    ----------
    mode : int
        1-based mode number.
    f_model_eig, zeta_model_eig : float
        Eigen-frequency (Hz) and damping ratio of the model at the posterior mean.
    data, model : ModalEstimate or None
        Damped-sinusoid estimates (:func:`~bayesbeam.trials.modal_id.damped_sinusoids`)
        from the data and from the noise-free posterior-mean prediction (None when the
        mode is not measurable).
    """

    mode: int
    f_model_eig: float
    zeta_model_eig: float
    data: ModalEstimate | None
    model: ModalEstimate | None

    @property
    def frequency_shift(self) -> float:
        """Relative frequency difference data/model - 1 (NaN if not measured)."""
        if self.data is None or self.model is None:
            return math.nan
        return self.data.frequency / self.model.frequency - 1.0

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dictionary.

        Returns
        -------
        dict
        """
        def est(e: ModalEstimate | None) -> dict[str, float] | None:
            return None if e is None else {k: finite_or_none(v) for k, v in e.__dict__.items()}

        return {
            "mode": self.mode,
            "f_model_eig_hz": finite_or_none(self.f_model_eig),
            "zeta_model_eig": finite_or_none(self.zeta_model_eig),
            "data": est(self.data),
            "model": est(self.model),
            "frequency_shift": finite_or_none(self.frequency_shift),
        }


def _ratio_err(a: float, sa: float, b: float, sb: float) -> float:
    return abs(a / b) * math.hypot(sa / a, sb / b)


@dataclass(frozen=True, eq=False)
class Signatures:
    """Residual signatures of one fitted model on one trial (see the module docstring).

    Scalars are in SI units of the signal unless stated. Arrays are kept for plotting;
    :meth:`to_json_dict` gives the numbers (long arrays left out).

    Attributes
    ----------
    model, quantity : str
    times : ndarray, shape (T,)
        Sample times in s.
    data, prediction, residual : ndarray, shape (T,)
        Measured signal, posterior-mean model signal, their difference.
    band_lo, band_hi : ndarray, shape (T,)
        Central 90 % posterior-predictive interval (model + noise).
    rms_residual : float
    rms_data : float
    residual_mean, residual_mean_z : float
        Mean residual, and it divided by its standard error (AR(1)-inflated).
    lowfreq_fraction : float
        Share of residual power below half the first frequency (offset / drift).
    acf : ndarray, shape (L + 1,)
        Residual autocorrelation, lags 0..L.
    lag1 : float
        ``acf[1]``.
    ljung_box_q, ljung_box_p : float
        Whiteness test statistic and p-value at ``ljung_box_lags`` lags.
    ljung_box_lags : int
    whiteness_series : str
        'residuals' or 'innovations' (AR(1) models).
    spectrum_f, spectrum_data, spectrum_residual : ndarray, shape (F,)
        Amplitude spectra (Hz; signal units).
    model_frequencies, model_damping : ndarray, shape (k,)
        Modal frequencies (Hz) and damping ratios of the model.
    modes : tuple of ModeComparison
    ratio_data, ratio_model, ratio_shift, ratio_shift_err : float
        f2/f1 measured from data and prediction, and ``data/model - 1`` ± se.
    zeta_ratio_data, zeta_ratio_model : float
        ζ2/ζ1 from data and prediction (frequency dependence of damping).
    decay_data, decay_model : DecayAmplitude or None
        Decay rate vs amplitude of mode 1 for the data and the prediction.
    decay_excess_diff, decay_excess_diff_err : float
        Difference data - model of the relative excess decay rate at the initial
        amplitude (:class:`DecayAmplitude`), and its se: > 0 the data decay faster at
        large amplitude than the model (drag), < 0 faster at small amplitude (friction).
    coverage50, coverage90 : float
        Fractions of data inside the central 50 % / 90 % predictive intervals.
    notes : tuple of str
    amplitude_trends : dict
        f1 and ζ1 slopes against the mode-1 amplitude, ``{"data": ..., "model": ...}``.
    state_change : dict or None
        The record's change-of-state test (data only, whatever the model:
        :meth:`bayesbeam.trials.state_change.StateChange.to_json_dict`).
    quadratic_k2, quadratic_k2_se : float
        Generalised least-squares coefficient of the residual on the square of the
        prediction (with a constant, AR(1)-prewhitened: :func:`quadratic_projection`) and
        its se, per signal unit: what a quadratic sensor (``sensor_quadratic``, reading
        ``y + k2 y²``) leaves.
    """

    model: str
    quantity: str
    times: np.ndarray
    data: np.ndarray
    prediction: np.ndarray
    residual: np.ndarray
    band_lo: np.ndarray
    band_hi: np.ndarray
    rms_residual: float
    rms_data: float
    residual_mean: float
    residual_mean_z: float
    lowfreq_fraction: float
    acf: np.ndarray
    lag1: float
    ljung_box_q: float
    ljung_box_p: float
    ljung_box_lags: int
    whiteness_series: str
    spectrum_f: np.ndarray
    spectrum_data: np.ndarray
    spectrum_residual: np.ndarray
    model_frequencies: np.ndarray
    model_damping: np.ndarray
    modes: tuple[ModeComparison, ...]
    ratio_data: float
    ratio_model: float
    ratio_shift: float
    ratio_shift_err: float
    zeta_ratio_data: float
    zeta_ratio_model: float
    decay_data: DecayAmplitude | None
    decay_model: DecayAmplitude | None
    decay_excess_diff: float
    decay_excess_diff_err: float
    coverage50: float
    coverage90: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    amplitude_trends: dict[str, Any] = field(default_factory=dict)
    state_change: dict[str, Any] | None = None
    quadratic_k2: float = math.nan
    quadratic_k2_se: float = math.nan

    @property
    def white(self) -> bool:
        """True when the Ljung–Box test does not reject whiteness at the 1 % level."""
        return self.ljung_box_p >= 0.01

    def to_json_dict(self) -> dict[str, Any]:
        """Return the numbers as a JSON-serialisable dictionary.

        Returns
        -------
        dict
            Scalars, the first 50 autocorrelation lags, the per-mode comparisons, the
            decay-vs-amplitude tables and the notes (time series and spectra left out).
        """
        return {
            "model": self.model,
            "quantity": self.quantity,
            "n_samples": int(self.times.size),
            "rms_residual": finite_or_none(self.rms_residual),
            "rms_data": finite_or_none(self.rms_data),
            "residual_mean": finite_or_none(self.residual_mean),
            "residual_mean_z": finite_or_none(self.residual_mean_z),
            "lowfreq_fraction": finite_or_none(self.lowfreq_fraction),
            "acf": [finite_or_none(v) for v in self.acf[:51]],
            "lag1": finite_or_none(self.lag1),
            "quadratic_k2": {"value": finite_or_none(self.quadratic_k2),
                             "se": finite_or_none(self.quadratic_k2_se)},
            "ljung_box": {"q": finite_or_none(self.ljung_box_q),
                          "p": finite_or_none(self.ljung_box_p),
                          "lags": self.ljung_box_lags, "series": self.whiteness_series,
                          "white_at_1pc": self.white},
            "model_frequencies_hz": [finite_or_none(v) for v in self.model_frequencies],
            "model_damping_ratios": [finite_or_none(v) for v in self.model_damping],
            "modes": [m.to_json_dict() for m in self.modes],
            "ratio_f2_f1": {"data": finite_or_none(self.ratio_data),
                            "model": finite_or_none(self.ratio_model),
                            "shift": finite_or_none(self.ratio_shift),
                            "shift_err": finite_or_none(self.ratio_shift_err)},
            "zeta2_over_zeta1": {"data": finite_or_none(self.zeta_ratio_data),
                                 "model": finite_or_none(self.zeta_ratio_model)},
            "decay_vs_amplitude": {
                "data": None if self.decay_data is None else self.decay_data.to_json_dict(),
                "model": None if self.decay_model is None else self.decay_model.to_json_dict(),
                "excess_difference": finite_or_none(self.decay_excess_diff),
                "excess_difference_err": finite_or_none(self.decay_excess_diff_err),
            },
            "coverage": {"central50": finite_or_none(self.coverage50),
                         "central90": finite_or_none(self.coverage90)},
            "amplitude_trends": {
                side: {k: (v if isinstance(v, int) else finite_or_none(v))
                       for k, v in tr.items()}
                for side, tr in self.amplitude_trends.items()},
            "state_change": self.state_change,
            "notes": list(self.notes),
        }


def _residual_for_whiteness(
    problem: Any, x_mean: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, str]:
    names = list(problem.names)
    if "rho" not in names:
        return r, "residuals"
    rho = float(x_mean[names.index("rho")])
    steps = np.diff(problem.trial.times)
    phi = rho ** (steps / np.median(steps))
    e = (r[1:] - phi * r[:-1]) / np.sqrt(np.maximum(1 - phi**2, 1e-12))
    return e, "innovations"


def compute_signatures(
    problem: Any,
    result: Any,
    *,
    seed: int = 0,
    n_draws: int = 200,
    n_modes: int = 3,
    max_lag: int = 100,
) -> Signatures:
    """Measure the residual signatures of a fitted model.

    Parameters
    ----------
    problem : Problem
        The model's problem (trial, forward model, priors).
    result : FitResult
        Its posterior samples.
    seed : int
        Seed of the replicated-noise draws (coverage).
    n_draws : int
        Posterior draws for the predictive distribution.
    n_modes : int
        Modes compared (those below 0.9 × Nyquist and measurable).
    max_lag : int
        Largest autocorrelation lag kept.

    Returns
    -------
    Signatures
    """
    trial = problem.trial
    t = np.asarray(trial.times, dtype=float)
    data = np.asarray(trial.values, dtype=float)
    rng = np.random.default_rng(seed)
    X, y, y_rep = posterior_predictive(problem, result, n_draws, rng, select="spaced")
    pred = y.mean(axis=0)
    r = data - pred
    n = r.size
    notes: list[str] = []
    x_mean = X.mean(axis=0)
    try:
        f_model, z_model = model_modes(problem, x_mean)
    except ValueError as err:  # e.g. an inadmissible mean of a multimodal posterior
        notes.append(f"model modes not computed: {err}")
        f_model, z_model = np.array([]), np.array([])
    # Residual whiteness.
    lags = int(min(max_lag, n - 1))
    acf = autocorrelation(r, lags)
    series, kind = _residual_for_whiteness(problem, x_mean, r)
    h = int(min(20, max(2, series.size // 5)))
    q, p = ljung_box(series, h, n_params=1 if kind == "innovations" else 0)
    lag1 = float(acf[1])
    rho_c = float(np.clip(lag1, 0.0, 0.99))
    se_mean = float(np.std(r) / math.sqrt(n) * math.sqrt((1 + rho_c) / (1 - rho_c)))
    mean_z = float(r.mean() / se_mean) if se_mean > 0 else 0.0
    # Spectra.
    sf, sd = periodogram(t, data)
    _, sr = periodogram(t, r)
    _, yg, dt = uniform_grid(t, r)
    nyq = 0.5 / dt
    f1_ref = float(f_model[0]) if f_model.size else float(sf[np.argmax(sd)])
    pw = np.abs(np.fft.rfft(yg)) ** 2
    fr = np.fft.rfftfreq(yg.size, dt)
    lowfreq = float(pw[fr < 0.5 * f1_ref].sum() / pw.sum()) if pw.sum() > 0 else 0.0
    # Per-mode comparison: the same estimator on data and prediction.
    modes = []
    fk = [float(f) for f in f_model[:n_modes] if f < 0.8 * nyq]
    sk = [float(z) * 2 * np.pi * float(f) for f, z in zip(f_model, z_model, strict=False)]
    if fk:
        # Each mode on the window that measures it best in the data, and the prediction
        # on that same window (like with like): over a whole record a fast-decaying
        # mode 2 is not measurable (f2/f1 was missing on every whole aluminium record).
        ed, windows = windowed_sinusoids(t, data, fk, sk[: len(fk)])
        fits: dict[float, list[Any]] = {}  # one fit per window, shared by its modes
        for w in set(windows):
            m = t - t[0] <= w * (1 + 1e-12)
            fits[w] = damped_sinusoids(t[m], pred[m], fk, sk[: len(fk)])
        em = [fits[w][k] for k, w in enumerate(windows)]
        for k in range(len(fk)):
            modes.append(ModeComparison(k + 1, fk[k], float(z_model[k]), ed[k], em[k]))
    ratio_d = ratio_m = shift = shift_err = zr_d = zr_m = math.nan
    if len(modes) >= 2 and all(m.data and m.model for m in modes[:2]):
        d1, d2 = modes[0].data, modes[1].data
        m1, m2 = modes[0].model, modes[1].model
        ratio_d, ratio_m = d2.frequency / d1.frequency, m2.frequency / m1.frequency
        shift = ratio_d / ratio_m - 1.0
        shift_err = _ratio_err(d2.frequency, d2.frequency_se, d1.frequency, d1.frequency_se)
        shift_err /= ratio_m
        zr_d = d2.damping_ratio / d1.damping_ratio if d1.damping_ratio > 0 else math.nan
        zr_m = m2.damping_ratio / m1.damping_ratio if m1.damping_ratio > 0 else math.nan
    elif f_model.size >= 2:
        notes.append("mode 2 not measurable: f2/f1 not compared")
    # Decay rate vs amplitude of mode 1, with the other model modes that enter the signal
    # (aliases folded). Those above the sensor band are not in the prediction (the forward
    # model removes them, physics.forward) nor in a low-passed record: fitted as extra
    # sinusoids at their aliases they only condition the fit badly. On the steel record
    # (32 elements, band 52 Hz, 236 Hz sampling) the aliases of modes up to ~20 kHz put
    # spurious components beside f1 = 6.6 Hz: the data's excess came out at its bound
    # (-0.90, with 0.09 for the amplitude against 0.47), and one fit of the final model's
    # prediction took ~8 min; with the band, -0.61 ± 0.06 in every round, in seconds.
    dd = dm = None
    ddiff = ddiff_err = math.nan
    if f_model.size:
        band = float(trial.sensor_band)
        others = [float(f) for f in f_model[1:] if f <= band]
        dd = decay_rate_vs_amplitude(t, data, f1_ref, other=others)
        dm = decay_rate_vs_amplitude(t, pred, f1_ref, other=others)
        if dd is None or dm is None:
            notes.append("decay vs amplitude: mode 1 not measurable")
        else:
            ddiff = dd.excess - dm.excess
            ddiff_err = math.hypot(dd.excess_se, dm.excess_se)
    trends, change = _amplitude_trends(trial, t, data, pred, f1_ref, notes)
    # The model's own AR(1) correlation where it has one, else the residual's lag 1.
    rho_q = float(x_mean[list(problem.names).index("rho")]) if "rho" in problem.names else rho_c
    k2, k2_se = quadratic_projection(r, pred, rho_q)
    lo, hi = np.quantile(y_rep, [0.05, 0.95], axis=0)
    q25, q75 = np.quantile(y_rep, [0.25, 0.75], axis=0)
    return Signatures(
        model=problem.model.name,
        quantity=trial.quantity,
        times=t,
        data=data,
        prediction=pred,
        residual=r,
        band_lo=lo,
        band_hi=hi,
        rms_residual=float(np.sqrt(np.mean(r**2))),
        rms_data=float(np.sqrt(np.mean(data**2))),
        residual_mean=float(r.mean()),
        residual_mean_z=mean_z,
        lowfreq_fraction=lowfreq,
        acf=acf,
        lag1=lag1,
        ljung_box_q=q,
        ljung_box_p=p,
        ljung_box_lags=h,
        whiteness_series=kind,
        spectrum_f=sf,
        spectrum_data=sd,
        spectrum_residual=sr,
        model_frequencies=np.asarray(f_model, dtype=float),
        model_damping=np.asarray(z_model, dtype=float),
        modes=tuple(modes),
        ratio_data=ratio_d,
        ratio_model=ratio_m,
        ratio_shift=shift,
        ratio_shift_err=shift_err,
        zeta_ratio_data=zr_d,
        zeta_ratio_model=zr_m,
        decay_data=dd,
        decay_model=dm,
        decay_excess_diff=ddiff,
        decay_excess_diff_err=ddiff_err,
        coverage50=float(np.mean((data >= q25) & (data <= q75))),
        coverage90=float(np.mean((data >= lo) & (data <= hi))),
        notes=tuple(notes),
        amplitude_trends=trends,
        state_change=change,
        quadratic_k2=k2,
        quadratic_k2_se=k2_se,
    )


def quadratic_projection(residual: np.ndarray, prediction: np.ndarray,
                         rho: float = 0.0) -> tuple[float, float]:
    """Coefficient of a residual on the square of the model's signal, and its se.

    Generalised least squares of ``residual ≈ c + k2 (y - ȳ)²`` with ``y`` the
    prediction, for residuals that are AR(1) with lag-1 correlation ``rho`` (0: ordinary
    least squares): the residual and both regressors are prewhitened, ``x_t - ρ x_{t-1}``
    (Cochrane–Orcutt), so the se is the GLS one whatever the residual's colour. The
    regressor is what a quadratic sensor (``y + k2 y²``,
    :mod:`bayesbeam.physics.nonlinear`) leaves when the model lacks it: lines at twice
    the signal's frequencies in phase with ``y²`` and a mean shift that decays with the
    amplitude.

    Parameters
    ----------
    residual, prediction : ndarray, shape (T,)
        In the signal's SI unit, on uniform (or nearly uniform) stamps.
    rho : float
        Lag-1 correlation of the residual, clipped to [0, 0.99].

    Returns
    -------
    k2, se : float
        Per signal unit; NaN when the prediction is constant or the record too short.
    """
    y = prediction - prediction.mean()
    z = y * y
    rho = float(np.clip(rho, 0.0, 0.99))
    n = residual.size - 1
    if n < 3 or not np.ptp(z) > 0:
        return math.nan, math.nan
    X = np.column_stack([np.full(n, 1.0 - rho), z[1:] - rho * z[:-1]])
    rw = residual[1:] - rho * residual[:-1]
    coef, *_ = np.linalg.lstsq(X, rw, rcond=None)
    fit_res = rw - X @ coef
    s2 = float(fit_res @ fit_res) / (n - 2)
    cov = s2 * np.linalg.inv(X.T @ X)
    return float(coef[1]), math.sqrt(max(float(cov[1, 1]), 0.0))


def _amplitude_trends(trial: Any, t: np.ndarray, data: np.ndarray, pred: np.ndarray,
                      f1: float, notes: list[str]
                      ) -> tuple[dict[str, dict[str, float]], dict[str, Any] | None]:
    """f1 and ζ1 against the mode-1 tip amplitude, for the data and the model's prediction.

    Sliding windows of four mode-1 periods (:func:`bayesbeam.trials.amplitude.
    amplitude_curves`), summarised by the slope per mm of amplitude
    (:func:`~bayesbeam.trials.amplitude_bins.amplitude_trend`). Where the model is linear
    its slopes are ~0; the data's slopes beyond theirs say what changes with amplitude:
    f1 falling with amplitude (softening), ζ1 rising (drag) or falling (friction).
    Empty when the record holds fewer than three windows. Also returns the data's
    change-of-state test (:func:`bayesbeam.trials.state_change.state_change`, as JSON),
    which no catalogue model explains and is reported whatever the model (None when the
    curves could not be made).
    """
    from bayesbeam.trials.amplitude import amplitude_curves
    from bayesbeam.trials.amplitude_bins import amplitude_trend, tip_factor
    from bayesbeam.trials.state_change import state_change

    out: dict[str, dict[str, float]] = {}
    change = None
    if not (np.isfinite(f1) and f1 > 0) or t[-1] - t[0] < 3 * 4.0 / f1:
        notes.append("amplitude trends: record shorter than three windows of 4 periods")
        return out, change
    tf = tip_factor(trial.beam)
    for side, y in (("data", data), ("model", pred)):
        try:
            c = amplitude_curves(t, y, f1=f1, n_modes=1, quantity=trial.quantity,
                                 tip_factor=tf)
        except SignatureError as err:  # too short, or no mode-1 peak: say so
            notes.append(f"amplitude trends ({side}): {err}")
            return {}, change
        if side == "data":
            change = state_change(c).to_json_dict()
        fs, fse, nf = amplitude_trend(c.amplitude_m, c.frequency[:, 0], c.frequency_se[:, 0],
                                      hop=c.hop_s, window=c.window_s)
        zs, zse, _ = amplitude_trend(c.amplitude_m, c.zeta[:, 0], c.zeta_se[:, 0],
                                     hop=c.hop_s, window=c.window_s)
        amp = c.amplitude_m[np.isfinite(c.amplitude_m)]
        out[side] = {"f1_hz_per_mm": fs, "f1_hz_per_mm_se": fse, "zeta1_per_mm": zs,
                     "zeta1_per_mm_se": zse, "n_windows": nf,
                     "amplitude_min_m": float(amp.min()) if amp.size else math.nan,
                     "amplitude_max_m": float(amp.max()) if amp.size else math.nan}
    return out, change


# --------------------------------------------------------------------------- plots


def plot_signatures(sig: Signatures, *, title: str | None = None) -> Any:
    """Draw the signatures on a new figure (matplotlib object API, no pyplot).

    Panels: data, prediction and 90 % predictive band; residual; residual
    autocorrelation with the ±1.96/√n white-noise band; data and residual spectra
    with the model's modal frequencies; measured vs model frequency shift and damping
    per mode; decay rate against amplitude (data and model).

    Parameters
    ----------
    sig : Signatures
    title : str, optional
        Figure title (default: the model name).

    Returns
    -------
    matplotlib.figure.Figure
        Save with ``fig.savefig(path)``.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 11), layout="constrained")
    axs = fig.subplots(3, 2)
    t = sig.times - sig.times[0]
    ax = axs[0, 0]
    ax.fill_between(t, sig.band_lo, sig.band_hi, color="C1", alpha=0.3, lw=0,
                    label="90 % predictive")
    ax.plot(t, sig.data, "k", lw=0.6, label="data")
    ax.plot(t, sig.prediction, "C1", lw=0.8, label="model")
    ax.set(xlabel="time [s]", ylabel=f"{sig.quantity} [SI]",
           title=f"coverage 90 %: {sig.coverage90:.2f}, 50 %: {sig.coverage50:.2f}")
    ax.legend(fontsize=7, loc="upper right")
    ax = axs[0, 1]
    ax.plot(t, sig.residual, "C3", lw=0.6)
    ax.axhline(0, color="k", lw=0.5)
    ax.set(xlabel="time [s]", ylabel="residual [SI]",
           title=f"RMS {sig.rms_residual:.3g} ({100 * sig.rms_residual / sig.rms_data:.1f} % "
                 f"of data), mean z = {sig.residual_mean_z:.1f}")
    ax = axs[1, 0]
    lags = np.arange(sig.acf.size)
    ax.bar(lags[1:], sig.acf[1:], width=0.8, color="C0")
    bound = 1.96 / math.sqrt(sig.times.size)
    ax.axhspan(-bound, bound, color="0.8", zorder=0)
    ax.set(xlabel="lag [samples]", ylabel="autocorrelation",
           title=f"Ljung–Box ({sig.whiteness_series}) Q={sig.ljung_box_q:.1f}, "
                 f"p={sig.ljung_box_p:.2g}")
    ax = axs[1, 1]
    ax.semilogy(sig.spectrum_f, sig.spectrum_data + 1e-300, "k", lw=0.6, label="data")
    ax.semilogy(sig.spectrum_f, sig.spectrum_residual + 1e-300, "C3", lw=0.6, label="residual")
    for i, f in enumerate(sig.model_frequencies):
        if f <= sig.spectrum_f[-1]:
            ax.axvline(f, color="C1", ls="--", lw=0.8, label="model modes" if i == 0 else None)
    top = float(np.max(sig.spectrum_data)) if sig.spectrum_data.size else 1.0
    ax.set_ylim(top * 1e-6, top * 2)
    ax.set(xlabel="frequency [Hz]", ylabel="amplitude [SI]", title="spectra")
    ax.legend(fontsize=7)
    ax = axs[2, 0]
    ks = [m.mode for m in sig.modes if m.data and m.model]
    if ks:
        fs = [100 * m.frequency_shift for m in sig.modes if m.data and m.model]
        zd = [m.data.damping_ratio for m in sig.modes if m.data and m.model]
        zm = [m.model.damping_ratio for m in sig.modes if m.data and m.model]
        ax.bar(np.array(ks) - 0.2, fs, width=0.4, color="C0", label="f data/model - 1 [%]")
        ax2 = ax.twinx()
        ax2.plot(ks, zd, "ks", label="ζ data")
        ax2.plot(ks, zm, "C1o", label="ζ model")
        ax2.set_ylabel("damping ratio")
        ax2.legend(fontsize=7, loc="upper right")
        ax.legend(fontsize=7, loc="upper left")
    ax.axhline(0, color="k", lw=0.5)
    ax.set(xlabel="mode", ylabel="frequency shift [%]",
           title=f"f2/f1 shift {100 * sig.ratio_shift:+.2f} ± {100 * sig.ratio_shift_err:.2f} %")
    ax = axs[2, 1]
    for d, style, lab in ((sig.decay_data, "ks", "data"), (sig.decay_model, "C1o", "model")):
        if d is None:
            continue
        if d.amplitude.size:
            ax.plot(d.amplitude, d.rate, style, ms=4, label=f"{lab} (windows)")
        a = np.linspace(0.0, d.amplitude0, 50)
        ax.plot(a, d.rate0 * (1 + d.excess * a / d.amplitude0), style[:-1] + "-", lw=1,
                label=f"{lab}: excess {d.excess:+.2f} ± {d.excess_se:.2f}")
    ax.set(xlabel="mode-1 amplitude [SI]", ylabel="decay rate σ [1/s]",
           title=f"decay vs amplitude: excess data − model {sig.decay_excess_diff:+.2f} "
                 f"± {sig.decay_excess_diff_err:.2f}")
    if ax.get_legend_handles_labels()[0]:  # no decay curves on a record too short for them
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, "decay rate vs amplitude not measurable", ha="center",
                va="center", transform=ax.transAxes, fontsize=8)
    fig.suptitle(title or f"model {sig.model}: residual signatures")
    return fig
