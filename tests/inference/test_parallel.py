"""Batches shared with helper processes give the problem's own values (inference.parallel)."""

from pathlib import Path

import numpy as np
import pytest

import bayesbeam.inference.parallel as par
from bayesbeam.inference.parallel import ParallelLogProb
from bayesbeam.inference.problem import Problem
from bayesbeam.trials.io import read_trial

DATA = Path(__file__).resolve().parents[2] / "data"


def _batch(pb, k, seed):
    """k points around the prior's centre, spread wide enough to differ in every kernel
    choice that depends on the parameters (band reduction iterations, mode order)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(pb.priors.bounds_u, dtype=float).T
    mid = np.where(np.isfinite(lo + hi), 0.5 * (lo + hi), 0.0)
    half = np.where(np.isfinite(hi - lo), 0.05 * (hi - lo), 0.1)
    return mid + half * rng.uniform(-1.0, 1.0, (k, pb.ndim))


def test_split_batches_equal_the_serial_values_bit_for_bit(monkeypatch):
    # The coupled SH model through the record's band (the per-set reduction) with AR(1)
    # noise: the helper's rows must be the serial rows exactly, not to a tolerance, so
    # that a sampler's chain does not depend on how its batches were shared.
    monkeypatch.setattr(par, "MIN_SECONDS", 0.0)
    pb = Problem(read_trial(DATA / "beam1-trial1.toml"), "viscous+sh+ar1_noise",
                 n_elements=8)
    U = _batch(pb, 13, seed=3)
    with ParallelLogProb(pb.log_prob, helpers=1) as lp:
        first = lp(U)             # serial, and starts the helper
        split = lp(U)
        assert lp.batches_split == 1
        small = lp(U[:1])         # one row: never split
    serial = pb.log_prob(U)
    assert np.array_equal(first, serial) and np.array_equal(split, serial)
    assert np.array_equal(small, serial[:1])
    assert lp._pool is None       # closed on exit


def test_a_cheap_problem_never_starts_helpers():
    # One row of a 4-element viscous model takes microseconds, far under MIN_SECONDS.
    pb = Problem(read_trial(DATA / "beam1-trial1.toml"), "viscous", n_elements=4)
    with ParallelLogProb(pb.log_prob, helpers=1) as lp:
        for _ in range(3):
            out = lp(_batch(pb, 8, seed=1))
        assert lp._pool is None and lp.batches_split == 0
    assert np.array_equal(out, pb.log_prob(_batch(pb, 8, seed=1)))


def test_a_helper_that_dies_is_reported_and_its_rows_computed_here(monkeypatch):
    monkeypatch.setattr(par, "MIN_SECONDS", 0.0)
    pb = Problem(read_trial(DATA / "beam1-trial1.toml"), "viscous", n_elements=4)
    U = _batch(pb, 6, seed=2)
    with ParallelLogProb(pb.log_prob, helpers=1) as lp:
        lp(U)
        lp(U)                     # the helper is up
        for proc in list(lp._pool._processes.values()):
            proc.kill()
            proc.join()
        with pytest.warns(RuntimeWarning, match="helper process"):
            out = lp(U)
        assert lp._pool is None
        assert np.array_equal(out, pb.log_prob(U))


@pytest.mark.parametrize("helpers", [-1, 1.5, True])
def test_bad_helper_counts_are_refused(helpers):
    with pytest.raises(ValueError, match="non-negative integer"):
        ParallelLogProb(len, helpers=helpers)
