"""Whiteness statistics: autocorrelation against brute force, Ljung–Box against its formula."""

import math

import numpy as np
import pytest
import scipy.stats as sst

from bayesbeam.stats.whiteness import WhitenessError, autocorrelation, ljung_box


def test_autocorrelation_matches_direct_sum():
    rng = np.random.default_rng(1)
    r = rng.standard_normal(300)
    x = r - r.mean()
    direct = [np.sum(x[: x.size - k] * x[k:]) / np.sum(x * x) for k in range(11)]
    # FFT vs direct summation: round-off only (1e-12 relative).
    np.testing.assert_allclose(autocorrelation(r, 10), direct, rtol=0, atol=1e-12)
    with pytest.raises(WhitenessError, match="max_lag"):
        autocorrelation(r, 300)


def test_ljung_box_statistic_and_power():
    rng = np.random.default_rng(2)
    white = rng.standard_normal(500)
    q, p = ljung_box(white, 20)
    rho = autocorrelation(white, 20)[1:]
    n = white.size
    q_direct = n * (n + 2) * sum(rho[k - 1] ** 2 / (n - k) for k in range(1, 21))
    assert q == pytest.approx(q_direct, rel=1e-12)
    assert p == pytest.approx(sst.chi2.sf(q_direct, 20), rel=1e-12)
    assert p > 0.01  # a white series (this seed) is not rejected at the 1 % level
    ar = np.empty(500)
    ar[0] = white[0]
    for t in range(1, 500):
        ar[t] = 0.8 * ar[t - 1] + math.sqrt(1 - 0.64) * white[t]
    # AR(1) rho = 0.8: lag-1 autocorrelation ~0.8, Q in the thousands -> p ~ 0.
    assert ljung_box(ar, 20)[1] < 1e-10


def test_degenerate_input():
    # A constant series has no autocorrelation beyond lag 0 (not 0/0) and Q = 0.
    np.testing.assert_array_equal(autocorrelation(np.full(16, 3.0), 4), [1, 0, 0, 0, 0])
    assert ljung_box(np.full(16, 3.0), 4) == (0.0, 1.0)
    # n_params fitted ARMA parameters leave h - n_params degrees of freedom.
    r = np.random.default_rng(3).standard_normal(200)
    q, p = ljung_box(r, 10, n_params=1)
    assert p == pytest.approx(sst.chi2.sf(q, 9), rel=1e-12)
    with pytest.raises(WhitenessError, match="n_params"):
        ljung_box(r, 2, n_params=2)
