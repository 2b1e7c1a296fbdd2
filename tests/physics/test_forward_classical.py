"""The closed-form path of classically damped models against the full propagation (issue 13).

Both paths are exact up to rounding: the closed form sums the modes' damped exponentials
(bayesbeam.physics.modal_closed), the full path propagates the modal state with matrix
exponentials (bayesbeam.physics.propagate). Their difference is rounding only: that of the
eigen-solve they share is common to both, and the full uniform path accumulates about
``k u ‖A dt‖``-sized errors over k steps (measured 2.6e-10 of the amplitude after 1,280 steps
with Kelvin–Voigt damping, whose stiff modes make ‖A dt‖ large; the closed form agrees with the
eigen route of ``response_times`` to 5e-15 there). The tolerance 1e-9 of the issue covers
that accumulation with a margin of ~4 while a wrong damping, frequency, band or initial
condition of any mode changes the signal by far more (see the last test).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward, ForwardError
from bayesbeam.physics.modal_closed import NEAR_CRITICAL

L = 0.3048
E = 6.2e10
W0 = 5e-3
TOL = 1e-9  # relative max error, see the module docstring


def _beam(quantity: str = "displacement", **extra) -> Beam:
    return Beam.rectangular(L, 0.127, 0.72e-3, 0.021, E=E, quantity=quantity, **extra)


BEAM = _beam()
W1 = 1.875104069**2 * math.sqrt(E * BEAM.I / (BEAM.rhoA * L**4))  # physics.md §4, rad/s
GAMMA = 2 * BEAM.rhoA * W1 * 0.01  # ζ1 = 1 % viscous (physics.md §2)
C_D = 2 * E * 0.01 / W1  # ζ1 = 1 % Kelvin–Voigt: modes above the ~7th overdamped

DT = 0.003906
UNIFORM = np.arange(1280) * DT
RNG_TIMES = np.random.default_rng(7)
NON_UNIFORM = np.sort(RNG_TIMES.uniform(0.0, 5.0, 400))
# A uniform grid with a few samples dropped (Forward simulates the grid whole).
HOLES = np.delete(np.arange(600) * DT, [5, 6, 100, 101, 102, 400])


def _sets(fwd: Forward, n: int = 6, seed: int = 0, **fixed: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = {
        "E": E * rng.uniform(0.9, 1.1, n),
        "gamma": GAMMA * rng.uniform(0.5, 2.0, n),
        "c_d": C_D * rng.uniform(0.5, 2.0, n),
        "w0": W0 * rng.uniform(0.5, 1.5, n),
        "p0": 1e-3 * rng.uniform(0.5, 1.5, n),
        **{k: np.full(n, v) for k, v in fixed.items()},
    }
    return np.column_stack([values[p] for p in fwd.param_names])


def _compare(beam: Beam, model: str, times: np.ndarray, theta=None, **kwargs) -> float:
    """Relative max difference closed form vs full; checks the paths taken and the masks."""
    fast = Forward(beam, model, times, **kwargs)
    full = Forward(beam, model, times, path="full", **kwargs)
    theta = _sets(fast) if theta is None else theta
    a, b = fast.simulate(theta), full.simulate(theta)
    assert fast.classical
    assert fast.last_path == "closed-form" and full.last_path == "full"
    np.testing.assert_array_equal(a.valid, b.valid)
    return float(np.max(np.abs(a.y - b.y)) / np.max(np.abs(b.y)))


@pytest.mark.parametrize("model", ["viscous", "kv", "viscous+kv"])
@pytest.mark.parametrize("quantity", ["displacement", "velocity", "acceleration"])
@pytest.mark.parametrize("times", [UNIFORM, NON_UNIFORM, HOLES], ids=["uniform", "times", "holes"])
def test_closed_form_matches_full_propagation(model, quantity, times):
    assert _compare(_beam(quantity), model, times) <= TOL


@pytest.mark.parametrize("initial", ["impulse", "modes:3"])
@pytest.mark.parametrize("t0", [None, -0.0123])
def test_closed_form_initial_conditions_and_lead_time(initial, t0):
    fwd = Forward(BEAM, "viscous+kv", UNIFORM, initial=initial)
    theta = _sets(fwd, A1=2e-3, B1=-1e-3, A2=5e-4, B2=2e-4, A3=1e-4, B3=0.0)
    assert _compare(BEAM, "viscous+kv", UNIFORM, theta, initial=initial, t0=t0) <= TOL


@pytest.mark.parametrize("bandwidth", [60.0, 700.0, 5000.0])
@pytest.mark.parametrize("model", ["viscous", "viscous+kv"])
def test_closed_form_applies_the_sensor_band_like_the_full_path(model, bandwidth):
    # 60 Hz keeps 2 modes, 700 Hz a few, 5 kHz cuts inside the overdamped KV modes (the
    # band edge then separates the two real roots of some of them).
    assert _compare(BEAM, model, UNIFORM, bandwidth=bandwidth) <= TOL


def test_band_edge_between_the_roots_of_an_overdamped_mode():
    # Heavy KV damping: mode 2 overdamped with its slow root in a 30 Hz band and its fast
    # root out of it. Only the slow eigen-solution may pass (sensor.band_limit).
    fwd = Forward(BEAM, "kv", UNIFORM, bandwidth=30.0)
    w2 = math.sqrt(E) * fwd._w_unit[1]
    c_d = 3.0 * w2 / fwd._c_unit["c_d"][1]  # c_2 = 3 ω2: roots 0.38 ω2 and 2.6 ω2
    slow, fast = 0.5 * (3 - math.sqrt(5)) * w2, 0.5 * (3 + math.sqrt(5)) * w2
    assert slow < 2 * np.pi * 30.0 < fast  # the premise of the test
    theta = np.array([[E, c_d, W0]])
    assert _compare(BEAM, "kv", UNIFORM, theta, bandwidth=30.0) <= TOL


@pytest.mark.parametrize("offset", [0.0, 0.3 * NEAR_CRITICAL, -0.3 * NEAR_CRITICAL, 0.05])
def test_near_and_exactly_critical_damping(offset):
    # Mode 1 at (or near) critical damping c_1 = 2 ω1 (1 + offset): the stable direct form
    # (offset 0 and ±0.3e-3) and the exponential form just outside it (5 %).
    fwd = Forward(BEAM, "kv", UNIFORM)
    c_d = 2 * W1 * (1 + offset) / fwd._c_unit["c_d"][0]
    theta = np.array([[E, c_d, W0]])
    assert _compare(BEAM, "kv", UNIFORM, theta) <= TOL
    assert _compare(BEAM, "kv", NON_UNIFORM, theta) <= TOL


def test_overdamped_high_modes_velocity():
    # Twenty times the 1 % KV damping: most modes overdamped, some by orders of magnitude
    # (fast roots ~ -E/c_d); velocity weighs the high modes most.
    beam = _beam("velocity")
    fwd = Forward(beam, "kv", UNIFORM)
    theta = _sets(fwd, c_d=20 * C_D)
    assert _compare(beam, "kv", UNIFORM, theta) <= TOL


def test_tip_mass_beam_with_kelvin_voigt_is_classical():
    # A fixed tip mass changes M only: KV ∝ K stays classical (shared shapes), viscous
    # damping ∝ ∫φφ is then not ∝ M and must take the full path.
    beam = _beam(tip_mass=0.003)
    assert _compare(beam, "kv", UNIFORM) <= TOL
    assert not Forward(beam, "viscous", UNIFORM).classical


@pytest.mark.parametrize(
    ("model", "beam_extra"),
    [
        ("viscous+sh", {}),
        ("kv+sh", {}),
        ("viscous+tip_mass", {}),
        ("kv+root_spring", {}),
        ("viscous+kv+stiffness_gradient", {}),
        ("kv", {"root_spring": 50.0}),
    ],
)
def test_coupled_or_varying_structure_takes_the_full_path(model, beam_extra):
    beam = _beam(**beam_extra)
    fwd = Forward(beam, model, UNIFORM[:64])
    assert not fwd.classical
    theta = _sets(fwd, a=1e-3, b=0.01, tip_mass=1e-3, root_spring=50.0,
                  stiffness_gradient=0.1)
    res = fwd.simulate(theta)
    assert fwd.last_path == "full" and res.valid.all()


def test_invalid_sets_are_flagged_like_the_full_path():
    fast = Forward(BEAM, "viscous+kv", UNIFORM)
    theta = _sets(fast, n=4)
    theta[1, 0] = -1.0  # E <= 0: inadmissible
    theta[2, 0] = 1e300  # admissible, overflows: flagged by both paths
    full = Forward(BEAM, "viscous+kv", UNIFORM, path="full")
    a, b = fast.simulate(theta), full.simulate(theta)
    np.testing.assert_array_equal(a.valid, b.valid)
    assert not a.valid[1] and not a.valid[2] and a.valid[0]
    assert np.all(a.y[~a.valid] == 0.0) and np.all(np.isfinite(a.y))
    assert np.max(np.abs(a.y - b.y)) <= TOL * np.max(np.abs(b.y))


def test_path_keyword_is_checked_and_can_be_switched():
    with pytest.raises(ForwardError, match="path must be"):
        Forward(BEAM, "viscous", UNIFORM, path="fast")
    fwd = Forward(BEAM, "viscous", UNIFORM)
    assert fwd.last_path is None
    theta = _sets(fwd, n=2)
    fwd.simulate(theta)
    assert fwd.last_path == "closed-form"
    fwd.path = "full"
    fwd.simulate(theta)
    assert fwd.last_path == "full"


def test_comparison_can_fail():
    # The check above is sharp: a 1e-6 relative change of one set's KV damping already
    # moves the signal by much more than the tolerance.
    fast = Forward(BEAM, "viscous+kv", UNIFORM)
    full = Forward(BEAM, "viscous+kv", UNIFORM, path="full")
    theta = _sets(fast, n=2)
    bumped = theta.copy()
    bumped[0, fast.param_names.index("c_d")] *= 1 + 1e-6
    a, b = fast.simulate(bumped).y, full.simulate(theta).y
    assert np.max(np.abs(a - b)) / np.max(np.abs(b)) > 100 * TOL
