"""Convergence diagnostics and the stopping rule of :func:`bayesbeam.stats.sampling.run_emcee`.

A run stops after a check when all of these hold, on the chain after its burn-in:

1. the kept chain is at least ``n_tau`` integrated autocorrelation times long,
   ``n_kept >= n_tau * max(tau)`` (emcee's recommendation; ``tau`` from
   :func:`emcee.autocorr.integrated_time`, Sokal's windowing);
2. every ``tau`` changed by less than ``tau_rtol`` (relative) since the previous
   check, i.e. the estimate itself has settled;
3. the bulk effective sample size (ArviZ, rank-normalised; Vehtari et al. 2021) of
   every parameter is at least ``target_ess``;
4. at least ``min_steps`` steps were taken.

Burn-in is the first ``ceil(burn_in_taus * max(tau_all))`` steps, capped at half the
chain, with ``tau_all`` estimated on every step. The criteria then use ``tau`` of the
kept part (:func:`kept_tau`): the walkers start in a small ball around the MAP and
spread over the posterior first, and where it has flat directions (a damping law's
coefficient on a plateau down to its prior bound) that spreading is a transient
hundreds of steps long which the whole-chain estimate counts as autocorrelation. On a
whole measured record (Al 50 cm #0, 2000 steps) the whole-chain τ was 2000–2800 steps
while the kept half had τ of 31–47 and bulk ESS 1474–2235 for every parameter. A
transient still inside the kept part shows as a large or unsettled τ there, and the
run goes on. R-hat is the rank-normalised split R-hat with each walker taken as a chain;
ensemble walkers are not independent chains, so it is a consistency check between
walkers and is reported, not used for stopping.

Nothing here touches the sampler or files: every function maps a chain array
``(n, nwalkers, ndim)`` and the criteria to numbers, so the rule can be tested
and reused on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import emcee
import numpy as np

__all__ = [
    "Check",
    "autocorr_time",
    "burn_in",
    "check_convergence",
    "ess_rhat",
    "failed_criteria",
    "kept_tau",
]


def autocorr_time(chain: np.ndarray, n_tau: float) -> tuple[np.ndarray, bool]:
    """Integrated autocorrelation time per parameter and whether it is trustworthy.

    emcee raises :class:`emcee.autocorr.AutocorrError` when the chain is shorter than
    ``n_tau`` τ; that is the normal state early in a run, so it is caught here and
    reported as ``long_enough=False`` with the (provisional) estimate.

    Parameters
    ----------
    chain : numpy.ndarray, shape (n, nwalkers, ndim)
        Ensemble chain, every step.
    n_tau : float
        Required chain length in autocorrelation times.

    Returns
    -------
    tau : numpy.ndarray, shape (ndim,)
        τ in steps; ``inf`` where it could not be estimated.
    long_enough : bool
        Whether the chain is at least ``n_tau`` τ long and every τ is finite.
    """
    if chain.shape[0] < 2:
        return np.full(chain.shape[2], np.inf), False
    # A parameter whose trace is constant in a walker (a walker that never moved
    # during the chain) makes emcee's normalised autocorrelation 0/0; that τ is
    # genuinely unknown, so the NaN is mapped to inf below instead of warned about.
    with np.errstate(invalid="ignore", divide="ignore"):
        try:
            tau = emcee.autocorr.integrated_time(chain, c=5, tol=n_tau, quiet=False)
            long_enough = True
        except emcee.autocorr.AutocorrError as exc:
            tau = np.asarray(exc.tau, dtype=float)
            long_enough = False
    tau = np.where(np.isfinite(tau), tau, np.inf)
    if not np.all(np.isfinite(tau)):
        long_enough = False
    return tau, long_enough


def burn_in(tau: np.ndarray, n: int, burn_in_taus: float) -> int:
    """Return the burn-in: ``ceil(burn_in_taus * max(tau))`` steps, at most half the chain.

    Parameters
    ----------
    tau : numpy.ndarray, shape (ndim,)
        Integrated autocorrelation times (steps); an infinite τ discards half.
    n : int
        Chain length (steps).
    burn_in_taus : float
        Burn-in in units of the largest τ.

    Returns
    -------
    int
    """
    tmax = float(np.max(tau))
    b = n // 2 if not math.isfinite(tmax) else math.ceil(burn_in_taus * tmax)
    return int(min(b, n // 2))


def ess_rhat(kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bulk ESS and rank-normalised split R-hat, walkers as chains.

    Parameters
    ----------
    kept : numpy.ndarray, shape (n, nwalkers, ndim)
        Post-burn-in chain.

    Returns
    -------
    ess : numpy.ndarray, shape (ndim,)
        Bulk effective sample size; ``0`` where undefined or ``n < 4``.
    rhat : numpy.ndarray, shape (ndim,)
        Split R-hat; ``inf`` where undefined or ``n < 4``.
    """
    ndim = kept.shape[2]
    if kept.shape[0] < 4:  # split R-hat needs >= 2 draws per half-chain
        return np.zeros(ndim), np.full(ndim, np.inf)
    import arviz  # deferred: importing ArviZ takes ~2 s

    x = np.ascontiguousarray(np.swapaxes(kept, 0, 1))  # (chain=walker, draw, ndim)
    ess = np.asarray(arviz.ess(x, chain_axis=0, draw_axis=1, method="bulk"), dtype=float)
    rhat = np.asarray(arviz.rhat(x, chain_axis=0, draw_axis=1, method="rank"), dtype=float)
    return np.where(np.isfinite(ess), ess, 0.0), np.where(np.isfinite(rhat), rhat, np.inf)


@dataclass(frozen=True)
class Check:
    """Outcome of one convergence check after ``n`` steps.

    Attributes
    ----------
    n : int
        Steps in the chain at the check.
    tau : numpy.ndarray, shape (ndim,)
        Integrated autocorrelation times (steps) of the kept chain.
    long_enough : bool
        Criterion 1: the kept chain is at least ``n_tau`` τ long.
    stable : bool
        Criterion 2: τ settled since the previous check.
    burn_in : int
        Steps to discard.
    ess, rhat : numpy.ndarray, shape (ndim,)
        Bulk ESS and split R-hat after burn-in; NaN where not computed.
    converged : bool
        Whether all criteria hold.
    """

    n: int
    tau: np.ndarray
    long_enough: bool
    stable: bool
    burn_in: int
    ess: np.ndarray
    rhat: np.ndarray
    converged: bool


def kept_tau(chain: np.ndarray, n_tau: float,
             burn_in_taus: float) -> tuple[np.ndarray, bool, int]:
    """τ of the chain after its burn-in, whether it is long enough, and the burn-in.

    The burn-in comes from τ on every step (:func:`burn_in`: ``burn_in_taus`` of its
    largest, at most half the chain); τ is then estimated again on the kept steps,
    without the start's transient (module notes).

    Parameters
    ----------
    chain : numpy.ndarray, shape (n, nwalkers, ndim)
        Every step so far.
    n_tau : float
        Required kept length in autocorrelation times.
    burn_in_taus : float

    Returns
    -------
    tau : numpy.ndarray, shape (ndim,)
        τ of the kept steps; ``inf`` where it could not be estimated.
    long_enough : bool
        Whether the kept steps are at least ``n_tau`` τ long.
    burn_in : int
    """
    tau_all, _ = autocorr_time(chain, n_tau)
    b = burn_in(tau_all, chain.shape[0], burn_in_taus)
    tau, long_enough = autocorr_time(chain[b:], n_tau)
    return tau, long_enough, b


def check_convergence(
    chain: np.ndarray,
    prev_tau: np.ndarray | None,
    *,
    n_tau: float,
    tau_rtol: float,
    burn_in_taus: float,
    min_steps: int,
    max_steps: int,
    target_ess: float,
) -> Check:
    """Apply the stopping rule (see the module notes) to ``chain``.

    Parameters
    ----------
    chain : numpy.ndarray, shape (n, nwalkers, ndim)
        Every step so far.
    prev_tau : numpy.ndarray or None
        τ at the previous check; ``None`` if there was none (τ is then not stable).
    n_tau, tau_rtol, burn_in_taus, min_steps, target_ess
        The criteria (see :func:`bayesbeam.stats.sampling.run_emcee`).
    max_steps : int
        Step budget; at it, ESS and R-hat are computed even if the rule already failed.

    Returns
    -------
    Check
    """
    n, ndim = chain.shape[0], chain.shape[2]
    tau, long_enough, b = kept_tau(chain, n_tau, burn_in_taus)
    stable = (
        prev_tau is not None
        and bool(np.all(np.isfinite(tau)))
        and bool(np.all(np.abs(tau - prev_tau) < tau_rtol * tau))
    )
    ok = n >= min_steps and long_enough and stable
    if ok or n >= max_steps:
        ess, rhat = ess_rhat(chain[b:])
        ok = ok and bool(np.all(ess >= target_ess))
    else:
        # ESS/R-hat cost more than tau and cannot change the decision yet.
        ess, rhat = np.full(ndim, np.nan), np.full(ndim, np.nan)
    return Check(n, tau, long_enough, stable, b, ess, rhat, ok)


def failed_criteria(
    check: Check, *, n_tau: float, tau_rtol: float, target_ess: float, min_steps: int
) -> list[str]:
    """Human-readable reasons why ``check`` did not converge.

    Parameters
    ----------
    check : Check
        A check with ``converged=False``.
    n_tau, tau_rtol, target_ess, min_steps
        The criteria it was made with.

    Returns
    -------
    list of str
    """
    reasons = []
    if not check.long_enough:
        reasons.append(
            f"chain length after burn-in {check.n - check.burn_in} < {n_tau:g} tau_max = "
            f"{n_tau * np.max(check.tau):.0f}"
        )
    if not check.stable:
        reasons.append(f"tau not stable to {tau_rtol:g} between checks")
    if np.any(check.ess < target_ess):
        reasons.append(f"ESS min {np.min(check.ess):.0f} < target {target_ess:g}")
    if check.n < min_steps:
        reasons.append(f"fewer than min_steps={min_steps} steps")
    return reasons
