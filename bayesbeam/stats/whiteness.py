"""Whiteness of a series: sample autocorrelation and the Ljung–Box portmanteau test.

* :func:`autocorrelation`: ``ρ̂_k = Σ_t (r_t - r̄)(r_{t+k} - r̄) / Σ_t (r_t - r̄)²``, the
  biased estimator of Box & Jenkins, by FFT (zero-padded, so not circular);
* :func:`ljung_box`: ``Q = n (n + 2) Σ_{k=1..h} ρ̂_k² / (n - k)``, approximately χ²
  with ``h - n_params`` degrees of freedom for a white series (Ljung & Box 1978,
  Biometrika 65, 297-303).

Lags count samples; for non-uniform time stamps they are lags in sample order.
Invalid input raises :class:`WhitenessError`.
"""

from __future__ import annotations

import numpy as np
import scipy.stats as sst

__all__ = ["WhitenessError", "autocorrelation", "ljung_box"]


class WhitenessError(ValueError):
    """Input to a whiteness statistic is invalid; the message says how to fix it."""


def autocorrelation(r: np.ndarray, max_lag: int) -> np.ndarray:
    """Sample autocorrelation ``ρ̂_k = Σ (r_t - r̄)(r_{t+k} - r̄) / Σ (r_t - r̄)²``.

    Parameters
    ----------
    r : ndarray, shape (T,)
        Series (e.g. residuals), any units.
    max_lag : int
        Largest lag in samples, ``1 <= max_lag < T``.

    Returns
    -------
    ndarray, shape (max_lag + 1,)
        ``ρ̂_0 = 1, ρ̂_1, ..., ρ̂_max_lag`` (the biased estimator of Box & Jenkins);
        zeros beyond lag 0 for a constant series.

    Raises
    ------
    WhitenessError
        If ``max_lag`` is outside ``[1, T - 1]``.
    """
    r = np.asarray(r, dtype=float)
    n = r.size
    if not 1 <= max_lag < n:
        raise WhitenessError(f"max_lag must be in [1, {n - 1}], got {max_lag}")
    x = r - r.mean()
    denom = float(x @ x)
    if denom == 0.0:
        return np.concatenate(([1.0], np.zeros(max_lag)))
    # Zero padding to >= 2T - 1 makes the FFT product the linear (not circular)
    # autocovariance; O(T log T) whatever max_lag.
    nfft = 1 << (2 * n - 1).bit_length()
    f = np.fft.rfft(x, nfft)
    ac = np.fft.irfft(f * np.conj(f), nfft)[: max_lag + 1]
    return ac / denom


def ljung_box(r: np.ndarray, lags: int, *, n_params: int = 0) -> tuple[float, float]:
    """Ljung–Box portmanteau test of whiteness.

    ``Q = n (n + 2) Σ_{k=1..h} ρ̂_k² / (n - k)``, approximately χ² with ``h - n_params``
    degrees of freedom for a white series (Ljung & Box 1978).

    Parameters
    ----------
    r : ndarray, shape (T,)
        Series, any units.
    lags : int
        Number of lags ``h`` (samples), ``1 <= h < T``.
    n_params : int
        Fitted ARMA parameters to subtract from the degrees of freedom.

    Returns
    -------
    q : float
        The statistic (dimensionless).
    p_value : float
        ``P(χ²_{h - n_params} > Q)``; small values reject whiteness.

    Raises
    ------
    WhitenessError
        If ``lags - n_params < 1`` or ``lags`` is outside ``[1, T - 1]``.
    """
    r = np.asarray(r, dtype=float)
    n = r.size
    dof = lags - n_params
    if dof < 1:
        raise WhitenessError(f"lags ({lags}) must exceed n_params ({n_params})")
    rho = autocorrelation(r, lags)[1:]
    k = np.arange(1, lags + 1)
    q = float(n * (n + 2) * np.sum(rho**2 / (n - k)))
    return q, float(sst.chi2.sf(q, dof))
