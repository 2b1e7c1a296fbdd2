"""The complete ArviZ tree of a fit from the Python API: every group, units, ArviZ's LOO."""

from __future__ import annotations

import dataclasses
import json
import warnings

import arviz
import numpy as np
import pytest

from bayesbeam.inference.predictive import LOGLIK_DRAWS, PPC_DRAWS, PRIOR_DRAWS, predictive_steps
from bayesbeam.inference.problem import Problem
from bayesbeam.inference.results import FitResult, ResultError
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

NE = 6  # elements of simulation and problem: the stand-in posteriors sit on the truth
#: Physical truth of the synthetic record (E Pa, gamma kg/(m s), w0 m, sigma m) and the
#: spread of the stand-in posterior in the sampling space.
TRUTH = {"viscous": [6.2e10, 0.2, 0.005, 1e-5],
         "viscous+ar1_noise": [6.2e10, 0.2, 0.005, 1e-5, 0.1]}
SD_U = {"viscous": [1e-6, 1e-3, 1e-5, 1e-2], "viscous+ar1_noise": [1e-6, 1e-3, 1e-5, 1e-2, 1e-2]}
#: 150 steps x 16 walkers = 2400 draws: more than LOGLIK_DRAWS, so the tree is thinned.
NSTEPS, NWALKERS = 150, 16
GROUPS = ("posterior", "unconstrained_posterior", "sample_stats", "log_likelihood",
          "posterior_predictive", "observed_data", "prior")


@pytest.fixture(scope="module")
def trial():
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)
    return simulate_trial(beam, "viscous", {"gamma": 0.2}, duration=0.5, dt=1 / 256,
                          noise_sd=1e-5, seed=3, n_elements=NE)


@pytest.fixture(scope="module")
def fits(trial, gaussian_cloud_result):
    """Stand-in posteriors of two models, each with the problem it belongs to."""
    out = {}
    for k, (model, truth) in enumerate(TRUTH.items()):
        pb = Problem(trial, model, n_elements=NE)
        res = gaussian_cloud_result(pb, truth, SD_U[model], nsteps=NSTEPS, nwalkers=NWALKERS,
                                    seed=k)
        # settings as fit() records them (with_problem(trial) rebuilds the problem by them)
        res = dataclasses.replace(res, settings={"n_elements": NE, "initial": "release"})
        out[model] = res.with_problem(pb)
    return out


@pytest.fixture(scope="module")
def trees(fits):
    return {m: r.to_inference_data() for m, r in fits.items()}


def test_tree_holds_every_group_on_the_same_draws(fits, trees, trial):
    for model, tree in trees.items():
        assert set(GROUPS) <= set(tree.children), model
        post, ll = tree["posterior"], tree["log_likelihood"]
        # Thinned to at most LOGLIK_DRAWS draws, all walkers; log_likelihood on exactly
        # the posterior's draws (arviz.loo reads the posterior for its relative ESS).
        n_draws = post.sizes["chain"] * post.sizes["draw"]
        assert post.sizes["chain"] == NWALKERS and NWALKERS <= n_draws <= LOGLIK_DRAWS
        assert n_draws < NSTEPS * NWALKERS  # it was thinned
        assert ll["y"].dims == ("chain", "draw", "time")
        assert ll["y"].shape == (NWALKERS, post.sizes["draw"], trial.times.size)
        np.testing.assert_array_equal(ll["draw"].values, post["draw"].values)
        assert tree["sample_stats"]["lp"].shape == post["E"].shape
        # The replicated data: a labelled subset of the posterior's draws.
        pp = tree["posterior_predictive"]
        want = predictive_steps(post.sizes["draw"], NWALKERS, PPC_DRAWS)
        np.testing.assert_array_equal(pp["draw"].values, post["draw"].values[want])
        assert pp["y"].shape == (NWALKERS, want.size, trial.times.size)
        # The measured signal on its time axis (s), and the prior.
        np.testing.assert_array_equal(tree["observed_data"]["y"].values, trial.values)
        np.testing.assert_array_equal(tree["observed_data"]["time"].values, trial.times)
        assert tree["prior"]["E"].shape == (1, PRIOR_DRAWS)
        assert tree.attrs["signal_unit"] == "m"
        # The same result gives the same tree (its noise draws are seeded by the chain).
        again = fits[model].to_inference_data()
        np.testing.assert_array_equal(again["posterior_predictive"]["y"].values,
                                      pp["y"].values)


def test_pointwise_log_likelihood_sums_to_the_problems_total(fits, trees):
    # The posterior draws read back from the tree (u) scored by the Problem's own
    # log_likelihood: the tree's pointwise terms must be at exactly those draws. The
    # two computations share the residuals and differ only in the order of summation
    # (a sum over T = 128 terms of size ~10): rounding ~T eps ~ 3e-14 relative, so
    # rtol 1e-10 holds with margin, while a term at the wrong draw or one term missing
    # (~10 nats of ~1300) fails it.
    for model, tree in trees.items():
        pb = fits[model].problem
        up = tree["unconstrained_posterior"]
        u = np.stack([up[n].values for n in pb.names], axis=-1).reshape(-1, pb.ndim)
        total = pb.log_likelihood(u)
        pointwise = tree["log_likelihood"]["y"].values.reshape(u.shape[0], -1).sum(axis=-1)
        assert np.all(np.isfinite(total))
        np.testing.assert_allclose(pointwise, total, rtol=1e-10)


def test_arviz_loo_and_compare_run_on_the_python_api_trees(fits, trees, tmp_path):
    files = {}
    for model, tree in trees.items():
        fits[model].save(tmp_path / model, idata=tree)
        files[model] = arviz.from_netcdf(tmp_path / model / "posterior.nc")
    with warnings.catch_warnings():
        # A stand-in posterior of few independent draws may have high Pareto k values.
        warnings.filterwarnings("ignore", message="Estimated shape parameter of Pareto")
        table = arviz.compare(files)  # the files that FitResult.save writes
        # The file holds the tree's draws and terms: ArviZ's LOO of both is the same
        # (the same float64 arrays, so equal to rounding; compare's table is rounded).
        loo_file, loo_tree = arviz.loo(files["viscous"]), arviz.loo(trees["viscous"])
    assert set(table.index) == set(trees)
    assert loo_file.elpd == pytest.approx(loo_tree.elpd, rel=1e-12)
    assert np.isfinite(loo_tree.elpd)


def _assert_units_everywhere(tree, signal_unit):
    for group in GROUPS:
        for name, var in tree[group].data_vars.items():
            assert var.attrs.get("units"), (group, name)
            assert var.attrs.get("long_name"), (group, name)
    for group in ("log_likelihood", "posterior_predictive", "observed_data"):
        assert tree[group]["time"].attrs["units"] == "s"
    assert tree["posterior"]["E"].attrs["units"] == "Pa"
    assert tree["posterior"]["gamma"].attrs["units"] == "kg/(m s)"
    assert tree["posterior"]["sigma"].attrs["units"] == signal_unit
    assert tree["observed_data"]["y"].attrs["units"] == signal_unit
    assert tree["posterior_predictive"]["y"].attrs["units"] == signal_unit
    assert tree["log_likelihood"]["y"].attrs["units"] == "nat"


def test_units_survive_save_and_load(fits, trial, tmp_path):
    res = fits["viscous+ar1_noise"]
    paths = res.save(tmp_path / "fit")
    tree = arviz.from_netcdf(paths["netcdf"])
    _assert_units_everywhere(tree, "m")
    assert tree["posterior"]["rho"].attrs["units"] == "1"
    # summary.json describes the full chain; posterior.nc holds the thinned draws.
    summary = json.loads(paths["summary"].read_text(encoding="utf-8"))
    assert summary["diagnostics"]["n_samples"] == NSTEPS * NWALKERS
    # A loaded result knows its signal's unit (no problem: only the groups it has) ...
    back = FitResult.load(tmp_path / "fit")
    assert back.signal_unit == "m" and back.problem is None
    assert back.to_inference_data()["posterior"]["sigma"].attrs["units"] == "m"
    # ... and writes the complete tree again once given its trial.
    again = back.with_problem(trial).to_inference_data()
    _assert_units_everywhere(again, "m")
    np.testing.assert_array_equal(again["log_likelihood"]["y"].values,
                                  tree["log_likelihood"]["y"].values)


def test_velocity_record_gets_velocity_units(trial, gaussian_cloud_result):
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10, quantity="velocity")
    tr = simulate_trial(beam, "viscous", {"gamma": 0.2}, duration=0.25, dt=1 / 256,
                        noise_sd=1e-4, seed=3, n_elements=NE)
    pb = Problem(tr, "viscous+sensor_offset", n_elements=NE)
    x = pb.priors.to_theta(np.zeros((1, pb.ndim)))[0]  # any point: units only
    tree = gaussian_cloud_result(pb, x, np.full(pb.ndim, 1e-3), nsteps=4).with_problem(
        pb).to_inference_data()
    for name in ("sigma", "offset"):
        assert tree["posterior"][name].attrs["units"] == "m/s"
    assert tree["observed_data"]["y"].attrs["units"] == "m/s"


def test_thin_keeps_at_most_max_draws_evenly_spaced_with_the_last_step(fits):
    res = fits["viscous"]
    steps = np.arange(NSTEPS)
    for n in (1, 16, 100, 999, 1000, 2399, 2400, 10_000):
        th = res.thin(n)
        kept = th.chain.nsteps
        assert kept * NWALKERS <= max(n, NWALKERS), n
        # at least half of the allowed steps: the spacing is the smallest that fits
        assert kept >= min(NSTEPS, max(1, n // NWALKERS)) / 2, n
        # which steps: evenly spaced, the last one included (compared by their values)
        idx = [int(np.flatnonzero(np.all(res.chain.samples[:, 0] == s, axis=1))[0])
               for s in th.chain.samples[:, 0]]
        assert idx[-1] == steps[-1] and len(set(np.diff(idx))) <= 1, n
        np.testing.assert_array_equal(th.chain.log_prob, res.chain.log_prob[idx])
    assert res.thin(NSTEPS * NWALKERS) is res


def test_with_problem_checks_the_problem(fits, trial):
    res = fits["viscous"]
    other = Problem(trial, "viscous+kv", n_elements=NE)
    with pytest.raises(ResultError, match="pass the problem that was fitted"):
        res.with_problem(other)
    # From the trial: the problem on the result's own mesh, model and priors.
    plain = FitResult(res.model, res.chain, res.priors,
                      settings={"n_elements": NE, "initial": "release"})
    rebuilt = plain.with_problem(trial).problem
    assert rebuilt.n_elements == NE and rebuilt.priors == res.priors
    with pytest.raises(ResultError, match="n_elements"):
        FitResult(res.model, res.chain, res.priors).with_problem(trial)
    # Without a problem the tree holds only what it is given (as before).
    bare = FitResult(res.model, res.chain, res.priors).to_inference_data()
    assert "log_likelihood" not in bare.children and "prior" not in bare.children
    assert bare["posterior"]["E"].attrs["units"] == "Pa"
    assert "units" not in bare["posterior"]["sigma"].attrs  # the signal's unit is unknown
