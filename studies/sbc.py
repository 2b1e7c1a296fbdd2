"""Simulation-based coverage of the default fit: do 90 % intervals hold 90 % of the truths.

Each trial draws a true parameter set, simulates the record a real sensor would give, adds
white noise, fits ``viscous+kv`` (the generating model) with every setting at its package
default (:func:`bayesbeam.inference.fit.fit`, mesh refined automatically), and records
whether the truth lies in the central 90 % posterior interval ``[q05, q95]`` of each of
E, gamma, c_d, the initial-condition amplitude (w0 or p0) and the noise sd sigma, together
with the posterior rank of the truth (share of draws below it), convergence, adequacy
(:mod:`bayesbeam.inference.adequacy`), the final mesh and the wall time.

No inverse crime: the data come from
:func:`bayesbeam.trials.synthetic.simulate_sensor` (64 Hermite elements, finer than any
mesh the fit reaches here, every mode, on a 16x faster grid, through a zero-phase Kaiser
FIR anti-alias filter with pass band to 200 Hz, then interpolated onto the stamps), while
the fit uses its own mesh ladder (8-48 elements) and an ideal band limit.

Design (crossed, balanced: trial ``i`` falls in cell ``i % 8``, so any prefix of the run
is balanced to within one trial per cell)

* quantity {displacement, acceleration} x excitation {release (``initial="release"``),
  tap (``initial="impulse"``)} x stamps {uniform, jittered (each step
  ``dt (1 + U(-0.15, 0.15))``)};
* two geometries, alternating within each cell (``(i // 8) % 2``): an aluminium strip
  0.4 m x 50.8 mm x 2 mm (density 2700 kg/m^3, nominal E 70 GPa; f1 = 10.3 Hz, modes at
  65 and 181 Hz in band, the 4th at 354 Hz above Nyquist) and a steel strip 0.3 m x 25 mm
  x 1 mm (7850 kg/m^3, 200 GPa; f1 = 9.1 Hz, modes at 57 and 159 Hz in band, the 4th at
  312 Hz). The thicknesses keep every mode clear of the filter's transition band
  (200-256 Hz) over the whole E range, where neither the FIR filter nor the fit's ideal
  band limit can be said to represent the sensor (a 1.5 mm steel strip puts mode 3 at
  238 Hz);
* 512 Hz, 1280 samples (2.5 s), the first at 0.06 s after the release / tap at t0 = 0
  (the FIR filter's half length is 0.053 s);
* truths per trial from ``numpy.random.default_rng(SeedSequence(base_seed,
  spawn_key=(i,)))``: ``E = E_nominal U(0.85, 1.15)``; viscous first-mode damping ratio
  ``zeta_v1`` log-uniform in [0.1 %, 2 %] (``gamma = 2 rhoA omega1 zeta_v1``);
  Kelvin-Voigt first-mode ratio ``zeta_kv1 = c_d omega1 / (2 E)`` log-uniform in
  [0.05 %, 1 %]; amplitude ``a`` U(2, 8) mm: a release from ``w0 = a``, or a tap of
  ``p0 = (m/4) omega1 a`` (the tip's mode-1 velocity amplitude ``omega1 a`` in both; m/4
  is the cantilever's first-mode mass at the tip); SNR U(30, 50) dB, noise sd = RMS of the
  noise-free record x 10^(-SNR/20). omega1 is that of the true E.

This is a coverage study at fixed truth ranges, not strict simulation-based calibration:
the truths are not drawn from the fit's priors (log-uniform damping over
zeta in [1e-6, 0.2], E over a factor 16), so where the data say little (KV damping on a
released displacement record, whose higher modes are small) the intervals are shaped by
the prior and need not cover at exactly 90 %.

Pass criterion (from the issue): per parameter, the 90 % intervals cover 85-95 % of the
truths. The table gives each coverage with its binomial standard error
``sqrt(p (1 - p) / n)``; the tails columns say on which side the misses fell.

A finite set of noise draws covers by luck as well as by calibration (104 trials: the
binomial standard error of a 90 % coverage is 3 %). The table therefore has a yardstick
row, the coverage that an exact linear-Gaussian estimator reaches on the *same* noise
draws (:func:`noise_projection`): where the fit and that estimator agree, the fit's
intervals are as calibrated as these records can show.

Run: ``python studies/sbc.py`` (112 trials = 14 per cell; on a shared 2-core machine with
two workers a converged fit took 40-150 s, one that ran into the 20 000-step budget
12-13 min, so 2-4 hours), ``--quick`` (the first 8 trials, one per cell), or
``--n N --workers W --seed S``. Every finished trial is appended at once to
``figures/sbc_runs.jsonl`` (one JSON record per line) and a re-run skips the trials already
there with the same design (``--no-resume`` starts afresh, ``--retry-errors`` re-runs
fits that raised). Writes ``figures/sbc.json`` (all records and the table) and
``figures/sbc.md`` (the table, ready for a README); ``--quick`` writes ``sbc_quick.*``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
             "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy: one BLAS thread per worker

import argparse  # noqa: E402
import concurrent.futures as cf  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import multiprocessing  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

MODEL = "viscous+kv"
FS = 512.0
N_SAMPLES = 1280
T_FIRST = 0.06
JITTER = 0.15
N_ELEMENTS_DATA = 64
E_RANGE = (0.85, 1.15)
ZETA_V_RANGE = (1e-3, 2e-2)
ZETA_KV_RANGE = (5e-4, 1e-2)
AMP_RANGE = (2e-3, 8e-3)
SNR_DB_RANGE = (30.0, 50.0)
BASE_SEED = 20250
#: Geometries: name -> (length, width, thickness, density, nominal E), SI.
GEOMETRIES = {
    "al-400x50.8x2": (0.4, 0.0508, 0.002, 2700.0, 70e9),
    "steel-300x25x1": (0.3, 0.025, 0.001, 7850.0, 200e9),
}
QUANTITIES = ("displacement", "acceleration")
EXCITATIONS = ("release", "tap")
STAMPS = ("uniform", "jittered")
#: The 8 cells, trial i in CELLS[i % 8].
CELLS = tuple((q, e, s) for q in QUANTITIES for e in EXCITATIONS for s in STAMPS)
PARAMS = ("E", "gamma", "c_d", "amplitude", "sigma")
PASS_RANGE = (0.85, 0.95)
#: A fit's MAP counts as missed when the chain found a point this many nats higher.
MAP_MISS_NATS = 10.0
BETA1 = 1.875104069
FIGURES = Path(__file__).resolve().parent / "figures"


def design(base_seed: int = BASE_SEED) -> dict[str, Any]:
    """Everything that fixes the trials, and its fingerprint.

    Parameters
    ----------
    base_seed : int
        Root of every trial's seed sequence.

    Returns
    -------
    dict
        The design constants plus ``fingerprint`` (12 hex digits of their SHA-256); a
        record is reused by a re-run only when its fingerprint matches.
    """
    d = {"model": MODEL, "fs": FS, "n_samples": N_SAMPLES, "t_first": T_FIRST,
         "jitter": JITTER, "n_elements_data": N_ELEMENTS_DATA, "E_range": E_RANGE,
         "zeta_v_range": ZETA_V_RANGE, "zeta_kv_range": ZETA_KV_RANGE,
         "amp_range": AMP_RANGE, "snr_db_range": SNR_DB_RANGE, "base_seed": base_seed,
         "geometries": GEOMETRIES, "cells": CELLS}
    blob = json.dumps(d, sort_keys=True, default=list).encode()
    return {**d, "fingerprint": hashlib.sha256(blob).hexdigest()[:12]}


def code_version() -> str:
    """Fingerprint (12 hex digits) of the package's source files as they are now.

    Stored in every record: the package changes under a long study, and a re-run
    resumes only by design, so the table reports when its records come from more than
    one version of the code.
    """
    import bayesbeam

    h = hashlib.sha256()
    root = Path(bayesbeam.__file__).resolve().parent
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


def make_trial(i: int, base_seed: int = BASE_SEED) -> tuple[Any, dict[str, Any]]:
    """Build trial ``i`` of the design.

    Parameters
    ----------
    i : int
        Trial index; its cell is ``CELLS[i % 8]``, its geometry alternates with ``i // 8``.
    base_seed : int
        Root seed; the trial's generator is ``SeedSequence(base_seed, spawn_key=(i,))``.

    Returns
    -------
    trial : bayesbeam.trials.trial.Trial
    info : dict
        Cell, geometry, ``initial`` (the fit's initial-condition kind), ``truth`` (SI:
        E, gamma, c_d, amplitude = w0 or p0, sigma = the noise sd) and the drawn ratios.
    """
    from bayesbeam.physics.beam import Beam
    from bayesbeam.trials.synthetic import simulate_sensor
    from bayesbeam.trials.trial import Trial

    quantity, excitation, stamps = CELLS[i % len(CELLS)]
    geo = list(GEOMETRIES)[(i // len(CELLS)) % len(GEOMETRIES)]
    L, w, t, rho, E_nom = GEOMETRIES[geo]
    beam = Beam.rectangular(L, w, t, rho * L * w * t, E=E_nom).replace(quantity=quantity)
    rng = np.random.default_rng(np.random.SeedSequence(base_seed, spawn_key=(i,)))
    # Fixed draw order, so every trial is reproducible from (base_seed, i) alone.
    E = E_nom * rng.uniform(*E_RANGE)
    zeta_v = float(np.exp(rng.uniform(*np.log(ZETA_V_RANGE))))
    zeta_kv = float(np.exp(rng.uniform(*np.log(ZETA_KV_RANGE))))
    amp = rng.uniform(*AMP_RANGE)
    snr_db = rng.uniform(*SNR_DB_RANGE)
    steps = (1.0 + rng.uniform(-JITTER, JITTER, N_SAMPLES - 1)) / FS
    z = rng.standard_normal(N_SAMPLES)
    if stamps == "uniform":
        steps = np.full(N_SAMPLES - 1, 1.0 / FS)
    times = T_FIRST + np.concatenate([[0.0], np.cumsum(steps)])
    w1 = BETA1**2 * np.sqrt(E * beam.I / (beam.rhoA * L**4))
    gamma = 2 * beam.rhoA * w1 * zeta_v
    c_d = 2 * E * zeta_kv / w1
    if excitation == "release":
        initial, ic_name, ic_value, ic_key = "release", "w0", amp, "tip_deflection"
    else:
        initial, ic_name, ic_key = "impulse", "p0", "tip_impulse"
        ic_value = 0.25 * beam.beam_mass * w1 * amp
    params = {"E": E, "gamma": gamma, "c_d": c_d, ic_name: ic_value}
    y = simulate_sensor(beam, MODEL, params, times, t0=0.0, n_elements=N_ELEMENTS_DATA,
                        initial=initial)
    rms = float(np.sqrt(np.mean(y**2)))
    noise_sd = rms * 10 ** (-snr_db / 20)
    trial = Trial(times=times, values=y + noise_sd * z, quantity=quantity, beam=beam,
                  name=f"sbc-{i:03d}-{geo}-{quantity}-{excitation}-{stamps}", t0=0.0,
                  initial={ic_key: float(ic_value)})
    info = {"quantity": quantity, "excitation": excitation, "stamps": stamps,
            "geometry": geo, "initial": initial, "ic_name": ic_name,
            "truth": {"E": E, "gamma": gamma, "c_d": c_d, "amplitude": ic_value,
                      "sigma": noise_sd},
            "zeta_v1": zeta_v, "zeta_kv1": zeta_kv, "amp_m": amp, "snr_db": snr_db,
            "f1_hz": w1 / (2 * np.pi), "signal_rms": rms}
    return trial, info


def run_trial(i: int, base_seed: int, fingerprint: str) -> dict[str, Any]:
    """Simulate and fit trial ``i``; the record of one line of the runs file.

    Parameters
    ----------
    i : int
    base_seed : int
    fingerprint : str
        Design fingerprint stored in the record.

    Returns
    -------
    dict
        ``i``, the cell and truths (see :func:`make_trial`), per parameter ``post``
        (q05, q50, q95, mean, sd), ``covered`` (truth in [q05, q95]), ``rank`` (share of
        posterior draws below the truth), and ``converged``, ``ess_min``, ``rhat_max``,
        ``adequate``, ``adequacy_reasons``, ``noise_ratio``, ``mesh_n_elements``,
        ``mesh_converged``, ``lp_map`` (log posterior at the fit's MAP), ``lp_chain_max``
        (best point of the chain), ``code`` (:func:`code_version`), ``seconds``; or
        ``error`` (traceback) when the fit raised.
    """
    from bayesbeam.inference.fit import fit

    t_start = time.perf_counter()
    rec: dict[str, Any] = {"i": i, "fingerprint": fingerprint, "code": code_version()}
    try:
        trial, info = make_trial(i, base_seed)
        rec.update(info)
        res = fit(trial, MODEL, seed=i, initial=info["initial"], progress=False)
        summ = res.summary()
        names = list(res.names)
        draws = res.theta_samples().reshape(-1, len(names))
        post, covered, rank = {}, {}, {}
        for p in PARAMS:
            name = info["ic_name"] if p == "amplitude" else p
            s, truth = summ[name], info["truth"][p]
            post[p] = {k: s[k] for k in ("q05", "q50", "q95", "mean", "sd")}
            covered[p] = bool(s["q05"] <= truth <= s["q95"])
            rank[p] = float(np.mean(draws[:, names.index(name)] < truth))
        diag = res.diagnostics()
        adeq = res.adequacy or {}
        rec.update(
            post=post, covered=covered, rank=rank,
            converged=bool(diag["converged"]), ess_min=float(diag["ess_min"]),
            rhat_max=float(diag["rhat_max"]), n_steps=int(diag["n_steps_total"]),
            adequate=bool(adeq.get("ok", False)),
            adequacy_reasons=list(adeq.get("reasons", [])),
            noise_ratio=adeq.get("noise_ratio"),
            mesh_n_elements=int(res.mesh["n_elements"]),
            mesh_converged=bool(res.mesh["converged"]),
            fit_seconds=float(res.settings["total_seconds"]),
            # A MAP far below the chain's best point means the optimiser missed the mode
            # (mesh check and walker start were then made at the wrong point).
            lp_map=float(res.settings["log_prob_map"]),
            lp_chain_max=float(np.max(res.chain.log_prob)),
        )
    except Exception:  # record it: a fit that fails is a result of the study
        rec["error"] = traceback.format_exc()
    rec["seconds"] = time.perf_counter() - t_start
    return rec


def noise_projection(rec: dict[str, Any], base_seed: int = BASE_SEED) -> dict[str, bool]:
    """Whether an exact linear-Gaussian estimator would cover each truth on this record.

    The record's data are ``clean + noise``. Linearised at the truth (on the fit's final
    mesh), the least-squares estimate errs by ``Δu = F⁻¹ Jᵀ n / σ²`` (J the Jacobian of
    the prediction in the sampling space, F = JᵀJ/σ²), an exact N(0, F⁻¹) draw for
    white Gaussian n. Its 90 % interval ``|Δu_k| <= 1.645 sqrt(F⁻¹_kk)`` (and the
    chi-square interval of σ from the noise's own sum of squares, N - 4 degrees of
    freedom) covers the truth in exactly 90 % of noise draws, so on a finite set of
    draws it shows how far the realised noise alone moves the coverage: the yardstick
    for the fit's coverage on the same records.

    Parameters
    ----------
    rec : dict
        A fitted record of :func:`run_trial`.
    base_seed : int

    Returns
    -------
    dict of str to bool
        Per parameter of :data:`PARAMS`, the oracle's coverage.
    """
    import scipy.stats

    from bayesbeam.inference.problem import Problem
    from bayesbeam.trials.synthetic import simulate_sensor

    trial, info = make_trial(int(rec["i"]), base_seed)
    T = info["truth"]
    params = {"E": T["E"], "gamma": T["gamma"], "c_d": T["c_d"],
              info["ic_name"]: T["amplitude"]}
    clean = simulate_sensor(trial.beam, MODEL, params, trial.times, t0=0.0,
                            n_elements=N_ELEMENTS_DATA, initial=info["initial"])
    noise = trial.values - clean
    pb = Problem(trial, MODEL, initial=info["initial"], n_elements=rec["mesh_n_elements"])
    x = np.array([[T[p] for p in PARAMS]])  # E, gamma, c_d, w0 / p0, sigma = pb.names
    u0 = pb.priors.to_u(x)[0]
    k = len(PARAMS) - 1
    h = 1e-6  # sampling-space step: the prediction is linear over it to ~1e-12
    U = np.repeat(u0[None], 2 * k, axis=0)
    U[np.arange(0, 2 * k, 2), np.arange(k)] += h
    U[np.arange(1, 2 * k, 2), np.arange(k)] -= h
    Y = pb.predict(pb.theta(U)).y
    J = (Y[0::2] - Y[1::2]).T / (2 * h)
    s = T["sigma"]
    C = np.linalg.inv(J.T @ J / s**2)
    z = (C @ J.T @ noise / s**2) / np.sqrt(np.diag(C))
    out = {p: bool(abs(z[j]) <= scipy.stats.norm.ppf(0.95)) for j, p in enumerate(PARAMS[:k])}
    dof = noise.size - k
    ss = float(np.sum(noise**2))
    lo, hi = (np.sqrt(ss / scipy.stats.chi2.ppf(q, dof)) for q in (0.95, 0.05))
    out["sigma"] = bool(lo <= s <= hi)
    return out


def load_runs(path: Path, fingerprint: str) -> dict[int, dict[str, Any]]:
    """Read the records of ``path`` with this design's fingerprint, by index (last wins)."""
    out: dict[int, dict[str, Any]] = {}
    if not path.exists():
        return out
    for line in path.read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if not line:
            continue
        try:
            r = json.loads(line)
        except json.JSONDecodeError:  # a line cut by an interruption
            continue
        if r.get("fingerprint") == fingerprint:
            out[int(r["i"])] = r
    return out


def _cov(recs: list[dict[str, Any]], p: str) -> dict[str, Any]:
    ok = [r for r in recs if "covered" in r]
    n = len(ok)
    if n == 0:
        return {"n": 0, "coverage": None, "se": None, "below": 0, "above": 0}
    k = sum(r["covered"][p] for r in ok)
    cov = k / n
    below = sum(r["truth"][p] < r["post"][p]["q05"] for r in ok)
    above = sum(r["truth"][p] > r["post"][p]["q95"] for r in ok)
    return {"n": n, "coverage": cov, "se": float(np.sqrt(cov * (1 - cov) / n)),
            "below": int(below), "above": int(above)}


def coverage_table(records: list[dict[str, Any]],
                   oracle: dict[int, dict[str, bool]] | None = None) -> dict[str, Any]:
    """Coverage per parameter, overall and per factor level and cell.

    Parameters
    ----------
    records : list of dict
        Records of :func:`run_trial`.
    oracle : dict, optional
        :func:`noise_projection` per trial index: adds the row of what the noise draws
        alone allow.

    Returns
    -------
    dict
        ``rows`` (label, n, per-parameter coverage dicts), ``verdict`` (PASS/FAIL per
        parameter, overall), and ``converged``, ``adequate``, ``both``, ``errors``,
        ``median_seconds``, ``mesh_counts``.
    """
    fitted = [r for r in records if "covered" in r]
    groups: list[tuple[str, list[dict[str, Any]]]] = [("all", fitted)]
    groups.append(("converged and adequate",
                   [r for r in fitted if r["converged"] and r["adequate"]]))
    for key, levels in (("quantity", QUANTITIES), ("excitation", EXCITATIONS),
                        ("stamps", STAMPS), ("geometry", tuple(GEOMETRIES))):
        groups += [(f"{key} = {lv}", [r for r in fitted if r[key] == lv]) for lv in levels]
    groups += [(" / ".join(c), [r for r in fitted
                                if (r["quantity"], r["excitation"], r["stamps"]) == c])
               for c in CELLS]
    rows = [{"label": lab, "n": len(g), "params": {p: _cov(g, p) for p in PARAMS}}
            for lab, g in groups]
    if oracle:
        for row, (_, g) in zip(rows, groups, strict=True):
            got = [oracle[r["i"]] for r in g if r["i"] in oracle]
            for p in PARAMS:
                row["params"][p]["exact"] = (sum(o[p] for o in got) / len(got)
                                             if got else None)
    verdict = {}
    for p in PARAMS:
        c = rows[0]["params"][p]["coverage"]
        verdict[p] = ("PASS" if c is not None and PASS_RANGE[0] <= c <= PASS_RANGE[1]
                      else "FAIL")
    n = len(fitted)
    secs = [r["seconds"] for r in records]
    mesh = {}
    for r in fitted:
        mesh[r["mesh_n_elements"]] = mesh.get(r["mesh_n_elements"], 0) + 1
    missed_map = [r["i"] for r in fitted
                  if "lp_map" in r and r["lp_chain_max"] - r["lp_map"] > MAP_MISS_NATS]
    return {
        "rows": rows, "verdict": verdict, "n_trials": len(records), "n_fitted": n,
        "map_missed": missed_map,
        "code_versions": sorted({r.get("code", "unknown") for r in records}),
        "errors": len(records) - n,
        "converged": sum(r["converged"] for r in fitted) / n if n else None,
        "adequate": sum(r["adequate"] for r in fitted) / n if n else None,
        "both": sum(r["converged"] and r["adequate"] for r in fitted) / n if n else None,
        "mesh_converged": sum(r["mesh_converged"] for r in fitted) / n if n else None,
        "median_seconds": float(np.median(secs)) if secs else None,
        "mesh_counts": {str(k): v for k, v in sorted(mesh.items())},
    }


def _fmt(c: dict[str, Any]) -> str:
    if c["coverage"] is None:
        return "–"
    txt = f"{100 * c['coverage']:.0f} ± {100 * c['se']:.0f}"
    if c.get("exact") is not None:
        txt += f" ({100 * c['exact']:.0f})"
    return txt


def markdown(table: dict[str, Any], des: dict[str, Any]) -> str:
    """Format the coverage table as markdown (README-ready).

    Parameters
    ----------
    table : dict
        :func:`coverage_table` output.
    des : dict
        :func:`design` output.

    Returns
    -------
    str
    """
    head = ["E", "gamma", "c_d", "w0 / p0", "sigma"]
    md = [f"Coverage of the central 90 % posterior intervals, `{MODEL}` fitted at default "
          f"settings to {table['n_fitted']} synthetic records (fine-mesh, FIR-filtered; "
          f"design {des['fingerprint']}, `studies/sbc.py`). Entries: % of truths inside "
          "[q05, q95] ± binomial standard error; in brackets, the coverage of an exact "
          "linear-Gaussian estimator on the same noise draws (`noise_projection`): it "
          "covers in exactly 90 % of all draws, so on these it differs from 90 % only "
          "by the luck of the draws.", "",
          "| trials | n | " + " | ".join(head) + " |",
          "|---|---|" + "---|" * len(head)]
    for row in table["rows"]:
        md.append(f"| {row['label']} | {row['n']} | "
                  + " | ".join(_fmt(row["params"][p]) for p in PARAMS) + " |")
    all_row = table["rows"][0]["params"]
    md += ["", "Misses below q05 / above q95 (all trials): "
           + "; ".join(f"{h} {all_row[p]['below']} / {all_row[p]['above']}"
                       for h, p in zip(head, PARAMS, strict=True)) + ".",
           "", f"Pass criterion: 90 % intervals cover {100 * PASS_RANGE[0]:.0f}-"
           f"{100 * PASS_RANGE[1]:.0f} % per parameter: "
           + "; ".join(f"{h} {table['verdict'][p]}" for h, p in zip(head, PARAMS, strict=True))
           + "."]

    def pct(x: float | None) -> str:
        return "–" if x is None else f"{100 * x:.0f} %"

    md += ["", f"Converged: {pct(table['converged'])}; adequate: {pct(table['adequate'])}; "
           f"both: {pct(table['both'])}; mesh converged: {pct(table['mesh_converged'])}; "
           f"fits that raised: {table['errors']}. Final meshes (elements: fits): "
           + ", ".join(f"{k}: {v}" for k, v in table["mesh_counts"].items())
           + f". Median time per fit: {table['median_seconds']:.0f} s."]
    if table["map_missed"]:
        md += ["", f"MAP missed (chain found a point > {MAP_MISS_NATS:g} nats higher) in "
               f"{len(table['map_missed'])} fits: trials "
               + ", ".join(map(str, table["map_missed"])) + "."]
    if len(table["code_versions"]) > 1:
        md += ["", "Note: the records come from "
               f"{len(table['code_versions'])} versions of the package code "
               f"({', '.join(table['code_versions'])})."]
    return "\n".join(md) + "\n"


def main(n: int = 112, workers: int = 2, base_seed: int = BASE_SEED, quick: bool = False,
         resume: bool = True, retry_errors: bool = False, outdir: Path | None = None,
         progress: bool = True) -> dict[str, Any]:
    """Run (or complete) the study; print and write the table.

    Parameters
    ----------
    n : int
        Trials (indices 0..n-1; 8 cells, so a multiple of 8 is balanced).
    workers : int
        Parallel fits (processes).
    base_seed : int
        Root seed of the design.
    quick : bool
        The first 8 trials (one per cell); outputs ``sbc_quick.*``.
    resume : bool
        Skip trials already in the runs file with the same design.
    retry_errors : bool
        Re-run trials whose recorded fit raised.
    outdir : path, optional
        Output folder (default ``studies/figures``).
    progress : bool
        One line per finished trial, with an ETA, on stderr.

    Returns
    -------
    dict
        ``records``, ``table``, ``markdown`` and ``paths``.
    """
    if quick:
        n = 8
    outdir = Path(outdir or FIGURES)
    outdir.mkdir(parents=True, exist_ok=True)
    des = design(base_seed)
    runs_path = outdir / "sbc_runs.jsonl"
    done = load_runs(runs_path, des["fingerprint"]) if resume else {}
    if not resume and runs_path.exists():
        runs_path.rename(runs_path.with_suffix(f".jsonl.{int(time.time())}.bak"))
    if retry_errors:
        done = {i: r for i, r in done.items() if "error" not in r}
    todo = [i for i in range(n) if i not in done]
    if progress:
        print(f"sbc: design {des['fingerprint']}, {n} trials, {n - len(todo)} already done, "
              f"{len(todo)} to run on {workers} worker(s)", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    if todo:
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool, \
                runs_path.open("a", encoding="utf-8") as fh:
            futs = {pool.submit(run_trial, i, base_seed, des["fingerprint"]): i for i in todo}
            try:
                for k, fut in enumerate(cf.as_completed(futs), 1):
                    rec = fut.result()
                    fh.write(json.dumps(rec) + "\n")
                    fh.flush()
                    os.fsync(fh.fileno())
                    done[rec["i"]] = rec
                    if progress:
                        el = time.perf_counter() - t0
                        eta = el / k * (len(todo) - k)
                        if "error" in rec:
                            what = "ERROR " + rec["error"].strip().splitlines()[-1]
                        else:
                            miss = [p for p in PARAMS if not rec["covered"][p]]
                            what = (f"{rec['seconds']:.0f} s, mesh {rec['mesh_n_elements']}, "
                                    f"conv {'y' if rec['converged'] else 'n'}, "
                                    f"adequate {'y' if rec['adequate'] else 'n'}, "
                                    f"missed {','.join(miss) or '-'}")
                        cell = "/".join(CELLS[rec["i"] % len(CELLS)])
                        print(f"[{k}/{len(todo)}] trial {rec['i']} {cell}: {what}; "
                              f"elapsed {el / 60:.1f} min, ETA {eta / 60:.1f} min",
                              file=sys.stderr, flush=True)
            except KeyboardInterrupt:
                for f in futs:
                    f.cancel()
                raise
    records = [done[i] for i in range(n) if i in done]
    oracle = {}
    fitted = [r for r in records if "covered" in r]
    if progress:
        print(f"sbc: the exact linear estimator on the same {len(fitted)} noise draws ...",
              file=sys.stderr, flush=True)
    for r in fitted:
        oracle[r["i"]] = noise_projection(r, base_seed)
    table = coverage_table(records, oracle)
    text = markdown(table, des)
    print(text)
    stem = "sbc_quick" if quick else "sbc"
    paths = [outdir / f"{stem}.json", outdir / f"{stem}.md"]
    paths[0].write_text(json.dumps({"design": des, "table": table, "records": records},
                                   indent=1, default=float) + "\n", encoding="utf-8")
    paths[1].write_text(text, encoding="utf-8")
    return {"records": records, "table": table, "markdown": text, "paths": paths}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=112, help="trials (default 112 = 14 per cell)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=BASE_SEED, help="root seed of the design")
    ap.add_argument("--quick", action="store_true", help="first 8 trials (one per cell)")
    ap.add_argument("--no-resume", dest="resume", action="store_false",
                    help="ignore (and move aside) the runs file")
    ap.add_argument("--retry-errors", action="store_true")
    ap.add_argument("--outdir", type=Path, default=None)
    a = ap.parse_args()
    main(n=a.n, workers=a.workers, base_seed=a.seed, quick=a.quick, resume=a.resume,
         retry_errors=a.retry_errors, outdir=a.outdir)
