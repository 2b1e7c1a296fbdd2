"""FitResult: physical summaries, ArviZ/NetCDF round trip, JSON record, plots."""

from __future__ import annotations

import json
import logging
import math
from dataclasses import FrozenInstanceError

import arviz
import numpy as np
import pytest
from scipy import stats

from bayesbeam.inference.results import FitResult, ResultError, make_provenance
from bayesbeam.stats.families import LogNormal, LogUniform, Normal
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import Chain

NSTEPS, NWALKERS = 400, 20
N = NSTEPS * NWALKERS
PRIORS = PriorSet(
    {"E": LogUniform(1e9, 1e12), "gamma": LogNormal(1e-2, 1.0), "offset": Normal(0.0, 1.0)}
)
# Independent Gaussian draws in u: E and gamma are then log-normal in physical units.
MU_U = np.array([math.log(7e10), math.log(2e-3), 0.1])
SD_U = np.array([0.05, 0.2, 0.01])
OBS_T = np.linspace(0.0, 1.0, 30)


def make_chain(seed=0, **over):
    rng = np.random.default_rng(seed)
    u = MU_U + SD_U * rng.standard_normal((NSTEPS, NWALKERS, 3))
    kw = dict(
        samples=u,
        log_prob=PRIORS.log_prior_u(u),
        names=PRIORS.names,
        tau=np.array([1.0, 1.0, 1.0]),
        ess=np.full(3, float(N)),
        rhat=np.ones(3),
        acceptance_fraction=np.full(NWALKERS, 0.4),
        n_calls=N,
        converged=True,
        seconds=1.5,
        burn_in=10,
        seed=seed,
    )
    kw.update(over)
    return Chain(**kw)


@pytest.fixture(scope="module")
def result():
    return FitResult(
        model="viscous",
        chain=make_chain(),
        priors=PRIORS,
        map_u=MU_U,
        settings={"nwalkers": NWALKERS, "quantity": "displacement", "dt": np.float64(1e-3)},
        provenance=make_provenance({"trial": "synthetic"}),
    )


def test_summary_matches_analytic_lognormal(result):
    s = result.summary()
    assert list(s) == ["E", "gamma", "offset"]
    assert all(list(row) == ["mean", "sd", "q05", "q50", "q95"] for row in s.values())
    z = stats.norm.ppf(0.95)
    for j, name in enumerate(("E", "gamma")):
        mu, sd = MU_U[j], SD_U[j]
        # log-normal moments and quantiles (physical units)
        mean = math.exp(mu + sd**2 / 2)
        std = mean * math.sqrt(math.expm1(sd**2))
        # Monte-Carlo tolerances for N iid draws, 4 standard errors each:
        # mean: std/sqrt(N); quantile q: sqrt(q(1-q)/N)/f(x_q); sd: ~std*sqrt((kurt+2)/(4N))
        assert s[name]["mean"] == pytest.approx(mean, abs=4 * std / math.sqrt(N))
        kurt = math.exp(4 * sd**2) + 2 * math.exp(3 * sd**2) + 3 * math.exp(2 * sd**2) - 6
        assert s[name]["sd"] == pytest.approx(std, abs=4 * std * math.sqrt((kurt + 2) / (4 * N)))
        ref = stats.lognorm(s=sd, scale=math.exp(mu))
        for key, q in (("q05", 0.05), ("q50", 0.5), ("q95", 0.95)):
            se = math.sqrt(q * (1 - q) / N) / ref.pdf(ref.ppf(q))
            assert s[name][key] == pytest.approx(ref.ppf(q), abs=4 * se)
        assert s[name]["q05"] < s[name]["q50"] < s[name]["q95"]
    # Normal prior: identity transform, plain normal summary
    assert s["offset"]["q95"] - s["offset"]["q05"] == pytest.approx(2 * z * SD_U[2], rel=0.05)
    np.testing.assert_allclose(result.map_theta, [7e10, 2e-3, 0.1], rtol=1e-12)


def test_str_and_json_record(result):
    text = str(result)
    assert "viscous" in text and "converged" in text
    for name in ("E", "gamma", "offset", "q05", "q95", "ess", "rhat"):
        assert name in text
    d = result.to_json_dict()
    for key in ("model", "posterior", "ess_min", "tau_max", "rhat_max", "converged", "seconds"):
        assert key in d
    assert d["model"] == "viscous"
    assert d["priors"] == PRIORS.to_dict()
    assert d["ess_min"] == N
    assert d["map"]["E"] == pytest.approx(7e10)
    json.dumps(d, allow_nan=False)  # strict JSON

    # a run too short to estimate tau: inf becomes null, the record stays strict JSON
    short = FitResult("viscous", make_chain(tau=np.array([np.inf, 2.0, 2.0])), PRIORS)
    d2 = short.to_json_dict()
    assert d2["tau_max"] is None
    assert d2["map"] is None
    json.dumps(d2, allow_nan=False)


def test_inference_data_and_netcdf_round_trip(result, tmp_path):
    rng = np.random.default_rng(5)
    y_obs = rng.standard_normal(OBS_T.size)
    loglik = rng.standard_normal((NWALKERS, NSTEPS, OBS_T.size))
    ppc = rng.standard_normal((NWALKERS, 7, OBS_T.size))  # a subset of draws
    kw = dict(
        posterior_predictive=ppc,
        log_likelihood=loglik,
        observed=y_obs,
        prior_samples=300,
        obs_coords=OBS_T,
    )
    tree = result.to_inference_data(**kw)
    for group in (
        "posterior",
        "unconstrained_posterior",
        "sample_stats",
        "log_likelihood",
        "posterior_predictive",
        "observed_data",
        "prior",
    ):
        assert group in tree.children, group
    post = tree["posterior"]
    assert post["E"].dims == ("chain", "draw")
    assert post["E"].shape == (NWALKERS, NSTEPS)
    np.testing.assert_allclose(
        post["E"].values, np.exp(result.chain.samples[:, :, 0]).T, rtol=1e-15
    )
    assert tree["log_likelihood"]["y"].dims == ("chain", "draw", "time")
    assert tree["prior"]["gamma"].shape == (1, 300)
    assert np.all(tree["prior"]["E"].values >= 1e9) and np.all(tree["prior"]["E"].values <= 1e12)

    paths = result.save(tmp_path / "out", idata=tree)
    back = arviz.from_netcdf(paths["netcdf"])
    for group in ("posterior", "sample_stats", "log_likelihood", "posterior_predictive"):
        for var in tree[group].data_vars:
            np.testing.assert_array_equal(back[group][var].values, tree[group][var].values)
    np.testing.assert_array_equal(back["observed_data"]["time"].values, OBS_T)
    assert back.attrs["model"] == "viscous"
    assert json.loads(back.attrs["priors"]) == PRIORS.to_dict()

    again = FitResult.load(tmp_path / "out")
    np.testing.assert_array_equal(again.chain.samples, result.chain.samples)
    np.testing.assert_array_equal(again.chain.log_prob, result.chain.log_prob)
    assert again.priors == result.priors
    assert again.summary() == result.summary()
    assert again.chain.seed == result.chain.seed and again.chain.converged
    np.testing.assert_array_equal(again.map_u, result.map_u)
    assert dict(again.settings) == json.loads(json.dumps(dict(result.settings), default=float))

    summary = json.loads(
        paths["summary"].read_text(encoding="utf-8"),
        parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"),
    )
    for name, row in result.summary().items():
        assert summary["posterior"][name] == pytest.approx(row, rel=1e-15)
    assert set(summary["posterior"]["E"]) == {"mean", "sd", "q05", "q50", "q95"}


def test_log_likelihood_group_feeds_arviz_loo(tmp_path):
    # Normal mean model, y_i ~ N(m, 1): pointwise log-likelihood for PSIS-LOO.
    rng = np.random.default_rng(9)
    y = rng.normal(0.3, 1.0, 40)
    priors = PriorSet({"m": Normal(0.0, 10.0)})
    # exact posterior of m (flat-ish prior): N(mean(y), 1/sqrt(n)), iid draws
    m = y.mean() + rng.standard_normal((NSTEPS, NWALKERS, 1)) / math.sqrt(y.size)
    chain = make_chain(
        samples=m,
        log_prob=np.zeros((NSTEPS, NWALKERS)),
        names=("m",),
        tau=np.ones(1),
        ess=np.full(1, float(N)),
        rhat=np.ones(1),
    )
    res = FitResult("mean", chain, priors)
    ll = stats.norm.logpdf(y[None, None, :], loc=np.swapaxes(m, 0, 1), scale=1.0)
    res.save(tmp_path, log_likelihood=ll, observed=y)
    loo = arviz.loo(arviz.from_netcdf(tmp_path / "posterior.nc"))
    # Exact LOO for a flat prior: y_i | y_-i ~ N(mean(y_-i), 1 + 1/(n-1)).
    n = y.size
    mean_minus_i = (y.sum() - y) / (n - 1)
    exact = stats.norm.logpdf(y, mean_minus_i, math.sqrt(1 + 1 / (n - 1))).sum()
    # PSIS error with 8000 iid draws is ~1e-2; the N(0, 10) prior shifts it by ~1e-3.
    assert loo.elpd == pytest.approx(exact, abs=0.1)
    assert loo.p == pytest.approx(1.0, abs=0.3)  # one parameter; sampling error ~0.1


def test_validation_errors(result):
    with pytest.raises(ResultError, match="do not match the priors"):
        FitResult("m", make_chain(), PRIORS.subset(["gamma", "E", "offset"]))
    with pytest.raises(ResultError, match="map_u"):
        FitResult("m", make_chain(), PRIORS, map_u=np.zeros(2))
    with pytest.raises(ResultError, match="log_likelihood"):
        result.to_inference_data(log_likelihood=np.zeros((NWALKERS, 5, 3)))
    with pytest.raises(ResultError, match="chains"):
        result.to_inference_data(posterior_predictive=np.zeros((3, 5, 3)))
    with pytest.raises(ResultError, match="differ in length"):
        result.to_inference_data(observed=np.zeros(4), posterior_predictive=np.zeros((20, 2, 5)))
    with pytest.raises(ResultError, match="obs_coords"):
        result.to_inference_data(observed=np.zeros(4), obs_coords=np.zeros(5))
    with pytest.raises(ResultError, match="prior_samples"):
        result.to_inference_data(prior_samples=np.zeros((5, 2)))
    with pytest.raises(ResultError, match="no result file"):
        FitResult.load("/nonexistent/dir")
    with pytest.raises(FrozenInstanceError):
        result.model = "other"
    assert not result.chain.samples.flags.writeable
    with pytest.raises(TypeError):
        result.settings["nwalkers"] = 3


def test_plots_write_images(result, tmp_path):
    png = b"\x89PNG\r\n\x1a\n"
    c = result.plot_corner(tmp_path / "corner.png", truths=[7e10, 2e-3, 0.1])
    t = result.plot_trace(tmp_path / "trace.png")
    for p in (c, t):
        data = p.read_bytes()
        assert data[:8] == png and len(data) > 10_000


def test_plot_corner_of_named_parameters(result, tmp_path):
    png = b"\x89PNG\r\n\x1a\n"
    two = result.plot_corner(tmp_path / "two.png", names=["gamma", "E"])
    one = result.plot_corner(tmp_path / "one.png", names=["E"], truths=[7e10])
    for p in (two, one):
        data = p.read_bytes()
        assert data[:8] == png and len(data) > 10_000
    with pytest.raises(ValueError, match="sampled parameters"):
        result.plot_corner(tmp_path / "bad.png", names=["E", "nope"])
    with pytest.raises(ValueError, match="no parameter"):
        result.plot_corner(tmp_path / "bad.png", names=[])
    assert not (tmp_path / "bad.png").exists()


def test_plot_corner_logs_wide_parameters_and_keeps_corner_quiet(tmp_path, caplog,
                                                                 monkeypatch):
    # E spread over ~4 decades (a ridge the data leave open) goes on a log axis.
    import corner

    from bayesbeam.inference.result_plots import _CornerNotes

    rng = np.random.default_rng(5)
    u = MU_U + np.array([2.0, 0.2, 0.01]) * rng.standard_normal((NSTEPS, NWALKERS, 3))
    res = FitResult(model="viscous", chain=make_chain(samples=u), priors=PRIORS,
                    map_u=MU_U, settings={"nwalkers": NWALKERS},
                    provenance=make_provenance({"trial": "synthetic"}))
    seen = {}
    real = corner.corner

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(corner, "corner", spy)
    with caplog.at_level("WARNING"):
        path = res.plot_corner(tmp_path / "wide.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert seen["axes_scale"] == ["log", "linear", "linear"]
    assert seen["labels"][0] == "E (log axis)"
    assert not [r for r in caplog.records if "contours" in r.getMessage()]
    # Where corner still finds too few points for contours (two such parameters on
    # linear axes) it says so on the root logger, once per panel: held and counted
    # inside plot_corner (a note on the figure), seen again outside it.
    wide = np.exp(u.reshape(-1, 3)[:, :2] * [1.0, 10.0])
    with caplog.at_level("WARNING"), _CornerNotes() as notes:
        real(wide)
    assert notes.count > 0
    assert not [r for r in caplog.records if "contours" in r.getMessage()]
    assert not logging.getLogger().filters
    with caplog.at_level("WARNING"):
        real(wide)
    assert len([r for r in caplog.records if "contours" in r.getMessage()]) == notes.count
