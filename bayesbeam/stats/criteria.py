"""Information criteria: PSIS-LOO, WAIC, AIC, BIC and paired ELPD differences.

All pointwise criteria take a log-likelihood matrix ``loglik[s, i] = log p(y_i | θ_s)``
over posterior draws ``s`` and observations ``i``, either flat ``(S, N)`` or in
ArviZ order ``(chains, draws, N)``. For an emcee run with per-observation blobs
(``get_blobs()`` has shape ``(n_steps, n_walkers, N)``) pass
``np.swapaxes(blobs, 0, 1)`` so that walkers are chains.

What "pointwise" means for a time series
----------------------------------------
LOO and WAIC estimate the expected log predictive density of *new exchangeable
observations*. Samples of one decay record are not exchangeable: with white-noise
residuals ``log p(y_i | θ)`` treats each sample as conditionally independent, and
leaving one out predicts a sample whose neighbours remain in the fit, which mostly
tests interpolation and is optimistic when the residuals are autocorrelated. With
the AR(1) noise model the pointwise terms must be the *conditional* densities
``log p(y_i | y_{i-1}, θ)`` (the innovations), which do factorise the likelihood;
the first sample carries the stationary marginal. LOO then estimates one-step-ahead
predictive accuracy given the previous sample. For comparing models on how well
they predict a *new trial*, use leave-one-group-out (:func:`logo`) with one group
per trial; Pareto k is often high there (a trial carries a lot of information)
and the warning then says that exact refits would be needed.

References
----------
Watanabe (2010), J. Mach. Learn. Res. 11, 3571-3594 (WAIC).
Vehtari, Gelman & Gabry (2017), Stat. Comput. 27, 1413-1432 (LOO, WAIC, SEs, eq. 24).
Vehtari et al. (2024), J. Mach. Learn. Res. 25(72) (PSIS, Pareto-k threshold).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import logsumexp

from bayesbeam.stats.evidence import effective_sample_size

__all__ = [
    "LOO",
    "WAIC",
    "CriteriaError",
    "ParetoKWarning",
    "WAICWarning",
    "aic",
    "bic",
    "elpd_difference",
    "group_loglik",
    "logo",
    "loo",
    "waic",
]

#: Observations used to estimate the relative efficiency r_eff (evenly spaced).
_REFF_MAX_OBS = 100
#: Vehtari et al. (2017) §2.3: WAIC is unreliable when any p_waic_i exceeds 0.4.
_P_WAIC_LIMIT = 0.4


class CriteriaError(ValueError):
    """Inputs to an information criterion are invalid; the message says how to fix them."""


class ParetoKWarning(UserWarning):
    """PSIS-LOO is unreliable: some Pareto k exceed the sample-size-dependent threshold."""


class WAICWarning(UserWarning):
    """WAIC is unreliable: some pointwise p_waic exceed 0.4 (Vehtari et al. 2017)."""


@dataclass(frozen=True, eq=False)
class WAIC:
    """Widely applicable information criterion (Watanabe 2010).

    Attributes
    ----------
    elpd_waic : float
        Estimated expected log pointwise predictive density (nats).
    se : float
        Standard error of ``elpd_waic`` (nats), ``sqrt(N var_i(elpd_i))``.
    p_waic : float
        Effective number of parameters, ``Σ_i var_s log p(y_i | θ_s)``.
    waic : float
        ``-2 elpd_waic`` (deviance scale; lower is better).
    pointwise : ndarray, shape (N,)
        ``elpd_waic_i``.
    p_waic_i : ndarray, shape (N,)
        Pointwise effective number of parameters.
    n_samples : int
        Posterior draws ``S``.
    """

    elpd_waic: float
    se: float
    p_waic: float
    waic: float
    pointwise: np.ndarray
    p_waic_i: np.ndarray
    n_samples: int

    @property
    def n_points(self) -> int:
        """Number of observations ``N``."""
        return int(self.pointwise.size)

    def __str__(self) -> str:
        return (
            f"elpd_waic = {self.elpd_waic:.2f} ± {self.se:.2f}, p_waic = {self.p_waic:.2f}, "
            f"WAIC = {self.waic:.2f} (N={self.n_points}, S={self.n_samples})"
        )

    def to_dict(self) -> dict[str, Any]:
        """Return the scalar summary as a JSON-serialisable dictionary.

        Returns
        -------
        dict
            ``elpd_waic``, ``se``, ``p_waic``, ``waic``, ``n_samples``, ``n_points``.
        """
        return {
            "elpd_waic": self.elpd_waic,
            "se": self.se,
            "p_waic": self.p_waic,
            "waic": self.waic,
            "n_samples": self.n_samples,
            "n_points": self.n_points,
        }


@dataclass(frozen=True, eq=False)
class LOO:
    """Pareto-smoothed importance-sampling leave-one-out cross-validation.

    Attributes
    ----------
    elpd_loo : float
        Estimated expected log pointwise predictive density (nats).
    se : float
        Standard error of ``elpd_loo`` (nats).
    p_loo : float
        Effective number of parameters, ``lppd - elpd_loo``.
    pointwise : ndarray, shape (N,)
        ``elpd_loo_i`` (per observation, or per group for :func:`logo`).
    pareto_k : ndarray, shape (N,)
        Pareto shape estimates; values above ``good_k`` (or NaN) flag unreliable terms.
    good_k : float
        Reliability threshold ``min(1 - 1/log10(S), 0.7)`` (Vehtari et al. 2024).
    n_samples : int
        Posterior draws ``S``.
    reff : float
        Relative efficiency ``ESS/S`` used for the Pareto smoothing.
    """

    elpd_loo: float
    se: float
    p_loo: float
    pointwise: np.ndarray
    pareto_k: np.ndarray
    good_k: float
    n_samples: int
    reff: float

    @property
    def looic(self) -> float:
        """``-2 elpd_loo`` (deviance scale)."""
        return -2.0 * self.elpd_loo

    @property
    def n_points(self) -> int:
        """Number of observations (or groups) ``N``."""
        return int(self.pointwise.size)

    @property
    def n_bad_k(self) -> int:
        """Number of terms with Pareto k above ``good_k`` or NaN."""
        k = self.pareto_k
        return int(np.sum(~(k <= self.good_k)))

    def __str__(self) -> str:
        return (
            f"elpd_loo = {self.elpd_loo:.2f} ± {self.se:.2f}, p_loo = {self.p_loo:.2f} "
            f"(N={self.n_points}, S={self.n_samples}, {self.n_bad_k} Pareto k > "
            f"{self.good_k:.2f})"
        )

    def to_dict(self) -> dict[str, Any]:
        """Return the scalar summary as a JSON-serialisable dictionary.

        Returns
        -------
        dict
            ``elpd_loo``, ``se``, ``p_loo``, ``looic``, ``max_pareto_k``, ``n_bad_k``,
            ``good_k``, ``n_samples``, ``n_points``.
        """
        return {
            "elpd_loo": self.elpd_loo,
            "se": self.se,
            "p_loo": self.p_loo,
            "looic": self.looic,
            "max_pareto_k": float(np.nanmax(self.pareto_k)) if self.n_points else math.nan,
            "n_bad_k": self.n_bad_k,
            "good_k": self.good_k,
            "n_samples": self.n_samples,
            "n_points": self.n_points,
        }


# --------------------------------------------------------------------------- helpers


def _loglik_array(loglik: Any) -> np.ndarray:
    """Validate and return ``loglik`` as float array (S, N) or (chains, draws, N)."""
    ll = np.asarray(loglik, dtype=float)
    if ll.ndim not in (2, 3):
        raise CriteriaError(
            "loglik must have shape (S, N) or (chains, draws, N) with one column per "
            f"observation; got shape {ll.shape}"
        )
    if ll.shape[-1] < 1 or ll[..., 0].size < 2:
        raise CriteriaError(f"loglik needs at least 2 draws and 1 observation, got {ll.shape}")
    if np.any(np.isnan(ll)) or np.any(ll == np.inf):
        raise CriteriaError("loglik contains NaN or +inf; check the pointwise log-likelihood")
    return ll


def _flat(ll: np.ndarray) -> np.ndarray:
    return ll.reshape(-1, ll.shape[-1])


def _se_sum(pointwise: np.ndarray) -> float:
    """Return the SE of a sum of pointwise terms, ``sqrt(N var(x_i))`` (VGG17 eq. 23)."""
    n = pointwise.size
    return float(math.sqrt(n * np.var(pointwise, ddof=1))) if n > 1 else 0.0


def _relative_eff(ll: np.ndarray) -> float:
    """Mean relative efficiency of ``exp(loglik_i)`` over walkers/chains (loo::relative_eff).

    ``ll`` has shape (chains, draws, N); at most ``_REFF_MAX_OBS`` evenly spaced
    observations are used (the mean changes little and the cost stays bounded).
    """
    n_chains, n_draws, n_obs = ll.shape
    if n_draws < 8:
        return 1.0
    idx = np.unique(np.linspace(0, n_obs - 1, min(n_obs, _REFF_MAX_OBS)).astype(int))
    s = n_chains * n_draws
    reffs = []
    for i in idx:
        x = ll[:, :, i]
        if not np.all(np.isfinite(x)):
            continue
        # exp(ll) is what the importance ratios are made of; shift for overflow.
        ess = effective_sample_size(np.exp(x - x.max()).T)
        reffs.append(min(ess, s) / s)
    return float(np.mean(reffs)) if reffs else 1.0


def _arviz_loo(ll3: np.ndarray, reff: float) -> tuple[float, float, float, np.ndarray, np.ndarray]:
    """Call ArviZ PSIS-LOO; returns (elpd, se, p, elpd_i, pareto_k).

    ArviZ >= 1 (arviz_stats, DataTree) and the 0.2x series (InferenceData) are
    supported. ArviZ's own Pareto-k UserWarning is replaced by :class:`ParetoKWarning`.
    """
    import arviz as az

    major = int(str(az.__version__).split(".")[0])
    with warnings.catch_warnings():
        # Re-issued as ParetoKWarning by the caller, with the offending indices.
        warnings.filterwarnings(
            "ignore", message="Estimated shape parameter of Pareto", category=UserWarning
        )
        if major >= 1:
            data = az.from_dict(
                {
                    "posterior": {"_loglik_sum": ll3.sum(axis=-1)},
                    "log_likelihood": {"y": ll3},
                }
            )
            res = az.loo(data, pointwise=True, reff=reff)
            return (
                float(res.elpd),
                float(res.se),
                float(res.p),
                np.asarray(res.elpd_i.values, dtype=float).reshape(-1),
                np.asarray(res.pareto_k.values, dtype=float).reshape(-1),
            )
        # ArviZ 0.2x (Python 3.11 environments): InferenceData and a pandas Series result.
        idata = az.from_dict(posterior={"_loglik_sum": ll3.sum(axis=-1)}, log_likelihood={"y": ll3})
        res = az.loo(idata, pointwise=True, reff=reff)
        return (
            float(res["elpd_loo"]),
            float(res["se"]),
            float(res["p_loo"]),
            np.asarray(res["loo_i"], dtype=float).reshape(-1),
            np.asarray(res["pareto_k"], dtype=float).reshape(-1),
        )


# --------------------------------------------------------------------------- criteria


def waic(loglik: np.ndarray) -> WAIC:
    """Widely applicable information criterion, computed directly.

    ``elpd_waic = Σ_i [log mean_s p(y_i|θ_s) - var_s log p(y_i|θ_s)]`` (Watanabe 2010;
    Vehtari et al. 2017, eqs. 3, 11-12); ArviZ 1.x no longer provides it.

    Parameters
    ----------
    loglik : ndarray, shape (S, N) or (chains, draws, N)
        Pointwise log-likelihood (nats) at posterior draws.

    Returns
    -------
    WAIC
        ``elpd_waic``, ``se``, ``p_waic``, ``waic = -2 elpd_waic`` and pointwise terms.

    Warns
    -----
    WAICWarning
        If any pointwise ``p_waic_i > 0.4``; prefer :func:`loo` then.
    """
    ll = _flat(_loglik_array(loglik))
    s = ll.shape[0]
    lppd_i = logsumexp(ll, axis=0) - math.log(s)
    with np.errstate(invalid="ignore"):
        p_i = np.var(ll, axis=0, ddof=1)
    if not np.all(np.isfinite(p_i)):
        raise CriteriaError(
            "loglik has -inf entries: WAIC is undefined when a draw gives zero likelihood"
        )
    elpd_i = lppd_i - p_i
    n_bad = int(np.sum(p_i > _P_WAIC_LIMIT))
    if n_bad:
        warnings.warn(
            f"{n_bad} of {p_i.size} observations have p_waic_i > {_P_WAIC_LIMIT} (max "
            f"{p_i.max():.2f}); WAIC is unreliable here, use PSIS-LOO (criteria.loo) instead",
            WAICWarning,
            stacklevel=2,
        )
    elpd = float(elpd_i.sum())
    return WAIC(
        elpd_waic=elpd,
        se=_se_sum(elpd_i),
        p_waic=float(p_i.sum()),
        waic=-2.0 * elpd,
        pointwise=elpd_i,
        p_waic_i=p_i,
        n_samples=s,
    )


def loo(loglik: np.ndarray, *, reff: float | None = None, k_threshold: float | None = None) -> LOO:
    """PSIS-LOO cross-validation through ArviZ, with a Pareto-k warning.

    Parameters
    ----------
    loglik : ndarray, shape (S, N) or (chains, draws, N)
        Pointwise log-likelihood (nats). A 2-D array is treated as independent draws
        (``reff = 1`` unless given); a 3-D array as chains (emcee walkers) in time order.
    reff : float, optional
        Relative efficiency ``ESS/S`` in (0, 1]. By default, for 3-D input, the mean
        over (up to 100) observations of the multi-chain ESS of ``exp(loglik_i)``
        divided by ``S`` (as R's ``loo::relative_eff``).
    k_threshold : float, optional
        Warn when any Pareto k exceeds it; default ``min(1 - 1/log10(S), 0.7)``
        (Vehtari et al. 2024), which is 0.7 for ``S >= 2154``.

    Returns
    -------
    LOO
        ``elpd_loo``, ``se``, ``p_loo``, ``pointwise``, ``pareto_k`` (N,).

    Warns
    -----
    ParetoKWarning
        If any Pareto k exceeds the threshold or is NaN: those LOO terms are not
        reliable (influential observations, or a misspecified model); the message
        lists the worst indices.
    """
    ll = _loglik_array(loglik)
    ll3 = ll[None] if ll.ndim == 2 else ll
    s = ll3.shape[0] * ll3.shape[1]
    if reff is None:
        reff = 1.0 if ll.ndim == 2 else _relative_eff(ll3)
    if not 0.0 < reff <= 1.0:
        raise CriteriaError(f"reff must be in (0, 1], got {reff}")
    elpd, se, p, elpd_i, k = _arviz_loo(ll3, float(reff))
    good_k = min(1.0 - 1.0 / math.log10(s), 0.7) if k_threshold is None else float(k_threshold)
    bad = ~(k <= good_k)  # NaN counts as bad
    if np.any(bad):
        worst = np.argsort(np.where(np.isnan(k), np.inf, k))[::-1][: min(5, int(bad.sum()))]
        listing = ", ".join(f"{i}: k={k[i]:.2f}" for i in worst)
        warnings.warn(
            f"{int(bad.sum())} of {k.size} Pareto k values exceed {good_k:.2f} (worst {listing}); "
            "PSIS-LOO is unreliable for them (influential observations or model misfit). "
            "Refit without those observations (exact LOO) or use K-fold cross-validation",
            ParetoKWarning,
            stacklevel=2,
        )
    return LOO(
        elpd_loo=elpd,
        se=se,
        p_loo=p,
        pointwise=elpd_i,
        pareto_k=k,
        good_k=float(good_k),
        n_samples=int(s),
        reff=float(reff),
    )


def group_loglik(loglik: np.ndarray, groups: Any) -> tuple[np.ndarray, np.ndarray]:
    """Sum pointwise log-likelihoods within groups (e.g. one group per trial).

    Parameters
    ----------
    loglik : ndarray, shape (S, N) or (chains, draws, N)
        Pointwise log-likelihood (nats).
    groups : array_like, shape (N,)
        Group label of each observation (any hashable values).

    Returns
    -------
    grouped : ndarray, shape (S, G) or (chains, draws, G)
        ``Σ_{i in g} loglik[..., i]``: the log-likelihood of each whole group.
    labels : ndarray, shape (G,)
        Sorted unique group labels, in the column order of ``grouped``.
    """
    ll = _loglik_array(loglik)
    g = np.asarray(groups)
    if g.shape != (ll.shape[-1],):
        raise CriteriaError(
            f"groups must have one label per observation ({ll.shape[-1]}), got shape {g.shape}"
        )
    labels, inverse = np.unique(g, return_inverse=True)
    grouped = np.stack([ll[..., inverse == j].sum(axis=-1) for j in range(labels.size)], axis=-1)
    return grouped, labels


def logo(
    loglik: np.ndarray,
    groups: Any,
    *,
    reff: float | None = None,
    k_threshold: float | None = None,
) -> LOO:
    """Leave-one-group-out (e.g. leave-one-trial-out) PSIS cross-validation.

    The importance ratios for leaving group ``g`` out are ``1/p(y_g | θ)`` with the
    group's joint likelihood, so this is :func:`loo` applied to the summed
    log-likelihood of each group (Vehtari et al. 2017, §4).

    Parameters
    ----------
    loglik : ndarray, shape (S, N) or (chains, draws, N)
        Pointwise log-likelihood (nats).
    groups : array_like, shape (N,)
        Group (trial) label of each observation.
    reff, k_threshold : float, optional
        As in :func:`loo`.

    Returns
    -------
    LOO
        One pointwise term and Pareto k per group, ordered like ``np.unique(groups)``.

    Warns
    -----
    ParetoKWarning
        Frequent here: a whole trial is influential. Exact refits are then needed.
    """
    grouped, _ = group_loglik(loglik, groups)
    return loo(grouped, reff=reff, k_threshold=k_threshold)


def elpd_difference(pointwise_a: Any, pointwise_b: Any) -> tuple[float, float]:
    """Paired difference of ELPD estimates and its standard error.

    ``Δ = Σ_i (a_i - b_i)``, ``se = sqrt(N var_i(a_i - b_i))`` (Vehtari et al. 2017,
    eq. 24): pairing over the same observations cancels the variation common to
    both models, so ``se`` is much smaller than combining the two separate SEs.

    Parameters
    ----------
    pointwise_a, pointwise_b : ndarray, shape (N,), or LOO / WAIC
        Pointwise ELPD terms (nats) of models A and B on the same observations, or
        the records returned by :func:`loo` / :func:`waic`.

    Returns
    -------
    delta : float
        ``elpd_a - elpd_b`` (nats); positive favours model A.
    se : float
        Standard error of ``delta`` (nats).
    """
    a = np.asarray(getattr(pointwise_a, "pointwise", pointwise_a), dtype=float).reshape(-1)
    b = np.asarray(getattr(pointwise_b, "pointwise", pointwise_b), dtype=float).reshape(-1)
    if a.shape != b.shape or a.size < 1:
        raise CriteriaError(
            f"pointwise terms must be over the same observations; got {a.size} and {b.size}"
        )
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise CriteriaError("pointwise ELPD terms must be finite")
    d = a - b
    return float(d.sum()), _se_sum(d)


def _check_ll_k(max_loglik: float, k: int) -> tuple[float, int]:
    ll = float(max_loglik)
    if not math.isfinite(ll):
        raise CriteriaError(f"max_loglik must be finite, got {max_loglik!r}")
    if int(k) != k or k < 0:
        raise CriteriaError(f"k (number of fitted parameters) must be a non-negative int, got {k}")
    return ll, int(k)


def aic(max_loglik: float, k: int) -> float:
    """Akaike information criterion ``2k - 2 log L_max`` (Akaike 1974).

    Parameters
    ----------
    max_loglik : float
        Maximum of the log-likelihood over the parameters (nats).
    k : int
        Number of fitted parameters, nuisance parameters (noise sigma, ...) included.

    Returns
    -------
    float
        AIC (lower is better).
    """
    ll, k = _check_ll_k(max_loglik, k)
    return 2.0 * k - 2.0 * ll


def bic(max_loglik: float, k: int, n: int) -> float:
    """Bayesian (Schwarz 1978) information criterion ``k ln n - 2 log L_max``.

    For an autocorrelated record ``n`` overstates the information; BIC is then only
    indicative and the evidence (:mod:`bayesbeam.stats.evidence`) is the principled quantity.

    Parameters
    ----------
    max_loglik : float
        Maximum of the log-likelihood (nats).
    k : int
        Number of fitted parameters.
    n : int
        Number of observations (samples of all trials).

    Returns
    -------
    float
        BIC (lower is better).
    """
    ll, k = _check_ll_k(max_loglik, k)
    if int(n) != n or n < 1:
        raise CriteriaError(f"n (number of observations) must be a positive int, got {n}")
    return k * math.log(int(n)) - 2.0 * ll
