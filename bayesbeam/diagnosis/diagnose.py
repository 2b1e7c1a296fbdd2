"""Name the cause of a model discrepancy from a catalogue, extend the model, measure the gain.

:func:`diagnose` starts from a baseline model (e.g. ``viscous+kv``) and, round by
round, tries every extension of the catalogue (:data:`CATALOGUE`) that the current
model lacks:

========================  ===========================================================
cause                     model extension (parameters)
========================  ===========================================================
``kv``, ``sh``            an internal damping law (``c_d``; ``eta``, ``b``)
``tip_mass``              concentrated tip mass (``tip_mass``, kg)
``added_mass``            a point mass anywhere on the span (``added_mass``, kg, at
                          ``added_mass_position``, m from the clamp): sensors, cables, glue
``root_spring``           rotational clamp compliance (``root_spring``, N m/rad)
``stiffness_gradient``    EI(x) ∝ 1 + g (x/L - 1/2) (``stiffness_gradient``)
``drag``                  quadratic air drag (``drag``, kg/m²): damping grows with amplitude
``friction``              dry clamp friction on mode 1 (``friction``, N): damping grows as
                          the amplitude falls
``amplitude_stiffness``   f1 moving with the mode-1 tip amplitude (``f1_slope``, Hz/m;
                          reported in Hz per mm; negative: softening)
``sensor_quadratic``      a sensor reading y + k2 y² (``k2``, per signal unit): lines
                          at twice the modes' frequencies, in phase with y²
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
   from the data's modal estimates (:func:`bayesbeam.trials.modal_id.damped_sinusoids`):
   a structural parameter solved so that the model's f2/f1 equals the measured one,
   E so that f1 matches, the damping coefficients from the measured decay rates of
   modes 1 and 2 (non-negative least squares on σ_n ≈ C_nn/2), and the drag (or the
   friction, whichever the candidate adds) at 0.25-2 times the measured ζ1
   (:meth:`~bayesbeam.physics.nonlinear.NonlinearForward.equivalent_damping` at the
   measured first-mode amplitude). ``drag`` and ``friction`` are separate candidates,
   each tried on its own in every round, so one candidate never adds both. The
   statistic is the
   gain in maximum log-likelihood ``Δχ²/2 = max log L(M+X) - max log L(M)``; the
   Laplace Δ log Z (:func:`bayesbeam.stats.evidence.laplace_evidence`) is recorded where
   both MAPs are interior. Adding a parameter multiplies the evidence by its Occam
   factor (≤ 1), so Δ log Z ≲ Δχ²/2: a candidate with ``Δχ²/2 <= SCREEN_THRESHOLD``
   (2 nats, 1 nat below the significance threshold for safety) cannot be
   significant and is not sampled. The MAPs of the passing candidates also restart
   the optimisation of M (a better optimum of M found this way replaces its MAP, so
   that a poor local optimum of M cannot make every extension look good; M is sampled
   again only if its chains never came near the better optimum, :func:`_chains_reached`).
2. **Confirm** (expensive): emcee from the MAP (walkers in a ball shaped by the
   Laplace covariance, differential-evolution moves), then bridge-sampling evidence
   with its Monte-Carlo error and PSIS-LOO (:func:`bayesbeam.comparison.scoring.evaluate`) for M
   and for the ``confirm_top`` best-screened candidates (plus any other within
   ``SCREEN_TIE`` = 3 nats of the best screen value), leaving out those screened more
   than ``CONFIRM_WINDOW`` = 50 nats behind the best (:func:`to_confirm`): such a
   candidate could beat the best only if the two Occam factors differed by more than
   that, and they differed by at most 18 nats (screen minus Δ log Z) over the whole
   records of the eleven-record study. It is screened again in the next round.
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
   mode-1 decay rate vs amplitude for ``drag`` (faster at large amplitude) and
   ``friction`` (faster at small amplitude), f1 against amplitude beyond the model's for
   ``amplitude_stiffness``, the residual's projection on the square of the model's
   signal for ``sensor_quadratic``, Ljung–Box whiteness and lag-1
   autocorrelation for ``ar1_noise``, mean / low-frequency residual for
   ``sensor_offset``, frequency dependence of the modal damping for ``kv``/``sh``.
5. **Measure the gain**: Δ log Z ± err, Δ ELPD ± se, RMS residual and 90 %
   predictive coverage before and after, and how the physical parameters moved
   (posterior mean ± sd before and after).

Then M ← M+X and the next round starts, up to ``max_rounds`` (default 3).

Cost: each screen is one MAP search (0.2-2 s for a 512-sample record and 8 elements
on one core; 5-15 s with drag or friction, whose forward model is ~5x slower); each
confirmation one emcee run plus bridge sampling (5-20 s at the test budget of 400
steps x 24 walkers). A round costs about 8 screens and 2-4 confirmations.

What separates the structural causes (a uniform 0.4 m strip, 32 elements; a point mass
of 8 % of the beam mass): a mass at the tip moves f2/f1 by +3 % and f3/f1 by +5 %, the
same mass at 0.85 L by +8 % and +9 %, at 0.5 L by -5 % and +2 % (f2/f1 rises when the
mass sits near mode 2's node, ~0.78 L, falls near its antinode); a root spring raises
f2/f1 by only ~0.3 % for a 4 % drop of f1, a stiffness gradient moves all ratios
smoothly. So f2/f1 alone leaves a curve of (position, mass) pairs, one of them at the
tip; f3/f1 and the modal amplitudes at the sensor (a mass near a mode's node hardly
changes that mode) pick the position. Where the record holds only two modes the data
cannot tell an inboard mass from a heavier tip mass: the diagnosis then names the one
with fewer parameters (``tip_mass``) and lists ``added_mass`` as equivalent. An added
mass at x = L is a tip mass, so a model holding one is never extended by the other.

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

The records returned (:class:`Diagnosis`, :class:`Round`, :class:`CandidateScore`)
are defined in :mod:`bayesbeam.diagnosis.records` and re-exported here.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import distribution_version, progress_bar, progress_note

# The records (and the text of the signatures, which their narrative uses) are re-exported.
from bayesbeam.diagnosis.records import CandidateScore, Diagnosis, Round
from bayesbeam.diagnosis.resume import StepStore

# DiagnoseError is defined with the search machinery (which raises it) and re-exported.
from bayesbeam.diagnosis.search import DiagnoseError, _Engine, _State
from bayesbeam.inference.settings import DIAGNOSIS_DEFAULTS
from bayesbeam.physics.models import LAWS, STRUCTURAL, Model, parse_model
from bayesbeam.trials.trial import Trial

__all__ = [
    "CATALOGUE",
    "SCREEN_THRESHOLD",
    "CONFIRM_WINDOW",
    "SIGNIFICANCE",
    "TIE",
    "diagnose",
    "signature_support",
]

#: The catalogue of causes, in the order they are tried (names are model parts).
CATALOGUE: tuple[str, ...] = (
    "kv", "sh", "tip_mass", "added_mass", "root_spring", "stiffness_gradient", "drag",
    "friction", "amplitude_stiffness", "sensor_quadratic", "ar1_noise", "sensor_offset",
)
#: A cause is significant when Δ log Z - 2 err exceeds this (nats; Bayes factor > 20).
SIGNIFICANCE = 3.0
#: Screening: candidates whose max-log-likelihood gain does not exceed this are dropped.
SCREEN_THRESHOLD = 2.0
#: Candidates within this many nats of the best screen value are confirmed too.
SCREEN_TIE = 3.0
#: Candidates screened more than this many nats behind the best are not confirmed.
CONFIRM_WINDOW = 50.0
#: Candidates are separated only when one's evidence beats the other's by more than
#: max(2 err, TIE) nats: the same strength (Bayes factor > 20) that significance needs.
TIE = 3.0


# --------------------------------------------------------------------------- signatures


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
               "uniform strip a point mass of 8 % of the beam mass moves it by -5 % at 0.5 L, "
               "+8 % at 0.85 L and +3 % at the tip (f3/f1 by +2, +9 and +5 %), a root "
               "spring lowering f1 by 4 % raises it by only ~0.3 %, a stiffness falling 30 % "
               "toward the tip lowers it by ~3.5 %")
        big = abs(s) > 2 * e
        if cause in ("stiffness_gradient", "added_mass"):
            # An inboard mass lowers f1 more than f2 near mode 2's node (~0.78 L) and f2
            # more than f1 near its antinode (~0.47 L): either sign.
            return big, txt
        return bool(big and s > 0), txt
    if cause in ("drag", "friction"):
        d, e = sig.decay_excess_diff, sig.decay_excess_diff_err
        if not (math.isfinite(d) and e < 1.0):
            return None, ("decay rate vs amplitude not measurable on this record (the "
                          "amplitude falls too little, or mode 1 is too weak)")
        # Drag damps more at large amplitude (excess > 0), friction more at small (< 0).
        agrees = d > 2 * e if cause == "drag" else d < -2 * e
        way = ("faster at large amplitude, as drag would make it" if d > 0
               else "faster at small amplitude, as friction would make it")
        want = ("drag needs it significantly positive (faster at large amplitude)"
                if cause == "drag" else
                "friction needs it significantly negative (faster at small amplitude)")
        return bool(agrees), (
            "mode-1 decay rate vs amplitude beyond the model: its excess at the initial "
            f"amplitude is {100 * d:+.0f} ± {100 * e:.0f} % of the small-amplitude rate, "
            f"{way}; {want}")
    if cause == "amplitude_stiffness":
        d = sig.amplitude_trends.get("data") or {}
        m = sig.amplitude_trends.get("model") or {}
        keys = ("f1_hz_per_mm", "f1_hz_per_mm_se")
        vals = [d.get(k, math.nan) for k in keys] + [m.get(k, math.nan) for k in keys]
        if not all(math.isfinite(x) for x in vals):
            return None, ("f1 against amplitude not measurable on this record (fewer than "
                          "three windows, or mode 1 too weak)")
        diff, err = vals[0] - vals[2], math.hypot(vals[1], vals[3])
        way = "falls" if diff < 0 else "rises"
        return bool(abs(diff) > 2 * err), (
            f"f1 {way} with the mode-1 tip amplitude by {1e3 * diff:+.3g} ± {1e3 * err:.2g} "
            "mHz per mm beyond the model (falls: softening, rises: hardening)")
    if cause == "sensor_quadratic":
        k2, se = sig.quadratic_k2, sig.quadratic_k2_se
        if not (math.isfinite(k2) and math.isfinite(se)):
            return None, "residual against the square of the signal not measurable"
        return bool(abs(k2) > 2 * se), (
            f"residual against the square of the model's signal: k2 = {k2:.3g} ± {se:.2g} "
            "per signal unit (a quadratic sensor, y + k2 y², leaves lines at twice the "
            "modes' frequencies in phase with y² and a mean shift)")
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


#: Causes that contain each other: an added mass at x = L is a tip mass, so a model
#: holding one is never extended by the other (the pair would be unidentifiable).
_NESTED = {"tip_mass": "added_mass", "added_mass": "tip_mass"}


def _valid_candidates(model: Model, candidates: Sequence[str]) -> list[str]:
    return [c for c in candidates
            if c not in model.parts and _NESTED.get(c) not in model.parts]


def diagnose(
    trial: Trial,
    baseline: str | Model = "viscous+kv",
    *,
    seed: int = 0,
    max_rounds: int = 3,
    candidates: Sequence[str] = CATALOGUE,
    n_elements: int = DIAGNOSIS_DEFAULTS.n_elements,
    refine_mesh: bool = DIAGNOSIS_DEFAULTS.refine_mesh,
    initial: str = DIAGNOSIS_DEFAULTS.initial,
    priors: Mapping[str, Any] | None = None,
    confirm_top: int = 3,
    nwalkers: int | None = DIAGNOSIS_DEFAULTS.nwalkers,
    target_ess: float = DIAGNOSIS_DEFAULTS.target_ess,
    min_steps: int = DIAGNOSIS_DEFAULTS.min_steps,
    max_steps: int = DIAGNOSIS_DEFAULTS.max_steps,
    loo_draws: int = 400,
    signatures: bool = True,
    progress: Callable[[str], None] | None = None,
    executor: Any = None,
    steps_dir: str | Path | None = None,
    resume: bool = False,
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
        Hermite elements of the forward model: the starting mesh.
    refine_mesh : bool
        Refine the mesh at the baseline's MAP until its prediction converges
        (:func:`bayesbeam.inference.mesh.converge_mesh`), check it again at the MAP of
        the model after every named round (refining where it no longer passes), and use
        the current mesh for every model of a round; the records are in the notes.
    initial : str
        Initial-condition kind (``'release'`` for synthetic release tests,
        ``'modes:K'`` for records whose window starts in free vibration).
    priors : mapping, optional
        Prior overrides (name → Prior or dict), applied to every model that has the
        parameter.
    confirm_top : int
        Screened candidates sampled per round (plus ties within 3 nats).
    nwalkers, target_ess, min_steps, max_steps : optional
        emcee budget per sampled model (defaults:
        :data:`bayesbeam.inference.settings.DIAGNOSIS_DEFAULTS`; see
        :func:`bayesbeam.stats.sampling.run_emcee`).
    loo_draws : int
        Posterior draws for PSIS-LOO.
    signatures : bool
        Compute the residual signatures of the baseline and the final model.
    progress : callable, optional
        Called with one line of text per step (e.g. ``print``); given, each round's
        screen and sampling also show a progress bar on stderr
        (:func:`bayesbeam._util.progress_bar`: the stage, the model done last, tqdm's
        time estimate).
    executor : concurrent.futures.Executor, optional
        Any object with the ``map`` method of :class:`concurrent.futures.Executor`
        (``bayesbeam.jobs.executor.make_executor`` makes one: local processes or a Dask
        cluster). Each round's candidate MAP searches, and its sampling runs, then run
        in parallel; each job carries the trial's data, its model, starts and seed, so
        the diagnosis is bitwise the serial one. None: everything in this process.
    steps_dir : path, optional
        Folder where each finished step (a MAP search, a Laplace evidence, a sampled
        and scored model) is written as it arrives
        (:class:`~bayesbeam.diagnosis.resume.StepStore`); emptied first unless
        ``resume``. None: nothing is kept.
    resume : bool
        Take the steps found in ``steps_dir`` instead of computing them again (an
        interrupted diagnosis resumed with the same record and settings gives the
        uninterrupted result; ``max_rounds`` and ``candidates`` may differ).

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
        raise DiagnoseError("trial must be a bayesbeam Trial (see bayesbeam.trials.io.read_trial)")
    if resume and steps_dir is None:
        raise DiagnoseError("resume=True needs steps_dir, the folder of the interrupted "
                            "run's steps")
    log = progress or (lambda s: None)
    notes: list[str] = []
    sampler = {"nwalkers": nwalkers, "target_ess": target_ess, "min_steps": min_steps,
               "max_steps": max_steps, "loo_draws": loo_draws}
    store = None
    if steps_dir is not None:
        store = StepStore(steps_dir, {
            "version": distribution_version("bayesbeam"), "data_sha256": trial.sha256, "seed": seed,
            "initial": initial, "refine_mesh": bool(refine_mesh), "sampler": sampler,
            "priors": {k: str(v) for k, v in sorted((priors or {}).items())},
        }, read=resume)
    eng = _Engine(trial, seed=seed, n_elements=n_elements, initial=initial, priors=priors,
                  sampler=sampler, notes=notes, log=log, store=store)
    cur = eng.state(model)
    eng.optimise(cur, eng.starts(cur, None), executor)
    if refine_mesh:
        cur = _converged_mesh(eng, cur, "mesh", log, refine=True)
    log(f"baseline {model.name}: max log L = {cur.ll:.2f}")
    first = cur
    rounds: list[Round] = []
    final_check: Round | None = None
    interrupted = None
    try:
        for k in range(1, max_rounds + 1):
            rnd = _round(eng, cur, k, candidates, confirm_top, log, executor,
                         show=progress is not None)
            if rnd.cause == "none":
                final_check = rnd
                break
            rounds.append(rnd)
            cur = eng.states[rnd.model_after]
            if refine_mesh:
                # A refinement needs the current model sampled again: only where a
                # round follows.
                cur = _converged_mesh(eng, cur, f"mesh after round {k}", log,
                                      refine=k < max_rounds)
    except KeyboardInterrupt:
        # Ctrl-C: the complete rounds are kept (minutes each on a whole record); with
        # none complete there is nothing to keep.
        if not rounds:
            raise
        interrupted = (f"interrupted in round {len(rounds) + 1} after {len(rounds)} "
                       "complete round(s)")
        log(f"{interrupted}; keeping them")  # cur: the model after the last complete one
    sig_before = sig_after = None
    if signatures and interrupted is None:
        sig_before = eng.signatures(first)
        sig_after = eng.signatures(cur)
    fits = {name: st.score.result for name, st in eng.states.items() if st.score is not None}
    if store is not None and store.hits:
        notes.append(f"resumed: {store.hits} finished step(s) taken from {store.folder}")
    return Diagnosis(
        trial=trial.name, baseline=model.name, final_model=cur.problem.model.name,
        named_causes=tuple(r.cause for r in rounds), rounds=tuple(rounds),
        final_check=final_check,
        thresholds={"significance": SIGNIFICANCE, "screen": SCREEN_THRESHOLD,
                    "screen_tie": SCREEN_TIE, "confirm_window": CONFIRM_WINDOW, "tie": TIE},
        signatures_before=sig_before, signatures_after=sig_after, fits=fits,
        notes=tuple(dict.fromkeys(notes)), seconds=time.perf_counter() - t_start,
        interrupted=interrupted,
    )


def _converged_mesh(eng: _Engine, cur: _State, label: str, log: Callable[[str], None], *,
                    refine: bool) -> _State:
    """Check the mesh at the current model's MAP; refine it (for every later model) if needed.

    One mesh serves every model of a round (so that no cause is named to absorb mesh
    error), converged at the MAP (:func:`bayesbeam.inference.mesh.converge_mesh`). The
    check is against the fitted noise: |Δ log L| <= 1 nat and |Δy| <= 0.1 σ. A baseline
    far from the data has a large σ and residual, so its mesh can pass that check and
    fail it once a named cause brings the residual down to the noise: on a synthetic
    acceleration record from a 32-element mesh with an EI gradient, the 8-element mesh
    passed at the uniform baseline (RMS residual 15.3, 40x the noise) and, unrechecked,
    the next round named a 1.7 ± 2.1 g point mass 3 cm from the clamp (Δ log Z 36) to
    absorb the mesh's error in f3. So the check is repeated after every named round;
    on refinement the current model is re-optimised on the finer mesh, and sampled
    again in the next round (its score on the coarse mesh is dropped). With ``refine``
    False (no round follows) the check is only reported.

    A resumable run keeps the check's outcome as a step (kind ``"mesh"``, keyed by the
    model, its mesh and MAP to the last bit): a resumed run takes it instead of
    evaluating the finer meshes again.
    """
    from bayesbeam.inference.fit import local_map
    from bayesbeam.inference.mesh import converge_mesh

    key = eng._key(cur, u=cur.u, refine=refine)
    hit = eng._recall("mesh", key)
    if hit is None:
        pb, u, _, mesh = converge_mesh(
            cur.problem, cur.u, cur.ll, local_map, refine=refine, progress=log,
            kept_because="(the final model: no round followed to refine it; raise "
                         "max_rounds)")
        hit = (pb.n_elements, u, mesh)
        eng._keep("mesh", key, hit)
    else:
        log(f"mesh: {hit[2]['summary']} (taken from the interrupted run's steps)")
    n_elements, u, mesh = hit
    eng.notes.append(f"{label}: {mesh['summary']}")
    if n_elements == eng.n_elements:
        return cur
    model = cur.problem.model
    eng.n_elements = n_elements
    del eng.states[model.name]
    new = eng.state(model)
    eng.optimise(new, new.problem.theta(u[None]))
    return new


def to_confirm(gains: Mapping[str, float], confirm_top: int) -> list[str]:
    """Return the screened candidates to sample, best screen first.

    Parameters
    ----------
    gains : mapping of str to float
        Each passing candidate's screen gain Δχ²/2 (nats).
    confirm_top : int
        How many of the best-screened candidates to sample at most, besides those
        within ``SCREEN_TIE`` of the best.

    Returns
    -------
    list of str
        The ``confirm_top`` best and any within ``SCREEN_TIE`` of the best, all within
        ``CONFIRM_WINDOW`` of it. ``Δ log Z = Δχ²/2 - (o_X - o_M)`` with ``o`` the log
        Occam factor (``max log L - log Z``), so a candidate ``D`` nats behind the best
        beats it only if their Occam factors differ by more than ``D`` (or its search
        stopped ``D`` short); sampling it costs as much as the best's confirmation
        (minutes on a whole record, most of a round's time).
    """
    ranked = sorted(gains, key=lambda c: -gains[c])
    if not ranked:
        return []
    best = gains[ranked[0]]
    return [c for i, c in enumerate(ranked)
            if (i < confirm_top or gains[c] > best - SCREEN_TIE)
            and gains[c] >= best - CONFIRM_WINDOW]


def _chains_reached(st: _State) -> bool:
    """Whether a sampled model's chains already visited its (newly improved) MAP.

    A better MAP found from a candidate's optimum only invalidates the model's sampled
    score (evidence, LOO, signatures) when the chains never came near it. Near a mode in
    d dimensions a posterior draw lies ``χ²_d / 2`` below it (Laplace), so a chain that
    sampled the mode's basin has drawn, with probability 1 - 0.99^ESS (95 % at the
    diagnosis's ESS of 300), at least one point within the 1 % quantile
    ``χ²_d(0.01) / 2`` of it (1.8 nats for d = 12). If the highest log posterior visited
    is that close to the new MAP's, the sample already holds the mode and sampling again
    would repeat it (measured on Al 50 cm #0: a MAP 34.5 nats better, re-sampled to the
    same log Z within 0.01 nat, 98 s); otherwise the model is sampled again.
    """
    from scipy.stats import chi2

    if st.score is None:
        return False
    lp = np.asarray(st.score.result.chain.log_prob, dtype=float)
    if not lp.size or not np.isfinite(lp).any():
        return False
    gap = 0.5 * float(chi2.ppf(0.01, st.problem.ndim))
    return bool(np.nanmax(lp) >= st.lp - gap)


def _round(eng: _Engine, cur: _State, index: int, candidates: Sequence[str],
           confirm_top: int, log: Callable[[str], None], executor: Any = None,
           show: bool = False) -> Round:
    from bayesbeam.stats.criteria import CriteriaError, elpd_difference

    t_round = time.perf_counter()
    model = cur.problem.model
    scores: dict[str, dict[str, Any]] = {}
    # 1. Screen (the candidates' MAP searches are independent: through the executor).
    screened: list[tuple[str, Any]] = []
    for cause in _valid_candidates(model, candidates):
        ext = model.extend(cause)
        try:
            st = eng.state(ext)
        except (ImportError, ValueError) as err:
            # e.g. the nonlinear forward model or a default prior is not available.
            eng.notes.append(f"candidate {cause} not tried: {err}")
            scores[cause] = {"model": ext.name, "gain": math.nan, "note": str(err)}
            continue
        scores[cause] = {"model": ext.name, "gain": math.nan, "note": ""}  # keeps the order
        screened.append((cause, st))

    bar = progress_bar(len(screened), f"diagnose round {index}: MAP screen", unit="model",
                       enabled=show)

    def screened_one(i: int, seconds: float) -> None:
        cause, st = screened[i]
        scores[cause].update(gain=st.ll - cur.ll, seconds=seconds)
        log(f"  round {index} screen {cause}: Δχ²/2 = {st.ll - cur.ll:.2f} ({seconds:.1f} s)")
        progress_note(bar, f"{st.problem.model.name} done")
        bar.update(1)

    pairs = [(st, eng.starts(st, cur.x)) for _, st in screened]
    for st, _ in pairs:
        eng.embed(st, cur.x)
    try:
        eng.optimise_many(pairs, executor, on_done=screened_one)
    finally:
        bar.close()
    for cause, _ in screened:
        if scores[cause]["gain"] < -SCREEN_THRESHOLD:
            # The search started from the current MAP (Engine.embed): a loss means that
            # no value in the prior's support nests the current model.
            scores[cause]["note"] = (
                f"screened {-scores[cause]['gain']:.1f} nats below the current model: even its "
                "most neutral prior value changes the prediction (e.g. the smallest mass "
                "the prior allows shifts the frequencies) and no start did better")
    passing = [c for c, s in scores.items() if s["gain"] > SCREEN_THRESHOLD]
    # A better optimum of the current model found from a candidate's MAP replaces its MAP.
    if passing:
        warm = [[eng.states[scores[c]["model"]].x.get(n, cur.x[n]) for n in cur.problem.names]
                for c in passing]
        before = cur.ll
        eng.optimise(cur, np.array(warm), executor)
        if cur.ll > before + 1e-6:
            log(f"  current model improved by {cur.ll - before:.2f} from candidate MAPs")
            if not _chains_reached(cur):
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
    chosen = to_confirm({c: scores[c]["gain"] for c in passing}, confirm_top)
    if chosen:
        best_gain = scores[chosen[0]]["gain"]
        for c in passing:
            if c not in chosen:
                scores[c]["note"] = (
                    f"not sampled: screened {best_gain - scores[c]['gain']:.1f} nats behind "
                    f"{chosen[0]} (beyond the {confirm_top} best or the "
                    f"{CONFIRM_WINDOW:g}-nat window)")
        # The sampling runs are independent: through the executor (seeds in this order).
        sampled = [cur] + [eng.states[scores[c]["model"]] for c in chosen]
        bar = progress_bar(sum(st.score is None for st in sampled),
                           f"diagnose round {index}: sampling", unit="model", enabled=show)

        def sampled_one(st: _State) -> None:
            progress_note(bar, f"{st.problem.model.name} done")
            bar.update(1)

        try:
            eng.confirm_many(sampled, executor, on_done=sampled_one)
        finally:
            bar.close()
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
