"""Benchmark: a whole record's sampler batch on one process and shared with one helper.

For each (record, model) the batch that emcee evaluates per half-step (``nwalkers / 2``
points in a small ball about a data-driven start) is timed with ``problem.log_prob``
(the baseline) and with :class:`bayesbeam.inference.parallel.ParallelLogProb` with one
helper process, alternately in the same process; the table gives median times and the
ratio. Records are the whole raw public ones, preprocessed as ``bayesbeam diagnose``
does. The values are checked equal, bit for bit.

Run: ``.venv/bin/python studies/bench_parallel.py [--repeats 15]``; prints a markdown
table. Compare times only within one run (the machine is shared).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from bayesbeam._util import one_blas_thread
from bayesbeam.inference.fit import _start_points, scan_E
from bayesbeam.inference.parallel import ParallelLogProb
from bayesbeam.inference.problem import Problem
from bayesbeam.inference.settings import walker_count
from bayesbeam.trials.preprocess import prepare
from bayesbeam.trials.realdata import load_enes

CASES = [(60, 1, "viscous+kv+ar1_noise"),
         (60, 1, "viscous+kv+added_mass+ar1_noise"),
         (60, 1, "viscous+kv+added_mass+drag+ar1_noise"),
         (30, 0, "viscous+kv+drag+amplitude_stiffness+ar1_noise")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)
    print("| record | model | samples | batch | one process, ms | with a helper, ms | ratio |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    with one_blas_thread():
        for length, index, model in CASES:
            tr, pre = prepare(load_enes(length, index, raw=True))
            pb = Problem(tr, pre.model_name(model), n_elements=16, initial=pre.initial)
            rng = np.random.default_rng(0)
            u = pb.priors.to_u(scan_E(pb, _start_points(pb, rng, 1)))[0]
            U = u + 1e-4 * rng.standard_normal((walker_count(None, pb.ndim) // 2, pb.ndim))
            with ParallelLogProb(pb.log_prob, helpers=1) as lp:
                lp(U)  # decides, and starts the helper if the batch is long enough
                lp(U)
                ts, tp = [], []
                for _ in range(args.repeats):
                    t = time.perf_counter()
                    a = pb.log_prob(U)
                    ts.append(time.perf_counter() - t)
                    t = time.perf_counter()
                    b = lp(U)
                    tp.append(time.perf_counter() - t)
                split = lp.batches_split > 0
            if not np.array_equal(a, b):
                raise SystemExit(f"{model}: split values differ from the serial ones")
            s, p = statistics.median(ts), statistics.median(tp)
            print(f"| Al {length} cm #{index} | {model} | {tr.times.size} | {len(U)} | "
                  f"{1e3 * s:.1f} | {1e3 * p:.1f}{'' if split else ' (not split)'} | "
                  f"{s / p:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
