"""Ranking models by log evidence: the tie rule and posterior model probabilities.

Pure functions of the log evidences and their Monte-Carlo errors, shared by the
baseline ranking (:func:`bayesbeam.comparison.compare.compare_scores`) and the re-ranking under
changed priors (:mod:`bayesbeam.comparison.sensitivity`); the rules are set out in
:mod:`bayesbeam.comparison.compare`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.special import logsumexp

__all__ = ["DEFAULT_THRESHOLD"]

#: Default tie threshold on |Δ log Z| in nats (Kass & Raftery 1995: B < e is "not
#: worth more than a bare mention").
DEFAULT_THRESHOLD = 1.0


def _tie_band(err_a: float, err_b: float, threshold: float) -> float:
    """Largest |Δ log Z| counted as a tie: max(2 sqrt(err_a² + err_b²), threshold)."""
    comb = 2.0 * math.hypot(err_a, err_b) if math.isfinite(err_a + err_b) else math.inf
    return max(comb, threshold)


def _rank(
    log_z: np.ndarray, err: np.ndarray, threshold: float, names: Sequence[str]
) -> tuple[str | None, tuple[str, ...], np.ndarray, np.ndarray]:
    """Best model, models tied with it (best first), Δ to best and its combined error."""
    ok = np.isfinite(log_z)
    delta = np.full(log_z.shape, math.nan)
    derr = np.full(log_z.shape, math.nan)
    if not np.any(ok):
        return None, (), delta, derr
    ib = int(np.nanargmax(np.where(ok, log_z, -np.inf)))
    e = np.where(np.isfinite(err), err, math.inf)
    delta[ok] = log_z[ok] - log_z[ib]
    derr[ok] = np.where(np.arange(log_z.size)[ok] == ib, 0.0, np.hypot(e[ok], e[ib]))
    tied = [names[ib]] + [
        names[i] for i in np.argsort(-np.where(ok, log_z, -np.inf))
        if ok[i] and i != ib and abs(delta[i]) <= _tie_band(e[i], e[ib], threshold)
    ]
    return names[ib], tuple(tied), delta, derr


def _probabilities(
    log_z: np.ndarray, err: np.ndarray, prior: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior model probabilities and their first-order (delta-method) errors.

    ``P_k = π_k Z_k / Σ_j π_j Z_j``; ``∂P_k/∂log Z_j = P_k (δ_kj - P_j)``, so
    ``sd(P_k)² = Σ_j P_k² (δ_kj - P_j)² err_j²`` with independent evidence errors.
    """
    p = np.full(log_z.shape, math.nan)
    sd = np.full(log_z.shape, math.nan)
    ok = np.isfinite(log_z) & (prior > 0)
    if not np.any(ok):
        return p, sd
    a = log_z[ok] + np.log(prior[ok])
    pk = np.exp(a - logsumexp(a))
    e = np.where(np.isfinite(err[ok]), err[ok], 0.0)
    jac = pk[:, None] * (np.eye(pk.size) - pk[None, :])
    p[ok] = pk
    sd[ok] = np.sqrt((jac**2) @ (e**2))
    p[np.isfinite(log_z) & (prior == 0)] = 0.0
    return p, sd


def _kass_raftery(log_b: float) -> str:
    """Verbal scale of Kass & Raftery (1995, §3.2) for a Bayes factor ``exp(log_b)``."""
    two = 2.0 * log_b
    if two < 2:
        return "not worth more than a bare mention"
    if two < 6:
        return "positive"
    if two < 10:
        return "strong"
    return "very strong"

