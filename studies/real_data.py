"""Whole-record diagnosis of the public measured data: causes named, their sizes, repeats.

Data (not in the repository; ``../shared/data/real`` beside it, each set with its
PROVENANCE.md): ``enes-alu-release`` (an aluminium strip 50.8 x 2 mm released by hand
at free lengths 30/40/50/60 cm, ten records; ADXL357 acceleration 6 cm from the tip,
software time stamps, not uniform) and ``hrshm-steel-impulse`` (a steel beam
759 x 50.66 x 5.14 mm struck by a hammer; IEPE acceleration near the tip).

For each record (:func:`bayesbeam.trials.realdata.list_real_datasets`):

1. the raw record is written as a trial file (:func:`bayesbeam.trials.io.write_trial`,
   acceleration in g as recorded; read back in m/s²);
2. ``bayesbeam diagnose TRIAL -o OUT/LABEL`` runs on it with default settings,
   in its own process: the command a user runs, whose preprocessing chooses the span
   (the whole motion), the rate, the modes in band and the offset from the record;
3. a row is kept: the causes named with Δ log Z ± error, Δ ELPD ± se and the RMS
   residual before → after; the final model's sizes in physical units (mass in g,
   its position in cm from the tip, E in GPa, frequency shift in mHz per mm of mode-1
   tip amplitude, ...), the wall time and the number of reliability notes.

Then the repeats of one free length are compared: for every size present in two
repeats, the difference of their posterior means in units of its combined sd.

Resumable: a record whose ``OUT/LABEL/diagnosis.json`` exists is read, not run again,
so the study can be spread over several sittings (a whole record takes 10–50 min on
2 cores). Writes ``OUT/real_data.jsonl`` (one row per record), ``OUT/real_data.md`` and,
per record, the command's output folder ``OUT/LABEL/`` and its progress log
``OUT/LABEL.log``.

Run: ``python studies/real_data.py --outdir OUT [--records alu50-0,steel]``;
``--small`` runs 4 s of one record with a tiny budget (seconds, for the tests; its
posteriors are not converged).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from itertools import combinations
from pathlib import Path
from typing import Any

from bayesbeam.trials.io import write_trial
from bayesbeam.trials.realdata import ENES, list_real_datasets

#: Extra options of the small setting: 4 s of one record at 256 Hz (modes 1-2), two
#: candidates, one round, 200 emcee steps on a fixed 8-element mesh.
SMALL = ("--window", "0.25", "4.25", "--rate", "256", "--candidates", "added_mass,ar1_noise",
         "--max-rounds", "1", "--max-steps", "200", "--target-ess", "30", "--elements", "8",
         "--fixed-mesh")
SMALL_RECORD = "alu40-0"

#: Sizes reported, from the final model's posterior: name -> (label, scale, unit). The
#: position is turned into the distance from the tip (the record names the sensor's).
SIZES = {
    "E": ("E", 1e-9, "GPa"),
    "added_mass": ("added mass", 1e3, "g"),
    "added_mass_position": ("mass from tip", 1e2, "cm"),
    "tip_mass": ("tip mass", 1e3, "g"),
    "stiffness_gradient": ("EI gradient", 1.0, ""),
    "root_spring": ("root spring", 1.0, "N m/rad"),
    "drag": ("drag", 1.0, "kg/m²"),
    "friction": ("friction", 1.0, "N"),
    "f1_slope": ("f1 shift", 1.0, "mHz/mm"),  # Hz per m of tip amplitude = mHz per mm
    "rho": ("AR(1) ρ", 1.0, ""),
}


def sizes(record: dict[str, Any], length: float) -> dict[str, list[float]]:
    """Final-model sizes in the units of :data:`SIZES`: name -> [mean, sd].

    Parameters
    ----------
    record : dict
        A ``diagnosis.json``.
    length : float
        Free length of the beam, m.
    """
    out = {}
    for name, (_, scale, _) in SIZES.items():
        p = record.get("final_posterior", {}).get(name)
        if not p or p.get("mean") is None:
            continue
        mean, sd = float(p["mean"]), float(p["sd"])
        if name == "added_mass_position":
            mean = length - mean
        out[name] = [scale * mean, scale * sd]
    return out


def row(rec: Any, record: dict[str, Any], seconds: float | None) -> dict[str, Any]:
    """One record's row of the study (plain JSON)."""
    length = _length(rec)
    return {
        "record": rec.label, "length_m": length,
        "samples": record.get("preprocessing", {}).get("n_samples"),
        "baseline": record.get("baseline"), "final_model": record.get("final_model"),
        "named": [{k: r.get(k) for k in ("cause", "equivalent", "delta_log_evidence",
                                          "delta_log_evidence_err", "delta_elpd",
                                          "delta_elpd_se", "rms_before", "rms_after")}
                  for r in record.get("rounds", [])],
        "sizes": sizes(record, length),
        "notes": len(record.get("notes", [])),
        **_chains(record),
        "seconds": seconds,
        "version": record.get("provenance", {}).get("versions", {}).get("bayesbeam"),
    }


def _chains(record: dict[str, Any]) -> dict[str, list[str]]:
    """Return the models sampled and those whose emcee run did not converge (notes)."""
    sampled = {record.get("baseline")} | {
        c["model"] for r in record.get("rounds", []) for c in r.get("candidates", [])
        if c.get("confirmed")}
    bad = {n.split(": ", 1)[0] for n in record.get("notes", [])
           if "emcee did not converge" in n}
    return {"sampled": sorted(m for m in sampled if m), "unconverged": sorted(bad)}


def _length(rec: Any) -> float:
    if rec.dataset == ENES:
        return rec.kwargs["length_cm"] / 100.0
    return rec.load(raw=True).beam.length


def repeats(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Pairs of repeats of one free length: per shared size, the z of their difference."""
    by_len: dict[float, list[dict[str, Any]]] = {}
    for r in rows:
        if r["record"].startswith("alu"):
            by_len.setdefault(round(r["length_m"], 3), []).append(r)
    out = []
    for length, group in sorted(by_len.items()):
        for a, b in combinations(group, 2):
            z = {}
            for k in sorted(set(a["sizes"]) & set(b["sizes"])):
                (ma, sa), (mb, sb) = a["sizes"][k], b["sizes"][k]
                se = math.hypot(sa, sb)
                z[k] = (ma - mb) / se if se > 0 else math.nan
            out.append({"length_m": length, "pair": [a["record"], b["record"]],
                        "same_causes": [n["cause"] for n in a["named"]]
                        == [n["cause"] for n in b["named"]], "z": z})
    return out


def markdown(rows: list[dict[str, Any]], pairs: list[dict[str, Any]]) -> str:
    """Return the study's tables (Markdown)."""
    lines = ["# Whole-record diagnosis of the public measured data", "",
             "| record | samples | named causes: Δ log Z ± err; Δ ELPD ± se | RMS m/s² | "
             "final sizes (mean ± sd) | chains unconverged | notes | time |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        named = "; ".join(
            f"`{n['cause']}` {_f(n['delta_log_evidence'])} ± {_f(n['delta_log_evidence_err'])}"
            f"; {_f(n['delta_elpd'])} ± {_f(n['delta_elpd_se'])}"
            + (f" (≈ {', '.join(n['equivalent'])})" if n.get("equivalent") else "")
            for n in r["named"]) or "none"
        rms = (f"{_f(r['named'][0]['rms_before'], 3)} → {_f(r['named'][-1]['rms_after'], 3)}"
               if r["named"] else "")
        sz = ", ".join(f"{SIZES[k][0]} {_f(m, 4)} ± {_f(s, 2)} {SIZES[k][2]}".rstrip()
                       for k, (m, s) in r["sizes"].items())
        t = "" if r["seconds"] is None else f"{r['seconds'] / 60:.1f} min"
        chains = (f"{len(r['unconverged'])} of {len(r['sampled'])}" if "sampled" in r
                  else "–")
        lines.append(f"| {r['record']} | {r['samples']} | {named} | {rms} | {sz} | "
                     f"{chains} | {r['notes']} | {t} |")
    if pairs:
        lines += ["", "Repeats of one length: difference of the posterior means in units "
                  "of the combined sd (|z| > 3: the repeats disagree beyond their "
                  "posterior widths).", "", "| pair | same causes | z per size |",
                  "| --- | --- | --- |"]
        for p in pairs:
            z = ", ".join(f"{SIZES[k][0]} {v:+.1f}" for k, v in p["z"].items())
            lines.append(f"| {' / '.join(p['pair'])} | {'yes' if p['same_causes'] else 'no'} "
                         f"| {z} |")
    return "\n".join(lines) + "\n"


def _f(x: float | None, digits: int = 1) -> str:
    if x is None or not math.isfinite(x):
        return "–"
    return f"{x:.{digits}g}" if digits > 1 else f"{x:.1f}"


def run_one(rec: Any, outdir: Path, *, small: bool, seed: int,
            log: Any) -> tuple[dict[str, Any], float | None]:
    """Diagnose one record (or read its earlier output); return its record and seconds."""
    name = rec.label
    out = outdir / name
    done = out / "diagnosis.json"
    if done.is_file():
        if log:
            log(f"{name}: read {done} (delete it to run again)")
        rec_json = json.loads(done.read_text(encoding="utf-8"))
        return rec_json, rec_json.get("study_seconds")
    trial = rec.load(raw=True)
    path = write_trial(trial, outdir / "trials" / f"{name}.toml", unit="g")
    cmd = [sys.executable, "-m", "bayesbeam", "diagnose", str(path), "-o", str(out),
           "--seed", str(seed)]
    if small:
        cmd += list(SMALL)
    if log:
        log(f"{name}: {' '.join(cmd[1:])}")
    t0 = time.perf_counter()
    # The command's progress lines (stderr) go to OUT/LABEL.log and, with progress on,
    # to this terminal as they come (a record takes tens of minutes); its narrative
    # (stdout) is not needed: it writes OUT/LABEL/diagnosis.json itself, atomically, at
    # the end, so an interrupted record leaves none and is run again on resuming.
    out.mkdir(parents=True, exist_ok=True)
    with (outdir / f"{name}.log").open("w", encoding="utf-8") as logf, subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) as proc:
        for line in proc.stderr:
            logf.write(line)
            if log:  # a progress bar's updates come as one line joined by carriage returns
                log(f"  {name}: {line.rstrip().split(chr(13))[-1]}")
    seconds = time.perf_counter() - t0
    if proc.returncode != 0 or not done.is_file():
        tail = (outdir / f"{name}.log").read_text(encoding="utf-8").strip()[-1500:]
        raise RuntimeError(f"{name}: bayesbeam diagnose failed ({proc.returncode}): {tail}")
    record = json.loads(done.read_text(encoding="utf-8"))
    # Keep the wall time beside the output, so that a resumed study still reports it.
    record["study_seconds"] = seconds
    done.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return record, seconds


def main(small: bool = False, outdir: str | Path | None = None, seed: int = 0,
         progress: bool = True, records: list[str] | None = None) -> dict[str, Any]:
    """Run the study (or resume it); write and return its rows and tables.

    Parameters
    ----------
    small : bool
        One record, short and cheap (for tests).
    outdir : path, optional
        Output folder (default ``real-data`` or ``real-data-small``).
    seed : int
        Seed of every diagnosis.
    progress : bool
        Progress lines on stderr.
    records : list of str, optional
        Labels (``alu30-0`` ... ``alu60-3``, ``steel``); default all (small: one).

    Returns
    -------
    dict
        ``rows``, ``repeats``, ``markdown`` and ``paths``.
    """
    outdir = Path(outdir or ("real-data-small" if small else "real-data"))
    outdir.mkdir(parents=True, exist_ok=True)
    log = (lambda s: print(s, file=sys.stderr, flush=True)) if progress else None
    recs = list_real_datasets()
    if not recs:
        raise SystemExit("no public records found under ../shared/data/real")
    want = records or ([SMALL_RECORD] if small else [r.label for r in recs])
    unknown = sorted(set(want) - {r.label for r in recs})
    if unknown:
        raise SystemExit(f"unknown record(s) {unknown}; known: {[r.label for r in recs]}")
    rows = []
    for rec in recs:
        if rec.label in want:
            record, seconds = run_one(rec, outdir, small=small, seed=seed, log=log)
            rows.append(row(rec, record, seconds))
    pairs = repeats(rows)
    text = markdown(rows, pairs)
    paths = [outdir / "real_data.jsonl", outdir / "real_data.md"]
    paths[0].write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    paths[1].write_text(text, encoding="utf-8")
    if progress:
        print(text, flush=True)
    return {"rows": rows, "repeats": pairs, "markdown": text, "paths": paths}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="one short record, tiny budget")
    ap.add_argument("--outdir", type=Path, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--records", default=None,
                    help="comma-separated labels, e.g. alu50-0,steel (default: all)")
    a = ap.parse_args()
    main(small=a.small, outdir=a.outdir, seed=a.seed,
         records=a.records.split(",") if a.records else None)
