"""Sampler coordinates: the clamp map (E and root spring as log ω1² and log k)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.special import logsumexp

from bayesbeam.inference.coordinates import (
    ClampCoordinates,
    SamplerCoordinates,
    sample_in_coordinates,
)
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam, PointMass
from bayesbeam.physics.fem import assemble, release_gain
from bayesbeam.stats.families import Uniform
from bayesbeam.trials.synthetic import simulate_trial
from tests.inference.test_joint import _fd_log_det

NE = 8


@pytest.fixture(scope="module")
def problem():
    # A beam with an attached mass (the map must follow the beam as declared, not a
    # uniform one); the record comes from a finer mesh than the problem's.
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10,
                            masses=(PointMass(0.2, 0.004),))
    tr = simulate_trial(beam, "viscous+root_spring", {"gamma": 0.2, "root_spring": 40.0},
                        duration=0.5, dt=1 / 256, noise_sd=1e-5, n_elements=16)
    return Problem(tr, "viscous+kv+root_spring", n_elements=NE)


def test_clamp_map_is_a_bijection_with_its_jacobian(problem):
    sc = SamplerCoordinates(problem)
    assert sc.clamp is not None and not sc.identity
    assert [problem.names[j] for j in sc.group] == ["gamma", "c_d"]
    U = problem.priors.sample_u(np.random.default_rng(0), 200)
    np.testing.assert_allclose(sc.to_u(sc.to_v(U)), U, rtol=0, atol=1e-11)
    # The damping map has unit Jacobian, so the whole map's is the clamp map's.
    V = sc.to_v(U[:4])
    for v, lj in zip(V, sc.log_jacobian(V), strict=True):
        assert lj == pytest.approx(_fd_log_det(sc.to_u, v), abs=1e-6)
    assert "log first-mode ω²" in sc.describe()
    assert "release amplitude" in sc.describe()
    # With the clamp map, the laws' total is log ζ1 of the beam as declared (its
    # attached mass included) at the point's own E and k, whatever the split: checked
    # against the first mode solved directly at each point, ζ1 = φᵀ(gamma G + c_d KV)φ
    # / (2 ω1) (fem.first_mode_integrals; the damped eigenvalue in test_fem). Tolerance:
    # the cubic Hermite tables of log g and log κ with finite-difference slopes at
    # Δs = ln(10)/24: 2.8e-6 at most over 400 prior draws (median 3e-8); 1e-5.
    fe = problem.forward.fe
    beam = problem.trial.beam
    n = list(problem.names)
    ig, ic = n.index("gamma"), n.index("c_d")

    def zeta1(u):
        E, k = math.exp(u[n.index("E")]), math.exp(u[n.index("root_spring")])
        w2, phi = sla.eigh(E * fe.K + k * fe.K_root, fe.M, subset_by_index=[0, 0])
        p = phi[:, 0]
        D = math.exp(u[ig]) * fe.G + math.exp(u[ic]) * fe.KV
        return (p @ D @ p) / (2 * math.sqrt(w2[0]))

    for u, v in zip(U[:5], sc.to_v(U[:5]), strict=True):
        assert v[sc.group[0]] == pytest.approx(math.log(zeta1(u)), abs=1e-5)
        # A move of the split at fixed total keeps the true ζ1 (the ridge the data fix).
        for d in (-1.0, 1.0):
            w = v.copy()
            w[sc.group[1]] += d
            assert math.log(zeta1(sc.to_u(w[None])[0])) == pytest.approx(
                v[sc.group[0]], abs=1e-5)
        E, k = math.exp(u[n.index("E")]), math.exp(u[n.index("root_spring")])
        # w0 moves as the first mode's release amplitude at the sensor, relative to the
        # stiff clamp's (fem.release_gain, here at the point and at κ = 1e6).
        g = release_gain(problem.forward.fe, [k / E, 1e6 * beam.I / beam.length],
                         beam.sensor_x)
        assert v[n.index("w0")] == pytest.approx(u[n.index("w0")] * g[0] / g[1], rel=1e-6)


def test_v_e_is_log_first_eigenvalue_of_the_declared_beam(problem):
    # v_E = log ω1² from the FE eigenproblem of the beam with its attached mass,
    # solved here directly at each (E, k). Tolerance: the cubic Hermite table's
    # interpolation error, at most Δs⁴/384 max|h⁗| with Δs = ln(10)/24 = 0.096 and
    # |h⁗| at most ~10 (h is a smooth step of unit height in s): ~2e-6.
    sc = SamplerCoordinates(problem)
    fe = problem.forward.fe
    iE, ik = problem.names.index("E"), problem.names.index("root_spring")
    U = problem.priors.sample_u(np.random.default_rng(1), 12)
    V = sc.to_v(U)
    for u, v in zip(U, V, strict=True):
        E, k = math.exp(u[iE]), math.exp(u[ik])
        w2 = sla.eigh(E * fe.K + k * fe.K_root, fe.M, eigvals_only=True,
                      subset_by_index=[0, 0])[0]
        assert v[iE] == pytest.approx(math.log(w2), abs=2e-6)
        assert v[ik] == u[ik]


def test_clamp_slope_stays_below_one_everywhere(problem):
    # The map is a bijection of the plane when h' < 1 everywhere, far beyond the table.
    c = ClampCoordinates.for_problem(problem)
    s = np.linspace(-60.0, 20.0, 400_001)
    val, slope = c.h(s)
    assert np.all(slope < 1.0) and np.all(np.isfinite(val))
    # The slope is the value's own derivative (the Jacobian is exact for the map).
    mid = slice(1, -1)
    fd = (val[2:] - val[:-2]) / (s[2:] - s[:-2])
    np.testing.assert_allclose(fd, slope[mid], atol=2e-6)


def test_no_clamp_map_without_a_sampled_spring_or_off_log_scale(problem):
    tr = problem.trial
    assert SamplerCoordinates(Problem(tr, "viscous+kv", n_elements=NE)).clamp is None
    # A user's uniform prior on the spring: u is not log k, so no map.
    pb = Problem(tr, "viscous+root_spring", {"root_spring": Uniform(1.0, 1e3)},
                 n_elements=NE)
    assert isinstance(pb.priors["root_spring"], Uniform)
    assert SamplerCoordinates(pb).clamp is None and SamplerCoordinates(pb).identity


def test_sampling_in_clamp_coordinates_gives_the_brute_force_marginal():
    # A density on (log E, log k) that is a tight ridge of constant ω1 (one mode seen),
    # inside a box: the ensemble moves in (v_E, log k) and must return the marginal of
    # log E that a grid quadrature gives; a wrong Jacobian would tilt it along the ridge.
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)
    fe = assemble(beam, NE, root_dof=True)
    c = ClampCoordinates((0, 1), fe, beam.length / beam.I)
    E0, k0 = 6.2e10, 40.0
    target = math.log(E0) + c.h(np.array(math.log(k0 / E0)))[0]
    lo, hi = np.array([math.log(E0 / 4), math.log(k0 / 20)]), np.array(
        [math.log(4 * E0), math.log(k0 * 50)])
    sd = 0.02

    def log_p(U):
        U = np.atleast_2d(U)
        inside = np.all((U >= lo) & (U <= hi), axis=1)
        v = c.to_v(U)[:, 0]
        return np.where(inside, -0.5 * ((v - target) / sd) ** 2, -np.inf)

    rng = np.random.default_rng(3)
    # Walkers start on the ridge near (E0, k0).
    u0 = np.c_[math.log(E0) + 0.01 * rng.standard_normal(32),
               math.log(k0) + 0.01 * rng.standard_normal(32)]
    u0[:, 0] = c.to_u(np.c_[np.full(32, target), u0[:, 1]])[:, 0]
    chain = sample_in_coordinates(log_p, c, u0, seed=5, max_steps=6000, target_ess=2000,
                                  progress=False, names=("E", "k"))
    draws = chain.samples[chain.samples.shape[0] // 4:, :, 0].ravel()
    # Brute force: the marginal of log E on a fine grid (density in u is log_p).
    gE = np.linspace(lo[0], hi[0], 401)
    gk = np.linspace(lo[1], hi[1], 1201)
    G = np.stack(np.meshgrid(gE, gk, indexing="ij"), axis=-1).reshape(-1, 2)
    lp = log_p(G).reshape(gE.size, gk.size)
    mE = np.exp(logsumexp(lp, axis=1) - logsumexp(lp))
    cdf = np.cumsum(mE)
    for q in (0.1, 0.5, 0.9):
        ref = float(np.interp(q, cdf, gE))
        # The run stops at ESS 2000: a quantile's MCSE is then ~0.03 of the marginal's
        # sd (~0.01 of its 10-90 % width); allow 10x that, plus the grid's spacing.
        width = float(np.interp(0.9, cdf, gE) - np.interp(0.1, cdf, gE))
        assert np.quantile(draws, q) == pytest.approx(ref, abs=0.1 * width + gE[1] - gE[0])


@pytest.mark.parametrize("model", ["viscous+kv+added_mass+stiffness_gradient",
                                   "viscous+kv+added_mass+stiffness_gradient+root_spring"])
def test_scales_follow_the_structure_at_the_start_point(problem, model):
    # A stiffness gradient of 0.9 and a point mass of 10 % of the beam's mass at
    # 0.85 L change the first mode: the declared beam's scales are then off relative
    # to one another, and a move of the split at fixed total changes the true ζ1. At
    # ``at`` the scales come from the first mode of the structure there, solved here
    # directly: M + m N(x)ᵀN(x), E (K + g K_grad) (+ k K_root).
    pb = Problem(problem.trial, model, n_elements=NE)
    n = list(pb.names)
    fe = pb.forward.fe
    beam = pb.trial.beam
    rng = np.random.default_rng(3)
    at = pb.priors.sample_u(rng, 1)[0]
    at[n.index("added_mass")] = pb.priors["added_mass"].to_u(0.1 * beam.beam_mass)
    at[n.index("added_mass_position")] = pb.priors["added_mass_position"].to_u(
        0.85 * beam.length)
    at[n.index("stiffness_gradient")] = pb.priors["stiffness_gradient"].to_u(0.9)
    ig, ic = n.index("gamma"), n.index("c_d")

    def mode(u):
        x = pb.theta(u[None])[0]
        m, xm = x[n.index("added_mass")], x[n.index("added_mass_position")]
        row = fe.shape(np.array([xm]))[0]
        M = fe.M + m * np.outer(row, row)
        K = x[n.index("E")] * (fe.K + x[n.index("stiffness_gradient")] * fe.K_grad)
        if "root_spring" in n:
            K = K + x[n.index("root_spring")] * fe.K_root
        w2, phi = sla.eigh(K, M, subset_by_index=[0, 0])
        p = phi[:, 0]
        return x, math.sqrt(w2[0]), p @ fe.G @ p, p @ fe.KV @ p

    def zeta1(u):
        x, w1, g, kappa = mode(u)
        return (x[ig] * g + x[ic] * kappa) / (2 * w1)

    # Equal shares of the two laws at ``at`` (where a move of the split matters most).
    _, _, g, kappa = mode(at)
    at[ig] = at[ic] + math.log(kappa / g)

    # Tolerances: exact (rounding, 1e-9) without the clamp map; with it the tables'
    # interpolation error as in the test above (1e-5).
    tol = 1e-5 if "root_spring" in n else 1e-9
    moved = {}
    for where in (None, at):
        sc = SamplerCoordinates(pb, at=where)
        v = sc.to_v(at[None])[0]
        np.testing.assert_allclose(sc.to_u(v[None])[0], at, rtol=0, atol=1e-11)
        w = v.copy()
        w[sc.group[1]] += 1.0
        moved[where is None] = math.log(zeta1(sc.to_u(w[None])[0])) - math.log(zeta1(at))
        if where is not None:
            assert v[sc.group[0]] == pytest.approx(math.log(zeta1(at)), abs=tol)
            assert abs(moved[False]) < tol
            assert "at the start point" in sc.describe()
    # The declared beam's scales move ζ1 (measured 6.9e-3 and 1.0e-2; a whole record fixes
    # ζ1 to ~1e-3): the correction is active here.
    assert abs(moved[True]) > 1e-3
