"""Search machinery of :func:`bayesbeam.diagnosis.diagnose.diagnose`: MAPs, starts, sampling.

:class:`_Engine` fits, caches and scores the models of one trial, one :class:`_State`
per model (problem, MAP, Laplace log evidence, sampled score, residual signatures):

* **MAP search** (:meth:`_Engine.optimise`): an E scan, then from each start the
  search of ``bayesbeam fit`` (:func:`~bayesbeam.inference.optimum.local_map`: scaled
  L-BFGS-B passes in the sampler's coordinates) and Newton polishing of the best
  (:func:`~bayesbeam.inference.optimum.newton_polish`); after sampling, a chain point
  above the MAP replaces it (:meth:`_Engine._scored`);
* **start points** (:meth:`_Engine.starts`): the current MAP with the new parameters
  at neutral values (:func:`~bayesbeam.inference.starts.neutral_value`), and
  physics-based starts from the data's modal estimates
  (:func:`~bayesbeam.inference.starts.physics_starts`: a structural parameter solved for
  the measured f2/f1, a point mass along the f2/f1 curve, E for f1, damping
  coefficients for the measured decay rates, drag or friction for the measured ζ1);
* **confirmation** (:meth:`_Engine.confirm`): emcee from the MAP in the sampler's
  coordinates (:func:`_sample`,
  :func:`~bayesbeam.inference.coordinates.sample_in_coordinates`), then bridge-sampling
  evidence and PSIS-LOO (:func:`bayesbeam.comparison.scoring.evaluate`).

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

from bayesbeam.diagnosis.resume import StepStore
from bayesbeam.inference.coordinates import PREBURN_STEPS, SamplerCoordinates, sample_in_coordinates
from bayesbeam.inference.optimum import SCREEN_POLISHED, best_map, chain_map
from bayesbeam.inference.parallel import ParallelLogProb
from bayesbeam.inference.settings import DIAGNOSIS_STOPPING
from bayesbeam.inference.starts import data_features, neutral_value, physics_starts
from bayesbeam.physics.models import Model
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
    laplace_u: np.ndarray | None = None  # where ``laplace`` was computed
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
                 notes: list[str], log: Callable[[str], None],
                 store: StepStore | None = None) -> None:
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
        # Finished steps on disk (a resumable run); their keys hash the inputs below.
        self.store = store

    def _key(self, st: _State, **inputs: Any) -> str | None:
        """Key of a step of ``st`` in :attr:`store` (None without one)."""
        if self.store is None:
            return None
        return self.store.key(model=st.problem.model.name,
                              n_elements=st.problem.n_elements, **inputs)

    def _recall(self, kind: str, key: str | None) -> Any:
        return None if key is None else self.store.get(kind, key)

    def _keep(self, kind: str, key: str | None, value: Any) -> None:
        if key is not None:
            self.store.put(kind, key, value)

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
            self._features = data_features(self.trial)
        return self._features

    def optimise(self, st: _State, starts: np.ndarray, executor: Any = None) -> None:
        """Improve the MAP of ``st`` from physical start points (rows of ``starts``).

        ``executor`` (anything with ``map``, e.g. a process pool) runs the local searches
        from the starts side by side; the result is the same.
        """
        from bayesbeam.inference import fit as fitmod

        key = self._key(st, starts=np.asarray(starts, dtype=float), u=st.u, lp=st.lp)
        hit = self._recall("map", key)
        if hit is not None:
            st.u, st.lp, st.ll = hit
            return
        pb = st.problem
        X = fitmod.clip_to_prior(pb, np.atleast_2d(starts))
        # Each start as it is and after an E scan (which profiles the amplitudes on every
        # row of its grid by least squares and sets sigma to the RMS residual). The scan
        # finds the phase of mode 1 for a start whose E is off; for a start built on the
        # current MAP it is harmful where the least-squares criterion is not the
        # likelihood (AR(1) noise, amplitude-dependent models): on Al 30 cm #0, round 3,
        # the drag start at half the measured ζ1 went from +466 nats to -2102 by the
        # scan, and its search from there ended at -1342; unscanned, the search and
        # polish reached +4201, the mode the chains found.
        X = np.vstack([X, fitmod.scan_E(pb, X)])
        U = pb.priors.to_u(X)
        if st.u is not None:
            # The current MAP (Engine.embed) is usually the first row itself: once.
            U = np.array([st.u] + [u for u in U if not np.array_equal(u, st.u)])
        # The search of `bayesbeam fit` (optimum.best_map: scaled L-BFGS-B passes in the
        # sampler's coordinates from each start, the best Newton-polished, here only the
        # best SCREEN_POLISHED: on a whole record each polish costs tens of seconds, a
        # screen's MAP only ranks the candidates, and the one sampled gets its chains'
        # best point); the current MAP is among the starts, and local_map never returns
        # below its start.
        mapper = None
        if executor is not None and len(U) > 1:
            def mapper(fn: Callable[[Any], Any], rows: Any) -> Any:
                return executor.map(_guarded_call, [(fn, r) for r in rows])
        u, v = best_map(pb, U, polished=SCREEN_POLISHED, mapper=mapper)
        if u is not None and v > st.lp:
            st.u, st.lp = u, v
        if st.u is None or not np.isfinite(st.lp):
            raise DiagnoseError(f"no start of model {pb.model.name!r} has a finite posterior "
                                "density; check the trial's units and the priors")
        st.ll = float(pb.log_likelihood(st.u[None])[0])
        self._keep("map", key, (st.u, st.lp, st.ll))

    def laplace(self, st: _State) -> None:
        """Laplace log evidence at the state's MAP, once per MAP.

        Recorded beside the screen (not used to decide); NaN where it does not apply.
        """
        from bayesbeam.stats.evidence import EvidenceError, laplace_evidence

        if st.laplace_u is not None and np.array_equal(st.laplace_u, st.u):
            return
        key = self._key(st, u=st.u)
        hit = self._recall("laplace", key)
        if hit is not None:
            st.laplace, st.laplace_u = hit, np.array(st.u, copy=True)
            return
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # inf - inf on a bound: reported
            try:
                st.laplace = laplace_evidence(st.problem.log_prob, st.u).log_z
            except EvidenceError:
                # MAP on a prior bound, or -H not (numerically) positive definite:
                # Laplace is not applicable, recorded NaN.
                st.laplace = math.nan
        st.laplace_u = np.array(st.u, copy=True)
        self._keep("laplace", key, st.laplace)

    def embed(self, st: _State, warm: Mapping[str, float]) -> None:
        """Take the current MAP, new parameters at neutral values, as ``st``'s MAP if better.

        :meth:`optimise` refines every physical start by an E scan, which re-profiles
        the amplitudes and resets the noise scale; on a whole record that moved the
        current model's own MAP (as a candidate's start) tens to hundreds of nats down,
        from where the search did not climb back, so that a candidate that nests the
        current model screened below it (friction -225, drag -97 nats on Al 30 cm #0).
        Held as the state's MAP, the point is a start as it is, and
        :func:`~bayesbeam.inference.optimum.local_map` never returns below its start: a
        candidate whose neutral values do nothing screens at >= 0.
        """
        from bayesbeam.inference.fit import clip_to_prior

        pb = st.problem
        u = pb.priors.to_u(clip_to_prior(pb, np.array([_warm_row(pb, warm)])))
        lp = float(pb.log_prob(u)[0])
        if np.isfinite(lp) and lp > st.lp:
            st.u, st.lp = u[0], lp
            st.ll = float(pb.log_likelihood(u)[0])

    def starts(self, st: _State, warm: Mapping[str, float] | None) -> np.ndarray:
        """Physical start points: warm (current MAP + neutral new values) and physics-based."""
        pb = st.problem
        names = list(pb.names)
        neutral = {n: neutral_value(pb, n) for n in names}
        rows = []
        if warm:
            rows.append(_warm_row(pb, warm))
        else:
            # No MAP yet (the baseline): also fit()'s first start, the record's damping
            # shared evenly among the laws (deterministic). The decay-rate starts alone can
            # put the baseline on the wrong side of the viscous/KV ridge: on Al 50 cm #0
            # they stopped 414 nats below the mode this start finds.
            from bayesbeam.inference.fit import _start_points

            rows.extend(_start_points(pb, np.random.default_rng(self.seed), 1))
        rows.extend(physics_starts(pb, self.features(), warm or {}, neutral))
        return np.array(rows, dtype=float)

    def config(self) -> dict[str, Any]:
        """Return what rebuilds this engine's problems elsewhere (plain, picklable data)."""
        return {"seed": self.seed, "n_elements": self.n_elements, "initial": self.initial,
                "priors": self.priors, "sampler": self.sampler}

    def optimise_many(self, pairs: Sequence[tuple[_State, np.ndarray]], executor: Any,
                      on_done: Callable[[int, float], None] | None = None) -> None:
        """:meth:`optimise` several states from their starts, then :meth:`laplace` each.

        Each state's MAP search depends on its problem, its starts and its current MAP
        only (no random numbers), so a worker that rebuilds the problem from
        :meth:`config` finds bitwise the MAP (and the Laplace evidence) this process
        would. The Laplace evidence is computed in the same job because its stencil
        costs a search's worth on a whole record (~600 points per Hessian pass at 17
        parameters) and, in this process after the screen, left the other cores idle.

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
                seconds = time.perf_counter() - t0
                self.laplace(st)
                if on_done is not None:
                    on_done(i, seconds)
            return
        # Steps finished by an interrupted run (a store): taken, not sent out again.
        keys = [self._key(st, starts=np.asarray(starts, dtype=float), u=st.u, lp=st.lp)
                for st, starts in pairs]
        todo = []
        for i, (st, _) in enumerate(pairs):
            hit = self._recall("map", keys[i])
            if hit is None:
                todo.append(i)
                continue
            st.u, st.lp, st.ll = hit
            self.laplace(st)
            if on_done is not None:
                on_done(i, 0.0)
        jobs = [{"trial": self.trial, "engine": self.config(), "model": pairs[i][0].problem.model,
                 "n_elements": pairs[i][0].problem.n_elements, "starts": pairs[i][1],
                 "u": pairs[i][0].u, "lp": pairs[i][0].lp} for i in todo]
        for i, (u, lp, ll, laplace, seconds) in zip(todo, executor.map(_optimise_job, jobs),
                                                    strict=True):
            st = pairs[i][0]
            st.u, st.lp, st.ll = u, lp, ll
            st.laplace, st.laplace_u = laplace, np.array(u, copy=True)
            self._keep("map", keys[i], (u, lp, ll))
            self._keep("laplace", self._key(st, u=u), laplace)
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
            # A lone run leaves the executor's cores idle: share its batches with one
            # helper process (inference.parallel; the same values, bit for bit).
            for st in todo:
                self.confirm(st, helpers=0 if executor is None else 1)
                if on_done is not None:
                    on_done(st)
            return
        jobs, keys, hits = [], [], []
        for st in todo:
            self._k += 1
            seed = int(self.seed) * 1000 + self._k
            keys.append(self._key(st, u=st.u, seed=seed))
            hits.append(self._recall("fit", keys[-1]))
            if hits[-1] is None:
                jobs.append({"trial": self.trial, "engine": self.config(),
                             "model": st.problem.model, "n_elements": st.problem.n_elements,
                             "u": st.u, "seed": seed})
        results = iter(executor.map(_confirm_job, jobs)) if jobs else iter(())
        # In the order given, stored or computed alike: the notes and log lines of a
        # resumed run are the uninterrupted run's.
        for st, key, hit in zip(todo, keys, hits, strict=True):
            if hit is None:
                hit = next(results)
                self._keep("fit", key, hit)
            self._scored(st, *hit)
            if on_done is not None:
                on_done(st)

    # -- sampling and scoring ---------------------------------------------------------
    def confirm(self, st: _State, helpers: int = 0) -> Any:
        """Sample from the MAP and score (bridge evidence, LOO); cached.

        ``helpers`` processes share the sampler's batches
        (:class:`~bayesbeam.inference.parallel.ParallelLogProb`).
        """
        if st.score is not None:
            return st.score
        t0 = time.perf_counter()
        self._k += 1
        seed = int(self.seed) * 1000 + self._k
        key = self._key(st, u=st.u, seed=seed)
        hit = self._recall("fit", key)
        if hit is None:
            notes: list[str] = []
            score = self._sample_and_score(st, seed, notes, helpers=helpers)
            hit = (score, notes, time.perf_counter() - t0)
            self._keep("fit", key, hit)
        self._scored(st, *hit)
        return st.score

    def _sample_and_score(self, st: _State, seed: int, notes: list[str],
                          helpers: int = 0) -> Any:
        from bayesbeam.comparison.scoring import evaluate

        # One set of helper processes for the chains and then the bridge's 10,000
        # proposal draws and Laplace's stencil.
        with ParallelLogProb(st.problem.log_prob, helpers=helpers) as shared:
            res = _sample(st.problem, st.u, seed=seed, settings=self.sampler, notes=notes,
                          log_prob=shared)
            return evaluate(self.trial, st.problem.model, seed=seed, result=res,
                            problem=st.problem, n_loo_draws=int(self.sampler["loo_draws"]),
                            log_prob=shared)

    def _scored(self, st: _State, score: Any, notes: Sequence[str], seconds: float) -> None:
        """Record a state's score: its notes (sampler's, then the score's), time, log line.

        The chains are an optimiser too: where they visited a point above the MAP (on
        whole records the search can stop hundreds of nats short, on a ridge where one
        damping law trades against another), that point, Newton-polished, becomes the
        state's MAP, so that the next round's candidates start from it and their gains
        are measured against it.
        """
        st.score = score
        self.notes.extend(notes)
        for n in score.notes:
            self.notes.append(f"{st.problem.model.name}: {n}")
        st.seconds += seconds
        self.log(f"  sampled {st.problem.model.name}: log Z = {score.log_evidence:.2f} ± "
                 f"{score.log_evidence_err:.2f}, elpd = {score.loo.elpd_loo:.1f} "
                 f"({seconds:.0f} s)")
        chain = score.result.chain
        pb = st.problem
        u, v = chain_map(pb, chain.flat_samples, chain.flat_log_prob, st.u, st.lp)
        if v > st.lp:
            self.log(f"  {pb.model.name}: MAP moved {v - st.lp:.2f} up, to the chains' best "
                     "point (polished)")
            st.u, st.lp = u, v
            st.ll = float(pb.log_likelihood(u[None])[0])

    def signatures(self, st: _State) -> Any:
        if st.sig is None:
            from bayesbeam.diagnosis.signatures import compute_signatures

            st.sig = compute_signatures(st.problem, self.confirm(st).result, seed=self.seed)
        return st.sig


def _warm_row(pb: Any, warm: Mapping[str, float]) -> list[float]:
    """Return the current MAP ``warm`` with ``pb``'s new parameters neutral (physical)."""
    return [warm[n] if n in warm else neutral_value(pb, n) for n in pb.names]


def _worker_state(job: Mapping[str, Any]) -> tuple[_Engine, _State]:
    """Rebuild, in a worker, the engine and the state of one model (see ``_Engine.config``)."""
    cfg = dict(job["engine"])
    cfg["n_elements"] = int(job["n_elements"])  # the state's own mesh
    eng = _Engine(job["trial"], notes=[], log=_silent, **cfg)
    st = eng.state(job["model"])
    st.u = None if job["u"] is None else np.array(job["u"], dtype=float)
    return eng, st


def _guarded_call(item: tuple[Callable[[Any], Any], Any]) -> Any:
    """Call ``fn(arg)`` for ``item = (fn, arg)``, an executor job (one BLAS thread)."""
    from bayesbeam._util import job_guard

    fn, arg = item
    with job_guard():
        return fn(arg)


def _silent(line: str) -> None:
    """Log of a worker's engine: its lines are the caller's to write."""


def _optimise_job(job: Mapping[str, Any]
                  ) -> tuple[np.ndarray | None, float, float, float, float]:
    """Improve one model's MAP from its starts and take its Laplace evidence there.

    An executor job of :meth:`_Engine.optimise_many`.

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
    laplace : float
        Laplace log evidence at ``u`` (:meth:`_Engine.laplace`; NaN where it does not
        apply).
    seconds : float
        Wall-clock time of the search (the Laplace evidence not included).
    """
    from bayesbeam._util import job_guard

    t0 = time.perf_counter()
    with job_guard():
        eng, st = _worker_state(job)
        st.lp = float(job["lp"])
        eng.optimise(st, job["starts"])
        seconds = time.perf_counter() - t0
        eng.laplace(st)
    return st.u, st.lp, st.ll, st.laplace, seconds


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


def _sample(pb: Any, u_map: np.ndarray, *, seed: int, settings: Mapping[str, Any],
            notes: list[str], log_prob: Any = None) -> Any:
    """Sample with emcee from a ball around the MAP (:func:`~.fit.walker_scale`).

    The ensemble moves in the coordinates of :class:`~.fit.SamplerCoordinates`, as in
    :func:`~.fit.fit`: the damping laws' log total first-mode damping and log ratios,
    where the viscous/KV trade-off that a record fixes only in total is a straight
    valley instead of a curved one (unit Jacobian: the density is unchanged).
    ``log_prob`` is ``pb.log_prob`` as the chains evaluate it (default itself), e.g. a
    :class:`~bayesbeam.inference.parallel.ParallelLogProb` whose helper processes share
    each batch. The chain stops by
    :data:`~bayesbeam.inference.settings.DIAGNOSIS_STOPPING` (20 τ, τ settled to 5 %;
    a full fit: 50 τ, 2 %), where the diagnosis's ESS target is met several times over.
    """
    from bayesbeam.inference import fit as fitmod
    from bayesbeam.inference.results import FitResult, make_provenance
    from bayesbeam.inference.settings import walker_count
    from bayesbeam.stats.sampling import NotConvergedWarning, init_walkers

    rng = np.random.default_rng(seed)
    ndim = pb.ndim
    nwalkers = walker_count(settings["nwalkers"], ndim)
    log_prob = pb.log_prob if log_prob is None else log_prob
    u0 = init_walkers(log_prob, u_map, nwalkers, rng=rng,
                      scale=fitmod.walker_scale(pb, u_map))
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NotConvergedWarning)
        chain = sample_in_coordinates(
            log_prob, SamplerCoordinates(pb, at=u_map), u0, seed=seed,
            max_steps=int(settings["max_steps"]), min_steps=int(settings["min_steps"]),
            target_ess=float(settings["target_ess"]), names=pb.names, progress=False,
            **DIAGNOSIS_STOPPING,
            # As in fit(): a discarded first run returns stranded walkers.
            preburn=min(PREBURN_STEPS, int(settings["max_steps"]) // 4))
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
                  **DIAGNOSIS_STOPPING,
                  "noise": "ar1" if "rho" in pb.names else "iid", "started_from": "diagnose MAP"},
        provenance=make_provenance({"trial": pb.trial.name, "data_sha256": pb.trial.sha256,
                                    "model": pb.model.name}),
        derived=derived,
    )
