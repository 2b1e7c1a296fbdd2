"""Amplitude curves: checked against direct time integrations, not against their own model.

The records are integrated with ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-10) and
sampled on stamps like a software-timed logger's (2 kHz mean, ±20 % jitter, a few gaps
of 5-10 ms), with white noise and a constant offset added.

Nonlinear oscillator ``x'' + 2ζ0ω0 x' + c_q |x'| x' + ω0² (1 + κx²) x = 0``. First-order
averaging (x ≈ a cos θ): the drag dissipates ``(8/3) c_q a³ ω²`` per cycle against
``π c_eq a² ω`` for a viscous ``c_eq x'``, so ``c_eq = 8 c_q a ω / (3π)`` and
``ζ(a) = ζ0 ω0/ω(a) + (4/(3π)) c_q a`` (c_q in 1/m, so ζ has no factor ω); the cubic
term gives ``ω(a)² = ω0² (1 + 3κa²/4)``, ``f(a) ≈ f0 (1 + 3κa²/8)``. These formulas
are only first order (errors O(ζκa², (κa²)²) ~ 1e-4 here), so the reference is measured
on the noise-free integration instead: zero crossings and peaks (v = 0) are located by
the integrator's event root-finding; the damped angular frequency of each half cycle is
``π / (t_{n+1} - t_n)`` between zero crossings and the decay rate
``-ln(|x_{n+1}| / |x_n|) / (s_{n+1} - s_n)`` between peaks, both interpolated (cubic
spline) to each window's centre time.

Error budget of the comparison (per amplitude bin), against the acceptance of the issue
(ζ within 1e-4 absolute, f within 1e-4 relative):

* noise: the bin standard errors from the fit's Jacobian are ≤ 1e-5 in ζ and ≤ 1e-5
  relative in f with the chosen noise (2e-4 of the initial amplitude), so 4 standard
  errors stay below 4e-5;
* estimator bias: the window fit follows a linear change of ω and σ; what is left is
  the curvature, ``ω̈ T²/40`` for a window of length T (measured ≤ 3e-5 relative in f
  and ≤ 1e-5 in ζ on the noise-free record);
* reference: peaks of x include the third harmonic (``κa³/32``), so they decay faster
  than the fundamental by the factor ``1 + κa²/16`` (≤ 0.25 % of ζ, i.e. ≤ 1.5e-5).

So the acceptance 1e-4 holds with a margin: the test asserts it and also the tighter
``4 SE + bias budget`` (2.5e-5 in ζ, 4e-5 in f), which is what the estimator can claim.
"""

import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from bayesbeam.trials.amplitude import amplitude_curves
from bayesbeam.trials.amplitude_bins import overlap_factor
from bayesbeam.trials.modal_id import SignatureError
from bayesbeam.trials.residual_lines import label_line, residual_lines

F0, ZETA0, CQ, KAPPA, A0 = 5.0, 0.002, 0.94, 400.0, 0.01  # Hz, -, 1/m, 1/m², m
NOISE, OFFSET = 2e-6, 3e-4  # m


def logger_stamps(duration, rng, *, rate=2000.0, jitter=0.2, n_gaps=4):
    """Software-timed stamps: mean step 1/rate, ±jitter, a few gaps of 5-10 ms."""
    steps = (1 + jitter * rng.uniform(-1, 1, int(1.2 * duration * rate))) / rate
    t = np.cumsum(steps)
    t = t[t < duration]
    for g in rng.uniform(1.0, duration - 1.0, n_gaps):
        t = t[(t < g) | (t > g + rng.uniform(0.005, 0.010))]
    return t


def integrate(rhs, y0, duration, *, events=()):
    return solve_ivp(rhs, (0.0, duration), y0, method="DOP853", rtol=1e-10, atol=1e-15,
                     dense_output=True, events=events)


def nonlinear_record(duration=20.0, seed=0):
    w0 = 2 * np.pi * F0

    def rhs(_, s):
        x, v = s
        return [v, -2 * ZETA0 * w0 * v - CQ * abs(v) * v - w0 ** 2 * (1 + KAPPA * x * x) * x]

    sol = integrate(rhs, [A0, 0.0], duration, events=(lambda _, s: s[0], lambda _, s: s[1]))
    rng = np.random.default_rng(seed)
    t = logger_stamps(duration, rng)
    y = sol.sol(t)[0] + OFFSET + NOISE * rng.standard_normal(t.size)
    # Reference from the integrator's events (noise-free, root-found to ~1e-10 s).
    tz = sol.t_events[0]
    tp, xp = sol.t_events[1], np.abs(sol.y_events[1][:, 0])
    wd = CubicSpline(0.5 * (tz[1:] + tz[:-1]), np.pi / np.diff(tz))
    sg = CubicSpline(0.5 * (tp[1:] + tp[:-1]), -np.diff(np.log(xp)) / np.diff(tp))
    peak = CubicSpline(0.5 * (tp[1:] + tp[:-1]), np.sqrt(xp[1:] * xp[:-1]))
    return t, y, wd, sg, peak


@pytest.fixture(scope="module")
def nonlinear():
    t, y, wd, sg, peak = nonlinear_record()
    c = amplitude_curves(t, y, n_modes=1)
    w, s = wd(c.centre), sg(c.centre)
    return c, w / (2 * np.pi), s / np.hypot(s, w), peak(c.centre)


def test_nonlinear_oscillator_per_window(nonlinear):
    c, f_true, z_true, peak = nonlinear
    ok = np.isfinite(c.zeta[:, 0])
    assert ok.all() and c.centre.size >= 45
    # Mode-1 amplitude at the window centre: the fundamental, below the peak by the
    # third harmonic κa²/32 (≤ 1.1e-3 here).
    rel_a = c.amplitude[:, 0] / peak - 1
    assert np.all((rel_a < 2e-4) & (rel_a > -1.3e-3))
    dz = c.zeta[:, 0] - z_true
    df = c.frequency[:, 0] / f_true - 1
    # Per window within 4 standard errors plus the bias budget of the module docstring.
    assert np.all(np.abs(dz) < 4 * c.zeta_se[:, 0] + 2.5e-5)
    assert np.all(np.abs(df) < 4 * c.frequency_se[:, 0] / f_true + 4e-5)
    # The offset and the noise level are recovered.
    assert np.all(np.abs(c.offset - OFFSET) < 4 * c.offset_se + 1e-7)
    assert np.median(c.resid_rms) == pytest.approx(NOISE, rel=0.1)


def test_nonlinear_oscillator_per_bin_meets_acceptance(nonlinear):
    c, f_true, z_true, _ = nonlinear
    amp = c.amplitude[:, 0]
    assert len(c.bins) == 8
    for b in c.bins:
        sel = (amp >= b.lo) & (amp < b.hi)
        err_z = b.zeta1 - np.mean(z_true[sel])
        err_f = b.f1 / np.mean(f_true[sel]) - 1
        # The acceptance of the issue ...
        assert abs(err_z) < 1e-4 and abs(err_f) < 1e-4
        # ... is achievable: 4 standard errors plus the bias budget stay below it, and
        # the error is within that tighter bound.
        assert 4 * b.zeta1_se + 2.5e-5 < 1e-4 and 4 * b.f1_se / b.f1 + 4e-5 < 1e-4
        assert abs(err_z) < 4 * b.zeta1_se + 2.5e-5
        assert abs(err_f) < 4 * b.f1_se / b.f1 + 4e-5
    # ζ rises with amplitude (drag), f rises (hardening): the curves span many tolerances.
    assert c.bins[-1].zeta1 - c.bins[0].zeta1 > 25e-4
    assert c.bins[-1].f1 / c.bins[0].f1 - 1 > 50e-4


def test_nonlinear_oscillator_first_order_formulas(nonlinear):
    c, *_ = nonlinear
    a = c.amplitude[:, 0]
    f_avg = F0 * (1 + 3 * KAPPA * a ** 2 / 8)
    z_avg = ZETA0 * F0 / c.frequency[:, 0] + 4 / (3 * math.pi) * CQ * a
    # First-order averaging: errors of second order, (κa²)² ~ 1e-3 and ζκa² ~ 2e-4.
    assert np.all(np.abs(c.frequency[:, 0] / f_avg - 1) < 1e-3)
    assert np.all(np.abs(c.zeta[:, 0] - z_avg) < 2e-4)


def test_nonlinear_residual_shows_third_harmonic(nonlinear):
    c, *_ = nonlinear
    labels = {ln.label for ln in c.lines}
    assert "3f1" in labels
    assert "unexplained" not in labels
    text = json.dumps(c.to_json_dict(), allow_nan=False)
    assert '"3f1"' in text


def two_mode_record(duration=6.0, seed=1, mains=0.0):
    """Two uncoupled linear oscillators (modal coordinates), integrated; sensor sum."""
    modes = [(5.0, 0.004, 1.0), (31.4, 0.012, 0.3)]  # f_n Hz, ζ, initial displacement

    def rhs(_, s):
        out = []
        for k, (f, z, _) in enumerate(modes):
            w = 2 * np.pi * f
            x, v = s[2 * k], s[2 * k + 1]
            out += [v, -2 * z * w * v - w * w * x]
        return out

    sol = integrate(rhs, [v for _, _, a in modes for v in (a, 0.0)], duration)
    rng = np.random.default_rng(seed)
    t = logger_stamps(duration, rng)
    s = sol.sol(t)
    y = s[0] + s[2] + 0.02 + 1e-4 * rng.standard_normal(t.size)
    y += mains * np.sin(2 * np.pi * 50.0 * t + 0.3)
    truth = [(f * math.sqrt(1 - z * z), z) for f, z, _ in modes]
    return t, y, truth


def test_linear_two_modes_constant_zeta_and_f():
    t, y, truth = two_mode_record(mains=2e-3)
    c = amplitude_curves(t, y, n_modes=2)
    (f1, z1), (f2, z2) = truth
    ok1 = np.isfinite(c.zeta[:, 0])
    ok2 = np.isfinite(c.zeta[:, 1])
    assert ok1.all() and ok2[:4].all()
    assert np.all(np.abs(c.zeta[:, 0] - z1) < 4 * c.zeta_se[:, 0])
    assert np.all(np.abs(c.frequency[:, 0] - f1) < 4 * c.frequency_se[:, 0])
    assert np.all(np.abs(c.zeta[ok2, 1] - z2) < 4 * c.zeta_se[ok2, 1])
    assert np.all(np.abs(c.frequency[ok2, 1] - f2) < 4 * c.frequency_se[ok2, 1])
    ratio, ratio_se = c.ratio
    assert np.all(np.abs(ratio[ok2] - f2 / f1) < 4 * ratio_se[ok2])
    # Mode 2 decays 19 times faster: once it is below 5 standard errors it is reported
    # as not resolved, never as a number.
    assert not ok2[-1]
    assert np.all(np.isnan(c.frequency[~ok2, 1]))
    for b in c.bins:
        assert abs(b.zeta1 - z1) < 4 * b.zeta1_se + 1e-6
    assert [ln.label for ln in c.lines] == ["mains 50 Hz"]
    assert c.lines[0].frequency == pytest.approx(50.0, abs=0.05)
    assert c.lines[0].amplitude == pytest.approx(2e-3, rel=0.1)
    json.dumps(c.to_json_dict(), allow_nan=False)


def test_displacement_amplitude_from_acceleration():
    t, y, _ = two_mode_record(duration=4.0)
    # The same motion recorded as acceleration (the ODE's right-hand side, exact).
    f, z = 5.0, 0.004
    w = 2 * np.pi * f
    sol = integrate(lambda _, s: [s[1], -2 * z * w * s[1] - w * w * s[0]], [1.0, 0.0], 4.0)
    x, v = sol.sol(t)
    acc = -2 * z * w * v - w * w * x
    cx = amplitude_curves(t, x, n_modes=1)
    ca = amplitude_curves(t, acc, n_modes=1, quantity="acceleration", tip_factor=1.5)
    np.testing.assert_allclose(ca.amplitude_m, 1.5 * cx.amplitude_m, rtol=1e-6)
    np.testing.assert_allclose(cx.amplitude_m, cx.amplitude[:, 0])


def test_label_line_and_lines_away_from_modes():
    assert label_line(15.1, (5.0, 5.06)) == "3f1"
    assert label_line(10.2, (5.0, 5.06)) == "2f1"
    assert label_line(10.5, (5.0, 5.06)) == "unexplained"
    assert label_line(150.3, (7.0, 7.0)) == "mains 3x50 Hz"
    assert label_line(59.6, (7.0, 7.0)) == "mains 60 Hz"
    t = np.arange(8000) / 2000.0
    rng = np.random.default_rng(5)
    r = 1e-3 * rng.standard_normal(t.size) + 0.01 * np.sin(2 * np.pi * 73.0 * t)
    r += 0.01 * np.sin(2 * np.pi * 5.0 * t)
    lines = residual_lines(t, r, (5.0, 5.0), [(5.0, 5.0)], factor=5.0)
    assert [(round(ln.frequency), ln.label) for ln in lines] == [(73, "unexplained")]


def test_overlap_factor():
    assert overlap_factor(1, 0.5, 1.0) == 1.0
    # Two windows sharing half their samples: 1 + 2 (1/2)(1/2).
    assert overlap_factor(2, 0.5, 1.0) == pytest.approx(1.5)
    assert overlap_factor(5, 1.0, 1.0) == 1.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"quantity": "strain"}, "quantity"), ({"periods": 1.0}, "periods"),
     ({"n_modes": 0}, "n_modes"), ({"f1": -1.0}, "f1")],
)
def test_bad_input_is_a_clear_error(kwargs, match):
    t = np.arange(2000) / 1000.0
    y = np.exp(-0.2 * t) * np.cos(2 * np.pi * 5.0 * t)
    with pytest.raises(SignatureError, match=match):
        amplitude_curves(t, y, **kwargs)


def test_record_shorter_than_a_window():
    t = np.arange(500) / 1000.0
    with pytest.raises(SignatureError, match="shorter than one window"):
        amplitude_curves(t, np.cos(2 * np.pi * 5.0 * t), f1=5.0)
