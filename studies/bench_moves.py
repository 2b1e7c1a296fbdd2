"""Benchmark: ESS per second of the emcee proposal mixtures and walker counts.

Issue 13 asks that moves and walker counts be chosen by measurement, in ESS per second
rather than wall time (a chain that stops early has a short wall time; one that runs
long has a large ESS). For each named mixture of
:data:`bayesbeam.stats.moves.MOVE_SETS` (``de``: differential evolution 0.8 +
snooker 0.2, the package default; ``stretch``: emcee's default; ``de+stretch``) and
each walker count (the default ``max(32, 4 ndim)`` and twice it), one 1280-sample
release of the source study's single-ply beam (:mod:`bench_fit`'s trial, simulated on a
24-element mesh and fitted on 16: no inverse crime) is fitted with
``target_ess=1000`` over several seeds (``--rate 2048``: the same 5 s at 10240
samples, the size of a whole measured record). Reported per configuration, as medians over
the seeds: sampling seconds, steps, τ max, smallest bulk ESS, ESS per second, and its
ratio to the default (``de``, default walkers) run in the same process.

Run: ``.venv/bin/python studies/bench_moves.py [--models viscous+kv] [--seeds 3]``
(writes ``studies/figures/bench_moves.{md,json}`` with ``--out``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

# The script's folder is on sys.path when it is run: the trial of bench_fit.py.
from bench_fit import bench_beam, true_params

from bayesbeam.inference.fit import fit
from bayesbeam.stats.moves import MOVE_SETS
from bayesbeam.stats.sampling import NotConvergedWarning
from bayesbeam.trials.synthetic import simulate_trial

try:  # optional: limits BLAS threads at run time
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - then BLAS keeps its default thread count
    threadpool_limits = None


def run_one(trial, model: str, moves: str, walkers: int | None, seed: int) -> dict:
    """Fit ``trial`` with one proposal mixture and walker count; return the chain figures."""
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)  # reported in the table
        res = fit(trial, model, seed=seed, n_elements=16, target_ess=1000.0,
                  nwalkers=walkers, progress=False, sampler_options={"moves": moves})
    c = res.chain
    return {"moves": moves, "nwalkers": int(c.nwalkers), "seed": seed,
            "sampling_seconds": float(c.seconds), "seconds": time.perf_counter() - t0,
            "steps": int(c.n_steps_total), "tau_max": c.tau_max, "ess_min": c.ess_min,
            "ess_per_second": c.ess_per_second, "converged": bool(c.converged)}


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark and print a markdown table per model.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (default ``sys.argv[1:]``).

    Returns
    -------
    dict
        Per model: the runs and the per-configuration medians.
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="viscous+kv")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--moves", default=",".join(MOVE_SETS))
    ap.add_argument("--rate", type=float, default=256.0,
                    help="sampling rate of the 5 s record, Hz (256: 1280 samples; 2048: "
                         "10240, the issue's whole-record size)")
    ap.add_argument("--out", type=Path, default=None,
                    help="folder for bench_moves.md and .json (default: print only)")
    args = ap.parse_args(argv)
    limit = (threadpool_limits(1) if threadpool_limits is not None
             else contextlib.nullcontext())
    out: dict = {}
    lines: list[str] = []
    beam = bench_beam()
    with limit:
        for model in args.models.split(","):
            runs = []
            for seed in range(args.seeds):
                trial = simulate_trial(beam, model, true_params(model, beam), duration=5.0,
                                       dt=1 / args.rate, tip_deflection=5e-3,
                                       noise_sd=1e-5, seed=seed, n_elements=24)
                for moves in args.moves.split(","):
                    walkers = None  # the default count first, then twice it
                    for _ in range(2):
                        r = run_one(trial, model, moves, walkers, seed)
                        print(f"{model} seed {seed} {moves} {r['nwalkers']} walkers: "
                              f"{r['sampling_seconds']:.1f} s, ESS {r['ess_min']:.0f}, "
                              f"{r['ess_per_second']:.1f}/s", file=sys.stderr, flush=True)
                        runs.append(r)
                        walkers = 2 * r["nwalkers"]
            configs = sorted({(r["moves"], r["nwalkers"]) for r in runs},
                             key=lambda k: (list(MOVE_SETS).index(k[0]), k[1]))
            base_w = min(w for m, w in configs if m == "de")
            rows = []
            for m, w in configs:
                sel = [r for r in runs if r["moves"] == m and r["nwalkers"] == w]
                # Ratio per seed against the default on the same trial, then the median.
                ratio = [r["ess_per_second"] / next(
                    b["ess_per_second"] for b in runs if b["moves"] == "de"
                    and b["nwalkers"] == base_w and b["seed"] == r["seed"]) for r in sel]
                rows.append({"moves": m, "nwalkers": w, "runs": len(sel),
                             **{k: float(np.median([r[k] for r in sel]))
                                for k in ("sampling_seconds", "steps", "tau_max", "ess_min",
                                          "ess_per_second")},
                             "ratio_to_default": float(np.median(ratio)),
                             "converged": sum(r["converged"] for r in sel)})
            out[model] = {"runs": runs, "medians": rows}
            lines += [f"**{model}**, {round(5 * args.rate)} samples, medians of {args.seeds} seeds "
                      "(ratio: per seed against `de` with the default walkers, same process)",
                      "",
                      "| moves | walkers | sampling s | steps | τ max | ESS min | ESS/s "
                      "| ratio | converged |",
                      "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
            lines += [f"| {r['moves']} | {r['nwalkers']} | {r['sampling_seconds']:.1f} | "
                      f"{r['steps']:.0f} | {r['tau_max']:.1f} | {r['ess_min']:.0f} | "
                      f"{r['ess_per_second']:.1f} | {r['ratio_to_default']:.2f} | "
                      f"{r['converged']}/{r['runs']} |" for r in rows]
            lines.append("")
    text = "\n".join(lines)
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bench_moves.md").write_text(text + "\n", encoding="utf-8")
        (args.out / "bench_moves.json").write_text(json.dumps(out, indent=2) + "\n",
                                                   encoding="utf-8")
    return out


if __name__ == "__main__":
    main()
