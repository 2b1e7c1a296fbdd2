"""Forward-model benchmark (issue: forward model; physics.md §4 timing reference).

Runs in one process, on the source study's single-ply beam (L 0.3048 m, width 0.127 m,
thickness 0.72 mm, mass 21 g) with a physical E = 6.2e10 Pa (f1 ≈ 11 Hz), 1280 samples
at dt = 0.003906 s, model ``viscous+sh`` with b = 0.01 m and damping ratios of a few %:

(i)   the package's batched forward model for 64 distinct parameter sets (S(b) included;
      a fresh batch per repeat, so that no modal system is reused, as in sampling);
(ii)  expm stepping of the same modal matrices (scipy.linalg.expm once per set, then
      z_{k+1} = P z_k);
(iii) scipy solve_ivp RK45 (rtol 1e-6) on the physical second-order system for one set, at
      4 elements to keep it to seconds.

Timings are medians over repeats; ratios are against (ii) and (iii) run in the same process.

(iv)  the forward model's paths (issue 13): for ``viscous``, ``viscous+kv`` and
      ``viscous+sh`` at 1,280 and 10,240 samples, the time per set of the path the forward
      model chooses (closed-form modal sum for the classically damped models, full
      propagation otherwise), the ratio of today's full propagation (``path='full'``, same
      sets, same process) to it, and its ratio to a bare loop doing only the ``m × T``
      complex rotations of the modes in band (the practical limit of any per-sample
      method): compiled (:func:`bayesbeam.physics.modal_kernel._rotations_kernel_py`, the
      closed form's kernel layout without its coefficients, lifetimes and anchors) when
      numba is installed, else a numpy loop; the table says which, and which backend the
      closed form used. One more row per length: ``viscous+sh`` seen through a
      :data:`PATH_BAND` sensor band, the eigen-solutions in band found directly and summed
      in closed form (path 'band-modes', :mod:`bayesbeam.physics.modal_coupled`; its ``m``
      the modes in band; its baseline the full propagation of every mode, whose signal
      differs by the modes the band removes).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np
import scipy.linalg as sla
from scipy.integrate import solve_ivp

from bayesbeam._util import compiled_kernel
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward
from bayesbeam.physics.modal_kernel import _rotations_kernel_py
from bayesbeam.physics.propagate import _pick_backend, single_blas_thread

__all__ = ["bench_beam", "bench_params", "format_bench", "run_bench"]

N_SETS = 64
N_SAMPLES = 1280
DT = 0.003906
#: Models and record lengths of the path table (iv).
PATH_MODELS = ("viscous", "viscous+kv", "viscous+sh")
PATH_SAMPLES = (1280, 10240)
#: Sensor band of the path table's band-limited row (Hz; the shipped trials' vibrometer):
#: spatial hysteresis from its eigen-solutions in band (:mod:`bayesbeam.physics.modal_coupled`).
PATH_BAND = 100.0


def bench_beam() -> Beam:
    """Return the source's single-ply beam with a physical E (first frequency ≈ 11 Hz)."""
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)


def bench_params(fwd: Forward, n_sets: int, rng: np.random.Generator) -> np.ndarray:
    """Draw ``n_sets`` distinct viscous+sh parameter sets giving ζ1 of ~1–3 %.

    Parameters
    ----------
    fwd : Forward
        A ``viscous+sh`` forward model with release initial condition.
    n_sets : int
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n_sets, 5)
        Columns E, gamma, a, b, w0.
    """
    beam = fwd.beam
    E = 6.2e10 * rng.uniform(0.9, 1.1, n_sets)
    w1 = 1.875104069**2 * np.sqrt(E * beam.I / (beam.rhoA * beam.length**4))
    zeta_v = rng.uniform(0.005, 0.015, n_sets)
    gamma = 2 * beam.rhoA * w1 * zeta_v  # physics.md §2: ζ = gamma / (2 rhoA ω)
    b = 0.01 * rng.uniform(0.9, 1.1, n_sets)
    # Narrow-ish kernel acts like KV with c_d I = a b²/2 and ζ = c_d ω / (2E) (physics.md §2).
    zeta_sh = rng.uniform(0.005, 0.015, n_sets)
    a = 4 * E * beam.I * zeta_sh / (w1 * b**2)
    w0 = np.full(n_sets, 5e-3)
    return np.column_stack([E, gamma, a, b, w0])


def _path_params(fwd: Forward, n_sets: int, rng: np.random.Generator) -> np.ndarray:
    """Return parameter sets for any of :data:`PATH_MODELS`, columns ``fwd.param_names``.

    Those of :func:`bench_params` plus a Kelvin–Voigt ``c_d`` giving ζ1 of 0.5–1.5 %
    (physics.md §2: ζ = c_d ω / (2E)).
    """
    E, gamma, a, b, w0 = bench_params(fwd, n_sets, rng).T
    beam = fwd.beam
    w1 = 1.875104069**2 * np.sqrt(E * beam.I / (beam.rhoA * beam.length**4))
    c_d = 2 * E * rng.uniform(0.005, 0.015, n_sets) / w1
    cols = {"E": E, "gamma": gamma, "c_d": c_d, "a": a, "b": b, "w0": w0}
    return np.column_stack([cols[name] for name in fwd.param_names])


def _bare_rotations(rot: np.ndarray, n: int) -> np.ndarray:
    """Rotate every mode ``n`` times, ``z ← z·r``, and nothing else (the practical limit).

    ``rot`` (B, m) holds each mode's one-step factor; a numpy loop over the samples,
    vectorised over sets and modes (the fallback of :func:`_bare_loop` without numba).
    """
    z = np.ones_like(rot)
    for _ in range(n):
        np.multiply(z, rot, out=z)
    return z


def _bare_loop() -> tuple[str, Callable[[np.ndarray, int], object]]:
    """Return the bare loop of the path table: ('compiled' or 'numpy', loop(rot, n)).

    The compiled one (with numba) sums ``Re Σ_j r_j^k`` over the samples in the closed
    form's kernel layout; the numpy one (:func:`_bare_rotations`) only rotates.
    """
    kernel = compiled_kernel(_rotations_kernel_py)
    if kernel is None:
        return "numpy", _bare_rotations

    def run(rot: np.ndarray, n: int) -> np.ndarray:
        return kernel(np.ascontiguousarray(rot.real), np.ascontiguousarray(rot.imag), n)

    return "compiled", run


def _modes_in_band(fwd: Forward, theta: np.ndarray) -> np.ndarray:
    """One-step rotations ``e^{iω dt}`` (B, m') of the undamped modes inside the band."""
    omega, _, _ = fwd.modal_system(theta)
    if fwd.bandwidth is not None:
        keep = omega <= 2 * np.pi * fwd.bandwidth
        omega = omega[:, : max(1, int(keep.sum(axis=1).max()))]
    return np.exp(1j * omega * fwd.dt)


def _path_table(
    n_elements: int, repeats: int, seed: int, n_sets: int, samples: tuple[int, ...]
) -> list[dict[str, float | int | str]]:
    """Rows of the path table (iv); see the module docstring."""
    rows: list[dict[str, float | int | str]] = []
    bare_kind, bare_loop = _bare_loop()
    backend = _pick_backend("auto")  # what the closed form's uniform sum uses
    cases = [(m, None) for m in PATH_MODELS] + [("viscous+sh", PATH_BAND)]
    for n in samples:
        times = np.arange(n) * DT
        for model, band in cases:
            auto = Forward(bench_beam(), model, times, n_elements=n_elements, bandwidth=band)
            # The baseline: today's full propagation of every mode (with a band, what the
            # reduction saves; the signals then differ by the modes the band removes).
            full = Forward(bench_beam(), model, times, n_elements=n_elements, path="full")
            theta = _path_params(auto, n_sets, np.random.default_rng(seed))
            y_auto = auto.simulate(theta)  # also the warm-up
            y_full = full.simulate(theta)
            if not (y_auto.valid.all() and y_full.valid.all()):
                raise RuntimeError(f"benchmark sets of {model!r} were rejected")
            # A fresh batch per repeat, as in sampling: the forward model keeps the modal
            # system of its last batch, and timing one batch again would skip it.
            batches = [_path_params(auto, n_sets, np.random.default_rng([seed, n, k]))
                       for k in range(repeats)]
            per_set = _median_time(auto.simulate, batches) / n_sets
            full_s = _median_time(full.simulate, batches) / n_sets
            rot = _modes_in_band(auto, theta)
            bare_loop(rot, n)  # warm-up: compiles or loads the kernel on the first call
            bare = _median_time(lambda _, r=rot, k=n: bare_loop(r, k), range(repeats)) / n_sets
            diff = (np.max(np.abs(y_auto.y - y_full.y)) / np.max(np.abs(y_full.y))
                    if band is None else math.nan)
            rows.append({
                "model": model, "n_samples": n, "band_hz": band,
                "path": str(auto.last_path) + ("" if band is None else f" {band:g} Hz"),
                "per_set_s": per_set, "full_per_set_s": full_s,
                "speedup_vs_full": full_s / per_set, "bare_per_set_s": bare,
                "ratio_to_bare": per_set / bare, "modes_in_band": int(rot.shape[1]),
                "max_rel_diff_vs_full": float(diff), "bare_loop": bare_kind,
                "closed_form_backend": backend,
            })
    return rows


def _median_time(fn: Callable[[Any], object], args: Iterable[Any]) -> float:
    """Median wall time (s) of ``fn(a)`` over the items ``a`` of ``args``."""
    times = []
    for a in args:
        t0 = time.perf_counter()
        fn(a)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _expm_stepping(A: np.ndarray, z0: np.ndarray, h: np.ndarray, n: int) -> np.ndarray:
    P = sla.expm(A * DT)
    z = z0.copy()
    y = np.empty(n)
    for k in range(n):
        y[k] = h @ z
        z = P @ z
    return y


def _rk45_one(theta: np.ndarray, n_elements: int, n_samples: int) -> float:
    beam = bench_beam()
    times = np.arange(n_samples) * DT
    fwd = Forward(beam, "viscous+sh", times, n_elements=n_elements)
    fe = fwd.fe
    E, gamma, a, b, w0 = theta
    K = E * fe.K
    D = gamma * fe.G + a * fwd.sh.matrix(b)
    n = K.shape[0]
    Minv = np.linalg.inv(fe.M)
    shape = np.linalg.solve(K, fe.tip)
    c0 = w0 * shape / (fe.tip @ shape)

    def rhs(_t: float, x: np.ndarray) -> np.ndarray:
        c, v = x[:n], x[n:]
        return np.concatenate([v, -Minv @ (K @ c + D @ v)])

    t0 = time.perf_counter()
    sol = solve_ivp(
        rhs,
        (0, times[-1]),
        np.concatenate([c0, np.zeros(n)]),
        method="RK45",
        rtol=1e-6,
        atol=1e-12,
        t_eval=times,
    )
    elapsed = time.perf_counter() - t0
    if not sol.success:  # a failed run would make a meaningless (short) timing
        raise RuntimeError(f"solve_ivp RK45 failed in the benchmark: {sol.message}")
    return elapsed


@single_blas_thread
def run_bench(
    *,
    n_elements: int = 16,
    repeats: int = 5,
    rk45_elements: int = 4,
    seed: int = 0,
    n_sets: int = N_SETS,
    n_samples: int = N_SAMPLES,
    path_samples: tuple[int, ...] = PATH_SAMPLES,
) -> dict[str, Any]:
    """Run the benchmark and return its figures.

    Parameters
    ----------
    n_elements : int
        Elements of the forward model under test (16 in the issue).
    repeats : int
        Repeats for the medians.
    rk45_elements : int
        Elements for the RK45 reference (its cost grows as N⁴).
    seed : int
        Seed of the parameter draws.
    n_sets : int
        Parameter sets in the batch (64 in the issue; fewer for a quick smoke test).
    n_samples : int
        Samples per response at dt = 0.003906 s (1280 in the issue).
    path_samples : tuple of int
        Record lengths of the path table (1,280 and 10,240 in issue 13); empty: no table.

    Returns
    -------
    dict
        ``per_set_s`` (s per parameter set of the batched forward model),
        ``expm_per_set_s``, ``rk45_per_set_s``, ``rk45_elements``, ``max_rel_diff``
        (forward model vs expm stepping, max over up to 16 sets of max|Δy| / max|y|),
        ``speedup_vs_expm``, ``speedup_vs_rk45``, ``n_sets``, ``n_samples``,
        ``n_elements``, and ``paths``: one dict per (samples, model) of the path table
        with ``model``, ``n_samples``, ``band_hz`` (None, or the sensor band of the
        band-limited row: the modes above it removed, its ``max_rel_diff_vs_full``
        NaN), ``path`` (the path the forward model took),
        ``per_set_s``, ``full_per_set_s``, ``speedup_vs_full`` (full / chosen),
        ``bare_per_set_s``, ``ratio_to_bare`` (chosen / bare rotations),
        ``modes_in_band``, ``max_rel_diff_vs_full``, ``bare_loop`` ('compiled' or
        'numpy') and ``closed_form_backend`` ('numba' or 'numpy').
    """
    for label, v in (("n_sets", n_sets), ("n_samples", n_samples), ("repeats", repeats)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
            raise ValueError(f"{label} must be a positive integer, got {v!r}")
    if n_samples < 2:
        raise ValueError(f"n_samples must be at least 2, got {n_samples}")
    for n in path_samples:
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
            raise ValueError(f"path_samples must be integers >= 2, got {n!r}")
    rng = np.random.default_rng(seed)
    times = np.arange(n_samples) * DT
    fwd = Forward(bench_beam(), "viscous+sh", times, n_elements=n_elements)
    theta = bench_params(fwd, n_sets, rng)
    fwd.simulate(theta)  # warm-up (caches, BLAS threads)
    # A fresh batch per repeat (the modal system of the last batch is kept: see _path_table).
    per_set = _median_time(fwd.simulate,
                           [bench_params(fwd, n_sets, rng) for _ in range(repeats)]) / n_sets
    res = fwd.simulate(theta)
    if not res.valid.all():
        raise RuntimeError("benchmark parameter sets were rejected by the forward model")
    y = res.y
    A, z0, h = fwd.state_space(theta)
    n_ref = min(n_sets, 16)
    expm_times, diffs = [], []
    for i in range(n_ref):
        t0 = time.perf_counter()
        y_ref = _expm_stepping(A[i], z0[i], h[i], n_samples)
        expm_times.append(time.perf_counter() - t0)
        diffs.append(np.max(np.abs(y[i] - y_ref)) / np.max(np.abs(y_ref)))
    rk45_runs = [_rk45_one(theta[0], rk45_elements, n_samples) for _ in range(max(1, repeats // 2))]
    rk45 = float(np.median(rk45_runs))
    expm_per_set = float(np.median(expm_times))
    return {
        "per_set_s": per_set,
        "expm_per_set_s": expm_per_set,
        "rk45_per_set_s": rk45,
        "rk45_elements": rk45_elements,
        "max_rel_diff": float(np.max(diffs)),
        "speedup_vs_expm": expm_per_set / per_set,
        "speedup_vs_rk45": rk45 / per_set,
        "n_sets": n_sets,
        "n_samples": n_samples,
        "n_elements": n_elements,
        "paths": _path_table(n_elements, repeats, seed, n_sets, tuple(path_samples)),
    }


def format_bench(res: dict[str, Any]) -> str:
    """Human-readable benchmark table.

    Parameters
    ----------
    res : dict
        Output of :func:`run_bench`.

    Returns
    -------
    str
    """
    lines = [
        f"forward-model benchmark: viscous+sh, {res['n_elements']} elements, "
        f"{res.get('n_samples', N_SAMPLES)} samples, {res['n_sets']} parameter sets "
        "(medians)",
        f"  batched forward model : {res['per_set_s'] * 1e6:10.1f} µs per set",
        f"  expm stepping (scipy) : {res['expm_per_set_s'] * 1e6:10.1f} µs per set"
        f"   ratio {res['speedup_vs_expm']:.1f}x",
        f"  solve_ivp RK45 ({res['rk45_elements']} el.) : "
        f"{res['rk45_per_set_s']:10.3f} s per set"
        f"   ratio {res['speedup_vs_rk45']:.0f}x",
        f"  max relative difference forward vs expm stepping: {res['max_rel_diff']:.2e}",
    ]
    paths = res.get("paths") or []
    if paths:
        lines += [
            "",
            f"forward-model paths ({res['n_sets']} sets; medians; full = today's full "
            f"propagation, bare = {paths[0]['bare_loop']} loop of only the m x T rotations; "
            f"closed form by the {paths[0]['closed_form_backend']} kernel)",
            f"  {'model':<11} {'samples':>7} {'path':<16} {'µs/set':>9} {'full µs/set':>11} "
            f"{'full/path':>9} {'path/bare':>9} {'m':>3} {'max rel diff':>12}",
        ]
        for row in paths:
            diff = row["max_rel_diff_vs_full"]
            lines.append(
                f"  {row['model']:<11} {row['n_samples']:>7} {row['path']:<16} "
                f"{row['per_set_s'] * 1e6:9.1f} {row['full_per_set_s'] * 1e6:11.1f} "
                f"{row['speedup_vs_full']:9.1f} {row['ratio_to_bare']:9.2f} "
                f"{row['modes_in_band']:>3} "
                + (f"{diff:12.2e}" if math.isfinite(diff) else f"{'(band)':>12}")
            )
    return "\n".join(lines)
