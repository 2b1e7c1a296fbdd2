"""``compare_joint(..., executor=...)``: variants fitted in worker processes give the serial
numbers, bit for bit.

Tiny fits (0.5 s at 256 Hz, 3 Hermite elements, a fixed mesh, short chains): the numbers
are not converged posteriors; the runs are compared with each other as JSON text (each
variant's job carries its trials, model, settings and seed, so nothing else can change
them).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing

import pytest

from bayesbeam.comparison.joint import compare_joint
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

TINY = {"n_elements": 3, "refine_mesh": False, "nwalkers": 16, "target_ess": 10.0,
        "max_steps": 60, "min_steps": 20, "progress": False}
VARIANTS = [(("E",), ()), ((), ())]


@pytest.fixture(scope="module")
def trials():
    beam = Beam.rectangular(0.3048, 0.127, 1.47e-3, 0.046, E=62e9)
    return [simulate_trial(beam, "viscous", {"gamma": 0.1}, duration=0.5, dt=1 / 256,
                           tip_deflection=0.008 - 0.001 * i, noise_sd=1e-5, seed=i,
                           n_elements=6, name=f"r{i}") for i in range(2)]


def _numbers(cmp):
    return json.dumps(cmp.to_json_dict(), sort_keys=True)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::bayesbeam.stats.sampling.NotConvergedWarning")
def test_process_pool_gives_the_serial_numbers(trials):
    serial = compare_joint(trials, "viscous", VARIANTS, seed=3, **TINY)
    with cf.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        pooled = compare_joint(trials, "viscous", VARIANTS, seed=3, executor=ex, **TINY)
    assert [s.name for s in pooled.scores] == [s.name for s in serial.scores]
    assert _numbers(pooled) == _numbers(serial)
    # The short chains did not converge: a worker's warning is lost, its note is not.
    assert all(any("converge" in n for n in s.notes) for s in pooled.scores)
