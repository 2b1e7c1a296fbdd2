"""Decay rate against amplitude in a free-decay record: the signature of nonlinear damping.

Linear damping gives a decay rate that is the same at every amplitude; quadratic air drag
makes it grow with amplitude and dry (Coulomb) friction makes it grow as the amplitude
falls (:mod:`bayesbeam.physics.nonlinear`, physics.md §3). :func:`decay_vs_amplitude` measures
it from a record (band-pass around f1, envelope by demodulation, windowed log-slopes).
It is re-exported by :mod:`bayesbeam.physics.nonlinear`.
"""

from __future__ import annotations

import numpy as np
import scipy.signal as sps

__all__ = ["decay_vs_amplitude"]


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

    Steps (the record is first interpolated to its mean step if the stamps are not
    uniform):

    1. band-pass around ``f1`` (2nd-order Butterworth, ``f1 (1 ± band)``, zero phase) and
       take the Hilbert transform; a weighted straight-line fit in the interior gives the
       record's mean decay rate σ̂ and its frequency f̂ (the slope of the unwrapped phase);
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
    tt = dt * np.arange(t.size)  # time since the first sample
    y = np.interp(t[0] + tt, t, y)
    y = y - np.mean(y)
    keep = (tt >= trim_cycles / f1) & (tt <= tt[-1] - trim_cycles / f1)
    period = int(round(fs / f1))
    if np.count_nonzero(keep) < 4 * n_windows or t.size < 4 * period:
        raise ValueError(
            f"record too short: {np.count_nonzero(keep)} samples remain after trimming "
            f"{trim_cycles} cycles at each end; need at least {4 * n_windows} for "
            f"{n_windows} windows (and 4 periods in all)"
        )
    sos = sps.butter(2, [f1 * (1 - band), f1 * (1 + band)], btype="bandpass", fs=fs,
                     output="sos")
    # 1. Mean decay rate and frequency (amplitude-weighted fits in the interior).
    a = sps.hilbert(sps.sosfiltfilt(sos, y))
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
    z = sps.sosfiltfilt(sos, yp) * np.exp(-1j * w * tp)
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
