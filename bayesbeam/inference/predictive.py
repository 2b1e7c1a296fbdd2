"""Posterior-predictive draws: the model signal of parameter sets plus the fitted noise.

For parameter sets ``θ_s`` (posterior draws) the replicated data are
``y_rep_s = y(θ_s) + e_s`` with ``e_s`` a draw of the noise model the likelihood scores
(:mod:`bayesbeam.stats.likelihood`): i.i.d. N(0, σ²), or, for a model with
``ar1_noise``, the stationary AR(1) with marginal sd σ and lag-one correlation ρ
(``ρ^(Δt/dt_ref)`` between stamps Δt apart when they are not uniform, ``dt_ref`` the
median step), drawn by :func:`~bayesbeam.stats.likelihood.stationary_ar1`. Checking the
data against ``y_rep`` is the posterior-predictive check of Gelman, Meng & Stern (1996,
Statistica Sinica 6, 733-807).

:func:`posterior_predictive` picks the draws from a :class:`~bayesbeam.inference.results.FitResult`
(at random for the fit plots of :mod:`bayesbeam.report.plots`, evenly spaced along the
chain for the coverage of :mod:`bayesbeam.diagnosis.signatures`);
:func:`predictive_draws` simulates given sampling-space points;
:func:`predictive_group` and :func:`log_likelihood_group` make the ArviZ
``posterior_predictive`` and ``log_likelihood`` groups of the complete tree of a fit
(:meth:`bayesbeam.inference.results.FitResult.to_inference_data`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bayesbeam.stats.likelihood import stationary_ar1

__all__ = [
    "LOGLIK_DRAWS",
    "MAX_VALUES",
    "PPC_DRAWS",
    "PRIOR_DRAWS",
    "PredictiveError",
    "log_likelihood_group",
    "loglik_draws",
    "posterior_predictive",
    "predictive_draws",
    "predictive_group",
    "predictive_steps",
]

#: Draws of the ArviZ ``posterior_predictive`` group (:func:`predictive_group`).
PPC_DRAWS = 200
#: Prior draws of the ArviZ ``prior`` group of a saved posterior file.
PRIOR_DRAWS = 1000
#: Posterior draws (at most) of a complete ArviZ tree: the pointwise log-likelihood is
#: computed at these, and the tree's posterior holds the same draws (:func:`loglik_draws`).
LOGLIK_DRAWS = 1000
#: Upper bound on the stored (draws x samples) values of one observation group
#: (25e6 float64 values, 200 MB), for long records.
MAX_VALUES = 25_000_000

#: How :func:`posterior_predictive` picks its draws from the flattened chain.
_SELECTIONS = ("random", "spaced")


class PredictiveError(ValueError):
    """Invalid input to a predictive draw; the message says how to fix it."""


def _noise(problem: Any, X: np.ndarray, T: int, rng: np.random.Generator) -> np.ndarray:
    """Draws of the fitted noise process, shape (n, T), one row per parameter set.

    The times are passed for non-uniform stamps exactly as the likelihood of
    :class:`~bayesbeam.inference.problem.Problem` gets them, so ``y_rep`` samples the
    process that the posterior was scored with.
    """
    names = list(problem.names)
    sigma = X[:, names.index("sigma")]
    z = rng.standard_normal((X.shape[0], T))
    if "rho" not in names:
        return sigma[:, None] * z
    times = None if problem.trial.is_uniform else problem.trial.times
    return sigma[:, None] * stationary_ar1(z, X[:, names.index("rho")], times=times)


def predictive_draws(
    problem: Any, U: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Model signal and replicated data for given sampling-space points.

    Parameters
    ----------
    problem : bayesbeam.inference.problem.Problem
        The problem the points belong to.
    U : array_like, shape (n, ndim)
        Points in the sampling space (e.g. posterior draws).
    rng : numpy.random.Generator
        Source of the noise draws (one standard normal array of shape (n, T)).

    Returns
    -------
    x : ndarray, shape (n, ndim)
        The points in physical units (``problem.theta(U)``).
    y_model : ndarray, shape (n, T)
        Model signal (offset included) in SI units of the trial's quantity.
    y_rep : ndarray, shape (n, T)
        ``y_model`` plus a draw of the fitted noise process.

    Raises
    ------
    PredictiveError
        If a point gives an invalid model (it cannot be a posterior draw then).
    """
    U = np.atleast_2d(np.asarray(U, dtype=float))
    X = problem.theta(U)
    res = problem.predict(X)
    if not np.all(res.valid):
        bad = int(np.count_nonzero(~res.valid))
        raise PredictiveError(
            f"{bad} of {U.shape[0]} points give an invalid forward model; pass posterior "
            "draws of this problem (finite log_prob)"
        )
    y_model = np.asarray(res.y, dtype=float)
    return X, y_model, y_model + _noise(problem, X, y_model.shape[1], rng)


def posterior_predictive(
    problem: Any,
    result: Any,
    n_draws: int,
    rng: np.random.Generator,
    *,
    select: str = "random",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Posterior-predictive draws of the model signal and of replicated data.

    Parameters
    ----------
    problem : bayesbeam.inference.problem.Problem
        The problem that was fitted.
    result : bayesbeam.inference.results.FitResult
        Its posterior.
    n_draws : int
        Number of posterior draws (all stored samples if there are fewer).
    rng : numpy.random.Generator
        Source of the noise draws, and of the draws' choice for ``select="random"``.
    select : {"random", "spaced"}
        ``"random"``: ``n_draws`` samples at random without replacement, in chain order;
        ``"spaced"``: samples evenly spaced over the flattened chain (a deterministic
        thinning; the same draws for every ``rng``).

    Returns
    -------
    x : ndarray, shape (n, ndim)
        Physical values of the draws.
    y_model : ndarray, shape (n, T)
        Model signal of each draw, SI units of the trial's quantity.
    y_rep : ndarray, shape (n, T)
        ``y_model`` plus the fitted noise (i.i.d. or AR(1)).

    Raises
    ------
    PredictiveError
        For a bad ``n_draws`` or ``select``, a result of another model, or a draw with
        an invalid forward model.
    """
    if isinstance(n_draws, bool) or not isinstance(n_draws, (int, np.integer)) or n_draws < 1:
        raise PredictiveError(f"n_draws must be a positive int, got {n_draws!r}")
    if select not in _SELECTIONS:
        raise PredictiveError(f"select must be one of {_SELECTIONS}, got {select!r}")
    if tuple(result.names) != tuple(problem.names):
        raise PredictiveError(
            f"result parameters {list(result.names)} do not match the problem's "
            f"{list(problem.names)}; pass the problem that was fitted"
        )
    flat = result.chain.flat_samples
    n = min(int(n_draws), flat.shape[0])
    if select == "random":
        idx = np.sort(rng.choice(flat.shape[0], size=n, replace=False))
    else:
        idx = np.unique(np.linspace(0, flat.shape[0] - 1, n).astype(int))
    return predictive_draws(problem, flat[idx], rng)


def loglik_draws(n_obs: int, nwalkers: int) -> int:
    """Return the number of draws of a complete ArviZ tree for ``n_obs`` samples.

    :data:`LOGLIK_DRAWS`, fewer for records so long that the pointwise log-likelihood
    would exceed :data:`MAX_VALUES` values, and never fewer than one step of every walker.

    Parameters
    ----------
    n_obs : int
        Samples in the record (T).
    nwalkers : int
        Walkers of the chain (the tree's chains).

    Returns
    -------
    int
        Upper bound on steps x walkers (for :meth:`~bayesbeam.inference.results.FitResult.thin`).
    """
    return max(int(nwalkers), min(LOGLIK_DRAWS, MAX_VALUES // max(1, int(n_obs))))


def predictive_steps(nsteps: int, nwalkers: int, max_draws: int = PPC_DRAWS) -> np.ndarray:
    """Return the steps of a chain that the posterior-predictive group simulates.

    Evenly spaced over the chain, first and last included, all walkers each, with
    steps x walkers at most ``max_draws`` (at least one step).

    Parameters
    ----------
    nsteps, nwalkers : int
        Shape of the chain's samples.
    max_draws : int
        Upper bound on steps x walkers.

    Returns
    -------
    ndarray of int, shape (steps,)
        Step indices into the chain (the ``draw`` coordinate of the group).
    """
    steps = max(1, min(nsteps, max_draws // nwalkers))
    return np.linspace(0, nsteps - 1, steps).round().astype(int)


def predictive_group(problem: Any, samples: np.ndarray, rng: np.random.Generator, *,
                     max_draws: int = PPC_DRAWS) -> np.ndarray:
    """Replicated data for an ArviZ ``posterior_predictive`` group (walkers as chains).

    The steps of :func:`predictive_steps` of every walker, so that the group shares the
    posterior's chains and its draws are a subset of the posterior's (used by
    :meth:`bayesbeam.inference.results.FitResult.to_inference_data`, the one home of a
    complete tree).

    Parameters
    ----------
    problem : bayesbeam.inference.problem.Problem
    samples : ndarray, shape (nsteps, nwalkers, ndim)
        Sampling-space draws (e.g. a thinned chain's ``samples``).
    rng : numpy.random.Generator
        Source of the noise draws.
    max_draws : int
        Upper bound on steps × walkers (at least one step is drawn).

    Returns
    -------
    ndarray, shape (nwalkers, steps, T)
        ``y_rep`` in SI units of the trial's quantity.
    """
    samples = np.asarray(samples, dtype=float)
    nsteps, nwalkers, ndim = samples.shape
    pick = predictive_steps(nsteps, nwalkers, max_draws)
    _, _, y_rep = predictive_draws(problem, samples[pick].reshape(-1, ndim), rng)
    return y_rep.reshape(pick.size, nwalkers, -1).swapaxes(0, 1)


def log_likelihood_group(problem: Any, samples: np.ndarray) -> np.ndarray:
    """Pointwise log-likelihood for an ArviZ ``log_likelihood`` group (walkers as chains).

    :meth:`~bayesbeam.inference.problem.Problem.log_likelihood_pointwise` (the one home
    of the pointwise terms, batched there) at every draw, in ArviZ's axis order.

    Parameters
    ----------
    problem : bayesbeam.inference.problem.Problem
    samples : ndarray, shape (nsteps, nwalkers, ndim)
        Sampling-space draws.

    Returns
    -------
    ndarray, shape (nwalkers, nsteps, T)
        Log densities in nats (AR(1) noise: conditional on the previous sample).
    """
    samples = np.asarray(samples, dtype=float)
    nsteps, nwalkers, ndim = samples.shape
    ll = problem.log_likelihood_pointwise(samples.reshape(-1, ndim))
    return ll.reshape(nsteps, nwalkers, -1).swapaxes(0, 1)
