"""``bayesbeam fit`` writes the complete ArviZ tree: ArviZ compares two runs' files."""

from __future__ import annotations

import argparse
import json
import math
import warnings

import arviz
import numpy as np
import pytest

from bayesbeam.cli.fit import register, run
from bayesbeam.inference.problem import BETA1
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

E = 6.2e10
GROUPS = ("posterior", "unconstrained_posterior", "sample_stats", "log_likelihood",
          "posterior_predictive", "observed_data", "prior")


def _fit(argv):
    p = argparse.ArgumentParser(prog="bayesbeam")
    register(p.add_subparsers(dest="command"))
    return run(p.parse_args(argv))


@pytest.mark.slow
def test_two_cli_fits_give_trees_that_arviz_compares(tmp_path, capsys):
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E, quantity="velocity")
    w1 = BETA1**2 * math.sqrt(E * beam.I / (beam.rhoA * beam.length**4))
    toml = tmp_path / "trial.toml"
    # ζ1 = gamma / (2 rhoA ω1) = 1 % (physics.md §2); a velocity record: units m/s
    simulate_trial(beam, "viscous", {"gamma": 2 * beam.rhoA * w1 * 0.01}, duration=0.5,
                   dt=1 / 256, noise_sd=1e-4, seed=2, n_elements=4, out=toml)
    trees = {}
    for model in ("viscous", "viscous+kv"):
        out = tmp_path / model
        # a short budget: the point is the file, not convergence
        assert _fit(["fit", str(toml), "--model", model, "-o", str(out), "--json",
                     "--elements", "4", "--max-steps", "200", "--seed", "3"]) == 0
        payload = json.loads(capsys.readouterr().out)
        tree = trees[model] = arviz.from_netcdf(out / "posterior.nc")
        assert set(GROUPS) <= set(tree.children), model
        for group in GROUPS:
            for name, var in tree[group].data_vars.items():
                assert var.attrs.get("units"), (model, group, name)
        assert tree["posterior"]["sigma"].attrs["units"] == "m/s"
        assert tree["observed_data"]["y"].attrs["units"] == "m/s"
        assert tree["observed_data"]["time"].attrs["units"] == "s"
        post = tree["posterior"]
        assert post.sizes["chain"] * post.sizes["draw"] == payload["posterior_nc_draws"]
        assert tree["log_likelihood"]["y"].shape[:2] == (post.sizes["chain"], post.sizes["draw"])
        assert np.all(np.isfinite(tree["log_likelihood"]["y"].values))
    with warnings.catch_warnings():  # 200 steps: high Pareto k values are expected
        warnings.filterwarnings("ignore", message="Estimated shape parameter of Pareto")
        table = arviz.compare(trees)
    assert set(table.index) == set(trees)
