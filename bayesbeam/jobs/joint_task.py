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

import json
import math
import tempfile
import textwrap
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bayesbeam._util import finite_json, interval_digits
from bayesbeam.physics.models import parse_model

__all__ = ["STRENGTH", "format_joint_table", "joint_model", "pooled_names", "run_joint_task"]

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
