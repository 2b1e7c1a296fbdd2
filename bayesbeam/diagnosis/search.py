"""Search machinery of :func:`bayesbeam.diagnosis.diagnose.diagnose`: MAPs, starts, sampling.

:class:`_Engine` fits, caches and scores the models of one trial, one :class:`_State`
per model (problem, MAP, Laplace log evidence, sampled score, residual signatures):

* **MAP search** (:meth:`_Engine.optimise`): an E scan, L-BFGS-B restarts with a
  finite-difference gradient (:func:`~bayesbeam.stats.numdiff.fd_gradient`, one-sided on
  a prior bound), then damped Newton steps with a finite-difference Hessian
  (:func:`_newton_polish`), since L-BFGS-B alone stops several nats short on these
  narrow curved ridges;
* **start points** (:meth:`_Engine.starts`): the current MAP with the new parameters
  at neutral values (:func:`_neutral`), and physics-based starts from the data's modal
  estimates (:mod:`bayesbeam.trials.modal_id`): a structural parameter solved for the measured
  f2/f1 (:func:`_root_on_ratio`), E for f1, damping coefficients for the measured
  decay rates (:func:`_set_damping`), drag or friction for the measured ζ1
  (:func:`_amplitude_starts`);
* **confirmation** (:meth:`_Engine.confirm`): emcee from the MAP (:func:`_sample`)
  then bridge-sampling evidence and PSIS-LOO (:func:`bayesbeam.comparison.scoring.evaluate`).

The procedure, thresholds and records are in :mod:`bayesbeam.diagnosis.diagnose`, which
re-exports :class:`DiagnoseError` (defined here so that this module need not import
it back).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize as sopt

from bayesbeam.physics.models import Model
from bayesbeam.stats.numdiff import fd_gradient, fd_hessian
from bayesbeam.trials.trial import Trial

__all__ = ["DiagnoseError"]

class DiagnoseError(ValueError):
    """Invalid input to :func:`~bayesbeam.diagnosis.diagnose.diagnose`; the message says the fix."""


# --------------------------------------------------------------------------- engine


@dataclass
class _State:
    """Everything known about one model: problem, MAP, fit, score."""

    problem: Any
    u: np.ndarray | None = None
    lp: float = -math.inf
    ll: float = -math.inf
    laplace: float = math.nan
    score: Any = None  # scoring.ModelScore
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
        from bayesbeam.inference.problem import Problem

        if model.name not in self.states:
            pb = Problem(self.trial, model, n_elements=self.n_elements, initial=self.initial)
            pri = {k: v for k, v in self.priors.items() if k in pb.names}
            if pri:
                pb = Problem(self.trial, model, pri, n_elements=self.n_elements,
                             initial=self.initial)
            self.states[model.name] = _State(pb)
        return self.states[model.name]

    def features(self) -> dict[str, float]:
        """Measured f1, f2 (f3) and decay rates of the data (for physics-based starts)."""
        if self._features is None:
            from bayesbeam.inference.problem import record_f1
            from bayesbeam.trials.modal_id import (
                damped_sinusoids,
                decay_rate_vs_amplitude,
                periodogram,
                spectral_peak,
            )

            t, y = self.trial.times, self.trial.values
            f1 = record_f1(self.trial)
            nyq = 0.5 / float(np.median(np.diff(t)))
            f, amp = periodogram(t, y)
            guesses = [f1]
            # The modes the preprocessing saw on the raw stamps, where it ran; else the
            # spectrum near the uniform-cantilever ratios f2/f1 = 6.267, f3/f1 = 17.55
            # (physics.md §4).
            seen = self.trial.meta.get("modes_seen_hz") or {}
            for k, ratio in ((2, 6.267), (3, 17.55)):
                g = seen.get(str(k)) or spectral_peak(f, amp, f1 * ratio, rel_window=0.15)
                if g is None or g > 0.8 * nyq:
                    break
                guesses.append(float(g))
            est = damped_sinusoids(t, y, guesses)
            feats: dict[str, float] = {"f1": f1}
            for k, e in enumerate(est[:2], start=1):
                if e is not None:
                    feats[f"f{k}"] = e.frequency
                    feats[f"a{k}"] = e.amplitude
                    if e.decay_rate > 0:
                        feats[f"sigma{k}"] = e.decay_rate
            if len(est) > 2 and est[2] is not None and "f2" in feats:
                feats["f3"] = est[2].frequency  # places an added mass along the span
            if est[0] is None:
                feats.pop("f2", None)  # a ratio needs both
                feats.pop("f3", None)
            else:
                # Amplitude dependence of the first mode's decay (starts for drag).
                dva = decay_rate_vs_amplitude(t, y, est[0].frequency,
                                              other=[est[0].frequency * r for r in (6.267, 17.55)])
                if dva is not None and np.isfinite(dva.excess_se):
                    feats.update(excess=dva.excess, excess_se=dva.excess_se, rate0=dva.rate0)
                feats.update(_frequency_slope(self.trial, est[0].frequency))
            self._features = feats
        return self._features

    def optimise(self, st: _State, starts: np.ndarray) -> None:
        """Improve the MAP of ``st`` from physical start points (rows of ``starts``)."""
        from bayesbeam.inference import fit as fitmod

        pb = st.problem
        X = fitmod.clip_to_prior(pb, np.atleast_2d(starts))
        X = fitmod.scan_E(pb, fitmod.profile_linear(pb, X))
        U = pb.priors.to_u(X)
        if st.u is not None:
            U = np.vstack([st.u[None], U])
        bounds = [(lo + 1e-9, hi - 1e-9) if np.isfinite(lo) and np.isfinite(hi) else (None, None)
                  for lo, hi in pb.priors.bounds_u]

        def negf(u: np.ndarray) -> tuple[float, np.ndarray]:
            # One-sided on a prior bound (e.g. rho = 0): a central difference would be
            # infinite there and the optimiser would never leave the bound.
            v, g = fd_gradient(pb.log_prob, u, 1e-6, one_sided=True)
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
        from bayesbeam.stats.evidence import EvidenceError, laplace_evidence

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
            if "added_mass" in new:
                v = dict(base)
                for other in struct:
                    v[other] = neutral[other]
                variants += _added_mass_starts(pb, lin, v, feats)
        rows = []
        for v in variants:
            th = _fwd_row(pb, lin, v)
            om, _, _ = lin.modal_system(th[None])
            E = v["E"] * (2 * np.pi * feats["f1"] / om[0, 0]) ** 2
            v["E"] = float(np.clip(E, *pb.priors["E"].bounds))
            _set_damping(pb, lin, v, feats)
            rows.append([v[n] for n in names])
        # Starts for whichever amplitude-dependent damping the candidate adds (drag and
        # friction are separate candidates; a model fitted from scratch may have both).
        amp_new = tuple(n for n in ("drag", "friction") if n in new)
        if amp_new and "a1" in feats and "sigma1" in feats:
            v0 = variants[0] if variants else base
            rows += [[v[n] for n in names]
                     for v in _amplitude_starts(pb, lin, v0, feats, amp_new)]
        if "f1_slope" in new and "f1_slope" in feats:
            # The data's f1 against the mode-1 tip amplitude (sliding windows), and half.
            v0 = variants[0] if variants else base
            lo, hi = pb.priors["f1_slope"].bounds
            for fac in (1.0, 0.5):
                w = dict(v0)
                w["f1_slope"] = float(np.clip(fac * feats["f1_slope"], 0.99 * lo, 0.99 * hi))
                rows.append([w[n] for n in names])
        return rows

    # -- many models at once (an executor) ---------------------------------------------
    def config(self) -> dict[str, Any]:
        """Return what rebuilds this engine's problems elsewhere (plain, picklable data)."""
        return {"seed": self.seed, "n_elements": self.n_elements, "initial": self.initial,
                "priors": self.priors, "sampler": self.sampler}

    def optimise_many(self, pairs: Sequence[tuple[_State, np.ndarray]], executor: Any,
                      on_done: Callable[[int, float], None] | None = None) -> None:
        """:meth:`optimise` several states from their starts, through ``executor``.

        Each state's MAP search depends on its problem, its starts and its current MAP
        only (no random numbers), so a worker that rebuilds the problem from
        :meth:`config` finds bitwise the MAP this process would.

        Parameters
        ----------
        pairs : sequence of (_State, ndarray)
            States and their physical start points, shape (S, ndim).
        executor : concurrent.futures.Executor or None
            Anything with ``map``; None: one after another here.
        on_done : callable, optional
            ``on_done(index, seconds)`` in the order of ``pairs`` as each is done.
        """
        if executor is None or len(pairs) < 2:
            for i, (st, starts) in enumerate(pairs):
                t0 = time.perf_counter()
                self.optimise(st, starts)
                if on_done is not None:
                    on_done(i, time.perf_counter() - t0)
            return
        jobs = [{"trial": self.trial, "engine": self.config(), "model": st.problem.model,
                 "n_elements": st.problem.n_elements, "starts": starts, "u": st.u,
                 "lp": st.lp} for st, starts in pairs]
        for i, (u, lp, ll, seconds) in enumerate(executor.map(_optimise_job, jobs)):
            st = pairs[i][0]
            st.u, st.lp, st.ll = u, lp, ll
            if on_done is not None:
                on_done(i, seconds)

    def confirm_many(self, states: Sequence[_State], executor: Any,
                     on_done: Callable[[_State], None] | None = None) -> None:
        """:meth:`confirm` several states (in this order), through ``executor``.

        Seeds are handed out in the order given, as consecutive :meth:`confirm` calls
        would, and notes and log lines follow that order: the result is the serial one.
        ``on_done(state)`` is called as each state not yet sampled is, in that order.
        """
        todo: list[_State] = []
        for st in states:  # once each (by identity: a state is a mutable record)
            if st.score is None and not any(st is t for t in todo):
                todo.append(st)
        if executor is None or len(todo) < 2:
            for st in todo:
                self.confirm(st)
                if on_done is not None:
                    on_done(st)
            return
        jobs = []
        for st in todo:
            self._k += 1
            jobs.append({"trial": self.trial, "engine": self.config(),
                         "model": st.problem.model, "n_elements": st.problem.n_elements,
                         "u": st.u, "seed": int(self.seed) * 1000 + self._k})
        for st, (score, notes, seconds) in zip(todo, executor.map(_confirm_job, jobs),
                                               strict=True):
            self._scored(st, score, notes, seconds)
            if on_done is not None:
                on_done(st)

    # -- sampling and scoring ---------------------------------------------------------
    def confirm(self, st: _State) -> Any:
        """Sample from the MAP and score (bridge evidence, LOO); cached."""
        if st.score is not None:
            return st.score
        t0 = time.perf_counter()
        self._k += 1
        notes: list[str] = []
        score = self._sample_and_score(st, int(self.seed) * 1000 + self._k, notes)
        self._scored(st, score, notes, time.perf_counter() - t0)
        return st.score

    def _sample_and_score(self, st: _State, seed: int, notes: list[str]) -> Any:
        from bayesbeam.comparison.scoring import evaluate

        res = _sample(st.problem, st.u, seed=seed, settings=self.sampler, notes=notes)
        return evaluate(self.trial, st.problem.model, seed=seed, result=res,
                        problem=st.problem, n_loo_draws=int(self.sampler["loo_draws"]))

    def _scored(self, st: _State, score: Any, notes: Sequence[str], seconds: float) -> None:
        """Record a state's score: its notes (sampler's, then the score's), time, log line."""
        st.score = score
        self.notes.extend(notes)
        for n in score.notes:
            self.notes.append(f"{st.problem.model.name}: {n}")
        st.seconds += seconds
        self.log(f"  sampled {st.problem.model.name}: log Z = {score.log_evidence:.2f} ± "
                 f"{score.log_evidence_err:.2f}, elpd = {score.loo.elpd_loo:.1f} "
                 f"({seconds:.0f} s)")

    def signatures(self, st: _State) -> Any:
        if st.sig is None:
            from bayesbeam.diagnosis.signatures import compute_signatures

            st.sig = compute_signatures(st.problem, self.confirm(st).result, seed=self.seed)
        return st.sig


def _worker_state(job: Mapping[str, Any]) -> tuple[_Engine, _State]:
    """Rebuild, in a worker, the engine and the state of one model (see ``_Engine.config``)."""
    cfg = dict(job["engine"])
    cfg["n_elements"] = int(job["n_elements"])  # the state's own mesh
    eng = _Engine(job["trial"], notes=[], log=_silent, **cfg)
    st = eng.state(job["model"])
    st.u = None if job["u"] is None else np.array(job["u"], dtype=float)
    return eng, st


def _silent(line: str) -> None:
    """Log of a worker's engine: its lines are the caller's to write."""


def _optimise_job(job: Mapping[str, Any]) -> tuple[np.ndarray | None, float, float, float]:
    """Improve one model's MAP from its starts (an executor job of :meth:`_Engine.optimise_many`).

    Parameters
    ----------
    job : mapping
        ``trial`` (the Trial itself), ``engine`` (:meth:`_Engine.config`), ``model``,
        ``n_elements``, ``starts`` (physical start points, shape (S, ndim)), ``u`` and
        ``lp`` (the current MAP in sampling space and its log posterior, or None, -inf).

    Returns
    -------
    u : ndarray, shape (ndim,)
    lp, ll : float
        Log posterior and log-likelihood at ``u``.
    seconds : float
        Wall-clock time of the search.
    """
    from bayesbeam._util import job_guard

    t0 = time.perf_counter()
    with job_guard():
        eng, st = _worker_state(job)
        st.lp = float(job["lp"])
        eng.optimise(st, job["starts"])
    return st.u, st.lp, st.ll, time.perf_counter() - t0


def _confirm_job(job: Mapping[str, Any]) -> tuple[Any, list[str], float]:
    """Sample one model from its MAP and score it (an executor job of ``confirm_many``).

    Parameters
    ----------
    job : mapping
        ``trial``, ``engine``, ``model``, ``n_elements``, ``u`` (the MAP) and ``seed``.

    Returns
    -------
    score : bayesbeam.comparison.scoring.ModelScore
        Pickles back from a worker (its FitResult's ``__reduce__``).
    notes : list of str
        The sampler's notes (e.g. not converged).
    seconds : float
    """
    from bayesbeam._util import job_guard

    t0 = time.perf_counter()
    notes: list[str] = []
    with job_guard():
        eng, st = _worker_state(job)
        score = eng._sample_and_score(st, int(job["seed"]), notes)
    return score, notes, time.perf_counter() - t0


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
            _, g, H = fd_hessian(f, u, h)
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
    if name in ("tip_mass", "added_mass"):
        return 1.001 * lo  # even 0.3 % of the beam mass shifts f1 by ~0.6 %
    if name == "added_mass_position":
        return 0.5 * L  # with a neutral mass the position hardly matters
    if np.isfinite(lo) and lo > 0:
        # Damping coefficients, drag, friction: the prior's lower end (even that is not
        # quite neutral: KV at ζ1 = 1e-6 still damps the highest FE modes visibly in an
        # acceleration record).
        return 1.001 * lo
    return float(np.clip(0.0, lo, hi))


def _linear_forward(pb: Any) -> Any:
    """Return the linear forward model of a problem (the linear part of a nonlinear one)."""
    from bayesbeam.physics.forward import Forward

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


def _frequency_slope(trial: Any, f1: float) -> dict[str, float]:
    """Return the data's change of f1 per m of mode-1 tip amplitude and its se (Hz/m), or {}.

    Sliding windows of four mode-1 periods (:func:`bayesbeam.trials.amplitude.
    amplitude_curves`), weighted slope (:func:`~bayesbeam.trials.amplitude_bins.
    amplitude_trend`, Hz per mm, converted here to SI). Empty for a record shorter than
    three windows or without a mode-1 peak.
    """
    from bayesbeam.trials.amplitude import amplitude_curves
    from bayesbeam.trials.amplitude_bins import amplitude_trend, tip_factor
    from bayesbeam.trials.modal_id import SignatureError

    t, y = trial.times, trial.values
    if not (np.isfinite(f1) and f1 > 0) or t[-1] - t[0] < 3 * 4.0 / f1:
        return {}
    try:
        c = amplitude_curves(t, y, f1=f1, n_modes=1, quantity=trial.quantity,
                             tip_factor=tip_factor(trial.beam))
    except SignatureError:
        return {}
    slope, se, n = amplitude_trend(c.amplitude_m, c.frequency[:, 0], c.frequency_se[:, 0],
                                   hop=c.hop_s, window=c.window_s)
    if not (np.isfinite(slope) and np.isfinite(se)) or n < 3:
        return {}
    return {"f1_slope": 1e3 * slope, "f1_slope_se": 1e3 * se}  # Hz/mm -> Hz/m


def _amplitude_starts(pb: Any, lin: Any, v: Mapping[str, float],
                      feats: Mapping[str, float],
                      which: Sequence[str] = ("drag", "friction")) -> list[dict[str, float]]:
    """Return starts whose drag or friction damps mode 1 about as much as the data show.

    The tip amplitude of mode 1 comes from its measured amplitude at the sensor
    (divided by ω1 per time derivative, scaled by the mode shape's tip/sensor ratio);
    :meth:`bayesbeam.physics.nonlinear.NonlinearForward.equivalent_damping` converts it to
    the damping ratio per unit drag and per unit friction. Starts: drag alone giving
    0.5 and 2 times the measured ζ1, friction alone 0.25 and 1 times it, each with the
    linear damping coefficients scaled by 1/(1 + factor) so that the total stays near
    the measured one (a linear fit has already absorbed the amplitude-dependent part);
    and, when the data's decay rate changes with amplitude beyond 2 standard errors
    (:func:`bayesbeam.trials.modal_id.decay_rate_vs_amplitude`: rate σ0 (1 + c) at the first
    sample), drag giving c σ0/ω1 with the linear damping giving σ0.

    Parameters
    ----------
    pb : Problem
        A problem whose model has ``drag`` or ``friction`` (otherwise no starts).
    lin : Forward
        Its linear part.
    v : mapping
        Sampled values (SI units) the starts are built from.
    feats : mapping
        The data's modal estimates (:meth:`_Engine.features`): ``f1`` (Hz), ``a1``
        (sensor units), ``sigma1`` (1/s), optionally ``excess``, ``excess_se``, ``rate0``.
    which : sequence of str
        The parameters to start (``drag``, ``friction``); those the model lacks are
        skipped.

    Returns
    -------
    list of dict
        Start points, name → value.
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
    which = [n for n in which if n in fwd.param_names]
    if not which:
        return []
    for n in ("drag", "friction"):
        if n in fwd.param_names:
            P[list(fwd.param_names).index(n)] = 1.0
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
        if name in which and np.isfinite(per_unit) and per_unit > 0:
            out += [start(name, fac * zeta1, per_unit, 1 / (1 + fac)) for fac in factors]
    c, c_se, s0 = feats.get("excess", 0.0), feats.get("excess_se", np.inf), feats.get("rate0", 0.0)
    if "drag" in which and c > 2 * c_se and s0 > 0 and np.isfinite(zd[0]) and zd[0] > 0:
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


def _added_mass_starts(pb: Any, lin: Any, v: Mapping[str, float],
                       feats: Mapping[str, float], n_keep: int = 3) -> list[dict[str, float]]:
    """Return starts for a point mass anywhere on the span from the measured f2/f1 and f3/f1.

    At each of 15 positions from 0.3 L to the tip the mass that gives the measured f2/f1
    is solved for (where the prior's range brackets it; a mass near mode 2's node, about
    0.78 L, lowers f1 and hardly f2, one near 0.5 L lowers f2 more than f1, so f2/f1
    alone leaves a curve of (position, mass) pairs). Where f3 was measured, the pairs
    whose f3/f1 is closest to it are kept; otherwise ``n_keep + 1`` pairs spread along
    the curve (the likelihood, whose phase over the record depends on every frequency,
    is multimodal along it).
    """
    if "f2" not in feats:
        return []
    L = pb.trial.beam.length
    prior = pb.priors["added_mass"]
    jm, jx = lin.param_names.index("added_mass"), lin.param_names.index("added_mass_position")
    lo, hi = prior.bounds_u
    grid_u = np.linspace(lo, hi, 41)[1:-1]
    positions = L * np.linspace(0.3, 1.0, 15)
    row = _fwd_row(pb, lin, v)
    th = np.repeat(row[None], positions.size * grid_u.size, axis=0)
    th[:, jx] = np.repeat(positions, grid_u.size)
    th[:, jm] = np.tile(prior.from_u(grid_u), positions.size)
    om, _, _ = lin.modal_system(th)
    target = feats["f2"] / feats["f1"]
    miss = (om[:, 1] / om[:, 0] - target).reshape(positions.size, grid_u.size)
    found = []
    for k, x in enumerate(positions):
        sign = np.flatnonzero(miss[k, :-1] * miss[k, 1:] < 0)
        if sign.size == 0:
            continue
        i = int(sign[0])  # the smallest mass that matches: the least disturbing start
        w = {**v, "added_mass_position": float(x)}
        w["added_mass"] = _root_on_ratio(pb, lin, w, "added_mass", grid_u[i], grid_u[i + 1],
                                         target)
        found.append(w)
    if not found:
        return []
    if "f3" in feats and om.shape[1] > 2:
        th = np.array([_fwd_row(pb, lin, w) for w in found])
        o, _, _ = lin.modal_system(th)
        score = np.abs(o[:, 2] / o[:, 0] - feats["f3"] / feats["f1"])
        return [found[i] for i in np.argsort(score)[:n_keep]]
    idx = np.unique(np.linspace(0, len(found) - 1, n_keep + 1).round().astype(int))
    return [found[i] for i in idx]


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
    """Sample with emcee from a ball around the MAP (:func:`~.fit.walker_scale`)."""
    from bayesbeam.inference import fit as fitmod
    from bayesbeam.inference.results import FitResult, make_provenance
    from bayesbeam.inference.settings import walker_count
    from bayesbeam.stats.sampling import NotConvergedWarning, de_moves, init_walkers, run_emcee

    rng = np.random.default_rng(seed)
    ndim = pb.ndim
    nwalkers = walker_count(settings["nwalkers"], ndim)
    u0 = init_walkers(pb.log_prob, u_map, nwalkers, rng=rng,
                      scale=fitmod.walker_scale(pb, u_map))
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NotConvergedWarning)
        chain = run_emcee(pb.log_prob, u0, seed=seed, max_steps=int(settings["max_steps"]),
                          min_steps=int(settings["min_steps"]),
                          target_ess=float(settings["target_ess"]), names=pb.names,
                          moves=de_moves(), progress=False,
                          # As in fit(): a discarded first run returns stranded walkers.
                          preburn=min(fitmod.PREBURN_STEPS, int(settings["max_steps"]) // 4))
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
