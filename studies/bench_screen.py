"""Benchmark: the diagnosis's MAP search on a whole measured record, against the FD step.

A screen of ``bayesbeam diagnose`` is a MAP search (:meth:`_Engine.optimise`: physical
starts, an E scan, scaled L-BFGS-B passes with finite-difference gradients, Newton
polishes). On a whole record the log density carries rounding noise (~1e-2 nats along
the structural parameters on the steel record), and the gradient's step
(:data:`bayesbeam.inference.optimum.FD_STEP`, in conditional sds) decides whether the
line searches see the slope or the noise. For each model and each step this runs the
search from the diagnosis's own starts, on the record prepared as ``bayesbeam diagnose``
prepares it, one process, and prints the wall time, the parameter sets evaluated and
the log posterior reached; the ratios are against the first step, run in the same
process.

Run: ``.venv/bin/python studies/bench_screen.py [--record steel] [--steps 1e-6,1e-2]
[--models viscous+kv+ar1_noise,...] [--elements 32] [--workdir DIR]``.
The machine and its load are printed with the table: compare times only within a run.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bayesbeam._util import one_blas_thread
from bayesbeam.cli import options as opts
from bayesbeam.cli.diagnose import register
from bayesbeam.diagnosis.search import _Engine
from bayesbeam.inference import optimum
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.models import parse_model
from bayesbeam.trials.io import write_trial
from bayesbeam.trials.realdata import list_real_datasets

MODELS = ("viscous+kv+ar1_noise", "viscous+kv+stiffness_gradient+ar1_noise",
          "viscous+kv+stiffness_gradient+drag+ar1_noise")


class _Counted:
    """Count the parameter sets a problem's ``log_prob`` is asked for."""

    def __init__(self) -> None:
        self.rows = 0
        self._orig = Problem.log_prob

    def __enter__(self) -> _Counted:
        orig, me = self._orig, self

        def counted(pb, U):
            me.rows += np.atleast_2d(U).shape[0]
            return orig(pb, U)

        Problem.log_prob = counted
        return self

    def __exit__(self, *exc) -> None:
        Problem.log_prob = self._orig


def search(trial, pre, model: str, n_elements: int, step: float) -> dict:
    """One screen-like MAP search of ``model`` (no current MAP: the diagnosis's starts)."""
    eng = _Engine(trial, seed=0, n_elements=n_elements, initial=pre.initial, priors=None,
                  sampler={}, notes=[], log=lambda line: None)
    st = eng.state(parse_model(pre.model_name(model)))
    starts = eng.starts(st, None)
    old = optimum.FD_STEP
    optimum.FD_STEP = step
    try:
        with _Counted() as count:
            t0 = time.perf_counter()
            eng.optimise(st, starts)
            seconds = time.perf_counter() - t0
    finally:
        optimum.FD_STEP = old
    return {"model": model, "step": step, "seconds": seconds, "sets": count.rows,
            "log_post": st.lp, "starts": len(starts)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", default="steel", help="label, e.g. steel or alu50-0")
    ap.add_argument("--steps", default="1e-6,1e-2", help="comma-separated FD steps (sd)")
    ap.add_argument("--models", default=",".join(MODELS), help="comma-separated models")
    ap.add_argument("--elements", type=int, default=32, help="mesh (default 32)")
    ap.add_argument("--workdir", type=Path, default=None)
    args = ap.parse_args(argv)
    recs = [r for r in list_real_datasets() if r.label == args.record]
    if not recs:
        print(f"record {args.record!r} not found under ../shared/data/real", file=sys.stderr)
        return 1
    work = args.workdir or Path(tempfile.mkdtemp(prefix="bench_screen_"))
    path = write_trial(recs[0].load(raw=True), work / f"{args.record}.toml", unit="g")
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    trial, pre = opts.prepare_trial(
        parser.parse_args(["diagnose", str(path), "-o", str(work / "out")]), ValueError)
    steps = [float(s) for s in args.steps.split(",")]
    rows = []
    with one_blas_thread():
        for model in args.models.split(","):
            base = None
            for step in steps:
                r = search(trial, pre, model, args.elements, step)
                base = base or r
                r["time_ratio"] = r["seconds"] / base["seconds"]
                r["gain_vs_first"] = r["log_post"] - base["log_post"]
                rows.append(r)
                print(r, flush=True)
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    print(f"\n{args.record}, {trial.times.size} samples, {args.elements} elements; "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"load {load[0]:.1f} at the end\n")
    print("| model | FD step (sd) | starts | s | x first step | sets | log posterior | "
          "vs first step |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['step']:g} | {r['starts']} | {r['seconds']:.1f} | "
              f"{r['time_ratio']:.2f} | {r['sets']} | {r['log_post']:.2f} | "
              f"{r['gain_vs_first']:+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
