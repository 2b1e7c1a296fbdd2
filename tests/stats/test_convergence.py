"""Stopping-rule pieces of the emcee runner, on synthetic chains (no sampling)."""

from __future__ import annotations

import numpy as np

from bayesbeam.stats.convergence import (
    autocorr_time,
    burn_in,
    check_convergence,
    ess_rhat,
    failed_criteria,
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
