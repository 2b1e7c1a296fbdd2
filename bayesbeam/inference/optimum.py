"""Local MAP search: scaled L-BFGS-B in the sampler's coordinates, then Newton polishing.

The posteriors of a whole measured record are narrow and badly scaled: at the MAP of
Al 50 cm #0 (9868 samples) the curvatures of the sampling space span 1e2–1e13, the
modal amplitudes in m/s² being the stiffest, and with two damping laws the mode lies
on a curved ridge along which the record fixes only the total damping. L-BFGS-B on
the raw coordinates with a fixed finite-difference step stops there hundreds of nats
short (-5365.9 against -4950.9). Three measures, each cheap:

* the search runs in the sampler's coordinates
  (:class:`~bayesbeam.inference.coordinates.SamplerCoordinates`), where the ridge is
  straight;
* each L-BFGS-B pass works in units of the coordinates' conditional sd at its start
  (:func:`curvature_scales`), and passes restart while they gain (a restart also
  resets L-BFGS-B's curvature memory);
* :func:`newton_polish` finishes with damped Newton steps on a finite-difference
  Hessian.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import scipy.optimize as sopt

from bayesbeam.inference.coordinates import Coordinates, SamplerCoordinates
from bayesbeam.inference.problem import Problem
from bayesbeam.stats.numdiff import fd_gradient, fd_hessian

__all__ = ["best_map", "chain_map", "curvature_scales", "diagonal_sd", "escape_bounds",
           "local_map", "map_bounds", "newton_polish"]

#: L-BFGS-B passes at most per start; a pass that gains under :data:`PASS_GAIN` nats ends
#: the search. On Al 50 cm #0 the second and third passes gained several nats each.
MAX_PASSES = 4
PASS_GAIN = 1e-3
#: Finite-difference step of :func:`local_map`'s gradient, in units of the coordinates'
#: conditional sd (:func:`curvature_scales`). A whole record's log density carries
#: rounding noise of δ ≈ 1e-2 nats along the structural parameters (steel record,
#: 32 elements: the predicted signal jitters by ~1e-8 of its peak, the eigen-solves'
#: rounding, and 11063 samples sum it), and a central difference errs by about
#: δ/h + h² |f‴| / 6 (Nocedal & Wright 2006, §8.1): ~1e4 nats per sd at the former step
#: 1e-6, noise on which L-BFGS-B's line searches failed and the searches stalled
#: thousands of nats below the mode, 1 nat per sd at 1e-2, where the cubic term is
#: ~2e-5 |f‴| (a central difference is exact on a quadratic whatever the step).
#: ``studies/bench_screen.py`` measures it on the measured records.
FD_STEP = 1e-2

#: :func:`best_map` Newton-polishes this many of its best distinct local results,
#: :data:`FIRST_STEPS` steps each, then the best of them to the end. 8 (was 3): on the
#: shipped beam 1, trial 1 with the clamp spring the start nearest the mode ranks 4th
#: after L-BFGS-B. Each polish step is a finite-difference Hessian (2 ndim² points), so
#: on a whole record the extra polishes cost: find_map with drag and a point mass on
#: Al 50 cm #0 took 145 s against 120 s with 3 (same MAP). The diagnosis's screens,
#: whose MAPs only rank candidates and are improved by the chains of the one sampled,
#: pass :data:`SCREEN_POLISHED`.
POLISHED = 8
SCREEN_POLISHED = 3
FIRST_STEPS = 6

#: :func:`escape_bounds`: a coordinate within this fraction of its prior's width of a
#: bound is "on" it; the scan along it has this many interior points; a restart is made
#: only where the scan gains more than :data:`ESCAPE_GAIN` nats.
ON_BOUND = 1e-6
ESCAPE_POINTS = 16
ESCAPE_GAIN = 1.0

#: :func:`best_map` ends by alternating an L-BFGS-B search and a Newton polish from the
#: polished best until a round gains under :data:`REFINE_GAIN` nats, at most
#: :data:`REFINE_ROUNDS` rounds. The polish can stop where its quadratic model fails
#: (a step that gains nothing at every shift) while a fresh L-BFGS-B pass from there still
#: climbs: on Al 60 cm #3 (6620 samples), the point-mass screen of round 2 stopped at
#: +9516.9 nats, behind the tip mass it nests (+9566.1), and one more pass reached
#: +9581.8 in 3 s (the point mass then ranks first, ahead of the EI gradient's +9570.9).
REFINE_ROUNDS = 5
REFINE_GAIN = 0.5

#: Levenberg-Marquardt shifts of :func:`newton_polish`, tried in turn until a step gains
#: (the Hessian in conditional-sd units has unit diagonal, so 1 is its own scale).
LM_SHIFTS = (0.0, 1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6)


def map_bounds(problem: Any) -> list[tuple[float | None, float | None]]:
    """L-BFGS-B bounds in the sampling space: the prior's, 1e-9 inside; None if open.

    Parameters
    ----------
    problem : Problem or JointProblem
        Anything with ``priors.bounds_u``, shape (ndim, 2).

    Returns
    -------
    list of (float or None, float or None)
    """
    return [(lo + 1e-9, hi - 1e-9) if np.isfinite(lo) and np.isfinite(hi) else (None, None)
            for lo, hi in problem.priors.bounds_u]


def diagonal_sd(log_prob: Callable[[np.ndarray], np.ndarray], u: np.ndarray,
                rounds: int = 3, h: float | np.ndarray = 1e-6) -> np.ndarray:
    """Conditional posterior sd of each coordinate from second differences of log_prob.

    The fallback of :func:`~bayesbeam.inference.fit.walker_scale` where the full Laplace
    covariance fails (MAP on a prior bound, -H not positive definite), and the scales of
    the MAP search (:func:`curvature_scales`). Per coordinate ``k`` the curvature
    ``c = -∂²lp/∂u_k²`` comes from a central second difference, or a forward one
    (``u, u+h, u+2h``) where ``u - h`` leaves the support; the step starts at ``h`` and is
    set to half the implied sd ``c^-1/2`` in the next round, so that it matches the
    posterior's own scale whether that is 1e-6 (E, known to ppm) or 1 (a weak parameter).

    Parameters
    ----------
    log_prob : callable
        Vectorised log density, ``(k, ndim) -> (k,)`` (-inf outside the support).
    u : ndarray, shape (ndim,)
        The point (a MAP), inside the support.
    rounds : int
        Step adaptations.
    h : float or ndarray, shape (ndim,)
        First step, sampling-space units.

    Returns
    -------
    ndarray, shape (ndim,)
        NaN where the curvature is not positive.
    """
    u = np.asarray(u, dtype=float)
    ndim = u.size
    h = np.broadcast_to(np.asarray(h, dtype=float), (ndim,)).copy()
    sd = np.full(ndim, np.nan)
    f0 = float(log_prob(u[None])[0])
    for _ in range(rounds):
        E = np.diag(h)
        pts = np.concatenate([u + E, u - E, u + 2 * E])
        f = log_prob(pts)
        fp, fm, f2 = f[:ndim], f[ndim:2 * ndim], f[2 * ndim:]
        central = np.isfinite(fm)
        curv = np.where(central, -(fp - 2 * f0 + fm), -(f2 - 2 * fp + f0)) / h**2
        ok = np.isfinite(curv) & (curv > 0)
        sd = np.where(ok, 1.0 / np.sqrt(np.where(ok, curv, 1.0)), np.nan)
        h = np.where(ok, np.clip(0.5 * sd, 1e-9, 0.5), h)
    return sd



def curvature_scales(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    """Return the conditional sd ``1/sqrt(-∂²f/∂x_j²)`` of each coordinate at ``x``.

    One round of :func:`diagonal_sd` with steps ``1e-4 max(1, |x|)`` (wide enough to see
    the curvature of a weak coordinate away from the mode, where a 1e-6 step measures
    round-off); 1 where the curvature is not positive (a direction the search should
    move in at its own pace).

    Parameters
    ----------
    f : callable
        Vectorised log density, ``(k, ndim) -> (k,)``.
    x : ndarray, shape (ndim,)

    Returns
    -------
    ndarray, shape (ndim,)
    """
    x = np.asarray(x, dtype=float)
    with np.errstate(all="ignore"):
        sd = diagonal_sd(f, x, rounds=1, h=1e-4 * np.maximum(1.0, np.abs(x)))
    return np.where(np.isfinite(sd), sd, 1.0)


def local_map(problem: Any, u0: np.ndarray, *, maxiter: int = 300,
              coords: Coordinates | None = None) -> tuple[np.ndarray, float]:
    """Local MAP search from one start: scaled L-BFGS-B passes in sampler coordinates.

    L-BFGS-B (finite-difference gradient, one-sided on a prior bound, where a central
    difference would be infinite and the search would never leave it) maximises
    ``log_prob(u(v))`` over the sampler's coordinates ``v``: a bijection, so the optimum
    is the MAP in ``u`` (no Jacobian enters). Each pass is scaled by
    :func:`curvature_scales` at its start; passes repeat, up to :data:`MAX_PASSES`,
    while one gains more than :data:`PASS_GAIN` nats.

    Parameters
    ----------
    problem : Problem or JointProblem
        Anything with a vectorised ``log_prob`` and ``priors.bounds_u``.
    u0 : ndarray, shape (ndim,)
        Start in the sampling space.
    maxiter : int
        L-BFGS-B iterations per pass.
    coords : Coordinates, optional
        The coordinates to search in; default :class:`SamplerCoordinates` of a
        :class:`Problem`, ``u`` itself for anything else.

    Returns
    -------
    u : ndarray, shape (ndim,)
    log_prob : float
        ``-inf`` when the search found no finite density.
    """
    if coords is None and isinstance(problem, Problem):
        coords = SamplerCoordinates(problem)
    if coords is not None and coords.identity:
        coords = None
    bounds = map_bounds(problem)
    if coords is not None:  # the laws' total and ratios are unbounded (-inf outside)
        free = {int(j) for j in coords.free}
        bounds = [(None, None) if j in free else b for j, b in enumerate(bounds)]

        def f(V: np.ndarray) -> np.ndarray:
            return problem.log_prob(coords.to_u(V))
    else:
        f = problem.log_prob
    x = np.asarray(u0, dtype=float) if coords is None else coords.to_v(u0)
    v = float(f(x[None])[0])
    for _ in range(MAX_PASSES):
        x0, sc = x, curvature_scales(f, x)
        zb = [(None if lo is None else (lo - x0[j]) / sc[j],
               None if hi is None else (hi - x0[j]) / sc[j])
              for j, (lo, hi) in enumerate(bounds)]

        def negf(z: np.ndarray, x0: np.ndarray = x0, sc: np.ndarray = sc
                 ) -> tuple[float, np.ndarray]:
            val, g = fd_gradient(lambda Z: f(x0 + Z * sc), z, FD_STEP, one_sided=True)
            if not np.isfinite(val):
                return 1e300, np.zeros_like(z)
            return -val, -np.where(np.isfinite(g), g, 0.0)

        res = sopt.minimize(negf, np.zeros_like(x0), jac=True, method="L-BFGS-B",
                            bounds=zb, options={"maxiter": maxiter})
        x_new = x0 + res.x * sc
        v_new = float(f(x_new[None])[0])
        gain = v_new - v if np.isfinite(v) else (math.inf if np.isfinite(v_new) else 0.0)
        if gain > 0:
            x, v = x_new, v_new
        if not gain > PASS_GAIN:
            break
    u = x if coords is None else np.asarray(coords.to_u(x), dtype=float)
    return u, v


def best_map(problem: Any, U: np.ndarray, *, maxiter: int = 300,
             polished: int = POLISHED, mapper: Callable[..., Any] | None = None,
             ) -> tuple[np.ndarray | None, float]:
    """:func:`local_map` from every row of ``U``; the best ``polished``, Newton-polished.

    The best is then refined by alternating :func:`local_map` and :func:`newton_polish`
    until a round gains under :data:`REFINE_GAIN` nats (:data:`REFINE_ROUNDS` at most).

    Parameters
    ----------
    problem : Problem
    U : ndarray, shape (S, ndim)
        Starts in the sampling space.
    maxiter : int
        L-BFGS-B iterations per pass.
    polished : int
        Distinct local results polished (:data:`FIRST_STEPS` steps each, then
        :func:`escape_bounds` where a polish ends on a prior bound).
    mapper : callable, optional
        Runs the local searches and the first polishes, as ``mapper(function,
        items)`` (e.g. the ``map`` of a process pool, whose workers then need
        ``problem`` pickled); default the built-in ``map``. Each is deterministic, so
        the result does not depend on where it ran.

    Returns
    -------
    u : ndarray, shape (ndim,), or None
        None when no start reached a finite density.
    log_prob : float
        ``-inf`` with ``u`` None.
    """
    found = list((mapper or map)(functools.partial(local_map, problem, maxiter=maxiter), U))
    found = sorted((f for f in found if np.isfinite(f[1])), key=lambda f: -f[1])
    if not found:
        return None, -np.inf
    # Polish the best POLISHED distinct results a few steps each, not the best alone:
    # where L-BFGS-B stalls far from the mode, which start stalls highest says little
    # about which polishes highest (Al 30 cm #0, AR(1) screen before its noise start:
    # +2573 and +2527 after L-BFGS-B, +4477 and +4507 after polishing; beam 1, trial 1
    # with the clamp spring: the start nearest the mode ranks 4th of 7 after L-BFGS-B).
    # A polish that ends on a prior bound is followed by escape_bounds. The best of them
    # is then polished to the end.
    bounds = map_bounds(problem)
    kept: list[tuple[np.ndarray, float]] = []
    for u, v in found:
        if len(kept) == polished:
            break
        if not any(np.allclose(u, k, rtol=0.0, atol=1e-8) for k, _ in kept):
            kept.append((u, v))
    # The first polishes are independent of each other: through the mapper too.
    first = functools.partial(_first_polish, problem, maxiter=maxiter)
    best_u, best_v = None, -np.inf
    for u, v in (mapper or map)(first, kept):
        if v > best_v:
            best_u, best_v = u, v
    u, v = newton_polish(problem.log_prob, best_u, best_v, bounds)
    for _ in range(REFINE_ROUNDS):
        u2, v2 = local_map(problem, u, maxiter=maxiter)
        if not v2 > v + REFINE_GAIN:
            return (u2, v2) if v2 > v else (u, v)
        u, v = newton_polish(problem.log_prob, u2, v2, bounds)
    return u, v


def _first_polish(problem: Any, found: tuple[np.ndarray, float], *, maxiter: int
                  ) -> tuple[np.ndarray, float]:
    """:data:`FIRST_STEPS` Newton steps from a local search's result, off a bound if need be.

    One of :func:`best_map`'s first polishes (:func:`newton_polish`, then
    :func:`escape_bounds` and a few steps more where the polish ends on a prior bound).
    """
    u, v = found
    bounds = map_bounds(problem)
    u, v = newton_polish(problem.log_prob, u, v, bounds, iters=FIRST_STEPS)
    u2, v2 = escape_bounds(problem, u, v, maxiter=maxiter)
    if v2 > v:
        u, v = newton_polish(problem.log_prob, u2, v2, bounds, iters=FIRST_STEPS)
    return u, v


def escape_bounds(problem: Any, u: np.ndarray, v: float, *, maxiter: int = 300,
                  coords: Coordinates | None = None) -> tuple[np.ndarray, float]:
    """Leave a prior bound that a local search stopped on, if the posterior rises inward.

    A local search can run a weak coordinate onto its prior bound early, when the
    others are still far from their values, and then stop there: on the shipped
    beam 1, trial 1 (viscous+sh+root_spring+ar1_noise), the start from f2/f1 has the
    right clamp spring, but L-BFGS-B puts the hysteresis width b on its lower bound and
    stops at +12744.6, while the mode on that ridge is at +12803.5 (b 0.056 L). A
    gradient cannot see past the bound's corner, a scan can: for every coordinate on a
    bound (within :data:`ON_BOUND` of the prior's width) the log density is evaluated at
    :data:`ESCAPE_POINTS` points across the prior's range, the others fixed (one
    vectorised call for all of them), and the search is restarted from the best point
    where it beats ``v`` by more than :data:`ESCAPE_GAIN` nats. A coordinate whose optimum
    is its bound (a cause absent from the data) costs one call and no restart.

    Parameters
    ----------
    problem : Problem or JointProblem
        Anything with a vectorised ``log_prob`` and ``priors.bounds_u``.
    u : ndarray, shape (ndim,)
        A local search's result, with ``v = log_prob(u)``.
    v : float
    maxiter : int
        L-BFGS-B iterations per pass of the restart (:func:`local_map`).
    coords : Coordinates, optional
        The restart's search coordinates, as for :func:`local_map`.

    Returns
    -------
    u : ndarray, shape (ndim,)
    v : float
        Never below the ``v`` given.
    """
    if not np.isfinite(v):
        return u, v
    B = np.asarray(problem.priors.bounds_u, dtype=float)
    lo, hi = B[:, 0], B[:, 1]
    width = hi - lo
    finite = np.isfinite(width) & (width > 0)
    tol = ON_BOUND * np.where(finite, width, 1.0)
    on = np.flatnonzero(finite & ((u - lo <= tol) | (hi - u <= tol)))
    if on.size == 0:
        return u, v
    frac = (np.arange(ESCAPE_POINTS) + 0.5) / ESCAPE_POINTS
    P = np.repeat(u[None], on.size * ESCAPE_POINTS, axis=0)
    for i, j in enumerate(on):
        P[i * ESCAPE_POINTS:(i + 1) * ESCAPE_POINTS, j] = lo[j] + frac * width[j]
    with np.errstate(all="ignore"):
        lp = np.asarray(problem.log_prob(P), dtype=float)
    lp = np.where(np.isfinite(lp), lp, -np.inf)
    k = int(np.argmax(lp))
    if not lp[k] > v + ESCAPE_GAIN:
        return u, v
    u2, v2 = local_map(problem, P[k], maxiter=maxiter, coords=coords)
    return (u2, v2) if v2 > v else (u, v)


def chain_map(problem: Any, samples: np.ndarray, log_prob: np.ndarray, u: np.ndarray,
              v: float) -> tuple[np.ndarray, float]:
    """Return the MAP moved to the chain's best point (Newton-polished) where higher.

    A search stops at the best local optimum its starts reach; the chains of the
    sampler explore the whole posterior and can find a higher one (the shipped beam 1,
    trial 1, ``viscous+sh+root_spring+ar1_noise``: the search's 12800.46 against the
    chains' 12803.93, a split of the damping between the laws that no start reached).

    Parameters
    ----------
    problem : Problem
        Anything with a vectorised ``log_prob`` and ``priors.bounds_u``.
    samples : ndarray, shape (..., ndim)
        The chain's points in the sampling space.
    log_prob : ndarray, shape (...)
        Their log densities.
    u : ndarray, shape (ndim,)
        The search's MAP, with ``v = log_prob(u)``.
    v : float

    Returns
    -------
    u : ndarray, shape (ndim,)
    v : float
        Never below the ``v`` given.
    """
    lp = np.asarray(log_prob, dtype=float).ravel()
    if not (lp.size and np.isfinite(lp).any() and np.nanmax(lp) > v + 1e-6):
        return u, v
    i = int(np.nanargmax(lp))
    U = np.asarray(samples, dtype=float).reshape(lp.size, -1)
    return newton_polish(problem.log_prob, U[i], float(lp[i]), map_bounds(problem))


def newton_polish(f: Callable[[np.ndarray], np.ndarray], u: np.ndarray, v: float,
                  bounds: Sequence[tuple[float | None, float | None]],
                  iters: int = 40) -> tuple[np.ndarray, float]:
    """Damped Newton steps with a finite-difference Hessian from a near-optimal point.

    L-BFGS-B crawls along the narrow curved ridges of these posteriors (curvatures
    spanning 1e3-1e10 in u) and can stop short; Newton steps with steps of 0.2
    conditional sd finish the job. Each step is one vectorised call. Where L-BFGS-B
    stalls far from the mode (its line search fails on the slow flow's not quite
    smooth log density: Al 30 cm #0 with drag, AR(1) noise and a moving f1 stopped
    3336 nats short after two iterations a pass), the steps keep climbing: 6 steps gained
    2776 nats there, 40 reached the mode (+3337, 16 s); steps stop as soon as one does
    not gain.

    Parameters
    ----------
    f : callable
        Vectorised log density, ``(k, ndim) -> (k,)``.
    u : ndarray, shape (ndim,)
        The start, with ``v = f(u)``.
    v : float
    bounds : sequence of (float or None, float or None)
        As :func:`map_bounds`; steps are clipped to them.
    iters : int
        Newton steps at most.

    Returns
    -------
    u : ndarray, shape (ndim,)
    v : float
        Never below the ``v`` given.
    """
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds])
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds])
    h = 1e-4 * np.maximum(1.0, np.abs(u))
    # The first Hessian's steps at 0.2 conditional sd too (three rounds of diagonal_sd):
    # on a log density that jitters by ~1e-2 nats (a whole record's rounding), a 1e-4
    # step's second differences are noise, and the first step would fail and end the
    # polish 0.5-30 nats below the mode (tests/inference/test_optimum.py).
    with np.errstate(all="ignore"):
        sd0 = diagonal_sd(f, u, rounds=3, h=h)
    h = np.where(np.isfinite(sd0), 0.2 * sd0, h)
    for _ in range(iters):
        with np.errstate(all="ignore"):
            _, g, H = fd_hessian(f, u, h)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
            break
        curv = -np.diag(H)
        sd = np.where(curv > 0, 1.0 / np.sqrt(np.where(curv > 0, curv, 1.0)), 1.0)
        # Steps of 0.2 conditional sd where the curvature is positive; keep h elsewhere.
        h = np.where(curv > 0, 0.2 * sd, h)
        # The Newton system in units of the conditional sd, where its eigenvalues measure
        # the correlations only (the diagonal is 1), whatever the curvatures' span
        # (1e2-1e13 on a whole record). A step that does not gain is retried with a
        # Levenberg-Marquardt shift mu (Marquardt 1963): shorter and turned toward the
        # gradient, the usual trust-region fallback where the log density is not
        # quadratic over a full Newton step (the slow flow's RK4 grid, for one, changes
        # with the parameters).
        w, V = np.linalg.eigh(-0.5 * (H + H.T) * np.outer(sd, sd))
        gs = V.T @ (g * sd)
        moved = False
        for mu in LM_SHIFTS:
            ww = np.maximum(w + mu, 1e-8 * max(float(np.max(np.abs(w))), 1e-300) + mu)
            un = np.clip(u + sd * (V @ (gs / ww)), lo, hi)
            vn = float(f(un[None])[0])
            if np.isfinite(vn) and vn > v:
                moved = vn > v + 1e-4
                u, v = un, vn
                break
        if not moved:
            break
    return u, v
