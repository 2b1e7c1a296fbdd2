"""Model comparison: evidence with error bars, information criteria, Bayes factors.

For every candidate model (damping laws and extensions, :mod:`bayesbeam.physics.models`) on
one trial, :func:`evaluate` fits the posterior (:func:`bayesbeam.inference.fit.fit`) and scores
it; :func:`compare` ranks the scores and says when the data cannot tell models apart.

The work is split by responsibility: scoring one model (:class:`ModelScore`,
:func:`evaluate`; what each criterion means for a time series) is in
:mod:`bayesbeam.comparison.scoring`; the tie rule and model probabilities in
:mod:`bayesbeam.stats.ranking`; evidence under changed priors in
:mod:`bayesbeam.comparison.sensitivity`.
This module holds the :class:`Comparison` record, how it is built and how it is
rendered (text, JSON, HTML, plot); the names of the other three are importable here too.

Parallel fits
-------------
``compare(..., executor=...)`` maps :func:`_evaluate_job` over the models with any
object that has the ``map`` of :class:`concurrent.futures.Executor` (a process pool, a
Dask client's executor; the command line makes one with
:func:`bayesbeam.jobs.executor.make_executor`, a layer above this one). Each job carries
the trial itself (its arrays and metadata, pickled), the model, the settings and the
seed; all models share the seed, as the tasks of :mod:`bayesbeam.jobs.tasks` do, so a
model's numbers depend neither on the order of the models nor on the executor. Jobs run
one at a time per process with one BLAS thread (:func:`bayesbeam._util.job_guard`), serial ones too:
a parallel comparison is bitwise the serial one. A progress bar over the models
(:func:`bayesbeam._util.progress_bar`) says which model is being fitted.

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
models (the Occam factor). Every prior of a non-shared parameter is halved and doubled
in width and the evidences are recomputed from the existing posterior samples by
importance reweighting (:func:`prior_reweight`; when it is exact, a lower bound, or
unavailable is explained in :mod:`bayesbeam.comparison.sensitivity`). Models outside the tie band
that tie with (or beat) the best one under such a change are listed in
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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import (
    SCHEMA_VERSION,
    atomic_path,
    finite_json,
    job_guard,
    progress_bar,
    progress_note,
    stderr_is_live,
    write_text_atomic,
)
from bayesbeam.comparison.scoring import CompareError, ModelScore, evaluate
from bayesbeam.comparison.sensitivity import (
    SensitivityRow,
    _sensitivity,
)
from bayesbeam.inference.settings import fit_settings
from bayesbeam.physics.models import Model, parse_model
from bayesbeam.stats.criteria import elpd_difference
from bayesbeam.stats.ranking import DEFAULT_THRESHOLD, _kass_raftery, _probabilities, _rank
from bayesbeam.trials.trial import Trial

# Names defined in bayesbeam.comparison.scoring, .ranking and .sensitivity are listed too: they
# have always been imported from here.
__all__ = [
    "Comparison",
    "compare",
    "compare_scores",
]


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
        (:func:`bayesbeam.stats.criteria.elpd_difference`), nats.
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
                "adequate": _adequate(s),
                "adequacy": dict(s.result.adequacy) if s.result.adequacy else None,
                "notes": list(s.notes),
            })
        return rows

    def to_json_dict(self) -> dict[str, Any]:
        """Strict-JSON record (non-finite numbers become ``null``).

        Returns
        -------
        dict
            ``schema_version``; ``models``: list of ``{name, n_params, log_evidence,
            log_evidence_err, elpd_loo, elpd_loo_se, waic, bic, probability, ...}`` (``probability``
            under the prior odds given, ``probability_equal_odds`` under equal odds;
            more keys are listed in :meth:`_rows`); ``best``; ``indistinguishable``
            (models tied with the best, the best included); ``threshold``;
            ``verdict``; ``best_elpd``; ``prior_dependent`` (models whose lower rank
            hinges on a prior width); ``prior_sensitivity`` (one entry per scaled
            prior group and factor).
        """
        return finite_json({
            "schema_version": SCHEMA_VERSION,
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
                "ELPD-LOO ± se", "Δ ELPD ± se", "WAIC", "BIC", "adequate"]
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
                {True: "yes", False: "NO", None: "n/a"}[_adequate(s)],
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
        notes += [f"  {s.name}: {s.result.adequacy['summary']}" for s in self.scores
                  if _adequate(s) is False]
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
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
        return path

    def modal_posteriors(self, trial: Trial, **kw: Any) -> dict[str, Any]:
        """Posterior of ``f_k`` and ``ζ_k`` per mode of every model (the ζ-vs-f picture).

        A :class:`ModelScore` keeps no Problem: each is rebuilt from the fit as
        :func:`evaluate` builds one from a ready result (its priors, mesh and initial
        condition), on ``trial``.

        Parameters
        ----------
        trial : Trial
            The trial the models were compared on (after any preprocessing).
        **kw
            Passed to :func:`bayesbeam.inference.modal.modal_posterior` (``n_draws``,
            ``n_modes``, ``data``).

        Returns
        -------
        dict
            ``{model: ModalPosterior}`` in the order of :attr:`scores`.

        Raises
        ------
        CompareError
            If ``trial`` has another number of samples than the compared one.
        """
        from bayesbeam.inference.modal import modal_posterior
        from bayesbeam.inference.problem import Problem
        from bayesbeam.inference.settings import FIT_DEFAULTS

        out = {}
        for s in self.scores:
            if s.n_data != trial.times.size:
                raise CompareError(
                    f"{s.name} was scored on {s.n_data} samples; the trial given has "
                    f"{trial.times.size}: pass the (preprocessed) trial of the comparison"
                )
            r = s.result
            problem = Problem(
                trial, r.model, r.priors,
                n_elements=int(r.settings.get("n_elements", FIT_DEFAULTS.n_elements)),
                initial=str(r.settings.get("initial", FIT_DEFAULTS.initial)),
            )
            out[s.name] = modal_posterior(problem, r, **kw)
        return out

    def save(self, outdir: str | Path, *, fits: bool = True,
             extra: dict[str, Any] | None = None, trial: Trial | None = None
             ) -> dict[str, Path]:
        """Write ``comparison.{json,txt,html,png}`` and each model's fit.

        Parameters
        ----------
        outdir : str or pathlib.Path
            Created if missing; existing files are replaced.
        fits : bool
            Also save each FitResult into ``outdir/<model>/`` (``posterior.nc``,
            ``summary.json``).
        extra : dict, optional
            Further JSON-ready keys of ``comparison.json`` (e.g. ``preprocessing``).
        trial : Trial, optional
            The compared trial: then ``comparison.json`` gets ``modes`` ({model: the
            record of :meth:`modal_posteriors`}) and ``zeta_vs_f.png`` shows ζ_k against
            f_k of every model (:func:`bayesbeam.inference.modal_plots.plot_zeta_vs_f`).

        Returns
        -------
        dict
            ``json``, ``txt``, ``html``, ``png``, ``zeta_vs_f`` (when written) and
            ``fit:<model>`` paths.
        """
        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        paths = {
            "json": outdir / "comparison.json",
            "txt": outdir / "comparison.txt",
            "html": outdir / "comparison.html",
            "png": outdir / "comparison.png",
        }
        record = {**self.to_json_dict(), **(extra or {})}
        modal = None if trial is None else self.modal_posteriors(trial)
        if modal is not None:
            record["modes"] = {name: m.to_json_dict() for name, m in modal.items()}
        write_text_atomic(paths["json"], json.dumps(record, indent=2, allow_nan=False) + "\n")
        write_text_atomic(paths["txt"], str(self) + "\n")
        write_text_atomic(
            paths["html"],
            "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>bayesbeam model "
            "comparison</title></head><body>\n" + self._repr_html_() + "\n</body></html>\n",
        )
        self.plot(paths["png"])
        if modal is not None:
            from bayesbeam.inference.modal_plots import plot_zeta_vs_f

            if plot_zeta_vs_f(modal, outdir / "zeta_vs_f.png", title=f"{trial.name}: "
                              "damping ratio against frequency") is not None:
                paths["zeta_vs_f"] = outdir / "zeta_vs_f.png"
        if fits:
            for s in self.scores:
                saved = s.save(outdir / s.name)
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


def _adequate(score: ModelScore) -> bool | None:
    """Return the fit's adequacy verdict (None when it was not assessed)."""
    ad = score.result.adequacy
    return bool(ad["ok"]) if ad and "ok" in ad else None


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
    bad = [s.name for s in scores if _adequate(s) is False]
    if bad and len(bad) == len(scores):
        tail += (" No model reproduces the data to its noise (adequacy): the ranking and "
                 "every interval are conditional on models the data reject; run `bayesbeam "
                 "diagnose` on this trial to look for the missing effect.")
    elif bad:
        tail += (f" Not adequate (do not reproduce the data to its noise): {', '.join(bad)}; "
                 "their intervals are conditional on models the data reject.")
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
    n_loo_draws: int = 1000,
    proposal: str = "normal",
    n_proposal: int | None = 10_000,
    sensitivity_factors: Sequence[float] = (0.5, 2.0),
    outdir: str | Path | None = None,
    progress: bool | None = None,
    executor: Any = None,
    **settings: Any,
) -> Comparison:
    """Fit and compare several models on one trial.

    Each model is fitted and scored by :func:`evaluate` (same ``seed``), then ranked
    by log evidence. The fits are independent: with an ``executor`` they run in
    parallel (local processes, a Dask cluster) and give bitwise the numbers of the
    serial run, since each fit's input (the trial's arrays, the model, the settings and
    the seed) travels with it and nothing depends on the order they finish in. Models
    tied with the best (|Δ log Z| within ``max(2 sqrt(err_a² + err_b²), threshold)``)
    are listed in ``indistinguishable`` and the verdict says so; posterior model
    probabilities carry the evidence errors; ELPD-LOO differences are paired; the prior widths of
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
        :meth:`Comparison.save` to write the results). Serial runs only: with an
        ``executor`` the workers (possibly on machines without this file system) write
        no checkpoint.
    progress : bool or None
        A progress bar over the models on stderr
        (:func:`bayesbeam._util.progress_bar`: which model is being fitted, with a
        time estimate) and, in a serial run, the sampler's
        progress lines; None: the bar only on a terminal or in Jupyter.
    executor : concurrent.futures.Executor, optional
        Any object with the ``map`` method of :class:`concurrent.futures.Executor`
        (a ``ProcessPoolExecutor``, ``distributed.Client(...).get_executor()``; the
        command line makes one with :func:`bayesbeam.jobs.executor.make_executor`).
        None: one fit after another in this process.
    **settings
        Forward-model and sampler settings of every fit (``n_elements``, ``initial``,
        ``nwalkers``, ``target_ess``, ``max_steps``, ``min_steps``), with the defaults
        of :data:`bayesbeam.inference.settings.FIT_DEFAULTS`.

    Returns
    -------
    Comparison
    """
    fit_settings(settings, caller="compare")  # a misspelt setting fails before any fit
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
    jobs = [
        {"trial": trial, "model": m.name, "seed": int(seed), "priors": priors.get(m.name),
         "n_loo_draws": n_loo_draws, "proposal": proposal, "n_proposal": n_proposal,
         "settings": dict(settings),
         # Sampler lines and checkpoints only in this process (workers have neither
         # this terminal nor, on a cluster, this file system).
         "progress": progress if executor is None else False,
         "outdir": (None if outdir is None or executor is not None
                    else str(Path(outdir) / m.name))}
        for m in parsed
    ]
    show = stderr_is_live() if progress is None else bool(progress)
    bar = progress_bar(len(jobs), f"compare {trial.name}", enabled=show, unit="model")
    scores: list[ModelScore] = []
    try:
        if executor is None:
            for job in jobs:
                progress_note(bar, f"fitting {job['model']}")
                scores.append(_evaluate_job(job))
                progress_note(bar, f"{job['model']} done")
                bar.update(1)
        else:
            # map yields in input order: the note names the model awaited next.
            progress_note(bar, f"fitting {len(jobs)} models; waiting for {jobs[0]['model']}")
            for i, score in enumerate(executor.map(_evaluate_job, jobs)):
                scores.append(score)
                nxt = f"; waiting for {jobs[i + 1]['model']}" if i + 1 < len(jobs) else ""
                progress_note(bar, f"{score.name} done{nxt}")
                bar.update(1)
    finally:
        bar.close()
    return compare_scores(scores, prior_odds=prior_odds, threshold=threshold,
                          sensitivity_factors=sensitivity_factors)


def _evaluate_job(job: Mapping[str, Any]) -> ModelScore:
    """Fit and score one model of :func:`compare` (the function an executor maps).

    Module-level and fed plain data, so that it pickles to worker processes and Dask
    workers: the result depends on ``job`` alone, not on where or in which order it runs.

    Parameters
    ----------
    job : mapping
        ``trial`` (the :class:`Trial` itself: its arrays and metadata travel with the
        job, no path is read on the worker), ``model``, ``seed``, ``priors``,
        ``n_loo_draws``, ``proposal``, ``n_proposal``, ``settings`` (fit settings),
        ``progress`` and ``outdir`` (checkpoint folder or None).

    Returns
    -------
    ModelScore
        Pickles back from a worker (:meth:`FitResult.__reduce
        <bayesbeam.inference.results.FitResult.__reduce__>`).
    """
    with job_guard():
        score = evaluate(
            job["trial"], job["model"], seed=job["seed"], priors=job["priors"],
            n_loo_draws=job["n_loo_draws"], proposal=job["proposal"],
            n_proposal=job["n_proposal"], progress=job["progress"], outdir=job["outdir"],
            **job["settings"],
        )
    return score
