"""``ModelScore.save``: the complete ArviZ tree of a scored model, with units, for ArviZ.

Stand-in posteriors (clouds of chosen draws, conftest) are scored by ``evaluate`` with a
ready result, so no sampler runs.
"""

from __future__ import annotations

import dataclasses
import warnings

import arviz
import numpy as np
import pytest

from bayesbeam.comparison.scoring import evaluate
from bayesbeam.inference.problem import Problem
from tests.comparison.test_compare_modes import C_D, GAMMA, NE, E, release_trial

GROUPS = ("posterior", "unconstrained_posterior", "sample_stats", "log_likelihood",
          "posterior_predictive", "observed_data", "prior")


@pytest.fixture(scope="module")
def scores(gaussian_cloud_result):
    trial = release_trial()
    out = {}
    for model, truth in (("viscous", [E, GAMMA, 0.005, 1e-5]),
                         ("kv+ar1_noise", [E, C_D, 0.005, 1e-5, 0.1])):
        pr = Problem(trial, model, n_elements=NE)
        # a tight cloud on the truth (E to 1e-6 in log: the signal's phase is sensitive)
        sd_u = [1e-6, 1e-3, 1e-5, 1e-2, 1e-2][: len(truth)]
        res = gaussian_cloud_result(pr, truth, sd_u, nsteps=20, nwalkers=8)
        res = dataclasses.replace(res, settings={"n_elements": NE, "initial": "release"})
        out[model] = evaluate(trial, model, result=res, problem=pr, n_loo_draws=80,
                              n_proposal=400)
    return trial, out


def test_saved_trees_carry_units_and_feed_arviz(scores, tmp_path):
    trial, by_model = scores
    trees = {}
    for model, score in by_model.items():
        score.save(tmp_path / model)
        tree = trees[model] = arviz.from_netcdf(tmp_path / model / "posterior.nc")
        assert set(GROUPS) <= set(tree.children), model
        for group in GROUPS:
            for name, var in tree[group].data_vars.items():
                assert var.attrs.get("units"), (model, group, name)
        for group in ("log_likelihood", "posterior_predictive", "observed_data"):
            assert tree[group]["time"].attrs["units"] == "s"
        post = tree["posterior"]
        assert post["E"].attrs["units"] == "Pa" and post["sigma"].attrs["units"] == "m"
        assert tree["observed_data"]["y"].attrs["units"] == "m"
        np.testing.assert_array_equal(tree["observed_data"]["time"].values, trial.times)
        # The file holds the score's own draws and pointwise terms.
        np.testing.assert_array_equal(tree["log_likelihood"]["y"].values, score.loglik)
        assert post.sizes["draw"] == score.loglik.shape[1]
    assert trees["kv+ar1_noise"]["posterior"]["c_d"].attrs["units"] == "Pa s"
    assert trees["kv+ar1_noise"]["posterior"]["rho"].attrs["units"] == "1"
    with warnings.catch_warnings():  # a stand-in cloud of 160 draws: high Pareto k
        warnings.filterwarnings("ignore", message="Estimated shape parameter of Pareto")
        table = arviz.compare(trees)
        for model, score in by_model.items():
            # Same draws and terms; the relative efficiency is estimated slightly
            # differently by ArviZ (0.01 nat on such runs): agreement to 0.1 nat.
            assert arviz.loo(trees[model]).elpd == pytest.approx(score.loo.elpd_loo, abs=0.1)
    assert set(table.index) == set(by_model)


def test_the_scored_result_knows_its_problem(scores):
    _, by_model = scores
    score = by_model["viscous"]
    assert score.result.problem is score.draws.problem
    assert score.result.signal_unit == "m"


def test_scores_with_the_density_shared_with_a_helper_equal_the_serial_ones(
        gaussian_cloud_result, monkeypatch):
    # The diagnosis evaluates the bridge's proposal draws and Laplace's stencil through
    # a ParallelLogProb with one helper process: the same values bit for bit (its rows
    # are the problem's own), and the calls made in the helper still counted.
    from bayesbeam.inference import parallel as par
    from bayesbeam.inference.parallel import ParallelLogProb

    monkeypatch.setattr(par, "MIN_SECONDS", 0.0)  # start the helper on the first batch
    trial = release_trial()
    pr = Problem(trial, "viscous", n_elements=NE)
    res = gaussian_cloud_result(pr, [E, GAMMA, 0.005, 1e-5], [1e-6, 1e-3, 1e-5, 1e-2],
                                nsteps=20, nwalkers=8)
    res = dataclasses.replace(res, settings={"n_elements": NE, "initial": "release"})
    kw = {"result": res, "problem": pr, "n_loo_draws": 80, "n_proposal": 400}
    serial = evaluate(trial, "viscous", **kw)
    with ParallelLogProb(pr.log_prob, helpers=1) as shared:
        split = evaluate(trial, "viscous", log_prob=shared, **kw)
        assert shared.batches_split >= 1
    assert split.evidence.log_z == serial.evidence.log_z
    assert split.laplace_log_z == serial.laplace_log_z
    assert split.n_calls == serial.n_calls
