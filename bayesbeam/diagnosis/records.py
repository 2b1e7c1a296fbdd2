"""Records of a diagnosis: the outcome, its rounds and candidate scores, and their text.

:func:`bayesbeam.diagnosis.diagnose.diagnose` returns a :class:`Diagnosis`; this module holds the
records only (like a results module): their fields, their strict-JSON form
(``to_json_dict``, written by ``bayesbeam diagnose --json``) and the markdown report
(:meth:`Diagnosis.narrative`, with :func:`describe_signatures` for the baseline's
residual signatures). The procedure and its thresholds are in :mod:`bayesbeam.diagnosis.diagnose`,
which re-exports every name defined here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bayesbeam._util import SCHEMA_VERSION, finite_or_none, interval_digits

__all__ = [
    "CandidateScore",
    "Diagnosis",
    "Round",
    "describe_signatures",
]

# --------------------------------------------------------------------------- records


@dataclass(frozen=True)
class CandidateScore:
    """How one candidate extension fared in one round.

    Attributes
    ----------
    cause, model : str
        Catalogue name and the extended model's name.
    delta_chi2_half : float
        Screening statistic: gain in maximum log-likelihood over the current model
        (nats); NaN when the candidate could not be fitted (see ``note``).
    laplace_delta : float
        Laplace Δ log Z (nats), NaN where a MAP lies on a prior bound.
    confirmed : bool
        Sampled and scored by bridge sampling / LOO.
    delta_log_evidence, delta_log_evidence_err : float
        Δ log Z and its error (nats); NaN unless confirmed.
    delta_elpd, delta_elpd_se : float
        Paired Δ ELPD (PSIS-LOO) and its se (nats); NaN unless confirmed.
    significant : bool
        ``Δ - 2 err > SIGNIFICANCE`` (:data:`bayesbeam.diagnosis.diagnose.SIGNIFICANCE`).
    n_params : int
        Sampled parameters of the extended model.
    seconds : float
        Wall-clock time spent on this candidate.
    note : str
        Why it was not screened or confirmed, reliability messages.
    """

    cause: str
    model: str
    delta_chi2_half: float
    laplace_delta: float = math.nan
    confirmed: bool = False
    delta_log_evidence: float = math.nan
    delta_log_evidence_err: float = math.nan
    delta_elpd: float = math.nan
    delta_elpd_se: float = math.nan
    significant: bool = False
    n_params: int = 0
    seconds: float = 0.0
    note: str = ""

    def to_json_dict(self) -> dict[str, Any]:
        """Return a strict-JSON dictionary.

        Returns
        -------
        dict
        """
        return {k: (finite_or_none(v) if isinstance(v, float) else v)
                for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class Round:
    """One round of the diagnosis.

    Attributes
    ----------
    index : int
        1-based round number.
    model_before, model_after : str
        Current model and the extended one (equal when nothing was named).
    cause : str
        Named cause, or ``"none"``.
    equivalent : tuple of str
        Other causes the evidence cannot separate from the named one.
    delta_log_evidence, delta_log_evidence_err : float
        Gain of the named cause in log evidence (nats) and its error.
    delta_elpd, delta_elpd_se : float
        Gain in PSIS-LOO ELPD (nats) and its paired se.
    rms_before, rms_after : float
        RMS residual of the posterior-mean prediction (signal units).
    coverage_before, coverage_after : float
        Fraction of the data inside the central 90 % posterior-predictive interval.
    parameter_moves : dict
        Physical parameter → ``{"before": [mean, sd], "after": [mean, sd]}``.
    signature : str
        The residual signature of the current model that points to the cause.
    signature_agrees : bool or None
        Whether that signature is significant in the cause's direction (None when it
        could not be measured).
    candidates : tuple of CandidateScore
    seconds : float
    """

    index: int
    model_before: str
    model_after: str
    cause: str
    equivalent: tuple[str, ...] = ()
    delta_log_evidence: float = math.nan
    delta_log_evidence_err: float = math.nan
    delta_elpd: float = math.nan
    delta_elpd_se: float = math.nan
    rms_before: float = math.nan
    rms_after: float = math.nan
    coverage_before: float = math.nan
    coverage_after: float = math.nan
    parameter_moves: Mapping[str, Any] = field(default_factory=dict)
    signature: str = ""
    signature_agrees: bool | None = None
    candidates: tuple[CandidateScore, ...] = ()
    seconds: float = 0.0

    def to_json_dict(self) -> dict[str, Any]:
        """Return a strict-JSON dictionary (the CLI's ``rounds`` entries).

        Returns
        -------
        dict
            ``cause``, ``equivalent``, ``delta_log_evidence``,
            ``delta_log_evidence_err``, ``delta_elpd``, ``rms_before``, ``rms_after``
            and the other fields.
        """
        return {
            "index": self.index,
            "cause": self.cause,
            "equivalent": list(self.equivalent),
            "delta_log_evidence": finite_or_none(self.delta_log_evidence),
            "delta_log_evidence_err": finite_or_none(self.delta_log_evidence_err),
            "delta_elpd": finite_or_none(self.delta_elpd),
            "delta_elpd_se": finite_or_none(self.delta_elpd_se),
            "rms_before": finite_or_none(self.rms_before),
            "rms_after": finite_or_none(self.rms_after),
            "coverage90_before": finite_or_none(self.coverage_before),
            "coverage90_after": finite_or_none(self.coverage_after),
            "model_before": self.model_before,
            "model_after": self.model_after,
            "parameter_moves": {
                k: {s: [finite_or_none(x) for x in v[s]] for s in ("before", "after")}
                for k, v in self.parameter_moves.items()
            },
            "signature": self.signature,
            "signature_agrees": self.signature_agrees,
            "candidates": [c.to_json_dict() for c in self.candidates],
            "seconds": finite_or_none(self.seconds),
        }


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Outcome of :func:`bayesbeam.diagnosis.diagnose.diagnose`.

    Attributes
    ----------
    trial : str
        Trial name.
    baseline, final_model : str
    named_causes : tuple of str
        Causes in the order found; empty when none is significant.
    rounds : tuple of Round
        The rounds that named a cause.
    final_check : Round or None
        The last round, in which nothing significant remained (None when the
        round limit was reached first).
    thresholds : dict
        The thresholds used (nats).
    signatures_before, signatures_after : Signatures or None
        Residual signatures of the baseline and of the final model.
    fits : dict of str to FitResult
        Posterior of every sampled model.
    notes : tuple of str
        Reliability messages (unconverged chains, Pareto k, unavailable candidates).
    seconds : float
    interrupted : str or None
        Set when the run was interrupted (Ctrl-C) after at least one complete round:
        which round was cut short. The rounds held are complete; the search did not end.
    """

    trial: str
    baseline: str
    final_model: str
    named_causes: tuple[str, ...]
    rounds: tuple[Round, ...]
    final_check: Round | None
    thresholds: Mapping[str, float]
    signatures_before: Any = None
    signatures_after: Any = None
    fits: Mapping[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    seconds: float = 0.0
    interrupted: str | None = None

    @property
    def verdict(self) -> str:
        """``"none"`` or the named causes joined by ``" + "``."""
        return " + ".join(self.named_causes) if self.named_causes else "none"

    @property
    def final_posterior(self) -> dict[str, dict[str, float | None]]:
        """Posterior summary of the final model, SI units.

        Returns
        -------
        dict
            ``{param: {mean, sd, q05, q50, q95}}`` for every sampled and derived
            parameter of :attr:`final_model`; empty when that model was not sampled.
        """
        res = self.fits.get(self.final_model)
        if res is None:
            return {}
        keys = ("mean", "sd", "q05", "q50", "q95")
        return {p: {k: finite_or_none(float(v[k])) for k in keys}
                for p, v in res.summary().items()}

    def to_json_dict(self) -> dict[str, Any]:
        """Return the strict-JSON record written by ``bayesbeam diagnose --json``.

        Returns
        -------
        dict
            ``named_causes``, ``rounds`` (see :meth:`Round.to_json_dict`),
            ``final_model``, ``baseline``, ``verdict``, ``final_check``,
            ``thresholds``, ``signatures`` (before/after), ``final_posterior``
            (:attr:`final_posterior`), ``final_posterior_units`` (SI unit of each of its
            entries), ``notes``, ``seconds``, ``interrupted`` (None, or which round was
            cut short).
        """
        sig = {
            k: (None if s is None else s.to_json_dict())
            for k, s in (("before", self.signatures_before), ("after", self.signatures_after))
        }
        return {
            "schema_version": SCHEMA_VERSION,
            "trial": self.trial,
            "baseline": self.baseline,
            "final_model": self.final_model,
            "named_causes": list(self.named_causes),
            "verdict": self.verdict,
            "rounds": [r.to_json_dict() for r in self.rounds],
            "final_check": None if self.final_check is None else self.final_check.to_json_dict(),
            "thresholds": dict(self.thresholds),
            "signatures": sig,
            "final_posterior": self.final_posterior,
            "final_posterior_units": ({} if self.fits.get(self.final_model) is None
                                      else self.fits[self.final_model].units()),
            "notes": list(self.notes),
            "seconds": finite_or_none(self.seconds),
            "interrupted": self.interrupted,
        }

    def narrative(self) -> str:
        """Return a short markdown report: what is wrong, the named causes, the gains.

        Returns
        -------
        str
        """
        lines = [f"# Diagnosis of trial `{self.trial}`", ""]
        sb = self.signatures_before
        lines.append(f"Baseline model `{self.baseline}`; final model `{self.final_model}`.")
        if self.interrupted:
            lines += ["", f"**Incomplete: {self.interrupted}.** The rounds below are complete; "
                      "causes the search did not reach may remain."]
        if sb is not None:
            lines += ["", "## What the baseline gets wrong", ""]
            lines += [f"- {s}" for s in describe_signatures(sb)]
        lines += ["", "## Named causes", ""]
        if not self.named_causes:
            lines.append("None: no extension in the catalogue improves the log evidence by more "
                         f"than {self.thresholds['significance']:g} nats beyond twice its error.")
        for r in self.rounds:
            eq = (f" The data cannot separate it from {', '.join(r.equivalent)} (evidence "
                  "within error): these explain the record equally well." if r.equivalent else "")
            lines.append(
                f"{r.index}. **{r.cause}**: Δ log Z = {r.delta_log_evidence:.1f} ± "
                f"{r.delta_log_evidence_err:.1f} nats, Δ ELPD = {r.delta_elpd:.1f} ± "
                f"{r.delta_elpd_se:.1f}; RMS residual {r.rms_before:.3g} → {r.rms_after:.3g}, "
                f"90 % coverage {r.coverage_before:.2f} → {r.coverage_after:.2f}.{eq} "
                f"Signature: {r.signature}"
            )
            moves = [f"{k} {_pm(*v['before'])} → {_pm(*v['after'])}"
                     for k, v in r.parameter_moves.items()]
            if moves:
                lines.append("   Parameters moved: " + "; ".join(moves) + ".")
            size = _size_text(r.parameter_moves)
            if size:
                lines.append(f"   Size: {size}.")
        if self.final_check is not None and self.named_causes:
            best = max(self.final_check.candidates, key=lambda c: _nan_low(c.delta_chi2_half),
                       default=None)
            extra = (f" (best remaining: {best.cause}, Δχ²/2 = {best.delta_chi2_half:.1f})"
                     if best is not None else "")
            lines.append(f"\nAfter round {len(self.rounds)} nothing significant remains{extra}.")
        lines += ["", "## Procedure", "",
                  f"Screen by MAP gain (Δχ²/2 > {self.thresholds['screen']:g} nats), confirm by "
                  "emcee + bridge-sampling evidence; significant when Δ log Z − 2 err > "
                  f"{self.thresholds['significance']:g} nats; equivalent within "
                  f"max(2 err, {self.thresholds['tie']:g}) nats of the best."]
        if self.notes:
            lines += ["", "## Notes", ""] + [f"- {n}" for n in self.notes]
        return "\n".join(lines) + "\n"


#: Parameters of named causes in the units a reader judges: name -> (factor, unit, label).
_SIZE_UNITS = {
    "f1_slope": (1.0, "mHz per mm of mode-1 tip amplitude (negative: softening)",
                 "f1 change"),
    "added_mass": (1e3, "g", "added mass"),
    "added_mass_position": (1e2, "cm from the clamp", "at"),
    "tip_mass": (1e3, "g", "tip mass"),
    "friction": (1e3, "mN", "clamp friction force"),
    "drag": (1.0, "kg/m²", "drag coefficient c_q"),
    "k2": (1.0, "per signal unit (the sensor reads y + k2 y²)", "sensor K2"),
}


def _size_text(moves: Mapping[str, Any]) -> str:
    """Posterior sizes of a round's new parameters in reader's units (SI internally)."""
    out = []
    for name, (factor, unit, label) in _SIZE_UNITS.items():
        v = moves.get(name)
        if v is None or not all(math.isfinite(x) for x in v["after"]):
            continue
        mean, sd = v["after"]
        out.append(f"{label} {_pm(factor * mean, factor * sd)} {unit}")
    return "; ".join(out)


def _pm(mean: float, sd: float) -> str:
    """``mean ± sd`` with enough digits in the mean that its ±sd interval shows."""
    d = interval_digits(mean, mean - sd, mean + sd, minimum=4)
    return f"{mean:#.{d}g} ± {sd:.2g}"


def _nan_low(x: float) -> float:
    return x if math.isfinite(x) else -math.inf


# --------------------------------------------------------------------------- signatures


def describe_signatures(sig: Any) -> list[str]:
    """Plain-language lines on what a fit's residual signatures show.

    Parameters
    ----------
    sig : Signatures

    Returns
    -------
    list of str
    """
    out = [f"RMS residual {sig.rms_residual:.3g} ({100 * sig.rms_residual / sig.rms_data:.1f} % "
           f"of the data's RMS); 90 % predictive coverage {sig.coverage90:.2f}."]
    white = "white" if sig.white else "NOT white"
    what = "Residuals" if sig.whiteness_series == "residuals" else "AR(1) innovations"
    out.append(f"{what} are {white} (Ljung–Box p = {sig.ljung_box_p:.2g}; lag-1 "
               f"autocorrelation of the residuals {sig.lag1:.2f}).")
    if math.isfinite(sig.ratio_shift):
        out.append(f"f2/f1: data {sig.ratio_data:.4f}, model {sig.ratio_model:.4f} "
                   f"({100 * sig.ratio_shift:+.2f} ± {100 * sig.ratio_shift_err:.2f} %).")
    for m in sig.modes:
        if m.data and m.model:
            out.append(f"Mode {m.mode}: f data {m.data.frequency:.4g} Hz vs model "
                       f"{m.model.frequency:.4g} Hz; ζ data {m.data.damping_ratio:.3g} vs model "
                       f"{m.model.damping_ratio:.3g}.")
    if math.isfinite(sig.decay_excess_diff) and sig.decay_excess_diff_err < 1.0:
        out.append(f"Decay rate vs amplitude (mode 1): excess decay rate at the initial amplitude "
                   f"data − model {100 * sig.decay_excess_diff:+.0f} ± "
                   f"{100 * sig.decay_excess_diff_err:.0f} %.")
    tr = getattr(sig, "amplitude_trends", {})
    if "data" in tr and "model" in tr and math.isfinite(tr["data"]["f1_hz_per_mm"]):
        d, m = tr["data"], tr["model"]
        out.append(
            f"Against the mode-1 tip amplitude ({1e3 * d['amplitude_min_m']:.2g}-"
            f"{1e3 * d['amplitude_max_m']:.2g} mm, {d['n_windows']} windows): f1 data "
            f"{1e3 * d['f1_hz_per_mm']:+.3g} ± {1e3 * d['f1_hz_per_mm_se']:.2g} vs model "
            f"{1e3 * m['f1_hz_per_mm']:+.3g} mHz/mm; ζ1 data {d['zeta1_per_mm']:+.2e} ± "
            f"{d['zeta1_per_mm_se']:.1e} vs model {m['zeta1_per_mm']:+.2e} per mm (f1 falling "
            "with amplitude: softening; ζ1 rising: drag, falling: friction).")
    change = getattr(sig, "state_change", None)
    if change and change.get("found"):
        out.append(f"In the record itself (no model): {change['reason']}.")
    out.append(f"Residual mean {sig.residual_mean:.3g} (z = {sig.residual_mean_z:.1f}); "
               f"{100 * sig.lowfreq_fraction:.1f} % of the residual power below f1/2.")
    k2, se = sig.quadratic_k2, sig.quadratic_k2_se
    if math.isfinite(k2) and math.isfinite(se):
        out.append(f"Residual against the square of the model's signal: k2 = {k2:.3g} ± "
                   f"{se:.2g} per signal unit (a quadratic sensor, y + k2 y²; lines at "
                   "twice the modes' frequencies).")
    return out
