"""Posterior-predictive checks of a fit: fit and residual plots, whiteness.

Figures are built on :class:`matplotlib.figure.Figure` directly (object API, Agg
canvas), so importing or calling this module never touches pyplot's global state or
the backend.

* :func:`plot_fit`: data against the 5–95 % posterior-predictive band (draws of
  :func:`bayesbeam.inference.predictive.posterior_predictive`) and the median model,
  residuals (data minus the pointwise posterior median of the model) underneath.
* :func:`plot_residual_spectrum`: Welch amplitude spectral density of the residuals with
  the model's modal frequencies marked; structure at a modal frequency points at a
  damping law that cannot reproduce that mode's decay (physics.md §3, correlated
  residuals).
* :func:`residual_summary`: RMS, sample autocorrelation and the Ljung–Box portmanteau
  test (Ljung & Box 1978) of whiteness; ``structured`` flags residuals that are not
  white noise at the 1 % level.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import scipy.signal as ssig

from bayesbeam._util import atomic_path
from bayesbeam.inference.predictive import posterior_predictive
from bayesbeam.stats.whiteness import autocorrelation, ljung_box

__all__ = [
    "PlotError",
    "UNIT_LABELS",
    "plot_fit",
    "plot_residual_spectrum",
    "residual_summary",
]

#: SI unit of each measured quantity, as written on plot axes.
UNIT_LABELS = {"displacement": "m", "velocity": "m/s", "acceleration": "m/s²"}

#: Significance level below which residual_summary calls residuals structured.
STRUCTURE_ALPHA = 0.01


class PlotError(ValueError):
    """Invalid input to a plotting or checking function; the message says how to fix it."""


def _quantity_unit(trial: Any) -> tuple[str, str]:
    return trial.quantity, UNIT_LABELS.get(trial.quantity, "SI")


def plot_fit(
    trial: Any,
    problem: Any,
    result: Any,
    path: str | Path,
    *,
    n_draws: int = 200,
    rng: np.random.Generator,
    draws: tuple[np.ndarray, np.ndarray] | None = None,
    dpi: int = 120,
    title: str | None = None,
) -> Path:
    """Plot data against the posterior-predictive band, with residuals underneath.

    Top panel: measured signal, the 5–95 % band of replicated data (model plus
    noise), the 5–95 % band of the model signal alone and its pointwise median.
    Bottom panel: residuals, data minus the pointwise posterior median of the model,
    with the ±1.645 σ̂ lines of the median noise sd (90 % of white noise falls inside).

    Parameters
    ----------
    trial : bayesbeam.trials.trial.Trial
        The fitted trial (times in s, values in SI units).
    problem : bayesbeam.inference.problem.Problem
    result : bayesbeam.inference.results.FitResult
    path : str or pathlib.Path
        Image file; the format follows the suffix.
    n_draws : int, default 200
        Posterior draws for the bands.
    rng : numpy.random.Generator
        Chooses draws and noise.
    draws : tuple of ndarray, optional
        Precomputed ``(y_model, y_rep)`` of
        :func:`bayesbeam.inference.predictive.posterior_predictive`, each shape (n, T);
        then ``n_draws`` and ``rng`` are not used.
    dpi : int, default 120
    title : str, optional
        Title of the top panel; default names the trial, the model and the draws.

    Returns
    -------
    pathlib.Path
    """
    from matplotlib.figure import Figure

    t = np.asarray(trial.times, dtype=float)
    y = np.asarray(trial.values, dtype=float)
    y_model, y_rep = draws if draws is not None else posterior_predictive(
        problem, result, n_draws, rng
    )[1:]
    if y_model.shape[-1] != t.size or y_rep.shape != y_model.shape:
        raise PlotError(
            f"predictive draws have shape {y_model.shape}/{y_rep.shape}; the trial has "
            f"{t.size} samples"
        )
    rep_lo, rep_hi = np.quantile(y_rep, [0.05, 0.95], axis=0)
    mod_lo, med, mod_hi = np.quantile(y_model, [0.05, 0.5, 0.95], axis=0)
    resid = y - med
    qty, unit = _quantity_unit(trial)
    names = list(problem.names)
    sig = float(np.median(result.theta_samples()[..., names.index("sigma")]))

    fig = Figure(figsize=(10, 6.5), layout="constrained")
    ax, rx = fig.subplots(2, 1, sharex=True, height_ratios=[2.2, 1])
    ax.fill_between(t, rep_lo, rep_hi, color="tab:blue", alpha=0.25, lw=0,
                    label="5–95 % posterior predictive (model + noise)")
    ax.fill_between(t, mod_lo, mod_hi, color="tab:blue", alpha=0.5, lw=0,
                    label="5–95 % model signal")
    ax.plot(t, y, ".", ms=1.5, color="k", label="data")
    ax.plot(t, med, "-", lw=0.8, color="tab:red", label="posterior median model")
    ax.set_ylabel(f"{qty} [{unit}]")
    ax.legend(loc="upper right", fontsize="small")
    ax.set_title(title or f"{getattr(trial, 'name', 'trial')}: model {result.model!r}, "
                 f"{y_model.shape[0]} posterior draws")
    rx.plot(t, resid, "-", lw=0.5, color="k")
    for s in (1.645 * sig, -1.645 * sig):
        rx.axhline(s, color="tab:red", lw=0.8, ls="--")
    rx.axhline(0.0, color="0.5", lw=0.5)
    rx.set_ylabel(f"residual [{unit}]")
    rx.set_xlabel("time [s]")
    rx.set_title(f"data − posterior median model (dashed: ±1.645 σ, σ = {sig:.3g} {unit})",
                 fontsize="small")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path


def _uniform_series(times: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, float, bool]:
    """Put the series on a uniform grid of its mean step (linear interpolation if needed)."""
    t = np.asarray(times, dtype=float)
    v = np.asarray(values, dtype=float)
    dt = (t[-1] - t[0]) / (t.size - 1)
    steps = np.diff(t)
    # Same tolerance as Trial.is_uniform (bayesbeam.trials.trial.UNIFORM_RTOL).
    from bayesbeam.trials.trial import UNIFORM_RTOL

    if np.max(np.abs(steps - dt)) <= UNIFORM_RTOL * dt:
        return v, dt, False
    grid = t[0] + dt * np.arange(t.size)
    return np.interp(grid, t, v), dt, True


def plot_residual_spectrum(
    trial: Any,
    residuals: np.ndarray,
    path: str | Path,
    *,
    mode_freqs_hz: np.ndarray | None = None,
    dpi: int = 120,
) -> Path:
    """Amplitude spectral density of the residuals with the modal frequencies marked.

    Welch's method (Hann window, segments of ``min(T, 512)`` samples, 50 % overlap,
    mean removed); the plotted quantity is ``sqrt(PSD)`` in unit/√Hz. White noise of
    sd σ gives a flat level ``σ sqrt(2 dt)``, drawn for reference. Non-uniform time
    stamps are linearly interpolated onto a uniform grid of their mean step first;
    the caption says so.

    Parameters
    ----------
    trial : bayesbeam.trials.trial.Trial
        Provides the time stamps (s) and the quantity.
    residuals : ndarray, shape (T,)
        Data minus model, SI units of the quantity.
    path : str or pathlib.Path
        Image file.
    mode_freqs_hz : array_like, optional
        Natural frequencies of the fitted model in Hz, marked as vertical lines:
        dashed below the Nyquist frequency, dotted at the aliases of those up to
        twice the sampling rate.
    dpi : int, default 120

    Returns
    -------
    pathlib.Path
    """
    from matplotlib.figure import Figure

    r = np.asarray(residuals, dtype=float)
    t = np.asarray(trial.times, dtype=float)
    if r.shape != t.shape:
        raise PlotError(f"residuals have shape {r.shape}; the trial has {t.size} samples")
    if not np.all(np.isfinite(r)):
        raise PlotError("residuals contain NaN/inf")
    v, dt, interpolated = _uniform_series(t, r)
    nper = min(v.size, 512)
    f, psd = ssig.welch(v, fs=1.0 / dt, window="hann", nperseg=nper, detrend="constant")
    asd = np.sqrt(psd)
    qty, unit = _quantity_unit(trial)

    fig = Figure(figsize=(9, 4.8), layout="constrained")
    ax = fig.subplots()
    ax.semilogy(f[1:], asd[1:], lw=0.9, color="k", label="residual ASD (Welch)")
    white = float(np.std(v)) * np.sqrt(2 * dt)
    ax.axhline(white, color="0.5", ls=":", lw=0.9, label="white noise of the same RMS")
    if mode_freqs_hz is not None:
        fs = 1.0 / dt
        fm = np.asarray(mode_freqs_hz, dtype=float).ravel()
        fm = fm[np.isfinite(fm) & (fm > 0)]
        for i, fi in enumerate(fm[fm < 0.5 * fs]):
            ax.axvline(fi, color="tab:red", ls="--", lw=0.8,
                       label="model modal frequencies" if i == 0 else None)
        # Modes above the Nyquist frequency appear folded back (sampling aliases);
        # mark those of the next few Nyquist zones so their peaks are not misread.
        high = fm[(fm >= 0.5 * fs) & (fm < 2.0 * fs)]
        for i, fi in enumerate(high):
            folded = fi % fs  # (named apart from the residuals r that the caption sizes)
            ax.axvline(min(folded, fs - folded), color="tab:orange", ls=":", lw=0.8,
                       label="aliases of higher modes" if i == 0 else None)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"amplitude spectral density [{unit}/√Hz]")
    ax.set_xlim(0, 0.5 / dt)
    ax.legend(loc="upper right", fontsize="small")
    how = (
        f"non-uniform stamps linearly interpolated to their mean step {dt:.4g} s; "
        if interpolated else ""
    )
    ax.set_title(f"{getattr(trial, 'name', 'trial')}: residual spectrum ({qty})")
    fig.text(
        0.01, 0.005,
        f"Welch, Hann window, {nper}-sample segments, 50 % overlap; {how}"
        f"RMS {np.sqrt(np.mean(r**2)):.3g} {unit}",
        fontsize="x-small", va="bottom",
    )
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path


def residual_summary(
    residuals: np.ndarray, times: np.ndarray, *, max_lag: int | None = None
) -> dict[str, Any]:
    """RMS, autocorrelation and Ljung–Box whiteness test of a residual series.

    Sample autocorrelations ``r_k`` at lags ``k = 1..h`` (in samples, mean removed;
    :func:`~bayesbeam.stats.whiteness.autocorrelation`) and the Ljung–Box statistic
    ``Q = n (n + 2) Σ r_k² / (n − k)``, which for white noise is χ² with ``h`` degrees
    of freedom (Ljung & Box 1978; :func:`~bayesbeam.stats.whiteness.ljung_box`); the
    p-value is ``chi2.sf(Q, h)``. Lags count samples, so for non-uniform stamps they are
    lags in sample order (``lag_seconds`` gives their mean duration).

    Parameters
    ----------
    residuals : ndarray, shape (T,)
        Data minus model, any units.
    times : ndarray, shape (T,)
        Sample times in s, strictly increasing.
    max_lag : int, optional
        ``h``; default ``min(20, T // 4)`` (a common choice; small enough that the
        χ² approximation holds, large enough to see oscillatory structure).

    Returns
    -------
    dict
        ``n``, ``rms`` (units of the residuals), ``lags`` (list of int),
        ``lag_seconds`` (list), ``autocorr`` (list of r_k), ``ljung_box_q``,
        ``dof``, ``p_value``, ``alpha`` (0.01) and ``structured`` (``p_value <
        alpha``: not white noise).

    Raises
    ------
    PlotError
        For mismatched shapes, non-finite values or fewer than 8 samples.
    """
    r = np.asarray(residuals, dtype=float)
    t = np.asarray(times, dtype=float)
    if r.ndim != 1 or r.shape != t.shape:
        raise PlotError(
            f"residuals and times must be 1-D of equal length, got {r.shape} and {t.shape}"
        )
    if r.size < 8:
        raise PlotError(f"need at least 8 residuals for a whiteness test, got {r.size}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
        raise PlotError("residuals and times must be finite")
    n = r.size
    h = min(20, n // 4) if max_lag is None else int(max_lag)
    if not 1 <= h < n:
        raise PlotError(f"max_lag must be in [1, {n - 1}], got {max_lag!r}")
    lags = np.arange(1, h + 1)
    acf = autocorrelation(r, h)[1:]
    q, p = ljung_box(r, h)
    dt = (t[-1] - t[0]) / (n - 1)
    return {
        "n": int(n),
        "rms": float(np.sqrt(np.mean(r**2))),
        "lags": lags.tolist(),
        "lag_seconds": (lags * dt).tolist(),
        "autocorr": acf.tolist(),
        "ljung_box_q": q,
        "dof": int(h),
        "p_value": p,
        "alpha": STRUCTURE_ALPHA,
        "structured": bool(p < STRUCTURE_ALPHA),
    }
