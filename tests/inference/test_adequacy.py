"""Model adequacy (bayesbeam.inference.adequacy) and the calibration cases of the issue.

The records are those of ``studies/adequacy_cases.py``: an independent route (a 64-element
model with every mode, sampled 16x faster, through a Kaiser FIR anti-alias filter and
interpolated onto the record's stamps), so no mesh of the fit reproduces them exactly (no
inverse crime). A 0.4 m aluminium strip, 50.8 x 2 mm, released from a 5 mm tip
deflection; accelerometer at the tip, 512 Hz, noise 0.02 m/s².
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from bayesbeam.inference.adequacy import LIMITS, assess, in_band
from bayesbeam.inference.fit import fit
from bayesbeam.inference.problem import Problem


def _load_study():
    path = Path(__file__).resolve().parents[2] / "studies" / "adequacy_cases.py"
    spec = importlib.util.spec_from_file_location("adequacy_cases", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


CASES = _load_study()  # the records' builder: one implementation, shared with the study
TRUE, NOISE, MASS = CASES.TRUE, CASES.NOISE, CASES.MASS


def _record(**kw):
    return CASES.record(**kw)


def test_true_model_is_adequate_and_a_wrong_one_is_not(gaussian_cloud_result):
    # Posterior stand-ins (a tight cloud) at the truth, and at the truth of a model that
    # lacks the added mass: the checks need no sampler to show their verdicts.
    rng = np.random.default_rng(1)
    trial = _record(n=1024)
    pb = Problem(trial, "viscous+kv", n_elements=32)
    truth = np.array([{**TRUE, "sigma": NOISE}[n] for n in pb.names])
    good = assess(pb, gaussian_cloud_result(pb, truth, 1e-6), rng=rng, n_draws=100)
    assert good["ok"], good["reasons"]
    assert good["noise_ratio"] == pytest.approx(1.0, abs=0.1)
    assert good["summary"].startswith("adequate")

    bad_trial = dataclasses.replace(_record(n=1024, added_mass=MASS), name="mass")
    pb2 = Problem(bad_trial, "viscous+kv", n_elements=32)
    bad = assess(pb2, gaussian_cloud_result(pb2, truth, 1e-6), rng=rng, n_draws=100)
    assert not bad["ok"]
    assert any("not white" in r for r in bad["reasons"])
    assert "bayesbeam diagnose" in bad["summary"]
    for key in ("noise_floor", "noise_ratio", "ljung_box", "spectral_line", "coverage_90",
                "coverage_band", "limits"):
        assert key in bad
    assert bad["limits"] == LIMITS


def _inside_90(result, truth):
    s = result.summary()
    return {n: s[n]["q05"] <= v <= s[n]["q95"] for n, v in truth.items()}


@pytest.mark.slow
@pytest.mark.parametrize("jitter", [False, True])
def test_default_fit_of_an_independent_acceleration_record_is_calibrated(jitter):
    # Issue "calibration that knows when not to trust itself": at 16 elements and without
    # the sensor band the default fit put γ and c_d at 1.7-1.8x the truth with tight
    # intervals and no warning; now the band removes the unresolved modes and the mesh
    # is refined at the MAP.
    res = fit(_record(jitter=jitter), "viscous+kv", progress=False)
    inside = _inside_90(res, {**{k: TRUE[k] for k in ("E", "gamma", "c_d")}, "sigma": NOISE})
    assert all(inside.values()), (inside, res.summary())
    assert res.adequacy["ok"], res.adequacy["reasons"]
    assert res.mesh["converged"] and res.mesh["n_elements"] > 16
    assert res.chain.converged


@pytest.mark.slow
def test_fit_that_leaves_out_a_mass_says_it_is_not_adequate():
    # 5 g, 6.7 cm inboard of the tip, fitted with viscous+kv on the nominal beam.
    res = fit(_record(added_mass=MASS), "viscous+kv", progress=False)
    ad = res.adequacy
    assert not ad["ok"]
    assert ad["noise_ratio"] > LIMITS["noise_ratio"]
    assert any("noise floor" in r for r in ad["reasons"])
    assert "NOT adequate" in str(res)
    js = res.to_json_dict()
    assert js["adequacy"]["ok"] is False and js["mesh"]["n_elements"] >= 16


def test_in_band_whitens_decimated_noise_and_keeps_a_line():
    # White noise decimated by 8 with the anti-alias filter: white inside the band
    # (rate / 2.56), falling off above it, so the whole series fails Ljung-Box (lag-1
    # correlation ~ sin(0.89 pi) / (0.89 pi) = 0.12) while its in-band part passes.
    from bayesbeam.physics.beam import Beam
    from bayesbeam.stats.whiteness import ljung_box
    from bayesbeam.trials.trial import Trial

    rng = np.random.default_rng(5)
    t = np.arange(48_000) * 1e-3
    beam = Beam.rectangular(0.3, 0.05, 2e-3, 0.08, E=7e10)
    d = Trial(times=t, values=rng.standard_normal(t.size), quantity="acceleration",
              beam=beam).decimate(8)
    z = d.values / d.values.std()
    assert ljung_box(z, 20)[1] < 1e-6
    zb, dtb = in_band(z, d.dt, d.sensor_band)
    assert ljung_box(zb, 20)[1] > LIMITS["p_min"]
    assert 1 / (2 * dtb) == pytest.approx(d.sensor_band, rel=0.01)
    # A sinusoid inside the band keeps its amplitude (Fourier frequency: no leakage).
    f0 = 40 / (z.size * d.dt)
    line = 0.3 * np.cos(2 * np.pi * f0 * (d.times - d.times[0]))
    lb, _ = in_band(line, d.dt, d.sensor_band)
    assert np.max(np.abs(lb)) == pytest.approx(0.3, rel=1e-6)
    # A band that reaches the Nyquist frequency leaves the series as it is.
    assert in_band(z, d.dt, 0.5 / d.dt)[0] is z


def test_prior_bound_pileup_on_constructed_posteriors():
    from bayesbeam.inference.adequacy import prior_bound_pileup
    from bayesbeam.stats.families import LogUniform, Normal, Uniform
    from bayesbeam.stats.priors import PriorSet

    rng = np.random.default_rng(0)
    priors = PriorSet({"gamma": LogUniform(50.0, 60.0), "rho": Uniform(0.0, 0.995),
                       "shift": Uniform(-1.0, 1.0), "offset": Normal(0.0, 1.0),
                       "added_mass_position": Uniform(0.0, 0.4)})
    n = 4000
    lo_g, hi_g = np.log(50.0), np.log(60.0)
    flat = np.column_stack([rng.uniform(lo_g, hi_g, n), rng.uniform(0, 0.995, n),
                            rng.uniform(-1, 1, n), rng.normal(0, 1, n),
                            rng.uniform(0, 0.4, n)])
    assert prior_bound_pileup(priors, flat) == []  # 1 % of a flat posterior per edge
    piled = flat.copy()
    # gamma against its lower bound (the data want less damping than the prior allows),
    # shift against its upper bound, rho at zero (no correlation: an answer), the mass
    # at the tip (a physical limit, not a prior's).
    piled[:, 0] = lo_g + np.abs(rng.normal(0, 0.002 * (hi_g - lo_g), n))
    piled[:, 2] = 1.0 - np.abs(rng.normal(0, 0.01, n))
    piled[:, 1] = np.abs(rng.normal(0, 1e-3, n))
    piled[:, 4] = 0.4 - np.abs(rng.normal(0, 1e-4, n))
    out = prior_bound_pileup(priors, piled.reshape(40, 100, 5))
    assert [(p["param"], p["side"]) for p in out] == [("gamma", "lower"), ("shift", "upper")]
    assert out[0]["bound"] == pytest.approx(50.0) and out[0]["share"] > 0.99
    assert out[1]["bound"] == 1.0 and 0.9 < out[1]["share"] < 0.99


def test_assess_flags_a_prior_bound_and_a_small_explained_variance(gaussian_cloud_result):
    from bayesbeam.stats.families import LogUniform

    rng = np.random.default_rng(1)
    trial = _record(n=1024)
    # gamma's prior ends just above the truth: the posterior (a tight cloud at the
    # truth) sits on the bound.
    pb = Problem(trial, "viscous+kv", {"gamma": LogUniform(TRUE["gamma"] / 10,
                                                           TRUE["gamma"] * 1.0001)},
                 n_elements=32)
    truth = np.array([{**TRUE, "sigma": NOISE}[n] for n in pb.names])
    ad = assess(pb, gaussian_cloud_result(pb, truth, 1e-6), rng=rng, n_draws=50)
    assert not ad["ok"]
    assert ad["prior_bounds"][0]["param"] == "gamma"
    assert ad["prior_bounds"][0]["side"] == "upper"
    assert any(r.startswith("posterior of gamma piles on its prior's upper bound")
               and "widen it" in r for r in ad["reasons"])
    assert ad["explained_variance"] > 0.9
    # σ of the order of the signal: the model explains little of it.
    big = np.std(pb.data) * 0.9
    pb2 = Problem(trial, "viscous+kv", n_elements=32)
    loud = np.array([{**TRUE, "sigma": big}[n] for n in pb2.names])
    ad2 = assess(pb2, gaussian_cloud_result(pb2, loud, 1e-6), rng=rng, n_draws=50)
    assert ad2["explained_variance"] == pytest.approx(1 - 0.81, abs=1e-6)
    assert any(r.startswith("the model explains only 19 % of the signal's variance")
               for r in ad2["reasons"])
    assert ad2["prior_bounds"] == []
