"""Many independent fits (trials × models) through a standard executor, with a result cache.

A study or a diagnosis is a set of independent fits. This module runs them through the
:class:`concurrent.futures.Executor` interface:

* ``jobs=1`` (default): one after another in this process;
* ``jobs=N``: a local :class:`~concurrent.futures.ProcessPoolExecutor` of N processes
  (``spawn`` start method: no fork of a multi-threaded parent, same on every OS);
* ``scheduler="tcp://host:port"``: a Dask distributed cluster, through
  ``distributed.Client(address).get_executor()`` (optional dependency:
  ``pip install "bayesbeam[dask]"``); a ``distributed.Client`` object is accepted too.

**Identical to a serial run.** Each :class:`FitTask` carries its own seed and every
setting; a task's result depends on nothing else (not on the executor, the worker or
the order), and each task runs with the BLAS thread pool limited to one thread
(:mod:`threadpoolctl`, when installed) so that parallel workers neither oversubscribe
the cores nor change the floating-point reduction order. The same tasks give bitwise
the same numbers serially, in a process pool or on Dask.

**Files travel with the result.** A worker writes a task's files into a temporary
folder and returns their bytes; the caller writes them under ``outdir``. So a Dask
cluster needs no shared file system, and a failed or interrupted run leaves no
half-written result folder.

**Cache.** Every task has a key: the SHA-256 of its trial (the data file's SHA-256 and
the trial TOML's, which holds the beam description), model, settings and seed. Its
result folder holds ``task.json`` with that key; a re-run skips every task whose
folder holds ``score.json`` and a matching ``task.json`` (``force=True`` recomputes).
Changing a setting, the seed or the data changes the key, so stale results are
recomputed, never reused.

Layout of one task's folder (``outdir/<trial name>/<model>/``):

=========================  ===============================================================
``task.json``              the task: trial file, SHA-256s, model, seed, settings, key
``posterior.nc``           the posterior (ArviZ NetCDF, :meth:`FitResult.save`)
``summary.json``           posterior summary, diagnostics, priors, settings, provenance
``score.json``             evidence ± error, Laplace, ELPD-LOO, WAIC, AIC, BIC, notes
``score.npz``              pointwise LOO/WAIC terms and Pareto k (to rebuild the ranking)
``fit.png`` etc.           data vs posterior predictive, residual spectrum, corner plot
                           (when the task asks for plots)
=========================  ===============================================================

:func:`load_score` rebuilds a :class:`bayesbeam.compare.ModelScore` from such a folder,
so :func:`bayesbeam.compare.compare_scores` ranks cached and fresh results alike.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import hashlib
import json
import math
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bayesbeam.jsonutil import finite_json, json_default

__all__ = [
    "DEFAULT_SETTINGS",
    "ExecutorError",
    "FitTask",
    "TaskOutcome",
    "fit_tasks",
    "load_score",
    "make_executor",
    "map_tasks",
    "run_fit_task",
    "run_fits",
    "task_key",
]

#: Settings of one fit (passed to :func:`bayesbeam.compare.evaluate`) and of its plots.
DEFAULT_SETTINGS: dict[str, Any] = {
    "n_elements": 16,
    "initial": "release",
    "nwalkers": None,
    "target_ess": 1000.0,
    "max_steps": 20_000,
    "min_steps": 300,
    "n_loo_draws": 1000,
    "proposal": "normal",
    "plots": False,
    "plot_dpi": 90,
    "ppc_draws": 100,
}

_EVALUATE_KEYS = ("n_elements", "initial", "nwalkers", "target_ess", "max_steps", "min_steps",
                  "n_loo_draws", "proposal")


class ExecutorError(ValueError):
    """Bad executor input (jobs, scheduler, tasks); the message says how to fix it."""


# --------------------------------------------------------------------------- tasks


def _sha256_file(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass(frozen=True)
class FitTask:
    """One fit: a model on a trial with a seed and settings (picklable, self-contained).

    Attributes
    ----------
    trial_file : str
        Absolute path of the trial TOML.
    trial_name : str
        The trial's name (folder name of its results).
    data_sha256 : str
        SHA-256 of the trial's data file (``Trial.sha256``).
    toml_sha256 : str
        SHA-256 of the trial TOML (the beam description).
    model : str
        Canonical model name, e.g. ``"viscous+kv"``.
    seed : int
        Seed of the fit and of the evidence estimate.
    settings : dict
        Full settings (:data:`DEFAULT_SETTINGS` updated by the caller's).
    """

    trial_file: str
    trial_name: str
    data_sha256: str
    toml_sha256: str
    model: str
    seed: int
    settings: dict = field(default_factory=dict, hash=False)

    @property
    def key(self) -> str:
        """Cache key: SHA-256 (hex) of trial hashes, model, settings and seed."""
        return task_key(self)

    @property
    def relpath(self) -> str:
        """Result folder relative to the output folder: ``<trial>/<model>``."""
        return f"{self.trial_name}/{self.model}"

    def to_dict(self) -> dict[str, Any]:
        """JSON record of the task (``task.json``), key included."""
        d = dataclasses.asdict(self)
        d["key"] = self.key
        return d


def task_key(task: FitTask) -> str:
    """SHA-256 of what determines a task's result.

    Parameters
    ----------
    task : FitTask

    Returns
    -------
    str
        Hex digest of the canonical JSON of data SHA-256, TOML SHA-256, model,
        settings and seed (file paths and names excluded: moving the data does not
        invalidate the cache).
    """
    payload = {
        "data_sha256": task.data_sha256,
        "toml_sha256": task.toml_sha256,
        "model": task.model,
        "settings": task.settings,
        "seed": int(task.seed),
    }
    text = json.dumps(payload, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def fit_tasks(
    trials: Iterable[str | Path],
    models: Sequence[str],
    *,
    seed: int = 0,
    settings: Mapping[str, Any] | None = None,
) -> list[FitTask]:
    """Build the tasks of every (trial, model) pair, trials outermost.

    Parameters
    ----------
    trials : iterable of path
        Trial TOML files.
    models : sequence of str
        Model names.
    seed : int
        Seed of every task (as :func:`bayesbeam.compare.compare` uses one seed for all
        models, so a task's result equals the corresponding part of ``compare``).
    settings : mapping, optional
        Overrides of :data:`DEFAULT_SETTINGS`.

    Returns
    -------
    list of FitTask

    Raises
    ------
    ExecutorError
        For unknown settings or a bad seed.
    """
    from bayesbeam.models import parse_model
    from bayesbeam.trial import read_trial

    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ExecutorError(f"seed must be a non-negative int, got {seed!r}")
    s = dict(DEFAULT_SETTINGS)
    unknown = sorted(set(settings or {}) - set(s))
    if unknown:
        raise ExecutorError(f"unknown settings {unknown}; known: {sorted(s)}")
    s.update(settings or {})
    names = [parse_model(m).name for m in models]
    if not names:
        raise ExecutorError("give at least one model, e.g. ['viscous', 'viscous+kv']")
    out = []
    for path in trials:
        path = Path(path).resolve()
        trial = read_trial(path)
        for m in names:
            out.append(FitTask(
                trial_file=str(path), trial_name=trial.name, data_sha256=trial.sha256,
                toml_sha256=_sha256_file(path), model=m, seed=int(seed), settings=dict(s),
            ))
    return out


@dataclass(frozen=True)
class TaskOutcome:
    """What a finished task reports back (the files are already written).

    Attributes
    ----------
    task : FitTask
    path : pathlib.Path
        The task's result folder.
    score : dict
        Contents of ``score.json``.
    cached : bool
        True when the result was found in the cache and not recomputed.
    seconds : float
        Wall-clock seconds of the task (0 for a cached one).
    """

    task: FitTask
    path: Path
    score: dict
    cached: bool
    seconds: float


# --------------------------------------------------------------------------- workers


_LIMIT_LOCK = threading.Lock()
_TASK_LOCK = threading.Lock()
_LIMIT_STATE: dict[str, Any] = {"depth": 0, "controller": None}


@contextlib.contextmanager
def _single_thread() -> Iterator[None]:
    """Limit BLAS/OpenMP pools to one thread (threadpoolctl), if it is installed.

    The limit is process-wide; with tasks in several threads of one process (a Dask
    worker with threads) the first task to enter sets it and the last to leave
    restores the original sizes.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional: results stay correct, only oversubscription risk
        yield
        return
    with _LIMIT_LOCK:
        if _LIMIT_STATE["depth"] == 0:
            _LIMIT_STATE["controller"] = threadpool_limits(limits=1)
        _LIMIT_STATE["depth"] += 1
    try:
        yield
    finally:
        with _LIMIT_LOCK:
            _LIMIT_STATE["depth"] -= 1
            if _LIMIT_STATE["depth"] == 0:
                _LIMIT_STATE["controller"].restore_original_limits()
                _LIMIT_STATE["controller"] = None


def _dump(path: Path, obj: Any) -> None:
    text = json.dumps(finite_json(json.loads(json.dumps(obj, default=json_default))), indent=2,
                      allow_nan=False)
    path.write_text(text + "\n", encoding="utf-8")


def _compute(task: FitTask, folder: Path, t0: float, c0: float) -> dict[str, Any]:
    """Fit, score and (optionally) plot one task into ``folder``; return score.json."""
    import numpy as np

    from bayesbeam.compare import evaluate
    from bayesbeam.problem import Problem
    from bayesbeam.trial import read_trial

    s = task.settings
    trial = read_trial(task.trial_file)
    if trial.sha256 != task.data_sha256:
        raise ExecutorError(
            f"{task.trial_file}: its data changed since the task was made (SHA-256 "
            f"{trial.sha256[:12]}..., task {task.data_sha256[:12]}...); rebuild the tasks"
        )
    problem = Problem(trial, task.model, n_elements=int(s["n_elements"]), initial=s["initial"])
    kw = {k: s[k] for k in _EVALUATE_KEYS}
    score = evaluate(trial, task.model, seed=task.seed, problem=problem, progress=False, **kw)
    res = score.result
    res.save(folder)
    record = score.to_dict()
    record.update({
        "trial": task.trial_name,
        "key": task.key,
        "seed": task.seed,
        "settings": dict(s),
        "evidence": score.evidence.to_dict(),
        "loo": {**score.loo.to_dict(), "reff": score.loo.reff},
        "waic": score.waic.to_dict(),
        "posterior": res.summary(),
        "diagnostics": {k: v for k, v in res.diagnostics().items()
                        if k not in ("tau", "ess", "rhat")},
        "provenance": dict(res.provenance),
        "priors": res.priors.to_dict(),
    })
    np.savez_compressed(
        folder / "score.npz",
        loo_pointwise=score.loo.pointwise, pareto_k=score.loo.pareto_k,
        waic_pointwise=score.waic.pointwise, p_waic_i=score.waic.p_waic_i,
    )
    if s.get("plots"):
        record["figures"] = _plots(trial, problem, score, folder, s)
    # Timing of the whole task (fit, evidence, criteria, plots) in this worker.
    record["task_seconds"] = time.perf_counter() - t0
    record["task_cpu_seconds"] = time.process_time() - c0
    _dump(folder / "score.json", record)
    _dump(folder / "task.json", task.to_dict())
    return record


def _plots(trial: Any, problem: Any, score: Any, folder: Path, s: Mapping) -> list[str]:
    import numpy as np

    from bayesbeam.plots import plot_fit, plot_residual_spectrum, posterior_predictive

    res = score.result
    dpi = int(s.get("plot_dpi", 90))
    rng = np.random.default_rng([int(score.result.chain.seed), 1])
    draws = posterior_predictive(problem, res, int(s.get("ppc_draws", 100)), rng)
    plot_fit(trial, problem, res, folder / "fit.png", rng=rng, draws=draws, dpi=dpi)
    resid = np.asarray(trial.values) - np.median(draws[0], axis=0)
    X = problem.theta(np.asarray(res.map_u)[None]) if res.map_u is not None else None
    freqs = None
    if X is not None:
        try:
            freqs = problem.forward.modes(problem.forward_params(X)[0])[0]
        except ValueError:  # an inadmissible MAP cannot happen after a fit; plot without
            freqs = None
    plot_residual_spectrum(trial, resid, folder / "residual_spectrum.png",
                           mode_freqs_hz=freqs, dpi=dpi)
    res.plot_corner(folder / "corner.png", dpi=min(dpi, 60))
    return ["fit.png", "residual_spectrum.png", "corner.png"]


def run_fit_task(task: FitTask) -> tuple[dict[str, bytes], dict[str, Any], float]:
    """Run one task in a scratch folder and return its files (executor entry point).

    Parameters
    ----------
    task : FitTask

    Returns
    -------
    files : dict of str to bytes
        File name → contents.
    score : dict
        The ``score.json`` record.
    seconds : float
        Wall-clock time of the task.

    Raises
    ------
    ExecutorError
        When the fit fails; the message names the task and the cause.
    """
    # One task at a time per process: the warning filters that evaluate() uses to record
    # the sampler's warnings and the BLAS thread limit are process-wide, so tasks in
    # threads of one process (a threaded Dask worker) must not overlap. Parallelism comes
    # from processes (a process pool, or Dask workers with one thread each).
    with _TASK_LOCK:
        try:
            return _run_locked(task)
        except Exception as err:  # say which task failed; the cause stays chained
            raise ExecutorError(
                f"fit of {task.model!r} on {task.trial_name} ({task.trial_file}) failed: "
                f"{type(err).__name__}: {err}"
            ) from err


def _run_locked(task: FitTask) -> tuple[dict[str, bytes], dict[str, Any], float]:
    t0 = time.perf_counter()
    c0 = time.process_time()
    with _single_thread(), tempfile.TemporaryDirectory(prefix="bayesbeam-task-") as tmp:
        folder = Path(tmp)
        record = _compute(task, folder, t0, c0)
        files = {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()
                 and p.name != "chain.h5"}
    return files, record, time.perf_counter() - t0


# --------------------------------------------------------------------------- executors


@contextlib.contextmanager
def make_executor(jobs: int | None = 1, scheduler: Any = None) -> Iterator[cf.Executor | None]:
    """Context manager giving the executor for ``jobs`` / ``scheduler``.

    Parameters
    ----------
    jobs : int or None
        Local worker processes; 1 (or None) means serial in this process (yields
        ``None``), 0 or less means one per CPU core.
    scheduler : str or distributed.Client, optional
        Dask scheduler address (``"tcp://host:port"``) or a connected client; takes
        precedence over ``jobs``.

    Yields
    ------
    concurrent.futures.Executor or None
        None for a serial run.

    Raises
    ------
    ExecutorError
        When ``scheduler`` is given but dask.distributed is not installed, or ``jobs``
        is not an integer.
    """
    if scheduler is not None:
        client, own = _dask_client(scheduler)
        try:
            yield client.get_executor(pure=False)
        finally:
            if own:
                client.close()
        return
    if jobs is None:
        jobs = 1
    if isinstance(jobs, bool) or not isinstance(jobs, int):
        raise ExecutorError(f"jobs must be an integer number of processes, got {jobs!r}")
    if jobs <= 0:
        jobs = os.cpu_count() or 1
    if jobs == 1:
        yield None
        return
    import multiprocessing

    with cf.ProcessPoolExecutor(max_workers=jobs,
                                mp_context=multiprocessing.get_context("spawn")) as ex:
        yield ex


def _dask_client(scheduler: Any) -> tuple[Any, bool]:
    try:
        from distributed import Client
    except ImportError:
        raise ExecutorError(
            "a Dask scheduler was given but dask.distributed is not installed; install it "
            "with: pip install 'bayesbeam[dask]' (or pip install 'dask[distributed]'), or "
            "run locally with --jobs N instead of --scheduler"
        ) from None
    if isinstance(scheduler, Client):
        return scheduler, False
    if not isinstance(scheduler, str) or "://" not in scheduler:
        raise ExecutorError(
            f"scheduler must be a Dask scheduler address such as 'tcp://host:8786', got "
            f"{scheduler!r}"
        )
    try:
        return Client(scheduler, timeout="20s"), True
    except OSError as err:
        raise ExecutorError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None


def map_tasks(
    fn: Callable[[Any], Any],
    items: Sequence[Any],
    *,
    jobs: int | None = 1,
    scheduler: Any = None,
    executor: cf.Executor | None = None,
    on_done: Callable[[int, Any], None] | None = None,
) -> list[Any]:
    """Apply ``fn`` to every item through an executor; results in input order.

    Parameters
    ----------
    fn : callable
        A module-level (picklable) function of one argument.
    items : sequence
        Its arguments (picklable).
    jobs, scheduler
        See :func:`make_executor` (ignored when ``executor`` is given).
    executor : concurrent.futures.Executor, optional
        An executor to use (and leave open), e.g. to share it with other work.
    on_done : callable, optional
        Called as ``on_done(index, result)`` in this process as each item finishes
        (completion order), e.g. to write files or show progress.

    Returns
    -------
    list
        ``[fn(item) for item in items]``.
    """
    items = list(items)
    out: list[Any] = [None] * len(items)
    ctx = (contextlib.nullcontext(executor) if executor is not None
           else make_executor(jobs, scheduler))
    with ctx as ex:
        if ex is None:
            for i, item in enumerate(items):
                out[i] = fn(item)
                if on_done is not None:
                    on_done(i, out[i])
            return out
        futures = {ex.submit(fn, item): i for i, item in enumerate(items)}
        try:
            for fut in cf.as_completed(futures):
                i = futures[fut]
                out[i] = fut.result()
                if on_done is not None:
                    on_done(i, out[i])
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
    return out


def _cached(task: FitTask, folder: Path) -> dict[str, Any] | None:
    tj, sj = folder / "task.json", folder / "score.json"
    if not (tj.is_file() and sj.is_file()):
        return None
    try:
        if json.loads(tj.read_text(encoding="utf-8")).get("key") != task.key:
            return None
        return json.loads(sj.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None  # unreadable: recompute


def _print_progress(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _progress_sink(progress: bool | Callable[[str], None]) -> Callable[[str], None] | None:
    """Where progress lines go: stderr (``True``), the callable itself, or nowhere (None)."""
    if progress is True:
        return _print_progress
    if callable(progress):
        return progress
    return None


def _progress_line(k: int, n: int, o: TaskOutcome, t_start: float) -> str:
    sc = o.score
    lz, err = sc.get("log_evidence"), sc.get("log_evidence_err")
    ev = f"log Z {lz:.1f} ± {err:.2f}" if lz is not None and err is not None else "log Z n/a"
    ess = sc.get("diagnostics", {}).get("ess_min")
    ess_s = f"ESS min {ess:.0f}" if ess is not None else ""
    conv = "" if sc.get("converged", True) else " (not converged)"
    how = "cached" if o.cached else f"{o.seconds:.1f} s"
    return (f"[{k:>3}/{n}] {o.task.trial_name:<14} {o.task.model:<12} {ev:<24} {ess_s}{conv}"
            f"  [{how}; {time.perf_counter() - t_start:.0f} s elapsed]")


def run_fits(
    tasks: Sequence[FitTask],
    outdir: str | Path,
    *,
    jobs: int | None = 1,
    scheduler: Any = None,
    executor: cf.Executor | None = None,
    force: bool = False,
    progress: bool | Callable[[str], None] = True,
) -> list[TaskOutcome]:
    """Run fit tasks (skipping cached ones) and write each into ``outdir/<trial>/<model>/``.

    Parameters
    ----------
    tasks : sequence of FitTask
    outdir : path
        Output folder (created).
    jobs, scheduler
        See :func:`make_executor`.
    executor : concurrent.futures.Executor, optional
        Use this executor instead (see :func:`map_tasks`).
    force : bool
        Recompute tasks even when a matching cached result exists.
    progress : bool or callable
        True: one line per finished task on stderr; a callable receives the lines.

    Returns
    -------
    list of TaskOutcome
        In the order of ``tasks``.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    tasks = list(tasks)
    rel = [t.relpath for t in tasks]
    if len(set(rel)) != len(rel):
        raise ExecutorError("two tasks share a result folder (same trial name and model)")
    say = _progress_sink(progress)
    t_start = time.perf_counter()
    outcomes: list[TaskOutcome | None] = [None] * len(tasks)
    todo: list[int] = []
    done = 0
    for i, t in enumerate(tasks):
        hit = None if force else _cached(t, outdir / t.relpath)
        if hit is None:
            todo.append(i)
            continue
        outcomes[i] = TaskOutcome(t, outdir / t.relpath, hit, True, 0.0)
        done += 1
        if say:
            say(_progress_line(done, len(tasks), outcomes[i], t_start))

    def finished(j: int, value: tuple[dict[str, bytes], dict[str, Any], float]) -> None:
        nonlocal done
        t = tasks[todo[j]]
        files, record, seconds = value
        folder = outdir / t.relpath
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in files.items():
            if name != "task.json":
                (folder / name).write_bytes(data)
        # task.json last: its presence with the key marks the folder complete.
        (folder / "task.json").write_bytes(files["task.json"])
        outcomes[todo[j]] = TaskOutcome(t, folder, record, False, seconds)
        done += 1
        if say:
            say(_progress_line(done, len(tasks), outcomes[todo[j]], t_start))

    if todo:
        map_tasks(run_fit_task, [tasks[i] for i in todo], jobs=jobs, scheduler=scheduler,
                  executor=executor, on_done=finished)
    return [o for o in outcomes if o is not None]


# --------------------------------------------------------------------------- reading back


def load_score(folder: str | Path) -> Any:
    """Rebuild a :class:`bayesbeam.compare.ModelScore` from a task's result folder.

    Parameters
    ----------
    folder : path
        Holds ``posterior.nc``, ``score.json`` and ``score.npz``.

    Returns
    -------
    bayesbeam.compare.ModelScore
        Its ``loglik`` is an empty array of shape (0, 0, T): the pointwise
        log-likelihood of the draws is not stored (tens of MB per fit); LOO and WAIC
        keep their pointwise terms, which is what the ranking needs.
    """
    import numpy as np

    from bayesbeam.compare import ModelScore
    from bayesbeam.criteria import LOO, WAIC
    from bayesbeam.evidence import Evidence
    from bayesbeam.results import FitResult

    folder = Path(folder)
    try:
        sc = json.loads((folder / "score.json").read_text(encoding="utf-8"))
        arrays = np.load(folder / "score.npz")
    except FileNotFoundError as err:
        raise ExecutorError(f"{folder} is not a complete fit-task folder: {err}") from None
    result = FitResult.load(folder)

    def num(x: Any) -> float:
        return math.nan if x is None else float(x)

    ev = dict(sc["evidence"])
    for k in ("log_z", "log_z_err", "tau"):
        ev[k] = num(ev.get(k))
    lo, wa = sc["loo"], sc["waic"]
    loo = LOO(elpd_loo=num(lo["elpd_loo"]), se=num(lo["se"]), p_loo=num(lo["p_loo"]),
              pointwise=arrays["loo_pointwise"], pareto_k=arrays["pareto_k"],
              good_k=num(lo["good_k"]), n_samples=int(lo["n_samples"]),
              reff=num(lo.get("reff", 1.0)))
    waic = WAIC(elpd_waic=num(wa["elpd_waic"]), se=num(wa["se"]), p_waic=num(wa["p_waic"]),
                waic=num(wa["waic"]), pointwise=arrays["waic_pointwise"],
                p_waic_i=arrays["p_waic_i"], n_samples=int(wa["n_samples"]))
    n = int(sc["n_data"])
    return ModelScore(
        name=sc["name"], n_params=int(sc["n_params"]), n_data=n,
        max_loglik=num(sc["max_loglik"]), evidence=Evidence(**ev),
        laplace_log_z=num(sc.get("laplace_log_evidence")), loo=loo, waic=waic,
        aic=num(sc["aic"]), bic=num(sc["bic"]), n_calls=int(sc["n_calls"]),
        seconds=num(sc["seconds"]), noise=sc["noise"], result=result,
        loglik=np.empty((0, 0, n)), notes=tuple(sc.get("notes", ())),
    )
