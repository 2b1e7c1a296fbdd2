"""Big and nonsense inputs on the command line (issue 18, "Reliability").

Each case was measured by a user: ``modes --n-modes -1`` printed 31 frequencies as JSON,
``modes --set gamma=1e6`` printed an empty table, ``simulate --duration 1e9`` asked for
terabytes, ``fit --elements 500`` ran 120 s without a line, and a 2-million-sample
record grew to 6 GB without a line. Every refusal here is one line on stderr with exit
status 2, before anything large is allocated.

The long record of the last case is scaled down (120 s at 1 kHz: 120,000 samples, 7x
the default budget of 16,384) so that the test writes it in about a second; the budget
logic and the mode search on a record that is mostly noise are the same as at 2 million.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from bayesbeam.cli.main import main
from bayesbeam.inference.settings import COSTLY_ELEMENTS, MAX_ELEMENTS
from bayesbeam.trials import preprocess
from bayesbeam.trials.io import read_trial
from bayesbeam.trials.synthetic import MAX_SIMULATED_SAMPLES

L, WIDTH, THICK, MASS, E = 0.3048, 0.127, 0.72e-3, 0.021, 6.2e10
RHOA = MASS / L
BEAM_TABLE = (f"[beam]\nlength = {L}\nwidth = {WIDTH}\nthickness = {THICK}\nmass = {MASS}\n"
              f"E = {E}\n")


@pytest.fixture
def beam_toml(tmp_path):
    path = tmp_path / "beam.toml"
    path.write_text(BEAM_TABLE, encoding="utf-8")
    return path


def _run(capsys, *argv) -> tuple[int, str, str]:
    """Run the command line in-process; a refusal while parsing exits (SystemExit)."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def _one_line_error(code: int, err: str, command: str) -> None:
    assert code == 2
    assert err.count("\n") == 1 and err.startswith(f"bayesbeam {command}: error:")
    assert "Traceback" not in err


# -- 1. modes --n-modes ------------------------------------------------------------------
@pytest.mark.parametrize("n", ["-1", "0"])
@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_modes_n_modes_must_be_positive(beam_toml, capsys, n, json_flag):
    code, out, err = _run(capsys, "modes", beam_toml, "--set", "gamma=0.1", "--n-modes", n,
                          *json_flag)
    _one_line_error(code, err, "modes")
    assert out == "" and "--n-modes must be a positive integer" in err and n in err


# -- 2. overdamped modes -----------------------------------------------------------------
def test_modes_all_overdamped_says_so(beam_toml, capsys):
    code, out, err = _run(capsys, "modes", beam_toml, "--set", "gamma=1e6")
    assert code == 0
    assert out.strip().splitlines() == [f"{'mode':>4} {'frequency [Hz]':>16} "
                                        f"{'damping ratio':>14}"]
    # 16 elements, 2 dofs a node: 32 modes, all above critical damping.
    assert err.count("\n") == 1 and err.startswith("note: all 32 modes")
    assert "overdamped" in err and "no frequency" in err
    code, out, err = _run(capsys, "modes", beam_toml, "--set", "gamma=1e6", "--json")
    rec = json.loads(out)
    assert rec["frequencies_hz"] == [] and rec["damping_ratios"] == []
    assert rec["overdamped_modes"] == 32 and "no frequency" in rec["note"]


def test_modes_some_overdamped_lists_the_others(beam_toml, capsys):
    # Viscous damping of a uniform beam: zeta_n = gamma / (2 rhoA omega_n). With
    # omega_1 ~ 71 rad/s and omega_2 ~ 448 rad/s, gamma = 20 puts mode 1 above critical
    # (zeta_1 ~ 2.0) and leaves mode 2 below (zeta_2 ~ 0.32).
    code, out, err = _run(capsys, "modes", beam_toml, "--set", "gamma=20", "--json")
    assert code == 0
    rec = json.loads(out)
    assert rec["overdamped_modes"] == 1 and len(rec["frequencies_hz"]) == 6
    z2 = 20 / (2 * RHOA * 2 * np.pi * rec["frequencies_hz"][0])
    assert rec["damping_ratios"][0] == pytest.approx(z2, rel=1e-6)
    assert "1 of the model's 32 modes is overdamped" in err
    code, out, _ = _run(capsys, "modes", beam_toml, "--set", "gamma=0.1", "--json")
    assert json.loads(out)["overdamped_modes"] == 0 and "note" not in json.loads(out)


# -- 3. simulate: sample count and nonsense values ---------------------------------------
def test_simulate_refuses_too_many_samples_before_allocating(beam_toml, tmp_path, capsys):
    out_path = tmp_path / "sim.toml"
    tic = time.perf_counter()
    code, out, err = _run(capsys, "simulate", beam_toml, "--set", "gamma=0.1",
                          "--duration", "1e9", "-o", out_path)
    assert time.perf_counter() - tic < 20  # 2.6e11 samples would take days (or fail)
    _one_line_error(code, err, "simulate")
    assert "2.56e+11 samples" in err and f"{MAX_SIMULATED_SAMPLES:,}" in err
    assert "--duration" in err and "--dt" in err
    assert not out_path.exists() and not out_path.with_suffix(".csv").exists()


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--duration", "0"], "duration must be a positive"),
        (["--duration", "-1"], "duration must be a positive"),
        (["--duration", "nan"], "duration must be a positive"),
        (["--dt", "0"], "dt must be a positive"),
        (["--dt", "-0.01"], "dt must be a positive"),
        (["--dt", "1e-12"], "larger sample step (--dt)"),
        (["--noise-sd", "-1"], "noise_sd must be a finite number >= 0"),
        (["--noise-sd", "inf"], "noise_sd must be a finite number >= 0"),
        (["--tip-deflection", "nan"], "tip_deflection must be a finite"),
        (["--seed", "-1"], "--seed must be a non-negative"),
        (["--elements", "0"], "--elements must be an integer from 1"),
    ],
)
def test_simulate_nonsense_values(beam_toml, tmp_path, capsys, args, match):
    out_path = tmp_path / "sim.toml"
    code, out, err = _run(capsys, "simulate", beam_toml, "--set", "gamma=0.1", *args,
                          "-o", out_path)
    _one_line_error(code, err, "simulate")
    assert match in err and out == "" and not out_path.exists()


# -- 4. --elements ---------------------------------------------------------------------
@pytest.mark.parametrize("command", ["modes", "simulate", "fit", "compare", "diagnose",
                                     "bench"])
def test_elements_above_the_limit_refused_while_parsing(beam_toml, tmp_path, capsys,
                                                        repo_root, command):
    trial = repo_root / "data" / "beam1-trial1.toml"
    argv = {
        "modes": ["modes", beam_toml, "--set", "gamma=0.1"],
        "simulate": ["simulate", beam_toml, "--set", "gamma=0.1", "-o", tmp_path / "s.toml"],
        "fit": ["fit", trial, "--model", "viscous", "-o", tmp_path / "out"],
        "compare": ["compare", trial, "--models", "viscous", "-o", tmp_path / "out"],
        "diagnose": ["diagnose", trial, "-o", tmp_path / "out"],
        "bench": ["bench"],
    }[command]
    tic = time.perf_counter()
    code, out, err = _run(capsys, *argv, "--elements", "500")
    assert time.perf_counter() - tic < 10
    _one_line_error(code, err, command)
    # The estimate (2000 dense states: 5.6 GB per step of 32 walkers) and the range.
    assert "--elements 500 is above the limit of 200" in err
    assert "2000 dense states" in err and "5.6 GB" in err
    assert f"at most {MAX_ELEMENTS}" in err and "use 8 to" in err
    assert out == "" and not (tmp_path / "out").exists()


def test_large_elements_print_what_they_cost(beam_toml, capsys):
    code, out, err = _run(capsys, "modes", beam_toml, "--set", "gamma=0.1", "--n-modes", "1",
                          "--elements", str(COSTLY_ELEMENTS))
    assert code == 0 and len(out.strip().splitlines()) == 2
    assert err.count("\n") == 1
    assert err.startswith(f"note: --elements {COSTLY_ELEMENTS}: {4 * COSTLY_ELEMENTS} dense")
    assert "MB" in err and "x the default 16 elements' time" in err
    code, _, err = _run(capsys, "modes", beam_toml, "--set", "gamma=0.1", "--elements",
                        str(COSTLY_ELEMENTS - 1))
    assert code == 0 and err == ""


# -- 5. a long record ------------------------------------------------------------------
def _long_record(folder, *, declared: bool, fs: float = 1000.0, duration: float = 120.0):
    """Write a long acceleration record (mostly noise after 10 s of decay) as a trial.

    Modes 1 and 2 of the trial's beam at the nominal E (the nominal ratio f2/f1), 1 %
    and 0.3 % damping, released 0.5 s into the record, a 0.3 m/s^2 offset and 0.05 m/s^2
    of white noise. The declared variant starts at the release, without the offset.
    """
    from bayesbeam.physics.beam import Beam
    from bayesbeam.trials.trial import Trial

    beam = Beam.rectangular(L, WIDTH, THICK, MASS, E=E, sensor_position=L,
                            quantity="acceleration")
    probe = Trial(times=np.arange(4) / fs, values=np.zeros(4), quantity="acceleration",
                  beam=beam, name="probe")
    f1 = preprocess.nominal_f1(probe)
    f2 = f1 * float(preprocess._ratios(probe)[1])
    rng = np.random.default_rng(5)
    t = np.arange(round(duration * fs)) / fs
    tt = np.clip(t - 0.5, 0.0, None)
    y = (50 * np.exp(-0.01 * 2 * np.pi * f1 * tt) * np.cos(2 * np.pi * f1 * tt)
         + 20 * np.exp(-0.003 * 2 * np.pi * f2 * tt) * np.cos(2 * np.pi * f2 * tt))
    y = np.where(t < 0.5, 0.0, y) + 0.3 + 0.05 * rng.standard_normal(t.size)
    name = "declared" if declared else "raw"
    if declared:
        t, y = t[t >= 0.5] - 0.5, y[t >= 0.5] - 0.3
    with (folder / f"{name}.csv").open("w", encoding="utf-8") as fh:
        fh.write("time_s,accel_m_s2\n")
        np.savetxt(fh, np.column_stack([t, y]), delimiter=",", fmt="%.7g")
    initial = "\n[initial]\ntip_deflection = 0.005\n" if declared else ""
    (folder / f"{name}.toml").write_text(
        f'name = "{name}"\n\n[signal]\nfile = "{name}.csv"\ntime_column = "time_s"\n'
        'value_column = "accel_m_s2"\nquantity = "acceleration"\nunit = "m/s^2"\n'
        f"sensor_position = {L}\n\n{BEAM_TABLE}{initial}",
        encoding="utf-8",
    )
    return folder / f"{name}.toml", f1, f2


def test_long_record_taken_as_given_is_refused_with_the_fixes(tmp_path, capsys):
    path, _, _ = _long_record(tmp_path, declared=True)
    tic = time.perf_counter()
    code, out, err = _run(capsys, "fit", path, "--model", "viscous", "-o", tmp_path / "out")
    assert time.perf_counter() - tic < 20
    _one_line_error(code, err, "fit")
    assert "119,500 samples" in err and "budget of 16,384" in err
    for fix in ("--rate 137 or lower", "--decimate 8 or more", "--window T0 T1",
                "--max-samples 119500"):
        assert fix in err
    assert out == ""


def test_long_raw_record_is_resampled_within_the_budget(tmp_path):
    path, f1, f2 = _long_record(tmp_path, declared=False)
    trial = read_trial(path)
    tic = time.perf_counter()
    out, pre = preprocess.prepare(trial)
    assert time.perf_counter() - tic < 10
    # Both modes are seen on the 10 s of motion (the 120 s Hann window over the whole
    # record weighted the decay by almost nothing: mode 2 was lost, mode 1's peak was 117
    # x the local floor instead of 1e7), the analysis ends with the motion and keeps
    # both modes within the budget.
    assert pre.modes_seen == pytest.approx([f1, f2], rel=2e-3)
    assert pre.mode_strength[0] > 1e6
    assert 7.0 < pre.end < 10.0 and pre.band > f2
    assert out.times.size == pre.n_samples <= preprocess.MAX_SAMPLES


def test_long_record_fixes_named_in_the_refusal_work(tmp_path):
    path, _, _ = _long_record(tmp_path, declared=True)
    trial = read_trial(path)
    out, pre = preprocess.prepare(trial, rate=137.0)
    assert out.times.size <= preprocess.MAX_SAMPLES and pre.initial == "release"
    out, pre = preprocess.prepare(trial, max_samples=119_500)
    assert out.times.size == 119_500 and pre.rate is None
    with pytest.raises(preprocess.PreprocessError, match="the given rate 500 Hz"):
        preprocess.prepare(trial, rate=500.0)


@pytest.mark.slow
def test_long_raw_record_fit_from_the_command_line(tmp_path, capsys):
    path, _, _ = _long_record(tmp_path, declared=False)
    code, _, err = _run(capsys, "fit", path, "--model", "viscous", "-o", tmp_path / "out",
                        "--max-steps", "20", "--fixed-mesh")
    assert code == 0, err
    lines = err.splitlines()
    assert lines[0].startswith("preprocessing: analysis span")
    assert "modes seen at" in lines[1] and "of 120000 samples" in lines[1]
    assert (tmp_path / "out" / "summary.json").is_file()
