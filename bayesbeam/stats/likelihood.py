"""Gaussian noise models for residuals ``r = data - model``, batched over parameter sets.

Shapes: residuals ``r`` have shape ``(..., T)`` (typically ``(B, T)``: B parameter
sets, T samples); ``sigma`` and ``rho`` broadcast against ``r.shape[:-1]``. Results
have shape ``r.shape[:-1]`` (log-likelihoods) or ``r.shape`` (pointwise terms).

Support: ``sigma <= 0`` or ``|rho| >= 1`` lie outside the parameter space, and the
log-likelihood there is ``-inf`` (density zero), so a sampler simply rejects them.
NaN/inf in ``r``, ``sigma`` or ``rho`` raise :class:`LikelihoodError`: an invalid
forward-model run must be masked by the caller (``Forward.simulate``'s ``valid``),
never turned into a number silently.

AR(1) parameterisation (physics.md §3: measured residuals are autocorrelated, and an
i.i.d. likelihood then overstates the evidence). ``sigma`` is the MARGINAL standard
deviation of each residual and ``rho`` the lag-one correlation, so the covariance is
``sigma^2 rho^|i-j|`` and the stationary process has

* ``r_1 ~ N(0, sigma^2)``,
* ``r_t | r_{t-1} ~ N(rho r_{t-1}, sigma^2 (1 - rho^2))``, i.e. innovations
  ``e_t = r_t - rho r_{t-1}`` with standard deviation ``sigma sqrt(1 - rho^2)``.

The log-likelihood is exact (first term stationary, the rest conditional); with this
parameterisation ``sigma`` keeps its meaning (size of the residuals) whatever rho is,
which makes priors on sigma independent of rho.

Non-uniform time stamps: the AR(1) is taken as the sampled Ornstein–Uhlenbeck
process with covariance ``sigma^2 rho^(|t_i - t_j| / dt_ref)``, i.e. the lag
correlation between samples ``dt`` apart is ``rho^(dt / dt_ref)``; ``rho`` is the
correlation at lag ``dt_ref`` (default: the median step). This needs ``0 <= rho < 1``
(a negative rho has no continuous-time meaning); outside it the log-likelihood is
``-inf``. For uniform steps equal to ``dt_ref`` it is the discrete AR(1) above.

Pointwise terms for LOO/WAIC on time series: ``ar1_pointwise`` returns the marginal
log density of the first sample and the CONDITIONAL log densities
``log p(r_t | r_{t-1})`` of the others; they sum to the joint log-likelihood. PSIS-LOO
or WAIC on them measure one-step-ahead predictive accuracy given the previous
residual, not leave-one-out of the joint density (leaving one sample out of a
correlated series would also change its neighbours' terms).

Sampling: :func:`stationary_ar1` draws this AR(1) process (synthetic noise, replicated
data of posterior-predictive checks), with the same lag correlations as the likelihood.
"""

from __future__ import annotations

import numpy as np
import scipy.signal as sps

from bayesbeam._util import compiled_kernel
from bayesbeam.stats.likelihood_kernel import _ar1_sum_py

__all__ = [
    "LikelihoodError",
    "ar1_loglik",
    "ar1_pointwise",
    "standardized_innovations",
    "iid_loglik",
    "iid_pointwise",
    "stationary_ar1",
]

_LOG_2PI = float(np.log(2.0 * np.pi))


class LikelihoodError(ValueError):
    """Invalid input to a likelihood (shape mismatch or NaN); says how to fix it."""


def _prepare(r: np.ndarray, **params: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    r = np.asarray(r, dtype=float)
    if r.ndim < 1 or r.shape[-1] < 1:
        raise LikelihoodError(f"residuals must have shape (..., T) with T >= 1, got {r.shape}")
    batch = r.shape[:-1]
    out = []
    for name, p in params.items():
        p = np.asarray(p, dtype=float)
        try:
            p = np.broadcast_to(p, np.broadcast_shapes(p.shape, batch))
        except ValueError:
            raise LikelihoodError(
                f"{name} of shape {p.shape} does not broadcast against the batch shape "
                f"{batch} of residuals {r.shape}"
            ) from None
        if not np.all(np.isfinite(p)):
            raise LikelihoodError(f"{name} contains NaN/inf; pass finite parameter values")
        out.append(p)
    if not np.all(np.isfinite(r)):
        rows = np.argwhere(~np.all(np.isfinite(r), axis=-1)) if r.ndim > 1 else []
        raise LikelihoodError(
            "residuals contain NaN/inf"
            + (f" in batch rows {[tuple(x) for x in rows[:5]]}" if len(rows) else "")
            + "; drop invalid forward-model runs (the valid mask of Forward.simulate) "
            "before evaluating the likelihood"
        )
    return r, out


def iid_pointwise(r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Pointwise i.i.d. Gaussian log densities ``log N(r_t; 0, sigma^2)``.

    Parameters
    ----------
    r : ndarray, shape (..., T)
        Residuals (data - model), in the units of the signal.
    sigma : float or ndarray, broadcastable to r.shape[:-1]
        Noise standard deviation, same units as ``r``.

    Returns
    -------
    ndarray, shape (..., T)
        Log densities; ``-inf`` where ``sigma <= 0``.
    """
    r, (s,) = _prepare(r, sigma=sigma)
    s = s[..., None]
    ok = s > 0
    safe = np.where(ok, s, 1.0)
    lp = -0.5 * _LOG_2PI - np.log(safe) - 0.5 * (r / safe) ** 2
    return np.where(ok, lp, -np.inf)


def iid_loglik(r: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """I.i.d. Gaussian log-likelihood ``sum_t log N(r_t; 0, sigma^2)``.

    Parameters
    ----------
    r : ndarray, shape (..., T)
        Residuals (data - model).
    sigma : float or ndarray, broadcastable to r.shape[:-1]
        Noise standard deviation, same units as ``r``.

    Returns
    -------
    ndarray, shape r.shape[:-1]
        Log-likelihoods; ``-inf`` where ``sigma <= 0``.
    """
    r, (s,) = _prepare(r, sigma=sigma)
    T = r.shape[-1]
    ok = s > 0
    safe = np.where(ok, s, 1.0)
    ll = -0.5 * T * _LOG_2PI - T * np.log(safe) - 0.5 * np.sum(r**2, axis=-1) / safe**2
    return np.where(ok, ll, -np.inf)


def _lag_table(
    rho: np.ndarray, times: np.ndarray | None, dt_ref: float | None, T: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """Lag correlations and innovation variance factors per distinct time step.

    Returns phi (..., K), one_minus_phi2 (..., K), the index (T-1,) of each step's
    entry (None for uniform stamps: K = 1), the count of each distinct step (K,) and
    the support mask (...). A record with a few gaps has a few distinct steps: the
    powers are taken once per step value, not once per sample.
    """
    rho = rho[..., None]
    if times is None:
        ok = np.abs(rho[..., 0]) < 1
        # (1 - rho)(1 + rho) keeps precision as |rho| -> 1.
        return rho, (1.0 - rho) * (1.0 + rho), None, np.array([max(T - 1, 0)]), ok
    t = np.asarray(times, dtype=float)
    if t.shape != (T,):
        raise LikelihoodError(f"times must have shape ({T},) like the series, got {t.shape}")
    steps = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(steps <= 0):
        raise LikelihoodError("times must be finite and strictly increasing (s)")
    ref = float(np.median(steps)) if dt_ref is None else float(dt_ref)
    if not (np.isfinite(ref) and ref > 0):
        raise LikelihoodError(f"dt_ref must be a positive time step in s, got {dt_ref!r}")
    ok = (rho[..., 0] >= 0) & (rho[..., 0] < 1)
    safe = np.where((rho >= 0) & (rho < 1), rho, 0.5)
    u, index, counts = np.unique(steps, return_inverse=True, return_counts=True)
    with np.errstate(divide="ignore"):  # log(0) = -inf gives phi = 0 exactly, as it should
        log_phi = (u / ref) * np.log(safe)
    # 1 - phi^2 = -expm1(2 log phi): accurate when steps are short and phi is near 1.
    return np.exp(log_phi), -np.expm1(2.0 * log_phi), index, counts, ok


def _lag_powers(
    rho: np.ndarray, times: np.ndarray | None, dt_ref: float | None, T: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-step correlations phi_t and innovation variance factors 1 - phi_t^2.

    Returns phi (..., T-1), one_minus_phi2 (..., T-1) and the support mask (...).
    """
    phi, vf, index, _, ok = _lag_table(rho, times, dt_ref, T)
    if index is None:
        shape = (*phi.shape[:-1], T - 1)
        return np.broadcast_to(phi, shape), np.broadcast_to(vf, shape), ok
    return phi[..., index], vf[..., index], ok


def ar1_pointwise(
    r: np.ndarray,
    sigma: np.ndarray,
    rho: np.ndarray,
    *,
    times: np.ndarray | None = None,
    dt_ref: float | None = None,
) -> np.ndarray:
    """Pointwise AR(1) log densities: marginal first term, conditional others.

    ``out[..., 0] = log N(r_0; 0, sigma^2)`` and, for t >= 1,
    ``out[..., t] = log N(r_t; phi_t r_{t-1}, sigma^2 (1 - phi_t^2))`` with
    ``phi_t = rho`` (uniform) or ``rho^((t_t - t_{t-1}) / dt_ref)`` (with ``times``).
    The terms are conditional on the previous sample (see the module docstring
    before using them for LOO/WAIC); they sum to :func:`ar1_loglik`.

    Parameters
    ----------
    r : ndarray, shape (..., T)
        Residuals (data - model).
    sigma : float or ndarray, broadcastable to r.shape[:-1]
        Marginal standard deviation of the residuals, same units as ``r``.
    rho : float or ndarray, broadcastable to r.shape[:-1]
        Lag-one correlation (at lag ``dt_ref`` when ``times`` are given).
    times : ndarray, shape (T,), optional
        Sample times in s, for non-uniform stamps.
    dt_ref : float, optional
        Reference lag in s for ``rho`` (default: median step of ``times``).

    Returns
    -------
    ndarray, shape (..., T)
        Log densities; ``-inf`` outside the support (``sigma <= 0``, ``|rho| >= 1``,
        or ``rho < 0`` with ``times``).
    """
    r, (s, p) = _prepare(r, sigma=sigma, rho=rho)
    T = r.shape[-1]
    s, p = np.broadcast_arrays(s, p)
    phi, var_factor, ok_rho = _lag_powers(p, times, dt_ref, T)
    ok = (s > 0) & ok_rho
    ss = np.where(ok, s, 1.0)[..., None]
    vf = np.where(ok[..., None], var_factor, 1.0)
    ph = np.where(ok[..., None], phi, 0.0)
    out = np.empty(np.broadcast_shapes(r.shape, (*ok.shape, T)))
    out[..., 0] = -0.5 * _LOG_2PI - np.log(ss[..., 0]) - 0.5 * (r[..., 0] / ss[..., 0]) ** 2
    if T > 1:
        e = r[..., 1:] - ph * r[..., :-1]  # innovations
        var = ss**2 * vf
        out[..., 1:] = -0.5 * (_LOG_2PI + np.log(var)) - 0.5 * e**2 / var
    return np.where(ok[..., None], out, -np.inf)


def standardized_innovations(
    r: np.ndarray, sigma: float, rho: float | None = None, *,
    times: np.ndarray | None = None, dt_ref: float | None = None,
) -> np.ndarray:
    """Residuals turned into the i.i.d. N(0, 1) series the likelihood assumes.

    i.i.d. noise: ``r / sigma``. AR(1): the first term ``r_0 / sigma`` and the one-step
    prediction errors ``(r_t - phi_t r_{t-1}) / (sigma sqrt(1 - phi_t^2))``, the terms of
    :func:`ar1_pointwise`. Under a correct model these are white with unit variance;
    whiteness tests (:mod:`bayesbeam.stats.whiteness`) are applied to them.

    Parameters
    ----------
    r : ndarray, shape (T,)
        Residuals (data - model).
    sigma : float
        Marginal noise standard deviation, units of ``r``.
    rho : float, optional
        Lag-one correlation of AR(1) noise; None for i.i.d. noise.
    times, dt_ref : optional
        As for :func:`ar1_pointwise` (non-uniform stamps).

    Returns
    -------
    ndarray, shape (T,)
    """
    r = np.asarray(r, dtype=float)
    if r.ndim != 1 or not (np.isfinite(sigma) and sigma > 0):
        raise LikelihoodError(
            f"need a 1-D residual series and sigma > 0, got shape {r.shape} and sigma={sigma!r}"
        )
    if rho is None:
        return r / sigma
    phi, vf, ok = _lag_powers(np.asarray(float(rho)), times, dt_ref, r.size)
    if not bool(ok):
        raise LikelihoodError(f"rho = {rho!r} is outside the AR(1) support")
    out = np.empty_like(r)
    out[0] = r[0] / sigma
    out[1:] = (r[1:] - phi * r[:-1]) / (sigma * np.sqrt(vf))
    return out


def ar1_loglik(
    r: np.ndarray, sigma: np.ndarray, rho: np.ndarray, *,
    times: np.ndarray | None = None, dt_ref: float | None = None,
) -> np.ndarray:
    """Exact stationary AR(1) Gaussian log-likelihood (covariance ``sigma^2 rho^|i-j|``).

    The sum over t of the terms of :func:`ar1_pointwise`.

    Parameters
    ----------
    r, sigma, times, dt_ref
        As for :func:`ar1_pointwise`: residuals (..., T), their marginal standard
        deviation, optional sample times (T,) in s and the reference lag in s.
    rho : float or ndarray, broadcastable to r.shape[:-1]
        Lag-one correlation in (-1, 1); with ``times``, the correlation at lag
        ``dt_ref`` in [0, 1) (covariance ``sigma^2 rho^(|t_i - t_j| / dt_ref)``).

    Returns
    -------
    ndarray, shape r.shape[:-1]
        Log-likelihoods; ``-inf`` outside the support.
    """
    # The sum of the pointwise terms, without them: per set one pass over the
    # innovations, and the log variance factors counted once per distinct step.
    r, (s, p) = _prepare(r, sigma=sigma, rho=rho)
    T = r.shape[-1]
    s, p = np.broadcast_arrays(s, p)
    phi, vf, index, counts, ok_rho = _lag_table(p, times, dt_ref, T)
    ok = (s > 0) & ok_rho
    ss = np.where(ok, s, 1.0)
    phi = np.where(ok[..., None], phi, 0.0)
    vf = np.where(ok[..., None], vf, 1.0)
    ll = -0.5 * T * _LOG_2PI - T * np.log(ss) - 0.5 * (r[..., 0] / ss) ** 2
    if T > 1:
        kernel = compiled_kernel(_ar1_sum_py, ("contract", "reassoc"))
        if kernel is not None:  # one pass (bayesbeam.stats.likelihood_kernel)
            K = phi.shape[-1]
            idx = np.zeros(T - 1, np.int64) if index is None else index.astype(np.int64)
            rb = np.broadcast_to(r, (*ok.shape, T))  # sigma, rho may widen the batch
            q = kernel(np.ascontiguousarray(rb.reshape(-1, T)),
                       np.ascontiguousarray(phi.reshape(-1, K)),
                       np.ascontiguousarray((1.0 / vf).reshape(-1, K)), idx)
            q = q.reshape(ok.shape)
        elif index is None:
            e = r[..., 1:] - phi * r[..., :-1]
            q = np.sum(e * e, axis=-1) / vf[..., 0]
        else:
            e = r[..., 1:] - phi[..., index] * r[..., :-1]
            q = np.sum(e * e * (1.0 / vf)[..., index], axis=-1)
        ll = ll - 0.5 * np.sum(counts * np.log(vf), axis=-1) - 0.5 * q / ss**2
    return np.where(ok, ll, -np.inf)


def stationary_ar1(
    z: np.ndarray,
    rho: float | np.ndarray,
    *,
    times: np.ndarray | None = None,
    dt_ref: float | None = None,
    sd: float = 1.0,
) -> np.ndarray:
    """Stationary AR(1) series from standard normal draws: the noise model, sampled.

    ``e_0 = sd z_0`` and ``e_t = phi_t e_{t-1} + sd sqrt(1 - phi_t²) z_t`` for t >= 1,
    with ``phi_t`` the lag correlation of :func:`ar1_pointwise` (``rho`` on uniform
    stamps, ``rho^((t_t - t_{t-1}) / dt_ref)`` with ``times``): every ``e_t`` has
    standard deviation ``sd`` and ``corr(e_i, e_j) = rho^|i-j|`` (uniform stamps): the
    process that :func:`ar1_loglik` scores. With one correlation for every step the
    recursion is the linear filter ``1 / (1 - phi B)`` (B the lag operator) and runs in
    :func:`scipy.signal.lfilter` (the same products and sums as the loop, so the same
    bits); otherwise it is stepped in time, vectorised over the series.

    Parameters
    ----------
    z : array_like, shape (..., T)
        Independent standard normal draws (from the caller's seeded Generator).
    rho : float or array_like, broadcastable to z.shape[:-1]
        Lag-one correlation of each series, in (-1, 1); with ``times``, the correlation
        at lag ``dt_ref``, in [0, 1).
    times : array_like, shape (T,), optional
        Sample times in s, for non-uniform stamps.
    dt_ref : float, optional
        Reference lag in s for ``rho`` (default: median step of ``times``).
    sd : float
        Marginal standard deviation, units of the series.

    Returns
    -------
    ndarray, shape z.shape
        The series, units of ``sd``.

    Raises
    ------
    LikelihoodError
        For ``rho`` outside its range, ``sd <= 0``, or ``rho`` / ``times`` whose shapes
        do not match ``z``.
    """
    z = np.asarray(z, dtype=float)
    if z.ndim < 1:
        raise LikelihoodError(f"z must have shape (..., T), got {z.shape}")
    sd = float(sd)
    if not (np.isfinite(sd) and sd > 0):
        raise LikelihoodError(f"sd must be a positive marginal standard deviation, got {sd!r}")
    rho = np.asarray(rho, dtype=float)
    try:
        rho = np.broadcast_to(rho, z.shape[:-1])
    except ValueError:
        raise LikelihoodError(
            f"rho of shape {rho.shape} does not broadcast against the batch shape "
            f"{z.shape[:-1]} of draws {z.shape}"
        ) from None
    T = z.shape[-1]
    e = np.empty(z.shape)
    if T == 0:
        return e
    phi, _, ok = _lag_powers(rho, times, dt_ref, T)
    if not np.all(ok):  # NaN fails the comparisons too
        support = "[0, 1) with times" if times is not None else "(-1, 1)"
        raise LikelihoodError(f"rho must lie in {support} for a stationary AR(1)")
    # Innovations: the stationary start, then sd sqrt(1 - phi²) per step (so every
    # sample has variance sd²).
    x = np.empty(z.shape)
    x[..., 0] = sd * z[..., 0]
    x[..., 1:] = (sd * np.sqrt(1 - phi**2)) * z[..., 1:]
    if times is None:
        for i in np.ndindex(z.shape[:-1]):  # one filter per series (rho may differ)
            e[i] = sps.lfilter([1.0], [1.0, -rho[i]], x[i])
        return e
    e[..., 0] = x[..., 0]
    for t in range(1, T):  # time-varying phi: sequential, vectorised over the series
        e[..., t] = phi[..., t - 1] * e[..., t - 1] + x[..., t]
    return e
