"""Real data loaders against the values documented in each data set's PROVENANCE.md.

The data live in ../shared/data/real beside the repository (not shipped); the
``real_data_root`` fixture (conftest.py) skips these tests when they are absent.
"""

import hashlib
from pathlib import Path

import numpy as np
import pytest

from bayesbeam.trials.io import read_trial, write_trial
from bayesbeam.trials.realdata import (
    RealDataError,
    list_real_datasets,
    load_enes,
    load_hrshm,
    record_at,
    resolve_root,
)
from bayesbeam.trials.trial import STANDARD_GRAVITY, TrialError


def _spectral_peak(trial, fmin, fmax):
    """Frequency (Hz) of the largest FFT peak in (fmin, fmax), Hann window, 16x zero pad."""
    u = trial if trial.is_uniform else trial.resample(1e-3)
    y = u.values - u.values.mean()
    n = y.size
    spec = np.abs(np.fft.rfft(y * np.hanning(n), 16 * n))
    f = np.fft.rfftfreq(16 * n, u.dt)
    band = (f > fmin) & (f < fmax)
    return f[band][np.argmax(spec[band])]


@pytest.fixture(scope="module")
def hrshm(real_data_root):
    return load_hrshm(root=real_data_root)


def test_listing(real_data_root):
    recs = list_real_datasets(real_data_root)
    enes = [r for r in recs if r.dataset == "enes-alu-release"]
    # PROVENANCE.md lists 2 + 2 + 2 + 4 copied recordings and one .lvm file.
    counts = {L: sum(r.kwargs["length_cm"] == L for r in enes) for L in (30, 40, 50, 60)}
    assert counts == {30: 2, 40: 2, 50: 2, 60: 4}
    assert [r.dataset for r in recs].count("hrshm-steel-impulse") == 1
    assert all(r.path.is_file() for r in recs)
    assert recs[0].load(real_data_root, duration=1.0).name == "enes-alu-30cm-0"
    assert recs[0].label == "alu30-0" and recs[-1].label == "steel"


def test_root_resolves_from_repo_root_and_elsewhere(
    real_data_root, repo_root, monkeypatch, tmp_path
):
    monkeypatch.chdir(repo_root)
    assert resolve_root() == real_data_root.resolve()
    monkeypatch.chdir(tmp_path)  # not beside the data: falls back to the repo root
    assert resolve_root() == real_data_root.resolve()
    with pytest.raises(RealDataError, match="not found.*not shipped"):
        resolve_root(tmp_path / "nowhere")


def test_enes_40cm(real_data_root):
    tr = load_enes(40, 0, root=real_data_root)
    n = len(tr)
    assert tr.times.shape == tr.values.shape == (n,)
    assert not tr.is_uniform  # software time stamps (PROVENANCE: median 1/3995 s, gaps)
    assert tr.quantity == "acceleration" and tr.source["unit"] == "g"
    assert tr.duration == pytest.approx(5.0, abs=0.01)  # 5 s window, ~0.25 ms steps
    assert tr.t0 == tr.times[0]
    # Start after the release peak + 0.1 s (PROVENANCE: release within the first 0.8 s).
    assert tr.times[0] > tr.meta["release_peak_time_s"] + 0.1
    assert tr.meta["release_peak_time_s"] < 0.8
    # SI magnitude: PROVENANCE max |a| 3.60 g for this record (baseline shifts it < 0.06 g).
    peak = np.max(np.abs(tr.values))
    assert 1.0 * STANDARD_GRAVITY < peak < 3.7 * STANDARD_GRAVITY < 10 * 9.81
    # Checksum documented in PROVENANCE.md (first 16 hex digits).
    assert tr.sha256.startswith("f54e7e1b9a8ad4b9")
    assert tr.meta["sha256_matches_provenance"]
    # Beam from PROVENANCE: 0.4 m, 50.8 x 2 mm, 2700 kg/m^3, sensor 6 cm from the tip.
    b = tr.beam
    assert b.length == 0.4 and b.sensor_position == pytest.approx(0.34)
    assert b.beam_mass == pytest.approx(2700 * 0.4 * 0.0508 * 0.002, rel=1e-12)
    assert b.tip_mass == 0.0 and tr.meta["documented_tip_mass_kg"] == 0.01


def test_enes_values_are_raw_minus_baseline_in_si(real_data_root):
    tr = load_enes(50, 1, root=real_data_root, duration=1.0)
    raw_t, raw_a = np.load(tr.source["file"])
    base = raw_a[raw_t >= raw_t[-1] - 2.0].mean()
    i = np.searchsorted(raw_t, tr.times)
    np.testing.assert_array_equal(raw_t[i], tr.times)
    np.testing.assert_allclose(tr.values, (raw_a[i] - base) * 9.80665, rtol=0, atol=1e-12)
    assert hashlib.sha256(Path(tr.source["file"]).read_bytes()).hexdigest() == tr.sha256


# PROVENANCE.md, own FFT: 16.3 / 9.4 / 6.1 / 4.3 Hz (points_data.xlsx: 16.49 / 9.383 /
# 6.02 / 4.25). Tolerance 0.2 Hz: values given to 0.1 Hz, a 10 s window resolves 0.1 Hz,
# and the frequency drifts slightly with amplitude.
@pytest.mark.parametrize("length_cm,f1", [(30, 16.3), (40, 9.4), (50, 6.1), (60, 4.3)])
def test_enes_first_frequency(real_data_root, length_cm, f1):
    tr = load_enes(length_cm, 0, root=real_data_root, duration=10.0)
    assert _spectral_peak(tr, 2.0, 30.0) == pytest.approx(f1, abs=0.2)


def test_enes_errors(real_data_root):
    with pytest.raises(RealDataError, match=r"available lengths \(cm\): \[30, 40, 50, 60\]"):
        load_enes(45, root=real_data_root)
    with pytest.raises(RealDataError, match="index 2 out of range: 2 record"):
        load_enes(40, 2, root=real_data_root)
    with pytest.raises(RealDataError, match="runs past the end of the record"):
        load_enes(40, root=real_data_root, duration=30.0)


def test_hrshm(hrshm):
    tr = hrshm
    assert tr.is_uniform
    # fs = 51200/31 Hz (PROVENANCE); fitted from stamps rounded to 1 us over 81920 samples,
    # so the step is known to ~1e-11 relative.
    assert tr.dt == pytest.approx(31 / 51200, rel=1e-9)
    assert tr.sha256 == "06912a5bdee18349fee5aeb3e373ac8b70e5cc98ff8df2c37b9b85ea5a305088"
    assert tr.meta["sha256_matches_provenance"]
    # Impact onset 1.102 s, peak |a| 1.45 g (PROVENANCE); window starts 0.1 s after the peak.
    assert 1.10 < tr.meta["impact_peak_time_s"] < 1.11
    assert tr.times[0] > tr.meta["impact_peak_time_s"] + 0.1
    assert np.max(np.abs(tr.values)) < 1.46 * STANDARD_GRAVITY
    assert tr.duration == pytest.approx(10.0, abs=1e-3)
    assert tr.beam.length == 0.759 and tr.beam.E == 200e9


def test_hrshm_modes(hrshm):
    # README of the source: 6.62, 41.4, 117.5 Hz. Tolerances: 10 s window resolves 0.1 Hz.
    assert _spectral_peak(hrshm, 2.0, 20.0) == pytest.approx(6.62, abs=0.1)
    assert _spectral_peak(hrshm, 20.0, 80.0) == pytest.approx(41.4, abs=0.2)
    d = hrshm.decimate(4)  # uniform: decimation allowed (new Nyquist 206 Hz)
    assert _spectral_peak(d, 2.0, 20.0) == pytest.approx(6.62, abs=0.1)


def test_real_trial_write_read(hrshm, tmp_path):
    tr = hrshm.window(hrshm.times[0], hrshm.times[0] + 0.5)
    back = read_trial(write_trial(tr, tmp_path / "h.toml", unit="g"))
    np.testing.assert_allclose(back.values, tr.values, rtol=4e-16, atol=0)
    assert back.meta["derived_from"]["sha256"] == hrshm.sha256
    assert back.meta["licence"].startswith("CC BY-SA 4.0")


def test_record_files_are_read_where_they_lie(real_data_root, tmp_path):
    # read_trial takes a record file (or an enes record's folder) in its data set's
    # layout as the loader's raw trial, the same one a written trial file gives back.
    recs = list_real_datasets(real_data_root)
    enes = next(r for r in recs if r.kwargs.get("length_cm") == 40 and r.kwargs["index"] == 1)
    steel = next(r for r in recs if r.dataset == "hrshm-steel-impulse")
    for rec, given in ((enes, enes.path), (enes, enes.path.parent), (steel, steel.path)):
        found, root = record_at(given)
        assert found == rec and root == real_data_root.resolve()
        raw = rec.load(real_data_root, raw=True)
        got = read_trial(given)
        assert got.name == raw.name and got.meta["raw"] and got.beam == raw.beam
        np.testing.assert_array_equal(got.values, raw.values)
        np.testing.assert_array_equal(got.times, raw.times)
        back = read_trial(write_trial(raw, tmp_path / f"{raw.name}.toml", unit="g"))
        np.testing.assert_array_equal(got.values, back.values)
        assert got.sensor_position == back.sensor_position
    # Recognised by place, not by format: a copy elsewhere has no beam to go with it.
    copy = tmp_path / "accelerometer_data.npy"
    copy.write_bytes(enes.path.read_bytes())
    assert record_at(copy) is None and record_at(tmp_path) is None
    with pytest.raises(TrialError, match="is a data file, not a trial file.*trial file "
                                         r"\(TOML\).*accelerometer_data.npy"):
        read_trial(copy)
    # A file in the layout but not of the data set: the loader's message, as a TrialError.
    fake = tmp_path / "hrshm-steel-impulse" / "timeseries_data.lvm"
    fake.parent.mkdir()
    fake.write_text("time,value\n0,1\n")
    assert record_at(fake) is not None
    with pytest.raises(TrialError, match="End_of_Header"):
        read_trial(fake)
