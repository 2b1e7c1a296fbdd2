"""Property-based fuzzing of the CLI: whatever the trial files and options, the answer is
a one-line error with a documented status or a valid result, never a traceback.

Hypothesis mutates a shipped trial (its TOML values and its CSV rows) and the options of
``fit`` and ``modes``. ``fit`` is run up to the sampler (the sampler itself is replaced
by a sentinel that ends the example): everything that reads, checks and prepares the
input runs for real. Examples are derandomised, so a failure reproduces.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import tomllib
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from bayesbeam.cli.main import main  # noqa: E402
from bayesbeam.trials.io import _toml_dumps  # noqa: E402 - the package's own TOML writer

DATA = Path(__file__).resolve().parents[2] / "data"
BASE = tomllib.loads((DATA / "beam1-trial1.toml").read_text(encoding="utf-8"))
ROWS = (DATA / "beam1-trial1.csv").read_text(encoding="utf-8").splitlines()
#: Statuses that a failure may end with (bayesbeam.cli.main.EXIT without 1, internal).
EXPECTED = {2, 3, 4, 5}
FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


class Reached(BaseException):
    """The input passed every check and reached the sampler (a valid result)."""


@pytest.fixture
def no_sampling(monkeypatch):
    import bayesbeam.inference.fit as fit_module

    def stop(*args, **kwargs):
        raise Reached

    monkeypatch.setattr(fit_module, "fit", stop)


values = st.one_of(
    st.booleans(), st.integers(-10**9, 10**9),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.lists(st.integers(-5, 5), max_size=3),
)
SLOTS = [("signal", k) for k in BASE["signal"]] + [("beam", k) for k in BASE["beam"]
                                                 if k != "segments"] \
    + [("initial", "tip_deflection"), ("signal", "delimiter"), ("beam", "E"),
       ("beam", "root_spring"), ("analysis", "start"), ("analysis", "rate")]


@st.composite
def trial_files(draw):
    doc = json.loads(json.dumps(BASE))
    for table, key in draw(st.lists(st.sampled_from(SLOTS), max_size=3)):
        if draw(st.booleans()):
            doc.setdefault(table, {})[key] = draw(values)
        else:
            doc.get(table, {}).pop(key, None)
    if draw(st.booleans()):
        doc["beam"][draw(st.sampled_from(["lenght", "mass_kg", "E_GPa"]))] = 1.0
    rows = list(ROWS[1:])
    n = draw(st.sampled_from([0, 1, 2, 10, 63, 64, 300, len(rows)]))
    rows = rows[:n]
    scale = draw(st.sampled_from([1.0, 1.0, 1e-3, 1e3, -1.0, 0.0]))
    rows = [f"{float(r.split(',')[0]) * scale!r},{r.split(',')[1]}" for r in rows]
    for _ in range(draw(st.integers(0, 3))):
        if not rows:
            break
        i = draw(st.integers(0, len(rows) - 1))
        t, y = rows[i].split(",")[:2] if "," in rows[i] else (rows[i], "")
        rows[i] = draw(st.sampled_from([f"{t},abc", f"{t},", f"{t},nan", f"{t},inf",
                                        f"{t},{y},5", f"{t}", rows[max(0, i - 1)]]))
    if rows and draw(st.booleans()):
        j = draw(st.integers(0, len(rows) - 1))
        rows[0], rows[j] = rows[j], rows[0]  # unsorted stamps
    header = draw(st.sampled_from([ROWS[0], ROWS[0], "t,y", ""]))
    csv = "\n".join([header, *rows]) + "\n"
    raw = csv.encode() if draw(st.integers(0, 9)) else b"\xff\xfe" + csv.encode()
    return _toml_dumps(doc), raw


def _check_outcome(argv, capsys):
    try:
        code = main(argv)
    except Reached:
        capsys.readouterr()
        return "reached"
    except SystemExit as err:  # argparse: usage line and one error line, status 2
        _, stderr = capsys.readouterr()
        assert err.code == 2 and "Traceback" not in stderr
        return "usage"
    out, err = capsys.readouterr()
    assert "Traceback" not in err and "Traceback" not in out
    if code == 0:
        return "ok"
    assert code in EXPECTED, err
    errors = [ln for ln in err.splitlines() if ": error: " in ln]
    assert len(errors) == 1, err
    assert len(errors[0]) < 1000
    return "error"


@FUZZ
@given(files=trial_files())
def test_fuzzed_trial_files_end_in_one_line_or_reach_the_sampler(files, no_sampling, capsys):
    toml_text, csv_bytes = files
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "t.toml").write_text(toml_text, encoding="utf-8")
        (tmp / "beam1-trial1.csv").write_bytes(csv_bytes)
        _check_outcome(["fit", str(tmp / "t.toml"), "--model", "viscous", "-o",
                        str(tmp / "out"), "--max-steps", "10"], capsys)


numbers = st.one_of(st.sampled_from(["1", "2", "6", "16", "40", "0.5", "100", "300"]),
                    st.integers(-10**12, 10**12).map(str),
                    st.floats(allow_nan=True, allow_infinity=True).map(repr),
                    st.sampled_from(["", "x", "1e400", "-0", "1,5"]))
OPTIONS = {
    "--elements": numbers, "--window": st.tuples(numbers, numbers), "--rate": numbers,
    "--decimate": numbers, "--resample": numbers, "--max-samples": numbers,
    "--initial": st.sampled_from(["release", "impulse", "modes:0", "modes:-1", "modes:3",
                                  "modes:x", "bogus"]),
    "--offset": st.sampled_from(["fit", "none", "maybe"]), "--target-ess": numbers,
    "--max-steps": numbers, "--seed": numbers, "--jobs": numbers,
}


@FUZZ
@given(picked=st.dictionaries(st.sampled_from(sorted(OPTIONS)), st.just(None), max_size=3),
       data=st.data())
def test_fuzzed_fit_options_end_in_one_line_or_reach_the_sampler(picked, data, no_sampling,
                                                                 capsys):
    argv = []
    for name in picked:
        value = data.draw(OPTIONS[name], label=name)
        argv += [name, *value] if isinstance(value, tuple) else [name, value]
    with tempfile.TemporaryDirectory() as tmp:
        for ext in ("toml", "csv"):
            shutil.copy(DATA / f"beam1-trial1.{ext}", Path(tmp) / f"beam1-trial1.{ext}")
        _check_outcome(["fit", str(Path(tmp) / "beam1-trial1.toml"), "--model", "viscous",
                        "-o", str(Path(tmp) / "out"), *argv], capsys)


@FUZZ
@given(n_modes=numbers, elements=numbers, gamma=numbers, model=st.sampled_from(
    ["viscous", "viscous", "viscous+kv", "viscous+bogus", ""]))
def test_fuzzed_modes_options_end_in_one_line_or_a_table(n_modes, elements, gamma, model,
                                                         capsys):
    kv = ["--set", "c_d=1e-4"] if model == "viscous+kv" else []
    argv = ["modes", str(DATA / "beam1-trial1.toml"), "--model", model, "--n-modes", n_modes,
            "--elements", elements, "--set", f"gamma={gamma}", "--set", "E=6e10", *kv,
            "--json"]
    outcome = _check_outcome(argv, capsys)
    assert outcome in ("ok", "error", "usage")
