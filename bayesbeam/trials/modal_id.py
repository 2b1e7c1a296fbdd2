"""Modal identification of a vibration record: time-series and modal estimators.

Estimators that work on a measured (or predicted) signal alone, with no model:

* :func:`uniform_grid` (resampling; the whiteness statistics are in
  :mod:`bayesbeam.stats.whiteness`);
* the Hann-windowed amplitude spectrum :func:`periodogram` and its refined peak
  :func:`spectral_peak`;
* per mode, frequency and decay rate (:class:`ModalEstimate`) by band-pass + Hilbert
  envelope (:func:`band_modal_estimate`) or by a variable-projection fit of damped
  sinusoids (:func:`damped_sinusoids`); the modal damping ratio of mode k is
  ``ζ_k = σ_k / sqrt(σ_k² + ω_dk²)``;
* the decay rate of one mode against its amplitude (:class:`DecayAmplitude`,
  :func:`decay_rate_vs_amplitude`): a linear model decays at one rate, quadratic air
  drag faster at large amplitude, dry friction faster at small amplitude.

:mod:`bayesbeam.diagnosis.signatures` applies them to data and to a fitted model's prediction;
:mod:`bayesbeam.diagnosis.search` uses them for physics-based start points. Invalid
input raises :class:`SignatureError` (re-exported by :mod:`bayesbeam.diagnosis.signatures`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize as sopt
import scipy.signal as ssig

from bayesbeam._util import finite_or_none
from bayesbeam.stats.whiteness import autocorrelation

__all__ = [
    "DecayAmplitude",
    "ModalEstimate",
    "SignatureError",
    "band_modal_estimate",
    "damped_sinusoids",
    "decay_rate_vs_amplitude",
    "periodogram",
    "spectral_peak",
    "uniform_grid",
]


class SignatureError(ValueError):
    """Input to a signature computation is invalid; the message says how to fix it."""


# --------------------------------------------------------------------------- basics


def uniform_grid(times: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Signal on a uniform grid (linear interpolation when the stamps are not uniform).

    Parameters
    ----------
    times, values : ndarray, shape (T,)
        Time stamps in s (increasing) and signal.

    Returns
    -------
    grid : ndarray, shape (T,)
        ``times[0] + k dt`` in s.
    y : ndarray, shape (T,)
        Signal on the grid.
    dt : float
        Mean step in s.
    """
    t, y = _as_series(times, values)
    dt = float((t[-1] - t[0]) / (t.size - 1))
    grid = t[0] + dt * np.arange(t.size)
    if np.max(np.abs(grid - t)) <= 1e-6 * dt:
        return grid, y.copy(), dt
    return grid, np.interp(grid, t, y), dt


def periodogram(
    times: np.ndarray, values: np.ndarray, *, pad: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Hann-windowed, zero-padded periodogram (one-sided amplitude spectrum).

    Parameters
    ----------
    times, values : ndarray, shape (T,)
    pad : int
        Zero-padding factor (to the next power of two of ``pad·T``).

    Returns
    -------
    f : ndarray, shape (F,)
        Frequencies in Hz.
    amp : ndarray, shape (F,)
        ``|FFT(w y)| · 2 / Σ w``: a sinusoid of amplitude A peaks at about A (units of
        the signal).
    """
    _, y, dt = uniform_grid(times, values)
    w = np.hanning(y.size)
    nfft = int(2 ** math.ceil(math.log2(pad * y.size)))
    amp = np.abs(np.fft.rfft((y - y.mean()) * w, nfft)) * 2.0 / w.sum()
    return np.fft.rfftfreq(nfft, dt), amp


def spectral_peak(
    f: np.ndarray, amp: np.ndarray, f_guess: float, *, rel_window: float = 0.12
) -> float | None:
    """Largest spectral peak within ``f_guess (1 ± rel_window)``, refined by a parabola.

    Parameters
    ----------
    f, amp : ndarray, shape (F,)
        Output of :func:`periodogram`.
    f_guess : float
        Expected frequency in Hz.
    rel_window : float
        Relative half-width of the search window.

    Returns
    -------
    float or None
        Peak frequency in Hz (None when the window is empty or holds no local maximum).
    """
    sel = np.flatnonzero((f >= f_guess * (1 - rel_window)) & (f <= f_guess * (1 + rel_window)))
    sel = sel[(sel > 0) & (sel < f.size - 1)]
    if sel.size == 0:
        return None
    i = int(sel[np.argmax(amp[sel])])
    if not (amp[i] >= amp[i - 1] and amp[i] >= amp[i + 1]):
        return None
    a, b, c = np.log(amp[i - 1 : i + 2] + 1e-300)
    denom = a - 2 * b + c
    shift = 0.5 * (a - c) / denom if denom != 0 else 0.0
    return float(f[i] + shift * (f[1] - f[0]))


# --------------------------------------------------------------------------- modal estimates


@dataclass(frozen=True)
class ModalEstimate:
    """Frequency and decay rate of one mode measured by band-pass + Hilbert envelope.

    Attributes
    ----------
    frequency : float
        Damped frequency in Hz (slope of the unwrapped analytic-signal phase).
    frequency_se : float
        Standard error of ``frequency`` in Hz (regression, inflated by the
        residual autocorrelation of the fit).
    decay_rate : float
        σ in 1/s (minus the slope of the log envelope).
    decay_rate_se : float
        Standard error of ``decay_rate`` in 1/s.
    damping_ratio : float
        ``σ / sqrt(σ² + ω_d²)``.
    amplitude : float
        Envelope at the start of the fitted span, units of the signal.
    """

    frequency: float
    frequency_se: float
    decay_rate: float
    decay_rate_se: float
    damping_ratio: float
    amplitude: float


def _bandpass(y: np.ndarray, dt: float, f_lo: float, f_hi: float) -> np.ndarray:
    nyq = 0.5 / dt
    lo, hi = f_lo / nyq, min(f_hi / nyq, 0.98)
    if not 0 < lo < hi:
        raise SignatureError(
            f"band [{f_lo:.3g}, {f_hi:.3g}] Hz does not fit below the Nyquist frequency "
            f"{nyq:.3g} Hz"
        )
    sos = ssig.butter(3, [lo, hi], btype="band", output="sos")
    return ssig.sosfiltfilt(sos, y - np.mean(y))


def _slope_se(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-squares slope, intercept and slope SE inflated for lag-1 correlation."""
    A = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    n = x.size
    s2 = float(res @ res) / max(n - 2, 1)
    sxx = float(np.sum((x - x.mean()) ** 2))
    se = math.sqrt(s2 / sxx) if sxx > 0 else math.inf
    # Residuals of a smooth phase/envelope are strongly correlated: inflate by the
    # AR(1) variance factor (1 + ρ)/(1 - ρ) of the lag-1 correlation (Bartlett).
    if n > 3 and float(res @ res) > 0:
        rho = float(np.clip(autocorrelation(res, 1)[1], 0.0, 0.999))
        se *= math.sqrt((1 + rho) / (1 - rho))
    return float(coef[0]), float(coef[1]), se


def band_modal_estimate(
    times: np.ndarray,
    values: np.ndarray,
    f_center: float,
    *,
    half_width: float = 0.3,
    trim: float = 0.1,
    floor: float = 0.0,
) -> ModalEstimate | None:
    """Frequency and decay rate of the mode near ``f_center`` (band-pass + Hilbert).

    Zero-phase Butterworth band-pass ``f_center (1 ± half_width)``, analytic signal
    (Hilbert transform), then straight-line fits of the unwrapped phase (slope 2π f)
    and of the log envelope (slope -σ) over the record with ``trim`` of it dropped at
    each end (filter edge transients) and only while the envelope exceeds ``floor``
    (so the noise floor does not flatten the decay).

    Parameters
    ----------
    times, values : ndarray, shape (T,)
        Record (s, signal units); non-uniform stamps are interpolated.
    f_center : float
        Expected frequency in Hz (e.g. the model's).
    half_width : float
        Relative half-width of the band (neighbouring modes of a cantilever are at
        least a factor 1.7 apart, physics.md §4, so 0.3 isolates each).
    trim : float
        Fraction dropped at each end.
    floor : float
        Envelope level (signal units) below which samples are ignored.

    Returns
    -------
    ModalEstimate or None
        None when fewer than 16 samples (or 1.5 periods) remain above the floor.
    """
    grid, y, dt = uniform_grid(times, values)
    yb = _bandpass(y, dt, f_center * (1 - half_width), f_center * (1 + half_width))
    z = ssig.hilbert(yb)
    env = np.abs(z)
    n = y.size
    k0, k1 = int(trim * n), n - int(trim * n)
    t = grid[k0:k1] - grid[0]
    e = env[k0:k1]
    ok = e > max(floor, 1e-12 * (env.max() + 1e-300))
    # Use the leading run above the floor (the decay ends in noise).
    if not ok[0]:
        return None
    stop = int(np.argmin(ok)) if not ok.all() else ok.size
    t, e = t[:stop], e[:stop]
    ph = np.unwrap(np.angle(z[k0:k1][:stop]))
    if t.size < 16 or (t[-1] - t[0]) * f_center < 1.5:
        return None
    w_slope, _, w_se = _slope_se(t, ph)
    s_slope, s_icpt, s_se = _slope_se(t, np.log(e))
    f = w_slope / (2 * np.pi)
    sigma = -s_slope
    wd = abs(w_slope)
    zeta = sigma / math.hypot(sigma, wd) if wd > 0 else math.nan
    return ModalEstimate(
        frequency=float(f),
        frequency_se=float(w_se / (2 * np.pi)),
        decay_rate=float(sigma),
        decay_rate_se=float(s_se),
        damping_ratio=float(zeta),
        amplitude=float(np.exp(s_icpt + s_slope * t[0])),
    )


def _fit_modes(t: np.ndarray, y: np.ndarray, f0: np.ndarray, s0: np.ndarray, *,
               offset: bool, excess: bool) -> dict[str, Any]:
    """Variable-projection fit of damped sinusoids (optionally with an excess on mode 0)."""
    K = f0.size
    w0 = 2 * np.pi * f0

    def shapes(p: np.ndarray) -> np.ndarray:
        e = np.exp(-np.outer(t, p[K : 2 * K]))
        if excess:
            # A(t)/A0 = e^{-σ0 t} / (1 + c (1 - e^{-σ0 t})): dA/dt = -σ0 A - κ A², c = κ A0/σ0.
            e0 = e[:, 0]
            e[:, 0] = e0 / (1.0 + p[2 * K] * (1.0 - e0))
        return e

    def basis(p: np.ndarray) -> np.ndarray:
        e = shapes(p)
        ph = 2 * np.pi * np.outer(t, p[:K])
        cols = [e * np.cos(ph), e * np.sin(ph)]
        if offset:
            cols.append(np.ones((t.size, 1)))
        return np.hstack(cols)

    def resid(p: np.ndarray) -> np.ndarray:
        B = basis(p)
        coef, *_ = np.linalg.lstsq(B, y, rcond=None)
        return y - B @ coef

    p0 = np.concatenate([f0, np.clip(s0, -0.005 * w0, 0.5 * w0)])
    lo = np.concatenate([0.8 * f0, -0.01 * w0])
    hi = np.concatenate([1.2 * f0, 0.5 * w0])
    if excess:
        p0, lo, hi = np.append(p0, 0.0), np.append(lo, -0.9), np.append(hi, 50.0)
    res = sopt.least_squares(resid, np.clip(p0, lo, hi), bounds=(lo, hi), x_scale="jac",
                             method="trf")
    p, r = res.x, res.fun
    B = basis(p)
    coef, *_ = np.linalg.lstsq(B, y, rcond=None)
    s2 = float(r @ r) / max(t.size - p.size - B.shape[1], 1)
    rho = float(np.clip(autocorrelation(r, 1)[1], 0.0, 0.99)) if float(r @ r) > 0 else 0.0
    infl = (1 + rho) / (1 - rho)

    def se_of(J: np.ndarray) -> np.ndarray:
        try:
            return np.sqrt(np.maximum(np.diag(np.linalg.inv(J.T @ J)), 0.0) * s2 * infl)
        except np.linalg.LinAlgError:
            return np.full(J.shape[1], np.inf)

    return {"p": p, "se": se_of(res.jac), "coef": coef, "se_lin": se_of(B), "K": K}


def _as_series(times: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return times and values as float arrays, checked: 1-D, same length, at least 8."""
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float)
    if t.ndim != 1 or t.shape != y.shape or t.size < 8:
        raise SignatureError(
            f"times and values must be 1-D arrays of the same length >= 8, got {t.shape} "
            f"and {y.shape}"
        )
    return t, y


def _check_series(times: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t, y = _as_series(times, values)
    return t - t[0], y


def damped_sinusoids(
    times: np.ndarray,
    values: np.ndarray,
    f0: Sequence[float],
    sigma0: Sequence[float] | None = None,
    *,
    offset: bool = True,
    min_snr: float = 5.0,
) -> list[ModalEstimate | None]:
    """Frequencies and decay rates of several modes by a damped-sinusoid least-squares fit.

    The record is fitted by ``c + Σ_k e^{-σ_k t} (a_k cos 2π f_k t + b_k sin 2π f_k t)``
    (t from the first sample) with the amplitudes ``a_k, b_k`` and ``c`` solved by
    linear least squares inside the optimisation of ``(f_k, σ_k)`` (variable
    projection, Golub & Pereyra 1973), which reaches the Cramér–Rao accuracy on short
    records where band-pass filters ring. Standard errors come from the Jacobian of
    the projected residual, inflated by the AR(1) factor ``(1+ρ)/(1-ρ)`` of the
    residual's lag-1 correlation ρ (unmodelled content is correlated).

    Parameters
    ----------
    times, values : ndarray, shape (T,)
        Record (s, signal units); non-uniform stamps are used as they are.
    f0 : sequence of float
        Starting frequencies in Hz (e.g. a model's), each searched within ±20 %.
        Include every mode present below the Nyquist frequency (and aliases of higher
        ones) or they bias the others.
    sigma0 : sequence of float, optional
        Starting decay rates in 1/s (default 1 % of critical).
    offset : bool
        Fit a constant too.
    min_snr : float
        A mode whose fitted amplitude is below ``min_snr`` times its standard error
        is reported as None (not measurable).

    Returns
    -------
    list of ModalEstimate or None
        One entry per ``f0``; ``amplitude`` is the fitted amplitude at the first sample.
    """
    t, y = _check_series(times, values)
    f0 = np.asarray(f0, dtype=float)
    K = f0.size
    if K == 0:
        return []
    s0 = (0.01 * 2 * np.pi * f0 if sigma0 is None
          else np.maximum(np.asarray(sigma0, dtype=float), 1e-6 * 2 * np.pi * f0))
    fit = _fit_modes(t, y, f0, s0, offset=offset, excess=False)
    p, se, coef, se_lin = fit["p"], fit["se"], fit["coef"], fit["se_lin"]
    out: list[ModalEstimate | None] = []
    for k in range(K):
        amp = math.hypot(coef[k], coef[K + k])
        amp_se = math.hypot(se_lin[k], se_lin[K + k]) / math.sqrt(2)
        if not amp > min_snr * amp_se:
            out.append(None)
            continue
        f, sg = float(p[k]), float(p[K + k])
        out.append(ModalEstimate(
            frequency=f, frequency_se=float(se[k]), decay_rate=sg, decay_rate_se=float(se[K + k]),
            damping_ratio=float(sg / math.hypot(sg, 2 * np.pi * f)), amplitude=float(amp),
        ))
    return out


@dataclass(frozen=True)
class DecayAmplitude:
    """Decay rate of one mode against its amplitude.

    The whole record is fitted with an amplitude-dependent envelope for the mode,
    ``A(t)/A0 = e^{-σ0 t} / (1 + c (1 - e^{-σ0 t}))``, the solution of
    ``dA/dt = -σ0 A - κ A²`` with ``c = κ A0/σ0``: the decay rate is ``σ0 (1 + c)``
    at the first sample and tends to σ0 as the amplitude falls. ``c`` is the relative
    excess of the decay rate at the initial amplitude: 0 for a linear mode, > 0 when
    it decays faster at large amplitude (quadratic drag), < 0 when faster at small
    amplitude (dry friction). Window estimates are kept for plotting.

    Attributes
    ----------
    frequency : float
        Mode frequency in Hz.
    excess, excess_se : float
        ``c`` and its standard error (dimensionless).
    rate0 : float
        Small-amplitude decay rate σ0 in 1/s.
    amplitude0 : float
        Fitted amplitude at the first sample (signal units).
    amplitude : ndarray, shape (k,)
        Window-centre amplitudes (signal units), possibly empty.
    rate : ndarray, shape (k,)
        Window decay rates in 1/s.
    """

    frequency: float
    excess: float
    excess_se: float
    rate0: float
    amplitude0: float
    amplitude: np.ndarray
    rate: np.ndarray

    @property
    def slope(self) -> float:
        """Return dσ/dA = c σ0 / A0 in 1/(s·signal unit)."""
        return self.excess * self.rate0 / self.amplitude0 if self.amplitude0 else math.nan

    def to_json_dict(self) -> dict[str, Any]:
        """Return a JSON-serialisable dictionary (arrays as lists).

        Returns
        -------
        dict
        """
        return {
            "frequency_hz": self.frequency,
            "excess": finite_or_none(self.excess),
            "excess_se": finite_or_none(self.excess_se),
            "rate0": finite_or_none(self.rate0),
            "amplitude0": finite_or_none(self.amplitude0),
            "window_amplitude": [finite_or_none(v) for v in self.amplitude],
            "window_rate": [finite_or_none(v) for v in self.rate],
        }


def decay_rate_vs_amplitude(
    times: np.ndarray,
    values: np.ndarray,
    f_center: float,
    *,
    other: Sequence[float] = (),
    periods_per_window: float = 3.0,
    min_snr: float = 5.0,
) -> DecayAmplitude | None:
    """Decay rate of the mode near ``f_center`` against its amplitude.

    The record is low-passed at ``min(2.5 f_center, 0.6 f_next)`` (zero-phase
    Butterworth, order 4; two periods of the cut-off trimmed at each end), then the
    whole of it is fitted
    with the amplitude-dependent envelope of
    :class:`DecayAmplitude` for this mode and plain damped sinusoids for the
    ``other`` modes (variable projection, as :func:`damped_sinusoids`; no filter, so
    it works on records of a few periods). For plotting, consecutive windows of
    ``periods_per_window`` periods are also fitted with plain damped sinusoids, giving
    local (A, σ) points.

    Parameters
    ----------
    times, values : ndarray, shape (T,)
    f_center : float
        Mode frequency in Hz.
    other : sequence of float
        Natural frequencies (Hz) of the other modes present; those above the Nyquist
        frequency are folded to their aliases here.
    periods_per_window : float
        Window length of the plotted points, in periods of the mode.
    min_snr : float
        The mode must exceed ``min_snr`` standard errors (globally, and in a window
        for its point to be kept).

    Returns
    -------
    DecayAmplitude or None
        None when the mode is not measurable.
    """
    t, y, dt = uniform_grid(times, values)
    t = t - t[0]
    nyq = 0.5 / dt
    # Low-pass well below the next mode:
    # with an acceleration sensor the higher modes (and their aliases) dominate the
    # record and would bias a short fit of mode 1. A low-pass settles within a few
    # periods of its cut-off (unlike a narrow band-pass), which are trimmed.
    above = [float(f) for f in other if f > 1.3 * f_center]
    cut = min(2.5 * float(f_center), 0.6 * min(above, default=np.inf), 0.9 * nyq)
    fs = 2 * nyq
    # Modes above the Nyquist frequency appear at their aliases |f - round(f/fs) fs|.
    other = [abs(f - round(f / fs) * fs) for f in above]
    sos = ssig.butter(4, cut / nyq, btype="low", output="sos")
    y = ssig.sosfiltfilt(sos, y - np.mean(y))
    k = int(math.ceil(2.0 / (cut * dt)))
    if t.size - 2 * k < 16:
        return None
    t, y = t[k:-k], y[k:-k]  # time still from the first sample: c and A0 refer to it
    freqs = np.array([float(f_center)] + [float(f) for f in other
                                           if 0 < f < cut and abs(f / f_center - 1) > 0.3])
    glob = damped_sinusoids(t, y, freqs, min_snr=0.0)
    f0 = np.array([g.frequency if g is not None else f for g, f in zip(glob, freqs, strict=True)])
    s0 = np.array([g.decay_rate if g is not None and g.decay_rate > 0 else 0.01 * 2 * np.pi * f
                   for g, f in zip(glob, f0, strict=True)])
    fit = _fit_modes(t, y, f0, s0, offset=True, excess=True)
    K = fit["K"]
    amp0 = math.hypot(fit["coef"][0], fit["coef"][K])
    amp_se = math.hypot(fit["se_lin"][0], fit["se_lin"][K]) / math.sqrt(2)
    if not amp0 > min_snr * amp_se:
        return None
    span = periods_per_window / float(f_center)
    amps, rates = [], []
    for a in np.arange(t[0], t[-1] - 0.999 * span, span):
        sel = (t >= a) & (t < a + span)
        if np.count_nonzero(sel) < 8 + 4 * K:
            break
        est = damped_sinusoids(t[sel], y[sel], f0, s0, min_snr=min_snr)[0]
        if est is None:
            break
        half = 0.5 * (t[sel][-1] - t[sel][0])
        amps.append(est.amplitude * math.exp(-est.decay_rate * half))
        rates.append(est.decay_rate)
    c, c_se = float(fit["p"][2 * K]), float(fit["se"][2 * K])
    if not -0.89 < c < 49.0:
        c_se = math.inf  # on a bound of the fit: the curvature of the envelope is not seen
    return DecayAmplitude(
        frequency=float(fit["p"][0]), excess=c,
        excess_se=c_se, rate0=float(fit["p"][K]), amplitude0=float(amp0),
        amplitude=np.array(amps), rate=np.array(rates),
    )
