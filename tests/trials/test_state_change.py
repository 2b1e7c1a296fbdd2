"""Change of state within a record: checked on direct integrations, not on the model.

Records are integrated with ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-10) on a
software-timed logger's stamps (``logger_stamps`` of ``test_amplitude``), with white
noise. A single-degree-of-freedom oscillator ``x'' + 2ζω x' + ω² x = 0`` whose f and ζ
jump at a known time (state continuous) must be flagged, with the time inside the
reported interval and the jump within 5 of its standard errors of the truth (the local
model holds exactly on both sides of a jump: constant f and ζ, so the estimate is
unbiased and 5 standard errors bound the noise). Records whose f and ζ change smoothly
with amplitude (quadratic drag with a cubic stiffness; dry friction) or not at all must
not be flagged.
"""

import json

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bayesbeam.trials.amplitude import amplitude_curves
from bayesbeam.trials.state_change import state_change
from tests.trials.test_amplitude import logger_stamps, nonlinear_record

F0, Z0 = 5.0, 0.003  # Hz, damping ratio before any change


def oscillator(f_of_t, z_of_t, *, duration=20.0, noise=2e-6, seed=0, quantity="displacement",
               x0=0.01):
    """Integrate ``x'' + 2ζ(t)ω(t) x' + ω(t)² x = 0`` and sample it on logger stamps."""
    def rhs(t, s):
        w = 2 * np.pi * f_of_t(t)
        return [s[1], -2 * z_of_t(t) * w * s[1] - w * w * s[0]]

    # max_step: the integrator must not step over a sudden change of the coefficients.
    sol = solve_ivp(rhs, (0.0, duration), [x0, 0.0], method="DOP853", rtol=1e-10,
                    atol=1e-15, dense_output=True, max_step=0.01)
    rng = np.random.default_rng(seed)
    t = logger_stamps(duration, rng)
    x, v = sol.sol(t)
    if quantity == "acceleration":
        w = 2 * np.pi * np.array([f_of_t(ti) for ti in t])
        z = np.array([z_of_t(ti) for ti in t])
        y = -2 * z * w * v - w * w * x
        noise *= (2 * np.pi * F0) ** 2
    else:
        y = x
    return t, y + noise * rng.standard_normal(t.size)


def jump(tc, before, after):
    return lambda t: before if t < tc else after


def ramp(tc, width, before, after):
    return lambda t: before + (after - before) * np.clip((t - tc + width / 2) / width, 0, 1)


@pytest.mark.parametrize("quantity", ["displacement", "acceleration"])
def test_sudden_jump_is_found_with_its_time_and_size(quantity):
    tc, df, dz = 8.13, -0.01, 0.0005
    t, y = oscillator(jump(tc, F0, F0 + df), jump(tc, Z0, Z0 + dz), quantity=quantity)
    sc = state_change(amplitude_curves(t, y, n_modes=1, quantity=quantity))
    assert sc.tested and sc.found, sc.reason
    assert abs(sc.time_s - tc) <= sc.time_halfwidth_s
    assert abs(sc.frequency_step_hz - df) <= 5 * sc.frequency_step_se
    assert abs(sc.zeta_step - dz) <= 5 * sc.zeta_step_se
    assert sc.p_value < 1e-3
    assert "change of state at t =" in sc.reason


def test_change_spread_over_two_seconds_is_found():
    tc, width, df, dz = 8.0, 2.0, -0.02, 0.0015
    t, y = oscillator(ramp(tc, width, F0, F0 + df), ramp(tc, width, Z0, Z0 + dz))
    sc = state_change(amplitude_curves(t, y, n_modes=1))
    assert sc.found, sc.reason
    # The reported interval overlaps the span of the change [7, 9] s ...
    lo, hi = sc.time_s - sc.time_halfwidth_s, sc.time_s + sc.time_halfwidth_s
    assert lo <= tc + width / 2 and hi >= tc - width / 2
    # ... and the levels either side move the right way by most of the change (the
    # windows on one side may lie inside the 2 s ramp, so not all of it).
    lv = sc.levels
    assert lv["frequency_before_hz"] - lv["frequency_after_hz"] > 0.5 * abs(df)
    assert lv["zeta_after"] - lv["zeta_before"] > 0.5 * dz


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_constant_parameters_are_not_a_change(seed):
    t, y = oscillator(lambda _: F0, lambda _: Z0, noise=2e-5, seed=seed)
    sc = state_change(amplitude_curves(t, y, n_modes=1))
    assert sc.tested and not sc.found, sc.reason
    assert sc.p_value > 1e-3


def test_drag_and_cubic_stiffness_are_not_a_change():
    """Strong smooth amplitude dependence (f moves 1.3 %, ζ by a factor 2.2)."""
    t, y, *_ = nonlinear_record()
    sc = state_change(amplitude_curves(t, y, n_modes=1))
    assert sc.tested and not sc.found, sc.reason


def test_dry_friction_is_not_a_change():
    """Coulomb friction (regularised sign): ζ grows as 1/A towards the stop."""
    w, mu = 2 * np.pi * F0, 2e-5  # rad/s; friction force / stiffness, m

    def rhs(_, s):
        return [s[1], -2 * 0.001 * w * s[1] - w * w * (s[0] + mu * np.tanh(s[1] / 1e-4))]

    sol = solve_ivp(rhs, (0.0, 20.0), [0.01, 0.0], method="LSODA", rtol=1e-9, atol=1e-13,
                    dense_output=True, max_step=0.002)
    rng = np.random.default_rng(2)
    t = logger_stamps(20.0, rng)
    y = sol.sol(t)[0] + 2e-6 * rng.standard_normal(t.size)
    c = amplitude_curves(t, y, n_modes=1)
    zeta = c.zeta[:, 0][np.isfinite(c.zeta[:, 0])]
    assert zeta[-1] > 3 * zeta[0]  # the friction signature is there
    sc = state_change(c)
    assert sc.tested and not sc.found, sc.reason


def test_short_record_is_not_tested():
    t, y = oscillator(lambda _: F0, lambda _: Z0, duration=4.0)
    sc = state_change(amplitude_curves(t, y, n_modes=1))
    assert not sc.tested and not sc.found
    assert "independent windows" in sc.reason
    rec = sc.to_json_dict()
    json.dumps(rec, allow_nan=False)
    assert rec["time_s"] is None and rec["levels"] == {}


def test_json_record_is_strict_and_names_units():
    t, y = oscillator(jump(8.13, F0, F0 - 0.01), lambda _: Z0)
    rec = state_change(amplitude_curves(t, y, n_modes=1)).to_json_dict()
    text = json.dumps(rec, allow_nan=False)
    for key in ("time_s", "frequency_step_hz", "zeta_step", "p_value", "levels"):
        assert key in rec
    assert rec["found"] is True and "frequency_before_hz" in text


@pytest.mark.parametrize(("kw", "match"), [
    ({"alpha": 0.0}, "alpha"), ({"alpha": 1.5}, "alpha"), ({"side": 2}, "side"),
    ({"min_sigma": 0.0}, "min_sigma"), ({"min_scatter": -1.0}, "min_scatter"),
])
def test_bad_settings_are_clear_errors(kw, match):
    t, y = oscillator(lambda _: F0, lambda _: Z0, duration=6.0)
    c = amplitude_curves(t, y, n_modes=1)
    with pytest.raises(ValueError, match=match):
        state_change(c, **kw)
