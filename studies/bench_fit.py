"""Benchmark: time for ``bayesbeam.inference.fit.fit`` to converge with ESS >= 1000 per parameter.

Trial (issue 3, physics.md §4): the source study's single-ply beam
(``Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021)``, E = 6.2e10 Pa, first frequency
≈ 11.4 Hz), tip displacement sampled at 256 Hz for 5 s (1280 samples), released from a
5 mm static tip deflection, white noise of sd 1e-5 m. Each model is fitted to a trial
simulated from that same model (so every fit is well specified), all with the same
damping of the first mode: viscous ζ1 = 1 %, plus Kelvin–Voigt ζ1 = 1 % or spatial
hysteresis ζ1 ≈ 1 % with kernel width b = 1 cm. 16 elements, seed 0, default sampler
settings, ``target_ess=1000``, BLAS limited to one thread (``--blas-threads``).

Reference: the seed-style workflow (Nelder–Mead on solve_ivp RK45) needs about an hour
(3600 s) for a two-parameter point estimate at 16 elements (physics.md §4). That figure
is quoted, not rerun here; it yields a point estimate only, whereas the fit gives a
converged posterior of every parameter (initial condition and noise included).

Run: ``.venv/bin/python studies/bench_fit.py [--models viscous,viscous+kv] [--json]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import time
import warnings

import numpy as np

from bayesbeam.inference.fit import fit
from bayesbeam.inference.problem import BETA1
from bayesbeam.physics.beam import Beam
from bayesbeam.stats.sampling import NotConvergedWarning
from bayesbeam.trials.synthetic import simulate_trial

try:  # optional: limits BLAS threads at run time
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - then BLAS keeps its default thread count
    threadpool_limits = None

#: physics.md §4: Nelder–Mead + RK45 point estimate of (E, gamma) at 16 elements.
SEED_WORKFLOW_SECONDS = 3600.0
E_TRUE = 6.2e10
MODELS = ("viscous", "viscous+kv", "viscous+sh")


def bench_beam() -> Beam:
    """Return the source's single-ply beam with a physical modulus."""
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E_TRUE)


def true_params(model: str, beam: Beam) -> dict[str, float]:
    """Damping parameters (SI) giving the stated first-mode damping ratios.

    Parameters
    ----------
    model : str
    beam : Beam

    Returns
    -------
    dict
    """
    w1 = BETA1**2 * math.sqrt(E_TRUE * beam.I / (beam.rhoA * beam.length**4))
    p = {"gamma": 2 * beam.rhoA * w1 * 0.01}  # ζ = gamma/(2 rhoA ω1), physics.md §2
    if "kv" in model:
        p["c_d"] = 2 * E_TRUE * 0.01 / w1  # ζ = c_d ω1/(2E)
    if "sh" in model:
        b = 0.01  # narrow-ish kernel: c_d I ≈ a b²/2 (physics.md §2)
        p["a"] = 4 * E_TRUE * beam.I * 0.01 / (w1 * b**2)
        p["b"] = b
    return p


def run_one(model: str, *, seed: int = 0, n_elements: int = 16) -> dict:
    """Simulate the trial for ``model``, fit it, and time the fit.

    Parameters
    ----------
    model : str
    seed : int
    n_elements : int

    Returns
    -------
    dict
        ``model``, ``seconds`` (wall clock of the whole fit: start search, MAP,
        sampling), ``cpu_seconds`` (CPU time of this process, all threads: on a
        shared, overloaded machine it is the fairer figure),
        ``sampling_seconds``, ``ess_min``, ``tau_max``, ``rhat_max``, ``converged``,
        ``steps``, ``n_calls``, ``ratio_to_seed_workflow``.
    """
    beam = bench_beam()
    trial = simulate_trial(beam, model, true_params(model, beam), duration=5.0,
                           dt=1 / 256, tip_deflection=5e-3, noise_sd=1e-5, seed=seed,
                           n_elements=n_elements)
    t0, c0 = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotConvergedWarning)  # reported in the table
        res = fit(trial, model, seed=seed, n_elements=n_elements, target_ess=1000.0,
                  progress=False)
    seconds = time.perf_counter() - t0
    cpu = time.process_time() - c0
    c = res.chain
    return {
        "model": model,
        "n_samples": int(trial.times.size),
        "seconds": seconds,
        "cpu_seconds": cpu,
        "sampling_seconds": float(c.seconds),
        "ess_min": c.ess_min,
        "tau_max": c.tau_max,
        "rhat_max": c.rhat_max,
        "converged": bool(c.converged),
        "steps": int(c.n_steps_total),
        "nwalkers": int(c.nwalkers),
        "n_calls": int(c.n_calls),
        "ratio_to_seed_workflow": SEED_WORKFLOW_SECONDS / seconds,
    }


def main(argv: list[str] | None = None) -> list[dict]:
    """Run the benchmark and print a table (or JSON).

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (default ``sys.argv[1:]``).

    Returns
    -------
    list of dict
        One record per model (see :func:`run_one`).
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--elements", type=int, default=16)
    ap.add_argument("--blas-threads", type=int, default=1,
                    help="BLAS threads (default 1; 0 keeps the library default)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    # The batched forward model multiplies many small matrices; BLAS threads only add
    # overhead there, and on a shared 2-core machine they made it 2.3x slower.
    limit = (threadpool_limits(args.blas_threads)
             if threadpool_limits is not None and args.blas_threads > 0
             else contextlib.nullcontext())
    with limit:
        rows = [run_one(m, seed=args.seed, n_elements=args.elements)
                for m in args.models.split(",")]
    if args.json:
        print(json.dumps(rows, indent=2))
        return rows
    print(f"{'model':<12} {'seconds':>8} {'cpu s':>8} {'sampling':>8} {'ESS_min':>8} "
          f"{'tau_max':>8} {'R-hat':>6} {'steps':>6} {'conv':>5} "
          f"{'x faster than NM+RK45 (3600 s)':>32}")
    for r in rows:
        print(f"{r['model']:<12} {r['seconds']:8.1f} {r['cpu_seconds']:8.1f} "
              f"{r['sampling_seconds']:8.1f} "
              f"{r['ess_min']:8.0f} {r['tau_max']:8.1f} {r['rhat_max']:6.3f} "
              f"{r['steps']:6d} {str(r['converged']):>5} {r['ratio_to_seed_workflow']:32.0f}")
    print(f"({np.mean([r['seconds'] for r in rows]):.1f} s per model on average; the "
          "reference gives a point estimate of two parameters only)")
    return rows


if __name__ == "__main__":
    main()
