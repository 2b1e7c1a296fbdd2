"""Benchmark: full comparison of viscous, viscous+kv and viscous+sh on one trial.

Issue 4's benchmark: posteriors + evidences + criteria for the three source models
on one 1280-sample trial (5 s at dt = 0.003906 s), 16 elements, the package's default
sampler settings; target at most 3 minutes on the 2-core development machine. Prints
the wall-clock and CPU time per model and in total, the evidence errors achieved, and
the comparison table.

The trial is synthetic, from the source's single-ply beam with a physical modulus
(bayesbeam.jobs.bench.bench_beam, f1 ≈ 11 Hz): viscous + Kelvin–Voigt damping, each giving
a first-mode damping ratio of 0.5 %, released from a 5 mm tip deflection, white
noise of 10 µm.

With ``--jobs 2`` the three fits run in two processes
(``compare(..., executor=...)`` with :func:`bayesbeam.jobs.executor.make_executor`;
bitwise the same results as the serial run).

Run: ``.venv/bin/python studies/bench_compare.py [--jobs N] [--target-ess X] [--max-steps N]``.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from bayesbeam.comparison.compare import compare
from bayesbeam.inference.problem import BETA1
from bayesbeam.inference.settings import FIT_DEFAULTS
from bayesbeam.jobs.bench import bench_beam
from bayesbeam.trials.synthetic import simulate_trial

MODELS = ("viscous", "viscous+kv", "viscous+sh")


def bench_trial(seed: int = 0):
    """Return the benchmark trial (1280 samples, viscous+kv, ζ1 = 0.5 % + 0.5 %)."""
    beam = bench_beam()
    E = beam.E
    w1 = BETA1**2 * math.sqrt(E * beam.I / (beam.rhoA * beam.length**4))
    params = {
        "gamma": 2 * beam.rhoA * w1 * 0.005,  # physics.md §2: ζ1 = gamma/(2 rhoA ω1)
        "c_d": 2 * E * 0.005 / w1,  # ζ1 = c_d ω1/(2E)
    }
    return simulate_trial(beam, "viscous+kv", params, duration=5.0, dt=0.003906,
                          noise_sd=1e-5, seed=seed, name="bench-compare")


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark and print its numbers.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments.

    Returns
    -------
    dict
        ``seconds``, ``cpu_seconds`` and per-model ``log_evidence``,
        ``log_evidence_err``, ``seconds``, ``n_calls``.
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target-ess", type=float, default=FIT_DEFAULTS.target_ess)
    ap.add_argument("--max-steps", type=int, default=FIT_DEFAULTS.max_steps)
    ap.add_argument("--elements", type=int, default=FIT_DEFAULTS.n_elements)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1, help="processes for the fits")
    args = ap.parse_args(argv)
    trial = bench_trial(args.seed)
    print(f"trial: {trial.times.size} samples, {args.elements} elements, models {MODELS}, "
          f"jobs {args.jobs}")
    t0, c0 = time.perf_counter(), time.process_time()
    from bayesbeam.jobs.executor import make_executor

    # --jobs N: the models' fits in N processes (bitwise the serial numbers).
    with make_executor(args.jobs) as executor:
        cmp = compare(trial, MODELS, seed=args.seed, n_elements=args.elements,
                      target_ess=args.target_ess, max_steps=args.max_steps,
                      executor=executor)
    # CPU time of this process only: with --jobs > 1 the fits' CPU is in the workers.
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    print(cmp)
    print()
    out = {"seconds": wall, "cpu_seconds": cpu, "models": {}}
    for s in cmp.scores:
        c = s.result.chain
        print(f"{s.name:<12} {s.seconds:7.1f} s  {s.n_calls:>8d} calls  log Z = "
              f"{s.log_evidence:.3f} ± {s.log_evidence_err:.3f} ({s.evidence.method}, "
              f"tau={s.evidence.tau:.1f})  chain: {c.nsteps} x {c.nwalkers}, "
              f"ESS min {c.ess_min:.0f}, converged {c.converged}")
        out["models"][s.name] = {
            "log_evidence": s.log_evidence, "log_evidence_err": s.log_evidence_err,
            "seconds": s.seconds, "n_calls": s.n_calls,
        }
    verdict = "within" if wall <= 180 else "OVER"
    print(f"\nfull comparison: {wall:.1f} s wall ({cpu:.1f} s CPU), {verdict} the 3-minute "
          f"target; max evidence error {np.nanmax([s.log_evidence_err for s in cmp.scores]):.3f}"
          " nats")
    return out


if __name__ == "__main__":
    main()
