"""Bad inputs at the command line: one clear line and exit status 2, never a nonsense fit.

The catalogue of issue 18 (sanity before sampling): implausible beams (a modulus no
solid has, a mass in grams), records without a free decay (white noise, all zeros),
stamps in ms, files that are not UTF-8, a zero length, a signal file that is not a CSV,
and records too short to analyse. Every record is written into ``tmp_path``.
"""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from bayesbeam.cli.main import main
from bayesbeam.cli.options import prepare_trial
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

E = 62e9

TOML = """name = "case"

[signal]
file = "{file}"
time_column = "time_s"
value_column = "displacement_mm"
quantity = "displacement"
unit = "mm"
sensor_position = 0.3048
bandwidth = 100.0

[beam]
length = {length}
width = 0.127
thickness = 0.00072
mass = {mass}
{extra}
[initial]
tip_deflection = 0.005
"""


def _csv(t, y_mm):
    rows = (f"{a:.10g},{b:.10g}\n" for a, b in zip(t, y_mm, strict=True))
    return "time_s,displacement_mm\n" + "".join(rows)


@pytest.fixture(scope="module")
def decay():
    """Stamps (s) and tip displacement (mm) of a 5 s, 256 Hz release of a carbon strip."""
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E)
    tr = simulate_trial(beam, "viscous", {"E": E, "gamma": 0.1}, duration=5.0, dt=1 / 256,
                        noise_sd=1e-5)
    return tr.times, 1e3 * tr.values


def _write(folder, name, *, csv=None, length=0.3048, mass=0.021, extra="", file=None,
           decay=None):
    """Write ``name``.toml (and its CSV unless ``file`` names another) into ``folder``."""
    toml = TOML.format(file=file or f"{name}.csv", length=length, mass=mass, extra=extra)
    (folder / f"{name}.toml").write_text(toml, encoding="utf-8")
    if file is None:
        data = csv if csv is not None else _csv(*decay)
        path = folder / f"{name}.csv"
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data, encoding="utf-8")
    return folder / f"{name}.toml"


def _refused(capsys, argv, *words, absent=()):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert code == 2, (code, err)
    assert out == "" and err.count("\n") == 1, err
    assert "Traceback" not in err and err.startswith(f"bayesbeam {argv[0]}: error: ")
    for w in words:
        assert w in err, (w, err)
    for w in absent:
        assert w not in err, (w, err)
    return err


def _fit(path, tmp_path, *more):
    return ["fit", path, "--model", "viscous", "-o", tmp_path / "out", "--max-steps", "5",
            *more]


def test_modulus_no_solid_has_is_refused(tmp_path, capsys, decay):
    path = _write(tmp_path, "e30", extra="E = 1e30\n", decay=decay)
    _refused(capsys, _fit(path, tmp_path), "E 1e+30 Pa", "diamond", "--skip-checks",
             absent=("no spectrum",))


def test_mass_in_grams_is_refused(tmp_path, capsys, decay):
    path = _write(tmp_path, "grams", mass=21.0, decay=decay)
    _refused(capsys, _fit(path, tmp_path), "mass 21 kg", "density", "grams")


def test_white_noise_is_refused(tmp_path, capsys, decay):
    rng = np.random.default_rng(1)
    t = decay[0]
    path = _write(tmp_path, "noise", csv=_csv(t, rng.normal(0, 1, t.size)))
    _refused(capsys, _fit(path, tmp_path), "no decaying oscillation", "noise.csv",
             "displacement_mm")


def test_all_zero_signal_is_refused(tmp_path, capsys, decay):
    t = decay[0]
    path = _write(tmp_path, "zero", csv=_csv(t, np.zeros_like(t)))
    _refused(capsys, _fit(path, tmp_path), "constant", "zero.csv", "'displacement_mm'",
             absent=("LogUniform",))


def test_time_column_in_ms_is_refused(tmp_path, capsys, decay):
    t, y = decay
    path = _write(tmp_path, "ms", csv=_csv(1e3 * t, y))
    _refused(capsys, _fit(path, tmp_path), "in ms", "seconds", absent=("LogUniform",))


def test_non_utf8_files_are_named(tmp_path, capsys, decay):
    text = TOML.format(file="latin.csv", length=0.3048, mass=0.021, extra="note = 'é'\n")
    (tmp_path / "latin.toml").write_bytes(text.encode("latin-1"))
    (tmp_path / "latin.csv").write_text(_csv(*decay), encoding="utf-8")
    _refused(capsys, _fit(tmp_path / "latin.toml", tmp_path), "latin.toml", "not UTF-8")
    raw = _csv(*decay).encode().replace(b"time_s", b"time_s\xe9", 1)
    path = _write(tmp_path, "latincsv", csv=raw)
    _refused(capsys, _fit(path, tmp_path), "latincsv.csv", "not UTF-8")


def test_zero_length_is_blamed_on_the_length(tmp_path, capsys, decay):
    path = _write(tmp_path, "len0", length=0, decay=decay)
    _refused(capsys, _fit(path, tmp_path), "length must be", absent=("sensor_position",))


def test_a_file_that_is_not_the_csv_is_not_echoed(tmp_path, capsys):
    secret = tmp_path / "secret"
    secret.write_text("root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1::/:/bin/sh\n",
                      encoding="utf-8")
    path = _write(tmp_path, "passwd", file="secret")
    _refused(capsys, _fit(path, tmp_path), "no column 'time_s'", "does not look like",
             absent=("root:x", "daemon", "/bin/"))


def test_a_csv_with_other_columns_lists_them(tmp_path, capsys, decay):
    t, y = decay
    csv = "t,x_mm\n" + "".join(f"{a},{b}\n" for a, b in zip(t, y, strict=True))
    path = _write(tmp_path, "cols", csv=csv)
    _refused(capsys, _fit(path, tmp_path), "available columns: ['t', 'x_mm']")


@pytest.mark.parametrize("rows", [2, 10])
@pytest.mark.parametrize("command", ["fit", "compare", "diagnose", "inspect"])
def test_too_short_records_say_so_on_every_command(tmp_path, capsys, rows, command):
    rng = np.random.default_rng(3)
    t = np.arange(rows) / 256
    path = _write(tmp_path, f"r{rows}", csv=_csv(t, rng.normal(0, 1, rows)))
    argv = {"fit": _fit(path, tmp_path),
            "compare": ["compare", path, "--models", "viscous,viscous+kv", "-o",
                        tmp_path / "c", "--max-steps", "5"],
            "diagnose": ["diagnose", path, "-o", tmp_path / "d", "--max-steps", "5"],
            "inspect": ["inspect", path, "-o", tmp_path / "i"]}[command]
    _refused(capsys, argv, f"holds {rows} samples", absent=("padlen", "scipy"))


@pytest.mark.parametrize("command", ["compare", "diagnose"])
def test_compare_and_diagnose_run_the_checks(tmp_path, capsys, command, decay):
    path = _write(tmp_path, "grams", mass=21.0, decay=decay)
    argv = {"compare": ["compare", path, "--models", "viscous,viscous+kv", "-o",
                        tmp_path / "c", "--max-steps", "5"],
            "diagnose": ["diagnose", path, "-o", tmp_path / "d", "--max-steps", "5"]}[command]
    _refused(capsys, argv, "grams")


def _args(path, **kw):
    base = {"trial": path, "initial": None, "offset": None, "max_samples": None,
            "as_is": False, "rate": None, "window": None, "resample": None,
            "decimate": None, "skip_checks": True}
    return argparse.Namespace(**(base | kw))


def test_skip_checks_lets_implausible_inputs_through_with_warnings(tmp_path, decay):
    rng = np.random.default_rng(1)
    lines: list[str] = []
    for path in (_write(tmp_path, "grams", mass=21.0, decay=decay),
                 _write(tmp_path, "noise", csv=_csv(decay[0], rng.normal(0, 1, 1280)))):
        lines.clear()
        trial, pre = prepare_trial(_args(path), ValueError, say=lines.append)
        assert trial.times.size > 100 and pre.f1 > 0
        warnings = [ln for ln in lines if ln.startswith("warning: ")]
        assert warnings and all(w.endswith("(--skip-checks)") for w in warnings), lines
        assert ("density" in warnings[0]) != ("no decaying oscillation" in warnings[0])
    with pytest.raises(ValueError, match="no decaying oscillation"):
        prepare_trial(_args(path, skip_checks=False), ValueError, say=lines.append)


def test_skip_checks_on_the_command_line_warns_then_goes_on(tmp_path, capsys, decay):
    # E = 1e30 Pa: under --skip-checks the checks warn, and the plan then says why it
    # cannot go on (no sampling is reached: a fast case).
    path = _write(tmp_path, "e30", extra="E = 1e30\n", decay=decay)
    code = main([str(a) for a in _fit(path, tmp_path, "--skip-checks")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    lines = err.splitlines()
    assert lines[0].startswith("warning: E 1e+30 Pa") and lines[0].endswith("(--skip-checks)")
    assert "nominal first frequency" in lines[-1] and "E (Pa)" in lines[-1]


@pytest.mark.slow
def test_skip_checks_fits_a_mass_in_grams_with_a_warning(tmp_path, capsys, decay):
    path = _write(tmp_path, "grams", mass=21.0, decay=decay)
    code = main([str(a) for a in _fit(path, tmp_path, "--skip-checks", "--fixed-mesh",
                                      "--elements", "8")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "warning: mass 21 kg gives a density" in err
    assert (tmp_path / "out" / "summary.json").is_file()
