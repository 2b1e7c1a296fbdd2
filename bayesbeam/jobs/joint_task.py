"""The demo's joint fits: each beam's trials in one posterior, E shared, damping pooled.

One task per beam (:func:`run_joint_task`, an executor job like the diagnosis): the model
is the one the per-trial evidence favours for that beam (:func:`joint_model`: the simplest
of the models that are best or tied with the best by ``Σ log Z``), Young's modulus is
shared by the beam's trials, the strength of each damping law (``gamma``, ``c_d``, and
``eta`` for spatial hysteresis) is pooled (one value per trial drawn from a log-normal
population whose median and spread are sampled, :mod:`bayesbeam.inference.joint`), and
everything else (the kernel width ``b``, the release amplitude, the noise) is per trial.

What it answers: how much narrower E is when the five records are fitted as the one beam
they are (about ``sqrt(n)`` narrower than one trial for equally informative trials), and
whether the damping differs between trials (a population spread consistent with zero says
one value serves them all). :func:`format_joint_table` prints both beside the per-trial
table of :func:`bayesbeam.jobs.summary.format_table`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
import textwrap
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from bayesbeam._util import file_sha256, finite_json, interval_digits
from bayesbeam.jobs.tasks import cached_record, json_key, write_task_files
from bayesbeam.physics.models import parse_model

__all__ = ["STRENGTH", "finish_joint", "format_joint_table", "joint_model", "joint_specs",
           "pooled_names", "run_joint_task", "start_joint"]

#: The pooled strength of each damping law (spatial hysteresis is sampled as ``eta``).
STRENGTH: dict[str, str] = {"viscous": "gamma", "kv": "c_d", "sh": "eta"}


def pooled_names(model: str) -> tuple[str, ...]:
    """Return the strengths of the model's damping laws, in the model's order.

    Parameters
    ----------
    model : str

    Returns
    -------
    tuple of str
    """
    return tuple(STRENGTH[law] for law in parse_model(model).laws)


def joint_model(rows: Sequence[Mapping[str, Any]], beam: str, models: Sequence[str]
                ) -> str | None:
    """Return the model of a beam's joint fit: the simplest best or tied with the best.

    Parameters
    ----------
    rows : sequence of dict
        :func:`bayesbeam.jobs.summary.beam_summary` rows.
    beam : str
    models : sequence of str
        The models in order of increasing complexity (the demo's order).

    Returns
    -------
    str or None
        None when no model of the beam has an evidence.
    """
    top = {r["model"] for r in rows if r["beam"] == beam
           and str(r.get("verdict", "")).startswith(("best", "tied"))}
    return next((m for m in models if m in top), None)


def run_joint_task(spec: Mapping[str, Any]) -> tuple[dict[str, bytes], dict[str, Any], float]:
    """Fit one beam's trials jointly and return the files to write (an executor task).

    Parameters
    ----------
    spec : mapping
        ``trials`` (the :class:`~bayesbeam.trials.trial.Trial` objects: their data
        travel with the task), ``beam``, ``model``, ``shared``, ``pooled``, ``seed`` and
        ``settings`` (keyword arguments of
        :func:`~bayesbeam.inference.joint_fit.fit_joint`); other keys are provenance.

    Returns
    -------
    files : dict of str to bytes
        ``summary.json`` (the joint fit's record) and ``corner.png`` (the shared and
        population parameters).
    record : dict
        What the demo's table needs (:func:`joint_record`).
    seconds : float
    """
    from bayesbeam._util import job_guard
    from bayesbeam.inference.joint_fit import fit_joint

    t0 = time.perf_counter()
    with job_guard(), warnings.catch_warnings(record=True) as caught:
        # Every warning (not converged, a bad Pareto k) is a finding of this fit: kept in
        # its record and printed under the table, not raised in a worker process.
        warnings.simplefilter("always")
        jf = fit_joint(list(spec["trials"]), spec["model"], shared=tuple(spec["shared"]),
                       pooled=tuple(spec["pooled"]), seed=int(spec["seed"]), progress=False,
                       **dict(spec["settings"]))
    notes = list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    payload = jf.to_json_dict()
    files = {"summary.json": (json.dumps(payload, indent=2, allow_nan=False) + "\n").encode()}
    jp = jf.problem
    top = [*jp.shared, *(f"{n}_{s}" for n in jp.pooled for s in ("median", "spread"))]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "corner.png"
        jf.result.plot_corner(path, names=top, dpi=70)
        files[path.name] = path.read_bytes()
    seconds = time.perf_counter() - t0
    return files, joint_record(spec, payload, notes, seconds), seconds


def joint_record(spec: Mapping[str, Any], payload: Mapping[str, Any], notes: Sequence[str],
                 seconds: float) -> dict[str, Any]:
    """Return the demo's record of one joint fit (from its ``summary.json`` payload).

    Parameters
    ----------
    spec : mapping
        The task (:func:`run_joint_task`).
    payload : mapping
        :meth:`~bayesbeam.inference.joint_fit.JointFit.to_json_dict`.
    notes : sequence of str
        Warnings of the fit.
    seconds : float

    Returns
    -------
    dict
        ``beam``, ``model``, ``shared``, ``pooled``, ``labels``, ``posterior`` (the
        shared and population parameters' summaries), ``converged``, ``ess_min``,
        ``tau_max``, ``adequate`` (per trial), ``notes``, ``seconds``.
    """
    post = payload["posterior"]
    keep = [*spec["shared"], *(f"{n}_{s}" for n in spec["pooled"] for s in ("median", "spread"))]
    return finite_json({
        "beam": spec["beam"], "model": spec["model"], "shared": list(spec["shared"]),
        "pooled": list(spec["pooled"]), "labels": list(payload["joint"]["labels"]),
        "posterior": {n: post[n] for n in keep if n in post},
        "converged": bool(payload.get("converged")), "ess_min": payload.get("ess_min"),
        "tau_max": payload.get("tau_max"),
        "adequate": {lb: bool(t["adequacy"].get("ok")) for lb, t in payload["trials"].items()},
        "notes": list(notes), "seconds": round(float(seconds), 1),
    })


def _interval(s: Mapping[str, float], scale: float = 1.0) -> str:
    lo, mid, hi = (scale * float(s[k]) for k in ("q05", "q50", "q95"))
    d = interval_digits(mid, lo, hi, minimum=3)
    return f"{mid:#.{d}g} [{lo:#.{d}g}, {hi:#.{d}g}]"


def format_joint_table(records: Sequence[Mapping[str, Any]],
                       rows: Sequence[Mapping[str, Any]]) -> str:
    """Plain-text table of the joint fits, set against the per-trial fits.

    Parameters
    ----------
    records : sequence of dict
        :func:`joint_record` outputs, one per beam (a record with ``error`` instead:
        a fit that failed, listed under the table).
    rows : sequence of dict
        :func:`bayesbeam.jobs.summary.beam_summary` rows (for the single-trial E sd).

    Returns
    -------
    str
    """
    head = ["beam", "model (trials)", "E [GPa] joint, 90 %", "E sd: one trial / joint",
            "damping population: median [90 %]; spread [90 %]", "ESS min", "adequate"]
    body, notes = [], []
    for rec in records:
        if "error" in rec:  # the fit refused its input (the demo's _finish_joint)
            notes.append(f"{rec['beam']}: joint fit of {rec['model']} FAILED: {rec['error']}")
            continue
        post = rec["posterior"]
        n = len(rec["labels"])
        single = next((r for r in rows if r["beam"] == rec["beam"]
                       and r["model"] == rec["model"]), None)
        ratio = "n/a"
        if single is not None and "E" in single["params"] and "E" in post:
            sd1, sdj = float(single["params"]["E"][1]), float(post["E"]["sd"])
            if sdj > 0 and math.isfinite(sd1):
                ratio = f"{sd1 / sdj:.2f} (sqrt({n}) = {math.sqrt(n):.2f})"
        pops = "; ".join(
            f"{p} {_interval(post[p + '_median'])}, spread {_interval(post[p + '_spread'])}"
            for p in rec["pooled"] if p + "_median" in post and p + "_spread" in post)
        ok = sum(rec["adequate"].values())
        body.append([rec["beam"], f"{rec['model']} ({n})",
                     _interval(post["E"], 1e-9) if "E" in post else "n/a", ratio, pops or "-",
                     f"{rec['ess_min']:.0f}" + ("" if rec["converged"] else " (not converged)")
                     if rec.get("ess_min") is not None else "n/a", f"{ok}/{n}"])
        notes += [f"{rec['beam']}: {x}" for x in rec.get("notes", [])]
    widths = [max(len(h), *(len(b[j]) for b in body)) if body else len(h)
              for j, h in enumerate(head)]
    lines = ["  ".join(h.ljust(widths[j]) for j, h in enumerate(head))]
    lines.append("-" * len(lines[0]))
    lines += ["  ".join(c.ljust(widths[j]) for j, c in enumerate(b)) for b in body]
    legend = (
        "Joint fits: each beam's trials in one posterior, the model the per-trial evidence "
        "favours (the simplest best or tied), E shared, each damping law's strength pooled "
        "(log-normal population: median, and spread = sd of its log; a spread consistent with "
        "zero says one value serves every trial); gamma kg/(m s), c_d Pa s, eta N s m². 'E "
        "sd: one trial / joint': the per-trial fits' RMS posterior sd over the joint one; "
        "about sqrt(n) when every trial is equally informative. 'adequate': trials the joint "
        "fit reproduces to their noise."
    )
    lines += ["", *textwrap.wrap(legend, 100)]
    if notes:
        lines += ["", "Warnings of the joint fits:", *(f"  {x}" for x in notes)]
    return "\n".join(lines)


# --------------------------------------------------------------------------- the demo's runs


def joint_specs(files: Sequence[Path], rows: Sequence[Mapping[str, Any]],
                 models: Sequence[str], seed: int, settings: Mapping[str, Any]
                 ) -> list[tuple[dict[str, Any], list[Any]]]:
    """Return one joint-fit task per beam with at least two trials: (spec with key, trials).

    The model is :func:`joint_model`'s choice from the per-trial evidence; the fit
    settings are the per-trial fits' except the walker count, which the joint fit sizes
    to its dimension.

    Parameters
    ----------
    files : sequence of Path
    rows : sequence of dict
        :func:`bayesbeam.jobs.summary.beam_summary` rows.
    models : sequence of str
    seed : int
    settings : mapping
        The replication's fit settings.

    Returns
    -------
    list of (dict, list of Trial)
    """
    from bayesbeam.inference.settings import FitSettings
    from bayesbeam.jobs.summary import beam_of
    from bayesbeam.trials.io import read_trial

    by_beam: dict[str, list[Path]] = {}
    for f in files:
        by_beam.setdefault(beam_of(f.stem), []).append(Path(f).resolve())
    fit_keys = [f.name for f in dataclasses.fields(FitSettings)]
    fit_settings = {k: settings[k] for k in fit_keys if k in settings}
    fit_settings["nwalkers"] = None
    out = []
    for beam, paths in by_beam.items():
        model = joint_model(rows, beam, models)
        if len(paths) < 2 or model is None:
            continue
        trials = [read_trial(p) for p in paths]
        spec = {"beam": beam, "model": model, "shared": ["E"],
                "pooled": list(pooled_names(model)), "seed": int(seed),
                "settings": fit_settings, "trial_files": [str(p) for p in paths]}
        spec["key"] = json_key({**{k: v for k, v in spec.items() if k != "trial_files"},
                            "data_sha256": [t.sha256 for t in trials],
                            "toml_sha256": [file_sha256(p) for p in paths]})
        out.append((spec, trials))
    return out


def start_joint(ex: Any, files: Sequence[Path], rows: Sequence[Mapping[str, Any]],
                 models: Sequence[str], seed: int, settings: Mapping[str, Any], outdir: Path,
                 force: bool, say: Callable[[str], None]) -> list[dict[str, Any]]:
    """Submit the joint fits that are not cached (run later, serially, without executor).

    Parameters
    ----------
    ex : Executor or None
        Where the fits run (None: in :func:`finish_joint`, serially).
    files : sequence of Path
        The trial files of the replication.
    rows : sequence of dict
        :func:`bayesbeam.jobs.summary.beam_summary` rows (the model choice).
    models : sequence of str
    seed : int
    settings : mapping
        The replication's fit settings.
    outdir : Path
        The joint fits' folders go in ``outdir / "joint-BEAM"``.
    force : bool
        Recompute cached fits.
    say : callable
        Progress lines.

    Returns
    -------
    list of dict
        One run per beam (spec, task, folder, cached record or None, future or None).
    """
    runs = []
    for spec, trials in joint_specs(files, rows, models, seed, settings):
        folder = outdir / f"joint-{spec['beam']}"
        rec = None if force else cached_record(folder, spec["key"], "joint.json")
        task = {**spec, "trials": trials}
        fut = ex.submit(run_joint_task, task) if rec is None and ex is not None else None
        if rec is None:
            say(f"joint fit of {spec['beam']}: {spec['model']} on {len(trials)} trials, "
                f"E shared, pooled {', '.join(spec['pooled'])}"
                + ("" if fut is not None else " (serial)"))
        runs.append({"spec": spec, "task": task, "folder": folder, "record": rec,
                     "future": fut})
    return runs


def finish_joint(runs: Sequence[Mapping[str, Any]], say: Callable[[str], None]
                 ) -> list[dict[str, Any]]:
    """Wait for (or run) the joint fits, write their folders, return their records.

    Parameters
    ----------
    runs : sequence of dict
        :func:`start_joint`'s output.
    say : callable
        Progress lines.

    Returns
    -------
    list of dict
        :func:`joint_record` per beam, or ``{"beam", "model", "error"}`` for a fit
        that refused its input.
    """
    records = []
    for run in runs:
        spec, rec = run["spec"], run["record"]
        if rec is not None:
            say(f"joint fit of {spec['beam']}: cached")
        else:
            try:
                files, rec, sec = (run["future"].result() if run["future"] is not None
                                   else run_joint_task(run["task"]))
            except ValueError as exc:
                # The fit's own refusals (JointError, FitError: trials that cannot share
                # a parameter, no finite start) end this beam's joint fit, not the demo's
                # minutes of per-trial results; said here and in the table, not cached.
                say(f"joint fit of {spec['beam']}: FAILED: {exc}")
                records.append({"beam": spec["beam"], "model": spec["model"],
                                "error": str(exc)})
                continue
            files = {**files, "joint.json": (json.dumps(finite_json(rec), indent=2,
                                                        allow_nan=False) + "\n").encode()}
            write_task_files(run["folder"], files, {"key": spec["key"], "spec": spec,
                                                "seconds": sec})
            say(f"joint fit of {spec['beam']}: done ({sec:.0f} s"
                + ("" if rec["converged"] else ", not converged") + ")")
        records.append(rec)
    return records
