"""What the data say before any model: modal frequency and damping against amplitude.

Model-free and time-resolved, on the raw (possibly non-uniform) time stamps:
:func:`amplitude_curves` slides a window of ``periods`` periods of mode 1 (hop: half a
window) along the record and fits, in each window, free damped sinusoids plus an offset,

``y(t) ≈ c + Σ_k e^{-σ_k τ} (a_k cos ω_k τ + b_k sin ω_k τ)``, ``τ = t - t_c``,

with ``t_c`` the window's centre, so ``A_k = hypot(a_k, b_k)`` is the amplitude of mode k
at the centre. Mode 1 also gets a linear change of its frequency and decay rate within
the window (``ω_1 τ + γ τ²/2`` in the phase, ``-σ_1 τ - β τ²/2`` in the log amplitude;
``chirp=True``): when ω and σ depend on amplitude they change along a window, and a
constant-parameter fit then misreads them by up to ~γT/30 depending on the phase at the
window edges (measured: 6e-5 in ζ and 8e-5 relative in f on the validation oscillator);
with the terms, ω_1 and σ_1 are the values at the centre and what is left is the
curvature ``ω̈ T²/40`` (T the window length; 3e-5 relative in the validation).

The fit is a variable projection: ``a_k, b_k, c`` are solved by linear least squares
inside a nonlinear least-squares fit of ``(ω_k, σ_k[, γ, β])`` (Kaufman's Jacobian); the
first window starts from the record's spectrum
(:func:`~bayesbeam.trials.modal_id.periodogram`), every later one from the window
before. Standard errors come from the full Jacobian at the solution and the residual
variance (inflated by the lag-1 autocorrelation of the residual, as in
:mod:`bayesbeam.trials.modal_id`). The damping ratio is ``ζ = σ / sqrt(σ² + ω²)``.

A mode is resolved in a window when its centre amplitude exceeds both ``min_snr`` (5)
of its standard errors and ``min_sd`` (1) residual standard deviations; otherwise it is
dropped from the window's fit and reported as NaN. (The standard-error test alone kept
fitting, on the 50 cm aluminium record, a weak steady line near mode 2 after mode 2 had
decayed, with negative ζ2; 3 residual sds alone lost mode 2 at the first glitch.) Window
results are binned by mode-1 amplitude (:mod:`bayesbeam.trials.amplitude_bins`); the
residual of the windowed fit, its spectrogram and its spectral lines are computed by
:mod:`bayesbeam.trials.residual_lines`. The validation against direct integrations of a
nonlinear oscillator is in ``tests/trials/test_amplitude.py``.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize as sopt

from bayesbeam._util import finite_or_none
from bayesbeam.trials.amplitude_bins import AmplitudeBin, bin_by_amplitude, tip_factor
from bayesbeam.trials.modal_id import SignatureError, periodogram, spectral_peak
from bayesbeam.trials.residual_lines import (
    ResidualLine,
    blend_windows,
    residual_lines,
    residual_spectrogram,
)

__all__ = ["AmplitudeBin", "AmplitudeCurves", "amplitude_curves", "tip_factor"]

_QUANTITY_POWER = {"displacement": 0, "velocity": 1, "acceleration": 2}


def _ro(a: Any) -> np.ndarray:
    out = np.array(a, dtype=float)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class AmplitudeCurves:
    """Window-by-window modal estimates of a free-decay record (arrays read-only).

    Attributes
    ----------
    quantity : str
        'displacement', 'velocity' or 'acceleration' (units of ``amplitude``).
    window_s, hop_s : float
        Window length and hop in s.
    centre : ndarray, shape (W,)
        Window centre times in s (record time axis).
    n_samples : ndarray, shape (W,)
        Samples in each window.
    amplitude, amplitude_se : ndarray, shape (W, K)
        Mode amplitudes at the window centre in record units (SI), NaN where unresolved.
    amplitude_m : ndarray, shape (W,)
        Mode-1 displacement amplitude in m: ``amplitude[:, 0] / ω_n^p`` (p = 0, 1, 2 for
        displacement, velocity, acceleration; ``ω_n² = σ² + ω²``) times ``tip_factor``.
    frequency, frequency_se : ndarray, shape (W, K)
        Damped frequencies in Hz.
    zeta, zeta_se : ndarray, shape (W, K)
        Damping ratios ``σ / sqrt(σ² + ω²)``.
    offset, offset_se : ndarray, shape (W,)
        Fitted constant in record units.
    resid_rms : ndarray, shape (W,)
        RMS of the window's residual (record units).
    bins : tuple of AmplitudeBin
        Results binned by mode-1 amplitude (empty bins left out), largest amplitude last.
    residual : ndarray, shape (T,)
        Data minus the blended windowed fit
        (:func:`~bayesbeam.trials.residual_lines.blend_windows`).
    spectrogram : tuple of ndarray
        ``(f (F,) Hz, t (S,) s, amplitude (F, S) record units)`` of the residual.
    lines : tuple of ResidualLine
        Residual spectral lines that are not fitted modes.
    tip_factor : float
        Factor applied to the sensor displacement amplitude (1: at the sensor).
    settings : dict
        ``periods``, ``n_modes``, ``min_snr``, ``line_factor``, start frequencies.
    """

    quantity: str
    window_s: float
    hop_s: float
    centre: np.ndarray
    n_samples: np.ndarray
    amplitude: np.ndarray
    amplitude_se: np.ndarray
    amplitude_m: np.ndarray
    frequency: np.ndarray
    frequency_se: np.ndarray
    zeta: np.ndarray
    zeta_se: np.ndarray
    offset: np.ndarray
    offset_se: np.ndarray
    resid_rms: np.ndarray
    bins: tuple[AmplitudeBin, ...]
    residual: np.ndarray
    spectrogram: tuple[np.ndarray, np.ndarray, np.ndarray]
    lines: tuple[ResidualLine, ...]
    tip_factor: float = 1.0
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def ratio(self) -> tuple[np.ndarray, np.ndarray]:
        """Return f2/f1 per window and its standard error (NaN without mode 2).

        Returns
        -------
        tuple of ndarray, shape (W,)
        """
        if self.frequency.shape[1] < 2:
            nan = np.full(self.centre.shape, np.nan)
            return nan, nan
        f1, f2 = self.frequency[:, 0], self.frequency[:, 1]
        r = f2 / f1
        se = r * np.hypot(self.frequency_se[:, 1] / f2, self.frequency_se[:, 0] / f1)
        return r, se

    def to_json_dict(self) -> dict[str, Any]:
        """Return a strict-JSON dictionary (NaN and inf as None; no residual arrays).

        Returns
        -------
        dict
        """
        def col(a: np.ndarray) -> list[float | None]:
            return [finite_or_none(v) for v in a]

        K = self.frequency.shape[1]
        ratio, ratio_se = self.ratio
        modes = [{"mode": k + 1, "frequency_hz": col(self.frequency[:, k]),
                  "frequency_se_hz": col(self.frequency_se[:, k]),
                  "zeta": col(self.zeta[:, k]), "zeta_se": col(self.zeta_se[:, k]),
                  "amplitude": col(self.amplitude[:, k]),
                  "amplitude_se": col(self.amplitude_se[:, k])} for k in range(K)]
        return {
            "quantity": self.quantity,
            "window_s": self.window_s,
            "hop_s": self.hop_s,
            "tip_factor": self.tip_factor,
            "settings": {k: (col(v) if isinstance(v, (list, tuple, np.ndarray)) else v)
                         for k, v in self.settings.items()},
            "windows": {
                "centre_s": col(self.centre),
                "n_samples": [int(v) for v in self.n_samples],
                "amplitude_m": col(self.amplitude_m),
                "offset": col(self.offset),
                "offset_se": col(self.offset_se),
                "resid_rms": col(self.resid_rms),
                "ratio_f2_f1": col(ratio),
                "ratio_se": col(ratio_se),
                "modes": modes,
            },
            "bins": [b.to_json_dict() for b in self.bins],
            "residual_lines": [ln.to_json_dict() for ln in self.lines],
            "residual_rms": finite_or_none(np.sqrt(np.nanmean(self.residual ** 2))),
        }


# --------------------------------------------------------------------------- fitting


def _basis(tau: np.ndarray, p: np.ndarray, K: int) -> tuple[np.ndarray, ...]:
    """Columns ``e^{-σ τ - β τ²/2} (cos ψ, sin ψ)``, ``ψ = ω τ + γ τ²/2``, and a constant.

    ``p = (ω_1..K, σ_1..K[, γ_1, β_1])``: the optional quadratic terms belong to mode 1.
    """
    w, s = p[:K], p[K:2 * K]
    lg = -np.outer(tau, s)
    ph = np.outer(tau, w)
    if p.size > 2 * K:
        half = 0.5 * tau * tau
        ph[:, 0] += p[2 * K] * half
        lg[:, 0] -= p[2 * K + 1] * half
    e = np.exp(lg)
    c, sn = e * np.cos(ph), e * np.sin(ph)
    return np.hstack([c, sn, np.ones((tau.size, 1))]), c, sn


def _fit_window(tau: np.ndarray, y: np.ndarray, p0: np.ndarray,
                K: int) -> dict[str, Any]:
    """Variable-projection fit of K damped sinusoids + offset; parameters and covariance.

    ``tau`` is time from the window centre (s); ``p0`` the start ``(ω_k [rad/s], σ_k
    [1/s][, γ_1 [rad/s²], β_1 [1/s²]])``. Returns the parameters ``p``, the linear
    coefficients ``coef = (a_1..K, b_1..K, c)``, the covariance of ``(p, coef)``, the
    residual RMS and the fitted signal.
    """
    cache: dict[str, Any] = {}

    def solve(p: np.ndarray) -> dict[str, Any]:
        if cache.get("p") is not None and np.array_equal(cache["p"], p):
            return cache
        B, c, sn = _basis(tau, p, K)
        Q, R = np.linalg.qr(B)
        coef = np.linalg.lstsq(R, Q.T @ y, rcond=None)[0]
        cache.update(p=p.copy(), B=B, c=c, sn=sn, Q=Q, coef=coef, r=y - B @ coef)
        return cache

    def dmodel(st: dict[str, Any], p: np.ndarray) -> np.ndarray:
        """Columns d(model)/dp at fixed linear coefficients."""
        a, b = st["coef"][:K], st["coef"][K:2 * K]
        t = tau[:, None]
        dpsi = b * st["c"] - a * st["sn"]  # d/dψ of each mode
        mode = a * st["c"] + b * st["sn"]
        cols = [t * dpsi, -t * mode]
        if p.size > 2 * K:
            half = 0.5 * t * t
            cols += [half * dpsi[:, :1], -half * mode[:, :1]]
        return np.hstack(cols)

    def jac(p: np.ndarray) -> np.ndarray:
        # Kaufman's variable-projection Jacobian: -P⊥ (∂B/∂p) coef.
        st = solve(p)
        D = dmodel(st, p)
        return -(D - st["Q"] @ (st["Q"].T @ D))

    w0 = p0[:K]
    lo = np.concatenate([0.85 * w0, -0.1 * w0, np.full(p0.size - 2 * K, -np.inf)])
    hi = np.concatenate([1.15 * w0, 0.5 * w0, np.full(p0.size - 2 * K, np.inf)])
    res = sopt.least_squares(lambda p: solve(p)["r"], np.clip(p0, lo, hi), jac=jac,
                             bounds=(lo, hi), method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12,
                             gtol=1e-12, max_nfev=200)
    st = solve(res.x)
    r = st["r"]
    J = np.hstack([dmodel(st, res.x), st["B"]])
    n, npar = tau.size, J.shape[1]
    s2 = float(r @ r) / max(n - npar, 1)
    # Residuals that are not white (unmodelled harmonics, sensor colour) carry less
    # information than their number says: inflate by the AR(1) factor (1 + ρ)/(1 - ρ).
    rho = float(np.clip(np.corrcoef(r[:-1], r[1:])[0, 1], 0.0, 0.99)) if s2 > 0 else 0.0
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    try:
        cov = np.linalg.inv((J / scale).T @ (J / scale)) / np.outer(scale, scale)
    except np.linalg.LinAlgError:
        cov = np.full((npar, npar), np.inf)
    cov = cov * s2 * (1 + rho) / (1 - rho)
    return {"p": res.x, "coef": st["coef"], "cov": cov, "rms": math.sqrt(float(r @ r) / n),
            "model": st["B"] @ st["coef"]}


def _mode_results(fit: dict[str, Any], K: int) -> dict[str, Any]:
    """Frequencies, damping ratios, amplitudes and their SEs (delta method) of one fit."""
    p, coef, cov = fit["p"], fit["coef"], fit["cov"]
    w, s = p[:K], p[K:2 * K]
    a, b = coef[:K], coef[K:2 * K]
    lin = p.size  # index of the first linear coefficient in cov
    wn2 = w ** 2 + s ** 2
    out: dict[str, Any] = {"f": w / (2 * np.pi), "wn": np.sqrt(wn2), "zeta": s / np.sqrt(wn2)}
    var = np.diag(cov)
    out["f_se"] = np.sqrt(np.maximum(var[:K], 0)) / (2 * np.pi)
    z_se, A, A_se = np.empty(K), np.hypot(a, b), np.empty(K)
    for k in range(K):
        g = np.array([-s[k] * w[k], w[k] ** 2]) / wn2[k] ** 1.5  # ∂ζ/∂(ω, σ)
        idx = [k, K + k]
        z_se[k] = math.sqrt(max(g @ cov[np.ix_(idx, idx)] @ g, 0.0))
        ga = np.array([a[k], b[k]]) / A[k] if A[k] > 0 else np.zeros(2)
        il = [lin + k, lin + K + k]
        A_se[k] = math.sqrt(max(ga @ cov[np.ix_(il, il)] @ ga, 0.0))
    out.update(zeta_se=z_se, A=A, A_se=A_se, offset=coef[-1],
               offset_se=math.sqrt(max(cov[-1, -1], 0.0)))
    return out


def _start_frequencies(times: np.ndarray, values: np.ndarray, f1: float | None,
                       n_modes: int) -> np.ndarray:
    """Mode frequencies (Hz) from the record's periodogram: f1 and the next peaks.

    Higher modes are the largest local maxima above 1.5 f1 and below 0.45 times the
    sampling rate that are not within 2 % of a harmonic of f1 or 1 Hz of a mains
    frequency (50/60 Hz and their multiples), at least 20 % apart.
    """
    f, amp = periodogram(times, values)
    dur = float(times[-1] - times[0])
    fmax = 0.45 * (times.size - 1) / dur
    if f1 is None:
        sel = (f > 3.0 / dur) & (f < fmax)
        if not np.any(sel):
            raise SignatureError("record too short to find a spectral peak; give f1")
        f_guess = float(f[sel][np.argmax(amp[sel])])
        f1 = spectral_peak(f, amp, f_guess, rel_window=0.05) or f_guess
    out = [float(f1)]
    interior = np.flatnonzero((amp[1:-1] > amp[:-2]) & (amp[1:-1] >= amp[2:])) + 1
    cand = [i for i in interior[np.argsort(amp[interior])[::-1]] if 1.5 * f1 < f[i] < fmax]
    for i in cand:
        if len(out) >= n_modes:
            break
        fi = float(f[i])
        n = round(fi / f1)
        if abs(fi - n * f1) < 0.02 * n * f1:
            continue
        if any(abs(fi - m * base) < 1.0 for base in (50.0, 60.0)
               for m in range(1, int(fi / base) + 2)):
            continue
        if all(abs(fi / g - 1) > 0.2 for g in out):
            out.append(fi)
    return np.array(out)


def _windows(t: np.ndarray, window: float, hop: float) -> np.ndarray:
    """Window start times covering [t0, t_end] with a hop no longer than asked."""
    span = float(t[-1] - t[0])
    if span < window:
        raise SignatureError(
            f"record of {span:.3g} s is shorter than one window ({window:.3g} s); use "
            "fewer periods or a longer record"
        )
    n = int(math.ceil((span - window) / hop - 1e-9)) + 1
    return t[0] + np.linspace(0.0, span - window, n) if n > 1 else np.array([t[0]])


def amplitude_curves(
    times: np.ndarray,
    values: np.ndarray,
    *,
    f1: float | None = None,
    n_modes: int = 2,
    periods: float = 4.0,
    step: float | None = None,
    quantity: str = "displacement",
    min_snr: float = 5.0,
    min_sd: float = 1.0,
    n_bins: int = 8,
    tip_factor: float = 1.0,
    line_factor: float = 5.0,
    chirp: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> AmplitudeCurves:
    """Modal frequencies and damping ratios against mode-1 amplitude, window by window.

    See the module docstring for the method.

    Parameters
    ----------
    times : ndarray, shape (T,)
        Sample times in s, strictly increasing (need not be uniform; gaps allowed).
    values : ndarray, shape (T,)
        Free-decay signal in SI units of ``quantity``.
    f1 : float, optional
        Mode-1 frequency in Hz to start from (default: the largest peak of the record's
        periodogram above 3/duration).
    n_modes : int
        Modes fitted (1 or more); the higher ones start from the next periodogram peaks.
    periods : float
        Window length in periods of mode 1 (at least 1.5).
    step : float, optional
        Hop between window starts in s (default half a window).
    quantity : str
        'displacement', 'velocity' or 'acceleration': how ``amplitude_m`` is derived.
    min_snr : float
        A mode is resolved in a window when its centre amplitude exceeds ``min_snr``
        times its standard error ...
    min_sd : float
        ... and ``min_sd`` times the window's residual RMS.
    n_bins : int
        Log-spaced mode-1 amplitude bins.
    tip_factor : float
        Mode-shape ratio φ1(tip)/φ1(sensor) applied to ``amplitude_m`` (see
        :func:`tip_factor`); 1 keeps the amplitude at the sensor.
    line_factor : float
        A residual spectral line must exceed the local median level by this factor
        (:func:`~bayesbeam.trials.residual_lines.residual_lines`).
    chirp : bool
        Let mode 1's frequency and decay rate change linearly within a window (terms
        ``γ τ²/2`` in its phase and ``-β τ²/2`` in its log amplitude), so that ω1 and σ1
        are the values at the window centre even when they change with amplitude (a
        constant-parameter fit is biased by the chirp: see the module docstring).
    progress : callable, optional
        Called as ``progress(done, total)`` after each window.

    Returns
    -------
    AmplitudeCurves

    Raises
    ------
    SignatureError
        For invalid input or a record shorter than one window.
    """
    t = np.asarray(times, dtype=float)
    y = np.asarray(values, dtype=float)
    if t.ndim != 1 or t.shape != y.shape or t.size < 32:
        raise SignatureError(f"times and values must be 1-D of the same length >= 32, got "
                             f"{t.shape} and {y.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise SignatureError("times and values must be finite")
    if np.any(np.diff(t) <= 0):
        raise SignatureError("times must be strictly increasing")
    if quantity not in _QUANTITY_POWER:
        raise SignatureError(f"quantity must be one of {sorted(_QUANTITY_POWER)}, got "
                             f"{quantity!r}")
    if not (isinstance(n_modes, (int, np.integer)) and n_modes >= 1):
        raise SignatureError(f"n_modes must be an integer >= 1, got {n_modes!r}")
    if not periods >= 1.5:
        raise SignatureError(f"periods must be >= 1.5, got {periods!r}")
    if f1 is not None and not (math.isfinite(f1) and f1 > 0):
        raise SignatureError(f"f1 must be a positive frequency in Hz, got {f1!r}")
    f_start = _start_frequencies(t, y, f1, n_modes)
    K = f_start.size
    window = periods / float(f_start[0])
    hop = 0.5 * window if step is None else float(step)
    if not 0 < hop <= window:
        raise SignatureError(f"step must lie in (0, window = {window:.4g} s], got {step!r}")
    starts = _windows(t, window, hop)
    hop = float(starts[1] - starts[0]) if starts.size > 1 else window
    W = starts.size
    w_last = 2 * np.pi * f_start
    s_last = 0.01 * w_last  # ζ = 1 % to start; the first window's fit moves it
    quad = np.zeros(2 if chirp else 0)  # mode 1's γ, β: start from none
    res = {k: np.full((W, K), np.nan) for k in ("f", "f_se", "zeta", "zeta_se", "A", "A_se")}
    wn1 = np.full(W, np.nan)
    off, off_se, rms = np.full(W, np.nan), np.full(W, np.nan), np.full(W, np.nan)
    counts = np.zeros(W, dtype=int)
    bounds, models = [], []
    for i, a in enumerate(starts):
        i0, i1 = np.searchsorted(t, [a, a + window * (1 + 1e-12)])
        tc = a + 0.5 * window
        counts[i] = i1 - i0
        active = np.arange(K)
        fit, m = None, None
        while counts[i] >= 8 * active.size + 8:
            p0 = np.concatenate([w_last[active], s_last[active], quad])
            fit = _fit_window(t[i0:i1] - tc, y[i0:i1], p0, active.size)
            m = _mode_results(fit, active.size)
            weak = ~((m["A"] > min_snr * m["A_se"]) & (m["A"] > min_sd * fit["rms"]))
            weak[0] = False  # mode 1 decides about the whole window below
            if not weak.any():
                break
            active = active[~weak]
        if progress is not None:
            progress(i + 1, W)
        if fit is None or not (m["A"][0] > min_snr * m["A_se"][0]
                               and m["A"][0] > min_sd * fit["rms"]):
            continue  # mode 1 not resolved: the whole window is NaN
        for key in res:
            res[key][i, active] = m[key]
        wn1[i] = m["wn"][0]
        off[i], off_se[i], rms[i] = m["offset"], m["offset_se"], fit["rms"]
        na = active.size
        w_last[active], s_last[active] = fit["p"][:na], fit["p"][na:2 * na]
        quad = fit["p"][2 * na:]
        bounds.append((i0, i1, tc))
        models.append(fit["model"])
    amp_m = res["A"][:, 0] / wn1 ** _QUANTITY_POWER[quantity] * tip_factor
    freq, f_se = res["f"], res["f_se"]
    ratio = ((freq[:, 1] / freq[:, 0],
              freq[:, 1] / freq[:, 0] * np.hypot(f_se[:, 1] / freq[:, 1], f_se[:, 0] / freq[:, 0]))
             if K > 1 else (np.full(W, np.nan), np.full(W, np.nan)))
    resid = y - blend_windows(t, bounds, models, window)
    f_ok = np.isfinite(freq)
    mode_ranges = [(float(np.min(freq[f_ok[:, k], k])), float(np.max(freq[f_ok[:, k], k])))
                   for k in range(K) if f_ok[:, k].any()]
    f1_range = mode_ranges[0] if mode_ranges else (float(f_start[0]),) * 2
    lines = residual_lines(t, resid, f1_range, mode_ranges, factor=line_factor)
    spec = residual_spectrogram(t, resid, nperseg_s=window)
    return AmplitudeCurves(
        quantity=quantity, window_s=float(window), hop_s=hop, centre=_ro(starts + 0.5 * window),
        n_samples=counts, amplitude=_ro(res["A"]), amplitude_se=_ro(res["A_se"]),
        amplitude_m=_ro(amp_m), frequency=_ro(freq), frequency_se=_ro(f_se),
        zeta=_ro(res["zeta"]), zeta_se=_ro(res["zeta_se"]), offset=_ro(off),
        offset_se=_ro(off_se), resid_rms=_ro(rms),
        bins=bin_by_amplitude(res["A"][:, 0], amp_m, freq, f_se, res["zeta"], res["zeta_se"], ratio,
                   n_bins, hop, window),
        residual=_ro(resid), spectrogram=tuple(_ro(a) for a in spec), lines=lines,
        tip_factor=float(tip_factor),
        settings={"periods": float(periods), "n_modes": int(n_modes), "min_snr": float(min_snr),
                  "min_sd": float(min_sd),
                  "line_factor": float(line_factor), "chirp": bool(chirp),
                  "start_frequencies_hz": f_start.tolist()},
    )
