"""Whiteness of a series: sample autocorrelation, Ljung–Box and Fisher's g tests.

* :func:`autocorrelation`: ``ρ̂_k = Σ_t (r_t - r̄)(r_{t+k} - r̄) / Σ_t (r_t - r̄)²``, the
  biased estimator of Box & Jenkins, by FFT (zero-padded, so not circular);
* :func:`ljung_box`: ``Q = n (n + 2) Σ_{k=1..h} ρ̂_k² / (n - k)``, approximately χ²
  with ``h - n_params`` degrees of freedom for a white series (Ljung & Box 1978,
  Biometrika 65, 297-303);
* :func:`fisher_g`: ``g = max_k I_k / Σ_k I_k`` over the periodogram ordinates at the
  Fourier frequencies strictly between 0 and Nyquist, with Fisher's exact null
  distribution for Gaussian white noise (Fisher 1929, Proc. R. Soc. Lond. A 125, 54-59):
  a test for one hidden periodic component (a spectral line) of unknown frequency.

Lags count samples; for non-uniform time stamps they are lags in sample order.
Invalid input raises :class:`WhitenessError`.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.stats as sst

__all__ = ["WhitenessError", "autocorrelation", "fisher_g", "ljung_box"]


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


#: Largest estimated round-off (absolute, on p) accepted from Fisher's alternating sum;
#: beyond it :func:`_fisher_sf` returns the first-term (Bonferroni) bound clipped to 1.
_FISHER_SUM_TOL = 1e-6


def _fisher_sf(x: float, m: int) -> float:
    """Fisher's exact ``P(g > x)`` for ``m`` i.i.d. exponential periodogram ordinates.

    ``P(g > x) = Σ_{j=1}^{⌊1/x⌋} (-1)^{j-1} C(m, j) (1 - j x)^{m-1}`` (Fisher 1929).

    Parameters
    ----------
    x : float
        Value of the statistic, in ``[0, 1]``.
    m : int
        Number of ordinates, ``>= 1``.

    Returns
    -------
    float
        The tail probability, in ``[0, 1]``.

    Notes
    -----
    The terms ``t_j`` are formed in log space (``log C(m, j)`` as a running sum of
    ``log((m - i + 1) / i)``, and ``log1p``), so none overflows or underflows before it
    is negligible, and summed with :func:`math.fsum`. Since ``1 - j x <= (1 - x)^j``,
    ``|t_j| <= t_1^j / j!`` with ``t_1 = m (1 - x)^{m-1}``: for ``t_1 <= 1`` (every p
    below about 0.6) the series has no cancellation and the sum is accurate to a few
    units of round-off *relative to p*, down to the underflow of ``t_1`` (p < 1e-308
    returns 0). For large ``t_1`` the terms grow like ``e^{t_1}`` and cancel; each
    term's round-off is estimated from the size of its logarithm and, when the total
    exceeds :data:`_FISHER_SUM_TOL` (1e-6), the first-term Bonferroni bound
    ``min(1, t_1) = 1`` is returned instead. That happens only far in the upper tail
    (``t_1`` above about 13): against exact rational arithmetic for ``m`` = 10 to 5000
    the result is within 1e-14 relative for p < 0.6 and within 3e-10 absolute
    everywhere.
    """
    if m <= 1 or x <= 1.0 / m:
        # g >= 1/m always (the largest of m ordinates is at least their mean), with
        # equality only on a set of probability zero; one ordinate makes g = 1.
        return 1.0 if x < 1.0 else 0.0
    if x >= 1.0:
        return 0.0
    j = np.arange(1, min(int(math.floor(1.0 / x)), m) + 1, dtype=float)
    j = j[1.0 - j * x > 0.0]  # j x = 1 exactly gives a zero term (and log 0)
    # log C(m, j) as a running sum of log((m - j + 1) / j): exact to ~j eps log m, where
    # lgamma or log-beta differences lose ~eps m log m (1e-10 at m = 1e5).
    log_c = np.cumsum(np.log((m - j + 1.0) / j))
    log_p = (m - 1.0) * np.log1p(-j * x)
    log_t = log_c + log_p
    t = np.exp(np.minimum(log_t, 700.0))
    signs = np.where(j % 2 == 1, 1.0, -1.0)
    total = math.fsum((signs * t).tolist())
    # The relative round-off of t_j = exp(log t_j) is the absolute round-off of log t_j,
    # a few eps times the size of its parts.
    eps = float(np.finfo(float).eps)
    err = float(np.sum(t * 4.0 * eps * (1.0 + j * math.log(m) + np.abs(log_p))))
    if err > _FISHER_SUM_TOL or log_t.max() >= 700.0:
        return min(1.0, float(t[0]))
    return float(min(max(total, 0.0), 1.0))


def fisher_g(r: np.ndarray, *, exclude_zero: bool = True) -> tuple[float, float, int]:
    """Fisher's g test for a hidden periodic component (one spectral line).

    The periodogram ``I_k = |Σ_t (r_t - r̄) e^{-2πi k t / n}|² / n`` at the Fourier
    frequencies ``k = 1, ..., m``, ``m = ⌊(n - 1)/2⌋`` (zero and, for even ``n``, the
    Nyquist frequency excluded: their ordinates have one degree of freedom, not two),
    gives ``g = max_k I_k / Σ_k I_k``. For Gaussian white noise the ``I_k`` are i.i.d.
    exponential and ``P(g > x) = Σ_{j=1}^{⌊1/x⌋} (-1)^{j-1} C(m, j) (1 - j x)^{m-1}``
    exactly (Fisher 1929, Proc. R. Soc. Lond. A 125, 54-59). A sinusoid of amplitude A
    in noise of variance s² adds about ``n A² / 4`` to one ordinate against a mean of s²,
    so the test finds a line far below the noise in a long series.

    Parameters
    ----------
    r : ndarray, shape (n,)
        Uniformly sampled series (e.g. residuals or standardised innovations), any
        units, ``n >= 8``, finite. Its mean is removed here.
    exclude_zero : bool
        True (the standard test): the mean is removed and only ``k = 1..m`` compete.
        False: the mean is kept and the zero-frequency ordinate ``I_0 = n r̄²`` competes
        too (``m + 1`` ordinates; ``k_max = 0`` flags an offset). The p-value then uses
        Fisher's formula with ``m + 1`` ordinates, which is only approximate: ``I_0`` has
        one degree of freedom, a heavier tail than the others, so p is somewhat too small
        when the offset is the largest ordinate.

    Returns
    -------
    g : float
        The statistic, in ``[1/m, 1]`` (dimensionless); 0 for a constant series.
    p_value : float
        ``P(g' > g)`` for white Gaussian noise: small values reveal a periodic
        component. 1 for a constant series. Computed by the exact alternating sum in
        log space (accurate to ~1e-14 relative for p < 0.6, down to underflow at
        1e-308); where its round-off could exceed 1e-6 (only far in the upper tail,
        p > 1 - 1e-9) the first-term Bonferroni bound ``m (1 - g)^{m-1}`` clipped to
        1, i.e. 1.
    k_max : int
        Index of the largest ordinate: the line's frequency is ``k_max / (n dt)`` Hz for
        a sampling step ``dt`` s (to within half a bin, ``1 / (2 n dt)``). 0 for a
        constant series.

    Raises
    ------
    WhitenessError
        If ``r`` is not 1-D, has fewer than 8 samples or non-finite values.
    """
    r = np.asarray(r, dtype=float)
    if r.ndim != 1:
        raise WhitenessError(
            f"r must be a 1-D series, got shape {r.shape}; test one series at a time "
            "(e.g. np.ravel a single column)"
        )
    n = r.size
    if n < 8:
        raise WhitenessError(
            f"r has {n} samples; Fisher's g needs at least 8 (3 Fourier frequencies) "
            "and is useful only for much longer series"
        )
    bad = int(np.count_nonzero(~np.isfinite(r)))
    if bad:
        raise WhitenessError(
            f"r has {bad} non-finite value(s) (NaN or inf); remove or interpolate them "
            "before testing"
        )
    m = (n - 1) // 2
    x = r - r.mean() if exclude_zero else r
    spec = np.abs(np.fft.rfft(x)[: m + 1]) ** 2 / n
    first = 1 if exclude_zero else 0
    ords = spec[first:]
    total = float(ords.sum())
    if not total > 0.0:
        return 0.0, 1.0, 0
    i = int(np.argmax(ords))
    g = float(ords[i] / total)
    return g, _fisher_sf(g, ords.size), i + first
