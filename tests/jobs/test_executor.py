"""Executor: serial, process-pool and Dask runs give identical results; the cache works."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from bayesbeam.jobs.executor import load_score, make_executor, map_tasks, run_fits
from bayesbeam.jobs.tasks import DEFAULT_SETTINGS, ExecutorError, FitTask, fit_tasks, task_key
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

# Tiny fits: a uniform beam, 0.6 s at 256 Hz, 4 elements, short chains. The numbers are
# not converged posteriors; the tests compare runs with each other, bit for bit.
TINY = {"n_elements": 4, "nwalkers": 16, "target_ess": 10.0, "max_steps": 60, "min_steps": 20,
        "n_loo_draws": 100}
MODELS = ["viscous", "viscous+kv"]


@pytest.fixture(scope="module")
def trial_file(tmp_path_factory):
    beam = Beam.rectangular(0.3048, 0.127, 1.47e-3, 0.046, E=62e9)
    path = tmp_path_factory.mktemp("trial") / "tiny.toml"
    simulate_trial(beam, "viscous+kv", {"gamma": 0.1, "c_d": 4e6}, duration=0.6, dt=1 / 256,
                   tip_deflection=0.008, noise_sd=1e-5, seed=3, n_elements=8, name="tiny",
                   out=path)
    return path


def _numbers(outcomes):
    """What must be identical between runs: evidence, criteria and posterior summaries."""
    out = {}
    for o in outcomes:
        s = o.score
        out[o.task.model] = (s["log_evidence"], s["log_evidence_err"], s["elpd_loo"], s["waic"],
                             s["max_loglik"], json.dumps(s["posterior"], sort_keys=True))
    return out


def test_task_key_depends_on_what_determines_the_result(trial_file, tmp_path):
    (t,) = fit_tasks([trial_file], ["viscous"], seed=1, settings=TINY)
    assert t.key == task_key(t) and len(t.key) == 64
    # Same inputs from another folder: same key (paths are not part of it).
    moved = FitTask(**{**t.__dict__, "trial_file": str(tmp_path / "elsewhere.toml")})
    assert moved.key == t.key
    for change in ({"seed": 2}, {"model": "viscous+kv"}, {"data_sha256": "0" * 64},
                   {"toml_sha256": "1" * 64}, {"settings": {**t.settings, "max_steps": 61}}):
        assert FitTask(**{**t.__dict__, **change}).key != t.key, change


def test_fit_tasks_validates_input(trial_file):
    with pytest.raises(ExecutorError, match="unknown settings"):
        fit_tasks([trial_file], ["viscous"], settings={"n_steps": 3})
    with pytest.raises(ExecutorError, match="seed"):
        fit_tasks([trial_file], ["viscous"], seed=-1)
    with pytest.raises(ExecutorError, match="at least one model"):
        fit_tasks([trial_file], [])
    tasks = fit_tasks([trial_file], MODELS, settings=TINY)
    assert [t.model for t in tasks] == MODELS
    assert tasks[0].settings == {**DEFAULT_SETTINGS, **TINY}


def test_make_executor_errors(monkeypatch):
    with pytest.raises(ExecutorError, match="jobs must be an integer"):
        with make_executor("2"):
            pass
    with pytest.raises(ExecutorError, match="scheduler address"):
        with make_executor(1, scheduler="localhost"):
            pass
    # dask.distributed missing: the message says how to install it.
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(ExecutorError, match=r"pip install 'bayesbeam\[dask\]'"):
        with make_executor(1, scheduler="tcp://127.0.0.1:1"):
            pass


def test_map_tasks_serial_keeps_order():
    seen = []
    out = map_tasks(abs, [-3, 2, -1], jobs=1, on_done=lambda i, r: seen.append((i, r)))
    assert out == [3, 2, 1] and seen == [(0, 3), (1, 2), (2, 1)]


@pytest.fixture(scope="module")
def serial_run(trial_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    tasks = fit_tasks([trial_file], MODELS, seed=5, settings=TINY)
    return tasks, out, run_fits(tasks, out, jobs=1, progress=False)


def test_serial_run_writes_results_and_scores_rebuild(serial_run):
    from bayesbeam.comparison.compare import compare_scores

    tasks, out, outcomes = serial_run
    assert [o.task.model for o in outcomes] == MODELS
    for o in outcomes:
        assert not o.cached
        for name in ("task.json", "score.json", "score.npz", "summary.json", "posterior.nc"):
            assert (o.path / name).is_file(), name
        assert json.loads((o.path / "task.json").read_text())["key"] == o.task.key
        prov = json.loads((o.path / "summary.json").read_text())["provenance"]
        assert prov["data_sha256"] == o.task.data_sha256 and prov["model"] == o.task.model
    scores = [load_score(o.path) for o in outcomes]
    # The rebuilt scores carry exactly the saved numbers.
    for s, o in zip(scores, outcomes, strict=True):
        assert s.log_evidence == o.score["log_evidence"]
        assert s.loo.elpd_loo == o.score["elpd_loo"]
        assert np.isclose(s.loo.pointwise.sum(), s.loo.elpd_loo, rtol=1e-12)  # sum of terms
    comp = compare_scores(scores)
    assert comp.best in MODELS and set(comp.names) == set(MODELS)
    # The demo's posterior files are complete ArviZ trees: ArviZ's own LOO reads them and
    # agrees with the saved score (same draws and terms; r_eff estimated a little
    # differently: 0.1 nat).
    import warnings

    import arviz

    for o in outcomes:
        tree = arviz.from_netcdf(o.path / "posterior.nc")
        assert {"log_likelihood", "posterior_predictive", "observed_data", "prior"} <= set(
            tree.children)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Estimated shape parameter of Pareto")
            assert arviz.loo(tree).elpd == pytest.approx(o.score["elpd_loo"], abs=0.1)


def test_rerun_skips_cached_and_recomputes_changed(serial_run, trial_file):
    tasks, out, first = serial_run
    lines = []
    again = run_fits(tasks, out, jobs=1, progress=lines.append)
    assert all(o.cached for o in again) and len(lines) == len(tasks)
    assert all("cached" in ln for ln in lines)
    assert _numbers(again) == _numbers(first)
    # A changed seed changes the key: that task is recomputed, into the same folder.
    (t2,) = fit_tasks([trial_file], ["viscous"], seed=6, settings=TINY)
    (o2,) = run_fits([t2], out, jobs=1, progress=False)
    assert not o2.cached
    assert json.loads((o2.path / "task.json").read_text())["key"] == t2.key


@pytest.mark.slow
def test_process_pool_identical_to_serial(serial_run, tmp_path):
    tasks, _, first = serial_run
    pooled = run_fits(tasks, tmp_path, jobs=2, progress=False)
    assert not any(o.cached for o in pooled)
    # Bitwise equality (exact ==): each task carries its seed and runs single-threaded.
    assert _numbers(pooled) == _numbers(first)


def test_dask_cluster_identical_to_serial(serial_run, tmp_path):
    # Two in-process (thread) workers: cheap to start; tasks in one process run one at a
    # time (see bayesbeam.jobs.executor.run_fit_task), which this also exercises.
    distributed = pytest.importorskip("dask.distributed")
    tasks, _, first = serial_run
    # ":0": a free port for the HTTP server (two clusters of parallel test workers would
    # both ask for 8787; the warning fails the strict suite)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        outcomes = run_fits(tasks, tmp_path, scheduler=cluster.scheduler_address,
                            progress=False)
    assert _numbers(outcomes) == _numbers(first)


@pytest.mark.slow
def test_dask_worker_processes_identical_to_serial(serial_run, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    tasks, _, first = serial_run
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        # A connected Client is accepted as the scheduler too.
        outcomes = run_fits(tasks, tmp_path, scheduler=client, progress=False)
    assert _numbers(outcomes) == _numbers(first)


def test_task_carries_its_trial_and_shows_a_progress_bar(tmp_path, capsys):
    # The trial file is gone (and the folder too) when the task runs: its data travel
    # in the task, which is what lets a cluster run it without a shared file system.
    import shutil

    src = tmp_path / "src"
    beam = Beam.rectangular(0.3048, 0.127, 1.47e-3, 0.046, E=62e9)
    simulate_trial(beam, "viscous", {"gamma": 0.1}, duration=0.4, dt=1 / 256,
                   tip_deflection=0.008, noise_sd=1e-5, seed=4, n_elements=6, name="gone",
                   out=src / "gone.toml")
    (task,) = fit_tasks([src / "gone.toml"], ["viscous"], seed=2, settings=TINY)
    shutil.rmtree(src)
    assert task.trial is not None and task.trial.sha256 == task.data_sha256
    record = task.to_dict()
    assert "trial" not in record and json.dumps(record)  # task.json: no arrays
    (o,) = run_fits([task], tmp_path / "out", jobs=1, progress=True, stage="tiny fits")
    assert np.isfinite(o.score["log_evidence"]) and not o.cached
    # stderr is captured (not a terminal): the bar writes whole lines, the first and the
    # last at least, naming the stage, the count and the last finished trial and model.
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert lines[0].startswith("tiny fits:") and "0/1" in lines[0]
    assert lines[-1].startswith("tiny fits: 100%") and "1/1" in lines[-1]
    assert "gone viscous log Z" in lines[-1]
    # A task without its data is refused with a message that says how to build one.
    bare = FitTask(**{**task.__dict__, "trial": None})
    assert bare.key == task.key  # the key is the SHA-256s, not the data object
    with pytest.raises(ExecutorError, match="carries no trial data"):
        run_fits([bare], tmp_path / "out2", jobs=1, progress=False)
