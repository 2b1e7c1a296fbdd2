"""Evidence and LOO of joint fits, and which parameters the data say the trials share.

A question such as "is E the same in all five releases?" or "does the damping vary
from release to release?" is a comparison of joint models that differ only in what
they share (:class:`~bayesbeam.inference.joint.JointProblem`): ``shared=("E",)`` against
every trial with its own E (``shared=()``), pooled damping against separate damping.
:func:`score_joint` gives one joint fit its bridge-sampling evidence
(:func:`bayesbeam.stats.evidence.bridge_sampling` on the joint log posterior; with sigma
and the amplitudes marginalised, the integral is the same as with them sampled) and its
PSIS-LOO over all trials' samples (pointwise terms of completed draws,
:meth:`~bayesbeam.inference.joint.JointProblem.log_likelihood_pointwise`).
:func:`compare_joint` fits the variants and ranks them with the package's tie rule
(:mod:`bayesbeam.stats.ranking`): a difference is reported as decided only when it is
larger than twice its combined standard error and the threshold.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from bayesbeam._util import SCHEMA_VERSION, finite_json, job_guard
from bayesbeam.inference.joint_fit import MAX_DRAWS, JointFit, fit_joint
from bayesbeam.stats.criteria import LOO, ParetoKWarning, loo
from bayesbeam.stats.evidence import Evidence, EvidenceError, bridge_sampling
from bayesbeam.stats.ranking import DEFAULT_THRESHOLD, _rank
from bayesbeam.trials.trial import Trial

__all__ = [
    "JointComparison", "JointScore", "compare_joint", "rank_scores", "score_joint", "variant_name",
]


def variant_name(model: str, shared: Iterable[str], pooled: Iterable[str]) -> str:
    """Readable name of a joint variant, e.g. ``"viscous+kv | shared E | pooled c_d"``."""
    shared, pooled = list(shared), list(pooled)
    parts = [model, "shared " + ",".join(shared) if shared else "nothing shared"]
    if pooled:
        parts.append("pooled " + ",".join(pooled))
    return " | ".join(parts)


@dataclasses.dataclass(frozen=True)
class JointScore:
    """Evidence and LOO of one joint fit (immutable).

    Attributes
    ----------
    name : str
        :func:`variant_name`.
    evidence : Evidence
        Bridge-sampling log evidence (nats) ± its standard error; NaN when it failed.
    loo : LOO or None
        PSIS-LOO over the samples of all trials (nats); None when it failed.
    n_params : int
        Sampled parameters.
    fit : JointFit
    notes : tuple of str
        Reliability messages (not converged, Pareto k, a failed estimator, a trial the
        model does not reproduce).
    """

    name: str
    evidence: Evidence
    loo: LOO | None
    n_params: int
    fit: JointFit = dataclasses.field(repr=False)
    notes: tuple[str, ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        """Record of ``comparison.json`` rows: name, evidence, LOO, notes, joint spec."""
        pb = self.fit.problem
        return finite_json({
            "name": self.name, "model": pb.model.name, "shared": list(pb.shared),
            "pooled": list(pb.pooled), "n_params": self.n_params,
            "log_z": self.evidence.log_z, "log_z_err": self.evidence.log_z_err,
            "evidence": self.evidence.to_dict(),
            "elpd_loo": None if self.loo is None else self.loo.elpd_loo,
            "elpd_loo_se": None if self.loo is None else self.loo.se,
            "pareto_k_max": None if self.loo is None else float(np.nanmax(self.loo.pareto_k)),
            "converged": bool(self.fit.result.chain.converged),
            "ess_min": self.fit.result.chain.ess_min,
            "adequate": self.fit.ok, "notes": list(self.notes),
        })


def score_joint(fit: JointFit, *, seed: int = 0, n_proposal: int | None = 10_000) -> JointScore:
    """Bridge-sampling evidence and PSIS-LOO of a joint fit.

    Parameters
    ----------
    fit : JointFit
    seed : int
        Seed of the bridge proposal draws and the marginalised parameters' draws.
    n_proposal : int or None
        Proposal draws of the bridge (:func:`bridge_sampling`).

    Returns
    -------
    JointScore
    """
    pb, res = fit.problem, fit.result
    notes: list[str] = []
    if not res.chain.converged:
        notes.append("sampler NOT converged: the evidence and LOO rest on an unconverged chain")
    try:
        ev = bridge_sampling(res.chain.samples, pb.log_prob, res.chain.log_prob,
                             rng=np.random.default_rng([seed, 4]), n_proposal=n_proposal)
    except EvidenceError as exc:
        ev = Evidence(math.nan, math.nan, "bridge-normal", 0, converged=False)
        notes.append(f"bridge sampling failed: {exc}")
    thin = res.thin(MAX_DRAWS).chain
    ll = pb.log_likelihood_pointwise(thin.samples.reshape(-1, thin.ndim),
                                     np.random.default_rng([seed, 5]))
    ll = np.swapaxes(ll.reshape(thin.nsteps, thin.nwalkers, -1), 0, 1)
    lo_: LOO | None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ParetoKWarning)
        try:
            lo_ = loo(ll)
        except ValueError as exc:
            lo_ = None
            notes.append(f"PSIS-LOO failed: {exc}")
    notes += [str(w.message) for w in caught if issubclass(w.category, ParetoKWarning)]
    bad = [lb for lb, v in zip(fit.labels, fit.trials, strict=True) if not v.adequacy.get("ok")]
    if bad:
        notes.append(f"the model does not reproduce {bad} to their noise")
    return JointScore(name=variant_name(pb.model.name, pb.shared, pb.pooled), evidence=ev,
                      loo=lo_, n_params=pb.ndim, fit=fit, notes=tuple(notes))


@dataclasses.dataclass(frozen=True)
class JointComparison:
    """Joint variants of one model on one set of trials, ranked by evidence (immutable).

    Attributes
    ----------
    scores : tuple of JointScore
        In the order given.
    best : str or None
        Highest evidence.
    tied : tuple of str
        Variants whose evidence is within the tie band of the best (best first):
        ``max(2 sqrt(err_best² + err²), threshold)``.
    delta_log_z, delta_log_z_err : dict of str to float
        Log evidence minus the best's, and its combined standard error (nats).
    threshold : float
        Tie threshold (nats).
    """

    scores: tuple[JointScore, ...]
    best: str | None
    tied: tuple[str, ...]
    delta_log_z: dict[str, float]
    delta_log_z_err: dict[str, float]
    threshold: float

    @property
    def decided(self) -> bool:
        """True when the best variant is not tied with any other."""
        return self.best is not None and len(self.tied) == 1

    def verdict(self) -> str:
        """One line: which variant the evidence prefers, or that it cannot tell."""
        if self.best is None:
            return "no variant has a finite evidence"
        if not self.decided:
            return (f"undecided: {', '.join(self.tied)} are within the evidence's error "
                    f"(tie band: 2 combined sd or {self.threshold:g} nats)")
        others = [s.name for s in self.scores if s.name != self.best]
        gaps = ", ".join(f"{n}: Δ log Z = {self.delta_log_z[n]:+.2f} ± "
                         f"{self.delta_log_z_err[n]:.2f}" for n in others)
        return f"the evidence prefers {self.best} ({gaps})"

    def to_json_dict(self) -> dict[str, Any]:
        """Strict-JSON record (``comparison.json`` of ``bayesbeam compare`` on several trials)."""
        return finite_json({
            "schema_version": SCHEMA_VERSION,
            "variants": [s.to_json_dict() for s in self.scores],
            "best": self.best, "tied": list(self.tied), "decided": self.decided,
            "delta_log_z": self.delta_log_z, "delta_log_z_err": self.delta_log_z_err,
            "threshold": self.threshold, "verdict": self.verdict(),
        })

    def table(self) -> str:
        """Plain-text table: variant, parameters, log Z ± err, Δ, ELPD ± se, notes."""
        w = max(8, *(len(s.name) for s in self.scores))
        lines = [f"{'variant':<{w}} {'k':>4} {'log Z':>12} {'± err':>7} {'Δ log Z':>9} "
                 f"{'elpd_loo':>12} {'± se':>7}  notes"]
        for s in self.scores:
            e = s.evidence
            el = (f"{s.loo.elpd_loo:>12.2f} {s.loo.se:>7.2f}" if s.loo is not None
                  else f"{'-':>12} {'-':>7}")
            notes = f"  {len(s.notes)} note(s)" if s.notes else ""
            lines.append(f"{s.name:<{w}} {s.n_params:>4} {e.log_z:>12.2f} {e.log_z_err:>7.2f} "
                         f"{self.delta_log_z.get(s.name, math.nan):>+9.2f} {el}{notes}")
        lines.append(self.verdict())
        return "\n".join(lines)


def rank_scores(scores: Sequence[JointScore], threshold: float = DEFAULT_THRESHOLD
                ) -> JointComparison:
    """Rank scored variants by log evidence with the package's tie rule.

    Parameters
    ----------
    scores : sequence of JointScore
    threshold : float
        Smallest |Δ log Z| (nats) that can decide (besides twice the combined error).

    Returns
    -------
    JointComparison
    """
    names = [s.name for s in scores]
    if len(set(names)) != len(names):
        raise ValueError(f"variants must differ; got {names}")
    log_z = np.array([s.evidence.log_z for s in scores])
    err = np.array([s.evidence.log_z_err for s in scores])
    best, tied, delta, derr = _rank(log_z, err, threshold, names)
    return JointComparison(
        scores=tuple(scores), best=best, tied=tied,
        delta_log_z={n: float(d) for n, d in zip(names, delta, strict=True)},
        delta_log_z_err={n: float(d) for n, d in zip(names, derr, strict=True)},
        threshold=float(threshold),
    )


def compare_joint(
    trials: Sequence[Trial],
    model: str,
    variants: Sequence[tuple[Iterable[str], Iterable[str]]],
    *,
    seed: int = 0,
    threshold: float = DEFAULT_THRESHOLD,
    executor: Any = None,
    **fit_kw: Any,
) -> JointComparison:
    """Fit and score joint variants of one model, then rank them.

    Parameters
    ----------
    trials : sequence of Trial
    model : str
    variants : sequence of (shared, pooled)
        e.g. ``[(("E",), ()), ((), ())]``: E shared against every trial on its own.
    seed : int
        Seed of every fit and score (the same for each variant).
    threshold : float
        Tie threshold in nats (:func:`rank_scores`).
    executor : concurrent.futures.Executor, optional
        Fits the variants in parallel (as :func:`bayesbeam.comparison.compare.compare`;
        the numbers do not depend on it); the sampler's progress lines are then off.
    **fit_kw
        Further keywords of :func:`bayesbeam.inference.joint_fit.fit_joint`.

    Returns
    -------
    JointComparison
    """
    jobs = [{"trials": list(trials), "model": model, "shared": tuple(shared),
             "pooled": tuple(pooled), "seed": int(seed),
             "fit_kw": dict(fit_kw) if executor is None else {**fit_kw, "progress": False}}
            for shared, pooled in variants]
    scores = ([_variant_job(job) for job in jobs] if executor is None
              else list(executor.map(_variant_job, jobs)))
    return rank_scores(scores, threshold)


def _variant_job(job: dict[str, Any]) -> JointScore:
    """Fit and score one variant of :func:`compare_joint` (the function an executor maps).

    Module-level and fed plain data, so that it pickles to worker processes; one job at
    a time per process with one BLAS thread (:func:`bayesbeam._util.job_guard`).
    """
    with job_guard():
        jf = fit_joint(job["trials"], job["model"], shared=job["shared"], pooled=job["pooled"],
                       seed=job["seed"], **job["fit_kw"])
        return score_joint(jf, seed=job["seed"])
