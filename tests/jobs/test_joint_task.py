"""The demo's joint fits: model choice, pooled names, the table, and one run end to end."""

from __future__ import annotations

import json
import math

import pytest

from bayesbeam.jobs.demo import DEMO_SETTINGS, run_replication
from bayesbeam.jobs.joint_task import format_joint_table, joint_model, pooled_names

TINY = {**DEMO_SETTINGS, "n_elements": 6, "nwalkers": 16, "target_ess": 10.0, "max_steps": 60,
        "min_steps": 20, "n_loo_draws": 100, "ppc_draws": 20, "plot_dpi": 50}


def _row(beam, model, verdict, E_sd=2e5):
    return {"beam": beam, "model": model, "verdict": verdict,
            "params": {"E": (60e9, E_sd, 1e5)}}


def test_joint_model_is_the_simplest_best_or_tied():
    models = ["viscous", "viscous+kv", "viscous+sh"]
    rows = [_row("b1", "viscous", "less supported"), _row("b1", "viscous+kv", "tied with best"),
            _row("b1", "viscous+sh", "best, tied"), _row("b2", "viscous", "best"),
            _row("b2", "viscous+kv", "less supported"), _row("b3", "viscous", "no evidence")]
    assert joint_model(rows, "b1", models) == "viscous+kv"
    assert joint_model(rows, "b2", models) == "viscous"
    assert joint_model(rows, "b3", models) is None
    assert joint_model(rows, "missing", models) is None


def test_pooled_names_are_the_laws_strengths():
    assert pooled_names("viscous+kv") == ("gamma", "c_d")
    assert pooled_names("viscous+sh+root_spring") == ("gamma", "eta")
    assert pooled_names("kv+ar1_noise") == ("c_d",)


def test_joint_table_sets_the_joint_sd_against_one_trials():
    q = {"mean": 60e9, "sd": 1e5, "q05": 59.9998e9, "q50": 60e9, "q95": 60.0002e9}
    pop = {"mean": 0.1, "sd": 0.01, "q05": 0.08, "q50": 0.1, "q95": 0.12}
    rec = {"beam": "b1", "model": "viscous", "pooled": ["gamma"],
           "labels": ["b1-t1", "b1-t2", "b1-t3", "b1-t4"],
           "posterior": {"E": q, "gamma_median": pop, "gamma_spread": pop},
           "converged": False, "ess_min": 80.0, "adequate": {"b1-t1": True, "b1-t2": False,
                                                             "b1-t3": True, "b1-t4": True},
           "notes": ["NotConvergedWarning: too short"]}
    text = format_joint_table([rec], [_row("b1", "viscous", "best", E_sd=2e5)])
    # RMS single-trial sd 2e5 over the joint 1e5: 2.00, beside sqrt(4) = 2.00.
    assert "2.00 (sqrt(4) = 2.00)" in text
    assert "80 (not converged)" in text and "3/4" in text
    assert "b1: NotConvergedWarning: too short" in text
    # GPa, with as many digits as it takes for the bounds to differ from the median.
    assert "60.00000 [59.99980, 60.00020]" in text


@pytest.mark.slow
def test_replication_fits_each_beam_jointly_and_caches_it(tmp_path):
    # Two trials of beam 2, tiny chains: the joint fit's folder, its record in
    # replication.json, its table in replication.txt; a re-run reuses it.
    lines: list[str] = []
    kw = {"beams": ["beam2"], "trials": [1, 2], "models": ["viscous", "viscous+kv"],
          "settings": TINY, "jobs": 1, "diagnosis": False, "report": False}
    rep = run_replication(tmp_path, progress=lines.append, **kw)
    (rec,) = rep.joint
    assert rec["beam"] == "beam2" and rec["labels"] == ["beam2-trial1", "beam2-trial2"]
    best = [r["model"] for r in rep.rows if r["verdict"].startswith("best")]
    assert rec["model"] in [m for m in kw["models"]
                            if any(r["model"] == m and r["verdict"] != "less supported"
                                   for r in rep.rows)]
    assert best  # the per-trial ranking exists and the joint model is among its top
    assert rec["shared"] == ["E"] and rec["pooled"] == list(pooled_names(rec["model"]))
    folder = tmp_path / "joint-beam2"
    for name in ("joint.json", "summary.json", "corner.png", "task.json"):
        assert (folder / name).is_file(), name
    summ = json.loads((folder / "summary.json").read_text())
    assert summ["joint"]["shared"] == ["E"] and set(summ["trials"]) == set(rec["labels"])
    E = rec["posterior"]["E"]
    assert E["q05"] < E["q50"] < E["q95"] and math.isfinite(E["sd"])
    saved = json.loads((tmp_path / "replication.json").read_text())
    assert saved["joint"][0]["model"] == rec["model"]
    assert "E sd: one trial / joint" in (tmp_path / "replication.txt").read_text()
    assert any("joint fit of beam2: done" in ln for ln in lines)
    again: list[str] = []
    rep2 = run_replication(tmp_path, progress=again.append, **kw)
    assert any("joint fit of beam2: cached" in ln for ln in again)
    assert rep2.joint == rep.joint


def test_a_failed_joint_fit_is_reported_not_fatal(tmp_path, monkeypatch):
    # A joint fit that refuses its input ends that beam's joint fit, with a message in
    # the progress lines and under the table; the per-trial results stand.
    import bayesbeam.jobs.joint_task as joint_task

    def refuse(task):
        raise ValueError("trials cannot share E: different beams")

    monkeypatch.setattr(joint_task, "run_joint_task", refuse)
    lines: list[str] = []
    rep = run_replication(tmp_path, beams=["beam2"], trials=[1, 2], models=["viscous"],
                          settings=TINY, jobs=1, diagnosis=False, report=False,
                          plots="none", progress=lines.append)
    assert rep.joint == [{"beam": "beam2", "model": "viscous",
                          "error": "trials cannot share E: different beams"}]
    assert any("joint fit of beam2: FAILED" in ln for ln in lines)
    text = (tmp_path / "replication.txt").read_text()
    assert "beam2: joint fit of viscous FAILED: trials cannot share E" in text
    assert not (tmp_path / "joint-beam2").exists()
