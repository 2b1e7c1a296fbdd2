"""The local MAP search against closed-form optima (bayesbeam.inference.optimum)."""

from types import SimpleNamespace

import numpy as np
import pytest

from bayesbeam.inference.optimum import (
    ESCAPE_POINTS,
    best_map,
    chain_map,
    curvature_scales,
    diagonal_sd,
    escape_bounds,
    local_map,
    map_bounds,
    newton_polish,
)


def test_diagonal_sd_matches_a_gaussian_inside_and_on_a_bound():
    # Independent Gaussian coordinates with sd spanning six decades (E is known to ppm,
    # a weak damping coefficient to order 1), the second truncated at its mode (a MAP on
    # a prior bound, where the central difference would step outside the support).
    sd = np.array([2e-6, 0.3, 1.5])
    mode = np.array([24.9, 0.0, -1.0])

    def log_prob(U):
        U = np.atleast_2d(U)
        out = -0.5 * np.sum(((U - mode) / sd) ** 2, axis=1)
        return np.where(U[:, 1] < 0.0, -np.inf, out)

    # Second differences of a quadratic are exact up to round-off, which the adapted
    # steps (half an sd) keep at ~eps |u| / sd ~ 1e-9 relative for the ppm coordinate.
    np.testing.assert_allclose(diagonal_sd(log_prob, mode), sd, rtol=1e-6)


def test_curvature_scales_are_the_conditional_sds():
    # A Gaussian log density with precisions spanning 1e2-1e12 (the range of a whole
    # record's posterior): the scales are its conditional sds, 1 where it is not concave.
    c = np.array([1e2, 1e6, 1e12, -3.0])
    x0 = np.array([0.3, -2.0, 1e-4, 5.0])

    def f(X):
        return -0.5 * np.sum(c * (X - x0) ** 2, axis=-1)

    sc = curvature_scales(f, x0 + np.array([0.01, 0.0, 1e-7, 0.0]))
    assert np.allclose(sc[:3], 1 / np.sqrt(c[:3]), rtol=1e-6)
    assert sc[3] == 1.0


def _gaussian_problem(cov_sd, corr, mode, bounds):
    """A correlated Gaussian 'problem' with known mode (anything with log_prob, bounds_u)."""
    R = np.array(corr, dtype=float)
    C = R * np.outer(cov_sd, cov_sd)
    P = np.linalg.inv(C)

    def log_prob(U):
        D = np.atleast_2d(U) - mode
        out = -0.5 * np.einsum("ki,ij,kj->k", D, P, D)
        lo, hi = np.asarray(bounds, dtype=float).T
        inside = np.all((np.atleast_2d(U) >= lo) & (np.atleast_2d(U) <= hi), axis=1)
        return np.where(inside, out, -np.inf)

    return SimpleNamespace(log_prob=log_prob,
                           priors=SimpleNamespace(bounds_u=np.asarray(bounds, dtype=float))), P


def test_local_map_reaches_a_badly_scaled_correlated_mode():
    # Conditional sds from 1e-6 to 1 (a whole record: the modal amplitudes known to ppm,
    # a weak damping law to order 1) and a 0.99 correlation (the damping ridge). The
    # optimum is known in closed form; the search must end within 1e-2 nats of it, from
    # a start ~1e4 nats below.
    sd = np.array([1e-6, 1e-3, 1.0, 0.5])
    corr = np.eye(4)
    corr[2, 3] = corr[3, 2] = 0.99
    mode = np.array([3.0, -1.0, 0.2, 0.4])
    pb, P = _gaussian_problem(sd, corr, mode, [[-10, 10]] * 4)
    u0 = mode + np.array([1e-4, 1e-1, 1.0, -0.8])
    assert pb.log_prob(u0[None])[0] < -1e3
    u, v = local_map(pb, u0)
    assert v > -1e-2
    # Distance in units of the posterior (Mahalanobis): 0.5 d'Pd = -v.
    d = u - mode
    assert 0.5 * d @ P @ d == -v or abs(0.5 * d @ P @ d + v) < 1e-9


@pytest.mark.parametrize("seed", range(8))
def test_map_search_reaches_the_mode_of_a_density_with_rounding_noise(seed):
    # A whole record's log density jitters by ~1e-2 nats from point to point (the
    # eigen-solves' rounding summed over ~1e4 samples: optimum.FD_STEP). Here: the
    # badly scaled Gaussian above plus uniform noise of that size, a hash of the point's
    # bits (splitmix64's mixer: integer arithmetic, the same on every machine, where a
    # sine of a huge phase is not; it changes at every ulp). The search as find_map runs
    # it (best_map: L-BFGS-B, then Newton steps). L-BFGS-B alone ends 0.02-29 nats below
    # the mode on these eight; the Newton polish, its first steps at 0.2 conditional sd
    # (diagonal_sd), finishes within 0.005 nats (it stopped at once before, its first
    # Hessian from 1e-4 steps being noise): 0.1 nat is the bound.
    sd = np.array([1e-6, 1e-3, 1.0, 0.5])
    corr = np.eye(4)
    corr[2, 3] = corr[3, 2] = 0.99
    mode = np.array([3.0, -1.0, 0.2, 0.4])
    pb, _ = _gaussian_problem(sd, corr, mode, [[-10, 10]] * 4)
    smooth = pb.log_prob
    salt = np.uint64(np.random.default_rng(seed).integers(1, 2**63))

    def noisy(U):
        bits = np.ascontiguousarray(np.atleast_2d(U), dtype=float).view(np.uint64)
        with np.errstate(over="ignore"):
            h = np.bitwise_xor.reduce(bits * np.uint64(0x9E3779B97F4A7C15), axis=1) ^ salt
            h = (h ^ (h >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            h = (h ^ (h >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            h ^= h >> np.uint64(31)
        return smooth(U) + 1e-2 * ((h >> np.uint64(11)) / 2.0**53 - 0.5)

    pb.log_prob = noisy
    u0 = mode + np.array([1e-4, 1e-1, 1.0, -0.8])
    assert smooth(u0[None])[0] < -1e3
    u, _ = best_map(pb, u0[None])
    assert smooth(u[None])[0] > -0.1


def test_local_map_stays_on_a_bound_and_newton_polish_finishes():
    # The mode is outside the support (the MAP is on the bound of coordinate 1); the
    # search returns a point on the bound (within the 1e-9 margin of map_bounds) whose
    # other coordinate is the conditional optimum; Newton polishing never loses density.
    sd = np.array([1e-3, 0.1])
    corr = np.array([[1.0, 0.5], [0.5, 1.0]])
    mode = np.array([0.0, -0.2])
    bounds = [[-5.0, 5.0], [0.0, 5.0]]
    pb, P = _gaussian_problem(sd, corr, mode, bounds)
    u, v = local_map(pb, np.array([0.3, 2.0]))
    assert abs(u[1] - map_bounds(pb)[1][0]) < 1e-6
    # Conditional optimum of u0 given u1 = 0: mode0 - (P01/P00)(u1 - mode1).
    u0_star = mode[0] - P[0, 1] / P[0, 0] * (0.0 - mode[1])
    assert abs(u[0] - u0_star) < 1e-3 * sd[0]
    u2, v2 = newton_polish(pb.log_prob, u, v, map_bounds(pb))
    assert v2 >= v


def test_newton_polish_solves_a_quadratic_in_one_step():
    # On a quadratic the finite-difference Hessian is exact (to round-off), so the
    # first Newton step lands on the mode.
    sd = np.array([1e-5, 2.0, 0.03])
    corr = np.array([[1.0, 0.3, 0.0], [0.3, 1.0, -0.6], [0.0, -0.6, 1.0]])
    mode = np.array([1.0, 2.0, 3.0])
    pb, _ = _gaussian_problem(sd, corr, mode, [[-100, 100]] * 3)
    u0 = mode + 0.5 * sd
    v0 = float(pb.log_prob(u0[None])[0])
    u, v = newton_polish(pb.log_prob, u0, v0, map_bounds(pb), iters=1)
    np.testing.assert_allclose((u - mode) / sd, 0.0, atol=1e-5)
    assert v > -1e-9


def test_newton_polish_reaches_a_mode_a_full_newton_step_overshoots():
    # A stiff quadratic coordinate (curvature 1e6) beside a pseudo-Huber one, started 100
    # units from its mode: there the curvature is ~1e-6 and the full Newton step ~1e6
    # units, far past the mode (and no halving of it gains). The Levenberg-Marquardt
    # shifts turn the step toward the gradient; the log density's maximum is 0.
    def f(X):
        X = np.atleast_2d(X)
        return -0.5e6 * (X[:, 0] - 1.0) ** 2 - (np.sqrt(1 + (X[:, 1] - 2.0) ** 2) - 1)

    u0 = np.array([1.0 + 1e-4, 102.0])
    v0 = float(f(u0)[0])
    u, v = newton_polish(f, u0, v0, [(None, None)] * 2)
    assert v0 < -99 and v > -1e-3
    assert abs(u[1] - 2.0) < 0.05


def _bound_trap(peak: float):
    """x in [0, 1], y in [-5, 5]: a slope down from the bound x = 0 (a local maximum
    there, log density 0) and, for ``peak > 0``, a narrow interior peak near x = 0.7 of
    height ``peak - 3.5`` that no gradient at the bound can see (its tail there is
    ~e^-68). Counts the calls of log_prob."""
    calls = []

    def log_prob(U):
        U = np.atleast_2d(U)
        calls.append(len(U))
        x, y = U[:, 0], U[:, 1]
        out = -5.0 * x - 0.5 * (y / 0.1) ** 2 + peak * np.exp(-0.5 * ((x - 0.7) / 0.06) ** 2)
        inside = (x >= 0) & (x <= 1) & (np.abs(y) <= 5)
        return np.where(inside, out, -np.inf)

    bounds = np.array([[0.0, 1.0], [-5.0, 5.0]])
    return SimpleNamespace(log_prob=log_prob, priors=SimpleNamespace(bounds_u=bounds)), calls


def test_escape_bounds_leaves_a_bound_for_a_higher_interior_mode():
    pb, _ = _bound_trap(peak=12.0)
    # The local search from near the bound stops on it (the test's premise).
    u, v = local_map(pb, np.array([0.05, 0.3]))
    assert u[0] < 1e-6 and abs(v) < 1e-6
    u2, v2 = escape_bounds(pb, u, v)
    # The interior mode: 5 = 12 (x - 0.7)/0.06^2 exp(...) gives x = 0.6985 to 1e-4, log
    # density 12 exp(-0.5 (0.0015/0.06)^2) - 5 x = 8.5038.
    assert abs(u2[0] - 0.6985) < 1e-3 and abs(u2[1]) < 1e-3
    assert abs(v2 - 8.5038) < 1e-3


def test_escape_bounds_keeps_a_bound_that_is_the_optimum_at_the_cost_of_one_call():
    pb, calls = _bound_trap(peak=0.0)
    u, v = local_map(pb, np.array([0.05, 0.3]))
    calls.clear()
    u2, v2 = escape_bounds(pb, u, v)
    assert np.array_equal(u2, u) and v2 == v
    assert calls == [ESCAPE_POINTS]   # one scan of the one coordinate on its bound


def test_best_map_polishes_and_escapes_a_start_stuck_on_a_bound():
    pb, _ = _bound_trap(peak=12.0)
    u, v = best_map(pb, np.array([[0.05, 0.3], [0.1, -0.2]]))
    assert abs(u[0] - 0.6985) < 1e-3 and abs(v - 8.5038) < 1e-3


def test_best_map_through_a_mapper_is_the_serial_search():
    # Three starts: two end on the bound (the same point: polished once), one in the
    # peak's basin; a mapper (e.g. a process pool's map) runs the three searches and the
    # two distinct first polishes, and the answer is the serial one bit for bit.
    starts = np.array([[0.05, 0.3], [0.1, -0.2], [0.69, 0.01]])
    pb, _ = _bound_trap(peak=12.0)
    u0, v0 = best_map(pb, starts)
    seen = []

    def mapper(fn, items):
        items = list(items)
        seen.append((fn.func.__name__, len(items)))
        return [fn(x) for x in items]

    u, v = best_map(pb, starts, mapper=mapper)
    assert np.array_equal(u, u0) and v == v0
    assert seen == [("local_map", 3), ("_first_polish", 2)]


def test_chain_map_moves_to_a_higher_mode_the_chain_found_and_polishes_it():
    # Two Gaussian bumps in 2-D: a local mode at (-1, 0), log density 0, and the
    # global one at (2, 1), log density 3 (widths 0.3 and 0.5: the bumps do not overlap,
    # so each mode sits at its centre to ~1e-9).
    def log_prob(U):
        U = np.atleast_2d(U)
        a = -0.5 * np.sum(((U - [-1.0, 0.0]) / 0.3) ** 2, axis=1)
        b = 3.0 - 0.5 * np.sum(((U - [2.0, 1.0]) / 0.5) ** 2, axis=1)
        return np.logaddexp(a, b)

    pb = SimpleNamespace(log_prob=log_prob,
                         priors=SimpleNamespace(bounds_u=np.array([[-5.0, 5.0]] * 2)))
    u0 = np.array([-1.0, 0.0])
    v0 = float(log_prob(u0)[0])
    near = np.array([[[-1.1, 0.05]], [[2.2, 0.8]]])  # (steps, walkers, ndim)
    u, v = chain_map(pb, near, log_prob(near.reshape(-1, 2)).reshape(2, 1), u0, v0)
    np.testing.assert_allclose(u, [2.0, 1.0], atol=1e-6)
    assert v == pytest.approx(3.0, abs=1e-9)
    # A chain that found nothing higher leaves the MAP as it was.
    low = near[:1]
    u2, v2 = chain_map(pb, low, log_prob(low.reshape(-1, 2)).reshape(1, 1), u0, v0)
    assert v2 == v0 and np.array_equal(u2, u0)


def test_best_map_keeps_searching_where_the_polish_stalls(monkeypatch):
    # Where the Newton polish stops (its quadratic model fails, as on a whole record's
    # slow flow), best_map alternates further L-BFGS-B searches with it until a round
    # gains under REFINE_GAIN. Here the polish is replaced by one that never moves, and
    # the log density is a narrow curved ridge (a banana, mode 0 at (1, 1); the shape of
    # a point mass's E-mass-position ridge) on which a search cut to 5 iterations a pass
    # stops far short of the mode.
    import bayesbeam.inference.optimum as opt

    def log_prob(U):
        U = np.atleast_2d(U)
        return -0.5 * ((U[:, 1] - U[:, 0] ** 2) / 0.01) ** 2 - 0.5 * ((U[:, 0] - 1.0) / 0.5) ** 2

    pb = SimpleNamespace(log_prob=log_prob,
                         priors=SimpleNamespace(bounds_u=np.array([[-5.0, 5.0]] * 2)))
    u0 = np.array([-1.5, 2.25])
    monkeypatch.setattr(opt, "newton_polish", lambda f, u, v, bounds, iters=40: (u, v))
    monkeypatch.setattr(opt, "escape_bounds", lambda problem, u, v, maxiter=300: (u, v))
    _, v_one = local_map(pb, u0, maxiter=5)
    assert v_one < -5.0  # one search alone stops short (-6.1)
    u, v = best_map(pb, u0[None], maxiter=5)
    # Without the refinement best_map would return v_one; with it, within a nat of the
    # mode (successive searches reach -3.3, -1.4, -0.5, -0.04).
    assert v > -1.0
    assert abs(u[1] - u[0] ** 2) < 0.03  # on the ridge (3 of its widths)
