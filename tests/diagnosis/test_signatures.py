"""Residual signatures: estimators checked against closed forms and brute force."""

import dataclasses
import json

import numpy as np
import pytest
import scipy.optimize as sopt

from bayesbeam.diagnosis.signatures import compute_signatures, plot_signatures
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_signal
from bayesbeam.trials.trial import Trial

# 0.4 m aluminium strip (25 x 2 mm): f1 = 10.28 Hz, f2/f1 = 6.267 (physics.md §4).
L, WIDTH, THICK, RHO, E = 0.4, 0.025, 0.002, 2700.0, 70e9
BEAM = Beam.rectangular(L, WIDTH, THICK, RHO * L * WIDTH * THICK, E=E)


def _frequency_equation(x, mu):
    # physics.md §3: 1 + cos βL cosh βL + μ βL (cos βL sinh βL - sin βL cosh βL) = 0.
    return 1 + np.cos(x) * np.cosh(x) + mu * x * (np.cos(x) * np.sinh(x) - np.sin(x) * np.cosh(x))


def _laplace_draws(problem, x_true, rng, steps=24, walkers=16):
    """Posterior stand-in draws (u-space): the Laplace approximation around the truth."""
    from bayesbeam.inference.fit import laplace_covariance

    u0 = problem.priors.to_u(np.atleast_2d(x_true))[0]
    cov = laplace_covariance(problem, u0)
    if cov is None:  # not at an optimum (a misfit model): a tight ball is enough here
        cov = np.eye(problem.ndim) * 1e-12
    return u0, rng.multivariate_normal(u0, cov, size=(steps, walkers))


def _tap_trial(model, params, mu_extra=None, noise=0.01, seed=5):
    t = np.arange(512) / 512.0
    y = simulate_signal(BEAM, model, {**params, "p0": 1e-3}, t, n_elements=8, initial="impulse")
    rng = np.random.default_rng(seed)
    sd = noise * np.sqrt(np.mean(y**2))
    return Trial(times=t, values=y + sd * rng.standard_normal(t.size), quantity="displacement",
                 beam=BEAM, name="tap"), sd


def test_signatures_of_the_true_model_are_clean(result_from_samples):
    w1 = 2 * np.pi * 10.28
    gamma = 2 * BEAM.rhoA * w1 * 0.003
    trial, sd = _tap_trial("viscous", {"gamma": gamma})
    pb = Problem(trial, "viscous", n_elements=8, initial="impulse")
    x_true = np.array([E, gamma, 1e-3, sd])
    u0, u = _laplace_draws(pb, x_true, np.random.default_rng(6))
    sig = compute_signatures(pb, result_from_samples(pb, u, map_u=u0), seed=1)
    assert sig.white  # i.i.d. noise: Ljung-Box does not reject at 1 %
    # 512 samples: binomial sd of a coverage fraction 0.013; 4 sd.
    assert abs(sig.coverage90 - 0.9) < 0.055
    assert abs(sig.coverage50 - 0.5) < 0.09
    assert abs(sig.ratio_shift) < 3 * sig.ratio_shift_err + 1e-4
    assert abs(sig.residual_mean_z) < 4
    assert sig.model_frequencies[0] == pytest.approx(10.28, rel=1e-3)
    assert sig.rms_residual == pytest.approx(sd, rel=0.1)  # residual = noise (10 % for n=512)
    rec = sig.to_json_dict()
    json.dumps(rec)
    assert rec["ljung_box"]["white_at_1pc"]
    fig = plot_signatures(sig)
    assert len(fig.axes) >= 6
    # A record too short for decay windows: the panel says so (no empty legend, whose
    # warning the command line would print).
    short = dataclasses.replace(sig, decay_data=None, decay_model=None)
    fig = plot_signatures(short)
    assert "not measurable" in " ".join(t.get_text() for ax in fig.axes for t in ax.texts)


def test_tip_mass_raises_f2_over_f1_as_the_frequency_equation_says(result_from_samples):
    mu = 0.1
    b1 = sopt.brentq(_frequency_equation, 1.0, 2.0, args=(mu,))
    b2 = sopt.brentq(_frequency_equation, 3.5, 5.0, args=(mu,))
    assert b1 == pytest.approx(1.72274152, abs=1e-8)  # physics.md §4 check value
    ratio = (b2 / b1) ** 2
    ratio0 = (4.694091133 / 1.875104069) ** 2
    w1 = 2 * np.pi * 10.28
    gamma = 2 * BEAM.rhoA * w1 * 0.003
    trial, sd = _tap_trial("viscous+tip_mass", {"gamma": gamma, "tip_mass": mu * BEAM.beam_mass})
    pb = Problem(trial, "viscous", n_elements=8, initial="impulse")
    # Uniform model with E set so that its f1 matches the loaded beam's: ω ∝ β² sqrt(E).
    x = np.array([E * (b1 / 1.875104069) ** 4, gamma, 1e-3, sd])
    u0, u = _laplace_draws(pb, x, np.random.default_rng(7))
    sig = compute_signatures(pb, result_from_samples(pb, u, map_u=u0), seed=1)
    # Measured from the records: 8 elements and the damped-sinusoid fit, 2e-3 relative.
    assert sig.ratio_data == pytest.approx(ratio, rel=2e-3)
    assert sig.ratio_model == pytest.approx(ratio0, rel=2e-3)
    assert sig.ratio_shift == pytest.approx(ratio / ratio0 - 1, abs=2e-3)
    assert sig.ratio_shift > 5 * sig.ratio_shift_err
    assert not sig.white  # the unmodelled mass leaves structure in the residuals


def test_amplitude_trends_see_drag_that_the_linear_model_lacks(result_from_samples):
    # Quadratic drag (slow flow; its envelope agrees with direct integration to ~1e-5,
    # tests/physics/test_nonlinear.py) damps mode 1 at ζ ≈ 0.6 % at 1 cm and less as the
    # amplitude falls: the data's ζ1 rises with amplitude, a linear viscous model's not.
    from bayesbeam.physics.nonlinear import NonlinearForward, nonlinear_damping_scales

    w1 = 2 * np.pi * 10.28
    gamma = 2 * BEAM.rhoA * w1 * 0.002
    t = np.arange(768) / 256.0
    k_drag, _ = nonlinear_damping_scales(BEAM, E, 0.01, n_elements=8)
    fwd = NonlinearForward(BEAM, "viscous+drag", t, n_elements=8, initial="release")
    res = fwd.simulate({"E": E, "gamma": gamma, "drag": 0.006 / k_drag, "w0": 0.01})
    rng = np.random.default_rng(7)
    sd = 0.01 * np.sqrt(np.mean(res.y[0] ** 2))
    trial = Trial(times=t, values=res.y[0] + sd * rng.standard_normal(t.size),
                  quantity="displacement", beam=BEAM, name="drag")
    pb = Problem(trial, "viscous", n_elements=8, initial="release")
    x = np.array([E, 2 * BEAM.rhoA * w1 * 0.004, 0.01, sd])  # a linear compromise
    u0, u = _laplace_draws(pb, x, np.random.default_rng(8))
    sig = compute_signatures(pb, result_from_samples(pb, u, map_u=u0), seed=1)
    d, m = sig.amplitude_trends["data"], sig.amplitude_trends["model"]
    assert d["n_windows"] >= 10
    # Significant and positive in the data (4 se), absent from the linear model's
    # prediction (within 4 se of zero, or tiny against the data's slope).
    assert d["zeta1_per_mm"] > 4 * d["zeta1_per_mm_se"], d
    assert abs(m["zeta1_per_mm"]) < max(4 * m["zeta1_per_mm_se"], 0.05 * d["zeta1_per_mm"])
    assert "ζ1 data +" in "\n".join(__import__(
        "bayesbeam.diagnosis.records", fromlist=["describe_signatures"]
    ).describe_signatures(sig))
    assert json.loads(json.dumps(sig.to_json_dict()))["amplitude_trends"]["data"]["n_windows"]


def test_decay_fit_leaves_out_the_modes_above_the_sensor_band(result_from_samples):
    # The forward model removes modes above the sensor band (physics.forward), and a
    # low-passed record holds none: the decay-vs-amplitude fit must not add sinusoids at
    # their aliases. Sample so that mode 4 (above the band) aliases to 18 Hz, inside the
    # fit's low-pass of mode 1 (cut 2.5 f1 = 25.7 Hz) and > 30 % from f1.
    from bayesbeam.diagnosis.signatures import model_modes

    w1 = 2 * np.pi * 10.28
    gamma = 2 * BEAM.rhoA * w1 * 0.003
    probe = Problem(_tap_trial("viscous", {"gamma": gamma})[0], "viscous", n_elements=8,
                    initial="impulse")
    f_model, _ = model_modes(probe, np.array([E, gamma, 1e-3, 1.0]))
    fs = f_model[3] - 18.0  # Hz: |f4 - fs| = 18 Hz
    t = np.arange(int(2.0 * fs)) / fs
    y = simulate_signal(BEAM, "viscous", {"gamma": gamma, "p0": 1e-3}, t, n_elements=8,
                        initial="impulse")
    sd = 0.01 * np.sqrt(np.mean(y**2))
    rng = np.random.default_rng(9)
    trial = Trial(times=t, values=y + sd * rng.standard_normal(t.size),
                  quantity="displacement", beam=BEAM, name="alias")
    assert f_model[2] > trial.sensor_band > 2.5 * f_model[0]  # modes 3+ out, mode 2 in
    pb = Problem(trial, "viscous", n_elements=8, initial="impulse")
    u0, u = _laplace_draws(pb, np.array([E, gamma, 1e-3, sd]), np.random.default_rng(10))
    sig = compute_signatures(pb, result_from_samples(pb, u, map_u=u0), seed=1)
    # Mode 2 (64 Hz) lies above the fit's cut-off, so nothing else is fitted beside f1.
    for dec in (sig.decay_data, sig.decay_model):
        assert dec is not None
        assert dec.others_hz == ()
        assert dec.frequency == pytest.approx(f_model[0], rel=1e-3)
        assert abs(dec.excess) < 4 * dec.excess_se  # a linear record: no excess


def test_quadratic_projection_recovers_k2_with_a_calibrated_error():
    # residual = k2 (y² - mean) + noise, white or AR(1): the estimate is unbiased and its
    # se is the sd of the estimate over noise draws (checked by brute force over 400
    # draws: an sd of 400 draws is known to ~3.5 %, so 14 % is 4 of its se).
    from bayesbeam.diagnosis.signatures import quadratic_projection
    from bayesbeam.stats.likelihood import stationary_ar1

    t = np.arange(1024) / 256.0
    y = np.exp(-0.4 * t) * np.cos(2 * np.pi * 7.0 * t) + 0.3 * np.cos(2 * np.pi * 19.0 * t)
    rng = np.random.default_rng(0)
    k2, sd = 0.05, 0.02
    for rho in (0.0, 0.9):
        est, ses = [], []
        for _ in range(400):
            e = rng.standard_normal(t.size)
            noise = sd * (stationary_ar1(e, rho) if rho else e)
            k, se = quadratic_projection(k2 * (y**2 - np.mean(y**2)) + noise, y, rho)
            est.append(k)
            ses.append(se)
        est, ses = np.array(est), np.array(ses)
        assert abs(est.mean() - k2) < 3 * est.std() / np.sqrt(est.size), rho
        assert np.std(est) == pytest.approx(np.median(ses), rel=0.14), rho
    # No quadratic term: the estimate is within its own error; a constant signal: NaN.
    k, se = quadratic_projection(sd * rng.standard_normal(t.size), y)
    assert abs(k) < 4 * se
    assert all(np.isnan(quadratic_projection(np.ones(10), np.ones(10))))
