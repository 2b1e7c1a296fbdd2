"""Sanity checks of a record before sampling (bayesbeam.trials.checks)."""

import dataclasses
import glob
import math

import numpy as np
import pytest

from bayesbeam.physics.beam import Beam
from bayesbeam.trials.checks import (
    FALSE_ALARM,
    check_trial,
    line_threshold,
    record_checks,
    spectrum_checks,
)
from bayesbeam.trials.io import read_trial, write_trial
from bayesbeam.trials.modal_id import periodogram
from bayesbeam.trials.noise import PEAK_FACTOR
from bayesbeam.trials.preprocess import plan
from bayesbeam.trials.synthetic import simulate_trial
from bayesbeam.trials.trial import Trial

E = 62e9


def _beam(**kw):
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, **kw)


def _decay(**kw):
    """A 5 s release record of the carbon strip at 256 Hz, 1 % damping, light noise."""
    return simulate_trial(_beam(E=E), "viscous", {"E": E, "gamma": 0.1}, duration=5.0,
                          dt=1 / 256, noise_sd=1e-5, **kw)


def _checks(trial):
    return [f.check for f in check_trial(trial, plan(trial))]


def test_line_threshold_is_the_false_alarm_level_of_the_largest_of_n_bins():
    assert line_threshold(10) == PEAK_FACTOR
    n = 100_000
    assert line_threshold(n) == pytest.approx((math.log(n) - math.log(FALSE_ALARM))
                                              / math.log(2))
    assert line_threshold(n) > PEAK_FACTOR


def test_white_noise_rarely_passes_the_mode_line_threshold():
    # The derivation in the module docstring, on the plan's own search: largest padded
    # periodogram ordinate in (3/T, band) over the median within a factor 2 of it.
    rng = np.random.default_rng(2)
    t = np.arange(1280) / 256.0
    f, _ = periodogram(t, t)
    sel = (f > 3 / t[-1]) & (f < 100.0)
    limit = line_threshold(int(np.count_nonzero(sel)))
    over = 0
    for _ in range(1000):
        _, a = periodogram(t, rng.standard_normal(t.size))
        p = a**2
        i = int(np.argmax(np.where(sel, p, -np.inf)))
        local = (f > f[i] / 2) & (f < min(100.0, 2 * f[i]))
        over += p[i] / np.median(p[local]) > limit
    assert over <= 5  # 1 expected at FALSE_ALARM = 1e-3; 5 has probability 4e-3


def test_a_free_decay_passes_every_check():
    trial = _decay()
    assert check_trial(trial, plan(trial)) == []
    assert check_trial(dataclasses.replace(trial, beam=trial.beam.replace(E=None))) == []


def test_constant_record_is_refused_naming_file_and_column(tmp_path):
    trial = _decay()
    write_trial(dataclasses.replace(trial, values=np.zeros_like(trial.values)),
                tmp_path / "zero.toml", unit="mm")
    zero = read_trial(tmp_path / "zero.toml")
    (f,) = record_checks(zero)
    assert f.severity == "error" and f.check == "constant"
    assert "zero.csv" in f.message and "displacement_mm" in f.message
    assert "constant" in f.message and "value_column" in f.message
    # no spectral verdict on a record without a spectrum
    assert [x.check for x in check_trial(zero, None)] == ["constant"]


def test_white_noise_is_refused():
    trial = _decay()
    rng = np.random.default_rng(1)
    noise = dataclasses.replace(trial, values=rng.standard_normal(trial.values.size))
    findings = spectrum_checks(noise, plan(noise))
    assert [f.check for f in findings] == ["mode_line"]
    assert "no decaying oscillation" in findings[0].message and "x the local median" in \
        findings[0].message


def test_time_column_in_ms_is_refused():
    trial = _decay(bandwidth=100.0)
    ms = dataclasses.replace(trial, times=1e3 * trial.times, t0=1e3 * trial.t0)
    # with a declared band: the stamps' Nyquist frequency gives it away before any plan
    assert [f.check for f in record_checks(ms)] == ["band", "nominal_f1"]
    assert "in ms" in record_checks(ms)[0].message
    # no declared band, no nominal E: the modulus the record's mode 1 implies
    bare = dataclasses.replace(ms, bandwidth=None, beam=ms.beam.replace(E=None))
    assert record_checks(bare) == []
    (f,) = spectrum_checks(bare, plan(bare))
    assert f.check == "implied_E" and "below the softest" in f.message
    assert "time column is in seconds" in f.message


def test_nominal_frequency_outside_the_record_is_refused():
    trial = _decay()
    stiff = dataclasses.replace(trial, beam=trial.beam.replace(E=1e16))
    (f,) = record_checks(stiff)
    assert f.check == "nominal_f1" and "above the record's band" in f.message
    soft = dataclasses.replace(trial, beam=trial.beam.replace(E=1e5))
    (g,) = record_checks(soft)
    assert g.check == "nominal_f1" and "periods" in g.message


def test_implausible_beam_is_part_of_check_trial():
    trial = _decay()
    heavy = dataclasses.replace(trial, beam=_beam(E=None).replace(
        rhoA=1000 * trial.beam.rhoA))
    assert "density" in [f.check for f in check_trial(heavy)]


def test_shipped_trials_pass(repo_root):
    files = sorted(glob.glob(str(repo_root / "data" / "beam*.toml")))
    assert files
    for path in files:
        assert _checks(read_trial(path)) == [], path


@pytest.mark.slow
def test_public_real_records_pass(real_data_root):
    from bayesbeam.trials.realdata import list_real_datasets

    for rec in list_real_datasets(real_data_root):
        assert _checks(rec.load(real_data_root)) == [], rec.name


def test_trial_without_file_is_named():
    t = np.arange(300) / 256.0
    trial = Trial(times=t, values=np.ones_like(t), quantity="displacement", beam=_beam(),
                  name="bench")
    (f,) = record_checks(trial)
    assert "trial 'bench'" in f.message
