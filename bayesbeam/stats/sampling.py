"""emcee ensemble sampling with autocorrelation-based stopping and HDF5 checkpoints.

:func:`run_emcee` runs an affine-invariant ensemble sampler (Goodman & Weare 2010,
emcee: Foreman-Mackey et al. 2013) on a *vectorised* log-probability over the
unconstrained sampling space ``u`` (see :mod:`bayesbeam.stats.priors`), in chunks of
``check_every`` steps, and stops when all of these hold after a chunk (the rule
and its estimators are in :mod:`bayesbeam.stats.convergence`):

1. the chain after burn-in is at least ``n_tau`` (default 50) integrated
   autocorrelation times long, ``n_kept >= n_tau * max(tau)`` (emcee's
   recommendation; τ of the kept part, without the walkers' spread from their start);
2. every ``tau`` changed by less than ``tau_rtol`` (relative) since the previous
   check, i.e. the estimate itself has settled;
3. the bulk effective sample size (ArviZ, rank-normalised; Vehtari et al. 2021) of
   every parameter after burn-in is at least ``target_ess``;
4. at least ``min_steps`` steps were taken.

Otherwise it stops at ``max_steps`` and issues a :class:`NotConvergedWarning` saying
which criterion failed.

Burn-in: the first ``ceil(burn_in_taus * max(tau_all))`` steps (default 3 τ of the
whole chain; capped at half the chain) are discarded; the walkers start in a small
ball around the MAP, so a few τ are enough to forget the start. Thinning (``thin``)
only reduces what is stored in the returned :class:`Chain`; τ, ESS and R-hat use every
kept step.

R-hat is the rank-normalised split R-hat with each walker taken as a chain. The
walkers of an ensemble are *not* independent chains (every move uses the other
walkers' positions), so R-hat here is a consistency check between walkers
(e.g. a stuck walker or a multimodal posterior raises it), not a proof of
convergence; it is reported, not used for stopping.

Reproducibility: emcee 3.1.6 draws from its own legacy ``RandomState``
(``EnsembleSampler.random_state``); it is seeded from ``seed`` through
``numpy.random.MT19937(seed)`` (a ``SeedSequence``), so the same seed and start
give bitwise the same chain. Checks happen at absolute step counts that are
multiples of ``check_every``, so a resumed run takes the same decisions as an
uninterrupted one.

Checkpoints: with ``backend_path`` the chain is kept in memory and mirrored to an
HDF5 file in emcee's :class:`~emcee.backends.HDFBackend` layout (see
:mod:`bayesbeam.stats.checkpoint`). New steps are written after every ``check_every``
steps, at least every ``checkpoint_seconds`` of sampling, and when the run ends or
is interrupted by an exception (Ctrl-C included). A hard kill (SIGKILL, power loss)
loses at most the unsaved steps, which ``resume=True`` recomputes identically: it
continues from the last saved step with the saved RNG state, so the resumed run
ends with the same samples as an uninterrupted one.
"""

from __future__ import annotations

import math
import signal
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import emcee
import numpy as np

from bayesbeam._util import progress_bar, stderr_is_live
from bayesbeam.stats.chain import Chain
from bayesbeam.stats.checkpoint import CheckpointBackend, SamplingError, open_checkpoint
from bayesbeam.stats.convergence import Check, check_convergence, failed_criteria, kept_tau
from bayesbeam.stats.priors import PriorSet

__all__ = [
    "Chain",
    "NotConvergedWarning",
    "init_walkers",
    "make_log_prob",
    "preburn_walkers",
    "run_emcee",
    "STRANDED_NATS",
]


class NotConvergedWarning(UserWarning):
    """The sampler stopped at its step budget before the convergence criteria held."""


class _CountingLogProb:
    """Wrap the user's vectorised log-probability: count points, validate output."""

    def __init__(self, fn: Callable[[np.ndarray], Any], ndim: int, n_calls: int = 0):
        self.fn = fn
        self.ndim = ndim
        self.n_calls = n_calls

    def __call__(self, U: np.ndarray) -> np.ndarray:
        U = np.asarray(U, dtype=float)
        self.n_calls += U.shape[0]
        out = np.asarray(self.fn(U), dtype=float)
        if out.shape != (U.shape[0],):
            raise SamplingError(
                f"log_prob must map an array of shape (k, ndim) = {U.shape} to shape "
                f"({U.shape[0]},); it returned shape {out.shape}"
            )
        bad = np.isnan(out) | (out == np.inf)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise SamplingError(
                f"log_prob returned {out[i]} at u = {U[i].tolist()}; return -inf for "
                "points outside the support or where the model is invalid"
            )
        return out


def _rng_state(seed: int) -> tuple:
    # emcee's EnsembleSampler draws from a legacy RandomState; seed its MT19937 via a
    # SeedSequence so any non-negative int works and nearby seeds are decorrelated.
    return np.random.RandomState(np.random.MT19937(seed)).get_state()


#: A walker counts as stranded when its log-probability lies this far below the
#: ensemble's median plus ``ndim / 2``: for a posterior near Gaussian, ``max - lp`` of a
#: walker in equilibrium is ``χ²_d / 2`` (median about d/2), so 25 nats beyond the median
#: has probability below 1e-10 for d <= 20. Emcee's ensemble moves cannot bring such a
#: walker back (its proposals along lines to far-away walkers are rejected), and it
#: holds the chain's τ and R-hat away from convergence for the whole run.
STRANDED_NATS = 25.0


def preburn_walkers(
    log_prob: Callable[[np.ndarray], np.ndarray],
    u0: np.ndarray,
    lp0: np.ndarray,
    steps: int,
    *,
    seed: int,
    moves: Any = None,
    block: int = 50,
) -> tuple[np.ndarray, np.ndarray]:
    """Run a discarded burn-in that puts stranded walkers back into the ensemble.

    Every ``block`` steps, walkers whose log-probability lies more than
    :data:`STRANDED_NATS` ``+ ndim/2`` below the median are moved onto the positions of
    walkers drawn from the rest (with a jitter of 1e-3 of the rest's spread); the run
    ends with a last block without resets, so the returned state is one the ensemble
    reached by its own moves. Nothing of this run is part of the posterior sample.

    Parameters
    ----------
    log_prob : callable
        Vectorised log-probability, ``(k, ndim) -> (k,)``.
    u0 : ndarray, shape (nwalkers, ndim)
    lp0 : ndarray, shape (nwalkers,)
        ``log_prob(u0)``, finite.
    steps : int
        Steps in all (at least ``2 * block``, or one block without resets).
    seed : int
        Seed of this run's random numbers (its own stream, so the recorded chain's is
        unchanged).
    moves : optional
        emcee moves.
    block : int
        Steps between checks.

    Returns
    -------
    u, lp : ndarray
        Final positions (nwalkers, ndim) and their log-probabilities (nwalkers,).
    """
    nwalkers, ndim = u0.shape
    rng = np.random.default_rng([int(seed), 0x5157])
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True, moves=moves)
    sampler.random_state = _rng_state(int(rng.integers(2**32)))
    state = emcee.State(np.array(u0, dtype=float), log_prob=np.array(lp0, dtype=float),
                        random_state=sampler.random_state)
    n_blocks = max(1, int(steps) // block)
    for k in range(n_blocks):
        state = sampler.run_mcmc(state, block, progress=False, store=False,
                                 skip_initial_state_check=k > 0)  # the start once (run_emcee)
        if k == n_blocks - 1:
            break  # the last block runs free
        lp = state.log_prob
        cut = np.median(lp) - STRANDED_NATS - ndim / 2
        bad = np.flatnonzero(lp < cut)
        good = np.flatnonzero(lp >= cut)
        if bad.size == 0 or good.size < 2:
            continue
        spread = np.std(state.coords[good], axis=0)
        src = rng.choice(good, size=bad.size)
        new = state.coords[src] + 1e-3 * spread * rng.standard_normal((bad.size, ndim))
        new_lp = np.asarray(log_prob(new), dtype=float)
        ok = np.isfinite(new_lp)
        coords, lps = state.coords.copy(), lp.copy()
        coords[bad[ok]], lps[bad[ok]] = new[ok], new_lp[ok]
        state = emcee.State(coords, log_prob=lps, random_state=state.random_state)
    return np.array(state.coords), np.array(state.log_prob)


class _Progress:
    """Progress of the sampler (:func:`bayesbeam._util.progress_bar`): stage, steps, ESS, time left.

    A tqdm bar on a terminal, a widget in Jupyter, a line every ``log_interval`` s in a
    log file. The bar counts steps up to ``max_steps``, but the run usually stops earlier,
    on the ESS target; so the time left shown is this module's own estimate, not tqdm's:
    ``elapsed × (target_ess / ess_min - 1)`` once the ESS is known (the ESS grows about
    linearly with the steps after burn-in), else the time to ``max_steps`` at the
    current pace (an upper bound, said as "at most").
    """

    def __init__(self, enabled: bool, max_steps: int, target_ess: float, label: str = "emcee",
                 log_interval: float = 10.0):
        self.enabled = enabled
        self.target_ess = target_ess
        self.max_steps = max_steps
        self.label = label
        self.log_interval = log_interval
        # Made at the first step, so that a resumed run with nothing left to sample shows
        # no bar, and a resumed one starts at its own step.
        self.bar: Any = None
        self._info = ""
        self._ess = math.nan
        self._t0 = time.monotonic()
        self._step0: int | None = None

    def set_info(self, check: Check) -> None:
        tmax = float(np.max(check.tau))
        self._info = f"tau_max {tmax:.1f}" if math.isfinite(tmax) else ""
        if not np.any(np.isnan(check.ess)):
            self._ess = float(np.min(check.ess))
            self._info += f"  ess_min {self._ess:.0f}/{self.target_ess:g}"

    def _eta(self, step: int) -> str:
        elapsed = time.monotonic() - self._t0
        done = step - (self._step0 or 0)
        if done <= 0 or elapsed < 1.0:
            return ""
        to_max = elapsed / done * (self.max_steps - step)
        if math.isfinite(self._ess) and self._ess > 0:
            left = min(to_max, elapsed * max(self.target_ess / self._ess - 1.0, 0.0))
            return f"~{_duration(left)} left"
        return f"at most ~{_duration(to_max)} left"

    def update(self, step: int, force: bool = False) -> None:
        if not self.enabled:
            return
        if self.bar is None:
            self._step0, self._t0 = step - 1, time.monotonic()
            self.bar = progress_bar(
                self.max_steps, self.label, unit="step", log_interval=self.log_interval,
                initial=step - 1,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| step {n_fmt}/{total_fmt} "
                           "[{elapsed}{postfix}]",
            )
        post = "  ".join(x for x in (self._info, self._eta(step)) if x)
        self.bar.set_postfix_str(post, refresh=False)
        if force:
            self.bar.n = step
            self.bar.refresh()
        else:
            self.bar.update(step - self.bar.n)  # tqdm throttles the redraws

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _duration(seconds: float) -> str:
    """Return ``seconds`` as '42 s' or '3.5 min'."""
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------
def make_log_prob(
    priors: PriorSet, log_lik: Callable[[np.ndarray], np.ndarray]
) -> Callable[[np.ndarray], np.ndarray]:
    """Vectorised ``log p(u) = log_prior_u(u) + log_lik(theta(u))`` (design.md).

    The likelihood is evaluated only where the prior density is positive, so a
    forward model never sees values outside the prior support.

    Parameters
    ----------
    priors : PriorSet
        Priors in parameter order; give the Jacobian-including density of ``u``.
    log_lik : callable
        ``theta (k, ndim) -> (k,)`` log-likelihood of physical parameters; ``-inf``
        where the model is invalid.

    Returns
    -------
    callable
        ``U (k, ndim) -> (k,)`` log posterior density (unnormalised) in ``u``.
    """

    def log_prob(U: np.ndarray) -> np.ndarray:
        lp = priors.log_prior_u(U)
        ok = np.isfinite(lp)
        if np.any(ok):
            lp[ok] += np.asarray(log_lik(priors.to_theta(U[ok])), dtype=float)
        return lp

    return log_prob


def init_walkers(
    log_prob: Callable[[np.ndarray], np.ndarray],
    center: Any,
    nwalkers: int,
    *,
    rng: np.random.Generator,
    scale: float | Sequence[float] = 1e-3,
    max_tries: int = 100,
) -> np.ndarray:
    """Start positions in a Gaussian ball around ``center`` with finite log-probability.

    Parameters
    ----------
    log_prob : callable
        Vectorised log-probability, ``(k, ndim) -> (k,)``.
    center : array_like, shape (ndim,)
        Ball centre in the sampling space (typically the MAP).
    nwalkers : int
        Number of walkers, at least ``2 * ndim``.
    rng : numpy.random.Generator
        Source of randomness.
    scale : float or sequence of float, default 1e-3
        Standard deviation of the ball per parameter (units of ``u``).
    max_tries : int, default 100
        Redraw rounds for walkers that land where ``log_prob`` is ``-inf``.

    Returns
    -------
    numpy.ndarray, shape (nwalkers, ndim)

    Raises
    ------
    SamplingError
        If ``center`` is not finite or some walkers stay outside the support.
    """
    center = np.asarray(center, dtype=float)
    if center.ndim != 1 or not np.all(np.isfinite(center)):
        raise SamplingError(f"center must be a finite 1-D vector, got {center!r}")
    ndim = center.size
    if nwalkers < 2 * ndim:
        raise SamplingError(f"need nwalkers >= 2*ndim = {2 * ndim}, got {nwalkers}")
    scale = np.broadcast_to(np.asarray(scale, dtype=float), (ndim,))
    u = center + scale * rng.standard_normal((nwalkers, ndim))
    bad = ~np.isfinite(np.asarray(log_prob(u), dtype=float))
    for _ in range(max_tries):
        if not bad.any():
            return u
        u[bad] = center + scale * rng.standard_normal((int(bad.sum()), ndim))
        bad[bad] = ~np.isfinite(np.asarray(log_prob(u[bad]), dtype=float))
    if bad.any():
        raise SamplingError(
            f"{int(bad.sum())} walkers still have non-finite log_prob after {max_tries} "
            "redraws; move center inside the support or reduce scale"
        )
    return u


class _DeferredInterrupt:
    """Ctrl-C while sampling: finish the current step, keep it, then stop.

    emcee wraps the log-probability in a function that prints its own report (the
    parameters, about 50 lines on stdout) when anything, KeyboardInterrupt included, is
    raised inside it. The handler installed here only sets :attr:`requested`; the
    sampler loop stops after the step in progress and raises KeyboardInterrupt itself,
    outside emcee, with every finished step written to the checkpoint. A second Ctrl-C
    raises at once. Installed only in the main thread over Python's default handler
    (a caller's own SIGINT handler, or a worker thread, is left alone).
    """

    def __init__(self) -> None:
        self.requested = False
        self._installed = False

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:  # a second Ctrl-C: do not wait for the step
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> _DeferredInterrupt:
        if (threading.current_thread() is threading.main_thread()
                and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
            signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            self._installed = False


def run_emcee(
    log_prob: Callable[[np.ndarray], np.ndarray],
    u0: Any,
    *,
    seed: int,
    max_steps: int = 20_000,
    min_steps: int = 500,
    target_ess: float = 1000.0,
    check_every: int = 100,
    n_tau: float = 50.0,
    tau_rtol: float = 0.02,
    burn_in_taus: float = 3.0,
    thin: int = 1,
    backend_path: str | Path | None = None,
    resume: bool = False,
    checkpoint_seconds: float = 10.0,
    progress: bool | None = None,
    names: Sequence[str] | None = None,
    space: str = "u",
    moves: Any = None,
    preburn: int = 0,
    label: str = "emcee",
) -> Chain:
    """Sample with emcee until converged (see the module notes) or ``max_steps``.

    Parameters
    ----------
    log_prob : callable
        Vectorised log-probability in the sampling space, ``(k, ndim) -> (k,)``;
        ``-inf`` outside the support, never NaN or ``+inf``.
    u0 : array_like, shape (nwalkers, ndim)
        Initial walker positions (e.g. from :func:`init_walkers`); ignored when a
        checkpoint is resumed (its last positions are used), but its shape must match.
    seed : int
        Non-negative seed of emcee's random number generator.
    max_steps : int, default 20000
        Step budget (steps of the whole ensemble).
    min_steps : int, default 500
        Never stop before this many steps.
    target_ess : float, default 1000
        Required bulk ESS per parameter after burn-in.
    check_every : int, default 100
        Steps between convergence checks.
    n_tau : float, default 50
        Required length of the chain after burn-in, in autocorrelation times.
    tau_rtol : float, default 0.02
        Required relative stability of τ between consecutive checks. (1 % made
        a 3-parameter Gaussian run ~30 % longer than needed for ESS >= 1000:
        τ estimates 100 steps apart scatter by a few per cent.)
    burn_in_taus : float, default 3
        Burn-in in units of the largest τ (capped at half the chain).
    thin : int, default 1
        Keep every ``thin``-th post-burn-in step in the returned chain (storage only).
    backend_path : str or pathlib.Path, optional
        HDF5 checkpoint file (emcee ``HDFBackend``, group ``mcmc``, plus this
        module's bookkeeping in group ``bayesbeam``).
    resume : bool, default False
        Continue the run in ``backend_path`` (same seed, walkers and names
        required); a missing or empty file starts afresh. ``False`` overwrites it.
    checkpoint_seconds : float, default 10
        Longest stretch of sampling between writes to ``backend_path`` (a hard
        kill loses at most this much work); ``0`` writes every step.
    progress : bool or None, default None
        Progress bar on stderr (:func:`bayesbeam._util.progress_bar`: terminal, Jupyter or
        log lines); ``None`` shows it only on a terminal or in Jupyter.
    names : sequence of str, optional
        Parameter names (default ``p0, p1, ...``).
    space : str, default "u"
        A description of the coordinates ``log_prob`` takes, recorded in the
        checkpoint; resuming one recorded in other coordinates is refused.
    moves : optional
        emcee moves, passed to :class:`emcee.EnsembleSampler` (default stretch move).
    preburn : int, default 0
        Steps of a first, discarded run (in memory, before the recorded chain) in
        which stranded walkers are moved back to the ensemble (:func:`preburn_walkers`).
        Only on a fresh start; a resumed checkpoint continues as it was.
    label : str, default "emcee"
        What the progress bar calls this run (e.g. ``"fit viscous+kv"``).

    Returns
    -------
    Chain

    Raises
    ------
    SamplingError
        For invalid arguments, a start outside the support, a log-probability with
        the wrong shape or NaN, or a checkpoint that does not match the request.

    Warns
    -----
    NotConvergedWarning
        When ``max_steps`` is reached before the criteria hold.
    """
    t_start = time.perf_counter()
    u0 = np.array(u0, dtype=float)
    if u0.ndim != 2:
        raise SamplingError(f"u0 must have shape (nwalkers, ndim), got {u0.shape}")
    nwalkers, ndim = u0.shape
    if nwalkers < 2 * ndim:
        raise SamplingError(f"emcee needs nwalkers >= 2*ndim = {2 * ndim}; got {nwalkers} walkers")
    if not np.all(np.isfinite(u0)):
        raise SamplingError("u0 contains non-finite values")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SamplingError(f"seed must be a non-negative int, got {seed!r}")
    seed = int(seed)
    for what, v, lo in (
        ("max_steps", max_steps, 1),
        ("check_every", check_every, 1),
        ("thin", thin, 1),
        ("min_steps", min_steps, 0),
    ):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise SamplingError(f"{what} must be an int >= {lo}, got {v!r}")
    if not (tau_rtol > 0 and n_tau > 0):
        raise SamplingError(f"tau_rtol and n_tau must be > 0, got {tau_rtol!r}, {n_tau!r}")
    if not (burn_in_taus >= 0 and target_ess >= 0 and checkpoint_seconds >= 0):
        raise SamplingError("burn_in_taus, target_ess and checkpoint_seconds must be >= 0")
    names = tuple(f"p{i}" for i in range(ndim)) if names is None else tuple(names)
    if len(names) != ndim or len(set(names)) != ndim:
        raise SamplingError(f"need {ndim} distinct names, got {names!r}")
    if progress is None:
        progress = stderr_is_live()

    path = None if backend_path is None else Path(backend_path)
    prior_calls, prior_seconds = 0, 0.0
    if path is None:
        backend: emcee.backends.Backend = emcee.backends.Backend()
    else:
        backend, prior_calls, prior_seconds = open_checkpoint(
            path,
            nwalkers=nwalkers,
            ndim=ndim,
            seed=seed,
            names=names,
            resume=resume,
            flush_seconds=checkpoint_seconds,
            space=space,
        )

    fn = _CountingLogProb(log_prob, ndim, prior_calls)
    sampler = emcee.EnsembleSampler(
        nwalkers, ndim, fn, vectorize=True, backend=backend, moves=moves
    )
    it = int(backend.iteration)
    if it == 0:
        # Fresh start (or a checkpoint killed before its first step): seeded RNG.
        sampler.random_state = _rng_state(seed)
        lp0 = fn(u0)
        if not np.all(np.isfinite(lp0)):
            bad = np.flatnonzero(~np.isfinite(lp0)).tolist()
            raise SamplingError(
                f"walkers {bad} start where log_prob is -inf (outside the prior support "
                "or an invalid model); start them inside, e.g. with init_walkers"
            )
        if not emcee.ensemble.walkers_independent(u0):
            raise SamplingError(
                "the start walkers are (nearly) linearly dependent (a column without spread, "
                "or a condition number above 1e8), so the ensemble moves cannot explore every "
                "direction; spread them around the start, e.g. with init_walkers"
            )
        if preburn > 0:
            u0, lp0 = preburn_walkers(fn, u0, lp0, preburn, seed=seed, moves=moves)
        state = emcee.State(u0, log_prob=lp0, random_state=sampler.random_state)
    else:
        # emcee restored the RNG state saved with the last step; continue from there.
        state = backend.get_last_sample()

    bar = _Progress(bool(progress), max_steps, target_ess, label=label)

    def evaluate(n: int, prev_tau: np.ndarray | None) -> Check:
        return check_convergence(
            backend.get_chain()[:n],
            prev_tau,
            n_tau=n_tau,
            tau_rtol=tau_rtol,
            burn_in_taus=burn_in_taus,
            min_steps=min_steps,
            max_steps=max_steps,
            target_ess=target_ess,
        )

    def save_meta(final: bool = False) -> None:
        if isinstance(backend, CheckpointBackend):  # steps and bookkeeping in one write
            backend.write_progress(fn.n_calls, prior_seconds + time.perf_counter() - t_start,
                                   final=final)

    check: Check | None = None
    prev_tau: np.ndarray | None = None
    # The handler stays in place while the last steps are saved: a Ctrl-C then does
    # not cut the write short.
    with _DeferredInterrupt() as stop:
        try:
            if it > 0:
                # Rebuild the decision history: τ at the last regular check before `it`,
                # and a check at `it` itself if the interrupted run was due one there.
                last = ((it - 1) // check_every) * check_every
                prev_tau = (kept_tau(backend.get_chain()[:last], n_tau, burn_in_taus)[0]
                            if last else None)
                if it % check_every == 0 or it >= max_steps:
                    check = evaluate(it, prev_tau)
                    prev_tau = check.tau
                    bar.set_info(check)
            while not (check is not None and check.converged) and it < max_steps:
                target = min((it // check_every + 1) * check_every, max_steps)
                # emcee's check that the walkers are linearly independent guards a
                # start (done above, before any pre-burn); each chunk here continues a
                # chain whose ensemble may legally have narrowed (a funnel's neck), which
                # the convergence checks judge.
                steps = sampler.sample(state, iterations=target - it, progress=False,
                                       skip_initial_state_check=True)
                for new_state in steps:
                    state = new_state
                    it += 1
                    bar.update(it)
                    if stop.requested:
                        break
                if stop.requested:  # the steps so far are saved by `finally`
                    raise KeyboardInterrupt(f"sampling interrupted after step {it}")
                check = evaluate(it, prev_tau)
                prev_tau = check.tau
                bar.set_info(check)
                bar.update(it, force=True)
                save_meta()
            if stop.requested:  # Ctrl-C during the last check: still an interruption
                raise KeyboardInterrupt(f"sampling interrupted after step {it}")
        finally:
            save_meta(final=True)
            bar.close()

    if check is None:  # unreachable: the loop runs at least once when it < max_steps
        raise RuntimeError("internal error: no convergence check was made")
    if not check.converged:
        reasons = failed_criteria(
            check, n_tau=n_tau, tau_rtol=tau_rtol, target_ess=target_ess, min_steps=min_steps
        )
        warnings.warn(
            f"emcee did not converge within max_steps={max_steps}: "
            + "; ".join(reasons)
            + ". Raise max_steps (resume=True continues a checkpoint), improve the start, "
            "or reparameterise; treat these samples with caution.",
            NotConvergedWarning,
            stacklevel=2,
        )

    chain = backend.get_chain()[: check.n]
    logp = backend.get_log_prob()[: check.n]
    b = check.burn_in
    return Chain(
        samples=chain[b::thin],
        log_prob=logp[b::thin],
        names=names,
        tau=check.tau,
        ess=check.ess,
        rhat=check.rhat,
        acceptance_fraction=backend.accepted / float(backend.iteration),
        n_calls=fn.n_calls,
        converged=check.converged,
        seconds=prior_seconds + time.perf_counter() - t_start,
        burn_in=b,
        seed=seed,
        thin=thin,
        n_steps_total=check.n,
    )
