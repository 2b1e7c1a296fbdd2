"""Tests of bayesbeam.physics.forward against independent references (issue 2 "Checks").

References used here and written independently of the package's modal path:
* the physical first-order system x' = [[0, I], [-M⁻¹K, -M⁻¹D]] x built from the FE matrices
  (fem / hysteresis) and scipy.linalg.expm at every sample time;
* closed forms: single-mode damped decay, static cantilever deflection P x²(3L - x)/(6EI),
  modal damping ratios of physics.md §2, first frequencies of physics.md §4;
* a shooting solution of (EI(x) w'')'' = ω² rhoA w (scipy solve_ivp) for a stiffness gradient;
* the narrow-kernel boundary layer of spatial hysteresis, derived in the test below.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from bayesbeam.physics import propagate
from bayesbeam.physics.beam import Beam, Gradient
from bayesbeam.physics.fem import assemble
from bayesbeam.physics.forward import (
    Forward,
    ForwardError,
    Response,
    grid_with_holes,
    modal_properties,
)
from bayesbeam.physics.hysteresis import HysteresisOperator
from bayesbeam.physics.models import ModelError

# The source study's single-ply beam (issue 2 benchmark) with a physical E (f1 ≈ 11.4 Hz).
L = 0.3048
E = 6.2e10
BEAM = Beam.rectangular(L, 0.127, 0.72e-3, 0.021, E=E)
EI = E * BEAM.I
RHOA = BEAM.rhoA
W1 = 1.875104069**2 * math.sqrt(EI / (RHOA * L**4))  # physics.md §4, rad/s

# Damping levels giving ζ1 = 1 % per mechanism (physics.md §2 formulas).
GAMMA = 2 * RHOA * W1 * 0.01  # viscous: ζ = gamma / (2 rhoA ω)
C_D = 2 * E * 0.01 / W1  # Kelvin–Voigt: ζ = c_d ω / (2E) (overdamps the high modes)
B_SH = 0.01  # m, a moderately wide kernel (couples the modes)
A_SH = 4 * EI * 0.01 / (W1 * B_SH**2)  # narrow-kernel estimate c_d I = a b²/2
W0 = 5e-3  # release tip deflection, m

# physics.md §4 reference values.
BETA_L = np.array([1.875104069, 4.694091133, 7.854757438, 10.99554073])
TIP_MASS_BETA = {0.1: 1.72274152, 0.5: 1.41996443, 1.0: 1.24791741}
ROOT_SPRING_BETA = {1.0: 1.24791741, 10.0: 1.72274152, 100.0: 1.85678698}

LAW_VALUES = {"gamma": GAMMA, "c_d": C_D, "a": A_SH, "b": B_SH}


def _params(fwd: Forward, **extra: float) -> np.ndarray:
    values = {"E": E, "w0": W0, **LAW_VALUES, **extra}
    return np.array([[values[n] for n in fwd.param_names]])


def _physical_matrices(fwd: Forward, theta: np.ndarray):
    """Total M, K, D of one parameter set, straight from the FE and hysteresis matrices."""
    p = dict(zip(fwd.param_names, theta, strict=True))
    fe = fwd.fe
    M = fe.M + p.get("tip_mass", 0.0) * fe.M_tip
    if "added_mass" in p:  # point mass m at x: m N(x)ᵀ N(x)
        row = fe.shape(p["added_mass_position"])[0]
        M = M + p["added_mass"] * np.outer(row, row)
    kr = p.get("root_spring", fwd.beam.root_spring or 0.0)
    K = p["E"] * (fe.K + p.get("stiffness_gradient", 0.0) * fe.K_grad) + kr * fe.K_root
    D = np.zeros_like(M)
    if "gamma" in p:
        D += p["gamma"] * fe.G
    if "c_d" in p:
        D += p["c_d"] * fe.KV
    if "a" in p:
        D += p["a"] * HysteresisOperator(fe.nodes, fe.root_dof).matrix(p["b"])
    return M, K, D


def _reference(fwd: Forward, theta: np.ndarray, times: np.ndarray, t0: float) -> np.ndarray:
    """Sensor signal from scipy.linalg.expm of the physical first-order system.

    State x = [c; c'/σ] with σ = ω_max, which balances the two blocks (with σ = 1 the
    matrix has norm ~3e10 and the reference is only good to ~1e-9). Uniform grids step with
    P = expm(A dt) (rounding grows ~linearly in the step count); other grids take one
    expm(A (t - t0)) per sample.
    """
    M, K, D = _physical_matrices(fwd, theta)
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    sig = math.sqrt(sla.eigh(K, M, eigvals_only=True)[-1])
    A = np.block([[np.zeros((n, n)), sig * np.eye(n)], [-Minv @ K / sig, -Minv @ D]])
    p = dict(zip(fwd.param_names, theta, strict=True))
    fe = fwd.fe
    if fwd.initial == "release":
        c0 = np.linalg.solve(K, fe.tip)
        x0 = np.concatenate([p["w0"] * c0 / (fe.tip @ c0), np.zeros(n)])
    else:  # impulse p0 at the tip: M c'(0+) = p0 e_tip
        x0 = np.concatenate([np.zeros(n), p["p0"] * Minv @ fe.tip / sig])
    s = fwd.sensor
    steps = np.diff(times)
    uniform = np.allclose(steps, steps[0], rtol=1e-12, atol=0) and times[0] == t0
    P = sla.expm(A * steps[0]) if uniform else None
    out = []
    x = x0
    for k, t in enumerate(times):
        if uniform:
            x = x if k == 0 else P @ x
        else:
            x = sla.expm(A * (t - t0)) @ x0
        c, v = x[:n], sig * x[n:]
        if fwd.quantity == "displacement":
            out.append(s @ c)
        elif fwd.quantity == "velocity":
            out.append(s @ v)
        else:
            out.append(s @ (Minv @ (-K @ c - D @ v)))
    return np.array(out)


def _relmax(y: np.ndarray, ref: np.ndarray) -> float:
    return float(np.max(np.abs(y - ref)) / np.max(np.abs(ref)))


def _accurate_omegas(fe, modulus: float) -> np.ndarray:
    """FE natural frequencies (rad/s, ascending) from the flexibility form L_K⁻¹ M L_K⁻ᵀ.

    Its largest eigenvalues 1/ω² (the low modes) are accurate to ~eps relative; eigh(K, M)
    loses ~eps λ_max/λ_1 on them (measured 4e-11 relative for ω1 at 16 elements).
    """
    c = sla.cholesky(modulus * fe.K, lower=True)
    ci = sla.solve_triangular(c, np.eye(c.shape[0]), lower=True)
    mu = sla.eigh(ci @ fe.M @ ci.T, eigvals_only=True)
    return 1.0 / np.sqrt(mu[::-1])


# --- (1) against an independent integration of the same physical matrices ------------------
UNIFORM_T = np.arange(300) * 2e-3  # 0.6 s, ~7 periods of mode 1
NONUNIFORM_T = np.sort(np.random.default_rng(11).uniform(0.01, 0.6, 120))


@pytest.mark.parametrize("model", ["viscous", "kv", "sh", "viscous+kv+sh"])
@pytest.mark.parametrize("quantity", ["displacement", "velocity", "acceleration"])
@pytest.mark.parametrize("grid", ["uniform", "nonuniform"])
def test_matches_physical_expm(model, quantity, grid):
    # 5 elements (10 dofs) keep the brute-force reference cheap; KV overdamps the top modes
    # and the kernel of width 0.01 m couples them, so both hard cases are exercised. The
    # non-uniform grid starts after the release instant (t0 = 0 < times[0]).
    beam = BEAM.replace(
        quantity=quantity, sensor_position=0.8 * L if grid == "nonuniform" else None
    )
    times = UNIFORM_T if grid == "uniform" else NONUNIFORM_T
    fwd = Forward(beam, model, times, n_elements=5, t0=0.0)
    assert fwd.uniform == (grid == "uniform")
    theta = _params(fwd)
    res = fwd.simulate(theta)
    assert res.valid.all()
    ref = _reference(fwd, theta[0], times, 0.0)
    # Issue 2 asks for 1e-7 relative; measured 4e-12 .. 2e-10 over these cases.
    assert _relmax(res.y[0], ref) < 1e-7


@pytest.mark.parametrize(
    ("model", "extra", "initial"),
    [
        ("viscous+tip_mass", {"tip_mass": 4e-3}, "release"),
        ("kv+root_spring", {"root_spring": 30.0}, "release"),
        ("viscous+sh+stiffness_gradient", {"stiffness_gradient": -0.5}, "release"),
        ("viscous+kv+sh", {"p0": 2e-3}, "impulse"),
        ("viscous+added_mass", {"added_mass": 4e-3, "added_mass_position": 0.7 * L}, "release"),
        ("kv+added_mass", {"added_mass": 2e-3, "added_mass_position": 0.3 * L, "p0": 2e-3},
         "impulse"),
    ],
)
def test_matches_physical_expm_structural_and_impulse(model, extra, initial):
    # The structural extensions take the per-set eigendecomposition path of Forward.
    fwd = Forward(
        BEAM.replace(quantity="velocity"), model, UNIFORM_T, n_elements=4, initial=initial
    )
    theta = _params(fwd, **extra)
    res = fwd.simulate(theta)
    assert res.valid.all()
    # Issue 2: 1e-7; measured 1e-13 .. 8e-11.
    assert _relmax(res.y[0], _reference(fwd, theta[0], UNIFORM_T, 0.0)) < 1e-7


# --- (2) single-mode analytic decay --------------------------------------------------------
def test_single_mode_viscous_decay_closed_form():
    # Uniform beam, viscous damping: G = M / rhoA, so C = (gamma/rhoA) I is diagonal and the
    # modes decouple exactly. Mode 1 alone, started with sensor displacement A and velocity
    # B ω, decays as q(t) = e^{-ζωt} [q0 cos ω_d t + (q0' + ζ ω q0)/ω_d sin ω_d t].
    times = np.arange(1280) * 0.003906
    fwd = Forward(BEAM, "viscous", times, initial="modes:1")
    zeta = 0.02
    gamma = 2 * RHOA * W1 * zeta
    amp, vel = 3e-3, -1e-3
    y = fwd.simulate({"E": E, "gamma": gamma, "A1": amp, "B1": vel}).y[0]
    w = _accurate_omegas(fwd.fe, E)[0]  # FE frequency of mode 1
    assert abs(w / W1 - 1) < 2e-7  # physics.md §4: 1.3e-7 at 16 elements
    z = gamma / (2 * RHOA * w)
    wd = w * math.sqrt(1 - z * z)
    ref = np.exp(-z * w * times) * (
        amp * np.cos(wd * times) + (vel * w + z * w * amp) / wd * np.sin(wd * times)
    )
    # Measured 7.6e-10: the ~4e-11 relative rounding error of Forward's ω1 (from eigh(K, M),
    # see _accurate_omegas) times ω1 t ≈ 360 rad at 5 s. With Forward's own ω1 the difference
    # is 2e-12, i.e. the propagation itself is exact to rounding. Issue 2 asks for 1e-7.
    assert _relmax(y, ref) < 1e-8


# --- (3) energy never increases --------------------------------------------------------------
@pytest.mark.parametrize(
    ("model", "extra"),
    [
        ("viscous", {}),
        ("kv", {}),
        ("sh", {}),
        ("viscous+kv+sh", {}),
        ("viscous+tip_mass", {"tip_mass": 4e-3}),
        ("sh+root_spring", {"root_spring": 30.0}),
        ("kv+stiffness_gradient", {"stiffness_gradient": 0.7}),
    ],
)
def test_energy_non_increasing(model, extra):
    # E = ½ c'ᵀ M c' + ½ cᵀ K c with the physical M, K of the FE model and c = Φ q from the
    # modal state z = [Ω q; q'] propagated by the package on a dense grid (dt = 1e-4 s, about
    # 1/900 of a period of mode 1 and 1/4 of the fastest KV decay time).
    dt, n = 1e-4, 2000
    fwd = Forward(BEAM, model, np.arange(n) * dt, n_elements=6)
    theta = _params(fwd, **extra)
    A, z0, _ = fwd.state_space(theta)
    omega, _, phi = fwd.modal_system(theta)
    s = A.shape[1]
    m = s // 2
    # Every component of z as an output: one batch item per unit output vector.
    z = propagate.response_uniform(
        np.repeat(A, s, axis=0), np.repeat(z0, s, axis=0), np.eye(s), dt, n
    )  # (s, n)
    phi = np.broadcast_to(phi, (1,) + phi.shape[-2:])[0]
    c = phi @ (z[:m] / omega[0][:, None])
    v = phi @ z[m:]
    M, K, _ = _physical_matrices(fwd, theta[0])
    energy = 0.5 * np.einsum("it,ij,jt->t", v, M, v) + 0.5 * np.einsum("it,ij,jt->t", c, K, c)
    # Released from rest: all energy is strain energy ½ P w0 of the static tip load.
    p_tip = W0 / (fwd.fe.tip @ np.linalg.solve(K, fwd.fe.tip))
    assert energy[0] == pytest.approx(0.5 * p_tip * W0, rel=1e-10)  # rounding of the solves
    # Non-increasing up to rounding (measured: every step decreases, by >= 4e-10 E(0)).
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    assert energy[-1] < 0.99 * energy[0]  # and the damping does act (ζ1 ≈ 1 %, 2.3 periods)


def test_uniform_beam_release_energy_is_static_work():
    # Uniform cantilever: the tip stiffness is 3EI/L³ exactly for Hermite elements
    # (physics.md §4), so the energy at release is ½ (3EI/L³) w0².
    fwd = Forward(BEAM, "viscous", np.arange(4) * 1e-3, n_elements=8)
    A, z0, _ = fwd.state_space(_params(fwd))
    assert 0.5 * z0[0] @ z0[0] == pytest.approx(0.5 * 3 * EI / L**3 * W0**2, rel=1e-12)


# --- (4) initial conditions and the start instant ------------------------------------------
@pytest.mark.parametrize("x_s", [L, 0.2, 0.05])
def test_release_starts_from_static_deflection_at_rest(x_s):
    times = np.arange(50) * 1e-3
    disp = Forward(BEAM.replace(sensor_position=x_s), "viscous+sh", times)
    vel = Forward(BEAM.replace(sensor_position=x_s, quantity="velocity"), "viscous+sh", times)
    y = disp.simulate(_params(disp)).y[0]
    # Static tip-load shape w(x) = w0 x²(3L - x)/(2L³), exact at any x for cubic elements.
    assert y[0] == pytest.approx(W0 * x_s**2 * (3 * L - x_s) / (2 * L**3), rel=1e-12)
    v = vel.simulate(_params(vel)).y[0]
    assert abs(v[0]) <= 1e-12 * np.max(np.abs(v))  # at rest (rounding only)


def test_impulse_starts_at_zero_with_momentum():
    times = np.arange(50) * 1e-3
    p0 = 2e-3  # N s
    disp = Forward(BEAM, "viscous+kv", times, initial="impulse", n_elements=8)
    vel = Forward(
        BEAM.replace(quantity="velocity"), "viscous+kv", times, initial="impulse", n_elements=8
    )
    assert disp.param_names[-1] == "p0"
    y = disp.simulate(_params(disp, p0=p0)).y[0]
    assert abs(y[0]) <= 1e-14 * np.max(np.abs(y))
    v = vel.simulate(_params(vel, p0=p0)).y[0]
    # M c'(0+) = p0 e_tip: tip velocity p0 e_tipᵀ M⁻¹ e_tip.
    tip = vel.fe.tip
    assert v[0] == pytest.approx(p0 * tip @ np.linalg.solve(vel.fe.M, tip), rel=1e-12)


def test_modal_initial_condition_amplitudes_at_sensor():
    # Undamped (gamma = 0): y = Σ_k A_k cos ω_k t + B_k sin ω_k t at the sensor, with the
    # FE frequencies ω_k; the amplitudes are those of the sensor signal (here at 0.6 L).
    times = np.arange(400) * 1e-3
    beam = BEAM.replace(sensor_position=0.6 * L)
    fwd = Forward(beam, "viscous", times, initial="modes:2", n_elements=10)
    assert fwd.param_names == ("E", "gamma", "A1", "B1", "A2", "B2")
    amps = {"A1": 2e-3, "B1": -1e-3, "A2": 4e-4, "B2": 3e-4}
    y = fwd.simulate({"E": E, "gamma": 0.0, **amps}).y[0]
    w = _accurate_omegas(fwd.fe, E)[:2]
    ref = sum(
        amps[f"A{k + 1}"] * np.cos(w[k] * times) + amps[f"B{k + 1}"] * np.sin(w[k] * times)
        for k in range(2)
    )
    # Measured 6e-10, from the ~1e-11 rounding of Forward's frequencies (eigh(K, M)) times
    # ω t ≈ 180 rad; issue 2 asks for 1e-7.
    assert _relmax(y, ref) < 1e-8


@pytest.mark.parametrize("uniform", [True, False])
def test_start_before_first_sample_equals_slicing(uniform):
    rng = np.random.default_rng(5)
    if uniform:
        long = np.arange(400) * 1.5e-3
    else:
        long = np.concatenate([[0.0], np.sort(rng.uniform(0.0, 0.6, 399))])
    full = Forward(BEAM, "viscous+kv+sh", long, n_elements=6)
    part = Forward(BEAM, "viscous+kv+sh", long[120:], n_elements=6, t0=0.0)
    assert full.uniform == uniform and part.uniform == uniform
    theta = _params(full)
    y_full = full.simulate(theta).y[0]
    y_part = part.simulate(theta).y[0]
    # Same exact solution, two propagation routes: rounding only (measured 5e-12).
    assert _relmax(y_part, y_full[120:]) < 1e-10


def test_grid_with_holes_equals_the_arbitrary_times_route():
    # A record resampled around its gaps (Trial.resample(max_gap=...)) is a uniform grid
    # with holes: simulated on the whole grid and indexed, it must equal the
    # eigendecomposition route for arbitrary times on the same stamps.
    keep = np.ones(600, bool)
    keep[100:180] = keep[420:425] = False
    times = 0.01 + np.arange(600)[keep] * 1.5e-3
    assert grid_with_holes(times - times[0])[1].size == keep.sum()
    holed = Forward(BEAM, "viscous+kv+sh", times, n_elements=6)
    assert not holed.uniform and holed._grid is not None
    theta = _params(holed)
    y_grid = holed.simulate(theta).y[0]
    holed._grid = None  # force the route for arbitrary times
    y_any = holed.simulate(theta).y[0]
    # Two exact routes: rounding only (measured 3e-12).
    assert _relmax(y_grid, y_any) < 1e-10
    # Jittered stamps, or a grid with more than GRID_FILL (4) points per sample, are not
    # such a grid.
    rng = np.random.default_rng(1)
    assert grid_with_holes(np.cumsum(rng.uniform(1e-3, 2e-3, 50))) is None
    assert grid_with_holes(np.array([0.0, 1e-3, 20e-3])) is None
    assert grid_with_holes(np.array([0.0, 1e-3, 5e-3])) is not None


# --- (5) batches, invalid sets, errors ---------------------------------------------------------
@pytest.mark.parametrize(
    ("model", "times"),
    [
        ("viscous+kv+sh", np.arange(200) * 2e-3),
        ("viscous+sh+tip_mass", np.arange(200) * 2e-3),
        ("kv+root_spring", np.sort(np.random.default_rng(2).uniform(0, 0.4, 150))),
    ],
)
def test_batch_equals_one_by_one(model, times):
    rng = np.random.default_rng(7)
    fwd = Forward(BEAM, model, times, n_elements=6)
    base = {"E": E, "w0": W0, "tip_mass": 3e-3, "root_spring": 30.0, **LAW_VALUES}
    theta = np.array([[base[n] * rng.uniform(0.7, 1.3) for n in fwd.param_names] for _ in range(7)])
    batch = fwd.simulate(theta)
    assert batch.valid.all()
    for k in range(theta.shape[0]):
        one = fwd.simulate(theta[k])
        # Per-set choices only (propagate's contract); BLAS may round differently in a batch
        # (measured <= 6e-16).
        assert np.max(np.abs(batch.y[k] - one.y[0])) <= 1e-12 * np.max(np.abs(one.y[0]))


def test_invalid_sets_are_flagged_never_nan():
    times = np.arange(200) * 2e-3
    fwd = Forward(BEAM, "viscous+sh+tip_mass", times, n_elements=6)
    good = {"E": E, "gamma": GAMMA, "a": A_SH, "b": B_SH, "tip_mass": 1e-3, "w0": W0}
    bad_values = [
        ("E", 0.0),
        ("E", -1.0),
        ("b", 0.0),
        ("b", -1e-3),
        ("gamma", -0.1),
        ("a", -1.0),
        ("tip_mass", -1e-3),
        ("E", np.nan),
        ("gamma", np.inf),
        ("w0", np.nan),
        # admissible ranges but absurd: the response overflows; flagged, not raised
        ("E", 1e300),
        ("gamma", 1e300),
        ("a", 1e300),
        ("tip_mass", 1e308),
    ]
    rows = [good] + [{**good, k: v} for k, v in bad_values] + [good]
    theta = np.array([[r[n] for n in fwd.param_names] for r in rows])
    with np.errstate(all="raise"):  # no floating-point warnings leak out either
        res = fwd.simulate(theta)
    assert isinstance(res, Response)
    assert res.y.shape == (len(rows), times.size)
    assert np.all(np.isfinite(res.y))
    assert res.valid.tolist() == [True] + [False] * len(bad_values) + [True]
    assert np.all(res.y[1:-1] == 0.0)
    # The good sets are unaffected by their bad neighbours (rounding only).
    alone = fwd.simulate(theta[0]).y[0]
    assert np.max(np.abs(res.y[0] - alone)) <= 1e-12 * np.max(np.abs(alone))
    assert np.array_equal(res.y[0], res.y[-1])
    # check() applies the range rules only; the overflowing sets pass it.
    assert fwd.check(theta).tolist() == [True] + [False] * 10 + [True] * 4 + [True]


@pytest.mark.parametrize("t0", [None, -0.01])
def test_structural_range_rules(t0):
    # The per-set eigendecomposition path: range violations and overflowing sets (absurd E or
    # clamp stiffness that make LAPACK fail) are flagged per set, never raised for the batch.
    fwd = Forward(
        BEAM,
        "viscous+root_spring+stiffness_gradient",
        np.arange(10) * 1e-3,
        n_elements=4,
        t0=t0,
    )
    base = {"E": E, "gamma": GAMMA, "root_spring": 30.0, "stiffness_gradient": 0.0, "w0": W0}
    rows = [
        base,
        {**base, "root_spring": 0.0},
        {**base, "stiffness_gradient": 2.0},
        {**base, "stiffness_gradient": -2.5},
        {**base, "E": 1e308},
        {**base, "root_spring": 1e308},
        base,
    ]
    theta = np.array([[r[n] for n in fwd.param_names] for r in rows])
    assert fwd.check(theta).tolist() == [True, False, False, False, True, True, True]
    with np.errstate(all="raise"):
        res = fwd.simulate(theta)
    assert res.valid.tolist() == [True, False, False, False, False, False, True]
    assert np.all(np.isfinite(res.y)) and np.all(res.y[1:-1] == 0.0)
    assert np.array_equal(res.y[0], res.y[-1])


def test_added_mass_parameter_matches_declared_mass_and_tip_mass():
    # The sampled point mass (added_mass at added_mass_position) and a declared one
    # (Beam.masses, assembled into fem.M) are the same physics; at x = L it is the tip mass.
    from bayesbeam.physics.beam import PointMass

    t = np.arange(200) * 2e-3
    m, x = 3e-3, 0.62 * L
    fwd = Forward(BEAM, "viscous+added_mass", t, n_elements=6)
    y = fwd.simulate(_params(fwd, added_mass=m, added_mass_position=x)).y[0]
    declared = Forward(BEAM.replace(masses=(PointMass(x, m),)), "viscous", t, n_elements=6)
    ref = declared.simulate(_params(declared)).y[0]
    # Same matrices, two eigen-routes (per-set vs fixed basis): round-off, measured 1e-13.
    assert _relmax(y, ref) < 1e-10
    y_tip = fwd.simulate(_params(fwd, added_mass=m, added_mass_position=L)).y[0]
    tip = Forward(BEAM, "viscous+tip_mass", t, n_elements=6)
    assert _relmax(y_tip, tip.simulate(_params(tip, tip_mass=m)).y[0]) < 1e-10
    rows = [_params(fwd, added_mass=m, added_mass_position=v)[0]
            for v in (0.0, L, -1e-3, 1.001 * L)]
    rows.append(_params(fwd, added_mass=-1e-3, added_mass_position=x)[0])
    assert fwd.check(np.array(rows)).tolist() == [True, True, False, False, False]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"times": np.array([0.0])}, "at least 2"),
        ({"times": np.zeros((3, 2))}, "1-D"),
        ({"times": np.array([0.0, np.nan, 1.0])}, "finite"),
        ({"times": np.array([0.0, 2.0, 1.0])}, "strictly increasing"),
        ({"times": np.array([0.0, 1.0, 1.0])}, "strictly increasing"),
        ({"t0": 0.5}, "t0"),
        ({"t0": np.nan}, "t0"),
        ({"initial": "tap"}, "unknown initial condition"),
        ({"initial": "modes:0"}, "modes:K"),
        ({"initial": "modes:x"}, "modes:K"),
        ({"initial": "modes:99"}, "modes"),
        ({"initial": "state"}, "initial_state"),
        ({"initial": "state", "initial_state": (np.zeros(3), np.zeros(3))}, "shape"),
        ({"model": "viscous+drag"}, "nonlinear"),
        ({"model": "viscous+friction"}, "nonlinear"),
    ],
)
def test_bad_setup_raises_clear_error(kwargs, match):
    args = {"model": "viscous", "times": np.arange(5) * 0.1, **kwargs}
    model, times = args.pop("model"), args.pop("times")
    with pytest.raises(ForwardError, match=match):
        Forward(BEAM, model, times, n_elements=4, **args)


def test_bad_model_and_beam_raise():
    with pytest.raises(ModelError, match="unknown model part"):
        Forward(BEAM, "viscous+foo", np.arange(5) * 0.1)
    with pytest.raises(ForwardError, match="Beam"):
        Forward({"length": L}, "viscous", np.arange(5) * 0.1)


def test_bad_theta_raises_clear_error():
    fwd = Forward(BEAM, "viscous+sh", np.arange(5) * 0.1, n_elements=4)
    with pytest.raises(ForwardError, match=r"shape \(B, 5\).*'E', 'gamma', 'a', 'b', 'w0'"):
        fwd.simulate(np.ones((2, 4)))
    with pytest.raises(ForwardError, match="shape"):
        fwd.simulate(np.ones((2, 5, 1)))
    with pytest.raises(ForwardError, match=r"missing parameters \['b'\]"):
        fwd.simulate({"E": E, "gamma": GAMMA, "a": A_SH, "w0": W0})
    with pytest.raises(ForwardError, match="admissible"):
        fwd.modes({"E": -E, "gamma": GAMMA, "a": A_SH, "b": B_SH, "w0": W0})


def test_state_initial_condition_matches_release():
    # initial='state' with the static release shape reproduces initial='release'.
    times = np.arange(100) * 2e-3
    rel = Forward(BEAM, "viscous+kv", times, n_elements=6)
    fe = rel.fe
    c0 = np.linalg.solve(E * fe.K, fe.tip)
    c0 *= W0 / (fe.tip @ c0)
    st = Forward(
        BEAM,
        "viscous+kv",
        times,
        n_elements=6,
        initial="state",
        initial_state=(c0, np.zeros_like(c0)),
    )
    assert st.param_names == ("E", "gamma", "c_d")
    y_rel = rel.simulate(_params(rel)).y[0]
    y_st = st.simulate(_params(st)).y[0]
    assert _relmax(y_st, y_rel) < 1e-9  # K solve vs statics: ~1e-11 (fem.static_tip_shape)


# --- (6) modal damping ratios (physics.md §2) -------------------------------------------------
def _fe_frequencies(n_elements: int = 16) -> np.ndarray:
    return _accurate_omegas(assemble(BEAM, n_elements), E)


def test_viscous_damping_ratios_formula():
    w = _fe_frequencies()
    gamma = 2 * RHOA * W1 * 0.05
    f, z = Forward(BEAM, "viscous", np.arange(3) * 0.01).modes({"E": E, "gamma": gamma, "w0": W0})
    k = f.size
    assert k >= 20  # all but the most heavily damped few stay underdamped
    # Exact: uniform beam, C = (gamma/rhoA) I, λ = -ζω ± iω√(1-ζ²); issue 2 tolerance 1e-8.
    # Forward's ω carry the ~eps λ_max/λ rounding of eigh(K, M) (measured 4e-11 on ω1).
    assert np.allclose(f, w[:k] / (2 * np.pi), rtol=1e-9, atol=0)
    assert np.max(np.abs(z - gamma / (2 * RHOA * w[:k]))) < 1e-8


def test_kelvin_voigt_damping_ratios_formula():
    w = _fe_frequencies()
    c_d = 2 * E * 0.002 / W1
    f, z = modal_properties(BEAM, "kv", {"E": E, "c_d": c_d})
    zeta = c_d * w / (2 * E)
    under = zeta < 1
    k = int(under.sum())
    assert 5 <= k < w.size and f.size == k  # the overdamped modes are left out
    # Uniform beam: KV = K/E, C = (c_d/E) Ω², ζ = c_d ω / (2E); issue 2 tolerance 1e-8.
    # Forward's ω carry the ~eps λ_max/λ rounding of eigh(K, M) (measured 4e-11 on ω1).
    assert np.allclose(f, w[:k] / (2 * np.pi), rtol=1e-9, atol=0)
    assert np.max(np.abs(z - zeta[:k])) < 1e-8


def test_damping_ratios_sorted_and_first_frequencies():
    f, z = modal_properties(
        BEAM, "viscous+kv+sh", {"gamma": GAMMA, "c_d": 1e3, "a": A_SH, "b": B_SH}
    )
    assert np.all(np.diff(f) > 0)
    assert np.all((z > 0) & (z < 1))
    # Light damping barely moves f1: |λ| = ω1 to O(ζ²)-free coupling terms; physics.md §4.
    assert f[0] == pytest.approx(W1 / (2 * np.pi), rel=1e-3)


def test_overdamped_modes_are_counted():
    # Uniform beam, viscous: ζ_n = gamma / (2 rhoA ω_n) (physics.md §2); the modes with
    # ζ_n > 1 have two real eigenvalues each and no frequency.
    w = _fe_frequencies()
    gamma = 2 * RHOA * w[2] * 1.5  # modes 1-3 above critical, the rest below
    f, z, n_over = modal_properties(BEAM, "viscous", {"E": E, "gamma": gamma},
                                    return_overdamped=True)
    assert n_over == int(np.sum(gamma / (2 * RHOA * w) > 1)) == 3
    assert f.size + n_over == w.size and np.all(z < 1)
    assert np.allclose(f, w[3:] / (2 * np.pi), rtol=1e-9, atol=0)
    f2, z2 = modal_properties(BEAM, "viscous", {"E": E, "gamma": gamma})  # the default
    assert np.array_equal(f2, f) and np.array_equal(z2, z)
    _, _, n_none = Forward(BEAM, "viscous", np.arange(3) * 0.01).modes(
        {"E": E, "gamma": 0.0, "w0": W0}, return_overdamped=True)
    assert n_none == 0


def test_modal_properties_errors():
    with pytest.raises(ForwardError, match="c_d"):
        modal_properties(BEAM, "viscous+kv", {"E": E, "gamma": GAMMA})
    with pytest.raises(ForwardError, match="give E"):
        modal_properties(BEAM.replace(E=None), "viscous", {"gamma": GAMMA})
    with pytest.raises(ForwardError, match="not parameters of model"):
        modal_properties(BEAM, "viscous", {"E": E, "gamma": GAMMA, "c_d": 1.0})


# --- (7) narrow-kernel spatial hysteresis -> Kelvin–Voigt ------------------------------------
def test_narrow_kernel_sh_modal_damping_tends_to_kv():
    # Issue 2: the modal damping of a S(b) over that of KV with c_d I = a b²/2 tends to 1 as
    # b -> 0 (0.999 at b = 1e-4 m, L = 0.3048 m, 16 elements). Boundary layer: for x within
    # ~b of the clamp the kernel misses its neighbours ξ < 0; with w'(x) - w'(ξ) ≈ w''(0) u,
    # the missing dissipation is ½ w''(0)² ∫_0^∞ dx ∫_x^∞ g_b(u) u² du = ½ w''(0)² √(2/π) b³
    # (the free end has w'' = 0), against ½ b² ∫ w''², so
    #   1 - ratio = √(2/π) b w''(0)² / ∫ w''² = 4 √(2/π) b / L
    # for every cantilever mode (φ_n''(0)² = 4 β_n⁴, ∫ φ_n''² = β_n⁴ L for unit-norm modes).
    a = 1.0
    deficits = {}
    for b in (1e-3, 1e-4):
        _, z_sh = modal_properties(BEAM, "sh", {"E": E, "a": a, "b": b})
        _, z_kv = modal_properties(BEAM, "kv", {"E": E, "c_d": a * b * b / (2 * BEAM.I)})
        deficits[b] = 1.0 - z_sh[:4] / z_kv[:4]
    predicted = 4 * math.sqrt(2 / math.pi) * 1e-4 / L
    assert np.all(np.abs(deficits[1e-4] / predicted - 1) < 0.01)  # measured <= 0.3 %
    assert np.all(np.abs((1 - deficits[1e-4]) - 0.999) <= 1e-3)  # issue value (measured 0.99895)
    assert np.all(np.abs(deficits[1e-3] / deficits[1e-4] / 10 - 1) < 0.02)  # linear in b


def test_narrow_kernel_operator_tends_to_fem_kv():
    # Cross-check of the two packages' matrices: S(b)/(b²/2) -> ∫φ''φ'' = fem KV / I (uniform
    # I), with the first-order boundary-layer error above (Frobenius, measured 5.3e-3 at 1e-4).
    fe = assemble(BEAM, 16)
    op = HysteresisOperator(fe.nodes, fe.root_dof)
    kv = fe.KV / BEAM.I
    err = [
        np.linalg.norm(op.matrix(b) / (0.5 * b * b) - kv) / np.linalg.norm(kv) for b in (1e-4, 1e-5)
    ]
    assert err[0] < 1e-2
    assert 9 < err[0] / err[1] < 11


# --- (8) structural parameters: first frequencies (physics.md §4) ----------------------------
def _f1_from_beta(beta_l: float) -> float:
    return beta_l**2 * math.sqrt(EI / (RHOA * L**4)) / (2 * np.pi)


@pytest.mark.parametrize("mu", sorted(TIP_MASS_BETA))
def test_tip_mass_first_frequency(mu):
    m_t = mu * RHOA * L
    fwd = Forward(BEAM, "viscous+tip_mass", np.arange(3) * 0.01)
    f, _ = fwd.modes({"E": E, "gamma": 0.0, "tip_mass": m_t, "w0": W0})
    # Issue 2: within 1e-6 at 16 elements (+ the 9-digit reference value).
    assert f[0] == pytest.approx(_f1_from_beta(TIP_MASS_BETA[mu]), rel=1e-6)
    # The same mass in the beam description (the fixed-basis path) agrees.
    f_b, _ = modal_properties(BEAM.replace(tip_mass=m_t), "viscous", {"E": E, "gamma": 0.0})
    assert f_b[0] == pytest.approx(f[0], rel=1e-10)


@pytest.mark.parametrize("kappa", sorted(ROOT_SPRING_BETA))
def test_root_spring_first_frequency(kappa):
    k_theta = kappa * EI / L
    fwd = Forward(BEAM, "viscous+root_spring", np.arange(3) * 0.01)
    f, _ = fwd.modes({"E": E, "gamma": 0.0, "root_spring": k_theta, "w0": W0})
    assert f[0] == pytest.approx(_f1_from_beta(ROOT_SPRING_BETA[kappa]), rel=1e-6)  # issue 2
    f_b, _ = modal_properties(BEAM.replace(root_spring=k_theta), "viscous", {"E": E, "gamma": 0})
    assert f_b[0] == pytest.approx(f[0], rel=1e-10)


def _shooting_f1(g: float) -> float:
    """First frequency (Hz) of (EI e(ξ) W'')'' = ω² rhoA W, e = 1 + g (ξ - 1/2), by shooting.

    Non-dimensional (ξ = x/L, λ = ω² rhoA L⁴ / EI): y = [W, W', m, m'] with m = e W'';
    clamped at ξ = 0, m = m' = 0 at ξ = 1.
    """

    def rhs(xi, y, lam):
        return [y[1], y[2] / (1 + g * (xi - 0.5)), y[3], lam * y[0]]

    def det(lam):
        ends = [
            solve_ivp(rhs, (0, 1), y0, args=(lam,), method="DOP853", rtol=1e-12, atol=1e-14).y[
                2:, -1
            ]
            for y0 in ([0, 0, 1, 0], [0, 0, 0, 1])
        ]
        return ends[0][0] * ends[1][1] - ends[0][1] * ends[1][0]

    lam = brentq(det, 0.3 * 1.875**4, 2.0 * 1.875**4, xtol=1e-14, rtol=1e-14)
    return math.sqrt(lam * EI / (RHOA * L**4)) / (2 * np.pi)


@pytest.mark.parametrize("g", [-0.8, 0.6])
def test_stiffness_gradient_first_frequency(g):
    fwd = Forward(BEAM, "viscous+stiffness_gradient", np.arange(3) * 0.01)
    f, _ = fwd.modes({"E": E, "gamma": 0.0, "stiffness_gradient": g, "w0": W0})
    # FE error at 16 elements ~1e-7 (physics.md §4 for the uniform beam); shooting ~1e-11.
    assert f[0] == pytest.approx(_shooting_f1(g), rel=1e-6)
    f_b, _ = modal_properties(
        BEAM.replace(gradient=Gradient(E=g)), "viscous", {"E": E, "gamma": 0.0}
    )
    assert f_b[0] == pytest.approx(f[0], rel=1e-10)
