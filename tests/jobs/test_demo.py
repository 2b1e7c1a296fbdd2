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
    assert "beam1" in text and "52.000" in text and "tied with best" in text


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
