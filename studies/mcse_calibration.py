"""Are the reported Monte Carlo standard errors honest? Repeated runs on a closed form.

A linear-Gaussian posterior (three coefficients, Gaussian priors, known noise; its mean
and covariance in closed form, e.g. Bishop 2006 eq. 3.50-3.51) is sampled by the
package's emcee runner with ``--runs`` different seeds, each to its own convergence
rule. For every run and coefficient the error of the posterior mean is divided by the
MCSE the package would report, ``sd / sqrt(ESS)`` with the bulk ESS of
:func:`bayesbeam.stats.convergence.ess_rhat` (walkers as chains). If the MCSE is right,
these z have unit RMS; the RMS's own sampling error is about ``1 / sqrt(2 n)`` for
``n`` independent z (the three coefficients of one run are correlated, so somewhat more).

Run from the repository root::

    python studies/mcse_calibration.py --runs 40

Prints the RMS of z per coefficient and over all, with the walkers' τ.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from bayesbeam.stats.families import Normal
from bayesbeam.stats.priors import PriorSet
from bayesbeam.stats.sampling import init_walkers, run_emcee


def _toy(seed: int = 11):
    """Return the log density and the closed-form posterior mean of the toy regression."""
    rng = np.random.default_rng(seed)
    X = np.column_stack([np.ones(25), np.linspace(-1, 1, 25), np.linspace(-1, 1, 25) ** 2])
    beta, s_noise = np.array([0.5, -1.0, 2.0]), 0.3
    y = X @ beta + s_noise * rng.standard_normal(25)
    priors = PriorSet({"b0": Normal(0.0, 2.0), "b1": Normal(0.0, 2.0), "b2": Normal(1.0, 1.0)})
    m0, s0 = np.array([0.0, 0.0, 1.0]), np.diag([4.0, 4.0, 1.0])
    cov = np.linalg.inv(np.linalg.inv(s0) + X.T @ X / s_noise**2)
    mean = cov @ (np.linalg.inv(s0) @ m0 + X.T @ y / s_noise**2)

    def log_prob(U: np.ndarray) -> np.ndarray:
        r = y[None, :] - U @ X.T
        return priors.log_prior_u(U) - 0.5 * np.sum(r * r, axis=1) / s_noise**2

    return log_prob, mean, priors.names


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--walkers", type=int, default=24)
    args = ap.parse_args()
    log_prob, mean, names = _toy()
    z, taus = [], []
    t0 = time.perf_counter()
    for s in range(args.runs):
        start = init_walkers(log_prob, mean, args.walkers, rng=np.random.default_rng(s),
                             scale=0.01)
        ch = run_emcee(log_prob, start, seed=1000 + s, names=names, progress=False)
        flat = ch.flat_samples
        z.append((flat.mean(0) - mean) / (flat.std(0) / np.sqrt(ch.ess)))
        taus.append(ch.tau_max)
        done = s + 1
        left = (time.perf_counter() - t0) / done * (args.runs - done)
        print(f"run {done}/{args.runs}, ~{left:.0f} s left", flush=True)
    z = np.array(z)
    rms = np.sqrt(np.mean(z**2, axis=0))
    print(f"{args.runs} runs, {args.walkers} walkers, median tau {np.median(taus):.1f} steps")
    print("| coefficient | RMS of (mean error / reported MCSE) |")
    print("|---|---|")
    for n, r in zip(names, rms, strict=True):
        print(f"| {n} | {r:.2f} |")
    print(f"| all | {math.sqrt(np.mean(z**2)):.2f} (±{1 / math.sqrt(2 * z.size):.2f} if "
          f"independent) |")


if __name__ == "__main__":
    main()
