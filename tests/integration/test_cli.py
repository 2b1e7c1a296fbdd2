"""Tests of the command line (bayesbeam.cli.main): modes, simulate, input errors, entry points."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from bayesbeam.cli.main import main
from bayesbeam.trials.io import read_trial

L, WIDTH, THICK, MASS = 0.3048, 0.127, 0.72e-3, 0.021
E = 6.2e10
I_REF = WIDTH * THICK**3 / 12
RHOA = MASS / L
# physics.md §4: β_n L of the uniform cantilever and the relative frequency errors of cubic
# Hermite elements at 16 elements (they converge as h⁴, from above: Rayleigh–Ritz).
BETA_L = np.array([1.875104069, 4.694091133, 7.854757438, 10.99554073])
ERR_16 = np.array([1.3e-7, 5.1e-6, 4.0e-5, 1.5e-4])


@pytest.fixture
def beam_toml(tmp_path):
    path = tmp_path / "beam.toml"
    path.write_text(
        f"[beam]\nlength = {L}\nwidth = {WIDTH}\nthickness = {THICK}\nmass = {MASS}\n",
        encoding="utf-8",
    )
    return path


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_modes_json_matches_beta_l(beam_toml, capsys):
    gamma = 0.05
    code, out, err = _run(
        capsys,
        "modes",
        beam_toml,
        "--model",
        "viscous",
        "--set",
        f"E={E}",
        "--set",
        f"gamma={gamma}",
        "--json",
    )
    assert code == 0 and err == ""
    res = json.loads(out)
    f = np.array(res["frequencies_hz"])
    z = np.array(res["damping_ratios"])
    assert f.size == z.size == 6  # default --n-modes
    omega = BETA_L**2 * math.sqrt(E * I_REF / (RHOA * L**4))
    rel = f[:4] / (omega / (2 * np.pi)) - 1
    # FE frequencies lie above the exact ones by the h⁴ error of physics.md §4 (given to two
    # digits there: allow 10 % on it, plus 1e-9 for the 10-digit β_n L values).
    assert np.all(rel > -1e-9)
    assert np.all(rel < 1.1 * ERR_16 + 1e-9)
    # Viscous damping of a uniform beam: ζ_n = gamma / (2 rhoA ω_n) exactly at the FE ω_n
    # (physics.md §2); against the analytic ω_n the same h⁴ error appears.
    assert np.all(np.abs(z[:4] * (2 * RHOA * omega) / gamma - 1) < 1.1 * ERR_16 + 1e-9)


def test_modes_text_and_options(beam_toml, capsys):
    code, out, _ = _run(
        capsys,
        "modes",
        beam_toml,
        "--set",
        f"E={E}",
        "--set",
        "gamma=0.05",
        "--elements",
        "8",
        "--n-modes",
        "3",
    )
    assert code == 0
    lines = out.strip().splitlines()
    assert "frequency" in lines[0] and len(lines) == 4
    f1 = float(lines[1].split()[1])
    assert f1 == pytest.approx(
        BETA_L[0] ** 2 * math.sqrt(E * I_REF / (RHOA * L**4)) / (2 * np.pi), rel=1e-5
    )  # 6 printed digits; 8-element error ~2e-6


def test_simulate_writes_trial(beam_toml, tmp_path, capsys):
    out_path = tmp_path / "out" / "trial.toml"
    code, out, err = _run(
        capsys,
        "simulate",
        beam_toml,
        "--model",
        "viscous",
        "--set",
        f"E={E}",
        "--set",
        "gamma=0.05",
        "--duration",
        "0.5",
        "--dt",
        "0.003906",
        "--tip-deflection",
        "0.004",
        "--noise-sd",
        "1e-5",
        "--seed",
        "1",
        "-o",
        out_path,
        "--json",
    )
    assert code == 0 and err == ""
    info = json.loads(out)
    assert info["n_samples"] == 128 and info["quantity"] == "displacement"
    trial = read_trial(out_path)
    assert trial.times.size == 128
    assert trial.values[0] == pytest.approx(0.004, abs=5e-5)  # w0 plus 1e-5 noise (5 sd)
    assert trial.meta["synthetic"]["params"] == {"E": E, "gamma": 0.05}


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--model", "viscous+foo", "--set", f"E={E}", "--set", "gamma=1"], "unknown model"),
        (["--model", "viscous+kv", "--set", f"E={E}", "--set", "gamma=1"], "c_d"),
        (["--set", f"E={E}", "--set", "gamma"], "NAME=VALUE"),
        (["--set", f"E={E}", "--set", "gamma=abc"], "not a number"),
        (["--set", f"E={E}", "--set", "gamma=1", "--set", "foo=2"], "not parameters"),
        (["--set", "E=-1", "--set", "gamma=1"], "admissible range"),
        (["--set", "gamma=1"], "give E"),
        (["--set", f"E={E}", "--set", "gamma=1", "--elements", "0"], "--elements"),
    ],
)
def test_modes_bad_input_exits_2_with_one_line(beam_toml, capsys, args, match):
    code, out, err = _run(capsys, "modes", beam_toml, *args)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("bayesbeam modes: error:")
    assert match in err
    assert "Traceback" not in err


def test_missing_files_and_bad_simulate_input(tmp_path, beam_toml, capsys):
    code, _, err = _run(capsys, "modes", tmp_path / "none.toml", "--set", f"E={E}")
    assert code == 2 and "not found" in err and err.count("\n") == 1
    code, _, err = _run(
        capsys,
        "simulate",
        beam_toml,
        "--set",
        f"E={E}",
        "--set",
        "gamma=0.05",
        "--duration",
        "-1",
        "-o",
        tmp_path / "t.toml",
    )
    assert code == 2 and "duration" in err and err.count("\n") == 1
    code, _, err = _run(
        capsys,
        "simulate",
        beam_toml,
        "--set",
        f"E={E}",
        "-o",
        tmp_path / "t.toml",
    )
    assert code == 2 and "gamma" in err


def test_console_entry_points(beam_toml):
    # The installed module entry point, in a fresh interpreter.
    res = subprocess.run(
        [sys.executable, "-m", "bayesbeam", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert res.returncode == 0
    for command in ("modes", "simulate", "bench"):
        assert command in res.stdout
    res = subprocess.run(
        [sys.executable, "-m", "bayesbeam", "modes", str(beam_toml), "--model", "nope"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr


def test_version_and_typed_marker():
    import importlib.metadata
    from pathlib import Path

    import bayesbeam

    res = subprocess.run([sys.executable, "-m", "bayesbeam", "--version"],
                         capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0
    assert res.stdout.strip() == f"bayesbeam {importlib.metadata.version('bayesbeam')}"
    # PEP 561: type checkers read the package's hints only where py.typed is installed
    assert (Path(bayesbeam.__file__).parent / "py.typed").is_file()
