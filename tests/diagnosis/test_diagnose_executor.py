"""``diagnose(..., executor=...)``: the parallel diagnosis is bitwise the serial one.

The smoke setting of ``test_diagnose.py`` (a short displacement record with an offset,
4 elements, a tiny sampler budget), with three candidates so that a round screens three
MAP searches and samples three models (the current one and the two best): both steps
go through the executor. The numbers are not converged posteriors; the runs are
compared with each other, as JSON text (equal text is equal bits; NaN equals NaN).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import pickle

import numpy as np
import pytest

from bayesbeam._util import one_blas_thread
from bayesbeam.diagnosis.diagnose import CONFIRM_WINDOW, diagnose
from bayesbeam.inference.problem import BETA1
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_signal
from bayesbeam.trials.trial import Trial

L, WIDTH, THICK, RHO, E = 0.4, 0.025, 0.002, 2700.0, 70e9
BEAM = Beam.rectangular(L, WIDTH, THICK, RHO * L * WIDTH * THICK, E=E)
W1 = BETA1**2 * np.sqrt(E * BEAM.I / (BEAM.rhoA * L**4))  # rad/s, physics.md §4
GAMMA = 2 * BEAM.rhoA * W1 * 0.003  # viscous ζ1 = 0.3 % (as in test_diagnose.py)
SETTINGS = dict(seed=0, max_rounds=1, candidates=("sensor_offset", "kv", "ar1_noise"),
                n_elements=4, refine_mesh=False, nwalkers=12, target_ess=50.0,
                min_steps=100, max_steps=100, loo_draws=100, confirm_top=2,
                signatures=False)


def _trial():
    t = np.arange(192) / 256.0
    y = simulate_signal(BEAM, "viscous", {"gamma": GAMMA, "w0": 0.01}, t, n_elements=4)
    rng = np.random.default_rng(1)
    rms = np.sqrt(np.mean(y**2))
    return Trial(times=t, values=y + 0.01 * rms * rng.standard_normal(t.size) + 0.1 * rms,
                 quantity="displacement", beam=BEAM, name="smoke")


def _record(d):
    """The diagnosis record without wall-clock times, as JSON text."""

    def drop(x):
        if isinstance(x, dict):
            return {k: drop(v) for k, v in x.items() if k != "seconds"}
        if isinstance(x, list):
            return [drop(v) for v in x]
        return x

    return json.dumps(drop(d.to_json_dict()), sort_keys=True)


class _Pickling:
    """An in-process executor that sends every job and result through pickle."""

    def __init__(self):
        self.calls = []

    def map(self, fn, jobs):
        for job in jobs:
            self.calls.append(fn.__name__)
            out = pickle.loads(pickle.dumps(fn))(pickle.loads(pickle.dumps(job)))
            yield pickle.loads(pickle.dumps(out))


@pytest.fixture(scope="module")
def serial():
    lines = []
    with one_blas_thread():  # the jobs' own thread limit, for the same floating point
        d = diagnose(_trial(), "viscous", progress=lines.append, **SETTINGS)
    return d, lines


def test_jobs_through_pickle_give_the_serial_diagnosis(serial, capsys):
    d0, lines0 = serial
    ex = _Pickling()
    lines = []
    capsys.readouterr()
    with one_blas_thread():
        d = diagnose(_trial(), "viscous", progress=lines.append, executor=ex, **SETTINGS)
    # With progress asked for, each stage of the round has a bar (stderr is captured:
    # not a terminal, so whole lines) that ends at 100 % naming the last model done.
    err = [ln for ln in capsys.readouterr().err.splitlines() if "100%" in ln]
    assert any(ln.startswith("diagnose round 1: MAP screen: 100%") and "3/3" in ln
               and "viscous+ar1_noise done" in ln for ln in err), err
    assert any(ln.startswith("diagnose round 1: sampling: 100%") and "2/2" in ln
               for ln in err), err
    # One round: three screens, then the current model and the best sampled (the
    # second best screened more than CONFIRM_WINDOW behind the offset: not sampled).
    # Around them, the local searches of the baseline's (and of the current model's
    # second) MAP search, one job per start.
    assert [c for c in ex.calls if c != "_guarded_call"] == (
        ["_optimise_job"] * 3 + ["_confirm_job"] * 2)
    assert ex.calls[0] == "_guarded_call"
    gains = sorted(c.delta_chi2_half for c in d.rounds[0].candidates)
    assert gains[-1] - gains[-2] > CONFIRM_WINDOW
    assert _record(d) == _record(d0)
    assert d.named_causes == d0.named_causes == ("sensor_offset",)
    # The same log, in the same order (times aside).
    strip = [ln.split(" (")[0] for ln in lines0]
    assert [ln.split(" (")[0] for ln in lines] == strip


@pytest.mark.slow
def test_process_pool_gives_the_serial_diagnosis(serial):
    d0, _ = serial
    with cf.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        d = diagnose(_trial(), "viscous", executor=ex, **SETTINGS)
    assert _record(d) == _record(d0)


def test_resumed_through_the_executor_sends_nothing_finished(serial, tmp_path):
    # Through the executor, a run that keeps its steps and then one that resumes from
    # them: the resumed run sends no job at all (every MAP search and sampling run is
    # taken from the folder) and its record is the serial one, bit for bit.
    d0, _ = serial
    steps = tmp_path / "steps"
    with one_blas_thread():
        first = diagnose(_trial(), "viscous", executor=_Pickling(), steps_dir=steps,
                         **SETTINGS)
        ex = _Pickling()
        again = diagnose(_trial(), "viscous", executor=ex, steps_dir=steps, resume=True,
                         **SETTINGS)
    assert ex.calls == []
    assert _record(first) == _record(d0)
    assert json.loads(_record(again))["rounds"] == json.loads(_record(d0))["rounds"]
    assert again.named_causes == d0.named_causes
    assert again.final_posterior == d0.final_posterior
