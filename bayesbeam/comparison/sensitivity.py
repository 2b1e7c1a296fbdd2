"""Prior sensitivity of the evidence: importance reweighting of existing posterior samples.

Evidences depend on the widths of the priors of the parameters that differ between
models (the Occam factor). :func:`prior_reweight` recomputes the evidence of one fit
under changed priors without refitting,

    Z'/Z = E_post[p'(θ) / p(θ)],

with its Monte-Carlo error; :func:`prior_sensitivity` does so for priors scaled in
width (:meth:`bayesbeam.stats.priors.Prior.scaled`). The estimate is exact in expectation
where the support of ``p'`` lies inside that of ``p`` (a narrowed prior) and the
posterior samples are numerous enough inside the new support; when too few are, no
number is returned. For a widened prior the region beyond the old bounds is not
sampled, so the estimate is a lower bound whenever the posterior reaches the old
bound (it is then flagged), and exact otherwise.

For a comparison, the priors of the non-shared parameters are halved and doubled in
width, together and one by one, and the models re-ranked under each change with the
baseline's tie rule (:mod:`bayesbeam.stats.ranking`): one :class:`SensitivityRow` per change,
which :class:`bayesbeam.comparison.compare.Comparison` reports.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayesbeam._util import finite_json
from bayesbeam.comparison.scoring import CompareError, ModelScore
from bayesbeam.inference.results import FitResult
from bayesbeam.stats.evidence import effective_sample_size
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.ranking import _rank

__all__ = ["PriorReweight", "SensitivityRow", "prior_reweight", "prior_sensitivity"]

#: Effective posterior samples that must stay inside a changed prior for a reweighted
#: evidence to be reported (relative error of the estimate about 1/sqrt(100) = 0.1).
MIN_EFFECTIVE_INSIDE = 100.0
#: Edge check for widened priors: the posterior "reaches" an old bound when more than
#: EDGE_FRACTION of the samples lie within EDGE_BAND (fraction of the u-width) of it.
EDGE_BAND = 0.02
EDGE_FRACTION = 0.01


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
    (:meth:`bayesbeam.stats.priors.Prior.log_pdf`) so that priors with parameter-dependent
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
        Width multipliers (:meth:`bayesbeam.stats.priors.PriorSet.scaled`).

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
        return finite_json(
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
