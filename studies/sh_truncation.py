"""Study: can coupled (spatial-hysteresis) damping be reduced to the modes in band.

Issue 13 asks for ``viscous+sh`` within 3x of a bare loop of the ``m x T`` rotations of the
modes in band, by a truncated reduction: keep the in-band modes, correct for the dropped
ones, and bound the truncation error. Within 3x at 1,280 samples leaves about 2.2 µs per
set for everything. The damping's modal matrix ``C = Φᵀ D Φ`` costs ``n²`` numbers per set;
only the rows of the kept modes (``J n``) and the diagonal fit that budget. This study
measures what is lost when nothing else of ``C`` is known, on the benchmark's own beam and
parameter sets (:mod:`bayesbeam.jobs.bench`: 16 elements, 32 modes, 100 Hz band, two modes
in band, ζ of 1-3 %).

Each variant changes ``C`` and then finds the in-band eigen-solutions exactly
(:func:`bayesbeam.physics.modal_coupled.band_eigenpairs`), so that the only error is the
information left out:

- ``kept block``: modal truncation, ``C_KK`` only (no coupling to the dropped modes);
- ``kept rows + dropped diagonal``: every entry a kept-rows method can know (the rows
  ``C_Kj``, and ``C_dd``), the dropped block's off-diagonal entries zeroed. A static
  (residual-flexibility) correction of the dropped modes uses less than this, so its
  error is no smaller in general.

It prints, over the 64 sets, the median and largest relative error of the in-band
eigenvalues, of the phase ``|δλ| t_end`` reached at the record's end, and of the signal
(``max |y - y_exact| / max |y_exact|``) against the exact band path (itself within 1e-13 of
the full state-space reduction, ``tests/physics/test_modal_coupled.py``). It also prints
the ratio ``ρ = |λ| Σ_d C_dd / |λ² + λ C_dd + ω_d²|`` that a bound from the kept rows and
the diagonal needs below 1 (``|C_ij| <= sqrt(C_ii C_jj)`` for a positive semidefinite C
turns the neglected dropped-block coupling into a geometric series of ratio ρ).

Run: ``.venv/bin/python studies/sh_truncation.py [--samples 1280] [--seed 0]``.
"""

from __future__ import annotations

import argparse

import numpy as np

from bayesbeam.jobs.bench import DT, N_SETS, PATH_BAND, _path_params, bench_beam
from bayesbeam.physics.forward import Forward
from bayesbeam.physics.modal_coupled import band_eigenpairs


def _variants(C: np.ndarray, J: int) -> dict[str, np.ndarray]:
    """Damping matrices (B, n, n) of the truncated variants (module docstring)."""
    n = C.shape[1]
    diag = np.arange(n)
    block = np.zeros_like(C)
    block[:, :J, :J] = C[:, :J, :J]
    block[:, diag[J:], diag[J:]] = C[:, diag[J:], diag[J:]]
    rows = C.copy()
    dropped = np.zeros((n, n), bool)
    dropped[J:, J:] = True
    dropped[diag, diag] = False
    rows[:, dropped] = 0.0
    return {"kept block": block, "kept rows + dropped diagonal": rows}


def _quantiles(x: np.ndarray) -> str:
    return f"median {np.median(x):.2e}, largest {np.max(x):.2e}"


def main(argv: list[str] | None = None) -> None:
    """Print the truncation errors of the variants on the benchmark's sets."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1280)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    times = np.arange(args.samples) * DT
    fwd = Forward(bench_beam(), "viscous+sh", times, n_elements=16, bandwidth=PATH_BAND)
    theta = _path_params(fwd, N_SETS, np.random.default_rng(args.seed))
    omega, C, phi, z0 = fwd.modal_initial_state(theta)
    w_band = 2 * np.pi * PATH_BAND
    lam, V, norm, keep, ok = band_eigenpairs(omega, C, w_band)
    if not ok.all():
        raise SystemExit("some benchmark sets left the band path; change --seed")
    J = lam.shape[1]
    y_exact, _ = fwd._band_modes_basis(omega, C, phi, z0[..., None])
    y_exact = y_exact[:, 0]
    print(f"{N_SETS} sets, {args.samples} samples, {omega.shape[1]} modes, "
          f"{int(keep.sum(axis=1).max())} in band ({J} tried)")
    # The ratio a bound from the kept rows and the diagonal needs below 1.
    d = np.diagonal(C, axis1=1, axis2=2)[:, None, J:]
    g = lam[..., None] ** 2 + lam[..., None] * d + omega[:, None, J:] ** 2
    rho = np.abs(lam) * np.sum(d / np.abs(g), axis=-1)
    print(f"rho (bound needs < 1): {_quantiles(rho[keep])}; "
          f"{np.mean(rho[keep] >= 1):.0%} of the in-band eigenvalues at or above 1")
    for name, Cv in _variants(C, J).items():
        lv, _, _, kv, okv = band_eigenpairs(omega, Cv, w_band)
        if not (okv.all() and np.array_equal(kv, keep)):
            print(f"{name}: the band's modes changed; not comparable")
            continue
        y, _ = fwd._band_modes_basis(omega, Cv, phi, z0[..., None])
        dl = np.abs(lv - lam)[keep]
        sig = np.max(np.abs(y[:, 0] - y_exact), axis=1) / np.max(np.abs(y_exact), axis=1)
        print(f"{name}:\n  eigenvalue, relative: {_quantiles(dl / np.abs(lam[keep]))}"
              f"\n  phase at the record's end (rad): {_quantiles(dl * times[-1])}"
              f"\n  signal, relative: {_quantiles(sig)}")


if __name__ == "__main__":
    main()
