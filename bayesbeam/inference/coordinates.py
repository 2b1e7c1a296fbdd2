"""The coordinates the ensemble moves in, and emcee run in them.

With two or more damping laws the data fix the first mode's total damping tightly and
the split among the laws loosely; in the priors' log coordinates that ridge is curved
and emcee crosses it slowly. :class:`SamplerCoordinates` straightens it (log total
first-mode damping and log ratios, unit Jacobian); :func:`sample_in_coordinates` runs
the sampler there and returns the chain in the sampling space ``u`` of
:mod:`bayesbeam.stats.priors`, as every other part of the package reads it. The MAP
search (:mod:`bayesbeam.inference.optimum`) uses the same coordinates.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from scipy.special import logsumexp

from bayesbeam.inference.parallel import ParallelLogProb
from bayesbeam.inference.problem import BETA1, Problem
from bayesbeam.stats.convergence import autocorr_time, ess_rhat
from bayesbeam.stats.families import HalfNormal, LogNormal, LogUniform
from bayesbeam.stats.sampling import Chain, named_moves, run_emcee

__all__ = ["PREBURN_STEPS", "Coordinates", "SamplerCoordinates", "chain_in_u",
           "sample_in_coordinates"]

#: Steps of the discarded first run that returns stranded walkers to the ensemble
#: (:func:`bayesbeam.stats.sampling.preburn_walkers`); ~10 % of a typical fit's steps.
PREBURN_STEPS = 200


class Coordinates(Protocol):
    """What a coordinate map offers the sampler and the MAP search.

    ``to_v`` / ``to_u`` map points (shape (..., ndim) kept) between the sampling space
    ``u`` and the sampler's coordinates ``v``; ``log_jacobian(V)`` is ``log |∂u/∂v|``,
    shape (...,); ``identity`` is True when ``v = u``; ``free`` lists the columns of
    ``v`` that are unbounded (a bound in ``u`` is not a bound on them).
    """

    identity: bool

    def to_v(self, U: np.ndarray) -> np.ndarray: ...  # noqa: D102

    def to_u(self, V: np.ndarray) -> np.ndarray: ...  # noqa: D102

    def log_jacobian(self, V: np.ndarray) -> np.ndarray: ...  # noqa: D102

    @property
    def free(self) -> np.ndarray: ...  # noqa: D102


class SamplerCoordinates:
    """Coordinates the ensemble moves in: the damping laws' total and split.

    With two or more damping laws, the data fix the first mode's total damping ratio
    ζ1 = Σ_j ζ1_j very tightly and the split among the laws only loosely (through the
    higher modes). In the log coordinates ``u_j = log x_j`` of the priors that ridge
    is a curved (hyperbolic) valley, which the affine-invariant moves of emcee cross
    slowly: integrated autocorrelation times ~70 steps for ``viscous+kv`` and ~110 for
    ``viscous+sh`` on the benchmark trial. The sampler therefore moves in

        v_tot = log Σ_j exp(u_j + c_j),     w_j = u_j - u_1  (j >= 2),

    with ``exp(u_j + c_j)`` the law's first-mode damping ratio at the prior's median
    modulus (physics.md §2: ``ζ = gamma/(2 rhoA ω1)``, ``c_d ω1/(2E)``,
    ``eta ω1/(2 E I)`` with eta as in :mod:`bayesbeam.inference.problem`). Both the total and the
    log ratios are straight in these coordinates; τ drops to 20–30 steps. The map is
    a bijection with unit Jacobian (``det ∂(v_tot, w)/∂u = Σ_j p_j = 1``, ``p_j`` the
    shares), so the density is unchanged: ``log_prob_v(v) = log_prob(u(v))``.

    Laws whose prior is not on ``log x`` (a user's Uniform or Normal override), and
    models with fewer than two laws, are left in ``u`` (the identity map).

    Parameters
    ----------
    problem : Problem
    """

    _LOG = (LogUniform, LogNormal, HalfNormal)

    def __init__(self, problem: Problem) -> None:
        beam = problem.trial.beam
        pri = problem.priors
        pE = pri["E"]
        E_c = float(pE.from_u(pE.ppf_u(0.5)))  # prior median: fixed, so resume-safe
        w1 = BETA1**2 * np.sqrt(E_c * beam.I / (beam.rhoA * beam.length**4))
        scale = {
            "gamma": 1.0 / (2 * beam.rhoA * w1),
            "c_d": w1 / (2 * E_c),
            "eta": w1 / (2 * E_c * beam.I),
        }
        idx = [problem.names.index(n) for n in scale
               if n in problem.names and isinstance(pri[n], self._LOG)]
        self.group = np.array(idx if len(idx) >= 2 else [], dtype=int)
        self.c = np.log([scale[problem.names[j]] for j in self.group])

    @classmethod
    def on_columns(cls, group: Any, c: Any) -> SamplerCoordinates:
        """Make the same map on other columns (e.g. one trial's laws inside a joint fit).

        Parameters
        ----------
        group : sequence of int
            Columns of the laws (two or more).
        c : sequence of float
            Their log first-mode damping ratio per unit parameter (as ``self.c``).

        Returns
        -------
        SamplerCoordinates
        """
        out = cls.__new__(cls)
        out.group = np.asarray(group, dtype=int)
        out.c = np.asarray(c, dtype=float)
        if out.group.size == 1 or out.group.shape != out.c.shape:
            raise ValueError("on_columns needs two or more columns and one scale per column")
        return out

    @property
    def identity(self) -> bool:
        """True when the sampler works in ``u`` itself."""
        return self.group.size == 0

    def to_v(self, U: np.ndarray) -> np.ndarray:
        """Map sampling-space points to sampler coordinates, shape (..., ndim) kept."""
        U = np.asarray(U, dtype=float)
        if self.identity:
            return U.copy()
        g = self.group
        V = U.copy()
        V[..., g[0]] = logsumexp(U[..., g] + self.c, axis=-1)
        V[..., g[1:]] = U[..., g[1:]] - U[..., g[:1]]
        return V

    def to_u(self, V: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_v`."""
        V = np.asarray(V, dtype=float)
        if self.identity:
            return V.copy()
        g = self.group
        w = np.zeros(V.shape[:-1] + (g.size,))
        w[..., 1:] = V[..., g[1:]]
        U = V.copy()
        U[..., g] = w + (V[..., g[0]] - logsumexp(w + self.c, axis=-1))[..., None]
        return U


    @property
    def free(self) -> np.ndarray:
        """Columns of ``v`` with no bound: the grouped laws (their total and ratios)."""
        return self.group

    def log_jacobian(self, V: np.ndarray) -> np.ndarray:
        """``log |∂u/∂v|`` = 0 (the map has unit Jacobian), shape ``V.shape[:-1]``."""
        return np.zeros(np.shape(V)[:-1])


def chain_in_u(chain: Chain, u_samples: np.ndarray, log_prob: np.ndarray | None = None) -> Chain:
    """Return the chain moved back from the sampler's coordinates to the sampling space ``u``.

    Convergence was judged in the sampler's coordinates; τ, ESS and R-hat are reported
    for the parameters themselves, with the estimators of the stopping rule (tol 0: τ
    as estimated, no length requirement here).

    Parameters
    ----------
    chain : Chain
    u_samples : ndarray, shape (nsteps, nwalkers, ndim)
    log_prob : ndarray, shape (nsteps, nwalkers), optional
        The log density in ``u`` where the map's Jacobian is not 1.

    Returns
    -------
    Chain
    """
    tau, _ = autocorr_time(u_samples, 0.0)
    ess, rhat = ess_rhat(u_samples)
    lp = chain.log_prob if log_prob is None else log_prob
    return dataclasses.replace(chain, samples=u_samples, log_prob=lp, tau=tau, ess=ess,
                               rhat=rhat)



def sample_in_coordinates(log_prob: Callable[[np.ndarray], np.ndarray], coords: Coordinates,
                          u0: np.ndarray, *, moves: str = "de", helpers: int = 0,
                          **kwargs: Any) -> Chain:
    """Run emcee (:func:`~bayesbeam.stats.sampling.run_emcee`) in ``coords``.

    The walkers start at ``coords.to_v(u0)`` and move on ``log_prob(u(v)) + log|∂u/∂v|``
    with the proposal mixture ``moves`` (default the differential-evolution mixture of
    :func:`~bayesbeam.stats.sampling.de_moves`); the chain comes back in ``u``
    (:func:`chain_in_u`), its log density in ``u``.

    Parameters
    ----------
    log_prob : callable
        Vectorised log density in ``u``, ``(k, ndim) -> (k,)``.
    coords : Coordinates
        e.g. :class:`SamplerCoordinates`.
    u0 : ndarray, shape (nwalkers, ndim)
        Initial walkers in ``u``.
    moves : str
        A name of :data:`~bayesbeam.stats.sampling.MOVE_SETS`.
    helpers : int
        Processes that share each batch of ``log_prob`` with this one
        (:class:`~bayesbeam.inference.parallel.ParallelLogProb`; ``log_prob`` must then
        be picklable, e.g. a problem's bound ``log_prob``). The chain is the same.
    **kwargs
        Passed to :func:`~bayesbeam.stats.sampling.run_emcee` (``seed``, ``max_steps``,
        ``target_ess``, ``names``, ``preburn``, ...).

    Returns
    -------
    Chain
    """
    with ParallelLogProb(log_prob, helpers=helpers) as shared:
        def log_prob_v(V: np.ndarray) -> np.ndarray:
            return shared(coords.to_u(V)) + coords.log_jacobian(V)

        chain = run_emcee(log_prob_v, coords.to_v(u0), moves=named_moves(moves), **kwargs)
    if coords.identity:
        return chain
    return chain_in_u(chain, coords.to_u(chain.samples),
                      chain.log_prob - coords.log_jacobian(chain.samples))
