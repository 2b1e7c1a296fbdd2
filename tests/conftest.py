"""Shared fixtures: repository paths and the public real data sets."""

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = REPO.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def real_data_root() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"public real data sets not found at {REAL_DATA} (expected beside the repo)")
    return REAL_DATA


def _result_from_samples(problem, u, *, seed=0, map_u=None):
    """A FitResult whose chain holds the given sampling-space draws ``u``.

    ``u`` has shape (n_steps, n_walkers, ndim); log densities are the problem's own, the
    convergence figures are placeholders (the tests that use this check what is computed
    from the draws, not the sampler).
    """
    from bayesbeam.inference.results import FitResult
    from bayesbeam.stats.sampling import Chain

    nsteps, nwalkers, nd = u.shape
    chain = Chain(
        samples=u, log_prob=problem.log_prob(u.reshape(-1, nd)).reshape(nsteps, nwalkers),
        names=problem.names, tau=np.ones(nd), ess=np.full(nd, 500.0), rhat=np.ones(nd),
        acceptance_fraction=np.full(nwalkers, 0.3), n_calls=0, converged=True,
        seconds=0.0, burn_in=0, seed=seed,
    )
    return FitResult(model=problem.model.name, chain=chain, priors=problem.priors, map_u=map_u)


def _gaussian_cloud_result(problem, truth, sd_u, nsteps=40, nwalkers=16, seed=0):
    """A FitResult whose 'posterior' is a Gaussian cloud around ``truth`` (sd ``sd_u`` in u)."""
    rng = np.random.default_rng(seed)
    u0 = problem.priors.to_u(np.asarray(truth)[None])[0]
    u = u0 + np.asarray(sd_u) * rng.standard_normal((nsteps, nwalkers, u0.size))
    return _result_from_samples(problem, u, seed=seed)


@pytest.fixture(scope="session")
def result_from_samples():
    """Factory of stand-in FitResults from given draws (see ``_result_from_samples``)."""
    return _result_from_samples


@pytest.fixture(scope="session")
def gaussian_cloud_result():
    """Factory of stand-in FitResults around a truth (see ``_gaussian_cloud_result``)."""
    return _gaussian_cloud_result
