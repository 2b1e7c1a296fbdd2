"""The main job: the source study's replication on the shipped data, in a few minutes.

``bayesbeam demo`` (:func:`run_demo`) fits three damping models (``viscous``,
``viscous+kv``, ``viscous+sh``) to every shipped example trial (``data/`` in the
repository, ``bayesbeam/examples`` when installed; three carbon-fibre beams, five release
tests each; see ``data/README.md``), ranks them per trial by log evidence
(:func:`bayesbeam.comparison.compare.compare_scores`), fits each beam's trials jointly with
the model they favour (E shared, the damping pooled: :mod:`bayesbeam.jobs.joint_task`),
diagnoses what the models get wrong on one trial
(:func:`bayesbeam.diagnosis.diagnose.diagnose`), prints a summary table per beam and model
and writes a self-contained HTML report (:func:`bayesbeam.report.html.write_report`).

The fits run through :mod:`bayesbeam.jobs.executor` (a process pool with ``jobs``, or a Dask
cluster), are cached (a re-run only redoes what changed) and give the same numbers
whatever the executor.

Demo settings versus a full study
---------------------------------
To finish in about five minutes on a 2-core machine the demo uses a coarser mesh and
short chains (:data:`DEMO_SETTINGS`: 8 Hermite elements, 24 walkers, at most 400
steps). The mesh is accurate enough for these records (first two natural frequencies
within 2e-4 of a 48-element reference), but chains of 400 steps are shorter than the
sampler's convergence rule asks for (50 autocorrelation times) for the models with
two damping laws: their posterior summaries are indicative and their evidence errors
do not cover the unconverged chains (each result says so in its notes). The printed
output and ``replication.json`` state the settings used.
``studies/source_replication.py`` runs the same analysis with the package's default
settings (16 elements, target ESS 1000).

Provenance: every fit's ``summary.json`` records the package version, the data file's
SHA-256, the model, the priors, the seed and the settings; ``replication.json``
records them for the whole run.
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from bayesbeam._util import (
    SCHEMA_VERSION,
    atomic_path,
    file_sha256,
    finite_json,
    read_toml,
    write_text_atomic,
)
from bayesbeam.inference.settings import FIT_DEFAULTS
from bayesbeam.jobs.joint_task import finish_joint, format_joint_table, start_joint
from bayesbeam.jobs.summary import beam_of, beam_summary, conclusions_text, format_table
from bayesbeam.jobs.tasks import cached_record, json_key, write_task_files

__all__ = [
    "DATA_DIR",
    "DEMO_SETTINGS",
    "DIAGNOSIS_SETTINGS",
    "MODELS",
    "QUICK_DIAGNOSIS",
    "QUICK_SETTINGS",
    "DemoError",
    "Replication",
    "find_data",
    "list_trials",
    "run_demo",
    "run_diagnosis_task",
    "run_replication",
]


def _shipped_trials() -> Path:
    """Return the folder of the example trials that ship with the package.

    The trials live in the repository's top-level ``data/``. A wheel (``pip install
    bayesbeam``, ``pip install .``) installs that folder as ``bayesbeam/examples``
    (``[tool.setuptools.package-dir]`` in ``pyproject.toml``), found here through
    :mod:`importlib.resources`, so the demo runs from any working directory. An editable
    install (``pip install -e .``) and a bare source checkout leave the files at ``data/``
    beside the package folder: setuptools' editable finder does not resolve a subpackage
    mapped onto a folder without ``__init__.py``, and ``data/`` holds no Python.

    Returns
    -------
    Path
        ``bayesbeam/examples`` of an installed package when it is a folder on disk, else
        ``data/`` of the source checkout (which :func:`find_data` checks).
    """
    installed = resources.files("bayesbeam").joinpath("examples")
    # A package imported from a zip archive gives a Traversable, not a folder the trial
    # reader can open; it then falls back to the checkout's data/ (and find_data says so).
    if isinstance(installed, Path) and installed.is_dir():
        return installed
    return Path(__file__).resolve().parents[2] / "data"  # the repo root, beside the package


#: The shipped trials: ``bayesbeam/examples`` in an installed wheel, ``data/`` in a source
#: checkout or an editable install (:func:`_shipped_trials`).
DATA_DIR = _shipped_trials()

#: The source study's three damping models.
MODELS: tuple[str, ...] = ("viscous", "viscous+kv", "viscous+sh")

#: Fit settings of the demo (see the module docstring; keys of
#: :data:`bayesbeam.jobs.tasks.DEFAULT_SETTINGS`).
DEMO_SETTINGS: dict[str, Any] = {
    "n_elements": 8,
    "nwalkers": 24,
    "target_ess": 100.0,
    "max_steps": 400,
    "min_steps": 100,
    "n_loo_draws": 200,
    "ppc_draws": 60,
    "plot_dpi": 80,
}

#: ``--quick``: the first trial of each beam only, and shorter chains.
QUICK_SETTINGS: dict[str, Any] = {**DEMO_SETTINGS, "max_steps": 300}

#: Diagnosis of one trial (beam 1: flexible, broad-kernel spatial hysteresis in truth).
DIAGNOSIS_SETTINGS: dict[str, Any] = {
    "trial": "beam1-trial1",
    "baseline": "viscous",
    "candidates": ("kv", "sh", "tip_mass", "root_spring", "stiffness_gradient", "ar1_noise",
                   "sensor_offset"),
    "max_rounds": 2,
    "confirm_top": 2,
    "n_elements": 8,
    "target_ess": 100.0,
    "min_steps": 100,
    "max_steps": 400,
    "loo_draws": 200,
}

#: What ``plots=...`` of :func:`run_replication` draws figures for.
_FIGURES = {"first": "the first trial of each beam", "all": "every trial", "none": "no trial"}

#: ``--quick``: one diagnosis round with fewer candidates.
QUICK_DIAGNOSIS: dict[str, Any] = {**DIAGNOSIS_SETTINGS, "max_rounds": 1, "confirm_top": 1,
                                   "candidates": ("kv", "sh", "root_spring", "ar1_noise"),
                                   "max_steps": 300}


class DemoError(ValueError):
    """The demo cannot run (e.g. the data folder is missing); the message says why."""


# --------------------------------------------------------------------------- data


def find_data(data_dir: str | Path | None = None) -> Path:
    """Return the folder of the shipped trials.

    Parameters
    ----------
    data_dir : path, optional
        Use this folder instead of :data:`DATA_DIR` (the example trials installed with
        the package; see :func:`_shipped_trials`).

    Returns
    -------
    Path
        The folder, as given (default :data:`DATA_DIR`, an absolute path that does not
        depend on the working directory).

    Raises
    ------
    DemoError
        If the folder holds no trial TOML; the message says where it looked.
    """
    d = Path(data_dir) if data_dir is not None else DATA_DIR
    if not d.is_dir() or not any(d.glob("beam*-trial*.toml")):
        where = (
            "pass --data DIR with a folder of trial files" if data_dir is not None else
            "the example trials install with the package (bayesbeam/examples; data/ beside "
            "the package in a source checkout): reinstall bayesbeam, or pass --data DIR"
        )
        raise DemoError(
            f"no shipped trials found: looked for beam*-trial*.toml in {d.resolve()}; {where}"
        )
    return d


def list_trials(data_dir: str | Path | None = None, *, beams: Sequence[str] | None = None,
                trials: Sequence[int] | None = None) -> list[Path]:
    """Trial TOML files of the shipped data, ordered by beam then trial.

    Parameters
    ----------
    data_dir : path, optional
    beams : sequence of str, optional
        e.g. ``["beam1"]`` (default all).
    trials : sequence of int, optional
        Trial numbers, e.g. ``[1, 2]`` (default all).

    Returns
    -------
    list of Path
    """
    d = find_data(data_dir)
    out = []
    for p in sorted(d.glob("beam*-trial*.toml")):
        beam, _, num = p.stem.partition("-trial")
        if beams is not None and beam not in beams:
            continue
        if trials is not None and int(num) not in trials:
            continue
        out.append(p)
    if not out:
        raise DemoError(f"no trials in {d} match beams={beams}, trials={trials}")
    return out


# --------------------------------------------------------------------------- diagnosis


def run_diagnosis_task(spec: Mapping[str, Any]) -> tuple[dict[str, bytes], dict[str, Any], float]:
    """Diagnose one trial and return the files to write (an executor task).

    Parameters
    ----------
    spec : mapping
        ``trial`` (the :class:`~bayesbeam.trials.trial.Trial` itself: its data travel
        with the task, the worker reads no file), ``seed`` and the other keys of
        :data:`DIAGNOSIS_SETTINGS`; ``trial_file`` and ``key`` are provenance only.

    Returns
    -------
    files : dict of str to bytes
        ``diagnosis.json``, ``diagnosis.md`` and signature figures.
    record : dict
        The diagnosis JSON record.
    seconds : float
    """
    import tempfile

    from bayesbeam._util import job_guard
    from bayesbeam.diagnosis.diagnose import diagnose

    t0 = time.perf_counter()
    with job_guard():  # alone in its process, one BLAS thread (as every fit task)
        trial = spec["trial"]
        d = diagnose(
            trial, spec["baseline"], seed=int(spec["seed"]), max_rounds=int(spec["max_rounds"]),
            candidates=tuple(spec["candidates"]), n_elements=int(spec["n_elements"]),
            confirm_top=int(spec["confirm_top"]), target_ess=float(spec["target_ess"]),
            min_steps=int(spec["min_steps"]), max_steps=int(spec["max_steps"]),
            loo_draws=int(spec["loo_draws"]),
        )
        record = d.to_json_dict()
        files = {
            "diagnosis.json": (json.dumps(record, indent=2, allow_nan=False) + "\n").encode(),
            "diagnosis.md": d.narrative().encode(),
        }
        try:
            from bayesbeam.diagnosis.signatures import plot_signatures
        except ImportError:  # optional figure; the JSON and narrative are the result
            plot_signatures = None
        if plot_signatures is not None:
            with tempfile.TemporaryDirectory() as tmp:
                for tag, sig in (("before", d.signatures_before), ("after", d.signatures_after)):
                    if sig is None:
                        continue
                    fig = plot_signatures(sig, title=f"{trial.name}: residual signatures, "
                                                     f"{tag} the diagnosis")
                    path = Path(tmp) / f"signatures_{tag}.png"
                    fig.savefig(path, dpi=75)
                    files[path.name] = path.read_bytes()
    return files, record, time.perf_counter() - t0


def _diagnosis_spec(trial_file: Path, seed: int, settings: Mapping[str, Any]
                    ) -> tuple[dict[str, Any], Any]:
    """Return the diagnosis task's JSON record (with its cache key) and its trial.

    The trial is read here, by the caller, and travels with the task
    (:func:`run_diagnosis_task` gets ``{**spec, "trial": trial}``): a worker of a
    cluster, or one started in another folder, could not resolve ``trial_file`` (a
    relative ``--data`` path). The key is the SHA-256 of the settings, the seed and the
    SHA-256s of the data and the TOML, not of the path.
    """
    from bayesbeam.trials.io import read_trial

    trial_file = Path(trial_file).resolve()
    trial = read_trial(trial_file)
    spec = {k: v for k, v in settings.items() if k != "trial"}
    spec["candidates"] = list(spec["candidates"])
    spec.update({"trial_file": str(trial_file), "seed": int(seed)})
    key_src = {k: v for k, v in spec.items() if k != "trial_file"}
    key_src["data_sha256"] = trial.sha256
    key_src["toml_sha256"] = file_sha256(trial_file)
    spec["key"] = json_key(key_src)
    return spec, trial


# --------------------------------------------------------------------------- overlay


def _overlay(trial: Any, trial_dir: Path, models: Sequence[str], dpi: int) -> None:
    """``fits.png``: the data with every model's MAP signal, and their residuals."""
    import numpy as np
    from matplotlib.figure import Figure

    from bayesbeam.inference.problem import Problem
    from bayesbeam.inference.results import FitResult

    t, y = np.asarray(trial.times), np.asarray(trial.values)
    fig = Figure(figsize=(10, 6.4), layout="constrained")
    ax1, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=[1.3, 1])
    ax1.plot(t, 1e3 * y, color="k", lw=0.7, label="data")
    offset = 0.0
    for i, m in enumerate(models):
        folder = trial_dir / m
        if not (folder / "posterior.nc").is_file():
            continue
        res = FitResult.load(folder)
        if res.map_u is None:
            continue
        s = res.settings
        pb = Problem(trial, m, res.priors,
                     n_elements=int(s.get("n_elements", FIT_DEFAULTS.n_elements)),
                     initial=str(s.get("initial", FIT_DEFAULTS.initial)))
        pred = pb.predict(pb.theta(np.asarray(res.map_u)[None])).y[0]
        ax1.plot(t, 1e3 * pred, lw=0.8, ls="--", color=f"C{i}", label=f"{m} (MAP)")
        r = 1e6 * (y - pred)
        step = 6 * float(np.std(r))
        ax2.plot(t, r - offset, lw=0.5, color=f"C{i}",
                 label=f"{m}: RMS {np.sqrt(np.mean(r**2)):.1f} µm")
        offset += max(step, 1e-9)
    ax1.set_ylabel("tip displacement [mm]")
    ax1.legend(loc="upper right", fontsize="small")
    ax1.set_title(f"{trial.name}: data and fitted models")
    ax2.set_ylabel("residual [µm] (offset per model)")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="upper right", fontsize="small")
    with atomic_path(trial_dir / "fits.png") as tmp:
        fig.savefig(tmp, dpi=dpi)


# --------------------------------------------------------------------------- main


@dataclass(frozen=True)
class Replication:
    """Outcome of :func:`run_replication`.

    Attributes
    ----------
    outdir : Path
    rows : list of dict
        :func:`beam_summary` rows.
    table : str
        :func:`format_table` text.
    comparisons : dict
        ``{trial: comparison JSON}``.
    scores : dict
        ``{trial: {model: score.json record}}``.
    diagnosis : dict or None
        The diagnosis JSON record, if one was run.
    joint : list of dict
        Per beam with at least two trials, the joint fit's record
        (:func:`bayesbeam.jobs.joint_task.joint_record`); empty if none was run.
    report : Path or None
        The HTML report.
    seconds : dict
        Wall-clock seconds: ``fits`` (with the diagnosis, run beside them),
        ``comparisons``, ``report``, ``total``.
    record : dict
        Contents of ``replication.json``.
    """

    outdir: Path
    rows: list
    table: str
    comparisons: dict
    scores: dict
    diagnosis: dict | None
    joint: list
    report: Path | None
    seconds: dict
    record: dict


def run_replication(
    outdir: str | Path,
    *,
    data_dir: str | Path | None = None,
    beams: Sequence[str] | None = None,
    trials: Sequence[int] | None = None,
    models: Sequence[str] = MODELS,
    settings: Mapping[str, Any] | None = None,
    seed: int = 0,
    jobs: int | None = 1,
    scheduler: Any = None,
    plots: str = "first",
    diagnosis: Mapping[str, Any] | bool | None = True,
    joint: bool = True,
    report: bool = True,
    force: bool = False,
    progress: bool | Callable[[str], None] = True,
    run_id: str | None = None,
) -> Replication:
    """Fit, compare and summarise every (trial, model); diagnose one trial; write a report.

    Parameters
    ----------
    outdir : path
        Output folder (created). Results already there with the same key are reused.
    data_dir : path, optional
        Folder of the trials (default the shipped ``data/``).
    beams, trials : optional
        Subsets, e.g. ``beams=["beam1"]``, ``trials=[1]``.
    models : sequence of str
    settings : mapping, optional
        Fit settings (keys of :data:`bayesbeam.jobs.tasks.DEFAULT_SETTINGS`); default the
        package defaults (a full study). The demo passes :data:`DEMO_SETTINGS`.
    seed : int
        Seed of every fit.
    jobs, scheduler
        Executor (see :func:`bayesbeam.jobs.executor.make_executor`).
    plots : {"first", "all", "none"}
        Which trials get per-fit figures (fit, residual spectrum, corner) and the
        overlay of all models: the first trial of each beam, all, or none.
    diagnosis : mapping, bool or None
        True: :data:`DIAGNOSIS_SETTINGS`; a mapping overrides them; False/None: no
        diagnosis. Skipped (with a message) if its trial is not among the trials run.
    joint : bool
        Fit each beam's trials jointly (:mod:`bayesbeam.jobs.joint_task`; beams with at
        least two trials): E shared, the damping pooled, the model the per-trial
        evidence favours. Run beside the diagnosis, cached like the fits.
    report : bool
        Write ``report.html``.
    force : bool
        Recompute cached results.
    progress : bool or callable
        True: messages on stderr and a progress bar of the fits
        (:func:`bayesbeam.jobs.executor.run_fits`); a callable receives the messages
        and one line per finished fit; False: silent.
    run_id : str, optional
        Id of the command run, written into ``replication.json`` (``run_id``).

    Returns
    -------
    Replication
    """
    from bayesbeam._util import distribution_version
    from bayesbeam.comparison.compare import compare_scores
    from bayesbeam.jobs.executor import _progress_sink, load_score, make_executor, run_fits
    from bayesbeam.jobs.tasks import DEFAULT_SETTINGS, fit_tasks

    t_start = time.perf_counter()
    if plots not in ("first", "all", "none"):
        raise DemoError(f"plots must be 'first', 'all' or 'none', got {plots!r}")
    sink = _progress_sink(progress)
    say: Callable[[str], None] = sink if sink is not None else _ignore
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    files = list_trials(data_dir, beams=beams, trials=trials)
    base = {**DEFAULT_SETTINGS, **dict(settings or {})}
    first_of_beam: dict[str, Path] = {}
    for f in files:
        first_of_beam.setdefault(beam_of(f.stem), f)
    tasks = []
    for f in files:
        want = plots == "all" or (plots == "first" and first_of_beam[beam_of(f.stem)] == f)
        tasks += fit_tasks([f], models, seed=seed, settings={**base, "plots": want})

    diag_spec = diag_trial = None
    if diagnosis:
        dset = {**DIAGNOSIS_SETTINGS, **(diagnosis if isinstance(diagnosis, Mapping) else {})}
        match = [f for f in files if f.stem == dset["trial"]]
        if not match:
            say(f"diagnosis skipped: its trial {dset['trial']} is not among the trials run")
        else:
            diag_spec, diag_trial = _diagnosis_spec(match[0], seed, dset)
    say(f"bayesbeam demo: {len(files)} trials x {len(models)} models = {len(tasks)} fits"
        + (f" + diagnosis of {Path(diag_spec['trial_file']).stem}" if diag_spec else "")
        + f"; executor: {scheduler or f'{jobs} local process(es)'}")
    say("settings: " + ", ".join(f"{k}={base[k]}" for k in (
        "n_elements", "nwalkers", "target_ess", "max_steps", "min_steps", "n_loo_draws")))

    diag_record = None
    diag_dir = None
    with make_executor(jobs, scheduler) as ex:
        diag_future = None
        if diag_spec is not None:
            diag_dir = outdir / f"diagnosis-{Path(diag_spec['trial_file']).stem}"
            diag_record = None if force else cached_record(diag_dir, diag_spec["key"],
                                                           "diagnosis.json")
            if diag_record is None and ex is not None:
                # Submitted first: the longest task starts while the fits fill the other slots.
                diag_future = ex.submit(run_diagnosis_task, {**diag_spec, "trial": diag_trial})
        outcomes = run_fits(tasks, outdir, executor=ex, jobs=jobs, force=force,
                            progress=progress, stage="demo fits")
        # Rank the models per trial (cached and fresh results alike): the joint fits
        # take the model the evidence favours, and run beside the diagnosis.
        t_comp0 = time.perf_counter()
        by_trial: dict[str, list[Any]] = {}
        for o in outcomes:
            by_trial.setdefault(o.task.trial_name, []).append(o)
        comparisons: dict[str, dict[str, Any]] = {}
        scores: dict[str, dict[str, Any]] = {}
        for tname, outs in by_trial.items():
            comp = compare_scores([load_score(o.path) for o in outs])
            comp.save(outdir / tname, fits=False)
            comparisons[tname] = comp.to_json_dict()
            scores[tname] = {o.task.model: o.score for o in outs}
        rows = beam_summary(scores, comparisons, [m for m in models])
        t_comp = time.perf_counter() - t_comp0
        joint_runs = start_joint(ex, files, rows, models, seed, base, outdir, force, say
                                 ) if joint else []
        if diag_spec is not None and diag_record is None:
            if diag_future is not None:
                dfiles, diag_record, dsec = diag_future.result()
            else:
                say("diagnosis: running (serial)...")
                dfiles, diag_record, dsec = run_diagnosis_task({**diag_spec, "trial": diag_trial})
            write_task_files(diag_dir, dfiles, {"key": diag_spec["key"], "spec": diag_spec,
                                            "seconds": dsec})
            say(f"diagnosis of {diag_record.get('trial')}: named causes "
                f"{diag_record.get('named_causes') or 'none'} ({dsec:.0f} s)")
        elif diag_record is not None:
            say(f"diagnosis of {diag_record.get('trial')}: cached")
        joint_records = finish_joint(joint_runs, say)
    t_fits = time.perf_counter()

    t_plot0 = time.perf_counter()
    for tname, outs in by_trial.items():
        if plots == "all" or (plots == "first"
                              and first_of_beam[beam_of(tname)].stem == tname):
            _overlay(outs[0].task.trial, outdir / tname, models,
                     int(base.get("plot_dpi", 90)))
    t_comp += time.perf_counter() - t_plot0

    table = format_table(rows)
    truth = None
    tpath = find_data(data_dir) / "truth.toml"
    if tpath.is_file():
        truth = read_toml(tpath, what="truth file", error=DemoError)
    conclusions = conclusions_text(rows, truth)
    joint_table = format_joint_table(joint_records, rows) if joint_records else ""
    task_cpu = sum(float(o.score.get("task_cpu_seconds") or 0.0) for o in outcomes
                   if not o.cached)
    record = {
        "table_text": table,
        "conclusions": conclusions,
        "joint_table_text": joint_table or None,
        "joint": joint_records,
        "settings_text": "Fit settings: " + ", ".join(
            f"{k}={v}" for k, v in base.items() if k != "plots")
        + f"; figures for {_FIGURES[plots]}.",
        "rows": [{**r, "params": {k: list(v) for k, v in r["params"].items()}} for r in rows],
        "models": list(models),
        "seed": seed,
        "schema_version": SCHEMA_VERSION,
        "run_id": run_id,
        "settings": base,
        "diagnosis_settings": None if diag_spec is None else
        {k: v for k, v in diag_spec.items() if k != "trial_file"},
        "diagnosis": None if diag_record is None else {
            k: diag_record.get(k) for k in ("trial", "baseline", "final_model", "named_causes",
                                            "verdict")},
        "data": {f.stem: {"toml": f.name, "toml_sha256": file_sha256(f),
                          "data_sha256": next(t.data_sha256 for t in tasks
                                              if t.trial_name == f.stem)} for f in files},
        "provenance": {"bayesbeam": distribution_version("bayesbeam"),
                       "python": platform.python_version(),
                       "platform": platform.platform(), "executor":
                       str(scheduler) if scheduler else f"{jobs} local process(es)"},
        "timing": {
            "fits_and_diagnosis_s": round(t_fits - t_start - t_comp, 1),
            "comparisons_s": round(t_comp, 1),
            "fits_computed": sum(not o.cached for o in outcomes),
            "fits_cached": sum(o.cached for o in outcomes),
            "fit_cpu_s": round(task_cpu, 1),
        },
        "comparisons": {t: {k: c.get(k) for k in ("best", "indistinguishable", "verdict")}
                        for t, c in comparisons.items()},
    }
    rep_path = None
    t_rep0 = time.perf_counter()
    write_text_atomic(outdir / "replication.txt", table + "\n\n" + conclusions + "\n"
                      + (f"\n{joint_table}\n" if joint_table else ""))
    _write_json(outdir / "replication.json", record)
    if report:
        from bayesbeam.report.html import write_report

        rep_path = write_report(outdir, title="bayesbeam: source replication on the shipped "
                                              "data")
    t_end = time.perf_counter()
    seconds = {"fits": t_fits - t_start - t_comp, "comparisons": t_comp,
               "report": t_end - t_rep0, "total": t_end - t_start}
    record["timing"].update({"report_s": round(seconds["report"], 1),
                             "total_s": round(seconds["total"], 1)})
    _write_json(outdir / "replication.json", record)
    return Replication(outdir=outdir, rows=rows, table=table, comparisons=comparisons,
                       scores=scores, diagnosis=diag_record, joint=joint_records,
                       report=rep_path, seconds=seconds,
                       record=record)


def _ignore(line: str) -> None:
    """Progress sink of ``progress=False``: drop the line."""


def _write_json(path: Path, obj: Any) -> None:
    write_text_atomic(path, json.dumps(finite_json(obj), indent=2, allow_nan=False) + "\n")


def run_demo(
    outdir: str | Path = "bayesbeam-demo",
    *,
    jobs: int | None = None,
    quick: bool = False,
    scheduler: Any = None,
    data_dir: str | Path | None = None,
    force: bool = False,
    progress: bool | Callable[[str], None] = True,
    run_id: str | None = None,
) -> Replication:
    """Run the ``bayesbeam demo`` job: :func:`run_replication` with the demo settings.

    All trials (or the first of each beam with ``quick``), :data:`MODELS`, seed 0,
    figures for the first trial of each beam, the diagnosis and the HTML report.

    Parameters
    ----------
    outdir : path
        Output folder (default ``./bayesbeam-demo``).
    jobs : int, optional
        Worker processes (default: one per CPU core).
    quick : bool
        First trial of each beam only, shorter chains (:data:`QUICK_SETTINGS`) and a
        one-round diagnosis (:data:`QUICK_DIAGNOSIS`).
    scheduler : str, optional
        Dask scheduler address.
    data_dir : path, optional
        Trials folder (default the shipped ``data/``).
    force : bool
        Recompute cached results.
    progress : bool or callable
    run_id : str, optional
        See :func:`run_replication`.

    Returns
    -------
    Replication
    """
    import os

    if jobs is None:
        jobs = os.cpu_count() or 1
    return run_replication(
        outdir, data_dir=data_dir, trials=[1] if quick else None,
        settings=QUICK_SETTINGS if quick else DEMO_SETTINGS, jobs=jobs, scheduler=scheduler,
        diagnosis=QUICK_DIAGNOSIS if quick else True, force=force, progress=progress,
        run_id=run_id,
    )
