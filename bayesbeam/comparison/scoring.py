"""Scoring one model on one trial: evidence with its error, PSIS-LOO, WAIC, AIC, BIC.

:func:`evaluate` fits the posterior of one candidate model (:func:`bayesbeam.inference.fit.fit`),
or takes a ready fit, and returns its :class:`ModelScore`; :mod:`bayesbeam.comparison.compare`
ranks several such scores. :class:`CompareError`, for bad input anywhere in a
comparison, is defined here because this module is the first the others build on.

What is computed per model (:class:`ModelScore`)
------------------------------------------------
* **log evidence** ``log Z = log p(data | model)`` by bridge sampling on the emcee
  output (Meng & Wong 1996; Gronau et al. 2017), with its Monte-Carlo error that
  accounts for the walkers' autocorrelation (:func:`bayesbeam.stats.evidence.bridge_sampling`);
  the Laplace approximation at the MAP is reported as a cross-check (NaN, with a
  note, when the MAP sits on a prior bound or the Hessian is not negative definite);
* **PSIS-LOO** (ArviZ; Pareto-k warnings recorded in ``notes``) and **WAIC**
  (computed directly), from the pointwise log-likelihood at up to ``n_loo_draws``
  evenly thinned posterior draws;
* **AIC** and **BIC** from the largest log-likelihood found (MAP and samples) and
  the number of sampled parameters (noise parameters and initial conditions included).

What pointwise criteria mean for a time series
----------------------------------------------
LOO and WAIC estimate the predictive density of *new exchangeable observations*.
Samples of one decay record are not exchangeable. With the i.i.d. noise model each
sample's term is ``log p(y_i | θ)`` and leaving one sample out predicts it with its
neighbours still in the fit: a test of interpolation that is optimistic when the
residuals are in fact autocorrelated (as measured residuals are, physics.md §3).
With ``ar1_noise`` the pointwise terms are, automatically (:class:`~bayesbeam.inference.problem.
Problem`), the *conditional* densities ``log p(y_i | y_{i-1}, θ)`` (the first sample
with its stationary marginal); they factorise the likelihood, and LOO then measures
one-step-ahead predictive accuracy given the previous sample. To compare models on
how well they predict a *new trial*, use leave-one-trial-out: stack the pointwise
log-likelihood of several trials (:attr:`ModelScore.loglik` of each) with one group
label per trial and call :func:`bayesbeam.stats.criteria.logo`. BIC's ``n`` (the number of
samples) likewise overstates the information in an autocorrelated record; the
evidence is the principled quantity and leads the verdict.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import finite_json
from bayesbeam.inference.fit import fit
from bayesbeam.inference.predictive import log_likelihood_group
from bayesbeam.inference.problem import Problem
from bayesbeam.inference.results import FitResult
from bayesbeam.inference.settings import fit_settings
from bayesbeam.physics.models import Model, parse_model
from bayesbeam.stats.criteria import LOO, WAIC, ParetoKWarning, WAICWarning, aic, bic, loo, waic
from bayesbeam.stats.evidence import (
    Evidence,
    EvidenceError,
    EvidenceWarning,
    bridge_sampling,
    laplace_evidence,
)
from bayesbeam.stats.sampling import NotConvergedWarning
from bayesbeam.trials.trial import Trial

__all__ = ["CompareError", "ModelScore", "evaluate"]

#: Warnings that evaluate() records in ModelScore.notes instead of re-issuing.
_RECORDED = (NotConvergedWarning, EvidenceWarning, ParetoKWarning, WAICWarning)


class CompareError(ValueError):
    """Invalid input to a model comparison; the message says how to fix it."""


@contextmanager
def _recorded(notes: list[str]) -> Iterator[None]:
    """Record the package's reliability warnings in ``notes``; re-issue all others."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        if issubclass(w.category, _RECORDED):
            note = f"{w.category.__name__}: {w.message}"
            if note not in notes:
                notes.append(note)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)



@dataclass(frozen=True, eq=False)
class ModelScore:
    """Evidence and information criteria of one model on one trial (immutable).

    Attributes
    ----------
    name : str
        Canonical model name, e.g. ``"viscous+kv"``.
    n_params : int
        Sampled parameters (physical, initial conditions and noise).
    n_data : int
        Samples in the trial (``n`` of BIC).
    max_loglik : float
        Largest log-likelihood found, nats (MAP, highest-posterior samples and the
        LOO draws).
    evidence : Evidence
        Bridge-sampling log evidence ``log_z`` ± ``log_z_err`` (nats); NaN if the
        estimator failed (see ``notes``).
    laplace_log_z : float
        Laplace approximation of the log evidence (nats) at the MAP, or at the
        highest-posterior sample if that lies higher; NaN when not applicable.
    loo : LOO
        PSIS-LOO (``elpd_loo``, ``se``, ``pareto_k``; nats).
    waic : WAIC
        WAIC (``elpd_waic``, ``waic`` on the deviance scale).
    aic, bic : float
        ``2k - 2 max_loglik`` and ``k ln n - 2 max_loglik``.
    n_calls : int
        Likelihood evaluations (points) spent: MAP search, sampling, evidence and
        criteria (when a ready FitResult was passed: its sampler calls plus ours).
    seconds : float
        Wall-clock seconds (fit included).
    noise : str
        ``"iid"`` or ``"ar1"`` (pointwise terms conditional on the previous sample).
    result : FitResult
        The posterior, with the problem it was scored on (:attr:`FitResult.problem`; None
        for a score read back from files).
    loglik : numpy.ndarray, shape (n_walkers, n_draws, T)
        Pointwise log-likelihood at the thinned draws (chains = walkers), for
        :func:`bayesbeam.stats.criteria.logo` over several trials.
    notes : tuple of str
        Reliability messages (sampler not converged, Pareto k, failed estimators).
    draws : FitResult or None
        The draws of :attr:`loglik` (:attr:`result` thinned to ``n_loo_draws``) with
        the problem they were scored on (:attr:`FitResult.problem`), from which
        :meth:`save` writes the complete tree; None for a score read back from files.
    """

    name: str
    n_params: int
    n_data: int
    max_loglik: float
    evidence: Evidence
    laplace_log_z: float
    loo: LOO
    waic: WAIC
    aic: float
    bic: float
    n_calls: int
    seconds: float
    noise: str
    result: FitResult
    loglik: np.ndarray
    notes: tuple[str, ...] = ()
    draws: FitResult | None = None

    def save(self, folder: str | Path) -> dict[str, Path]:
        """Write the model's complete ArviZ tree (``posterior.nc``) and ``summary.json``.

        The tree (:meth:`bayesbeam.inference.results.FitResult.to_inference_data` of
        :attr:`draws`) holds the draws of :attr:`loglik` with those pointwise terms, the
        posterior predictive, the observed data on its time axis (s) and prior draws,
        every variable with its ``units``, so that ``arviz.loo`` and ``arviz.compare``
        work on the file and agree with this score; ``summary.json`` summarises the full
        chain. A score read back without them (:func:`bayesbeam.jobs.executor.load_score`)
        saves its posterior only.

        Parameters
        ----------
        folder : str or pathlib.Path
            Created if missing.

        Returns
        -------
        dict
            ``{"netcdf": path, "summary": path}``.
        """
        if self.draws is None or self.loglik.size == 0:
            return self.result.save(folder)
        return self.draws.save(folder, summary_from=self.result, log_likelihood=self.loglik)

    @property
    def log_evidence(self) -> float:
        """Bridge-sampling log evidence, nats."""
        return float(self.evidence.log_z)

    @property
    def log_evidence_err(self) -> float:
        """Monte-Carlo standard error of :attr:`log_evidence`, nats."""
        return float(self.evidence.log_z_err)

    def to_dict(self) -> dict[str, Any]:
        """Return the scalar summary as a strict-JSON dictionary (NaN → ``None``).

        Returns
        -------
        dict
        """
        return finite_json(
            {
                "name": self.name,
                "n_params": self.n_params,
                "n_data": self.n_data,
                "max_loglik": self.max_loglik,
                "log_evidence": self.log_evidence,
                "log_evidence_err": self.log_evidence_err,
                "evidence_method": self.evidence.method,
                "laplace_log_evidence": self.laplace_log_z,
                "elpd_loo": self.loo.elpd_loo,
                "elpd_loo_se": self.loo.se,
                "p_loo": self.loo.p_loo,
                "n_bad_pareto_k": self.loo.n_bad_k,
                "elpd_waic": self.waic.elpd_waic,
                "waic": self.waic.waic,
                "aic": self.aic,
                "bic": self.bic,
                "n_calls": self.n_calls,
                "seconds": self.seconds,
                "noise": self.noise,
                "converged": bool(self.result.chain.converged),
                "notes": list(self.notes),
            }
        )


def evaluate(
    trial: Trial,
    model: str | Model,
    *,
    seed: int = 0,
    result: FitResult | None = None,
    problem: Problem | None = None,
    priors: Mapping[str, Any] | None = None,
    n_loo_draws: int = 1000,
    proposal: str = "normal",
    n_proposal: int | None = 10_000,
    n_top: int = 64,
    outdir: str | Path | None = None,
    progress: bool | None = None,
    log_prob: Callable[[np.ndarray], np.ndarray] | None = None,
    **settings: Any,
) -> ModelScore:
    """Fit one model (or take a fit) and compute its evidence and criteria.

    Parameters
    ----------
    trial : Trial
        The measured record (SI units).
    model : str or Model
        e.g. ``"viscous+kv"``; with ``ar1_noise`` the pointwise terms are AR(1)
        conditional densities (see the module docstring).
    seed : int
        Seed of the fit and of the bridge-sampling proposal draws.
    result : FitResult, optional
        A ready posterior of this model on this trial (then no fit is run).
    problem : Problem, optional
        The matching :class:`~bayesbeam.inference.problem.Problem` (built from ``result``'s
        priors when omitted).
    priors : mapping, optional
        Prior overrides (name → Prior or dict) for a new fit.
    n_loo_draws : int
        Posterior draws (at most) for the pointwise log-likelihood of LOO/WAIC.
    proposal : {"normal", "t", "warp3"}
        Bridge-sampling proposal (:func:`bayesbeam.stats.evidence.bridge_sampling`).
    n_proposal : int or None
        Proposal draws of the bridge (each one likelihood call), at most the number
        of posterior samples in the bridge half; None: as many as those. The default
        10 000 keeps the evidence error at a few 0.01 nats on beam posteriors (the
        posterior half, with its autocorrelation, dominates the error) while saving
        up to half of the evidence's cost on long chains.
    n_top : int
        Highest-posterior samples at which the log-likelihood is evaluated, besides
        the MAP and the LOO draws, to find ``max_loglik``.
    outdir : path, optional
        Where the fit keeps its HDF5 checkpoint.
    progress : bool or None
        Sampler progress line.
    log_prob : callable, optional
        The problem's own ``log_prob`` as the bridge's proposal draws are to be
        evaluated, e.g. a :class:`~bayesbeam.inference.parallel.ParallelLogProb` that
        shares the calls with helper processes (the same values); default
        ``problem.log_prob``.
    **settings
        Forward-model and sampler settings of a new fit (``n_elements``, ``initial``,
        ``nwalkers``, ``target_ess``, ``max_steps``, ``min_steps``), with the defaults
        of :data:`bayesbeam.inference.settings.FIT_DEFAULTS`
        (:func:`bayesbeam.inference.settings.fit_settings`). With a
        ``result`` and no ``problem``, the result's own ``n_elements`` and ``initial``
        take precedence.

    Returns
    -------
    ModelScore

    Raises
    ------
    CompareError
        If ``result``/``problem`` do not match ``model`` or each other.
    """
    settings = fit_settings(settings, caller="evaluate")
    t_start = time.perf_counter()
    model = parse_model(model)
    if result is not None and parse_model(result.model).name != model.name:
        raise CompareError(f"result is a fit of {result.model!r}, not of {model.name!r}")
    if problem is None:
        n_elements, initial = settings["n_elements"], settings["initial"]
        if result is not None:
            n_elements = int(result.settings.get("n_elements", n_elements))
            initial = str(result.settings.get("initial", initial))
            priors = result.priors
        problem = Problem(trial, model, priors, n_elements=n_elements, initial=initial)
    elif problem.model.name != model.name:
        raise CompareError(f"problem is for {problem.model.name!r}, not for {model.name!r}")
    if result is not None and result.priors != problem.priors:
        raise CompareError(
            "the FitResult's priors differ from the Problem's; pass the Problem the fit used "
            "(or none, to rebuild it from the result's priors)"
        )
    notes: list[str] = []
    calls0 = problem.n_calls
    fit_seconds = 0.0
    with _recorded(notes):
        if result is None:
            # The fit records the settings it is given, so they must be the problem's.
            settings.update(n_elements=problem.n_elements, initial=problem.initial)
            result = fit(trial, model, seed=seed, problem=problem, outdir=outdir,
                         progress=progress, **settings)
            # The fit refines the mesh until its MAP converges: score on the fit's mesh.
            # (Calls spent on the fit's refined problems are counted by its sampler's
            # total; MAP polishing on intermediate meshes is not counted.)
            coarse = problem
            problem = problem.with_mesh(int(result.settings["n_elements"]))
            extra_calls = coarse.n_calls - calls0
            if problem is not coarse:
                extra_calls += int(result.chain.n_calls)
            calls0 = problem.n_calls
        else:
            fit_seconds = float(result.settings.get("total_seconds", 0.0))
            extra_calls = int(result.chain.n_calls)
        chain = result.chain
        # Evidence: bridge sampling on the emcee output; Laplace as a cross-check.
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xB51D6E]))
        n_bridge = (chain.nsteps - chain.nsteps // 2) * chain.nwalkers
        n2 = n_bridge if n_proposal is None else max(2, min(int(n_proposal), n_bridge))
        here = problem.n_calls
        try:
            ev = bridge_sampling(chain.samples, log_prob or problem.log_prob, chain.log_prob,
                                 rng=rng, proposal=proposal, n_proposal=n2)
        except EvidenceError as err:
            notes.append(f"bridge sampling failed: {err}")
            ev = Evidence(math.nan, math.nan, f"bridge-{proposal}", 0, converged=False)
        # Calls that log_prob made in helper processes, which problem.n_calls misses.
        helper_calls = ev.n_calls - (problem.n_calls - here)
        # Laplace at the best point known: the MAP, or a sample above it when the
        # optimiser stopped short (the Newton step in laplace_evidence does the rest).
        i_best = int(np.argmax(chain.flat_log_prob))
        u_lap, lp_lap = chain.flat_samples[i_best], float(chain.flat_log_prob[i_best])
        if result.map_u is not None:
            lp_map = float(problem.log_prob(np.asarray(result.map_u)[None])[0])
            if lp_map >= lp_lap:
                u_lap, lp_lap = np.asarray(result.map_u), lp_map
            elif lp_lap - lp_map > 0.5:
                notes.append(
                    f"a posterior sample has log_prob {lp_lap - lp_map:.2f} above the MAP "
                    "estimate: the MAP search stopped short (Laplace uses that sample)"
                )
        laplace = math.nan
        here = problem.n_calls
        try:
            lap = laplace_evidence(log_prob or problem.log_prob, u_lap)
            laplace = lap.log_z
            helper_calls += lap.n_calls - (problem.n_calls - here)
        except EvidenceError as err:  # includes HessianNotNegativeDefiniteError
            notes.append(f"Laplace evidence not available: {err}")
        if log_prob is not None:
            extra_calls += max(0, helper_calls)
        # Pointwise log-likelihood at thinned draws (walkers as chains for ArviZ).
        draws = result.thin(n_loo_draws).with_problem(problem)
        loglik = log_likelihood_group(problem, draws.chain.samples)
        with warnings.catch_warnings():
            # ArviZ guesses dimension names from their lengths; with fewer draws per
            # walker than walkers it warns, though the names are given explicitly.
            warnings.filterwarnings("ignore", message="Found chain dimension to be longer",
                                    category=UserWarning)
            loo_res = loo(loglik)
        waic_res = waic(loglik)
    if not chain.converged and not any(n.startswith("NotConvergedWarning") for n in notes):
        notes.append(
            "the chain did not meet its convergence criteria: the evidence error does not "
            "cover an unconverged chain"
        )
    # Largest log-likelihood: LOO draws, MAP and the highest-posterior samples.
    cands = [loglik.sum(axis=-1).ravel()]
    top = np.argsort(chain.flat_log_prob)[::-1][: max(0, int(n_top))]
    pts = chain.flat_samples[top]
    if result.map_u is not None:
        pts = np.vstack([np.asarray(result.map_u)[None], pts])
    if pts.size:
        cands.append(problem.log_likelihood(pts))
    max_ll = float(np.max(np.concatenate(cands)))
    k = problem.ndim
    n = int(problem.data.size)
    n_calls = problem.n_calls - calls0 + extra_calls + loglik.shape[0] * loglik.shape[1]
    return ModelScore(
        name=model.name,
        n_params=k,
        n_data=n,
        max_loglik=max_ll,
        evidence=ev,
        laplace_log_z=float(laplace),
        loo=loo_res,
        waic=waic_res,
        aic=aic(max_ll, k),
        bic=bic(max_ll, k, n),
        n_calls=int(n_calls),
        seconds=fit_seconds + time.perf_counter() - t_start,
        noise="ar1" if "rho" in problem.names else "iid",
        result=result.with_problem(problem),  # its complete tree: result.to_inference_data()
        loglik=loglik,
        notes=tuple(notes),
        draws=draws,
    )

