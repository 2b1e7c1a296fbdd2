"""Whiteness statistics: autocorrelation against brute force, Ljung–Box against its formula,
Fisher's g against exact rational arithmetic and Monte Carlo."""

import math
from fractions import Fraction

import numpy as np
import pytest
import scipy.stats as sst

from bayesbeam.stats.whiteness import (
    WhitenessError,
    _fisher_sf,
    autocorrelation,
    fisher_g,
    ljung_box,
)


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


def _fisher_sf_exact(x: Fraction, m: int) -> Fraction:
    """Fisher's alternating sum in exact rational arithmetic (no round-off at all)."""
    total, j = Fraction(0), 1
    while j <= m and 1 - j * x > 0:
        total += (-1) ** (j - 1) * math.comb(m, j) * (1 - j * x) ** (m - 1)
        j += 1
    return total


@pytest.mark.parametrize("m", [10, 128, 600])
def test_fisher_tail_probability_against_exact_arithmetic(m):
    # x = c/m spans p from 1 - 1e-10 (c = 2) down to 1e-20 and below (c = 60).
    for c in [1.5, 2, 3, 4, 5, 6, 8, 12, 20, 60]:
        x = Fraction(int(100 * c), 100 * m)
        if x >= 1:
            continue
        exact = float(_fisher_sf_exact(x, m))
        got = _fisher_sf(float(x), m)
        # float(x) is x to 1e-16 relative; the log-space sum is then exact to round-off
        # relative to p in the lower tail, and within 1e-9 absolute in the upper tail
        # where the cancelling sum gives way to the clipped Bonferroni bound.
        assert abs(got - exact) <= 1e-12 * exact + 1e-9, (m, c, got, exact)
    assert _fisher_sf(0.5 / m, m) == 1.0  # below the smallest possible g (1/m)
    assert _fisher_sf(1.0, m) == 0.0


def test_fisher_g_p_value_matches_monte_carlo():
    rng = np.random.default_rng(11)
    n, n_series = 257, 20_000
    m = (n - 1) // 2
    r = rng.standard_normal((n_series, n))
    ords = np.abs(np.fft.rfft(r - r.mean(axis=1, keepdims=True), axis=1)[:, 1 : m + 1]) ** 2
    g_all = ords.max(axis=1) / ords.sum(axis=1)
    # The function computes the same statistic and bin as this vectorised version.
    for i in range(50):
        g, _, k = fisher_g(r[i])
        assert g == pytest.approx(g_all[i], rel=1e-12)
        assert k == 1 + int(np.argmax(ords[i]))
    # Its p-value at a series' own g is P(g' > g): compare with the share of the
    # 20000 white-noise series whose g exceeds it, at tail levels 0.5 down to 0.002.
    order = np.argsort(g_all)
    for level in [0.5, 0.1, 0.01, 0.002]:
        i = order[int((1 - level) * n_series)]
        g, p, _ = fisher_g(r[i])
        empirical = float(np.mean(g_all > g))
        # binomial sampling error of the empirical share; 4 sd
        assert abs(empirical - p) < 4 * math.sqrt(p * (1 - p) / n_series), (level, p, empirical)


def test_fisher_g_finds_a_weak_sinusoid():
    rng = np.random.default_rng(5)
    n, dt, f_line = 2048, 1 / 512, 50.0  # bin 200 of n dt = 4 s
    t = dt * np.arange(n)
    noise = rng.standard_normal(n)
    g, p, k = fisher_g(noise)
    assert p > 1e-3  # white noise alone (this seed) is not flagged
    # Amplitude 0.3 sd (SNR -13 dB): its ordinate is about n A² / 4 = 46 against a mean
    # of 1, so p ~ m e^{-46} ~ 1e-17 (median over 400 noise seeds 1e-17, all < 1e-6). At
    # 0.2 sd the ordinate, about 20, gives a median p of 7e-7: only half the seeds reach
    # p < 1e-6, so that amplitude would make the test a coin toss.
    g, p, k = fisher_g(noise + 0.3 * np.sin(2 * np.pi * f_line * t + 0.7))
    assert p < 1e-6
    assert k == 200 and k / (n * dt) == pytest.approx(f_line)
    # Off a bin (50.3 Hz = bin 201.2) the largest ordinate is the nearest bin.
    g, p, k = fisher_g(noise + 0.4 * np.sin(2 * np.pi * 50.3 * t + 0.7))
    assert p < 1e-6 and k == 201


def test_fisher_g_offset_and_degenerate_input():
    rng = np.random.default_rng(6)
    r = rng.standard_normal(512) + 0.5
    # The standard test ignores the mean; exclude_zero=False lets the offset compete
    # (n r̄² = 128 against a mean ordinate of 1).
    assert fisher_g(r)[2] > 0
    g0, p0, k0 = fisher_g(r, exclude_zero=False)
    assert k0 == 0 and p0 < 1e-20
    assert fisher_g(np.full(64, 2.0)) == (0.0, 1.0, 0)


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (np.zeros((64, 2)), "1-D"),
        (np.arange(7.0), "at least 8"),
        (np.r_[np.arange(20.0), np.nan], "non-finite"),
        (np.r_[np.arange(20.0), np.inf], "non-finite"),
    ],
)
def test_fisher_g_rejects_bad_input(bad, match):
    with pytest.raises(WhitenessError, match=match):
        fisher_g(bad)
