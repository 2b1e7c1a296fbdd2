"""emcee runner: closed-form posterior, determinism, budget warning, checkpoint resume."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import emcee
import numpy as np
import pytest

from bayesbeam.stats.checkpoint import SamplingError
from bayesbeam.stats.families import LogUniform, Normal
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import (
    Chain,
    NotConvergedWarning,
    init_walkers,
    make_log_prob,
    run_emcee,
)

# ---- linear-Gaussian toy: y = X beta + e, e ~ N(0, s^2), beta_j ~ N(m0_j, sd0_j) ------
_rng = np.random.default_rng(11)
X = np.column_stack([np.ones(25), np.linspace(-1, 1, 25), np.linspace(-1, 1, 25) ** 2])
BETA = np.array([0.5, -1.0, 2.0])
S_NOISE = 0.3
Y = X @ BETA + S_NOISE * _rng.standard_normal(25)
PRIORS = PriorSet({"b0": Normal(0.0, 2.0), "b1": Normal(0.0, 2.0), "b2": Normal(1.0, 1.0)})
M0 = np.array([0.0, 0.0, 1.0])
S0 = np.diag([4.0, 4.0, 1.0])
# Closed-form conjugate posterior (e.g. Bishop 2006, eq. 3.50-3.51).
POST_COV = np.linalg.inv(np.linalg.inv(S0) + X.T @ X / S_NOISE**2)
POST_MEAN = POST_COV @ (np.linalg.inv(S0) @ M0 + X.T @ Y / S_NOISE**2)
NWALKERS = 24
ROOT = Path(__file__).resolve().parents[2]


def log_prob(U):
    r = Y[None, :] - U @ X.T
    return PRIORS.log_prior_u(U) - 0.5 * np.sum(r * r, axis=1) / S_NOISE**2


def start(seed=0):
    return init_walkers(log_prob, POST_MEAN, NWALKERS, rng=np.random.default_rng(seed), scale=0.01)


@pytest.fixture(scope="module")
def toy_chain():
    return run_emcee(log_prob, start(), seed=42, names=PRIORS.names, progress=False)


def test_matches_closed_form_posterior(toy_chain):
    import arviz  # imported here: the subprocess tests import this module and need speed

    ch = toy_chain
    assert isinstance(ch, Chain)
    assert ch.converged
    assert ch.names == ("b0", "b1", "b2")
    assert ch.samples.shape == (ch.nsteps, NWALKERS, 3)
    assert ch.log_prob.shape == (ch.nsteps, NWALKERS)
    assert np.all(ch.ess >= 1000)
    # The rule (stats.convergence): the kept steps are 50 of their own τ; the burn-in is
    # 3 τ of the whole chain, at most half of it.
    assert ch.nsteps >= 50 * ch.tau_max
    assert 3 * ch.tau_max <= ch.burn_in <= ch.n_steps_total // 2
    assert ch.n_steps_total == ch.burn_in + ch.nsteps
    # loose sanity bounds: stretch-move acceptance is typically 0.2-0.7; R-hat over
    # walkers that each hold only ~n/tau ~ 50 effective draws is ~1.01-1.03
    assert 0.2 < np.mean(ch.acceptance_fraction) < 0.8
    assert ch.rhat_max < 1.05
    assert ch.n_calls == NWALKERS * (ch.n_steps_total + 1)  # +1: the initial evaluation
    assert not ch.samples.flags.writeable

    flat = ch.flat_samples
    draws = np.swapaxes(ch.samples, 0, 1)
    ess_mean = arviz.ess(draws, chain_axis=0, draw_axis=1, method="mean")
    sd = np.sqrt(np.diag(POST_COV))
    # Monte-Carlo standard error of a mean: sd / sqrt(ESS). Allow 4 MCSE (two-sided
    # p ~ 6e-5 per comparison; 9 comparisons below).
    mcse_mean = sd / np.sqrt(ess_mean)
    np.testing.assert_array_less(np.abs(flat.mean(axis=0) - POST_MEAN), 4 * mcse_mean)
    # Covariance: for Gaussian draws var(cov_ij estimate) = (S_ii S_jj + S_ij^2) / n;
    # use the smallest ESS for n and again allow 4 standard errors.
    cov = np.cov(flat.T)
    var_diag = np.diag(POST_COV)
    se_cov = np.sqrt((np.outer(var_diag, var_diag) + POST_COV**2) / np.min(ess_mean))
    np.testing.assert_array_less(np.abs(cov - POST_COV), 4 * se_cov)


def test_same_seed_same_chain(toy_chain):
    # thinning only changes what is stored: same decisions, every 3rd step kept
    again = run_emcee(log_prob, start(), seed=42, names=PRIORS.names, progress=False, thin=3)
    np.testing.assert_array_equal(again.samples, toy_chain.samples[::3])
    np.testing.assert_array_equal(again.log_prob, toy_chain.log_prob[::3])
    np.testing.assert_array_equal(again.tau, toy_chain.tau)
    np.testing.assert_array_equal(again.ess, toy_chain.ess)
    assert again.n_steps_total == toy_chain.n_steps_total
    assert again.thin == 3


def test_ess_per_second_is_the_smallest_ess_over_the_sampling_time(toy_chain):
    import dataclasses
    import math

    assert toy_chain.seconds > 0
    assert toy_chain.ess_per_second == toy_chain.ess_min / toy_chain.seconds
    assert toy_chain.ess_min == float(np.min(toy_chain.ess))
    # A chain without a time (a record read from a file that had none) gives NaN, not inf.
    assert math.isnan(dataclasses.replace(toy_chain, seconds=0.0).ess_per_second)


def test_named_move_sets():
    import emcee

    from bayesbeam.stats.moves import MOVE_SETS, named_moves

    kw = {"seed": 3, "names": PRIORS.names, "progress": False, "max_steps": 400,
          "min_steps": 400, "target_ess": 1.0}
    # "stretch" is emcee's default move (Goodman & Weare, a = 2): the same chain as
    # leaving the moves to emcee.
    with pytest.warns(NotConvergedWarning):
        named = run_emcee(log_prob, start(), moves=named_moves("stretch"), **kw)
    with pytest.warns(NotConvergedWarning):
        default = run_emcee(log_prob, start(), moves=emcee.moves.StretchMove(), **kw)
    np.testing.assert_array_equal(named.samples, default.samples)
    # Each set holds fresh move objects whose weights sum to one.
    for name in MOVE_SETS:
        a, b = named_moves(name), named_moves(name)
        assert sum(w for _, w in a) == pytest.approx(1.0)
        assert all(m1 is not m2 for (m1, _), (m2, _) in zip(a, b, strict=True))
    with pytest.raises(ValueError, match="choose one of"):
        named_moves("hmc")


def test_different_seed_different_chain():
    kw = dict(max_steps=100, progress=False)
    with pytest.warns(NotConvergedWarning):
        a = run_emcee(log_prob, start(), seed=1, **kw)
    with pytest.warns(NotConvergedWarning):
        b = run_emcee(log_prob, start(), seed=2, **kw)
    assert not np.array_equal(a.samples, b.samples)


def test_budget_exhausted_warns():
    with pytest.warns(NotConvergedWarning, match="did not converge within max_steps=150"):
        ch = run_emcee(log_prob, start(), seed=5, max_steps=150, progress=False)
    assert not ch.converged
    assert ch.n_steps_total == 150
    assert 0 < ch.burn_in <= 75  # 3 tau of the whole chain, at most half
    assert ch.nsteps == 150 - ch.burn_in
    assert np.all(np.isfinite(ch.ess))


class _KillAfter:
    """log_prob that raises KeyboardInterrupt (a Ctrl-C) after ``n`` point evaluations."""

    def __init__(self, n):
        self.n = n
        self.calls = 0

    def __call__(self, U):
        self.calls += len(U)
        if self.calls > self.n:
            raise KeyboardInterrupt
        return log_prob(U)


class _Counting:
    def __init__(self):
        self.calls = 0

    def __call__(self, U):
        self.calls += len(U)
        return log_prob(U)


def _same_chain(a, b):
    assert a.n_steps_total == b.n_steps_total
    assert a.samples.shape == b.samples.shape
    np.testing.assert_array_equal(a.samples, b.samples)
    np.testing.assert_array_equal(a.log_prob, b.log_prob)
    np.testing.assert_array_equal(a.ess, b.ess)
    np.testing.assert_array_equal(a.acceptance_fraction, b.acceptance_fraction)


def test_killed_run_resumes_to_the_same_chain(toy_chain, tmp_path):
    path = tmp_path / "chain.h5"
    kw = dict(seed=42, names=PRIORS.names, progress=False, backend_path=path)
    kill = _KillAfter(NWALKERS * 750 + 5)  # dies half-way through a step, mid-chunk
    with pytest.raises(KeyboardInterrupt):
        run_emcee(kill, start(), **kw)
    saved = emcee.backends.HDFBackend(str(path), read_only=True).iteration
    assert saved == 749  # initial evaluation + 749 full steps, then the kill

    resumed = run_emcee(log_prob, start(), resume=True, **kw)
    assert resumed.converged
    assert np.all(resumed.ess >= 1000)
    _same_chain(resumed, toy_chain)
    # calls: the killed process's work (incl. the lost half step) plus the rest
    assert resumed.n_calls == kill.calls + NWALKERS * (resumed.n_steps_total - saved)

    # resuming a finished run samples nothing and returns the same chain
    count = _Counting()
    again = run_emcee(count, start(), resume=True, **kw)
    assert count.calls == 0
    _same_chain(again, toy_chain)

    with pytest.raises(SamplingError, match="seed=42"):
        run_emcee(log_prob, start(), **{**kw, "seed": 7}, resume=True)
    with pytest.raises(SamplingError, match="parameters"):
        run_emcee(log_prob, start(), **{**kw, "names": ["x", "y", "z"]}, resume=True)
    # The walkers' positions mean other points in other coordinates.
    with pytest.raises(SamplingError, match="other coordinates"):
        run_emcee(log_prob, start(), **kw, space="u with E as log ω1²", resume=True)


def test_budget_then_extend_equals_uninterrupted(toy_chain, tmp_path):
    path = tmp_path / "chain.h5"
    kw = dict(seed=42, names=PRIORS.names, progress=False, backend_path=path)
    with pytest.warns(NotConvergedWarning):
        run_emcee(log_prob, start(), max_steps=250, **kw)  # not a multiple of check_every
    _same_chain(run_emcee(log_prob, start(), resume=True, **kw), toy_chain)
    # resume=False starts over in the same file
    with pytest.warns(NotConvergedWarning):
        fresh = run_emcee(log_prob, start(), max_steps=100, **kw)
    assert fresh.n_steps_total == 100
    assert emcee.backends.HDFBackend(str(path), read_only=True).iteration == 100


class _HardKillAfter:
    """log_prob that ends the process with os._exit after ``n`` points: no cleanup
    code runs (like SIGKILL, but at a reproducible point and never inside a write)."""

    def __init__(self, n):
        self.n = n
        self.calls = 0

    def __call__(self, U):
        self.calls += len(U)
        if self.calls > self.n:
            os._exit(3)
        return log_prob(U)


@pytest.mark.parametrize(("checkpoint_seconds", "lo"), [(0.0, 319), (10.0, 300)])
def test_hard_killed_process_resumes(toy_chain, tmp_path, checkpoint_seconds, lo):
    path = tmp_path / "chain.h5"
    script = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(ROOT)!r})
        from tests.stats.test_sampling import _HardKillAfter, start, NWALKERS, PRIORS
        from bayesbeam.stats.sampling import run_emcee
        run_emcee(_HardKillAfter(NWALKERS * 320), start(), seed=42, names=PRIORS.names,
                  backend_path={str(path)!r}, progress=False,
                  checkpoint_seconds={checkpoint_seconds})
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
    # 319 steps were complete; with checkpoint_seconds=0 all are on disk, otherwise
    # at least those up to the last check (step 300; a slower machine may add a
    # time-triggered save in between).
    saved = emcee.backends.HDFBackend(str(path), read_only=True).iteration
    assert lo <= saved <= 319
    kw = dict(seed=42, names=PRIORS.names, progress=False, backend_path=path)
    _same_chain(run_emcee(log_prob, start(), resume=True, **kw), toy_chain)


def test_progress_line_only_when_asked(capsys):
    kw = dict(seed=3, max_steps=100, check_every=50)
    with pytest.warns(NotConvergedWarning):
        run_emcee(log_prob, start(), progress=True, **kw)
    err = capsys.readouterr().err
    assert "step 100/100" in err and "emcee:" in err  # the bar's last state, named
    assert "\r" not in err  # stderr is not a terminal here: whole lines for a log
    assert "tau_max" in err
    with pytest.warns(NotConvergedWarning):
        run_emcee(log_prob, start(), progress=None, **kw)  # stderr is not a TTY here
    assert capsys.readouterr().err == ""


def test_input_errors():
    u0 = start()
    with pytest.raises(SamplingError, match="nwalkers >= 2\\*ndim"):
        run_emcee(log_prob, u0[:4], seed=0)
    with pytest.raises(SamplingError, match="shape"):
        run_emcee(log_prob, u0[0], seed=0)
    with pytest.raises(SamplingError, match="seed"):
        run_emcee(log_prob, u0, seed=-1)
    with pytest.raises(SamplingError, match="names"):
        run_emcee(log_prob, u0, seed=0, names=["a", "a", "b"])
    with pytest.raises(SamplingError, match="walkers \\[0\\] start where log_prob is -inf"):
        run_emcee(lambda U: np.where(U[:, 0] == u0[0, 0], -np.inf, 0.0), u0, seed=0)
    flat = u0.copy()
    flat[:, 2] = 1.0  # one parameter without spread: the ensemble cannot move along it
    with pytest.raises(SamplingError, match="linearly dependent"):
        run_emcee(log_prob, flat, seed=0)


def test_a_narrowed_ensemble_keeps_sampling():
    # The target pins x2 - x1 to ~1e-9 (as a pooled spread near zero pins each trial's
    # value to the population's): within a few hundred steps the ensemble lies on the
    # line x1 = x2, its columns linearly dependent, which emcee's start check rejects.
    # The run continues (each chunk continues the chain) and stays on the pin.
    def pinned(U):
        return -0.5 * (U[:, 0] ** 2 + U[:, 2] ** 2 + ((U[:, 1] - U[:, 0]) / 1e-9) ** 2)

    u0 = np.random.default_rng(0).standard_normal((16, 3))
    u0[:, 1] = u0[:, 0] + 1e-3 * u0[:, 1]
    with pytest.warns(NotConvergedWarning):
        ch = run_emcee(pinned, u0, seed=0, max_steps=600, min_steps=600, target_ess=1e9,
                       check_every=100, progress=False)
    assert ch.n_steps_total == 600
    assert np.abs(ch.samples[-1, :, 1] - ch.samples[-1, :, 0]).max() < 1e-7
    with pytest.raises(SamplingError, match="returned nan"):
        run_emcee(lambda U: np.full(len(U), np.nan), u0, seed=0)
    with pytest.raises(SamplingError, match="shape"):
        run_emcee(lambda U: np.zeros((len(U), 1)), u0, seed=0)


def test_init_walkers_stays_in_support():
    # half-space support u0 > 0; a ball centred on the boundary must be redrawn
    def half(U):
        return np.where(U[:, 0] > 0, -0.5 * np.sum(U**2, axis=1), -np.inf)

    u = init_walkers(half, np.zeros(2), 10, rng=np.random.default_rng(0), scale=1.0)
    assert u.shape == (10, 2)
    assert np.all(u[:, 0] > 0)
    with pytest.raises(SamplingError, match="non-finite"):
        init_walkers(
            lambda U: np.full(len(U), -np.inf), np.zeros(2), 4, rng=np.random.default_rng(0)
        )


def test_make_log_prob_skips_likelihood_outside_support():
    priors = PriorSet({"E": LogUniform(1e9, 1e11), "c": Normal(0.0, 1.0)})
    seen = []

    def log_lik(theta):
        seen.append(theta.copy())
        return -0.5 * theta[:, 1] ** 2

    lp = make_log_prob(priors, log_lik)
    U = np.array([[math.log(1e10), 0.5], [math.log(1e12), 0.5], [math.log(2e9), -1.0]])
    out = lp(U)
    assert out[1] == -np.inf
    expected = priors.log_prior_u(U[[0, 2]]) - 0.5 * np.array([0.25, 1.0])
    np.testing.assert_allclose(out[[0, 2]], expected, rtol=1e-15)
    assert len(seen) == 1 and seen[0].shape == (2, 2)  # one batched call, in-support rows
    np.testing.assert_allclose(seen[0][:, 0], [1e10, 2e9], rtol=1e-14)


# -- stranded walkers ------------------------------------------------------------------
def _gauss_lp(U):
    U = np.atleast_2d(U)
    return -0.5 * np.sum(U**2, axis=1)


def test_preburn_returns_stranded_walkers_to_the_ensemble():
    from bayesbeam.stats.sampling import STRANDED_NATS, preburn_walkers

    rng = np.random.default_rng(0)
    u0 = 0.1 * rng.standard_normal((16, 3))
    u0[:2] += 30.0  # two walkers 450 nats below the rest: emcee alone keeps them out
    lp0 = _gauss_lp(u0)
    u, lp = preburn_walkers(_gauss_lp, u0, lp0, 200, seed=1)
    assert np.all(lp > np.median(lp) - STRANDED_NATS - 1.5)
    assert np.all(np.abs(u) < 8)
    np.testing.assert_allclose(lp, _gauss_lp(u))
    # Same seed, same result; the recorded chain's stream is not used.
    u2, _ = preburn_walkers(_gauss_lp, u0, lp0, 200, seed=1)
    assert np.array_equal(u, u2)


def _two_modes_lp(U):
    # Main mode at 0; a second one 20 sd away and 40 nats lower. Stretch moves never
    # propose less than halfway towards another walker, into the empty valley, so a
    # walker started in the minor mode stays there.
    U = np.atleast_2d(U)
    a = -0.5 * np.sum(U**2, axis=1)
    shift = U.copy()
    shift[:, 0] -= 20.0
    b = -40.0 - 0.5 * np.sum(shift**2, axis=1)
    return np.logaddexp(a, b)


def test_run_emcee_with_preburn_converges_where_stranded_walkers_would_not():
    rng = np.random.default_rng(2)
    u0 = 0.1 * rng.standard_normal((16, 3))
    u0[0, 0] += 20.0
    kw = {"seed": 3, "max_steps": 4000, "min_steps": 300, "target_ess": 300, "progress": False}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)
        stuck = run_emcee(_two_modes_lp, u0, **kw)
    # The walker never left the minor mode: 1/16 of the "posterior" sits 20 sd away.
    assert np.min(np.max(stuck.samples[..., 0], axis=0)) < 5
    assert np.max(stuck.samples[..., 0]) > 15
    ch = run_emcee(_two_modes_lp, u0, preburn=200, **kw)
    assert ch.converged
    assert np.max(ch.samples[..., 0]) < 8
    np.testing.assert_allclose(ch.samples.reshape(-1, 3).mean(axis=0), 0.0, atol=0.15)
