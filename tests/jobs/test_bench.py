"""Smoke test of the forward-model benchmark (bayesbeam.jobs.bench); no timing assertions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayesbeam.jobs import bench
from bayesbeam.jobs.bench import bench_beam, bench_params, format_bench, run_bench
from bayesbeam.physics.forward import Forward
from bayesbeam.physics.propagate import numba_available

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


def test_path_table_reports_each_model_and_the_path_taken():
    # Issue 13: the path table (closed form for the classically damped models, full
    # propagation for spatial hysteresis, its eigen-solutions in band with a sensor band),
    # on a small problem (same code as the real run).
    res = run_bench(n_sets=3, n_samples=64, repeats=1, rk45_elements=2, n_elements=6,
                    path_samples=(64, 96))
    rows = res["paths"]
    assert [(r["model"], r["n_samples"], r["band_hz"]) for r in rows] == [
        (m, n, b) for n in (64, 96) for m, b in (("viscous", None), ("viscous+kv", None),
                                                  ("viscous+sh", None),
                                                  ("viscous+sh", bench.PATH_BAND))]
    for row in rows:
        expected = "full" if row["model"] == "viscous+sh" else "closed-form"
        if row["band_hz"] is not None:
            expected = f"band-modes {row['band_hz']:g} Hz"
        assert row["path"] == expected
        for key in ("per_set_s", "full_per_set_s", "bare_per_set_s"):
            assert math.isfinite(row[key]) and row[key] > 0
        if row["band_hz"] is not None:
            # The bench beam's modes at 11, 69 and 193 Hz: two inside 100 Hz; the band
            # changes the signal, so no difference to the full propagation is claimed
            # (the path's accuracy: tests/physics/test_modal_coupled.py).
            assert row["modes_in_band"] == 2 and math.isnan(row["max_rel_diff_vs_full"])
            continue
        assert row["modes_in_band"] == 12  # 6 elements, 2 dofs per node, clamped root
        # The closed form and the full propagation are both exact to rounding (issue 13:
        # 1e-9 relative; tests/physics/test_forward_classical.py).
        assert row["max_rel_diff_vs_full"] <= 1e-9
        # The bare loop is compiled where numba is (a dependency), like the closed form.
        assert row["bare_loop"] == ("compiled" if numba_available() else "numpy")
        assert row["closed_form_backend"] == ("numba" if numba_available() else "numpy")
    text = format_bench(res)
    assert "closed-form" in text and "viscous+kv" in text and "path/bare" in text
    assert f"bare = {rows[0]['bare_loop']} loop" in text


def test_bare_loops_agree_and_numpy_one_is_the_fallback(monkeypatch):
    # The compiled bare loop sums Re r^k over the modes; the numpy one only rotates: the
    # sum of its final rotations is the compiled loop's last sample (rounding: a few
    # hundred products of unit numbers).
    rot = np.exp(1j * np.random.default_rng(1).uniform(0, np.pi, (3, 5)))
    kind, loop = bench._bare_loop()
    if kind == "compiled":
        y = loop(rot, 301)
        z = bench._bare_rotations(rot, 300)
        assert np.abs(y[:, -1] - z.real.sum(axis=1)).max() <= 1e-12
    monkeypatch.setattr(bench, "compiled_kernel", lambda kernel: None)
    assert bench._bare_loop() == ("numpy", bench._bare_rotations)


def test_path_table_can_be_left_out_and_rejects_bad_lengths():
    res = run_bench(n_sets=2, n_samples=32, repeats=1, rk45_elements=2, n_elements=4,
                    path_samples=())
    assert res["paths"] == [] and "paths (" not in format_bench(res)
    with pytest.raises(ValueError, match="path_samples"):
        run_bench(path_samples=(1,))
