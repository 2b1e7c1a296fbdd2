"""The demo (source replication on the shipped data) at a tiny size, and its summary maths."""

from __future__ import annotations

import argparse
import json
import math

import pytest

from bayesbeam.cli import demo as cli_demo
from bayesbeam.cli import report as cli_report
from bayesbeam.jobs.demo import (
    DATA_DIR,
    DEMO_SETTINGS,
    DemoError,
    Replication,
    find_data,
    list_trials,
    run_replication,
)
from bayesbeam.jobs.summary import beam_summary, format_table

# Tiny settings: a few seconds per fit; the numbers are not converged posteriors.
TINY = {**DEMO_SETTINGS, "n_elements": 6, "nwalkers": 16, "target_ess": 10.0, "max_steps": 60,
        "min_steps": 20, "n_loo_draws": 100, "ppc_draws": 20, "plot_dpi": 50}


def test_find_data_says_where_it_looked(tmp_path):
    assert find_data() == DATA_DIR
    with pytest.raises(DemoError, match=str(tmp_path / "missing")):
        find_data(tmp_path / "missing")


def test_list_trials_of_the_shipped_data():
    all_trials = list_trials()
    assert len(all_trials) == 15  # 3 beams x 5 trials
    assert [p.stem for p in list_trials(beams=["beam2"], trials=[1, 3])] == [
        "beam2-trial1", "beam2-trial3"]
    with pytest.raises(DemoError, match="match"):
        list_trials(beams=["beam9"])


def _score(lz, err, mean_e, sd_e, converged=True):
    return {"log_evidence": lz, "log_evidence_err": err, "converged": converged,
            "posterior": {"E": {"mean": mean_e, "sd": sd_e}, "gamma": {"mean": 0.1, "sd": 0.01}}}


def test_beam_summary_adds_evidences_and_applies_the_tie_rule():
    scores = {
        "beam1-trial1": {"a": _score(100.0, 0.3, 50e9, 1e8), "b": _score(90.0, 0.4, 52e9, 3e8)},
        "beam1-trial2": {"a": _score(101.0, 0.4, 54e9, 2e8), "b": _score(110.5, 0.3, 53e9, 1e8)},
    }
    comps = {"beam1-trial1": {"indistinguishable": ["a"]},
             "beam1-trial2": {"indistinguishable": ["b"]}}
    rows = beam_summary(scores, comps, ["a", "b"])
    a, b = rows
    # Σ log Z and the error added in quadrature (independent trials).
    assert a["log_z"] == pytest.approx(201.0) and b["log_z"] == pytest.approx(200.5)
    assert a["log_z_err"] == pytest.approx(0.5)  # sqrt(0.3² + 0.4²)
    # |Δ| = 0.5 <= max(2 sqrt(0.5² + 0.5²), 1): tied.
    assert a["verdict"] == "best, tied" and b["verdict"] == "tied with best"
    assert b["delta"] == pytest.approx(-0.5) and b["delta_err"] == pytest.approx(math.sqrt(0.5))
    # Pooled E: mean of means, RMS of sds, sd of the means across trials.
    m, rms, sc = a["params"]["E"]
    assert m == pytest.approx(52e9)
    assert rms == pytest.approx(math.sqrt((1e16 + 4e16) / 2))
    assert sc == pytest.approx(math.sqrt(2) * 2e9)
    assert a["wins"] == 1 and b["wins"] == 1
    text = format_table(rows)
    assert "beam1" in text and "52.00 ± 0.16" in text and "tied with best" in text


def test_beam_summary_pools_modal_damping_when_every_trial_has_it():
    def with_modes(rec, z1, z2):
        modes = [{"damping_ratio": {"mean": z, "sd": 1e-5}} for z in (z1, z2)]
        return {**rec, "modes": {"modes": modes}}

    scores = {
        "beam1-trial1": {"a": with_modes(_score(100.0, 0.3, 50e9, 1e8), 0.010, 0.004),
                         "b": _score(90.0, 0.4, 52e9, 3e8)},
        "beam1-trial2": {"a": with_modes(_score(101.0, 0.4, 54e9, 2e8), 0.012, 0.006),
                         "b": with_modes(_score(110.5, 0.3, 53e9, 1e8), 0.01, 0.01)},
    }
    a, b = beam_summary(scores, {}, ["a", "b"])
    assert a["params"]["zeta1"][0] == pytest.approx(0.011)
    assert a["params"]["zeta2"][0] == pytest.approx(0.005)
    assert "zeta1" not in b["params"]  # one trial lacks modes: no pooled value
    text = format_table([a, b])
    assert "0.011 ± 1e-05; 0.005 ± 1e-05" in text and "n/a" in text


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    lines = []
    rep = run_replication(out, beams=["beam2"], trials=[1], models=["viscous", "viscous+kv"],
                          settings=TINY, jobs=1, diagnosis=False, progress=lines.append)
    return rep, lines


def test_tiny_replication_writes_results_report_and_provenance(tiny_run):
    rep, lines = tiny_run
    out = rep.outdir
    assert isinstance(rep, Replication)
    assert [(r["beam"], r["model"]) for r in rep.rows] == [("beam2", "viscous"),
                                                          ("beam2", "viscous+kv")]
    assert any("2 fits" in ln for ln in lines) and any("[  2/2]" in ln for ln in lines)
    for name in ("replication.json", "replication.txt", "report.html",
                 "beam2-trial1/comparison.json", "beam2-trial1/fits.png",
                 "beam2-trial1/viscous/summary.json", "beam2-trial1/viscous+kv/fit.png"):
        assert (out / name).is_file(), name
    rec = json.loads((out / "replication.json").read_text())
    assert rec["settings"]["n_elements"] == 6 and rec["seed"] == 0
    assert rec["data"]["beam2-trial1"]["data_sha256"] == rep.scores["beam2-trial1"][
        "viscous"]["provenance"]["data_sha256"]
    assert rec["provenance"]["bayesbeam"]
    summ = json.loads((out / "beam2-trial1/viscous+kv/summary.json").read_text())
    for key in ("priors", "settings", "provenance"):
        assert summ[key], key
    assert summ["settings"]["seed"] == 0 and summ["provenance"]["model"] == "viscous+kv"
    html = (out / "report.html").read_text()
    assert "beam2-trial1" in html and "data:image/png;base64," in html
    assert rep.table in (out / "replication.txt").read_text()
    # Every JSON output has the schema version; the fits carry f_k, ζ_k and units.
    jsons = sorted(out.rglob("*.json"))
    assert all(json.loads(p.read_text())["schema_version"] == 1 for p in jsons), jsons
    score = json.loads((out / "beam2-trial1/viscous+kv/score.json").read_text())
    assert score["modes"]["available"] and score["units"]["E"] == "Pa"
    assert (out / "beam2-trial1/viscous+kv/zeta_vs_f.png").is_file()


def test_rerun_reuses_cached_fits(tiny_run):
    rep, _ = tiny_run
    lines = []
    again = run_replication(rep.outdir, beams=["beam2"], trials=[1],
                            models=["viscous", "viscous+kv"], settings=TINY, jobs=1,
                            diagnosis=False, report=False, progress=lines.append)
    assert again.record["timing"]["fits_cached"] == 2
    assert again.record["timing"]["fits_computed"] == 0
    assert again.table == rep.table


def test_cli_demo_prints_table_and_report(tiny_run, monkeypatch, capsys):
    rep, _ = tiny_run
    seen = {}

    def fake_run_demo(outdir, **kw):
        seen.update(kw, outdir=outdir)
        return rep

    monkeypatch.setattr("bayesbeam.jobs.demo.run_demo", fake_run_demo)
    parser = argparse.ArgumentParser(prog="bayesbeam")
    sub = parser.add_subparsers(dest="command")
    cli_demo.register(sub)
    cli_report.register(sub)
    args = parser.parse_args(["demo", "-o", str(rep.outdir), "--jobs", "2", "--quick"])
    assert args.func(args) == 0
    assert seen["jobs"] == 2 and seen["quick"] is True
    out = capsys.readouterr().out
    assert "Σ log Z" in out and "Report:" in out and "Time:" in out
    args = parser.parse_args(["report", str(rep.outdir), "--json"])
    assert args.func(args) == 0
    assert json.loads(capsys.readouterr().out)["bytes"] > 1000


def test_demo_settings_are_bounded():
    # The demo must finish in minutes: a coarse mesh and a hard step cap.
    assert DEMO_SETTINGS["n_elements"] <= 8 and DEMO_SETTINGS["max_steps"] <= 400


@pytest.mark.slow
def test_tiny_replication_with_diagnosis_in_a_process_pool(tmp_path):
    rep = run_replication(tmp_path, beams=["beam1"], trials=[1], models=["viscous", "viscous+kv"],
                          settings=TINY, jobs=2, plots="none", progress=False,
                          diagnosis={"candidates": ("kv", "ar1_noise"), "max_rounds": 1,
                                     "n_elements": 6, "max_steps": 60, "min_steps": 20,
                                     "target_ess": 10.0, "loo_draws": 100})
    assert rep.diagnosis is not None and "named_causes" in rep.diagnosis
    d = tmp_path / "diagnosis-beam1-trial1"
    assert (d / "diagnosis.json").is_file() and (d / "diagnosis.md").is_file()
    assert "Diagnosis" in (tmp_path / "report.html").read_text()


class _FakeDiagnosis:
    """What run_diagnosis_task needs of a Diagnosis (the real one is a slow test)."""

    signatures_before = signatures_after = None

    def __init__(self, trial):
        self.trial = trial

    def to_json_dict(self):
        return {"trial": self.trial.name, "named_causes": [], "n": int(self.trial.times.size)}

    def narrative(self):
        return f"# Diagnosis of {self.trial.name}\n"


def test_diagnosis_task_carries_the_trial_not_a_relative_path(tmp_path, monkeypatch):
    # `bayesbeam demo --data DIR` with a relative DIR: the diagnosis task named the trial
    # by that relative path and a worker in another folder (a Dask worker) could not
    # read it. The task now carries the trial's data; the key is unchanged by the path.
    import shutil

    from bayesbeam.jobs import demo

    data = tmp_path / "here" / "mydata"
    data.mkdir(parents=True)
    for suffix in (".toml", ".csv"):
        shutil.copy(DATA_DIR / f"beam1-trial1{suffix}", data)
    monkeypatch.chdir(tmp_path / "here")
    settings = {**demo.DIAGNOSIS_SETTINGS, "candidates": ("kv",)}
    spec, trial = demo._diagnosis_spec(demo.Path("mydata/beam1-trial1.toml"), 0, settings)
    absolute, _ = demo._diagnosis_spec(data / "beam1-trial1.toml", 0, settings)
    assert spec == absolute  # the same record and cache key from either path
    assert demo.Path(spec["trial_file"]).is_absolute() and "trial" not in spec
    json.dumps(spec)  # task.json
    seen = []

    def fake_diagnose(trial, baseline, **kw):
        seen.append((trial, baseline, kw["seed"]))
        return _FakeDiagnosis(trial)

    monkeypatch.setattr("bayesbeam.diagnosis.diagnose.diagnose", fake_diagnose)
    monkeypatch.chdir(tmp_path)  # where a worker might start: mydata/ is not here
    files, record, _ = demo.run_diagnosis_task({**spec, "trial": trial})
    assert seen == [(trial, "viscous", 0)]
    assert record["n"] == trial.times.size and b"beam1-trial1" in files["diagnosis.md"]


@pytest.mark.slow
def test_demo_with_relative_data_on_a_dask_cluster(tmp_path, monkeypatch):
    # The cluster's workers start in an empty folder; the demo then runs from the folder
    # that holds the data, named by a relative path the workers cannot resolve.
    import shutil

    distributed = pytest.importorskip("dask.distributed")
    (tmp_path / "workers").mkdir()
    data = tmp_path / "caller" / "mydata"
    data.mkdir(parents=True)
    for suffix in (".toml", ".csv"):
        shutil.copy(DATA_DIR / f"beam1-trial1{suffix}", data)
    monkeypatch.chdir(tmp_path / "workers")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster:
        monkeypatch.chdir(tmp_path / "caller")
        rep = run_replication(
            "out", data_dir="mydata", models=["viscous", "viscous+kv"], settings=TINY,
            scheduler=cluster.scheduler_address, plots="none", report=False, progress=False,
            diagnosis={"candidates": ("kv",), "max_rounds": 1, "confirm_top": 1,
                       "n_elements": 6, "max_steps": 60, "min_steps": 20,
                       "target_ess": 10.0, "loo_draws": 100})
    assert rep.diagnosis is not None and rep.diagnosis["trial"] == "beam1-trial1"
    assert (tmp_path / "caller/out/diagnosis-beam1-trial1/diagnosis.json").is_file()
    assert set(rep.scores["beam1-trial1"]) == {"viscous", "viscous+kv"}
