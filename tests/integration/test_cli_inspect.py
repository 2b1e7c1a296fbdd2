"""``bayesbeam inspect``: outputs, summary, errors; one real aluminium record (slow)."""

import json
import math

import numpy as np
import pytest

from bayesbeam.cli.main import main
from bayesbeam.report.amplitude_plots import FIGURES, write_amplitude_figures
from bayesbeam.trials.amplitude import amplitude_curves
from bayesbeam.trials.io import write_trial
from bayesbeam.trials.modal_id import periodogram, spectral_peak
from bayesbeam.trials.realdata import enes_beam, load_enes
from bayesbeam.trials.trial import Trial


def _run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def trial_toml(tmp_path_factory):
    # Two damped modes in acceleration on jittered stamps (closed form is enough here:
    # this checks the command's plumbing; the estimator is validated in
    # tests/trials/test_amplitude.py against direct integrations).
    rng = np.random.default_rng(2)
    t = np.cumsum((1 + 0.2 * rng.uniform(-1, 1, 12000)) / 2000.0)
    y = (9.0 * np.exp(-0.15 * t) * np.cos(2 * np.pi * 6.0 * t)
         + 2.0 * np.exp(-1.0 * t) * np.cos(2 * np.pi * 39.0 * t + 0.4)
         + 0.01 * rng.standard_normal(t.size) - 0.005)
    trial = Trial(times=t, values=y, quantity="acceleration", beam=enes_beam(50),
                  name="two-mode")
    return write_trial(trial, tmp_path_factory.mktemp("inspect") / "trial.toml")


def test_inspect_writes_record_figures_and_summary(trial_toml, tmp_path, capsys):
    code, out, err = _run(capsys, "inspect", trial_toml, "-o", tmp_path)
    assert code == 0
    rec = json.loads((tmp_path / "inspect.json").read_text())
    for name in FIGURES.values():
        assert (tmp_path / name).stat().st_size > 1000
    assert rec["trial"] == "two-mode" and rec["quantity"] == "acceleration"
    f1 = [v for v in rec["windows"]["modes"][0]["frequency_hz"] if v is not None]
    assert np.allclose(f1, 6.0, rtol=1e-4)
    assert rec["bins"] and rec["bins"][-1]["ratio"] == pytest.approx(6.5, rel=1e-3)
    assert "largest amplitude bin" in out and "f2/f1" in out and "offset" in out
    # constant modal parameters: no change of state (tested or, if too short, said so)
    assert rec["state_change"]["found"] is False
    assert rec["state_change"]["reason"] in out
    # The span: the record starts at its largest value (a release), so the analysis
    # starts 0.1 s later (trials.preprocess); stderr says so and shows no progress for a
    # run of a second.
    assert rec["preprocessing"]["start"] == pytest.approx(rec["preprocessing"]["release"] + 0.1)
    assert [ln for ln in err.splitlines() if not ln.startswith("preprocessing:")] == []
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "What the data say before any model" in page
    assert page.count("data:image/png;base64,") == len(FIGURES)
    assert f"{rec['bins'][-1]['f1']:.5f}" in page  # the bin table
    code, out, _ = _run(capsys, "inspect", trial_toml, "-o", tmp_path, "--json",
                        "--periods", "3", "--modes", "1")
    assert code == 0 and json.loads(out)["settings"]["periods"] == 3.0


@pytest.mark.parametrize(
    ("args", "match"),
    [(["--periods", "1"], "--periods"), (["--modes", "0"], "--modes"),
     (["--f1", "-2"], "--f1"), (["--window", "2", "1"], "--window")],
)
def test_inspect_bad_input_exits_2_with_one_line(trial_toml, tmp_path, capsys, args, match):
    code, out, err = _run(capsys, "inspect", trial_toml, "-o", tmp_path, *args)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("bayesbeam inspect: error:")
    assert match in err
    code, _, err = _run(capsys, "inspect", tmp_path / "none.toml", "-o", tmp_path)
    assert code == 2 and err.count("\n") == 1
    data = tmp_path / "record.csv"  # a data file where its trial file is meant
    data.write_text("t,a\n0,1\n")
    code, _, err = _run(capsys, "inspect", data, "-o", tmp_path)
    assert code == 2 and err.count("\n") == 1 and "is a data file, not a trial file" in err


def test_overlay_hook_draws_extra_curves(tmp_path):
    t = np.arange(8000) / 2000.0
    y = np.exp(-0.3 * t) * np.cos(2 * np.pi * 5.0 * t)
    c = amplitude_curves(t, y, n_modes=1)
    a = np.geomspace(0.3, 1.0, 5)
    paths = write_amplitude_figures(
        c, tmp_path, extra={"f1": {"model": (a, np.full(5, 5.0))},
                            "zeta1": {"model": (a, np.full(5, 0.3 / (2 * math.pi * 5)))}})
    # No mode-2 figure when mode 2 was never fitted.
    assert sorted(p.name for p in paths) == sorted(
        v for k, v in FIGURES.items() if k != "mode2")


@pytest.mark.slow
def test_inspect_whole_real_record(real_data_root, tmp_path, capsys):
    trial = load_enes(50, 0, root=real_data_root, duration=None)
    toml = write_trial(trial, tmp_path / "trial" / "enes50.toml")
    code, out, _ = _run(capsys, "inspect", toml, "-o", tmp_path / "out")
    assert code == 0
    rec = json.loads((tmp_path / "out" / "inspect.json").read_text())
    for name in ("f1_vs_amplitude.png", "zeta1_vs_amplitude.png",
                 "residual_spectrogram.png"):
        assert (tmp_path / "out" / name).is_file()
    f, amp = periodogram(trial.times, trial.values)
    peak = spectral_peak(f, amp, float(f[np.argmax(amp)]))
    for b in rec["bins"]:
        assert b["f1"] == pytest.approx(peak, rel=0.05)
    assert rec["wall_time_s"] < 60
    assert "smallest amplitude bin" in out


@pytest.mark.slow
def test_inspect_reads_a_public_record_where_it_lies(real_data_root, tmp_path, capsys):
    # The record's own folder, no trial file: the raw record, the analysis chosen.
    folder = min(p for p in (real_data_root / "enes-alu-release" / "30cm_adxl").iterdir()
                 if p.is_dir())
    code, out, err = _run(capsys, "inspect", folder, "-o", tmp_path)
    assert code == 0
    rec = json.loads((tmp_path / "inspect.json").read_text())
    assert rec["trial"] == "enes-alu-30cm-0" and rec["quantity"] == "acceleration"
    assert rec["preprocessing"]["start"] > rec["preprocessing"]["release"]
    assert "preprocessing: analysis span" in err and "largest amplitude bin" in out
