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

**Data travel with the task, files with the result.** A task carries its trial (the
:class:`~bayesbeam.trials.trial.Trial` read by the caller: arrays and metadata), never a
path for the worker to open. A worker writes a task's files into a temporary folder and
returns their bytes; the caller writes them under ``outdir``. So a Dask cluster needs no
shared file system (nor the caller's working directory: relative paths are the
caller's business), and a failed or interrupted run leaves no half-written result
folder.

**Progress.** :func:`run_fits` shows a ``tqdm`` bar on stderr
(:func:`bayesbeam._util.progress_bar`: a bar on a terminal, a widget in Jupyter, a line
at most every 30 s in a log file) with the stage, the last finished trial and model and
tqdm's time estimate; a callable ``progress`` gets one line per finished task instead.

**Cache.** Every task has a key: the SHA-256 of its trial (the data file's SHA-256 and
the trial TOML's, which holds the beam description), model, settings and seed. Its
result folder holds ``task.json`` with that key; a re-run skips every task whose
folder holds ``score.json`` and a matching ``task.json`` (``force=True`` recomputes).
Changing a setting, the seed or the data changes the key, so stale results are
recomputed, never reused.

Layout of one task's folder (``outdir/<trial name>/<model>/``):

=========================  ===============================================================
``task.json``              the task: trial file (provenance), SHA-256s, model, seed,
                           settings, key
``posterior.nc``           complete ArviZ tree of the LOO draws: posterior, pointwise
                           log-likelihood, posterior predictive, observed data, prior
                           (:meth:`bayesbeam.comparison.scoring.ModelScore.save`)
``summary.json``           posterior summary, diagnostics, priors, settings, provenance
``score.json``             evidence ± error, Laplace, ELPD-LOO, WAIC, AIC, BIC, notes,
                           posterior summary with ``units``, ``modes`` (f_k, ζ_k
                           posteriors: :func:`bayesbeam.inference.modal.modal_posterior`)
``score.npz``              pointwise LOO/WAIC terms and Pareto k (to rebuild the ranking)
``fit.png`` etc.           data vs posterior predictive, residual spectrum, corner plot,
                           ``zeta_vs_f.png`` (when the task asks for plots)
=========================  ===============================================================

:func:`load_score` rebuilds a :class:`bayesbeam.comparison.scoring.ModelScore` from such a folder,
so :func:`bayesbeam.comparison.compare.compare_scores` ranks cached and fresh results alike.

:class:`FitTask`, :func:`task_key`, :func:`fit_tasks` and the worker entry point
:func:`run_fit_task` are defined in :mod:`bayesbeam.jobs.tasks` and re-exported here; this
module schedules them, looks up the cache and reads results back.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import json
import math
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

# Re-exported from bayesbeam.jobs.tasks: studies, tests and jobs.demo import these from here.
from bayesbeam.jobs.tasks import (
    ExecutorError,
    FitTask,
    TaskOutcome,
    run_fit_task,
)

__all__ = [
    "load_score",
    "make_executor",
    "map_tasks",
    "run_fits",
]


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
    """Write one progress line on stderr (the ``True`` sink of :func:`_progress_sink`)."""
    print(line, file=sys.stderr, flush=True)


def _progress_sink(progress: bool | Callable[[str], None]) -> Callable[[str], None] | None:
    """Where message lines go: stderr (``True``), the callable itself, or nowhere (None)."""
    if progress is True:
        return _print_progress
    if callable(progress):
        return progress
    return None


def _outcome_text(o: TaskOutcome) -> str:
    """Return what one finished task reports: trial, model, evidence, ESS (in columns)."""
    sc = o.score
    lz, err = sc.get("log_evidence"), sc.get("log_evidence_err")
    ev = f"log Z {lz:.1f} ± {err:.2f}" if lz is not None and err is not None else "log Z n/a"
    ess = sc.get("diagnostics", {}).get("ess_min")
    ess_s = f"ESS min {ess:.0f}" if ess is not None else ""
    conv = "" if sc.get("converged", True) else " (not converged)"
    return f"{o.task.trial_name:<14} {o.task.model:<12} {ev:<24} {ess_s}{conv}"


def _how(o: TaskOutcome) -> str:
    return "cached" if o.cached else f"{o.seconds:.1f} s"


def _progress_line(k: int, n: int, o: TaskOutcome, t_start: float) -> str:
    """Return the log line of the ``k``-th of ``n`` finished tasks (callable sinks)."""
    return (f"[{k:>3}/{n}] {_outcome_text(o)}  [{_how(o)}; "
            f"{time.perf_counter() - t_start:.0f} s elapsed]")


class _Progress:
    """Progress of :func:`run_fits`: a tqdm bar, or one line per task to a callable.

    ``True``: a bar on stderr (:func:`bayesbeam._util.progress_bar`: a bar on a
    terminal, a widget in Jupyter, a line at most every 30 s in a log) named after the
    stage, with tqdm's time estimate and the last finished trial and model beside it. A
    callable receives one line per finished task (a log of every result). ``False``:
    nothing.
    """

    def __init__(self, progress: bool | Callable[[str], None], total: int, stage: str) -> None:
        from bayesbeam._util import progress_bar

        self.say = progress if callable(progress) else None
        self.bar = progress_bar(total, stage, enabled=progress is True, unit="fit")
        self.total = total
        self.done = 0
        self.t_start = time.perf_counter()

    def note(self, text: str) -> None:
        from bayesbeam._util import progress_note

        progress_note(self.bar, text)

    def finished(self, o: TaskOutcome) -> None:
        self.done += 1
        if self.say is not None:
            self.say(_progress_line(self.done, self.total, o, self.t_start))
        self.note(" ".join(_outcome_text(o).split()) + f" [{_how(o)}]")
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


def run_fits(
    tasks: Sequence[FitTask],
    outdir: str | Path,
    *,
    jobs: int | None = 1,
    scheduler: Any = None,
    executor: cf.Executor | None = None,
    force: bool = False,
    progress: bool | Callable[[str], None] = True,
    stage: str = "fits",
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
        True: a progress bar on stderr (the stage, the last finished trial and model,
        tqdm's time estimate; a line at most every 30 s when stderr is a log file);
        a callable receives one line per finished task instead; False: silent.
    stage : str
        Name of the stage on the bar.

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
    shown = _Progress(progress, len(tasks), stage)
    outcomes: list[TaskOutcome | None] = [None] * len(tasks)
    todo: list[int] = []
    try:
        for i, t in enumerate(tasks):
            hit = None if force else _cached(t, outdir / t.relpath)
            if hit is None:
                todo.append(i)
                continue
            outcomes[i] = TaskOutcome(t, outdir / t.relpath, hit, True, 0.0)
            shown.finished(outcomes[i])

        def finished(j: int, value: tuple[dict[str, bytes], dict[str, Any], float]) -> None:
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
            shown.finished(outcomes[todo[j]])

        if todo:
            first = tasks[todo[0]]
            shown.note(f"{len(todo)} to fit, from {first.trial_name} {first.model}")
            map_tasks(run_fit_task, [tasks[i] for i in todo], jobs=jobs, scheduler=scheduler,
                      executor=executor, on_done=finished)
    finally:
        shown.close()
    return [o for o in outcomes if o is not None]


# --------------------------------------------------------------------------- reading back


def load_score(folder: str | Path) -> Any:
    """Rebuild a :class:`bayesbeam.comparison.scoring.ModelScore` from a task's result folder.

    Parameters
    ----------
    folder : path
        Holds ``posterior.nc``, ``score.json`` and ``score.npz``.

    Returns
    -------
    bayesbeam.comparison.scoring.ModelScore
        Its ``result`` holds the draws of ``posterior.nc`` (the LOO draws, thinned
        from the chain that ``summary.json`` summarises) and its ``loglik`` is an empty
        array of shape (0, 0, T) (the file holds the pointwise terms for ArviZ); LOO and
        WAIC keep their pointwise terms, which is what the ranking needs.
    """
    import numpy as np

    from bayesbeam.comparison.scoring import ModelScore
    from bayesbeam.inference.results import FitResult
    from bayesbeam.stats.criteria import LOO, WAIC
    from bayesbeam.stats.evidence import Evidence

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
