"""Benchmark: the amplitude-dependent forward models, numpy route against the compiled one.

:class:`bayesbeam.physics.nonlinear.NonlinearForward` (drag, friction, amplitude-dependent
stiffness: a linear model plus a slow-flow correction) on the 0.5 m aluminium strip of
the public data set (50.8 x 2 mm, no tip mass, so that the linear part is classically
damped as on the measured records; sensor at 0.44 m, acceleration), released from a
5 mm tip deflection, 512 Hz sampling. Each row times ``simulate`` on a
batch of 16 parameter sets (random damping, drag, friction and slope around realistic
sizes, seed 0) with ``backend='numpy'`` (the vectorised route) and ``backend='numba'``
(:mod:`bayesbeam.physics.slow_flow_kernel`), both in this process, medians of
``--repeats`` calls after one warm-up, and prints µs per set, the speed-up, and how the
compiled time grows with the mesh (the issue's aim: with the modes in band and the
samples, not with the elements) and with the samples.

Run: ``.venv/bin/python studies/bench_nonlinear.py [--repeats 7] [--elements 8,16,32]``;
writes ``studies/figures/bench_nonlinear.md``. The machine and its load are printed with
the table: compare times only within a run.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from bayesbeam._util import one_blas_thread
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.nonlinear import NonlinearForward
from bayesbeam.physics.propagate import numba_available

FIGURES = Path(__file__).resolve().parent / "figures"
L_, W_, T_ = 0.5, 0.0508, 0.002
MASS = 2700 * L_ * W_ * T_
FS = 512.0
CASES = {
    "viscous+kv+drag": {"drag": 0.2},
    "viscous+kv+friction": {"friction": 0.005},
    "viscous+kv+amplitude_stiffness": {"f1_slope": -40.0},
}


def _sets(fwd: NonlinearForward, force: dict[str, float], rng: np.random.Generator,
          n: int) -> np.ndarray:
    base = {"E": 70e9, "gamma": 0.01, "c_d": 2e-5, "w0": 5e-3, **force}
    X = np.array([[base.get(name, 0.0) for name in fwd.param_names]] * n)
    for j, name in enumerate(fwd.param_names):
        if name in ("gamma", "c_d", "drag", "friction", "f1_slope"):
            X[:, j] *= 1 + 0.3 * rng.uniform(-1, 1, n)
    return X


def _time(fwd: NonlinearForward, X: np.ndarray, repeats: int) -> float:
    """Median µs per set of ``fwd.simulate(X)``."""
    fwd.simulate(X)  # warm-up (and numba's compilation or cache load)
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fwd.simulate(X)
        runs.append(time.perf_counter() - t0)
    return 1e6 * statistics.median(runs) / X.shape[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--elements", default="8,16,32")
    ap.add_argument("--samples", default="1280,10240")
    ap.add_argument("--sets", type=int, default=16)
    args = ap.parse_args(argv)
    if not numba_available():
        print("numba is not installed: only the numpy route exists here")
        return 1
    beam = Beam.rectangular(L_, W_, T_, MASS, E=70e9, sensor_position=0.44,
                            quantity="acceleration")
    rows = []
    with one_blas_thread():
        for model, force in CASES.items():
            for n_t in (int(s) for s in args.samples.split(",")):
                times = np.arange(n_t) / FS
                for n_el in (int(e) for e in args.elements.split(",")):
                    us = {}
                    for backend in ("numpy", "numba"):
                        fwd = NonlinearForward(beam, model, times, n_elements=n_el,
                                               backend=backend)
                        X = _sets(fwd, force, np.random.default_rng(0), args.sets)
                        us[backend] = _time(fwd, X, args.repeats)
                    rows.append((model, n_t, n_el, us["numpy"], us["numba"]))
                    print(f"{model:32s} {n_t:6d} samples {n_el:3d} elements: numpy "
                          f"{us['numpy']:9.0f} µs, compiled {us['numba']:8.0f} µs "
                          f"({us['numpy'] / us['numba']:.1f}x)", flush=True)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"load {load:.1f}; 16 sets per call, medians of {args.repeats}, one BLAS thread.",
        "",
        "| model | samples | elements | numpy µs/set | compiled µs/set | speed-up |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    lines += [f"| {m} | {n} | {e} | {a:.0f} | {b:.0f} | {a / b:.1f}x |"
              for m, n, e, a, b in rows]
    text = "\n".join(lines) + "\n"
    FIGURES.mkdir(exist_ok=True)
    (FIGURES / "bench_nonlinear.md").write_text(text)
    print()
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
