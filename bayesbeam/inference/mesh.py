"""Mesh convergence at the MAP: the forward model's discretisation error below the noise.

A fit is only as good as its forward model. The Hermite mesh converges as ``h^4`` in the
frequencies (physics.md §4), but what matters is the *signal* the data see: a mode whose
frequency is wrong by a relative ``ε`` drifts in phase by ``2π f ε t`` over the record, and
on a long, quiet record that is many noise levels. The sensor's band
(:attr:`bayesbeam.trials.trial.Trial.sensor_band`) limits the modes that enter the signal,
so the mesh only has to resolve those; how finely is decided here, at the MAP, by the
data's own likelihood:

1. evaluate the model at the MAP on the current mesh and on the next finer one of
   :data:`LADDER`;
2. the mesh is *converged* when the log-likelihood moves by at most :data:`MAX_DELTA_LOGLIK`
   (1 nat: a change the posterior would not notice against its own spread) and the
   predicted signal by at most :data:`MAX_DELTA_PREDICTION` (0.1 σ) at every sample;
3. otherwise move to the finer mesh, re-optimise the MAP there and repeat.

The record (:func:`converge_mesh`) goes into every fit's JSON as ``mesh``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from bayesbeam.inference.problem import Problem

__all__ = ["LADDER", "MAX_DELTA_LOGLIK", "MAX_DELTA_PREDICTION", "converge_mesh", "mesh_check",
           "on_mesh"]

#: Meshes tried, coarse to fine (elements). Each step refines h by 1.33-1.5, so the
#: frequency error of a converging mode falls by 3-5x per step.
LADDER = (8, 12, 16, 24, 32, 48, 64, 96)

#: Largest change of the log-likelihood at the MAP (nats) between a mesh and the next.
MAX_DELTA_LOGLIK = 1.0

#: Largest change of the predicted signal at any sample between a mesh and the next,
#: in units of the fitted noise σ.
MAX_DELTA_PREDICTION = 0.1


def _next_mesh(n: int) -> int:
    finer = [m for m in LADDER if m > n]
    return finer[0] if finer else (3 * n + 1) // 2


def mesh_check(coarse: Problem, fine: Problem, u: np.ndarray) -> dict[str, Any]:
    """Compare two meshes' predictions and log-likelihoods at one point.

    Parameters
    ----------
    coarse, fine : Problem
        The same trial, model and priors on two meshes.
    u : ndarray, shape (ndim,)
        Point in the sampling space (the MAP).

    Returns
    -------
    dict
        ``n_elements``, ``refined_n_elements``, ``delta_loglik`` (fine minus coarse,
        nats), ``max_delta_prediction_sigma`` (largest |Δy| over σ) and ``converged``.
    """
    u = np.atleast_2d(np.asarray(u, dtype=float))
    X = coarse.theta(u)
    sigma = float(X[0, coarse.names.index("sigma")])
    yc, yf = coarse.predict(X), fine.predict(X)
    ll_c = float(coarse.log_likelihood(u)[0])
    ll_f = float(fine.log_likelihood(u)[0])
    if yc.valid[0] and yf.valid[0] and np.isfinite(ll_c) and np.isfinite(ll_f):
        dpred = float(np.max(np.abs(yf.y[0] - yc.y[0]))) / sigma
        dll = ll_f - ll_c
    else:  # a mesh on which the MAP is invalid cannot be called converged
        dpred, dll = float("inf"), float("inf")
    return {
        "n_elements": coarse.n_elements,
        "refined_n_elements": fine.n_elements,
        "delta_loglik": dll,
        "max_delta_prediction_sigma": dpred,
        "converged": bool(abs(dll) <= MAX_DELTA_LOGLIK and dpred <= MAX_DELTA_PREDICTION),
    }


def on_mesh(problem: Problem, mesh: Mapping[str, Any] | None) -> Problem:
    """Return ``problem`` on a mesh record's element count (itself where it is the same).

    Parameters
    ----------
    problem : Problem
    mesh : mapping or None
        A :func:`converge_mesh` record (``n_elements``); None keeps the problem's mesh.

    Returns
    -------
    Problem
    """
    n = int((mesh or {}).get("n_elements", problem.n_elements))
    return problem if n == problem.n_elements else problem.with_mesh(n)


def converge_mesh(
    problem: Problem,
    u_map: np.ndarray,
    lp_map: float,
    optimise: Callable[[Problem, np.ndarray], tuple[np.ndarray, float]],
    *,
    refine: bool = True,
    progress: Callable[[str], None] | None = None,
    kept_because: str = "as asked (refine_mesh=False)",
) -> tuple[Problem, np.ndarray, float, dict[str, Any]]:
    """Refine the mesh until the MAP's prediction no longer depends on it.

    Parameters
    ----------
    problem : Problem
        The problem on the starting (coarsest) mesh.
    u_map : ndarray, shape (ndim,)
        Its MAP in the sampling space.
    lp_map : float
        Log posterior at ``u_map``.
    optimise : callable
        ``optimise(problem, u0) -> (u, log_prob)``: a local MAP search from ``u0``,
        used after each refinement.
    refine : bool
        False: check the starting mesh against the next one and report, but keep it.
    progress : callable, optional
        Called with a one-line message at each refinement.
    kept_because : str
        Why an unconverged mesh was kept with ``refine`` False (ends the summary).

    Returns
    -------
    problem : Problem
        On the converged mesh (if none converges: the last mesh of :data:`LADDER`, or the
        starting one when that is finer).
    u_map : ndarray
    lp_map : float
    record : dict
        ``n_elements`` (final), ``converged`` (bool), ``checks`` (list of
        :func:`mesh_check` records, coarse to fine), ``criterion`` (text),
        ``band_hz`` (the sensor band the modes were limited to; None: all modes) and
        ``summary`` (one line).
    """
    checks: list[dict[str, Any]] = []
    converged = False
    while True:
        n_next = _next_mesh(problem.n_elements)
        fine = problem.with_mesh(n_next)  # same priors: same u space
        chk = mesh_check(problem, fine, u_map)
        checks.append(chk)
        if chk["converged"]:
            converged = True
            break
        if not refine or problem.n_elements >= LADDER[-1]:
            break
        if progress is not None:
            progress(
                f"mesh: {problem.n_elements} elements not converged at the MAP "
                f"(Δloglik {chk['delta_loglik']:.3g}, "
                f"Δy {chk['max_delta_prediction_sigma']:.3g} σ); refining to {n_next}"
            )
        problem = fine
        u_map, lp_map = optimise(problem, u_map)
    band = problem.forward.bandwidth
    if converged:
        last = checks[-1]
        summary = (
            f"{problem.n_elements} elements, converged at the MAP (next mesh "
            f"{last['refined_n_elements']}: Δloglik {last['delta_loglik']:.2g} nat, "
            f"Δy {last['max_delta_prediction_sigma']:.2g} σ)"
        )
    else:
        last = checks[-1]
        summary = (
            f"{problem.n_elements} elements, NOT converged: a finer mesh "
            f"({last['refined_n_elements']}) changes the MAP's prediction (Δloglik "
            f"{last['delta_loglik']:.3g} nat, Δy {last['max_delta_prediction_sigma']:.3g} σ)"
            + ("; results may carry discretisation error" if refine else
               f"; the mesh was kept {kept_because}")
        )
    record = {
        "n_elements": problem.n_elements,
        "converged": converged,
        "refined": bool(refine),
        "checks": checks,
        "criterion": (
            f"|Δ log-likelihood| <= {MAX_DELTA_LOGLIK} nat and max |Δy| <= "
            f"{MAX_DELTA_PREDICTION} σ at the MAP against the next finer mesh"
        ),
        "band_hz": band,
        "summary": summary,
    }
    return problem, u_map, lp_map, record
