"""Fit tasks: what one fit is, its cache key, and how a worker computes it.

A :class:`FitTask` is one model on one trial with a seed and every setting; it is
picklable and self-contained (it carries the trial's data, not a path), so
:func:`run_fit_task` (the entry point that :mod:`bayesbeam.jobs.executor` sends to local
processes or Dask workers) computes the same bytes wherever it runs.
:func:`run_fit_task` writes a task's files into a scratch folder and returns their
contents (the folder layout is in :mod:`bayesbeam.jobs.executor`); each task runs with
the BLAS thread pool limited to one thread, and one task at a time per process (the
guard of every fit job, :func:`bayesbeam._util.job_guard`).

:func:`task_key` is the task's cache key: the SHA-256 of its trial (data file and TOML),
model, settings and seed. Scheduling, the cache lookup and reading results back are in
:mod:`bayesbeam.jobs.executor`, which re-exports every public name defined here.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tempfile
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bayesbeam._util import (
    SCHEMA_VERSION,
    atomic_path,
    file_sha256,
    finite_json,
    json_default,
    write_text_atomic,
)
from bayesbeam.inference.settings import FIT_DEFAULTS, FitSettings

__all__ = [
    "DEFAULT_SETTINGS",
    "ExecutorError",
    "FitTask",
    "TaskOutcome",
    "fit_tasks",
    "run_fit_task",
    "task_key",
]

#: Settings of one fit (passed to :func:`bayesbeam.comparison.scoring.evaluate`) and of its plots.
#: The fit settings are the package's (:data:`bayesbeam.inference.settings.FIT_DEFAULTS`).
DEFAULT_SETTINGS: dict[str, Any] = {
    **dataclasses.asdict(FIT_DEFAULTS),
    "n_loo_draws": 1000,
    "proposal": "normal",
    "plots": False,
    "plot_dpi": 90,
    "ppc_draws": 100,
}

_EVALUATE_KEYS = (*(f.name for f in dataclasses.fields(FitSettings)), "n_loo_draws", "proposal")


class ExecutorError(ValueError):
    """Bad executor input (jobs, scheduler, tasks); the message says how to fix it."""


# --------------------------------------------------------------------------- tasks


@dataclass(frozen=True)
class FitTask:
    """One fit: a model on a trial with a seed and settings (picklable, self-contained).

    The task carries the trial itself, read once by the caller; a worker opens no file,
    so it needs neither a shared file system nor the caller's working directory.

    Attributes
    ----------
    trial_file : str
        Absolute path of the trial TOML on the caller's machine (provenance only: the
        worker does not read it).
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
    trial : Trial or None
        The trial's data (:class:`~bayesbeam.trials.trial.Trial`: times, values, beam,
        metadata), which travels with the task; its ``sha256`` is ``data_sha256``.
        Not part of the key (the SHA-256s are) nor of ``task.json``.
    """

    trial_file: str
    trial_name: str
    data_sha256: str
    toml_sha256: str
    model: str
    seed: int
    settings: dict = field(default_factory=dict, hash=False)
    trial: Any = field(default=None, hash=False, compare=False, repr=False)

    @property
    def key(self) -> str:
        """Cache key: SHA-256 (hex) of trial hashes, model, settings and seed."""
        return task_key(self)

    @property
    def relpath(self) -> str:
        """Result folder relative to the output folder: ``<trial>/<model>``."""
        return f"{self.trial_name}/{self.model}"

    def to_dict(self) -> dict[str, Any]:
        """JSON record of the task (``task.json``), key included, the trial's data not."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
             if f.name != "trial"}
        d["settings"] = dict(self.settings)
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
    return json_key(payload)



def json_key(payload: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of a task's canonical JSON description: its cache key.

    Parameters
    ----------
    payload : mapping
        What determines the task's result (data by their SHA-256s, not their paths).

    Returns
    -------
    str
    """
    text = json.dumps(payload, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def cached_record(folder: Path, key: str, name: str) -> dict[str, Any] | None:
    """Return the record ``name`` of a task folder whose ``task.json`` has ``key``, or None.

    Parameters
    ----------
    folder : Path
    key : str
        :func:`json_key` of the task.
    name : str
        The record's file in ``folder`` (e.g. ``diagnosis.json``).

    Returns
    -------
    dict or None
        None when the folder holds another task's results, or none readable.
    """
    try:
        if json.loads((folder / "task.json").read_text("utf-8")).get("key") != key:
            return None
        return json.loads((folder / name).read_text("utf-8"))
    except (OSError, json.JSONDecodeError):
        return None


def write_task_files(folder: Path, files: Mapping[str, bytes], task: Mapping[str, Any]) -> None:
    """Write a task's files atomically, then its ``task.json`` (``key``, spec, seconds).

    Parameters
    ----------
    folder : Path
        Created if missing.
    files : mapping of str to bytes
    task : mapping
        Written with the schema version as ``task.json``, last: a folder whose
        ``task.json`` has the key holds all the task's files.
    """
    folder.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        with atomic_path(folder / name) as tmp:
            tmp.write_bytes(data)
    write_text_atomic(folder / "task.json",
                      json.dumps({"schema_version": SCHEMA_VERSION, **task}, indent=2) + "\n")


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
        Seed of every task (as :func:`bayesbeam.comparison.compare.compare` uses one seed for all
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
    from bayesbeam.physics.models import parse_model
    from bayesbeam.trials.io import read_trial

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
                toml_sha256=file_sha256(path), model=m, seed=int(seed), settings=dict(s),
                trial=trial,
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


def _dump(path: Path, obj: Any) -> None:
    obj = {"schema_version": SCHEMA_VERSION, **obj}  # the layout of every JSON output
    text = json.dumps(finite_json(json.loads(json.dumps(obj, default=json_default))), indent=2,
                      allow_nan=False)
    write_text_atomic(path, text + "\n")


def _compute(task: FitTask, folder: Path, t0: float, c0: float) -> dict[str, Any]:
    """Fit, score and (optionally) plot one task into ``folder``; return score.json."""
    import numpy as np

    from bayesbeam.comparison.scoring import evaluate
    from bayesbeam.inference.modal import modal_posterior
    from bayesbeam.inference.modal_plots import plot_zeta_vs_f
    from bayesbeam.inference.problem import Problem

    s = task.settings
    trial = task.trial
    if trial is None:
        raise ExecutorError(
            f"the task of {task.model!r} on {task.trial_name} carries no trial data; build "
            "tasks with fit_tasks (a worker reads no trial file)"
        )
    if trial.sha256 != task.data_sha256:
        raise ExecutorError(
            f"the trial data of {task.trial_name} do not match the task (SHA-256 "
            f"{trial.sha256[:12]}..., task {task.data_sha256[:12]}...); rebuild the tasks"
        )
    problem = Problem(trial, task.model, n_elements=int(s["n_elements"]), initial=s["initial"])
    kw = {k: s[k] for k in _EVALUATE_KEYS}
    score = evaluate(trial, task.model, seed=task.seed, problem=problem, progress=False, **kw)
    res = score.result
    score.save(folder)  # the complete ArviZ tree (arviz.loo / arviz.compare read it)
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
    fitted = problem.with_mesh(int(res.settings["n_elements"]))  # the fit's final mesh
    # f_k and ζ_k of the posterior (the quantity a damping study looks at first).
    modes = modal_posterior(fitted, res)
    record["modes"] = modes.to_json_dict()
    record["units"] = res.units()
    if s.get("plots"):
        record["figures"] = _plots(trial, fitted, score, folder, s)
        if plot_zeta_vs_f(modes, folder / "zeta_vs_f.png", dpi=int(s.get("plot_dpi", 90)),
                          title=f"{task.trial_name}: {task.model}") is not None:
            record["figures"].append("zeta_vs_f.png")
    # Timing of the whole task (fit, evidence, criteria, plots) in this worker.
    record["task_seconds"] = time.perf_counter() - t0
    record["task_cpu_seconds"] = time.process_time() - c0
    _dump(folder / "score.json", record)
    _dump(folder / "task.json", task.to_dict())
    return record


def _plots(trial: Any, problem: Any, score: Any, folder: Path, s: Mapping) -> list[str]:
    import numpy as np

    from bayesbeam.inference.predictive import posterior_predictive
    from bayesbeam.report.plots import plot_fit, plot_residual_spectrum

    res = score.result
    dpi = int(s.get("plot_dpi", 90))
    rng = np.random.default_rng([int(score.result.chain.seed), 1])
    _, y_model, y_rep = posterior_predictive(problem, res, int(s.get("ppc_draws", 100)), rng)
    plot_fit(trial, problem, res, folder / "fit.png", rng=rng, draws=(y_model, y_rep),
             dpi=dpi)
    resid = np.asarray(trial.values) - np.median(y_model, axis=0)
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
    # One task at a time per process, with one BLAS thread: the guard of every fit job
    # (bayesbeam._util.job_guard says why).
    from bayesbeam._util import job_guard

    with job_guard():
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
    with tempfile.TemporaryDirectory(prefix="bayesbeam-task-") as tmp:
        folder = Path(tmp)
        record = _compute(task, folder, t0, c0)
        files = {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()
                 and p.name != "chain.h5"}
    return files, record, time.perf_counter() - t0
