"""Information criteria against brute-force LOO on a conjugate normal model.

Model: y_i ~ N(mu, SIG²), SIG known, prior mu ~ N(M0, S0²). The posterior and every
leave-one-out / leave-one-group-out posterior are normal in closed form, so exact LOO
is a refit per observation; WAIC also has a closed form (lppd_i = log N(y_i; m,
SIG² + s²), p_waic_i = Var[(y_i - mu)²] / (4 SIG⁴) = (2 s⁴ + 4 (y_i - m)² s²) / (4 SIG⁴)).
Posterior draws are exact (iid), 4 chains x 2000.

Tolerance for totals: 0.05 nats. Measured over 30 data/draw seeds, the Monte Carlo
scatter of PSIS-LOO, WAIC and LOGO around their exact values has sd 0.012-0.014 nats
(max 0.027), so 0.05 is ~4 sd; pointwise terms: 0.02 (measured max 0.011).
"""

import math

import numpy as np
import pytest
from scipy import stats

from bayesbeam.stats.criteria import (
    LOO,
    WAIC,
    CriteriaError,
    ParetoKWarning,
    WAICWarning,
    aic,
    bic,
    elpd_difference,
    group_loglik,
    logo,
    loo,
    waic,
)

SIG, M0, S0 = 1.0, 0.0, 3.0
TOL_TOTAL, TOL_POINT = 0.05, 0.02


def posterior(y):
    prec = 1 / S0**2 + len(y) / SIG**2
    return (M0 / S0**2 + y.sum() / SIG**2) / prec, 1 / math.sqrt(prec)


def exact_loo(y):
    out = []
    for i in range(len(y)):
        m, s = posterior(np.delete(y, i))
        out.append(stats.norm.logpdf(y[i], m, math.sqrt(SIG**2 + s**2)))
    return np.array(out)


def exact_logo(y, groups):
    out = []
    for g in np.unique(groups):
        m, s = posterior(y[groups != g])
        yg = y[groups == g]
        cov = SIG**2 * np.eye(yg.size) + s**2  # shared mu couples the group's points
        out.append(stats.multivariate_normal(np.full(yg.size, m), cov).logpdf(yg))
    return np.array(out)


def exact_waic(y):
    m, s = posterior(y)
    lppd = stats.norm.logpdf(y, m, math.sqrt(SIG**2 + s**2))
    p = (2 * s**4 + 4 * (y - m) ** 2 * s**2) / (4 * SIG**4)
    return lppd - p, p


def draws(y, seed, n_chains=4, n_draws=2000):
    """Exact posterior draws and the pointwise log-likelihood (chains, draws, N)."""
    m, s = posterior(y)
    mu = np.random.default_rng(seed).normal(m, s, size=(n_chains, n_draws))
    return stats.norm.logpdf(y, mu[..., None], SIG)


@pytest.fixture(scope="module")
def data():
    y = np.random.default_rng(0).normal(1.0, SIG, 30)
    return y, draws(y, seed=1)


def test_loo_matches_brute_force(data):
    y, ll = data
    res = loo(ll)
    exact = exact_loo(y)
    assert isinstance(res, LOO)
    assert res.elpd_loo == pytest.approx(exact.sum(), abs=TOL_TOTAL)
    np.testing.assert_allclose(res.pointwise, exact, atol=TOL_POINT)
    assert res.pareto_k.shape == (30,) and np.all(res.pareto_k < 0.5)
    # p_loo = lppd - elpd_loo; for one well-identified mean it is close to 1
    # (exact value: Σ p_waic_i of the closed form, ~1.0 here; 0.1 covers MC scatter).
    assert res.p_loo == pytest.approx(exact_waic(y)[1].sum(), abs=0.1)
    # se: sqrt(N var(elpd_i)) of the exact pointwise values (VGG17 eq. 23), to 2 %.
    assert res.se == pytest.approx(math.sqrt(30 * np.var(exact, ddof=1)), rel=0.02)
    # iid chains: r_eff ~ 1 (ESS estimates scatter by a few %).
    assert 0.85 < res.reff <= 1.0
    # Flat (S, N) input gives the same answer up to r_eff's small effect on smoothing.
    assert loo(ll.reshape(-1, 30)).elpd_loo == pytest.approx(res.elpd_loo, abs=1e-3)
    assert res.to_dict()["n_bad_k"] == 0 and "elpd_loo" in str(res)


def test_waic_matches_closed_form_and_loo(data):
    y, ll = data
    res = waic(ll)
    exact_i, exact_p = exact_waic(y)
    assert isinstance(res, WAIC)
    assert res.elpd_waic == pytest.approx(exact_i.sum(), abs=TOL_TOTAL)
    assert res.p_waic == pytest.approx(exact_p.sum(), abs=TOL_TOTAL)
    assert res.waic == -2 * res.elpd_waic
    np.testing.assert_allclose(res.pointwise, exact_i, atol=TOL_POINT)
    # WAIC and exact LOO are asymptotically equivalent; in this model they differ by
    # < 0.003 nats exactly (measured), so the MC tolerance applies.
    assert res.elpd_waic == pytest.approx(exact_loo(y).sum(), abs=TOL_TOTAL)


def test_outlier_raises_pareto_k_and_waic_warnings():
    # One observation 12 sd away in a small data set dominates its LOO posterior:
    # importance sampling fails for it (k > 0.7), and p_waic_i > 0.4.
    y = np.random.default_rng(2).normal(1.0, SIG, 10)
    y[3] = 12.0
    ll = draws(y, seed=3)
    with pytest.warns(ParetoKWarning, match="Pareto k") as rec:
        res = loo(ll)
    assert "3: k=" in str(rec[0].message)
    assert int(np.argmax(res.pareto_k)) == 3 and res.pareto_k[3] > 0.7
    assert res.n_bad_k >= 1
    with pytest.warns(WAICWarning, match="p_waic_i"):
        waic(ll)


def test_logo_matches_brute_force_leave_group_out(data):
    y, ll = data
    groups = np.repeat(np.array(["t0", "t1", "t2", "t3", "t4", "t5", "t6", "t7", "t8", "t9"]), 3)
    res = logo(ll, groups)
    exact = exact_logo(y, groups)
    assert res.pointwise.shape == (10,)
    assert res.elpd_loo == pytest.approx(exact.sum(), abs=TOL_TOTAL)
    np.testing.assert_allclose(res.pointwise, exact, atol=TOL_POINT)
    grouped, labels = group_loglik(ll, groups)
    assert grouped.shape == (4, 2000, 10) and labels[0] == "t0"
    np.testing.assert_allclose(grouped[..., 1], ll[..., 3:6].sum(axis=-1))
    # Singleton groups reproduce plain LOO.
    assert logo(ll, np.arange(30)).elpd_loo == pytest.approx(loo(ll).elpd_loo, rel=1e-12)


def test_elpd_difference_matches_arviz_compare(data):
    # External check: arviz.compare's elpd_diff equals ours; its dse uses the population
    # variance (ddof=0), ours the sample variance of VGG17 eq. 24 / R loo (ddof=1).
    az = pytest.importorskip("arviz")
    if int(az.__version__.split(".")[0]) < 1:
        pytest.skip("checked against the ArviZ 1.x compare table")
    y, ll_a = data
    mu = np.random.default_rng(1).normal(*posterior(y), size=(4, 2000))
    ll_b = stats.t.logpdf(y, 3, mu[..., None], SIG)  # a heavier-tailed rival
    a, b = loo(ll_a), loo(ll_b)
    delta, se = elpd_difference(a, b)
    table = az.compare(
        {
            "a": az.from_dict({"posterior": {"mu": mu}, "log_likelihood": {"y": ll_a}}),
            "b": az.from_dict({"posterior": {"mu": mu}, "log_likelihood": {"y": ll_b}}),
        },
        round_to="none",
    )
    # arviz ranks models best first; elpd_diff of the worse is negative.
    worse = table.index[1]
    assert worse == "b" and delta > 0
    assert table.loc["b", "elpd_diff"] == pytest.approx(-delta, abs=0.01)  # r_eff differs
    assert table.loc["b", "dse"] == pytest.approx(se * math.sqrt(29 / 30), rel=0.01)
    # Paired se is far below the combined unpaired se (the point of pairing).
    assert se < 0.5 * math.hypot(a.se, b.se)
    assert elpd_difference(a.pointwise, a.pointwise) == (0.0, 0.0)
    with pytest.raises(CriteriaError, match="same observations"):
        elpd_difference(a.pointwise, b.pointwise[:-1])


def test_aic_bic_definitions():
    # Normal sample with unknown mean and sd: the maximised log-likelihood has the
    # closed form -n/2 (log(2 pi s²_ml) + 1); AIC = 2k - 2 lnL, BIC = k ln n - 2 lnL.
    y = np.random.default_rng(4).normal(2.0, 0.5, 40)
    s2 = np.var(y)  # ML variance
    max_ll = float(np.sum(stats.norm.logpdf(y, y.mean(), math.sqrt(s2))))
    assert max_ll == pytest.approx(-20 * (math.log(2 * math.pi * s2) + 1), rel=1e-12)
    assert aic(max_ll, 2) == pytest.approx(4 - 2 * max_ll, rel=1e-12)
    assert bic(max_ll, 2, 40) == pytest.approx(2 * math.log(40) - 2 * max_ll, rel=1e-12)
    with pytest.raises(CriteriaError, match="non-negative int"):
        aic(max_ll, -1)
    with pytest.raises(CriteriaError, match="positive int"):
        bic(max_ll, 2, 0)
    with pytest.raises(CriteriaError, match="finite"):
        aic(float("nan"), 2)


def test_input_errors():
    with pytest.raises(CriteriaError, match="shape"):
        loo(np.zeros(10))
    with pytest.raises(CriteriaError, match="NaN"):
        waic(np.full((10, 3), np.nan))
    with pytest.raises(CriteriaError, match="reff"):
        loo(np.zeros((10, 3)), reff=1.5)
    with pytest.raises(CriteriaError, match="one label per observation"):
        logo(np.zeros((10, 3)), [0, 1])
