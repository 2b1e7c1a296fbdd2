"""Modal identification of a vibration record: time-series and modal estimators.

Estimators that work on a measured (or predicted) signal alone, with no model:

* :func:`uniform_grid` (resampling; the whiteness statistics are in
  :mod:`bayesbeam.stats.whiteness`);
* the Hann-windowed amplitude spectrum :func:`periodogram` and its refined peak
  :func:`spectral_peak`;
* per mode, frequency and decay rate (:class:`ModalEstimate`) by band-pass + Hilbert
  envelope (:func:`band_modal_estimate`) or by a variable-projection fit of damped
  sinusoids (:func:`damped_sinusoids`), each higher mode on the window from the
  first sample that measures it best (:func:`windowed_sinusoids`); the modal damping
  ratio of mode k is ``ζ_k = σ_k / sqrt(σ_k² + ω_dk²)``;
* the decay rate of one mode against its amplitude: a linear model decays at one rate,
  quadratic air drag faster at large amplitude, dry friction faster at small amplitude.
  Two methods: :func:`decay_rate_vs_amplitude` (:class:`DecayAmplitude`) fits the
  envelope law of ``dA/dt = -σ0 A - κ A²`` to the whole record, with the other modes,
  and gives the relative excess of the initial rate with a standard error (short
  records, acceleration; the diagnosis statistic); :func:`envelope_decay_vs_amplitude`
  measures the demodulated envelope's log-slope window by window with no law assumed
  (long records of an isolated first mode; compares two records of the same motion).

All the decay-rate estimators of the package are here (the fit's start value uses
:func:`band_modal_estimate`).

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
from bayesbeam.physics.inputs import grid_with_holes
from bayesbeam.stats.whiteness import autocorrelation

__all__ = [
    "DecayAmplitude",
    "ModalEstimate",
    "SignatureError",
    "band_modal_estimate",
    "damped_sinusoids",
    "decay_rate_vs_amplitude",
    "envelope_decay_vs_amplitude",
    "first_mode_decay_rate",
    "periodogram",
    "spectral_peak",
    "uniform_grid",
    "windowed_sinusoids",
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
    grid : ndarray, shape (T,) or (G,)
        ``times[0] + k dt`` in s.
    y : ndarray, shape (T,) or (G,)
        Signal on the grid.
    dt : float
        Mean step in s; for a uniform grid with holes (a record resampled around its
        gaps, :func:`bayesbeam.physics.forward.grid_with_holes`) the grid's own step,
        the G grid points covering the holes, which hold the series' mean (no
        interpolation across a hole: a straight line or a spline over a tenth of a
        second puts spurious low frequencies into a spectrum).
    """
    t, y = _as_series(times, values)
    holes = grid_with_holes(t - t[0])
    if holes is not None and holes[1].size < int(holes[1][-1]) + 1:
        step, index = holes
        filled = np.full(int(index[-1]) + 1, float(np.mean(y)))
        filled[index] = y
        return t[0] + step * np.arange(filled.size), filled, step
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


def _bandpass(y: np.ndarray, dt: float, f_lo: float, f_hi: float, *, order: int = 3,
              edge: float = 0.98) -> np.ndarray:
    """Zero-phase Butterworth band-pass of the mean-removed signal.

    ``order`` is the Butterworth order (doubled by the forward-backward pass); the
    upper edge is capped at ``edge`` times the Nyquist frequency.
    """
    nyq = 0.5 / dt
    lo, hi = f_lo / nyq, min(f_hi / nyq, edge)
    if not 0 < lo < hi:
        raise SignatureError(
            f"band [{f_lo:.3g}, {f_hi:.3g}] Hz does not fit below the Nyquist frequency "
            f"{nyq:.3g} Hz"
        )
    sos = ssig.butter(order, [lo, hi], btype="band", output="sos")
    return ssig.sosfiltfilt(sos, y - np.mean(y))


def first_mode_decay_rate(times: np.ndarray, values: np.ndarray, f1: float) -> float:
    """Coarse decay rate (1/s) of the first mode, for a fit's starting point.

    Band-pass ±30 % around ``f1`` (order-2 zero-phase Butterworth), Hilbert envelope,
    then a straight-line fit of the log envelope against time over the central 80 % of
    the record (the filter's edge transients excluded), using every sample above
    1e-12 of the peak. Unlike :func:`band_modal_estimate` it never fails: a start needs
    only the scale, so a record without a measurable envelope gives ζ = 1e-3, and the
    result is floored at ζ = 1e-6. (The two differ in filter order and in which samples
    enter the fit; the fits' seeded chains depend on this start, so it is kept as it was.)

    Parameters
    ----------
    times, values : ndarray, shape (T,)
        Record (s, signal units); non-uniform stamps are interpolated.
    f1 : float
        First natural frequency in Hz.

    Returns
    -------
    float
        Decay rate σ = ζ ω1 in 1/s, at least 1e-6 ω1.
    """
    w1 = 2 * np.pi * f1
    t = np.asarray(times, dtype=float)
    dt = (t[-1] - t[0]) / (t.size - 1)
    grid = t[0] + dt * np.arange(t.size)
    y = np.interp(grid, t, values)
    try:
        yb = _bandpass(y, dt, 0.7 * f1, 1.3 * f1, order=2, edge=0.99)
    except SignatureError:
        return 1e-3 * w1
    env = np.abs(ssig.hilbert(yb))
    n = env.size
    sl = slice(n // 10, n - n // 10)
    ok = env[sl] > 1e-12 * env.max()
    if ok.sum() < 10:
        return 1e-3 * w1
    slope = np.polyfit(grid[sl][ok], np.log(env[sl][ok]), 1)[0]
    return float(max(-slope, 1e-6 * w1))


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

    return {"p": p, "se": se_of(res.jac), "coef": coef, "se_lin": se_of(B), "K": K,
            "resid": r}


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


def windowed_sinusoids(
    times: np.ndarray,
    values: np.ndarray,
    f0: Sequence[float],
    sigma0: Sequence[float] | None = None,
) -> tuple[list[ModalEstimate | None], list[float]]:
    """Damped-sinusoid estimates of each mode from the window that measures it best.

    A higher mode of a whole record lives for a fraction of it (mode 2 of the 40 cm
    aluminium strip decays at 7/s against 0.3/s for mode 1), so a fit of the whole
    record drowns it: its amplitude falls below 5 standard errors (the residual's
    lag-1 correlation inflates them) and it is reported as not measurable. Windows
    from the first sample, the record halved until a window holds fewer than 8
    periods of mode 1, are each fitted with all modes (:func:`damped_sinusoids`); each
    higher mode keeps the estimate with the smallest frequency standard error, mode 1
    the whole record's (its mean frequency and decay rate over the record).

    Parameters
    ----------
    times, values : ndarray, shape (T,)
        Record (s, signal units).
    f0 : sequence of float
        Starting frequencies (Hz), mode 1 first.
    sigma0 : sequence of float, optional
        Starting decay rates (1/s), as in :func:`damped_sinusoids`.

    Returns
    -------
    estimates : list of ModalEstimate or None
        One entry per ``f0``; None where no window measures the mode.
    windows : list of float
        Each mode's window: the span (s) from the first sample that gave its estimate
        (the whole record where none did). Apply :func:`damped_sinusoids` to another
        signal on the same span to compare like with like.
    """
    t, y = _check_series(times, values)
    span = float(t[-1] - t[0])
    best: list[ModalEstimate | None] = [None] * len(f0)
    windows = [span] * len(f0)
    if not len(f0):
        return best, windows
    dur = span
    while True:
        m = t - t[0] <= dur * (1 + 1e-12)
        for k, e in enumerate(damped_sinusoids(t[m], y[m], f0, sigma0)):
            if k == 0 and dur < span:
                continue  # mode 1 from the whole record, as its decay rate is meant
            if e is not None and (best[k] is None or e.frequency_se < best[k].frequency_se):
                best[k], windows[k] = e, dur
        dur *= 0.5
        if dur * f0[0] < 8 or np.count_nonzero(t - t[0] <= dur) < 16 * len(f0):
            return best, windows


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
    others_hz : tuple of float
        Fitted frequencies (Hz) of the other modes (aliases folded) fitted beside it.
    """

    frequency: float
    excess: float
    excess_se: float
    rate0: float
    amplitude0: float
    amplitude: np.ndarray
    rate: np.ndarray
    others_hz: tuple[float, ...] = ()

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
            "others_hz": [float(f) for f in self.others_hz],
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
    local (A, σ) points. This is the diagnosis statistic (the excess c and its standard
    error); the model-free window estimate of a long record is
    :func:`envelope_decay_vs_amplitude`.

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
        others_hz=tuple(float(f) for f in fit["p"][1:K]),
    )


def envelope_decay_vs_amplitude(
    times: np.ndarray,
    values: np.ndarray,
    f1: float,
    n_windows: int = 8,
    *,
    band: float = 0.3,
    trim_cycles: float = 3.0,
    floor: float = 0.02,
) -> tuple[np.ndarray, np.ndarray]:
    """Local decay rate of the first mode against its amplitude, from its envelope.

    Model-free: the demodulated envelope's log-slope in consecutive windows, with no law
    assumed for σ(A). It needs a record of many periods in which the first mode stands
    alone in its band (accuracy ~1e-5 1/s for linear damping), and it is the instrument
    for comparing two records of the same motion window by window (the slow flow of
    :mod:`bayesbeam.physics.nonlinear` against a direct integration). For a short record,
    or one dominated by higher modes (acceleration), and for an excess with a standard
    error, use the whole-record fit :func:`decay_rate_vs_amplitude`.

    Steps (the record is first interpolated to its mean step if the stamps are not
    uniform):

    1. band-pass around ``f1`` (2nd-order Butterworth, ``f1 (1 ± band)``, zero phase) and
       take the Hilbert transform; a weighted straight-line fit in the interior gives the
       record's mean decay rate σ̂ and its frequency f̂ (the slope of the unwrapped phase);
       these are only the reference for step 2 (amplitude-weighted, unlike
       :func:`band_modal_estimate`, so that the noise floor does not pull them), and σ̂
       is divided out again at its end;
    2. divide the mean decay out (multiply by ``e^{σ̂ t}``), extend the record at both ends
       by 5 periods of the sinusoid fitted to its first and last two periods (so that the
       filter and the averaging below see no start-up transient), band-pass again,
       demodulate by ``e^{-2πi f̂ t}`` and average over two periods with a Hann window:
       the envelope is twice the modulus, times ``e^{-σ̂ t}``;
    3. cut ``trim_cycles`` periods at both ends, split the rest into ``n_windows`` equal
       windows and fit a straight line to the log envelope in each: the decay rate is
       minus its slope, the amplitude the envelope's geometric mean.

    Every step is linear and time-invariant on ``e^{-σt} cos ωt`` up to a constant factor,
    so for linear damping the rate is the same in every window (σ = ζ ω; measured error
    ~1e-5 1/s, edges included); drag makes it grow with amplitude, Coulomb friction makes
    it grow as the amplitude falls.

    Parameters
    ----------
    times : array_like, shape (T,)
        Sample times, s, strictly increasing.
    values : array_like, shape (T,)
        Signal (any quantity; the amplitude is in its units).
    f1 : float
        First natural frequency, Hz, to within the band (e.g.
        :func:`bayesbeam.inference.problem.first_frequency`).
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
    SignatureError
        For non-finite or mismatched input, a band outside (0, Nyquist) or a record too
        short for the windows.
    """
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float)
    if t.ndim != 1 or y.shape != t.shape or t.size < 16:
        raise SignatureError(
            "times and values must be 1-D arrays of the same length (>= 16 samples)"
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise SignatureError("times and values must be finite")
    if np.any(np.diff(t) <= 0):
        raise SignatureError("times must be strictly increasing")
    if not (isinstance(n_windows, (int, np.integer)) and n_windows >= 2):
        raise SignatureError(f"n_windows must be an integer >= 2, got {n_windows!r}")
    if not 0 < band < 1:
        raise SignatureError(f"band must lie in (0, 1) (relative half-width), got {band!r}")
    dt = (t[-1] - t[0]) / (t.size - 1)
    fs = 1.0 / dt
    f1 = float(f1)
    if not (np.isfinite(f1) and f1 > 0 and f1 * (1 + band) < 0.5 * fs):
        raise SignatureError(
            f"f1 = {f1} Hz with band {band} must lie below the Nyquist frequency {0.5 * fs} Hz"
        )
    tt = dt * np.arange(t.size)  # time since the first sample
    y = np.interp(t[0] + tt, t, y)
    y = y - np.mean(y)
    keep = (tt >= trim_cycles / f1) & (tt <= tt[-1] - trim_cycles / f1)
    period = int(round(fs / f1))
    if np.count_nonzero(keep) < 4 * n_windows or t.size < 4 * period:
        raise SignatureError(
            f"record too short: {np.count_nonzero(keep)} samples remain after trimming "
            f"{trim_cycles} cycles at each end; need at least {4 * n_windows} for "
            f"{n_windows} windows (and 4 periods in all)"
        )
    sos = ssig.butter(2, [f1 * (1 - band), f1 * (1 + band)], btype="bandpass", fs=fs,
                     output="sos")
    # 1. Mean decay rate and frequency (amplitude-weighted fits in the interior).
    a = ssig.hilbert(ssig.sosfiltfilt(sos, y))
    e1 = np.abs(a)[keep]
    if not np.any(e1 > 0):
        return np.array([]), np.array([])
    wts = e1 / e1.max()
    with np.errstate(divide="ignore"):
        le1 = np.log(np.maximum(e1, 1e-300))
    s_hat = -np.polyfit(tt[keep], le1, 1, w=wts)[0]
    f_hat = np.polyfit(tt[keep], np.unwrap(np.angle(a))[keep], 1, w=wts)[0] / (2 * np.pi)
    if not (np.isfinite(f_hat) and abs(f_hat / f1 - 1) < band):
        f_hat = f1
    s_hat = float(np.clip(s_hat, -50 * f1, 50 * f1)) if np.isfinite(s_hat) else 0.0
    # 2. Detrend, extend by the fitted sinusoid, band-pass, demodulate, Hann-average.
    g = np.exp(np.clip(s_hat * tt, -700, 700))
    yd = y * g
    P = int(round(fs / f_hat))
    n_pad = 5 * P
    w = 2 * np.pi * f_hat

    def extend(t_fit: np.ndarray, y_fit: np.ndarray, t_new: np.ndarray) -> np.ndarray:
        basis = np.column_stack([np.cos(w * t_fit), np.sin(w * t_fit)])
        coef = np.linalg.lstsq(basis, y_fit, rcond=None)[0]
        return np.column_stack([np.cos(w * t_new), np.sin(w * t_new)]) @ coef

    t_left = -dt * np.arange(n_pad, 0, -1)
    t_right = tt[-1] + dt * np.arange(1, n_pad + 1)
    tp = np.concatenate([t_left, tt, t_right])
    yp = np.concatenate([extend(tt[:2 * P], yd[:2 * P], t_left), yd,
                         extend(tt[-2 * P:], yd[-2 * P:], t_right)])
    z = ssig.sosfiltfilt(sos, yp) * np.exp(-1j * w * tp)
    hann = np.hanning(2 * P + 2)[1:-1]
    env = 2 * np.abs(np.convolve(z, hann / hann.sum(), mode="same"))[n_pad:-n_pad] / g
    # 3. Windowed log-slopes.
    tk, ek = tt[keep], env[keep]
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
