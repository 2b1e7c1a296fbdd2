"""Smoke test of the forward-model benchmark (bayesbeam.jobs.bench); no timing assertions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayesbeam.jobs.bench import bench_beam, bench_params, format_bench, run_bench
from bayesbeam.physics.forward import Forward

KEYS = ("per_set_s", "expm_per_set_s", "rk45_per_set_s", "rk45_elements", "max_rel_diff")


def test_run_bench_small():
    # 4 sets of 128 samples, RK45 at 2 elements: the same code paths as the run
    # (64 sets, 1280 samples, RK45 at 4 elements) in about a second.
    res = run_bench(n_sets=4, n_samples=128, repeats=1, rk45_elements=2, n_elements=8)
    for key in KEYS:
        assert key in res
        assert math.isfinite(res[key]) and res[key] > 0
    assert res["rk45_elements"] == 2 and res["n_sets"] == 4 and res["n_samples"] == 128
    # Issue 2 target: the batched forward model agrees with expm stepping of the same modal
    # matrices to < 1e-6 (expm stepping itself is good to ~1e-7 over 1280 steps).
    assert res["max_rel_diff"] < 1e-6
    text = format_bench(res)
    assert "128 samples" in text and "RK45 (2 el.)" in text


def test_bench_parameters_give_a_few_percent_damping():
    # The benchmark's sets are physical: f1 ≈ 11 Hz and modal damping of a few percent.
    fwd = Forward(bench_beam(), "viscous+sh", np.arange(2) * 0.003906)
    theta = bench_params(fwd, 3, np.random.default_rng(0))
    assert theta.shape == (3, 5) and fwd.check(theta).all()
    for row in theta:
        f, z = fwd.modes(row)
        assert 9.5 < f[0] < 13.0
        assert 0.005 < z[0] < 0.05


@pytest.mark.parametrize("kwargs", [{"n_sets": 0}, {"n_samples": 1}, {"repeats": 0}])
def test_run_bench_rejects_bad_sizes(kwargs):
    with pytest.raises(ValueError, match="must be"):
        run_bench(**kwargs)
