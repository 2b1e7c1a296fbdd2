"""Noise models against scipy's densities (brute force, written by others)."""

import math

import numpy as np
import pytest
from scipy import stats

from bayesbeam.stats.likelihood import (
    LikelihoodError,
    ar1_loglik,
    ar1_pointwise,
    iid_loglik,
    iid_pointwise,
    stationary_ar1,
)

# Agreement with scipy: both sides are sums of ~T well-conditioned float64 terms of size
# O(10..100); 1e-10 absolute leaves room for their different summation orders.
TOL = 1e-10


def _ar1_cov(sigma, rho, lags):
    return sigma**2 * rho ** np.abs(lags)


def test_iid_matches_scipy_norm():
    rng = np.random.default_rng(1)
    r = rng.normal(size=(4, 50)) * 3e-3
    sigma = np.array([1e-3, 3e-3, 1e-2, 0.5])
    ref_pw = stats.norm.logpdf(r, scale=sigma[:, None])
    np.testing.assert_allclose(iid_pointwise(r, sigma), ref_pw, rtol=0, atol=TOL)
    np.testing.assert_allclose(iid_loglik(r, sigma), ref_pw.sum(axis=1), rtol=0, atol=TOL)


def test_iid_broadcasts_shared_residuals_over_sigmas():
    rng = np.random.default_rng(2)
    r = rng.normal(size=30)
    sigma = np.array([0.5, 1.0, 2.0])
    out = iid_loglik(r, sigma)
    assert out.shape == (3,)
    ref = [stats.norm.logpdf(r, scale=s).sum() for s in sigma]
    np.testing.assert_allclose(out, ref, rtol=0, atol=TOL)


@pytest.mark.parametrize("rho", [-0.7, 0.0, 0.5, 0.95])
def test_ar1_uniform_matches_multivariate_normal(rho):
    rng = np.random.default_rng(3)
    T = 40
    sigma = 2e-3
    idx = np.arange(T)
    cov = _ar1_cov(sigma, rho, idx[:, None] - idx[None, :])
    r = rng.multivariate_normal(np.zeros(T), cov, size=3)
    ref = stats.multivariate_normal(mean=np.zeros(T), cov=cov).logpdf(r)
    got = ar1_loglik(r, np.full(3, sigma), np.full(3, rho))
    np.testing.assert_allclose(got, ref, rtol=0, atol=TOL)


def test_ar1_batched_distinct_parameters():
    rng = np.random.default_rng(4)
    T = 25
    r = rng.normal(size=(3, T))
    sigmas = np.array([0.8, 1.0, 1.7])
    rhos = np.array([0.1, -0.4, 0.8])
    idx = np.arange(T)
    ref = [
        stats.multivariate_normal(np.zeros(T), _ar1_cov(s, p, idx[:, None] - idx[None, :])).logpdf(
            r[k]
        )
        for k, (s, p) in enumerate(zip(sigmas, rhos, strict=True))
    ]
    np.testing.assert_allclose(ar1_loglik(r, sigmas, rhos), ref, rtol=0, atol=TOL)


@pytest.mark.parametrize("dt_ref", [None, 0.01])
def test_ar1_nonuniform_matches_ou_covariance(dt_ref):
    rng = np.random.default_rng(5)
    T = 40
    times = np.cumsum(rng.uniform(0.005, 0.02, size=T))
    rho, sigma = 0.8, 1.5e-2
    ref_dt = np.median(np.diff(times)) if dt_ref is None else dt_ref
    cov = sigma**2 * rho ** (np.abs(times[:, None] - times[None, :]) / ref_dt)
    r = rng.multivariate_normal(np.zeros(T), cov, size=2)
    ref = stats.multivariate_normal(np.zeros(T), cov).logpdf(r)
    got = ar1_loglik(r, sigma, rho, times=times, dt_ref=dt_ref)
    np.testing.assert_allclose(got, ref, rtol=0, atol=TOL)


def test_ar1_uniform_times_equal_discrete_ar1():
    rng = np.random.default_rng(6)
    r = rng.normal(size=(2, 30))
    times = 0.004 * np.arange(30)
    a = ar1_loglik(r, 1.0, 0.6)
    b = ar1_loglik(r, 1.0, 0.6, times=times, dt_ref=0.004)
    np.testing.assert_allclose(a, b, rtol=0, atol=TOL)


def test_ar1_pointwise_terms():
    rng = np.random.default_rng(7)
    r = rng.normal(size=(2, 20))
    sigma, rho = np.array([1.0, 2.0]), np.array([0.3, -0.5])
    pw = ar1_pointwise(r, sigma, rho)
    assert pw.shape == r.shape
    # First term: stationary marginal; the rest: conditional on the previous sample.
    np.testing.assert_allclose(pw[:, 0], stats.norm.logpdf(r[:, 0], scale=sigma), atol=TOL)
    cond = stats.norm.logpdf(
        r[:, 1:],
        loc=rho[:, None] * r[:, :-1],
        scale=(sigma * np.sqrt(1 - rho**2))[:, None],
    )
    np.testing.assert_allclose(pw[:, 1:], cond, rtol=0, atol=TOL)
    np.testing.assert_allclose(pw.sum(axis=1), ar1_loglik(r, sigma, rho), rtol=0, atol=TOL)


def test_ar1_rho_zero_is_iid():
    rng = np.random.default_rng(8)
    r = rng.normal(size=(3, 15))
    np.testing.assert_allclose(ar1_loglik(r, 0.7, 0.0), iid_loglik(r, 0.7), rtol=0, atol=TOL)
    times = np.cumsum(rng.uniform(0.5, 1.5, size=15))
    np.testing.assert_allclose(
        ar1_loglik(r, 0.7, 0.0, times=times), iid_loglik(r, 0.7), rtol=0, atol=TOL
    )


def test_outside_support_is_minus_inf():
    r = np.ones((4, 5))
    assert np.all(iid_loglik(r, np.array([0.0, -1.0, 1.0, 2.0]))[:2] == -np.inf)
    ll = ar1_loglik(r, 1.0, np.array([1.0, -1.0, 0.5, 1.2]))
    assert ll[0] == -np.inf and ll[1] == -np.inf and ll[3] == -np.inf
    assert np.isfinite(ll[2])
    times = np.arange(5.0)
    assert ar1_loglik(r[:1], 1.0, -0.3, times=times)[0] == -np.inf


def test_nan_residuals_raise():
    r = np.zeros((2, 4))
    r[1, 2] = np.nan
    with pytest.raises(LikelihoodError, match="NaN/inf.*valid mask"):
        iid_loglik(r, 1.0)
    with pytest.raises(LikelihoodError, match="sigma contains NaN"):
        ar1_loglik(np.zeros((1, 3)), np.nan, 0.2)


def test_bad_shapes_raise():
    with pytest.raises(LikelihoodError, match="does not broadcast"):
        iid_loglik(np.zeros((3, 5)), np.ones(2))
    with pytest.raises(LikelihoodError, match="times must have shape"):
        ar1_loglik(np.zeros((1, 5)), 1.0, 0.5, times=np.arange(4.0))
    with pytest.raises(LikelihoodError, match="strictly increasing"):
        ar1_loglik(np.zeros((1, 3)), 1.0, 0.5, times=np.array([0.0, 1.0, 1.0]))



# ----------------------------------------------------------------------------- sampling


def test_stationary_ar1_has_unit_variance_and_geometric_autocorrelation():
    # Closed form of a stationary AR(1): var 1, corr(lag j) = rho^j. Tolerances: 4 sd of
    # the sample estimates over T draws: var(s²) ≈ 2 (1 + ρ²) / ((1 - ρ²) T), and
    # Bartlett's var(r_j) ≈ [(1 + ρ²)(1 - ρ^2j) / (1 - ρ²) - 2 j ρ^2j] / T.
    rho, n = 0.8, 200_000
    e = stationary_ar1(np.random.default_rng(11).standard_normal(n), rho)
    sd_var = math.sqrt(2 * (1 + rho**2) / ((1 - rho**2) * n))
    assert np.var(e) == pytest.approx(1.0, abs=4 * sd_var)
    for lag in (1, 2, 5):
        r2j = rho ** (2 * lag)
        sd_r = math.sqrt(((1 + rho**2) * (1 - r2j) / (1 - rho**2) - 2 * lag * r2j) / n)
        assert np.corrcoef(e[:-lag], e[lag:])[0, 1] == pytest.approx(rho**lag, abs=4 * sd_r)
    with pytest.raises(ValueError, match="stationary"):
        stationary_ar1(np.zeros(3), 1.0)
    with pytest.raises(LikelihoodError, match=r"\[0, 1\) with times"):
        stationary_ar1(np.zeros(3), -0.2, times=np.arange(3.0))
    with pytest.raises(LikelihoodError, match="does not broadcast"):
        stationary_ar1(np.zeros((2, 3)), [0.1, 0.2, 0.3])


def _ar1_loop(z, phi, sd):
    """The recursion written out: e_0 = sd z_0, e_t = phi_t e_{t-1} + sd sqrt(1-phi_t²) z_t."""
    e = np.empty_like(z)
    e[..., 0] = sd * z[..., 0]
    innov = sd * np.sqrt(1 - phi**2)
    for t in range(1, z.shape[-1]):
        e[..., t] = phi[..., t - 1] * e[..., t - 1] + innov[..., t - 1] * z[..., t]
    return e


def test_stationary_ar1_is_the_recursion_and_the_likelihoods_process():
    rng = np.random.default_rng(4)
    z = rng.standard_normal((3, 400))
    rho = np.array([0.0, -0.7, 0.95])
    # Uniform stamps: the filter runs the same products and sums as the loop, bit for bit.
    phi = np.broadcast_to(rho[:, None], (3, 399))
    np.testing.assert_array_equal(stationary_ar1(z, rho, sd=2e-5), _ar1_loop(z, phi, 2e-5))
    # Non-uniform stamps: phi_t = rho^(Δt_t / dt_ref) (dt_ref the median step), as scored by
    # ar1_pointwise; exp(log) against pow differ by a few ulp.
    times = np.cumsum(rng.uniform(0.5, 1.5, 400)) / 512
    rho = np.array([0.0, 0.7, 0.95])
    steps = np.diff(times)
    phi = rho[:, None] ** (steps / np.median(steps))
    np.testing.assert_allclose(stationary_ar1(z, rho, times=times), _ar1_loop(z, phi, 1.0),
                               rtol=1e-13, atol=1e-13)
    # Its innovations are what the likelihood conditions on: e_t - phi_t e_{t-1} has
    # variance 1 - phi_t², so the pointwise terms are those of the standard normal z.
    e = stationary_ar1(z, rho, times=times)
    lp = ar1_pointwise(e, 1.0, rho, times=times)
    var = 1 - phi**2
    np.testing.assert_allclose(lp[:, 1:], stats.norm.logpdf(z[:, 1:]) - 0.5 * np.log(var),
                               rtol=1e-9, atol=1e-9)
