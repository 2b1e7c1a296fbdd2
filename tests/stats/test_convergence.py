"""Stopping-rule pieces of the emcee runner, on synthetic chains (no sampling)."""

from __future__ import annotations

import numpy as np

from bayesbeam.stats.convergence import (
    autocorr_time,
    burn_in,
    check_convergence,
    ess_rhat,
    failed_criteria,
    kept_tau,
)

RULE = dict(n_tau=50.0, tau_rtol=0.02, burn_in_taus=3.0, min_steps=0, target_ess=100.0)


def _white(n, nwalkers=8, ndim=2, seed=0):
    return np.random.default_rng(seed).standard_normal((n, nwalkers, ndim))


def test_burn_in_is_capped_at_half_the_chain():
    assert burn_in(np.array([1.2, 2.1]), 100, 3.0) == 7
    assert burn_in(np.array([40.0]), 100, 3.0) == 50
    assert burn_in(np.array([1.0, np.inf]), 101, 3.0) == 50


def test_short_or_frozen_chains_give_infinite_tau():
    tau, ok = autocorr_time(_white(1), 50.0)
    assert not ok and np.all(np.isinf(tau))
    frozen = _white(400)
    frozen[:, :, 1] = 1.0
    tau, ok = autocorr_time(frozen, 50.0)
    assert not ok and np.isinf(tau[1]) and np.isfinite(tau[0])
    ess, rhat = ess_rhat(_white(3))
    assert np.all(ess == 0) and np.all(np.isinf(rhat))


def test_rule_needs_a_previous_tau_and_reports_why_it_failed():
    chain = _white(2000)
    first = check_convergence(chain, None, max_steps=10_000, **RULE)
    assert first.long_enough and not first.stable and not first.converged
    assert np.all(np.isnan(first.ess))  # not computed: cannot change the decision
    kw = {k: RULE[k] for k in ("n_tau", "tau_rtol", "target_ess", "min_steps")}
    assert failed_criteria(first, **kw) == ["tau not stable to 0.02 between checks"]
    second = check_convergence(chain, first.tau, max_steps=10_000, **RULE)
    assert second.converged and np.all(second.ess >= 100)
    assert second.burn_in == burn_in(second.tau, 2000, 3.0)


def _ar1_with_start_transient(n, phi, offset, relax, nwalkers=16, ndim=2, seed=1):
    """AR(1) walkers (τ = (1+φ)/(1-φ)) that start ``offset`` sd away and relax to the mode
    with time constant ``relax`` steps (the walkers' spread from a ball around a MAP)."""
    rng = np.random.default_rng(seed)
    eps = rng.standard_normal((n, nwalkers, ndim)) * np.sqrt(1 - phi**2)
    x = np.empty((n, nwalkers, ndim))
    x[0] = rng.standard_normal((nwalkers, ndim))
    for t in range(1, n):
        x[t] = phi * x[t - 1] + eps[t]
    return x + offset * np.exp(-np.arange(n) / relax)[:, None, None]


def test_tau_of_the_kept_chain_leaves_out_the_start_transient():
    # τ = (1 + 0.8) / (1 - 0.8) = 9 steps; a start 30 sd away relaxing over 150 steps.
    # On every step the transient reads as autocorrelation (emcee's estimate is many
    # times 9, the 50-τ rule fails at 3000 steps); on the kept half τ is 9 within the
    # estimator's scatter (~12 % here: Sokal window 5τ, 1500 x 16 draws; 3 sd).
    chain = _ar1_with_start_transient(3000, 0.8, 30.0, 150.0)
    tau_all, long_all = autocorr_time(chain, 50.0)
    assert np.max(tau_all) > 5 * 9.0 and not long_all
    tau, long_enough, b = kept_tau(chain, 50.0, 3.0)
    assert b == burn_in(tau_all, 3000, 3.0) and long_enough
    np.testing.assert_allclose(tau, 9.0, rtol=0.36)
    first = check_convergence(chain[:2900], None, max_steps=10_000, **RULE)
    second = check_convergence(chain, first.tau, max_steps=10_000, **RULE)
    assert second.converged and second.burn_in == b and np.all(second.ess >= 100)


def test_a_transient_that_reaches_the_kept_half_is_not_converged():
    # The same walkers relaxing over 1500 steps: the kept part still drifts, its τ is
    # large (~240 steps), and the rule goes on.
    chain = _ar1_with_start_transient(3000, 0.8, 30.0, 1500.0)
    first = check_convergence(chain[:2900], None, max_steps=10_000, **RULE)
    second = check_convergence(chain, first.tau, max_steps=10_000, **RULE)
    assert not second.converged and not second.long_enough
