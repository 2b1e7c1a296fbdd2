"""Trial format: round trips, unit conversion, errors, windowing and decimation."""

import hashlib
import tomllib
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

from bayesbeam.physics.beam import Beam, Segment
from bayesbeam.trials.io import _toml_dumps, read_trial, write_trial
from bayesbeam.trials.trial import STANDARD_GRAVITY, Trial, TrialError, anti_alias_taps


def _beam(**kw):
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10, **kw)


def _trial(quantity="displacement", n=200, seed=0, times=None, **kw):
    rng = np.random.default_rng(seed)
    t = 0.004 * np.arange(n) if times is None else times
    y = 1e-3 * np.exp(-t) * np.sin(2 * np.pi * 11 * t) + 1e-6 * rng.normal(size=t.size)
    return Trial(t, y, quantity, _beam(sensor_position=0.25), name="t1", **kw)


def _write_files(tmp_path, csv_text, **signal):
    sig = {
        "file": "d.csv",
        "time_column": "time",
        "value_column": "w",
        "quantity": "displacement",
        "unit": "m",
        "sensor_position": 0.3,
    }
    sig.update(signal)
    beam = {"length": 0.3048, "width": 0.127, "thickness": 0.00072, "mass": 0.021}
    (tmp_path / "d.csv").write_text(csv_text)
    p = tmp_path / "trial.toml"
    p.write_text(_toml_dumps({"signal": sig, "beam": beam}))
    return p


GOOD_CSV = "time,w,other\n0.0,1.0,5\n0.1,2.0,5\n0.25,-3.5,5\n"


# -- round trips -------------------------------------------------------------------------
@pytest.mark.parametrize(
    "quantity,unit",
    [
        ("displacement", "m"),
        ("displacement", "mm"),
        ("velocity", "m/s"),
        ("velocity", "mm/s"),
        ("acceleration", "m/s^2"),
        ("acceleration", "g"),
    ],
)
def test_round_trip_each_unit(tmp_path, quantity, unit):
    tr = _trial(
        quantity,
        initial={"tip_deflection": 0.005, "note": 'a "quoted" note'},
        meta={"seed": 3, "ok": True, "nested": {"x": [1.0, 2.0]}},
    )
    p = write_trial(tr, tmp_path / "out" / "x.toml", unit=unit)
    back = read_trial(p)
    np.testing.assert_array_equal(back.times, tr.times)  # %.17g round-trips float64 exactly
    if unit in ("m", "m/s", "m/s^2"):
        np.testing.assert_array_equal(back.values, tr.values)
    else:
        # value / factor * factor: two roundings of ~1.1e-16 each.
        np.testing.assert_allclose(back.values, tr.values, rtol=4e-16, atol=0)
    assert back.quantity == quantity and back.beam.quantity == quantity
    assert back.source["unit"] == unit
    assert back.sensor_position == tr.sensor_position
    assert back.t0 == tr.t0
    assert back.initial == tr.initial
    assert back.meta["nested"] == {"x": [1.0, 2.0]} and back.meta["seed"] == 3
    for f in ("length", "I", "rhoA", "E", "width", "thickness", "tip_mass"):
        assert getattr(back.beam, f) == getattr(tr.beam, f)
    assert back.name == "t1"


def test_round_trip_beam_with_segments_and_root_spring(tmp_path):
    beam = _beam(
        segments=(Segment(0.05, 0.15, I=0.6, rhoA=0.7),),
        root_spring=120.0,
        tip_mass=0.002,
        sensor_position=0.3,
    )
    tr = Trial(np.arange(5.0), np.zeros(5), "velocity", beam)
    back = read_trial(write_trial(tr, tmp_path / "s.toml"))
    assert back.beam == tr.beam


def test_derived_from_recorded(tmp_path):
    p = write_trial(_trial(), tmp_path / "a.toml")
    a = read_trial(p)
    b = read_trial(write_trial(a.window(0.1, 0.5), tmp_path / "b.toml"))
    d = b.meta["derived_from"]
    assert d["sha256"] == a.sha256 and d["file"] == a.source["file"]
    assert d["processing"][0].startswith("window")


# -- unit conversion ---------------------------------------------------------------------
def test_mm_to_m(tmp_path):
    tr = read_trial(_write_files(tmp_path, GOOD_CSV, unit="mm"))
    np.testing.assert_array_equal(tr.values, np.array([1.0, 2.0, -3.5]) * 1e-3)
    np.testing.assert_array_equal(tr.times, [0.0, 0.1, 0.25])


def test_g_to_si(tmp_path):
    tr = read_trial(_write_files(tmp_path, GOOD_CSV, unit="g", quantity="acceleration"))
    # Standard gravity is defined as 9.80665 m/s^2 exactly (3rd CGPM, 1901).
    np.testing.assert_array_equal(tr.values, np.array([1.0, 2.0, -3.5]) * 9.80665)
    assert STANDARD_GRAVITY == 9.80665


def test_sha256_and_source(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV)
    tr = read_trial(p)
    assert tr.sha256 == hashlib.sha256((tmp_path / "d.csv").read_bytes()).hexdigest()
    assert Path(tr.source["file"]) == (tmp_path / "d.csv").resolve()
    assert tr.name == "trial"  # the TOML's stem when no name is given


def test_in_memory_sha256_is_content_hash():
    tr = _trial(n=10)
    h = hashlib.sha256(tr.times.astype("<f8").tobytes() + tr.values.astype("<f8").tobytes())
    assert tr.sha256 == h.hexdigest()


# -- errors ------------------------------------------------------------------------------
def test_missing_trial_file(tmp_path):
    with pytest.raises(TrialError, match="trial file .* not found"):
        read_trial(tmp_path / "nope.toml")


def test_invalid_toml(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[signal\nfile = 1")
    with pytest.raises(TrialError, match="not valid TOML"):
        read_trial(p)


def test_missing_csv(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV, file="missing.csv")
    with pytest.raises(TrialError, match="missing.csv not found.*relative to the TOML"):
        read_trial(p)


def test_missing_column_lists_available(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV, value_column="disp")
    with pytest.raises(TrialError, match=r"'disp' is not a column.*\['time', 'w', 'other'\]"):
        read_trial(p)


def test_unknown_unit_lists_allowed(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV, unit="cm")
    with pytest.raises(TrialError, match=r"unknown unit 'cm'.*m, mm \(displacement\).*9\.80665"):
        read_trial(p)


def test_unit_quantity_mismatch(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV, unit="g")
    with pytest.raises(TrialError, match=r"'g' measures acceleration.*\['m', 'mm'\]"):
        read_trial(p)


def test_nan_in_data(tmp_path):
    p = _write_files(tmp_path, "time,w\n0,1\n1,nan\n2,3\n")
    with pytest.raises(TrialError, match=r"NaN/inf value\(s\) at sample index 1"):
        read_trial(p)


def test_empty_cell(tmp_path):
    p = _write_files(tmp_path, "time,w\n0,1\n1,\n2,3\n")
    with pytest.raises(TrialError, match="could not read numbers"):
        read_trial(p)


def test_non_increasing_time(tmp_path):
    p = _write_files(tmp_path, "time,w\n0,1\n1,2\n1,3\n0.5,1\n")
    with pytest.raises(TrialError, match="strictly increasing.*sample 2.*Sort the samples"):
        read_trial(p)


def test_sensor_beyond_beam(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV, sensor_position=0.5)
    with pytest.raises(TrialError, match="sensor_position 0.5 m lies beyond the free end"):
        read_trial(p)


def test_missing_and_unknown_signal_keys(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV)
    text = p.read_text().replace('unit = "m"\n', "")
    p.write_text(text)
    with pytest.raises(TrialError, match=r"\[signal\] is missing \['unit'\]"):
        read_trial(p)
    p = _write_files(tmp_path, GOOD_CSV, units="m")
    with pytest.raises(TrialError, match=r"unknown \[signal\] keys \['units'\]"):
        read_trial(p)


def test_bad_beam_is_reported(tmp_path):
    p = _write_files(tmp_path, GOOD_CSV)
    p.write_text(p.read_text().replace("mass = 0.021", "mass = -1.0"))
    with pytest.raises(TrialError, match=r"\[beam\]: mass must be a finite positive"):
        read_trial(p)


def test_empty_csv(tmp_path):
    with pytest.raises(TrialError, match="no data rows"):
        read_trial(_write_files(tmp_path, "time,w\n"))


def test_unknown_initial_key(tmp_path):
    with pytest.raises(TrialError, match=r"unknown \[initial\] keys \['tip_deflexion'\]"):
        _trial(initial={"tip_deflexion": 0.01})


def test_trial_validation():
    b = _beam()
    with pytest.raises(TrialError, match="same length"):
        Trial(np.arange(3.0), np.zeros(4), "displacement", b)
    with pytest.raises(TrialError, match="t0 = 1.0 s lies after the first sample"):
        Trial(np.arange(3.0), np.zeros(3), "displacement", b, t0=1.0)
    with pytest.raises(TrialError, match="quantity must be one of"):
        Trial(np.arange(3.0), np.zeros(3), "strain", b)
    tr = Trial(np.arange(3.0), np.zeros(3), "acceleration", b)
    assert tr.beam.quantity == "acceleration"  # the signal's quantity is authoritative
    assert not tr.times.flags.writeable


def test_write_errors(tmp_path):
    with pytest.raises(TrialError, match="must end in .toml"):
        write_trial(_trial(), tmp_path / "x.csv")
    with pytest.raises(TrialError, match="'g' measures acceleration"):
        write_trial(_trial(), tmp_path / "x.toml", unit="g")


# -- TOML writer -------------------------------------------------------------------------
def test_toml_writer_escapes_round_trip():
    doc = {
        "s": 'quote " backslash \\ newline \n tab \t del \x7f bell \x07 unicode µ→',
        "odd key.with dots": 1,
        "f": [1e-300, -0.0, 1.5e20, float("inf")],
        "b": False,
        "t": {"inner": {"x": "y"}, "arr": [[1, 2], ["a"]]},
        "segs": [{"start": 0.1, "end": 0.2}, {"start": 0.3, "end": 0.4}],
    }
    assert tomllib.loads(_toml_dumps(doc)) == doc


# -- derived trials ----------------------------------------------------------------------
def test_uniform_detection_and_dt():
    assert _trial().is_uniform
    assert _trial().dt == pytest.approx(0.004, rel=1e-12)
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.003, 0.005, size=100))
    assert not _trial(times=t).is_uniform


def test_window_keeps_t0():
    tr = _trial()
    w = tr.window(0.1, 0.3)
    assert w.times[0] >= 0.1 and w.times[-1] <= 0.3
    np.testing.assert_array_equal(w.times, tr.times[(tr.times >= 0.1) & (tr.times <= 0.3)])
    assert w.t0 == tr.t0 == 0.0
    assert w.source["processing"] == ["window [0.1, 0.3] s"]
    with pytest.raises(TrialError, match=r"holds 0 sample\(s\)"):
        tr.window(5.0, 6.0)
    with pytest.raises(TrialError, match="must come before"):
        tr.window(0.3, 0.1)


def _fir_gain(q, freqs, fs):
    """|H| and l1 norm of the decimation filter (anti_alias_taps), from its taps."""
    b = anti_alias_taps(q)
    _, h = scipy.signal.freqz(b, worN=2 * np.pi * np.asarray(freqs) / fs)
    return np.abs(h), np.sum(np.abs(b))


def test_anti_alias_filter_meets_its_specification():
    # Kaiser's design rule: pass-band ripple and stop-band gain both 1e-5 (100 dB), pass
    # band to 1/2.56 of the new rate, stop band from its Nyquist frequency.
    for q in (2, 5, 8):
        fs = 1.0
        f = np.linspace(0, fs / 2, 20001)
        gain, _ = _fir_gain(q, f, fs)
        passband = f <= fs / q / 2.56
        stopband = f >= fs / q / 2
        assert np.max(np.abs(gain[passband] - 1)) < 2e-5
        assert np.max(gain[stopband]) < 2e-5
        assert anti_alias_taps(q).size % 2 == 1


def _two_tone(t):
    # 20 Hz component to keep, 700 Hz component above the new Nyquist frequency (125 Hz at
    # q = 4, fs = 1 kHz) that would alias to 700 - 3*250 = -50 Hz without the filter.
    return np.sin(2 * np.pi * 20 * t + 0.3), 0.5 * np.sin(2 * np.pi * 700 * t)


def test_decimate_removes_alias_and_keeps_passband():
    t = np.arange(4000) / 1000.0
    keep, alias = _two_tone(t)
    tr = Trial(t, keep + alias, "velocity", _beam())
    d = tr.decimate(4)
    assert d.is_uniform and d.dt == pytest.approx(0.004, rel=1e-9)
    half = anti_alias_taps(4).size // 2  # outputs whose support reaches t < 0 dropped
    assert d.t0 == 0.0 and d.times[0] == pytest.approx(np.ceil(half / 4) * 0.004)
    assert set(d.times).issubset(set(t))
    # Bound from the filter's own response: passband gain error at 20 Hz plus the 700 Hz
    # amplitude times its stopband gain (zero-phase: no delay to account for).
    (g20, g700), _ = _fir_gain(4, [20.0, 700.0], 1000.0)
    ref, _ = _two_tone(d.times)
    err = np.max(np.abs(d.values - ref))
    assert err <= abs(g20 - 1) + 0.5 * g700 + 1e-12
    assert d.source["processing"][-1].startswith("decimate 4")


def test_decimate_rejects_nonuniform_and_bad_factor():
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, size=3000))
    tr = Trial(t, np.sin(t), "velocity", _beam())
    with pytest.raises(TrialError, match="uniformly sampled.*Trial.resample"):
        tr.decimate(4)
    with pytest.raises(TrialError, match="integer >= 1"):
        _trial().decimate(2.5)
    assert _trial().decimate(1).times.size == 200


def test_resample_nonuniform():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, size=5000))
    f_keep, f_alias, a_alias = 5.0, 80.0, 0.5
    tr = Trial(
        t,
        np.sin(2 * np.pi * f_keep * t + 0.3) + a_alias * np.sin(2 * np.pi * f_alias * t),
        "acceleration",
        _beam(),
    )
    u = tr.resample(0.01)  # q = 10 from the 1 ms median step; new Nyquist 50 Hz
    assert u.is_uniform and u.dt == pytest.approx(0.01, rel=1e-9)
    assert u.t0 == tr.t0 and u.times[0] >= t[0]
    assert "FIR decimation by 10" in u.source["processing"][-1]
    ref = np.sin(2 * np.pi * f_keep * u.times + 0.3)
    # Bound: filter gain error at 5 Hz + stopband gain at 80 Hz (80 Hz would alias to 20 Hz)
    # + the linear-interpolation error of each tone, (2 pi f h)^2 / 8 of its amplitude with
    # h <= 1.2 ms, passed through a filter of l1 norm sum|b|.
    (g_keep, g_alias), l1 = _fir_gain(10, [f_keep, f_alias], 1.0 / 1e-3)
    interp = sum(
        a * (2 * np.pi * f * 1.2e-3) ** 2 / 8 for a, f in ((1, f_keep), (a_alias, f_alias))
    )
    bound = abs(g_keep - 1) + a_alias * g_alias + l1 * interp
    err = np.max(np.abs(u.values - ref))
    assert err <= bound
    assert err < 1e-2  # and small in absolute terms (bound is ~0.03)
    with pytest.raises(TrialError, match="finer than the native"):
        tr.resample(1e-4)


def test_readme_example_is_a_valid_trial(tmp_path, repo_root):
    """The example in data/README.md reads as documented."""
    text = (repo_root / "data" / "README.md").read_text(encoding="utf-8")
    blocks = text.split("```")
    toml_text = next(b for b in blocks if b.startswith("toml\n"))[len("toml\n") :]
    csv_text = next(b for b in blocks if b.startswith("text\ntime_s"))[len("text\n") :]
    (tmp_path / "beam1-trial1.toml").write_text(toml_text)
    (tmp_path / "beam1-trial1.csv").write_text(csv_text)
    tr = read_trial(tmp_path / "beam1-trial1.toml")
    assert len(tr) == 4 and tr.values[0] == 5e-3
    assert tr.beam.beam_mass == pytest.approx(0.021, rel=1e-12)
    assert tr.beam.root_spring == 150.0 and len(tr.beam.segments) == 1
    assert tr.initial["tip_deflection"] == 0.005


# -- sensor band -----------------------------------------------------------------------
def test_default_sensor_band_is_rate_over_2_56():
    tr = _trial()  # 250 Hz sampling
    assert tr.bandwidth is None
    assert tr.sensor_band == pytest.approx(250.0 / 2.56, rel=1e-12)


@pytest.mark.parametrize("band", [40.0, float("inf")])
def test_bandwidth_round_trips(tmp_path, band):
    tr = _trial(bandwidth=band)
    back = read_trial(write_trial(tr, tmp_path / "t.toml"))
    assert back.bandwidth == band
    assert back.sensor_band == band


def test_bandwidth_read_from_signal_table(tmp_path):
    p = _write_files(tmp_path, "time,w\n0,0\n0.01,1\n0.02,0\n", bandwidth=12.5)
    assert read_trial(p).sensor_band == 12.5


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "wide", True])
def test_bad_bandwidth(bad):
    with pytest.raises(TrialError, match="bandwidth"):
        _trial(bandwidth=bad)


def test_decimation_narrows_the_band():
    tr = _trial(n=400, bandwidth=100.0)
    assert tr.decimate(4).sensor_band == pytest.approx(250.0 / 4 / 2.56, rel=1e-9)
    narrow = _trial(n=400, bandwidth=10.0)
    assert narrow.decimate(2).sensor_band == 10.0  # already narrower than the new rate's
