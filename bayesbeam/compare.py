"""Model comparison: evidence with error bars, information criteria, Bayes factors.

For every candidate model (damping laws and extensions, :mod:`bayesbeam.models`) on
one trial, :func:`evaluate` fits the posterior (:func:`bayesbeam.fit.fit`) and scores
it; :func:`compare` ranks the scores and says when the data cannot tell models apart.

What is computed per model (:class:`ModelScore`)
------------------------------------------------
* **log evidence** ``log Z = log p(data | model)`` by bridge sampling on the emcee
  output (Meng & Wong 1996; Gronau et al. 2017), with its Monte-Carlo error that
  accounts for the walkers' autocorrelation (:func:`bayesbeam.evidence.bridge_sampling`);
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
With ``ar1_noise`` the pointwise terms are, automatically (:class:`~bayesbeam.problem.
Problem`), the *conditional* densities ``log p(y_i | y_{i-1}, θ)`` (the first sample
with its stationary marginal); they factorise the likelihood, and LOO then measures
one-step-ahead predictive accuracy given the previous sample. To compare models on
how well they predict a *new trial*, use leave-one-trial-out: stack the pointwise
log-likelihood of several trials (:attr:`ModelScore.loglik` of each) with one group
label per trial and call :func:`bayesbeam.criteria.logo`. BIC's ``n`` (the number of
samples) likewise overstates the information in an autocorrelated record; the
evidence is the principled quantity and leads the verdict.

When models are "indistinguishable"
-----------------------------------
Two models are reported indistinguishable when their log evidences differ by no more
than ``max(2 sqrt(err_a² + err_b²), threshold)``: twice the combined Monte-Carlo
standard error (a difference inside it is noise of the estimator), or ``threshold``
nats (default 1), whichever is larger. The default follows Kass & Raftery (1995,
J. Am. Stat. Assoc. 90, 773-795, §3.2): a Bayes factor below ``e¹`` (2 ln B < 2) is
"not worth more than a bare mention". :attr:`Comparison.indistinguishable` lists the
models tied with the best one (the best included), and the verdict never calls one
model better than another inside that band.

Prior sensitivity
-----------------
Evidences depend on the widths of the priors of the parameters that differ between
models (the Occam factor). For every prior of a non-shared parameter, halved and
doubled in width (:meth:`bayesbeam.priors.Prior.scaled`), the evidence is
recomputed from the existing posterior samples by importance reweighting,

    Z'/Z = E_post[p'(θ) / p(θ)],

with its Monte-Carlo error (:func:`prior_reweight`). This is exact in expectation
where the support of ``p'`` lies inside that of ``p`` (a narrowed prior) and the
posterior samples are numerous enough inside the new support; when too few are, no
number is returned. For a widened prior the region beyond the old bounds is not
sampled, so the estimate is a lower bound whenever the posterior reaches the old
bound (it is then flagged), and exact otherwise. Models outside the tie band that
tie with (or beat) the best one under such a change are listed in
:attr:`Comparison.prior_dependent` and named in the verdict: their lower rank is an
Occam factor of a prior width, not something the data decided. A typical case is
spatial hysteresis with a narrow kernel against Kelvin–Voigt (physics.md §2): the
fits are identical and the evidence differs only by the fraction of b's prior the
data cannot exclude.

Posterior model probabilities ``P_k = π_k Z_k / Σ_j π_j Z_j`` (prior odds ``π``,
equal by default) carry first-order errors from the evidence errors,
``sd(P_k)² = Σ_j P_k² (δ_kj - P_j)² err_j²``.
"""

from __future__ import annotations

import html
import json
import math
import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import logsumexp

from bayesbeam.criteria import (
    LOO,
    WAIC,
    ParetoKWarning,
    WAICWarning,
    aic,
    bic,
    elpd_difference,
    loo,
    waic,
)
from bayesbeam.evidence import (
    Evidence,
    EvidenceError,
    EvidenceWarning,
    bridge_sampling,
    effective_sample_size,
    laplace_evidence,
)
from bayesbeam.fit import fit, thin_result
from bayesbeam.models import Model, parse_model
from bayesbeam.priors import PriorSet
from bayesbeam.problem import Problem
from bayesbeam.results import FitResult
from bayesbeam.sampling import NotConvergedWarning
from bayesbeam.trial import Trial

__all__ = [
    "DEFAULT_THRESHOLD",
    "CompareError",
    "Comparison",
    "ModelScore",
    "PriorReweight",
    "SensitivityRow",
    "compare",
    "compare_scores",
    "evaluate",
    "prior_reweight",
    "prior_sensitivity",
]

#: Default tie threshold on |Δ log Z| in nats (Kass & Raftery 1995: B < e is "not
#: worth more than a bare mention").
DEFAULT_THRESHOLD = 1.0
#: Effective posterior samples that must stay inside a changed prior for a reweighted
#: evidence to be reported (relative error of the estimate about 1/sqrt(100) = 0.1).
MIN_EFFECTIVE_INSIDE = 100.0
#: Edge check for widened priors: the posterior "reaches" an old bound when more than
#: EDGE_FRACTION of the samples lie within EDGE_BAND (fraction of the u-width) of it.
EDGE_BAND = 0.02
EDGE_FRACTION = 0.01
#: Warnings that evaluate() records in ModelScore.notes instead of re-issuing.
_RECORDED = (NotConvergedWarning, EvidenceWarning, ParetoKWarning, WAICWarning)
#: Forward-model batch for the pointwise log-likelihood (bounds memory: B x T floats).
_BATCH = 256


class CompareError(ValueError):
    """Invalid input to a model comparison; the message says how to fix it."""


def _finite_or_none(x: Any) -> Any:
    """Replace non-finite floats by ``None`` recursively (strict JSON)."""
    if isinstance(x, bool | str) or x is None:
        return x
    if isinstance(x, int | np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_finite_or_none(v) for v in x]
    return x


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


# --------------------------------------------------------------------------- one model


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
        The posterior.
    loglik : numpy.ndarray, shape (n_walkers, n_draws, T)
        Pointwise log-likelihood at the thinned draws (chains = walkers), for
        :func:`bayesbeam.criteria.logo` over several trials.
    notes : tuple of str
        Reliability messages (sampler not converged, Pareto k, failed estimators).
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
        return _finite_or_none(
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


def _pointwise(problem: Problem, U: np.ndarray) -> np.ndarray:
    out = np.empty((U.shape[0], problem.data.size))
    for i in range(0, U.shape[0], _BATCH):
        out[i : i + _BATCH] = problem.log_likelihood_pointwise(U[i : i + _BATCH])
    return out


def evaluate(
    trial: Trial,
    model: str | Model,
    *,
    seed: int = 0,
    result: FitResult | None = None,
    problem: Problem | None = None,
    priors: Mapping[str, Any] | None = None,
    n_elements: int = 16,
    initial: str = "release",
    nwalkers: int | None = None,
    target_ess: float = 1000.0,
    max_steps: int = 20_000,
    min_steps: int = 300,
    n_loo_draws: int = 1000,
    proposal: str = "normal",
    n_proposal: int | None = 10_000,
    n_top: int = 64,
    outdir: str | Path | None = None,
    progress: bool | None = None,
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
        The matching :class:`~bayesbeam.problem.Problem` (built from ``result``'s
        priors when omitted).
    priors : mapping, optional
        Prior overrides (name → Prior or dict) for a new fit.
    n_elements : int
        Hermite elements of the forward model.
    initial : str
        Initial-condition kind.
    nwalkers, target_ess, max_steps, min_steps : optional
        Sampler settings, see :func:`bayesbeam.fit.fit`.
    n_loo_draws : int
        Posterior draws (at most) for the pointwise log-likelihood of LOO/WAIC.
    proposal : {"normal", "t", "warp3"}
        Bridge-sampling proposal (:func:`bayesbeam.evidence.bridge_sampling`).
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

    Returns
    -------
    ModelScore

    Raises
    ------
    CompareError
        If ``result``/``problem`` do not match ``model`` or each other.
    """
    t_start = time.perf_counter()
    model = parse_model(model)
    if result is not None and parse_model(result.model).name != model.name:
        raise CompareError(f"result is a fit of {result.model!r}, not of {model.name!r}")
    if problem is None:
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
            result = fit(
                trial, model, seed=seed, problem=problem, n_elements=problem.n_elements,
                initial=problem.initial, nwalkers=nwalkers, target_ess=target_ess,
                max_steps=max_steps, min_steps=min_steps, outdir=outdir, progress=progress,
            )
            extra_calls = 0
        else:
            fit_seconds = float(result.settings.get("total_seconds", 0.0))
            extra_calls = int(result.chain.n_calls)
        chain = result.chain
        # Evidence: bridge sampling on the emcee output; Laplace as a cross-check.
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xB51D6E]))
        n_bridge = (chain.nsteps - chain.nsteps // 2) * chain.nwalkers
        n2 = n_bridge if n_proposal is None else max(2, min(int(n_proposal), n_bridge))
        try:
            ev = bridge_sampling(chain.samples, problem.log_prob, chain.log_prob, rng=rng,
                                 proposal=proposal, n_proposal=n2)
        except EvidenceError as err:
            notes.append(f"bridge sampling failed: {err}")
            ev = Evidence(math.nan, math.nan, f"bridge-{proposal}", 0, converged=False)
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
        try:
            laplace = laplace_evidence(problem.log_prob, u_lap).log_z
        except EvidenceError as err:  # includes HessianNotNegativeDefiniteError
            notes.append(f"Laplace evidence not available: {err}")
        # Pointwise log-likelihood at thinned draws (walkers as chains for ArviZ).
        thin = thin_result(result, n_loo_draws).chain.samples
        n_s, n_w, d = thin.shape
        ll_flat = _pointwise(problem, thin.reshape(-1, d))
        loglik = np.swapaxes(ll_flat.reshape(n_s, n_w, -1), 0, 1)
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
    cands = [ll_flat.sum(axis=1)]
    top = np.argsort(chain.flat_log_prob)[::-1][: max(0, int(n_top))]
    pts = chain.flat_samples[top]
    if result.map_u is not None:
        pts = np.vstack([np.asarray(result.map_u)[None], pts])
    if pts.size:
        cands.append(problem.log_likelihood(pts))
    max_ll = float(np.max(np.concatenate(cands)))
    k = problem.ndim
    n = int(problem.data.size)
    n_calls = problem.n_calls - calls0 + extra_calls + ll_flat.shape[0]
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
        result=result,
        loglik=loglik,
        notes=tuple(notes),
    )


# --------------------------------------------------------------------------- priors


@dataclass(frozen=True)
class PriorReweight:
    """Change of the log evidence under a changed prior, by importance reweighting.

    Attributes
    ----------
    log_ratio : float
        ``log Z' - log Z`` in nats (NaN when ``status == "unavailable"``).
    err : float
        Monte-Carlo standard error of ``log_ratio`` (nats), with the walkers'
        autocorrelation (multi-chain ESS of the weights).
    status : str
        ``"ok"``; ``"lower bound"`` (a widened prior whose old bound the posterior
        reaches: the new region is unsampled, so ``log_ratio`` underestimates); or
        ``"unavailable"`` (too few samples inside the new prior).
    fraction_inside : float
        Fraction of posterior samples inside the new prior's support.
    n_eff : float
        Effective number of samples carrying the weights (Kish size times the
        autocorrelation factor ESS/N).
    note : str
        Explanation when ``status`` is not ``"ok"``.
    """

    log_ratio: float
    err: float
    status: str
    fraction_inside: float
    n_eff: float
    note: str = ""


def prior_reweight(
    samples: np.ndarray,
    priors: PriorSet,
    new_priors: PriorSet,
    *,
    min_effective: float = MIN_EFFECTIVE_INSIDE,
) -> PriorReweight:
    """Log evidence ratio ``log Z'/Z`` for a changed prior from existing posterior samples.

    ``Z'/Z = E_post[p'(θ)/p(θ)]`` (importance sampling with the posterior as
    proposal), averaged over the samples; the densities are taken in physical units
    (:meth:`bayesbeam.priors.Prior.log_pdf`) so that priors with parameter-dependent
    transforms (logit) are handled too. Valid where the posterior samples cover the
    support of ``p'`` weighted by the likelihood: see :class:`PriorReweight` for the
    two failure modes that are detected and reported.

    Parameters
    ----------
    samples : ndarray, shape (n_steps, n_walkers, ndim)
        Posterior samples in the sampling space of ``priors`` (burn-in removed).
    priors : PriorSet
        Priors the samples were drawn under.
    new_priors : PriorSet
        Changed priors, same names in the same order.
    min_effective : float
        Smallest effective number of samples inside the new prior for which a
        number is returned.

    Returns
    -------
    PriorReweight
    """
    s = np.asarray(samples, dtype=float)
    if s.ndim != 3 or s.shape[2] != priors.ndim:
        raise CompareError(
            f"samples must have shape (n_steps, n_walkers, {priors.ndim}), got {s.shape}"
        )
    if tuple(new_priors.names) != tuple(priors.names):
        raise CompareError(
            f"new priors {list(new_priors.names)} must have the same names in the same order "
            f"as {list(priors.names)}"
        )
    n_steps, n_walkers, _ = s.shape
    X = priors.to_theta(s)
    logw = np.zeros((n_steps, n_walkers))
    edge_hits: list[str] = []
    for j, name in enumerate(priors.names):
        old, new = priors[name], new_priors[name]
        if old == new:
            continue
        x = X[..., j]
        with np.errstate(invalid="ignore"):  # -inf - finite only; no inf - inf inside p
            logw = logw + new.log_pdf(x) - old.log_pdf(x)
        # Widened beyond an old finite bound: is that bound reached by the posterior?
        (olo, ohi), (nlo, nhi) = old.bounds, new.bounds
        ulo, uhi = old.bounds_u
        if math.isfinite(ulo) and math.isfinite(uhi):
            band = EDGE_BAND * (uhi - ulo)
            u = s[..., j]
            if nlo < olo and np.mean(u < ulo + band) > EDGE_FRACTION:
                edge_hits.append(f"{name} (lower)")
            if nhi > ohi and np.mean(u > uhi - band) > EDGE_FRACTION:
                edge_hits.append(f"{name} (upper)")
    logw = np.where(np.isnan(logw), -np.inf, logw)
    inside = np.isfinite(logw)
    frac = float(np.mean(inside))
    if not np.any(inside):
        return PriorReweight(
            math.nan, math.nan, "unavailable", 0.0, 0.0,
            "no posterior sample lies inside the changed prior; refit with it",
        )
    shift = float(np.max(logw[inside]))
    w = np.exp(logw - shift)  # zeros outside the new support
    mean_w = float(np.mean(w))
    n_tot = w.size
    if frac == 1.0 and float(np.ptp(logw)) < 1e-9:
        # Constant ratio (e.g. a uniform prior rescaled around the whole posterior): the
        # average is exact; only rounding of log p (~1e-15 |u|) varies between samples.
        ess = kish = float(n_tot)
        var_w = 0.0
    else:
        ess = min(float(n_tot), effective_sample_size(w)) if n_steps >= 8 else float(n_tot)
        kish = float(np.sum(w) ** 2 / np.sum(w * w))
        var_w = float(np.var(w, ddof=1)) if n_tot > 1 else 0.0
    n_eff = kish * ess / n_tot
    if n_eff < min_effective:
        return PriorReweight(
            math.nan, math.nan, "unavailable", frac, n_eff,
            f"only {n_eff:.0f} effective posterior samples ({100 * frac:.1f} %) lie inside the "
            f"changed prior (< {min_effective:.0f}); reweighting would be unreliable, refit "
            "with that prior",
        )
    err = math.sqrt(var_w / (ess * mean_w**2))  # delta method: sd(log mean) = sd(mean)/mean
    log_ratio = math.log(mean_w) + shift
    if edge_hits:
        return PriorReweight(
            log_ratio, err, "lower bound", frac, n_eff,
            "the posterior reaches the old prior bound of " + ", ".join(edge_hits)
            + "; the widened region is unsampled, so the change is a lower bound",
        )
    return PriorReweight(log_ratio, err, "ok", frac, n_eff)


def prior_sensitivity(
    result: FitResult,
    names: Sequence[str] | None = None,
    factors: Sequence[float] = (0.5, 2.0),
) -> dict[float, PriorReweight]:
    """Log evidence change of one fit when the chosen priors are scaled in width.

    Parameters
    ----------
    result : FitResult
        Posterior samples and the priors they were drawn under.
    names : sequence of str, optional
        Parameters whose priors are scaled together (default: all).
    factors : sequence of float
        Width multipliers (:meth:`bayesbeam.priors.PriorSet.scaled`).

    Returns
    -------
    dict
        ``{factor: PriorReweight}``.
    """
    out = {}
    for f in factors:
        new = result.priors.scaled(float(f), names)
        out[float(f)] = prior_reweight(result.chain.samples, result.priors, new)
    return out


# --------------------------------------------------------------------------- ranking


def _tie_band(err_a: float, err_b: float, threshold: float) -> float:
    """Largest |Δ log Z| counted as a tie: max(2 sqrt(err_a² + err_b²), threshold)."""
    comb = 2.0 * math.hypot(err_a, err_b) if math.isfinite(err_a + err_b) else math.inf
    return max(comb, threshold)


def _rank(
    log_z: np.ndarray, err: np.ndarray, threshold: float, names: Sequence[str]
) -> tuple[str | None, tuple[str, ...], np.ndarray, np.ndarray]:
    """Best model, models tied with it (best first), Δ to best and its combined error."""
    ok = np.isfinite(log_z)
    delta = np.full(log_z.shape, math.nan)
    derr = np.full(log_z.shape, math.nan)
    if not np.any(ok):
        return None, (), delta, derr
    ib = int(np.nanargmax(np.where(ok, log_z, -np.inf)))
    e = np.where(np.isfinite(err), err, math.inf)
    delta[ok] = log_z[ok] - log_z[ib]
    derr[ok] = np.where(np.arange(log_z.size)[ok] == ib, 0.0, np.hypot(e[ok], e[ib]))
    tied = [names[ib]] + [
        names[i] for i in np.argsort(-np.where(ok, log_z, -np.inf))
        if ok[i] and i != ib and abs(delta[i]) <= _tie_band(e[i], e[ib], threshold)
    ]
    return names[ib], tuple(tied), delta, derr


def _probabilities(
    log_z: np.ndarray, err: np.ndarray, prior: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Posterior model probabilities and their first-order (delta-method) errors.

    ``P_k = π_k Z_k / Σ_j π_j Z_j``; ``∂P_k/∂log Z_j = P_k (δ_kj - P_j)``, so
    ``sd(P_k)² = Σ_j P_k² (δ_kj - P_j)² err_j²`` with independent evidence errors.
    """
    p = np.full(log_z.shape, math.nan)
    sd = np.full(log_z.shape, math.nan)
    ok = np.isfinite(log_z) & (prior > 0)
    if not np.any(ok):
        return p, sd
    a = log_z[ok] + np.log(prior[ok])
    pk = np.exp(a - logsumexp(a))
    e = np.where(np.isfinite(err[ok]), err[ok], 0.0)
    jac = pk[:, None] * (np.eye(pk.size) - pk[None, :])
    p[ok] = pk
    sd[ok] = np.sqrt((jac**2) @ (e**2))
    p[np.isfinite(log_z) & (prior == 0)] = 0.0
    return p, sd


def _kass_raftery(log_b: float) -> str:
    """Verbal scale of Kass & Raftery (1995, §3.2) for a Bayes factor ``exp(log_b)``."""
    two = 2.0 * log_b
    if two < 2:
        return "not worth more than a bare mention"
    if two < 6:
        return "positive"
    if two < 10:
        return "strong"
    return "very strong"


@dataclass(frozen=True)
class SensitivityRow:
    """The comparison under one change of prior widths.

    Attributes
    ----------
    parameters : tuple of str
        Parameters whose priors were scaled (in every model that has them).
    factor : float
        Width multiplier (0.5 halves, 2 doubles).
    log_evidence, log_evidence_err : tuple of float
        Per model (in the comparison's order), nats; NaN where unavailable.
    status : tuple of str
        Per model: ``"unchanged"`` (none of its priors scaled) or the
        :class:`PriorReweight` status.
    delta : tuple of float
        ``log Z' - max log Z'`` per model, nats.
    best : str or None
        Best model under the changed priors.
    indistinguishable : tuple of str
        Models tied with that best (same rule as the baseline).
    verdict_changed : bool
        Whether the ranking flips: the best model under the changed priors was not
        tied for best before, or the baseline's best is no longer tied for best
        (a tie that merely resolves, or a new tie with the baseline best, is not a
        change).
    notes : tuple of str
    """

    parameters: tuple[str, ...]
    factor: float
    log_evidence: tuple[float, ...]
    log_evidence_err: tuple[float, ...]
    status: tuple[str, ...]
    delta: tuple[float, ...]
    best: str | None
    indistinguishable: tuple[str, ...]
    verdict_changed: bool
    notes: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        """Short description, e.g. ``"c_d,b x0.5"``."""
        return f"{','.join(self.parameters)} x{self.factor:g}"

    def to_dict(self, names: Sequence[str]) -> dict[str, Any]:
        """Strict-JSON dictionary.

        Parameters
        ----------
        names : sequence of str
            Model names in the comparison's order.

        Returns
        -------
        dict
        """
        return _finite_or_none(
            {
                "parameters": list(self.parameters),
                "factor": self.factor,
                "models": [
                    {"name": n, "log_evidence": z, "log_evidence_err": e, "status": s,
                     "delta_log_evidence": dl}
                    for n, z, e, s, dl in zip(names, self.log_evidence, self.log_evidence_err,
                                              self.status, self.delta, strict=True)
                ],
                "best": self.best,
                "indistinguishable": list(self.indistinguishable),
                "verdict_changed": self.verdict_changed,
                "notes": list(self.notes),
            }
        )


def _sensitivity(
    scores: Sequence[ModelScore], factors: Sequence[float], threshold: float,
    base_tied: tuple[str, ...],
) -> tuple[SensitivityRow, ...]:
    names = [s.name for s in scores]
    sets = [set(s.result.priors.names) for s in scores]
    shared = set.intersection(*sets) if sets else set()
    ordered: list[str] = []
    for s in scores:
        ordered += [n for n in s.result.priors.names if n not in shared and n not in ordered]
    if not ordered:
        return ()
    groups = [tuple(ordered)] + ([(n,) for n in ordered] if len(ordered) > 1 else [])
    rows = []
    for f in factors:
        for group in groups:
            lz, le, st, notes = [], [], [], []
            for s in scores:
                mine = [n for n in group if n in s.result.priors.names]
                if not mine:
                    lz.append(s.log_evidence)
                    le.append(s.log_evidence_err)
                    st.append("unchanged")
                    continue
                rw = prior_sensitivity(s.result, mine, (f,))[float(f)]
                lz.append(s.log_evidence + rw.log_ratio)
                le.append(math.hypot(s.log_evidence_err, rw.err))
                st.append(rw.status)
                if rw.note:
                    notes.append(f"{s.name}: {rw.note}")
            best, tied, delta, _ = _rank(np.array(lz), np.array(le), threshold, names)
            changed = bool(base_tied) and best is not None and (
                best not in base_tied or base_tied[0] not in tied)
            rows.append(SensitivityRow(
                parameters=tuple(group), factor=float(f), log_evidence=tuple(lz),
                log_evidence_err=tuple(le), status=tuple(st),
                delta=tuple(float(x) for x in delta), best=best, indistinguishable=tied,
                verdict_changed=changed, notes=tuple(notes),
            ))
    return tuple(rows)


def _fmt(x: float, spec: str = ".2f") -> str:
    return format(x, spec) if math.isfinite(x) else "n/a"


def _pm(x: float, e: float, spec: str = ".2f") -> str:
    if not math.isfinite(x):
        return "n/a"
    return f"{format(x, spec)} ± {_fmt(e, spec)}"


@dataclass(frozen=True, eq=False)
class Comparison:
    """Ranking of several models on one trial (immutable).

    Attributes
    ----------
    scores : tuple of ModelScore
        One per model, in the order given.
    best : str or None
        Model with the largest log evidence (None if no evidence could be computed).
    indistinguishable : tuple of str
        Models whose log evidence is within ``max(2 sqrt(err_best² + err²),
        threshold)`` of the best one, the best first (module docstring).
    threshold : float
        Tie threshold in nats.
    prior_probabilities : tuple of float
        Prior model probabilities used for :attr:`probability` (normalised odds).
    delta_log_evidence, delta_err : tuple of float
        ``log Z - log Z_best`` and the combined error of that difference, nats.
    probability, probability_err : tuple of float
        Posterior model probabilities under ``prior_probabilities`` and their
        delta-method errors from the evidence errors.
    probability_equal, probability_equal_err : tuple of float
        The same under equal prior odds.
    best_elpd : str
        Model with the largest ELPD-LOO.
    delta_elpd, delta_elpd_se : tuple of float
        Paired ELPD-LOO differences to ``best_elpd`` and their standard errors
        (:func:`bayesbeam.criteria.elpd_difference`), nats.
    sensitivity : tuple of SensitivityRow
        The ranking under halved and doubled priors of the non-shared parameters.
    prior_dependent : tuple of str
        Models outside :attr:`indistinguishable` that become tied for best (or best)
        under one of those prior changes: their lower rank hinges on a prior width.
    verdict : str
        One-line summary.
    """

    scores: tuple[ModelScore, ...]
    best: str | None
    indistinguishable: tuple[str, ...]
    threshold: float
    prior_probabilities: tuple[float, ...]
    delta_log_evidence: tuple[float, ...]
    delta_err: tuple[float, ...]
    probability: tuple[float, ...]
    probability_err: tuple[float, ...]
    probability_equal: tuple[float, ...]
    probability_equal_err: tuple[float, ...]
    best_elpd: str
    delta_elpd: tuple[float, ...]
    delta_elpd_se: tuple[float, ...]
    sensitivity: tuple[SensitivityRow, ...]
    prior_dependent: tuple[str, ...]
    verdict: str

    @property
    def names(self) -> tuple[str, ...]:
        """Model names in order."""
        return tuple(s.name for s in self.scores)

    def __getitem__(self, name: str) -> ModelScore:
        for s in self.scores:
            if s.name == name:
                return s
        raise KeyError(f"no model {name!r} in this comparison; models are {list(self.names)}")

    # -- outputs ------------------------------------------------------------------------
    def _rows(self) -> list[dict[str, Any]]:
        rows = []
        for i, s in enumerate(self.scores):
            rows.append({
                "name": s.name,
                "n_params": s.n_params,
                "max_loglik": s.max_loglik,
                "log_evidence": s.log_evidence,
                "log_evidence_err": s.log_evidence_err,
                "laplace_log_evidence": s.laplace_log_z,
                "delta_log_evidence": self.delta_log_evidence[i],
                "delta_log_evidence_err": self.delta_err[i],
                "probability": self.probability[i],
                "probability_err": self.probability_err[i],
                "probability_equal_odds": self.probability_equal[i],
                "probability_equal_odds_err": self.probability_equal_err[i],
                "prior_probability": self.prior_probabilities[i],
                "elpd_loo": s.loo.elpd_loo,
                "elpd_loo_se": s.loo.se,
                "p_loo": s.loo.p_loo,
                "delta_elpd_loo": self.delta_elpd[i],
                "delta_elpd_loo_se": self.delta_elpd_se[i],
                "n_bad_pareto_k": s.loo.n_bad_k,
                "waic": s.waic.waic,
                "aic": s.aic,
                "bic": s.bic,
                "noise": s.noise,
                "n_calls": s.n_calls,
                "seconds": s.seconds,
                "converged": bool(s.result.chain.converged),
                "notes": list(s.notes),
            })
        return rows

    def to_json_dict(self) -> dict[str, Any]:
        """Strict-JSON record (non-finite numbers become ``null``).

        Returns
        -------
        dict
            ``models``: list of ``{name, n_params, log_evidence, log_evidence_err,
            elpd_loo, elpd_loo_se, waic, bic, probability, ...}`` (``probability``
            under the prior odds given, ``probability_equal_odds`` under equal odds;
            more keys are listed in :meth:`_rows`); ``best``; ``indistinguishable``
            (models tied with the best, the best included); ``threshold``;
            ``verdict``; ``best_elpd``; ``prior_dependent`` (models whose lower rank
            hinges on a prior width); ``prior_sensitivity`` (one entry per scaled
            prior group and factor).
        """
        return _finite_or_none({
            "models": self._rows(),
            "best": self.best,
            "indistinguishable": list(self.indistinguishable),
            "threshold": self.threshold,
            "tie_rule": "|dlogZ| <= max(2*sqrt(err_best^2 + err^2), threshold)",
            "verdict": self.verdict,
            "best_elpd": self.best_elpd,
            "prior_dependent": list(self.prior_dependent),
            "prior_sensitivity": [r.to_dict(self.names) for r in self.sensitivity],
        })

    def _table(self) -> tuple[list[str], list[list[str]]]:
        head = ["model", "k", "max logL", "log Z ± err", "Δ log Z", "Laplace", "P(M|D)",
                "ELPD-LOO ± se", "Δ ELPD ± se", "WAIC", "BIC"]
        body = []
        for i, s in enumerate(self.scores):
            body.append([
                s.name + (" *" if s.name in self.indistinguishable
                          else " ~" if s.name in self.prior_dependent else ""),
                str(s.n_params),
                _fmt(s.max_loglik, ".1f"),
                _pm(s.log_evidence, s.log_evidence_err),
                _pm(self.delta_log_evidence[i], self.delta_err[i]),
                _fmt(s.laplace_log_z, ".1f"),
                _pm(self.probability[i], self.probability_err[i], ".3f"),
                _pm(s.loo.elpd_loo, s.loo.se, ".1f"),
                _pm(self.delta_elpd[i], self.delta_elpd_se[i], ".1f"),
                _fmt(s.waic.waic, ".1f"),
                _fmt(s.bic, ".1f"),
            ])
        return head, body

    def _sensitivity_lines(self) -> list[str]:
        if not self.sensitivity:
            return []
        changed = [r for r in self.sensitivity if r.verdict_changed]
        lines = ["", "Prior sensitivity (non-shared priors halved/doubled in width; Δ log Z to "
                 "the best under the changed priors, nats; '≥' lower bound, 'n/a' too few "
                 "samples inside):"]
        w = max(len(r.label) for r in self.sensitivity)
        for r in self.sensitivity:
            cells = []
            for n, dl, st in zip(self.names, r.delta, r.status, strict=True):
                mark = "≥" if st == "lower bound" else ""
                cells.append(f"{n} {mark}{_fmt(dl)}")
            tie = ", ".join(r.indistinguishable)
            lines.append(f"  {r.label:<{w}}  " + "; ".join(cells) + f"  -> tied best: {tie}"
                         + ("  (VERDICT CHANGES)" if r.verdict_changed else ""))
        lines.append(
            f"  verdict changes under {len(changed)} of {len(self.sensitivity)} prior changes"
            if changed else "  verdict unchanged under every prior change"
        )
        return lines

    def __str__(self) -> str:
        head, body = self._table()
        widths = [max(len(h), *(len(r[j]) for r in body)) for j, h in enumerate(head)]
        line = "  ".join(h.ljust(widths[j]) if j == 0 else h.rjust(widths[j])
                         for j, h in enumerate(head))
        out = [line, "-" * len(line)]
        for r in body:
            out.append("  ".join(c.ljust(widths[j]) if j == 0 else c.rjust(widths[j])
                                 for j, c in enumerate(r)))
        out.append(
            f"* tied for best: |Δ log Z| <= max(2 sqrt(err_best² + err²), {self.threshold:g} nat)"
            " (Kass & Raftery 1995)" + ("; ~ tied under a halved/doubled prior width"
                                        if self.prior_dependent else "")
            + ". P(M|D) from the evidences"
            + (" and the given prior odds" if len(set(self.prior_probabilities)) > 1
               else " with equal prior odds") + "; ± from the evidence errors."
        )
        out += self._sensitivity_lines()
        notes = [f"  {s.name}: {n}" for s in self.scores for n in s.notes]
        if notes:
            out += ["", "Notes:"] + notes
        out += ["", self.verdict]
        return "\n".join(out)

    def _repr_html_(self) -> str:
        head, body = self._table()
        esc = html.escape
        rows = ["<tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>"]
        for r in body:
            rows.append("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>")
        parts = [
            '<table class="bayesbeam-comparison">',
            "<thead>" + rows[0] + "</thead>",
            "<tbody>" + "".join(rows[1:]) + "</tbody>",
            "</table>",
            f"<p><b>{esc(self.verdict)}</b></p>",
        ]
        sens = self._sensitivity_lines()
        if sens:
            parts.append("<pre>" + esc("\n".join(sens[1:])) + "</pre>")
        notes = [f"{s.name}: {n}" for s in self.scores for n in s.notes]
        if notes:
            parts.append("<ul>" + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>")
        return "\n".join(parts)

    def plot(self, path: str | Path, *, dpi: int = 120) -> Path:
        """Plot Δ log evidence (± 2 s.e.) and paired ELPD-LOO differences (± 2 s.e.).

        Axes switch to a symmetric-log scale (linear within a few nats of zero) when
        some difference is much larger than the tie band.

        Parameters
        ----------
        path : str or pathlib.Path
            Image file (format from the suffix, e.g. ``.png``).
        dpi : int

        Returns
        -------
        pathlib.Path
        """
        from matplotlib.figure import Figure

        path = Path(path)
        n = len(self.scores)
        y = np.arange(n)[::-1]
        fig = Figure(figsize=(9.0, 1.2 + 0.5 * n), layout="constrained")
        ax1, ax2 = fig.subplots(1, 2, sharey=True)
        dz = np.array(self.delta_log_evidence, dtype=float)
        ez = np.array([s.log_evidence_err for s in self.scores], dtype=float)
        ax1.axvspan(-self.threshold, 0.0, color="0.9", label=f"tie threshold ({self.threshold:g})")
        ax1.errorbar(dz, y, xerr=2 * np.nan_to_num(ez), fmt="o", color="C0", capsize=3)
        ax1.axvline(0.0, color="0.4", lw=0.8)
        # Differences of hundreds of nats beside ties of a fraction of one: symlog keeps
        # the band around zero linear and readable.
        lin1 = max(2.0, 2.0 * self.threshold)
        if np.nanmax(np.abs(dz), initial=0.0) > 10 * lin1:
            ax1.set_xscale("symlog", linthresh=lin1)
        ax1.set_xlabel("log Z - log Z_best [nats]  (± 2 s.e.)")
        ax1.set_title("evidence")
        ax1.legend(loc="lower left", fontsize="small")
        de = np.array(self.delta_elpd, dtype=float)
        se = np.array(self.delta_elpd_se, dtype=float)
        ax2.errorbar(de, y, xerr=2 * np.nan_to_num(se), fmt="s", color="C1", capsize=3)
        ax2.axvline(0.0, color="0.4", lw=0.8)
        lin2 = max(2.0, 2.0 * float(np.nanmedian(se))) if se.size else 2.0
        if np.nanmax(np.abs(de), initial=0.0) > 10 * lin2:
            ax2.set_xscale("symlog", linthresh=lin2)
        ax2.set_xlabel(f"ELPD-LOO - ELPD({self.best_elpd}) [nats]  (± 2 s.e.)")
        ax2.set_title("PSIS-LOO")
        for ax in (ax1, ax2):
            ax.margins(x=0.08)
        ax1.set_yticks(y, list(self.names))
        fig.savefig(path, dpi=dpi)
        return path

    def save(self, outdir: str | Path, *, fits: bool = True) -> dict[str, Path]:
        """Write ``comparison.{json,txt,html,png}`` and each model's fit.

        Parameters
        ----------
        outdir : str or pathlib.Path
            Created if missing; existing files are replaced.
        fits : bool
            Also save each FitResult into ``outdir/<model>/`` (``posterior.nc``,
            ``summary.json``).

        Returns
        -------
        dict
            ``json``, ``txt``, ``html``, ``png`` and ``fit:<model>`` paths.
        """
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        paths = {
            "json": outdir / "comparison.json",
            "txt": outdir / "comparison.txt",
            "html": outdir / "comparison.html",
            "png": outdir / "comparison.png",
        }
        paths["json"].write_text(
            json.dumps(self.to_json_dict(), indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        paths["txt"].write_text(str(self) + "\n", encoding="utf-8")
        paths["html"].write_text(
            "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>bayesbeam model "
            "comparison</title></head><body>\n" + self._repr_html_() + "\n</body></html>\n",
            encoding="utf-8",
        )
        self.plot(paths["png"])
        if fits:
            for s in self.scores:
                saved = s.result.save(outdir / s.name)
                paths[f"fit:{s.name}"] = saved["summary"].parent
        return paths


def _prior_probabilities(prior_odds: Any, names: Sequence[str]) -> np.ndarray:
    if prior_odds is None:
        return np.full(len(names), 1.0 / len(names))
    if isinstance(prior_odds, Mapping):
        unknown = sorted(set(prior_odds) - set(names))
        if unknown:
            raise CompareError(f"prior odds given for {unknown}, not among the models {names}")
        odds = np.array([float(prior_odds.get(n, 1.0)) for n in names])
    else:
        odds = np.asarray(prior_odds, dtype=float).reshape(-1)
        if odds.size != len(names):
            raise CompareError(
                f"{odds.size} prior odds for {len(names)} models; give one per model or a "
                "mapping name -> odds"
            )
    if not (np.all(np.isfinite(odds)) and np.all(odds >= 0) and odds.sum() > 0):
        raise CompareError(f"prior odds must be non-negative numbers, not all zero; got {odds}")
    return odds / odds.sum()


def compare_scores(
    scores: Sequence[ModelScore],
    *,
    prior_odds: Mapping[str, float] | Sequence[float] | None = None,
    threshold: float | None = None,
    sensitivity_factors: Sequence[float] = (0.5, 2.0),
) -> Comparison:
    """Rank already evaluated models (see :func:`compare` for the rules).

    Parameters
    ----------
    scores : sequence of ModelScore
        From :func:`evaluate`, all on the same trial.
    prior_odds : mapping or sequence, optional
        Prior odds per model (relative, normalised here); default equal.
    threshold : float, optional
        Tie threshold on |Δ log Z| in nats (default :data:`DEFAULT_THRESHOLD`).
    sensitivity_factors : sequence of float
        Prior width multipliers for the sensitivity analysis (empty to skip).

    Returns
    -------
    Comparison
    """
    scores = tuple(scores)
    if not scores:
        raise CompareError("no models to compare")
    names = [s.name for s in scores]
    if len(set(names)) != len(names):
        raise CompareError(f"duplicate models in {names}")
    n_data = {s.n_data for s in scores}
    if len(n_data) != 1:
        raise CompareError("all models must be evaluated on the same trial (sample counts differ)")
    thr = DEFAULT_THRESHOLD if threshold is None else float(threshold)
    if not (math.isfinite(thr) and thr >= 0):
        raise CompareError(f"threshold must be a non-negative number of nats, got {threshold}")
    prior = _prior_probabilities(prior_odds, names)
    lz = np.array([s.log_evidence for s in scores])
    le = np.array([s.log_evidence_err for s in scores])
    best, tied, delta, derr = _rank(lz, le, thr, names)
    p, p_sd = _probabilities(lz, le, prior)
    p0, p0_sd = _probabilities(lz, le, np.full(len(names), 1.0 / len(names)))
    # Paired ELPD differences to the model with the largest ELPD-LOO.
    ib = int(np.argmax([s.loo.elpd_loo for s in scores]))
    d_elpd, d_se = [], []
    for s in scores:
        d, se = elpd_difference(s.loo, scores[ib].loo)
        d_elpd.append(d)
        d_se.append(se)
    sens = _sensitivity(scores, sensitivity_factors, thr, tied)
    dependent: list[str] = []
    for r in sens:
        dependent += [n for n in r.indistinguishable if n not in tied and n not in dependent]
    verdict = _verdict(names, lz, best, tied, delta, derr, dependent, scores)
    return Comparison(
        scores=scores, best=best, indistinguishable=tied, threshold=thr,
        prior_probabilities=tuple(map(float, prior)),
        delta_log_evidence=tuple(map(float, delta)), delta_err=tuple(map(float, derr)),
        probability=tuple(map(float, p)), probability_err=tuple(map(float, p_sd)),
        probability_equal=tuple(map(float, p0)), probability_equal_err=tuple(map(float, p0_sd)),
        best_elpd=names[ib], delta_elpd=tuple(d_elpd), delta_elpd_se=tuple(d_se),
        sensitivity=sens, prior_dependent=tuple(dependent), verdict=verdict,
    )


def _verdict(
    names: Sequence[str], lz: np.ndarray, best: str | None, tied: tuple[str, ...],
    delta: np.ndarray, derr: np.ndarray, dependent: Sequence[str],
    scores: Sequence[ModelScore],
) -> str:
    if best is None:
        return "Verdict: no evidence could be computed; no ranking (see the notes)."
    unranked = [n for n, z in zip(names, lz, strict=True) if not math.isfinite(z)]
    tail = f" Not ranked (evidence failed): {', '.join(unranked)}." if unranked else ""
    if dependent:
        tail += (f" Prior-dependent: {', '.join(dependent)} would tie for best under a "
                 "halved or doubled prior width (see prior sensitivity).")
    if any(not s.result.chain.converged for s in scores):
        tail += " Some chains did not converge (see notes)."
    if len(names) == 1:
        return f"Verdict: only one model ({best}); nothing to compare.{tail}"
    others = [i for i, n in enumerate(names) if n not in tied and math.isfinite(lz[i])]
    if len(tied) > 1:
        rest = (f"; {', '.join(names[i] for i in others)} less supported"
                if others else "")
        return (f"Verdict: the data cannot distinguish {', '.join(tied)} (|Δ log Z| within "
                f"the tie band){rest}.{tail}")
    i2 = max(others, key=lambda i: lz[i])
    gap = -float(delta[i2])
    return (f"Verdict: {best} is favoured over {names[i2]} by Δ log Z = {gap:.2f} ± "
            f"{derr[i2]:.2f} nats ({_kass_raftery(gap)}, Kass & Raftery 1995).{tail}")


def compare(
    trial: Trial,
    models: Sequence[str | Model],
    *,
    seed: int = 0,
    prior_odds: Mapping[str, float] | Sequence[float] | None = None,
    threshold: float | None = None,
    priors: Mapping[str, Mapping[str, Any]] | None = None,
    n_elements: int = 16,
    initial: str = "release",
    nwalkers: int | None = None,
    target_ess: float = 1000.0,
    max_steps: int = 20_000,
    min_steps: int = 300,
    n_loo_draws: int = 1000,
    proposal: str = "normal",
    n_proposal: int | None = 10_000,
    sensitivity_factors: Sequence[float] = (0.5, 2.0),
    outdir: str | Path | None = None,
    progress: bool | None = None,
) -> Comparison:
    """Fit and compare several models on one trial.

    Each model is fitted and scored by :func:`evaluate` (same ``seed``), then ranked
    by log evidence. Models tied with the best (|Δ log Z| within
    ``max(2 sqrt(err_a² + err_b²), threshold)``) are listed in
    ``indistinguishable`` and the verdict says so; posterior model probabilities
    carry the evidence errors; ELPD-LOO differences are paired; the prior widths of
    the non-shared parameters are halved and doubled to show whether the ranking
    hinges on them (module docstring).

    Parameters
    ----------
    trial : Trial
    models : sequence of str or Model
        e.g. ``["viscous", "viscous+kv", "viscous+sh"]``.
    seed : int
        Seed of every fit and evidence estimate.
    prior_odds : mapping or sequence, optional
        Prior odds of the models (default equal).
    threshold : float, optional
        Tie threshold in nats (default 1, Kass & Raftery 1995).
    priors : mapping, optional
        Per-model prior overrides ``{model name: {parameter: Prior or dict}}``.
    n_elements, initial, nwalkers, target_ess, max_steps, min_steps : optional
        Forward-model and sampler settings (:func:`bayesbeam.fit.fit`).
    n_loo_draws : int
        Draws for the pointwise log-likelihood.
    proposal : str
        Bridge-sampling proposal.
    n_proposal : int or None
        Bridge proposal draws per model (see :func:`evaluate`).
    sensitivity_factors : sequence of float
        Prior width multipliers for the sensitivity analysis (empty to skip).
    outdir : path, optional
        Fits keep their checkpoints in ``outdir/<model>/`` (use
        :meth:`Comparison.save` to write the results).
    progress : bool or None
        Sampler progress lines.

    Returns
    -------
    Comparison
    """
    parsed = [parse_model(m) for m in models]
    if not parsed:
        raise CompareError("give at least one model, e.g. ['viscous', 'viscous+kv']")
    names = [m.name for m in parsed]
    if len(set(names)) != len(names):
        raise CompareError(f"duplicate models in {names}")
    priors = dict(priors or {})
    unknown = sorted(set(priors) - set(names))
    if unknown:
        raise CompareError(f"prior overrides for {unknown}, which are not among {names}")
    scores = [
        evaluate(
            trial, m, seed=seed, priors=priors.get(m.name), n_elements=n_elements,
            initial=initial, nwalkers=nwalkers, target_ess=target_ess, max_steps=max_steps,
            min_steps=min_steps, n_loo_draws=n_loo_draws, proposal=proposal,
            n_proposal=n_proposal, progress=progress,
            outdir=None if outdir is None else Path(outdir) / m.name,
        )
        for m in parsed
    ]
    return compare_scores(scores, prior_odds=prior_odds, threshold=threshold,
                          sensitivity_factors=sensitivity_factors)

