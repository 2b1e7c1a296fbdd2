"""A batch evaluated in threads: the serial values to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.stats.threads import batch_threads
from bayesbeam.trials.synthetic import simulate_trial


def test_threads_give_the_serial_values_to_rounding():
    # A coupled model (spatial hysteresis: the band-limited invariant-subspace route) on a
    # 2 s release; 33 sets, so the slices are uneven.
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)
    trial = simulate_trial(beam, "viscous+sh", {"gamma": 0.03, "a": 0.02, "b": 0.05},
                           duration=2.0, noise_sd=1e-6, seed=0, n_elements=10)
    pb = Problem(trial, "viscous+sh", n_elements=6)
    U = pb.priors.to_u(pb.priors.sample(np.random.default_rng(1), 33))
    serial = pb.log_prob(U)
    with batch_threads(pb.log_prob, 3) as lp:
        threaded = lp(U)
        small = lp(U[:5])  # fewer rows than 2 slices of MIN_SLICE: one piece
    # Slices change how BLAS blocks the batched products: last-bit differences only
    # (5e-15 relative measured; 1e-13 allows 20x that, and a set evaluated with the
    # wrong parameters would be off by O(1)).
    assert np.array_equal(np.isfinite(serial), np.isfinite(threaded))
    fin = np.isfinite(serial)
    assert fin.sum() > 20
    np.testing.assert_allclose(threaded[fin], serial[fin], rtol=1e-13, atol=0)
    np.testing.assert_allclose(small, pb.log_prob(U[:5]), rtol=0, atol=0)
    with batch_threads(pb.log_prob, 1) as lp:
        assert lp == pb.log_prob  # the function itself, no pool


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_threads_must_be_a_positive_integer(bad):
    with pytest.raises(ValueError, match="positive integer"):
        with batch_threads(np.sum, bad):
            pass
