"""The immutable record of an emcee run: :class:`Chain`.

:func:`bayesbeam.stats.sampling.run_emcee` returns it; fits, evidences and diagnostics
read it. It holds the stored (thinned) walkers, their log densities, the convergence
figures computed on every step, and the run's bookkeeping, and checks their shapes
agree; nothing here runs a sampler.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bayesbeam.stats.checkpoint import SamplingError

__all__ = ["Chain"]


def _readonly(a: Any, dtype: Any = float) -> np.ndarray:
    a = np.array(a, dtype=dtype)  # copy: the record must not alias caller arrays
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)  # eq=False: arrays have no single truth value
class Chain:
    """Post-burn-in ensemble samples in the sampling space ``u`` with diagnostics.

    Attributes
    ----------
    samples : numpy.ndarray, shape (nsteps, nwalkers, ndim)
        Sampling-space positions after burn-in (and thinning, if asked).
    log_prob : numpy.ndarray, shape (nsteps, nwalkers)
        Log-probability (in ``u`` space) of each sample.
    names : tuple of str
        Parameter names, length ``ndim``.
    tau : numpy.ndarray, shape (ndim,)
        Integrated autocorrelation time in steps (unthinned), of the chain after
        burn-in at the final check; ``inf`` where it could not be estimated.
    ess : numpy.ndarray, shape (ndim,)
        Bulk effective sample size after burn-in (ArviZ, walkers as chains).
    rhat : numpy.ndarray, shape (ndim,)
        Rank-normalised split R-hat, walkers as chains (see the module notes).
    acceptance_fraction : numpy.ndarray, shape (nwalkers,)
        Fraction of accepted proposals per walker over all steps.
    n_calls : int
        Log-probability evaluations (points, not vectorised calls) made by this
        and, when resumed, earlier processes (their counts as of their last
        checkpoint); work redone after an interruption is counted again.
    converged : bool
        Whether all stopping criteria held.
    seconds : float
        Wall-clock seconds spent sampling (summed over resumed runs).
    burn_in : int
        Steps discarded at the start.
    seed : int
        Seed of the sampler's random number generator.
    thin : int
        Storage thinning factor applied to ``samples``.
    n_steps_total : int
        Steps run in total, burn-in included.
    """

    samples: np.ndarray
    log_prob: np.ndarray
    names: tuple[str, ...]
    tau: np.ndarray
    ess: np.ndarray
    rhat: np.ndarray
    acceptance_fraction: np.ndarray
    n_calls: int
    converged: bool
    seconds: float
    burn_in: int
    seed: int
    thin: int = 1
    n_steps_total: int = field(default=-1)

    def __post_init__(self) -> None:
        s = np.asarray(self.samples)
        if s.ndim != 3:
            raise SamplingError(f"samples must be (nsteps, nwalkers, ndim), got {s.shape}")
        nsteps, nwalkers, ndim = s.shape
        names = tuple(str(n) for n in self.names)
        if len(names) != ndim:
            raise SamplingError(f"{len(names)} names for {ndim} parameters")
        lp = np.asarray(self.log_prob)
        if lp.shape != (nsteps, nwalkers):
            raise SamplingError(f"log_prob must be {(nsteps, nwalkers)}, got {lp.shape}")
        for name in ("tau", "ess", "rhat"):
            if np.shape(getattr(self, name)) != (ndim,):
                raise SamplingError(f"{name} must have shape ({ndim},)")
        if np.shape(self.acceptance_fraction) != (nwalkers,):
            raise SamplingError(f"acceptance_fraction must have shape ({nwalkers},)")
        object.__setattr__(self, "samples", _readonly(s))
        object.__setattr__(self, "log_prob", _readonly(lp))
        object.__setattr__(self, "names", names)
        for name in ("tau", "ess", "rhat", "acceptance_fraction"):
            object.__setattr__(self, name, _readonly(getattr(self, name)))
        if self.n_steps_total < 0:
            object.__setattr__(self, "n_steps_total", self.burn_in + nsteps * self.thin)

    @property
    def nsteps(self) -> int:
        """Stored steps after burn-in and thinning."""
        return self.samples.shape[0]

    @property
    def nwalkers(self) -> int:
        """Number of walkers."""
        return self.samples.shape[1]

    @property
    def ndim(self) -> int:
        """Number of parameters."""
        return self.samples.shape[2]

    @property
    def flat_samples(self) -> np.ndarray:
        """Samples flattened over steps and walkers, shape ``(nsteps*nwalkers, ndim)``."""
        return self.samples.reshape(-1, self.ndim)

    @property
    def flat_log_prob(self) -> np.ndarray:
        """Log-probabilities flattened like :attr:`flat_samples`, shape ``(nsteps*nwalkers,)``."""
        return self.log_prob.reshape(-1)

    @property
    def tau_max(self) -> float:
        """Largest integrated autocorrelation time (steps)."""
        return float(np.max(self.tau))

    @property
    def ess_min(self) -> float:
        """Smallest bulk ESS over parameters."""
        return float(np.min(self.ess))

    @property
    def rhat_max(self) -> float:
        """Largest split R-hat over parameters."""
        return float(np.max(self.rhat))

    @property
    def ess_per_second(self) -> float:
        """Smallest bulk ESS per second of sampling wall time (NaN without a time).

        The figure that compares samplers, moves and likelihoods: wall time alone
        rewards a chain that stops early, ESS alone one that runs long.
        """
        return self.ess_min / self.seconds if self.seconds > 0 else math.nan


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------
