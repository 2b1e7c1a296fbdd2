"""Posterior-predictive draws: model signal plus a draw of the fitted noise model."""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.inference.predictive import (
    PredictiveError,
    posterior_predictive,
    predictive_draws,
)
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.stats.likelihood import stationary_ar1
from bayesbeam.trials.synthetic import simulate_trial
from bayesbeam.trials.trial import Trial

TRUTH = [6.2e10, 0.2, 0.005, 1e-5]
SD_U = [1e-6, 1e-3, 1e-5, 1e-2]


def _beam():
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)


def _trial(duration=0.5):
    return simulate_trial(_beam(), "viscous", {"gamma": 0.2}, duration=duration, dt=1 / 256,
                          noise_sd=1e-5, seed=3, n_elements=6)


@pytest.fixture(scope="module")
def setup(gaussian_cloud_result):
    tr = _trial()
    pr = Problem(tr, "viscous", n_elements=6)
    return tr, pr, gaussian_cloud_result(pr, TRUTH, SD_U)


def test_posterior_predictive_shapes_and_noise(setup):
    tr, pr, res = setup
    x, y_model, y_rep = posterior_predictive(pr, res, 50, np.random.default_rng(0))
    assert y_model.shape == y_rep.shape == (50, tr.times.size)
    assert x.shape == (50, pr.ndim)
    # The replicate minus the model is the noise draw: its sd is the sampled sigma
    # (~1e-5 m); with 50*128 values the sample sd is within 3 % (chi-square: sd ~ 1/sqrt(2N)).
    sd = np.std(y_rep - y_model)
    assert sd == pytest.approx(1e-5, rel=0.05)
    # The model is close to the data (truth +- noise): RMS misfit ~ sigma.
    assert np.sqrt(np.mean((tr.values - y_model) ** 2)) < 3e-5


def test_posterior_predictive_same_rng_same_draws(setup):
    _, pr, res = setup
    a = posterior_predictive(pr, res, 10, np.random.default_rng(7))
    b = posterior_predictive(pr, res, 10, np.random.default_rng(7))
    np.testing.assert_array_equal(a[2], b[2])


def test_spaced_draws_are_evenly_spaced_and_the_noise_is_sigma_times_z(setup):
    _, pr, res = setup
    flat = res.chain.flat_samples
    x, y_model, y_rep = posterior_predictive(pr, res, 9, np.random.default_rng(3),
                                             select="spaced")
    # 640 stored samples, 9 draws: indices 0, 79.875, ..., 639 truncated.
    idx = np.linspace(0, flat.shape[0] - 1, 9).astype(int)
    np.testing.assert_array_equal(x, pr.theta(flat[idx]))
    # The only randomness is the noise, one standard normal array in (draw, time) order.
    z = np.random.default_rng(3).standard_normal(y_model.shape)
    np.testing.assert_array_equal(y_rep, y_model + x[:, -1:] * z)
    # More draws than samples: every sample once.
    assert posterior_predictive(pr, res, 10_000, np.random.default_rng(3),
                                select="spaced")[0].shape[0] == flat.shape[0]


@pytest.mark.parametrize("uniform", [True, False])
def test_ar1_noise_is_the_likelihoods_process(uniform):
    tr = _trial()
    if not uniform:
        jitter = np.random.default_rng(2).uniform(-0.2, 0.2, tr.times.size) / 256
        jitter[[0, -1]] = 0.0
        tr = Trial(times=tr.times + jitter, values=tr.values, quantity=tr.quantity,
                   beam=tr.beam, name="jittered")
    pr = Problem(tr, "viscous+ar1_noise", n_elements=6)
    X = np.array([[6.2e10, 0.2, 0.005, 1e-5, 0.3], [6.2e10, 0.2, 0.005, 2e-5, 0.9]])
    x, y_model, y_rep = predictive_draws(pr, pr.priors.to_u(X), np.random.default_rng(5))
    z = np.random.default_rng(5).standard_normal(y_model.shape)
    # The stamps go to the generator exactly as to the likelihood (None when uniform).
    e = stationary_ar1(z, x[:, -1], times=None if uniform else tr.times)
    np.testing.assert_array_equal(y_rep, y_model + x[:, -2:-1] * e)


def test_ar1_replicates_have_the_fitted_lag_correlation():
    tr = _trial(duration=2.0)
    pr = Problem(tr, "viscous+ar1_noise", n_elements=4)
    X = np.array([[6.2e10, 0.2, 0.005, 1e-5, 0.8]] * 40)
    _, y_model, y_rep = predictive_draws(pr, pr.priors.to_u(X), np.random.default_rng(1))
    e = y_rep - y_model
    r1 = np.mean(np.sum(e[:, 1:] * e[:, :-1], axis=1) / np.sum(e * e, axis=1))
    # Lag-1 autocorrelation estimate from 40 x 512 samples: sd ~ sqrt((1-rho^2)/N) ~ 4e-3.
    assert r1 == pytest.approx(0.8, abs=0.03)
    assert np.std(e) == pytest.approx(1e-5, rel=0.1)  # marginal sd is sigma (10 %: few draws)


def test_bad_input_raises(setup):
    tr, pr, res = setup
    rng = np.random.default_rng(0)
    with pytest.raises(PredictiveError, match="positive int"):
        posterior_predictive(pr, res, 0, rng)
    with pytest.raises(PredictiveError, match="select"):
        posterior_predictive(pr, res, 5, rng, select="first")
    other = Problem(tr, "viscous+kv", n_elements=6)
    with pytest.raises(PredictiveError, match="do not match"):
        posterior_predictive(other, res, 5, rng)
    U = res.chain.flat_samples[:3].copy()
    U[1, 0] = np.nan
    with pytest.raises(PredictiveError, match="1 of 3 points"):
        predictive_draws(pr, U, rng)
