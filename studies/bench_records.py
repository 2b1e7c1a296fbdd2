"""Benchmark: ``bayesbeam fit`` (and optionally ``inspect``) on every whole raw public record.

Each record of ``../shared/data/real`` (ten aluminium releases, one steel impulse) is
written as a trial file straight from the raw file -- all stamps, in g, offset left in,
starting before the release (:func:`bayesbeam.trials.realdata.load_enes` with
``raw=True``) -- and given to the command line exactly as a user would::

    bayesbeam fit TRIAL.toml --model viscous+kv -o OUT --json

with no other option: the analysis start, rate, initial condition and offset are the
tool's own choices (``preprocessing`` in the JSON). The table lists per record the wall
time of the whole command (median over ``--repeats``), whether the posterior converged,
the choices made, and the adequacy verdict (a uniform beam with linear damping is not
expected to reproduce these records: see the README's real-data section).

Run: ``.venv/bin/python studies/bench_records.py [--records alu50-0,steel] [--inspect]
[--repeats 1] [--workdir DIR]``; writes ``studies/figures/bench_records.{md,jsonl}``.
The machine and its load are printed with the table: compare times only within a run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bayesbeam.trials.io import write_trial
from bayesbeam.trials.realdata import list_real_datasets

HERE = Path(__file__).resolve().parent
FIGURES = HERE / "figures"


def _run(cmd: list[str]) -> tuple[float, dict | None, str]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        return seconds, None, proc.stderr[-2000:]
    try:
        return seconds, json.loads(proc.stdout), proc.stderr
    except json.JSONDecodeError:
        return seconds, None, proc.stdout[-2000:]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--records", default=None, help="comma-separated labels (default: all)")
    ap.add_argument("--model", default="viscous+kv")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--inspect", action="store_true", help="also time `bayesbeam inspect`")
    ap.add_argument("--workdir", type=Path, default=None,
                    help="where trial files and outputs go (default: a temporary folder)")
    args = ap.parse_args(argv)
    records = list_real_datasets()
    if not records:
        print("no real data found under ../shared/data/real", file=sys.stderr)
        return 1
    want = None if args.records is None else set(args.records.split(","))
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_records_"))
    rows = []
    for rec in records:
        label = rec.label
        if want is not None and label not in want:
            continue
        trial = rec.load(raw=True)
        path = write_trial(trial, work / "trials" / f"{label}.toml", unit="g")
        times, payload, err = [], None, ""
        for r in range(args.repeats):
            out = work / "out" / f"{label}-{r}"
            sec, payload, err = _run([sys.executable, "-m", "bayesbeam", "fit", str(path),
                                      "--model", args.model, "-o", str(out), "--json"])
            times.append(sec)
        row = {"record": label, "n_raw": int(trial.times.size), "fit_s": statistics.median(times),
               "fit_s_all": times}
        if payload is None:
            row["error"] = err.strip().splitlines()[-1] if err.strip() else "no output"
        else:
            pre = payload["preprocessing"]
            row.update(
                converged=payload["converged"], ess_min=payload["ess_min"],
                adequate=payload["adequacy"]["ok"], n_samples=pre["n_samples"],
                start=pre["start"], end=pre["end"], rate=pre["rate"], band=pre["band"],
                initial=pre["initial"], model=payload["model"],
                n_elements=payload["settings"]["n_elements"],
                E_GPa=payload["posterior"]["E"]["mean"] / 1e9,
                sigma=payload["posterior"]["sigma"]["mean"],
                offset=payload["posterior"].get("offset", {}).get("mean"),
            )
        if args.inspect:
            sec, _, _ = _run([sys.executable, "-m", "bayesbeam", "inspect", str(path),
                              "-o", str(work / "inspect" / label), "--json"])
            row["inspect_s"] = sec
        rows.append(row)
        print(json.dumps(row), flush=True)
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    head = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load "
            f"{load[0]:.1f} at the end; model {args.model}; median of {args.repeats} run(s)")
    lines = [f"# Whole raw records: `bayesbeam fit TRIAL --model {args.model}`", "", head, "",
             "| record | raw samples | analysis samples | span s | rate Hz | initial | mesh | "
             "fit s | converged | adequate | E GPa | sigma m/s^2 | offset m/s^2 |"
             + (" inspect s |" if args.inspect else ""),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
             + ("---|" if args.inspect else "")]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['record']} | {r['n_raw']} | error: {r['error']} |")
            continue
        rate = "raw" if r["rate"] is None else f"{r['rate']:.0f}"
        off = "-" if r["offset"] is None else f"{r['offset']:.3f}"
        lines.append(
            f"| {r['record']} | {r['n_raw']} | {r['n_samples']} | {r['start']:.2f}-{r['end']:.2f}"
            f" | {rate} | {r['initial']} | {r['n_elements']} | {r['fit_s']:.0f} | "
            f"{r['converged']} | {r['adequate']} | {r['E_GPa']:.2f} | {r['sigma']:.3f} | {off} |"
            + (f" {r['inspect_s']:.0f} |" if args.inspect else "")
        )
    ok = [r["fit_s"] for r in rows if "error" not in r]
    if ok:
        lines += ["", f"median fit time {statistics.median(ok):.0f} s, longest {max(ok):.0f} s "
                      f"over {len(ok)} record(s)"]
    text = "\n".join(lines) + "\n"
    print(text)
    if want is None:
        FIGURES.mkdir(exist_ok=True)
        (FIGURES / "bench_records.md").write_text(text, encoding="utf-8")
        with open(FIGURES / "bench_records.jsonl", "w", encoding="utf-8") as fh:
            for r in rows:
                fh.write(json.dumps(r) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
