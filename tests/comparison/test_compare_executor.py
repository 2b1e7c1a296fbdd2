"""``compare(..., executor=...)``: parallel fits give the serial numbers, bit for bit.

Tiny fits (0.5 s at 256 Hz, 3 Hermite elements, a fixed mesh, short chains): the numbers
are not converged posteriors; the tests compare runs with each other with ``==`` (each
fit carries its trial, model, settings and seed, so nothing else can change them).
"""

from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing
import pickle

import numpy as np
import pytest

from bayesbeam.comparison.compare import _evaluate_job, compare
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.io import read_trial
from bayesbeam.trials.synthetic import simulate_trial

MODELS = ["viscous", "viscous+kv", "viscous+sh"]
TINY = {"n_elements": 3, "refine_mesh": False, "nwalkers": 16, "target_ess": 10.0,
        "max_steps": 40, "min_steps": 20}
KW = {"seed": 4, "n_loo_draws": 60, "n_proposal": 200, "sensitivity_factors": ()}


@pytest.fixture(scope="module")
def trial_file(tmp_path_factory):
    beam = Beam.rectangular(0.3048, 0.127, 1.47e-3, 0.046, E=62e9)
    path = tmp_path_factory.mktemp("trial") / "tiny.toml"
    simulate_trial(beam, "viscous+kv", {"gamma": 0.1, "c_d": 4e6}, duration=0.5, dt=1 / 256,
                   tip_deflection=0.008, noise_sd=1e-5, seed=3, n_elements=6, name="tiny",
                   out=path)
    return path


def _numbers(comp):
    """What must be identical: evidence, criteria, posterior means, the verdict.

    As JSON text (floats by their shortest round-trip repr): equal text is equal bits,
    and a NaN (Laplace fails on a MAP at a prior bound) equals a NaN, unlike with ==.
    """
    out = {}
    for s in comp.scores:
        means = {k: v["mean"] for k, v in s.result.summary().items()}
        out[s.name] = [s.log_evidence, s.log_evidence_err, s.laplace_log_z, s.loo.elpd_loo,
                       s.waic.waic, s.max_loglik, means]
    return json.dumps([out, comp.verdict, comp.best], sort_keys=True)


@pytest.fixture(scope="module")
def serial(trial_file):
    return compare(read_trial(trial_file), MODELS, progress=False, **KW, **TINY)


def test_serial_comparison_has_every_model(serial):
    assert serial.names == tuple(MODELS)
    for s in serial.scores:
        assert np.isfinite(s.log_evidence), s.name


@pytest.mark.slow
def test_process_pool_gives_the_serial_numbers(serial, trial_file):
    with cf.ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        pooled = compare(read_trial(trial_file), MODELS, progress=False, executor=ex,
                         **KW, **TINY)
    assert pooled.names == serial.names
    assert _numbers(pooled) == _numbers(serial)


@pytest.mark.slow
def test_dask_cluster_gives_the_serial_numbers_without_the_trial_file(
        serial, trial_file, tmp_path, monkeypatch):
    # The workers start in another folder and the trial is named by a path relative to
    # this one: had a worker to read it, it could not. The trial's data travel in the job.
    distributed = pytest.importorskip("dask.distributed")
    monkeypatch.chdir(trial_file.parent)
    trial = read_trial(trial_file.name)
    monkeypatch.chdir(tmp_path)
    assert not (tmp_path / trial_file.name).exists()
    # ":0": a free port for the HTTP server (parallel test runs would both ask for 8787).
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        comp = compare(trial, MODELS, progress=False, executor=client.get_executor(), **KW,
                       **TINY)
    assert _numbers(comp) == _numbers(serial)


def test_job_is_independent_of_order(serial, trial_file):
    # The last model's job alone, in this process: the numbers of the full run.
    trial = read_trial(trial_file)
    job = {"trial": trial, "model": MODELS[-1], "seed": KW["seed"], "priors": None,
           "n_loo_draws": KW["n_loo_draws"], "proposal": "normal",
           "n_proposal": KW["n_proposal"], "settings": TINY, "progress": False, "outdir": None}
    s = _evaluate_job(job)
    assert s.log_evidence == serial[MODELS[-1]].log_evidence
    assert s.loo.elpd_loo == serial[MODELS[-1]].loo.elpd_loo


class _Replay:
    """An executor stand-in: any object with ``map`` will do; this one replays scores."""

    def __init__(self, scores):
        self.scores = {s.name: s for s in scores}
        self.jobs = []

    def map(self, fn, jobs):
        assert fn is _evaluate_job  # module-level: it pickles by name
        for job in jobs:
            self.jobs.append(job)
            yield self.scores[job["model"]]


def test_any_map_executor_gets_the_data_and_progress_names_models(serial, trial_file,
                                                                   capsys):
    trial = read_trial(trial_file)
    ex = _Replay(serial.scores)
    comp = compare(trial, MODELS, progress=True, executor=ex, outdir="ignored", **KW, **TINY)
    assert _numbers(comp) == _numbers(serial)
    for job in ex.jobs:
        # The trial object itself (its arrays) travels, and no folder of this machine.
        assert job["trial"] is trial and job["outdir"] is None and job["progress"] is False
        assert pickle.loads(pickle.dumps(job))["trial"].sha256 == trial.sha256
    # stderr is captured (not a terminal): the bar writes whole lines, the first and the
    # last at least; the last names the stage, the count and the last model done.
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert lines[0].startswith("compare tiny:") and "0/3" in lines[0]
    assert lines[-1].startswith("compare tiny: 100%") and "3/3" in lines[-1]
    assert "viscous+sh done" in lines[-1]
    compare(trial, MODELS, progress=False, executor=_Replay(serial.scores), **KW, **TINY)
    assert capsys.readouterr().err == ""


def test_scores_pickle_back_to_equal_numbers(serial):
    # FitResult keeps read-only mapping proxies, which pickle refuses by default: its
    # __reduce__ sends plain fields and rebuilds the result with its own constructor.
    back = pickle.loads(pickle.dumps(serial["viscous+kv"]))
    s = serial["viscous+kv"]
    assert back.log_evidence == s.log_evidence and back.loo.elpd_loo == s.loo.elpd_loo
    np.testing.assert_array_equal(back.result.chain.samples, s.result.chain.samples)
    assert dict(back.result.settings) == dict(s.result.settings)
    assert back.result.summary() == s.result.summary()
