"""Name the cause of a model discrepancy from a catalogue, extend the model, measure the gain.

:func:`diagnose` starts from a baseline model (e.g. ``viscous+kv``) and, round by
round, tries every extension of the catalogue (:data:`CATALOGUE`) that the current
model lacks:

========================  ===========================================================
cause                     model extension (parameters)
========================  ===========================================================
``kv``, ``sh``            an internal damping law (``c_d``; ``eta``, ``b``)
``tip_mass``              concentrated tip mass (``tip_mass``, kg)
``root_spring``           rotational clamp compliance (``root_spring``, N m/rad)
``stiffness_gradient``    EI(x) ∝ 1 + g (x/L - 1/2) (``stiffness_gradient``)
``amplitude_damping``     quadratic air drag and clamp friction (``drag``, ``friction``)
``ar1_noise``             AR(1) correlated residuals (``rho``)
``sensor_offset``         constant offset of the signal (``offset``)
========================  ===========================================================

Procedure of one round (current model M)
----------------------------------------
1. **Screen** (cheap, every candidate X): the MAP of M+X from several starts, each
   refined by an E scan, L-BFGS-B and a few damped Newton steps with a
   finite-difference Hessian (these posteriors are narrow curved ridges on which
   L-BFGS-B alone stops several nats short). Starts: the current MAP with X's
   parameters at their neutral values (the prior's lower end; ``g = 0``, ``rho = 0``,
   a stiff root spring), so M+X ⊇ M is at least as good; and physics-based starts
   from the data's modal estimates (:func:`bayesbeam.signatures.damped_sinusoids`):
   a structural parameter solved so that the model's f2/f1 equals the measured one,
   E so that f1 matches, the damping coefficients from the measured decay rates of
   modes 1 and 2 (non-negative least squares on σ_n ≈ C_nn/2), and drag or friction
   at 0.25-2 times the measured ζ1 (:meth:`~bayesbeam.nonlinear.NonlinearForward.
   equivalent_damping` at the measured first-mode amplitude). The statistic is the
   gain in maximum log-likelihood ``Δχ²/2 = max log L(M+X) - max log L(M)``; the
   Laplace Δ log Z (:func:`bayesbeam.evidence.laplace_evidence`) is recorded where
   both MAPs are interior. Adding a parameter multiplies the evidence by its Occam
   factor (≤ 1), so Δ log Z ≲ Δχ²/2: a candidate with ``Δχ²/2 <= SCREEN_THRESHOLD``
   (2 nats, 1 nat below the significance threshold for safety) cannot be
   significant and is not sampled. The MAPs of the passing candidates also restart
   the optimisation of M (a better optimum of M found this way replaces its MAP, so
   that a poor local optimum of M cannot make every extension look good).
2. **Confirm** (expensive): emcee from the MAP (walkers in a ball shaped by the
   Laplace covariance, differential-evolution moves), then bridge-sampling evidence
   with its Monte-Carlo error and PSIS-LOO (:func:`bayesbeam.compare.evaluate`) for M
   and for the ``confirm_top`` best-screened candidates (plus any other within
   ``SCREEN_TIE`` = 3 nats of the best screen value).
3. **Decide**. ``Δ = log Z(M+X) - log Z(M)`` with ``err = sqrt(err_M² + err_X²)``.
   X is *significant* when ``Δ - 2 err > SIGNIFICANCE`` (3 nats: a Bayes factor above
   20, "strong" on Kass & Raftery's 1995 scale). Two candidates count as *separated*
   only when one's evidence beats the other's by the same strength, more than
   ``max(2 err, TIE)`` with ``TIE`` = 3 nats. The best significant candidate and all
   significant ones not separated from it form a set the data cannot tell apart: the
   one with fewest parameters is named (parsimony; by construction their evidences
   do not distinguish them; ties broken by evidence) and the others are listed as
   ``equivalent``. Nothing significant → the round's answer is ``"none"`` and the
   diagnosis stops. Δ ELPD (PSIS-LOO, paired se; Vehtari et al. 2017) is reported
   beside it, and a note is made when it points the other way beyond 2 se.
4. **Tie to a signature**: the residual signature of M that points the same way is
   reported (:func:`signature_support`): f2/f1 shift for the structural causes,
   decay rate vs amplitude for ``amplitude_damping``, Ljung–Box whiteness and lag-1
   autocorrelation for ``ar1_noise``, mean / low-frequency residual for
   ``sensor_offset``, frequency dependence of the modal damping for ``kv``/``sh``.
5. **Measure the gain**: Δ log Z ± err, Δ ELPD ± se, RMS residual and 90 %
   predictive coverage before and after, and how the physical parameters moved
   (posterior mean ± sd before and after).

Then M ← M+X and the next round starts, up to ``max_rounds`` (default 3).

Cost: each screen is one MAP search (0.2-2 s for a 512-sample record and 8 elements
on one core; 5-15 s with amplitude damping, whose forward model is ~5x slower); each
confirmation one emcee run plus bridge sampling (5-20 s at the test budget of 400
steps x 24 walkers). A round costs about 8 screens and 2-4 confirmations.

Known limits: a tip mass and a root spring have exactly the same natural frequencies
when μ = m_t/(rhoA L) = 1/κ (physics.md §3 gives the same frequency equation for
both); only the mode shapes (hence the modal amplitudes of a release or a tap) tell
them apart, so with free modal amplitudes (``initial='modes:K'``) they differ only
through the modal damping. With only two modes in the record, a broad-kernel SH and
viscous + KV damping both fit two decay rates exactly, and a root spring and a
stiffness gradient both fit f2/f1: the third mode separates them (visible in
acceleration records and in displacement records of a tap, not of a release). A
narrow-kernel SH is KV (physics.md §2), so ``sh`` is never separable from ``kv``
when KV is the cause.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.optimize as sopt

from bayesbeam.models import LAWS, STRUCTURAL, Model, parse_model
from bayesbeam.trial import Trial

__all__ = [
    "CATALOGUE",
    "SCREEN_THRESHOLD",
    "SIGNIFICANCE",
    "TIE",
    "CandidateScore",
    "Diagnosis",
    "DiagnoseError",
    "Round",
    "describe_signatures",
    "diagnose",
    "signature_support",
]

#: The catalogue of causes, in the order they are tried (names are model parts).
CATALOGUE: tuple[str, ...] = (
    "kv", "sh", "tip_mass", "root_spring", "stiffness_gradient", "amplitude_damping",
    "ar1_noise", "sensor_offset",
)
#: A cause is significant when Δ log Z - 2 err exceeds this (nats; Bayes factor > 20).
SIGNIFICANCE = 3.0
#: Screening: candidates whose max-log-likelihood gain does not exceed this are dropped.
SCREEN_THRESHOLD = 2.0
#: Candidates within this many nats of the best screen value are confirmed too.
SCREEN_TIE = 3.0
#: Candidates are separated only when one's evidence beats the other's by more than
#: max(2 err, TIE) nats: the same strength (Bayes factor > 20) that significance needs.
TIE = 3.0


class DiagnoseError(ValueError):
    """Invalid input to :func:`diagnose`; the message says how to fix it."""


# --------------------------------------------------------------------------- records


def _num(x: Any) -> Any:
    """Float, or None when not finite (strict JSON)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


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
        ``Δ - 2 err > SIGNIFICANCE``.
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
        return {k: (_num(v) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


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
            "delta_log_evidence": _num(self.delta_log_evidence),
            "delta_log_evidence_err": _num(self.delta_log_evidence_err),
            "delta_elpd": _num(self.delta_elpd),
            "delta_elpd_se": _num(self.delta_elpd_se),
            "rms_before": _num(self.rms_before),
            "rms_after": _num(self.rms_after),
            "coverage90_before": _num(self.coverage_before),
            "coverage90_after": _num(self.coverage_after),
            "model_before": self.model_before,
            "model_after": self.model_after,
            "parameter_moves": {
                k: {s: [_num(x) for x in v[s]] for s in ("before", "after")}
                for k, v in self.parameter_moves.items()
            },
            "signature": self.signature,
            "signature_agrees": self.signature_agrees,
            "candidates": [c.to_json_dict() for c in self.candidates],
            "seconds": _num(self.seconds),
        }


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Outcome of :func:`diagnose`.

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

    @property
    def verdict(self) -> str:
        """``"none"`` or the named causes joined by ``" + "``."""
        return " + ".join(self.named_causes) if self.named_causes else "none"

    def to_json_dict(self) -> dict[str, Any]:
        """Return the strict-JSON record written by ``bayesbeam diagnose --json``.

        Returns
        -------
        dict
            ``named_causes``, ``rounds`` (see :meth:`Round.to_json_dict`),
            ``final_model``, ``baseline``, ``verdict``, ``final_check``,
            ``thresholds``, ``signatures`` (before/after), ``notes``, ``seconds``.
        """
        sig = {
            k: (None if s is None else s.to_json_dict())
            for k, s in (("before", self.signatures_before), ("after", self.signatures_after))
        }
        return {
            "trial": self.trial,
            "baseline": self.baseline,
            "final_model": self.final_model,
            "named_causes": list(self.named_causes),
            "verdict": self.verdict,
            "rounds": [r.to_json_dict() for r in self.rounds],
            "final_check": None if self.final_check is None else self.final_check.to_json_dict(),
            "thresholds": dict(self.thresholds),
            "signatures": sig,
            "notes": list(self.notes),
            "seconds": _num(self.seconds),
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
            moves = [
                f"{k} {v['before'][0]:.4g} ± {v['before'][1]:.2g} → {v['after'][0]:.4g} ± "
                f"{v['after'][1]:.2g}" for k, v in r.parameter_moves.items()
            ]
            if moves:
                lines.append("   Parameters moved: " + "; ".join(moves) + ".")
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
    out.append(f"Residual mean {sig.residual_mean:.3g} (z = {sig.residual_mean_z:.1f}); "
               f"{100 * sig.lowfreq_fraction:.1f} % of the residual power below f1/2.")
    return out


def signature_support(cause: str, sig: Any) -> tuple[bool | None, str]:
    """Find the residual signature that points to ``cause`` and say whether it does.

    Parameters
    ----------
    cause : str
        A catalogue name.
    sig : Signatures
        Signatures of the model the cause would extend.

    Returns
    -------
    agrees : bool or None
        True when the signature is significant (beyond 2 se, or the stated level) in
        the cause's direction; None when it could not be measured.
    text : str
    """
    if cause in STRUCTURAL:
        s, e = sig.ratio_shift, sig.ratio_shift_err
        if not math.isfinite(s):
            return None, "f2/f1 not measurable (mode 2 not seen)"
        txt = (f"f2/f1 of the data is {100 * s:+.2f} ± {100 * e:.2f} % off the model's; on a "
               "uniform strip a tip mass of 8 % of the beam mass raises f2/f1 by ~3 %, a root "
               "spring lowering f1 by 4 % raises it by only ~0.3 %, a stiffness falling 30 % "
               "toward the tip lowers it by ~3.5 %")
        big = abs(s) > 2 * e
        if cause == "stiffness_gradient":
            return big, txt
        return bool(big and s > 0), txt
    if cause == "amplitude_damping":
        d, e = sig.decay_excess_diff, sig.decay_excess_diff_err
        if not (math.isfinite(d) and e < 1.0):
            return None, ("decay rate vs amplitude not measurable on this record (the "
                          "amplitude falls too little, or mode 1 is too weak)")
        way = ("faster at large amplitude (drag)" if d > 0
               else "faster at small amplitude (friction)")
        return bool(abs(d) > 2 * e), (
            "mode-1 decay rate changes with amplitude beyond the model: its excess at the "
            f"initial amplitude is {100 * d:+.0f} ± {100 * e:.0f} % of the small-amplitude "
            f"rate, {way}")
    if cause == "ar1_noise":
        return bool(not sig.white and sig.lag1 > 0.2), (
            f"residuals autocorrelated: lag-1 {sig.lag1:.2f}, Ljung–Box p = {sig.ljung_box_p:.2g}")
    if cause == "sensor_offset":
        ok = abs(sig.residual_mean_z) > 3 or sig.lowfreq_fraction > 0.2
        return bool(ok), (f"residual mean {sig.residual_mean:.3g} (z = {sig.residual_mean_z:.1f}), "
                          f"{100 * sig.lowfreq_fraction:.0f} % of residual power below f1/2")
    if cause in LAWS:
        ms = [m for m in sig.modes if m.data and m.model]
        if not ms:
            return None, "modal damping not measurable"
        parts, agree = [], False
        for m in ms:
            d, mm = m.data, m.model
            err = math.hypot(d.decay_rate_se, mm.decay_rate_se)
            parts.append(f"mode {m.mode} decay rate data {d.decay_rate:.3g} vs model "
                         f"{mm.decay_rate:.3g} 1/s")
            agree |= abs(d.decay_rate - mm.decay_rate) > 2 * err
        return agree, ("frequency dependence of damping: " + "; ".join(parts)
                       + f" (ζ2/ζ1 data {sig.zeta_ratio_data:.3g}, model "
                       f"{sig.zeta_ratio_model:.3g}; viscous ζ falls with f, KV rises, wide-kernel "
                       "SH rises about linearly)")
    raise DiagnoseError(f"unknown cause {cause!r}; the catalogue is {list(CATALOGUE)}")


# --------------------------------------------------------------------------- engine


@dataclass
class _State:
    """Everything known about one model: problem, MAP, fit, score."""

    problem: Any
    u: np.ndarray | None = None
    lp: float = -math.inf
    ll: float = -math.inf
    laplace: float = math.nan
    score: Any = None  # compare.ModelScore
    sig: Any = None  # signatures.Signatures
    seconds: float = 0.0

    @property
    def x(self) -> dict[str, float]:
        return dict(zip(self.problem.names, self.problem.theta(self.u[None])[0], strict=True))


class _Engine:
    """Fits, caches and scores models of one trial."""

    def __init__(self, trial: Trial, *, seed: int, n_elements: int, initial: str,
                 priors: Mapping[str, Any] | None, sampler: Mapping[str, Any],
                 notes: list[str], log: Callable[[str], None]) -> None:
        self.trial = trial
        self.seed = seed
        self.n_elements = n_elements
        self.initial = initial
        self.priors = dict(priors or {})
        self.sampler = dict(sampler)
        self.notes = notes
        self.log = log
        self.rng = np.random.default_rng(seed)
        self.states: dict[str, _State] = {}
        self._features: dict[str, float] | None = None
        self._k = 0

    # -- problems and MAPs ------------------------------------------------------------
    def state(self, model: Model) -> _State:
        from bayesbeam.problem import Problem

        if model.name not in self.states:
            pb = Problem(self.trial, model, n_elements=self.n_elements, initial=self.initial)
            pri = {k: v for k, v in self.priors.items() if k in pb.names}
            if pri:
                pb = Problem(self.trial, model, pri, n_elements=self.n_elements,
                             initial=self.initial)
            self.states[model.name] = _State(pb)
        return self.states[model.name]

    def features(self) -> dict[str, float]:
        """Measured f1, f2 and decay rates of the data (for physics-based starts)."""
        if self._features is None:
            from bayesbeam.problem import first_frequency
            from bayesbeam.signatures import (
                damped_sinusoids,
                decay_rate_vs_amplitude,
                periodogram,
                spectral_peak,
            )

            t, y = self.trial.times, self.trial.values
            f1 = first_frequency(t, y)
            nyq = 0.5 / float(np.median(np.diff(t)))
            f, amp = periodogram(t, y)
            guesses = [f1]
            # Uniform-cantilever ratios f2/f1 = 6.267, f3/f1 = 17.55 (physics.md §4).
            for ratio in (6.267, 17.55):
                g = spectral_peak(f, amp, f1 * ratio, rel_window=0.15)
                if g is None or g > 0.8 * nyq:
                    break
                guesses.append(g)
            est = damped_sinusoids(t, y, guesses)
            feats: dict[str, float] = {"f1": f1}
            for k, e in enumerate(est[:2], start=1):
                if e is not None:
                    feats[f"f{k}"] = e.frequency
                    feats[f"a{k}"] = e.amplitude
                    if e.decay_rate > 0:
                        feats[f"sigma{k}"] = e.decay_rate
            if est[0] is None:
                feats.pop("f2", None)  # a ratio needs both
            else:
                # Amplitude dependence of the first mode's decay (starts for drag).
                dva = decay_rate_vs_amplitude(t, y, est[0].frequency,
                                              other=[est[0].frequency * r for r in (6.267, 17.55)])
                if dva is not None and np.isfinite(dva.excess_se):
                    feats.update(excess=dva.excess, excess_se=dva.excess_se, rate0=dva.rate0)
            self._features = feats
        return self._features

    def optimise(self, st: _State, starts: np.ndarray) -> None:
        """Improve the MAP of ``st`` from physical start points (rows of ``starts``)."""
        from bayesbeam import fit as fitmod

        pb = st.problem
        X = fitmod.clip_to_prior(pb, np.atleast_2d(starts))
        X = fitmod.scan_E(pb, fitmod.profile_linear(pb, X))
        U = pb.priors.to_u(X)
        if st.u is not None:
            U = np.vstack([st.u[None], U])
        bounds = [(lo + 1e-9, hi - 1e-9) if np.isfinite(lo) and np.isfinite(hi) else (None, None)
                  for lo, hi in pb.priors.bounds_u]

        def negf(u: np.ndarray) -> tuple[float, np.ndarray]:
            v, g = _gradient(pb.log_prob, u)
            if not np.isfinite(v):
                return 1e300, np.zeros_like(u)
            return -v, -g

        for u0 in U:
            u, v = u0, -math.inf
            for _ in range(4):
                # Restarting L-BFGS-B resets its curvature memory; on these narrow,
                # curved ridges a restart often gains several nats (up to 4 passes).
                res = sopt.minimize(negf, u, jac=True, method="L-BFGS-B", bounds=bounds,
                                    options={"maxiter": 300})
                v_new = float(pb.log_prob(res.x[None])[0])
                gain = v_new - v
                if gain > 0:
                    u, v = res.x, v_new
                if not gain > 1e-3:
                    break
            if v > st.lp:
                st.u, st.lp = np.asarray(u, dtype=float), v
        if st.u is not None and np.isfinite(st.lp):
            st.u, st.lp = _newton_polish(pb.log_prob, st.u, st.lp, bounds)
        if st.u is None or not np.isfinite(st.lp):
            raise DiagnoseError(f"no start of model {pb.model.name!r} has a finite posterior "
                                "density; check the trial's units and the priors")
        st.ll = float(pb.log_likelihood(st.u[None])[0])

    def laplace(self, st: _State) -> None:
        from bayesbeam.evidence import EvidenceError, laplace_evidence

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # inf - inf on a bound: reported
            try:
                st.laplace = laplace_evidence(st.problem.log_prob, st.u).log_z
            except EvidenceError:
                # MAP on a prior bound, or -H not (numerically) positive definite:
                # Laplace is not applicable, recorded NaN.
                st.laplace = math.nan

    def starts(self, st: _State, warm: Mapping[str, float] | None) -> np.ndarray:
        """Physical start points: warm (current MAP + neutral new values) and physics-based."""
        pb = st.problem
        names = list(pb.names)
        neutral = {n: _neutral(pb, n) for n in names}
        rows = []
        if warm:
            rows.append([warm.get(n, neutral[n]) for n in names])
        rows.extend(self._physics_starts(pb, warm or {}, neutral))
        return np.array(rows, dtype=float)

    def _physics_starts(self, pb: Any, warm: Mapping[str, float],
                        neutral: Mapping[str, float]) -> list[list[float]]:
        feats = self.features()
        names = list(pb.names)
        lin = _linear_forward(pb)
        base = {n: warm.get(n, neutral[n]) for n in names}
        # From a warm start only the parameters it lacks need physics-based values.
        new = {n for n in names if n not in warm}
        struct = [n for n in names if n in ("tip_mass", "root_spring", "stiffness_gradient")]
        variants: list[dict[str, float]] = []
        if not warm or new & {"gamma", "c_d", "eta", "b"}:
            variants.append(dict(base))
        if "f2" in feats:
            target = feats["f2"] / feats["f1"]
            for s in struct:
                if s not in new:
                    continue
                v = dict(base)
                for other in struct:
                    v[other] = neutral[other]
                lo, hi = pb.priors[s].bounds_u
                grid_u = np.linspace(lo, hi, 41)[1:-1]
                grid = pb.priors[s].from_u(grid_u)
                th = np.repeat(_fwd_row(pb, lin, v)[None], grid.size, axis=0)
                th[:, lin.param_names.index(s)] = grid
                om, _, _ = lin.modal_system(th)
                miss = om[:, 1] / om[:, 0] - target
                i = int(np.argmin(np.abs(miss)))
                # Refine between the bracketing grid points: 1e-3 of f2/f1 is already a
                # phase error of ~0.1 cycle per second at f2 ~ 60 Hz.
                j = i + 1 if i + 1 < grid.size and miss[i] * miss[i + 1] < 0 else i - 1
                if 0 <= j < grid.size and miss[i] * miss[j] < 0:
                    v[s] = _root_on_ratio(pb, lin, v, s, grid_u[min(i, j)], grid_u[max(i, j)],
                                          target)
                else:
                    v[s] = float(grid[i])
                variants.append(v)
        rows = []
        for v in variants:
            th = _fwd_row(pb, lin, v)
            om, _, _ = lin.modal_system(th[None])
            E = v["E"] * (2 * np.pi * feats["f1"] / om[0, 0]) ** 2
            v["E"] = float(np.clip(E, *pb.priors["E"].bounds))
            _set_damping(pb, lin, v, feats)
            rows.append([v[n] for n in names])
        if "drag" in new and "a1" in feats and "sigma1" in feats:
            v0 = variants[0] if variants else base
            rows += [[v[n] for n in names] for v in _amplitude_starts(pb, lin, v0, feats)]
        return rows

    # -- sampling and scoring ---------------------------------------------------------
    def confirm(self, st: _State) -> Any:
        """Sample from the MAP and score (bridge evidence, LOO); cached."""
        if st.score is not None:
            return st.score
        from bayesbeam.compare import evaluate

        t0 = time.perf_counter()
        self._k += 1
        seed = int(self.seed) * 1000 + self._k
        res = _sample(st.problem, st.u, seed=seed, settings=self.sampler, notes=self.notes)
        st.score = evaluate(self.trial, st.problem.model, seed=seed, result=res,
                            problem=st.problem, n_loo_draws=int(self.sampler["loo_draws"]))
        for n in st.score.notes:
            self.notes.append(f"{st.problem.model.name}: {n}")
        st.seconds += time.perf_counter() - t0
        self.log(f"  sampled {st.problem.model.name}: log Z = {st.score.log_evidence:.2f} ± "
                 f"{st.score.log_evidence_err:.2f}, elpd = {st.score.loo.elpd_loo:.1f} "
                 f"({time.perf_counter() - t0:.0f} s)")
        return st.score

    def signatures(self, st: _State) -> Any:
        if st.sig is None:
            from bayesbeam.signatures import compute_signatures

            st.sig = compute_signatures(st.problem, self.confirm(st).result, seed=self.seed)
        return st.sig


def _gradient(f: Callable[[np.ndarray], np.ndarray], u: np.ndarray,
              h: float = 1e-6) -> tuple[float, np.ndarray]:
    """Value and finite-difference gradient of a vectorised function (one call).

    Central differences, one-sided where the other side is outside the support (a
    parameter on a prior bound, e.g. rho = 0: a central difference would be infinite
    and the optimiser would never leave the bound); 0 where both sides are.
    """
    d = u.size
    v = f(np.vstack([u, u + h * np.eye(d), u - h * np.eye(d)]))
    f0, fp, fm = v[0], v[1 : d + 1], v[d + 1 :]
    g = np.where(np.isfinite(fp) & np.isfinite(fm), (fp - fm) / (2 * h),
                 np.where(np.isfinite(fp), (fp - f0) / h,
                          np.where(np.isfinite(fm), (f0 - fm) / h, 0.0)))
    return float(f0), g


def _fd_hessian(f: Callable[[np.ndarray], np.ndarray], u: np.ndarray,
                h: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Central-difference value, gradient and Hessian of a vectorised function (one call)."""
    d = u.size
    E = np.diag(h)
    pairs = [(i, j) for i in range(d) for j in range(i + 1, d)]
    pts = [u[None], u + E, u - E]
    pts += [np.array([u + si * E[i] + sj * E[j] for i, j in pairs]).reshape(-1, d)
            for si, sj in ((1, 1), (1, -1), (-1, 1), (-1, -1))]
    v = f(np.vstack(pts))
    f0, fp, fm = v[0], v[1 : d + 1], v[d + 1 : 2 * d + 1]
    g = (fp - fm) / (2 * h)
    H = np.diag((fp - 2 * f0 + fm) / h**2)
    p = len(pairs)
    q = v[2 * d + 1 :].reshape(4, p) if p else np.zeros((4, 0))
    for k, (i, j) in enumerate(pairs):
        H[i, j] = H[j, i] = (q[0, k] - q[1, k] - q[2, k] + q[3, k]) / (4 * h[i] * h[j])
    return float(f0), g, H


def _newton_polish(f: Callable[[np.ndarray], np.ndarray], u: np.ndarray, v: float,
                   bounds: Sequence[tuple[float | None, float | None]],
                   iters: int = 6) -> tuple[np.ndarray, float]:
    """Damped Newton steps with a finite-difference Hessian from a near-optimal point.

    L-BFGS-B crawls along the narrow curved ridges of these posteriors (curvatures
    spanning 1e3-1e10 in u) and can stop a few nats short; two or three Newton steps
    with steps of 0.2 conditional sd finish the job. Each step is one vectorised call.
    """
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds])
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds])
    h = 1e-4 * np.maximum(1.0, np.abs(u))
    for _ in range(iters):
        with np.errstate(all="ignore"):
            _, g, H = _fd_hessian(f, u, h)
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(H))):
            break
        curv = -np.diag(H)
        # Steps of 0.2 conditional sd where the curvature is positive; keep h elsewhere.
        h = np.where(curv > 0, 0.2 / np.sqrt(np.where(curv > 0, curv, 1.0)), h)
        w, V = np.linalg.eigh(-0.5 * (H + H.T))
        # Levenberg shift keeps the step an ascent direction where -H is not PD.
        w = np.maximum(w, 1e-8 * max(float(np.max(np.abs(w))), 1e-300))
        step = V @ ((V.T @ g) / w)
        moved = False
        for _ in range(12):
            un = np.clip(u + step, lo, hi)
            vn = float(f(un[None])[0])
            if np.isfinite(vn) and vn > v:
                moved = vn > v + 1e-4
                u, v = un, vn
                break
            step = 0.5 * step
        if not moved:
            break
    return u, v


def _neutral(pb: Any, name: str) -> float:
    """Return a value at which an extension's parameter does (almost) nothing."""
    lo, hi = pb.priors[name].bounds
    L = pb.trial.beam.length
    table = {"stiffness_gradient": 0.0, "rho": 0.01, "offset": 0.0, "b": 0.3 * L, "w0": 0.0}
    if name in table:
        return table[name]
    if name == "root_spring":
        return hi / 2.0
    if name == "sigma":
        return float(np.std(pb.data))
    if name == "E":
        return float(np.sqrt(lo * hi)) if np.isfinite(hi) else float(lo)
    if name == "tip_mass":
        return 1.001 * lo  # even 0.3 % of the beam mass shifts f1 by ~0.6 %
    if np.isfinite(lo) and lo > 0:
        # Damping coefficients, drag, friction: the prior's lower end (even that is not
        # quite neutral: KV at ζ1 = 1e-6 still damps the highest FE modes visibly in an
        # acceleration record).
        return 1.001 * lo
    return float(np.clip(0.0, lo, hi))


def _linear_forward(pb: Any) -> Any:
    """Return the linear forward model of a problem (the linear part of a nonlinear one)."""
    from bayesbeam.forward import Forward

    if isinstance(pb.forward, Forward):
        return pb.forward
    if isinstance(getattr(pb.forward, "linear", None), Forward):
        return pb.forward.linear  # NonlinearForward keeps its linear part
    m = pb.model
    parts = [p for p in m.parts if p not in m.nonlinear and p not in m.noise]
    return Forward(pb.trial.beam, "+".join(parts), pb.trial.times[:2],
                   n_elements=pb.n_elements, initial=pb.initial)


def _fwd_row(pb: Any, lin: Any, v: Mapping[str, float]) -> np.ndarray:
    """Forward-parameter row of the linear model from sampled values (eta → a)."""
    X = np.array([[v[n] for n in pb.names]])
    P = pb.forward_params(X)[0]
    vals = dict(zip(pb.forward.param_names, P, strict=True))
    return np.array([vals[n] for n in lin.param_names], dtype=float)


def _amplitude_starts(pb: Any, lin: Any, v: Mapping[str, float],
                      feats: Mapping[str, float]) -> list[dict[str, float]]:
    """Return starts whose drag (or friction) damps mode 1 about as much as the data show.

    The tip amplitude of mode 1 comes from its measured amplitude at the sensor
    (divided by ω1 per time derivative, scaled by the mode shape's tip/sensor ratio);
    :meth:`bayesbeam.nonlinear.NonlinearForward.equivalent_damping` converts it to
    the damping ratio per unit drag and per unit friction. Starts: drag alone giving
    0.5 and 2 times the measured ζ1, friction alone 0.25 and 1 times it, each with the
    linear damping coefficients scaled by 1/(1 + factor) so that the total stays near
    the measured one (a linear fit has already absorbed the amplitude-dependent part);
    and, when the data's decay rate changes with amplitude beyond 2 standard errors
    (:func:`bayesbeam.signatures.decay_rate_vs_amplitude`: rate σ0 (1 + c) at the first
    sample), drag giving c σ0/ω1 with the linear damping giving σ0.
    """
    fwd = pb.forward
    if not hasattr(fwd, "equivalent_damping"):
        return []
    th = _fwd_row(pb, lin, v)
    om, _, phi = lin.modal_system(th[None])
    phi1 = np.asarray(phi)[..., 0].reshape(-1)
    ratio = abs(float(lin.fe.tip @ phi1) / float(lin.sensor @ phi1))
    order = {"displacement": 0, "velocity": 1, "acceleration": 2}[pb.trial.quantity]
    amp = feats["a1"] / om[0, 0] ** order * ratio
    X = np.array([[v[n] for n in pb.names]])
    P = pb.forward_params(X)[0]
    P[list(fwd.param_names).index("drag")] = 1.0
    P[list(fwd.param_names).index("friction")] = 1.0
    zd, zf = fwd.equivalent_damping(P[None], amp)
    w1 = 2 * np.pi * feats["f1"]
    zeta1 = feats["sigma1"] / w1
    laws = [k for k in ("gamma", "c_d", "eta") if k in v]

    def start(name: str, zeta: float, per_unit: float, scale: float) -> dict[str, float]:
        w = dict(v)
        lo, hi = pb.priors[name].bounds
        w[name] = float(np.clip(zeta / per_unit, lo * 1.01, hi * 0.99))
        for k in laws:
            klo, khi = pb.priors[k].bounds
            w[k] = float(np.clip(v[k] * scale, klo * 1.01, khi * 0.99))
        return w

    out = []
    for name, per_unit, factors in (("drag", zd[0], (0.5, 2.0)), ("friction", zf[0], (0.25, 1.0))):
        if np.isfinite(per_unit) and per_unit > 0:
            out += [start(name, fac * zeta1, per_unit, 1 / (1 + fac)) for fac in factors]
    c, c_se, s0 = feats.get("excess", 0.0), feats.get("excess_se", np.inf), feats.get("rate0", 0.0)
    if c > 2 * c_se and s0 > 0 and np.isfinite(zd[0]) and zd[0] > 0:
        out.append(start("drag", c * s0 / w1, zd[0], s0 / feats["sigma1"]))
    return out


def _root_on_ratio(pb: Any, lin: Any, v: Mapping[str, float], name: str, u_lo: float,
                   u_hi: float, target: float) -> float:
    """Value of structural parameter ``name`` at which ω2/ω1 equals ``target`` (bisection in u)."""
    prior = pb.priors[name]
    j = lin.param_names.index(name)
    row = _fwd_row(pb, lin, v)

    def miss(u: float) -> float:
        th = row.copy()
        th[j] = float(prior.from_u(u))
        om, _, _ = lin.modal_system(th[None])
        return float(om[0, 1] / om[0, 0] - target)

    return float(prior.from_u(sopt.brentq(miss, u_lo, u_hi, xtol=1e-10, maxiter=60)))


def _set_damping(pb: Any, lin: Any, v: dict[str, float], feats: Mapping[str, float]) -> None:
    """Damping coefficients that reproduce the measured decay rates of modes 1 and 2.

    The decay rate of mode n is about half the diagonal modal damping, σ_n ≈ C_nn/2,
    and C is linear in the coefficients: non-negative least squares on σ1, σ2.
    """
    laws = [law for law in pb.model.laws]
    sig = [feats[k] for k in ("sigma1", "sigma2") if k in feats]
    if not sig:
        return
    cols = []
    for law in laws:
        w = dict(v)
        for other in ("gamma", "c_d", "eta"):
            if other in w:
                w[other] = 0.0
        key = {"viscous": "gamma", "kv": "c_d", "sh": "eta"}[law]
        w[key] = 1.0
        _, C, _ = lin.modal_system(_fwd_row(pb, lin, w)[None])
        cols.append(0.5 * np.diag(C[0])[: len(sig)])
    A = np.array(cols).T  # (modes, laws): decay rate per unit coefficient
    coef, _ = sopt.nnls(A / np.array(sig)[:, None], np.ones(len(sig)))
    for j, law in enumerate(laws):
        key = {"viscous": "gamma", "kv": "c_d", "sh": "eta"}[law]
        lo, hi = pb.priors[key].bounds
        # A law that nnls switches off starts where it alone gives 5 % of σ1.
        c = coef[j] if coef[j] > 0 else 0.05 * sig[0] / max(A[0, j], 1e-300)
        v[key] = float(np.clip(c, lo * 1.01, hi * 0.99))


def _sample(pb: Any, u_map: np.ndarray, *, seed: int, settings: Mapping[str, Any],
            notes: list[str]) -> Any:
    """Sample with emcee from a ball around the MAP (shaped by the Laplace covariance)."""
    import emcee

    from bayesbeam import fit as fitmod
    from bayesbeam.results import FitResult, make_provenance
    from bayesbeam.sampling import NotConvergedWarning, init_walkers, run_emcee

    rng = np.random.default_rng(seed)
    ndim = pb.ndim
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # -inf stencil points on a bound
        cov = fitmod.laplace_covariance(pb, u_map)
    scale = 0.1 * np.sqrt(np.diag(cov)) if cov is not None else np.full(ndim, 1e-3)
    scale = np.clip(np.where(np.isfinite(scale), scale, 1e-3), 1e-8, 0.5)
    nwalkers = settings["nwalkers"] or max(32, 4 * ndim)
    nwalkers += nwalkers % 2
    u0 = init_walkers(pb.log_prob, u_map, nwalkers, rng=rng, scale=scale)
    t0 = time.perf_counter()
    # Differential-evolution moves mix faster on these correlated posteriors (fit.py).
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NotConvergedWarning)
        chain = run_emcee(pb.log_prob, u0, seed=seed, max_steps=int(settings["max_steps"]),
                          min_steps=int(settings["min_steps"]),
                          target_ess=float(settings["target_ess"]), names=pb.names,
                          moves=moves, progress=False)
    for w in caught:
        if issubclass(w.category, NotConvergedWarning):
            notes.append(f"{pb.model.name}: {w.message}")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    X = pb.theta(chain.samples.reshape(-1, ndim))
    derived = {k: v.reshape(chain.samples.shape[:2]) for k, v in pb.derived(X).items()}
    return FitResult(
        model=pb.model.name, chain=chain, priors=pb.priors, map_u=u_map,
        settings={"n_elements": pb.n_elements, "initial": pb.initial, "nwalkers": nwalkers,
                  "seed": seed, "total_seconds": time.perf_counter() - t0,
                  "noise": "ar1" if "rho" in pb.names else "iid", "started_from": "diagnose MAP"},
        provenance=make_provenance({"trial": pb.trial.name, "data_sha256": pb.trial.sha256,
                                    "model": pb.model.name}),
        derived=derived,
    )


def _moves(before: _State, after: _State) -> dict[str, Any]:
    """Posterior mean and sd of the physical parameters shared by two fits."""
    out = {}
    sb, sa = before.score.result.summary(), after.score.result.summary()
    for n in before.problem.model.physical_params + ("a",):
        key = "eta" if n == "a" and "eta" in sb else n
        if key in sb and key in sa:
            out[key] = {"before": [sb[key]["mean"], sb[key]["sd"]],
                        "after": [sa[key]["mean"], sa[key]["sd"]]}
    for n in after.problem.model.physical_params:
        if n in sa and n not in out:
            out[n] = {"before": [math.nan, math.nan], "after": [sa[n]["mean"], sa[n]["sd"]]}
    return out


# --------------------------------------------------------------------------- diagnose


def _valid_candidates(model: Model, candidates: Sequence[str]) -> list[str]:
    return [c for c in candidates if c not in model.parts]


def diagnose(
    trial: Trial,
    baseline: str | Model = "viscous+kv",
    *,
    seed: int = 0,
    max_rounds: int = 3,
    candidates: Sequence[str] = CATALOGUE,
    n_elements: int = 16,
    initial: str = "release",
    priors: Mapping[str, Any] | None = None,
    confirm_top: int = 3,
    nwalkers: int | None = None,
    target_ess: float = 300.0,
    min_steps: int = 200,
    max_steps: int = 2000,
    loo_draws: int = 400,
    signatures: bool = True,
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Show what the baseline gets wrong, name the causes, extend the model, measure the gain.

    See the module docstring for the procedure and its thresholds.

    Parameters
    ----------
    trial : Trial
        The record (SI units).
    baseline : str or Model
        Starting model, e.g. ``'viscous+kv'``.
    seed : int
        Seed of every random choice (starts, walkers, bridge proposals, noise draws).
    max_rounds : int
        At most this many causes are named.
    candidates : sequence of str
        Catalogue subset to try (default all of :data:`CATALOGUE`).
    n_elements : int
        Hermite elements of the forward model.
    initial : str
        Initial-condition kind (``'release'`` for synthetic release tests,
        ``'modes:K'`` for records whose window starts in free vibration).
    priors : mapping, optional
        Prior overrides (name → Prior or dict), applied to every model that has the
        parameter.
    confirm_top : int
        Screened candidates sampled per round (plus ties within 3 nats).
    nwalkers, target_ess, min_steps, max_steps : optional
        emcee budget per sampled model (see :func:`bayesbeam.sampling.run_emcee`).
    loo_draws : int
        Posterior draws for PSIS-LOO.
    signatures : bool
        Compute the residual signatures of the baseline and the final model.
    progress : callable, optional
        Called with one line of text per step (e.g. ``print``).

    Returns
    -------
    Diagnosis

    Raises
    ------
    DiagnoseError
        For an unknown cause, an invalid round limit or a model that cannot be fitted.
    """
    t_start = time.perf_counter()
    model = parse_model(baseline)
    unknown = [c for c in candidates if c not in CATALOGUE]
    if unknown:
        raise DiagnoseError(f"unknown cause(s) {unknown}; the catalogue is {list(CATALOGUE)}")
    if isinstance(max_rounds, bool) or not isinstance(max_rounds, int) or max_rounds < 1:
        raise DiagnoseError(f"max_rounds must be an int >= 1, got {max_rounds!r}")
    if not isinstance(trial, Trial):
        raise DiagnoseError("trial must be a bayesbeam Trial (see bayesbeam.trial.read_trial)")
    log = progress or (lambda s: None)
    notes: list[str] = []
    eng = _Engine(trial, seed=seed, n_elements=n_elements, initial=initial, priors=priors,
                  sampler={"nwalkers": nwalkers, "target_ess": target_ess,
                           "min_steps": min_steps, "max_steps": max_steps,
                           "loo_draws": loo_draws},
                  notes=notes, log=log)
    cur = eng.state(model)
    eng.optimise(cur, eng.starts(cur, None))
    log(f"baseline {model.name}: max log L = {cur.ll:.2f}")
    first = cur
    rounds: list[Round] = []
    final_check: Round | None = None
    for k in range(1, max_rounds + 1):
        rnd = _round(eng, cur, k, candidates, confirm_top, log)
        if rnd.cause == "none":
            final_check = rnd
            break
        rounds.append(rnd)
        cur = eng.states[rnd.model_after]
    sig_before = sig_after = None
    if signatures:
        sig_before = eng.signatures(first)
        sig_after = eng.signatures(cur)
    fits = {name: st.score.result for name, st in eng.states.items() if st.score is not None}
    return Diagnosis(
        trial=trial.name, baseline=model.name, final_model=cur.problem.model.name,
        named_causes=tuple(r.cause for r in rounds), rounds=tuple(rounds),
        final_check=final_check,
        thresholds={"significance": SIGNIFICANCE, "screen": SCREEN_THRESHOLD,
                    "screen_tie": SCREEN_TIE, "tie": TIE},
        signatures_before=sig_before, signatures_after=sig_after, fits=fits,
        notes=tuple(dict.fromkeys(notes)), seconds=time.perf_counter() - t_start,
    )


def _round(eng: _Engine, cur: _State, index: int, candidates: Sequence[str],
           confirm_top: int, log: Callable[[str], None]) -> Round:
    from bayesbeam.criteria import CriteriaError, elpd_difference

    t_round = time.perf_counter()
    model = cur.problem.model
    scores: dict[str, dict[str, Any]] = {}
    # 1. Screen.
    for cause in _valid_candidates(model, candidates):
        t0 = time.perf_counter()
        ext = model.extend(cause)
        try:
            st = eng.state(ext)
        except (ImportError, ValueError) as err:
            # e.g. the nonlinear forward model or a default prior is not available.
            eng.notes.append(f"candidate {cause} not tried: {err}")
            scores[cause] = {"model": ext.name, "gain": math.nan, "note": str(err)}
            continue
        eng.optimise(st, eng.starts(st, cur.x))
        scores[cause] = {"model": ext.name, "gain": st.ll - cur.ll, "note": "",
                         "seconds": time.perf_counter() - t0}
        log(f"  round {index} screen {cause}: Δχ²/2 = {st.ll - cur.ll:.2f} "
            f"({time.perf_counter() - t0:.1f} s)")
    passing = [c for c, s in scores.items() if s["gain"] > SCREEN_THRESHOLD]
    # A better optimum of the current model found from a candidate's MAP replaces its MAP.
    if passing:
        warm = [[eng.states[scores[c]["model"]].x.get(n, cur.x[n]) for n in cur.problem.names]
                for c in passing]
        before = cur.ll
        eng.optimise(cur, np.array(warm))
        if cur.ll > before + 1e-6:
            log(f"  current model improved by {cur.ll - before:.2f} from candidate MAPs")
            cur.score = cur.sig = None
            for s in scores.values():
                if math.isfinite(s["gain"]):
                    s["gain"] -= cur.ll - before
            passing = [c for c, s in scores.items() if s["gain"] > SCREEN_THRESHOLD]
    # Laplace Δ for the record.
    eng.laplace(cur)
    for s in scores.values():
        if math.isfinite(s["gain"]):
            st = eng.states[s["model"]]
            eng.laplace(st)
            s["laplace"] = st.laplace - cur.laplace
    # 2. Confirm.
    ranked = sorted(passing, key=lambda c: -scores[c]["gain"])
    if ranked:
        best_gain = scores[ranked[0]]["gain"]
        chosen = [c for i, c in enumerate(ranked)
                  if i < confirm_top or scores[c]["gain"] > best_gain - SCREEN_TIE]
        sc_cur = eng.confirm(cur)
        for c in chosen:
            st = eng.states[scores[c]["model"]]
            sc = eng.confirm(st)
            d = sc.log_evidence - sc_cur.log_evidence
            err = math.hypot(sc.log_evidence_err, sc_cur.log_evidence_err)
            try:
                de, dse = elpd_difference(sc.loo, sc_cur.loo)
            except CriteriaError as e:
                eng.notes.append(f"Δ ELPD of {c} not computed: {e}")
                de, dse = math.nan, math.nan
            scores[c].update(confirmed=True, delta=d, err=err, elpd=de, elpd_se=dse,
                             significant=bool(d - 2 * err > SIGNIFICANCE))
            if math.isfinite(de) and d - 2 * err > SIGNIFICANCE and de < -2 * dse:
                eng.notes.append(
                    f"round {index}: {c} raises the evidence by {d:.1f} nats but lowers ELPD by "
                    f"{-de:.1f} ± {dse:.1f}; check the LOO notes (Pareto k) of both models")
    cand = tuple(
        CandidateScore(
            cause=c, model=s["model"], delta_chi2_half=float(s["gain"]),
            laplace_delta=float(s.get("laplace", math.nan)),
            confirmed=bool(s.get("confirmed", False)),
            delta_log_evidence=float(s.get("delta", math.nan)),
            delta_log_evidence_err=float(s.get("err", math.nan)),
            delta_elpd=float(s.get("elpd", math.nan)),
            delta_elpd_se=float(s.get("elpd_se", math.nan)),
            significant=bool(s.get("significant", False)),
            n_params=(eng.states[s["model"]].problem.ndim if s["model"] in eng.states else 0),
            seconds=float(s.get("seconds", 0.0)), note=s["note"],
        )
        for c, s in scores.items()
    )
    sig = [c for c in cand if c.significant]
    if not sig:
        return Round(index=index, model_before=model.name, model_after=model.name,
                     cause="none", candidates=cand, seconds=time.perf_counter() - t_round)
    # 3. Decide: best evidence, its equivalents, parsimony among them.
    best = max(sig, key=lambda c: c.delta_log_evidence)
    sc_b = eng.states[best.model].score

    def tied(c: CandidateScore) -> bool:
        sc_c = eng.states[c.model].score
        band = max(2 * math.hypot(sc_b.log_evidence_err, sc_c.log_evidence_err), TIE)
        return best.delta_log_evidence - c.delta_log_evidence <= band

    group = [c for c in sig if tied(c)]
    named = min(group, key=lambda c: (c.n_params, -c.delta_log_evidence))
    equivalent = tuple(c.cause for c in group if c is not named)
    after = eng.states[named.model]
    sig_cur = eng.signatures(cur)
    agrees, text = signature_support(named.cause, sig_cur)
    sig_after = eng.signatures(after)
    log(f"  round {index}: named {named.cause} (Δ log Z = {named.delta_log_evidence:.1f} ± "
        f"{named.delta_log_evidence_err:.1f}); equivalent {list(equivalent)}")
    return Round(
        index=index, model_before=model.name, model_after=named.model, cause=named.cause,
        equivalent=equivalent, delta_log_evidence=named.delta_log_evidence,
        delta_log_evidence_err=named.delta_log_evidence_err, delta_elpd=named.delta_elpd,
        delta_elpd_se=named.delta_elpd_se, rms_before=sig_cur.rms_residual,
        rms_after=sig_after.rms_residual, coverage_before=sig_cur.coverage90,
        coverage_after=sig_after.coverage90, parameter_moves=_moves(cur, after),
        signature=text, signature_agrees=agrees, candidates=cand,
        seconds=time.perf_counter() - t_round,
    )

