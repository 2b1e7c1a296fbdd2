"""Automatic analysis choices on raw records (bayesbeam.trials.preprocess).

The synthetic raw record is made the way a measured one comes off an acquisition and
not by the model that is later fitted: a fine-mesh simulation of every mode through a
FIR anti-alias filter (``simulate_sensor``, 64 elements), on jittered stamps with gaps,
after a quiet pre-release stretch, with a constant offset and white noise.
"""

import dataclasses

import numpy as np
import pytest
import scipy.linalg as sla

from bayesbeam.inference.fit import fit
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.fem import assemble
from bayesbeam.trials.io import read_trial, write_trial
from bayesbeam.trials.modal_id import periodogram
from bayesbeam.trials.preprocess import (
    MAX_GAP_STEPS,
    MAX_SAMPLES,
    RATE_PER_BAND,
    SETTLE_S,
    PreprocessError,
    _ratios,
    apply,
    nominal_f1,
    plan,
    prepare,
)
from bayesbeam.trials.synthetic import simulate_sensor
from bayesbeam.trials.trial import Trial, TrialError, anti_alias_taps

# gamma = 0.1 kg/(m s): zeta1 = gamma / (2 rhoA omega1) = 1.0 % (physics.md §2).
E_TRUE, GAMMA_TRUE, OFFSET, NOISE, T_RELEASE = 6.2e10, 0.1, 0.4, 0.05, 0.3


def _beam() -> Beam:
    # The source study's single-ply beam (physics.md §4), sensor at the tip.
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E_TRUE,
                            sensor_position=0.3048, quantity="acceleration")


def _fine_frequencies(beam: Beam, k: int) -> np.ndarray:
    fe = assemble(beam, 64, root_dof=False)
    lam = sla.eigh(fe.K, fe.M, eigvals_only=True, subset_by_index=[0, k - 1])
    return np.sqrt(lam * E_TRUE) / (2 * np.pi)


@pytest.fixture(scope="module")
def raw_record() -> tuple[Trial, dict]:
    rng = np.random.default_rng(7)
    beam = _beam()
    # ~2 kHz software stamps like the aluminium records' (90 % of their steps within
    # 1 % of the median): steps 0.5 ms +- 1 %, and four gaps of 4-8 ms. (Their 2 % of
    # steps 1.5-2 x longer are left out: across such a step no interpolation can
    # recover content near the native Nyquist frequency, which this beam's tip
    # acceleration holds in strength and the aluminium records hardly at all.)
    steps = 5e-4 * (1 + 0.01 * rng.uniform(-1, 1, 9000))
    for i in (2500, 4000, 5200, 7100):
        steps[i] = rng.uniform(4e-3, 8e-3)
    t = np.cumsum(steps)
    t = t[t < 4.3]
    quiet = t < T_RELEASE
    # The filter must settle after the release (simulate_sensor says how long): the
    # sensor records nothing useful in the first 40 ms; leave them out.
    moving = t >= T_RELEASE + 0.04
    keep = quiet | moving
    t = t[keep]
    y = np.zeros(t.size)
    y[t > T_RELEASE] = simulate_sensor(
        beam, "viscous", {"E": E_TRUE, "gamma": GAMMA_TRUE, "w0": 5e-3}, t[t > T_RELEASE],
        t0=T_RELEASE, bandwidth=250.0,
    )
    y = y + OFFSET + NOISE * rng.standard_normal(t.size)
    trial = Trial(times=t, values=y, quantity="acceleration", beam=beam, name="raw",
                  bandwidth=250.0)
    big = np.flatnonzero(np.diff(t) > 3e-3)
    return trial, {"gaps": list(zip(t[big], t[big + 1], strict=True))}


def test_raw_record_choices(raw_record):
    trial, truth = raw_record
    pre = plan(trial, max_samples=2000)
    f = _fine_frequencies(trial.beam, 4)
    # The release: the largest |a| comes within the first period of mode 1 (88 ms).
    assert T_RELEASE < pre.release <= T_RELEASE + 1.0 / f[0]
    assert pre.start == pytest.approx(pre.release + SETTLE_S)
    assert pre.end == trial.times[-1]  # still moving at the end (zeta1 ~ 1 %)
    assert pre.f1 == pytest.approx(f[0], rel=0.02)  # a 4 s record: 0.25 Hz bins, padded
    assert pre.modes_seen[1] == pytest.approx(f[1], rel=0.01)
    # Budget 2000 samples over ~3.9 s at 4 samples per band Hz: band cap 128 Hz, so mode 3
    # (202 Hz) is left out and the band is 1.25 f2.
    assert pre.band == pytest.approx(1.25 * pre.modes_seen[1])
    assert pre.rate == pytest.approx(RATE_PER_BAND * pre.band)
    assert all(fd > pre.band for fd in pre.modes_dropped)
    assert pre.initial == "modes:2"  # model modes below the band
    assert pre.offset == "fit" and pre.model_name("viscous") == "viscous+sensor_offset"
    assert pre.model_name("viscous+sensor_offset") == "viscous+sensor_offset"
    out = apply(trial, pre)
    assert out.t0 == out.times[0] >= pre.start
    assert out.sensor_band == pytest.approx(pre.band)
    # Uniform grid with holes: every output at least one filter reach from a gap.
    dt = 1.0 / pre.rate
    k = (out.times - out.times[0]) / dt
    assert np.allclose(k, np.round(k), atol=1e-6)
    med = float(np.median(np.diff(trial.window(pre.start, pre.end).times)))
    assert MAX_GAP_STEPS * med < 3e-3  # the four gaps count as gaps
    q = int(np.ceil(0.99 * dt / med))
    edge = pre.band * dt  # the filter's pass band, as a fraction of the new rate
    reach = dt / q * (anti_alias_taps(q, edge).size // 2) + 10 * med  # FIR + spline
    for a, b in truth["gaps"]:
        if a > pre.start:
            assert not np.any((out.times > a - 0.999 * reach) & (out.times < b + 0.999 * reach))
    assert out.times.size < np.floor((pre.end - pre.start) * pre.rate)  # holes
    assert "dropped" in out.source["processing"][-2]
    # The modes seen on the raw stamps travel with the record (for the diagnosis).
    assert out.meta["modes_seen_hz"]["2"] == pytest.approx(f[1], rel=0.01)
    assert pre.mode_numbers[:2] == (1, 2)
    js = pre.to_json_dict()
    assert js["initial"] == "modes:2" and js["release"] == pre.release


def test_fit_on_prepared_raw_record_recovers_truth(raw_record):
    """The chain end to end: a fit on the prepared record finds E, gamma and the offset.

    Tolerances: 4 posterior sd plus the mesh bias of the fitted 16-element model against
    the 64-element data (E: 1e-4 relative at mode 1, physics.md §4).
    """
    trial, _ = raw_record
    out, pre = prepare(trial, max_samples=2000)
    res = fit(out, pre.model_name("viscous"), initial=pre.initial, seed=3, target_ess=200,
              progress=False)
    post = res.to_json_dict()["posterior"]
    assert res.chain.converged
    for name, truth, extra in (("E", E_TRUE, 1e-4 * E_TRUE), ("gamma", GAMMA_TRUE, 0.0),
                               ("offset", OFFSET, 0.0)):
        assert abs(post[name]["mean"] - truth) < 4 * post[name]["sd"] + extra, name
    # The anti-alias filter keeps the noise below the band only (white noise: sd scales
    # with sqrt(band / native Nyquist) ~ sqrt(90 / 1000) = 0.3; the filter's skirt adds).
    assert 0.2 * NOISE < post["sigma"]["mean"] < 0.6 * NOISE


def test_declared_trial_is_taken_as_given(raw_record):
    trial, _ = raw_record
    declared = dataclasses.replace(trial, initial={"tip_deflection": 5e-3})
    pre = plan(declared)
    assert (pre.start, pre.end, pre.rate) == (trial.times[0], trial.times[-1], None)
    assert (pre.initial, pre.offset, pre.release) == ("release", "none", None)
    assert apply(declared, pre) is not None


def test_choices_given_by_trial_file_and_options(raw_record, tmp_path):
    trial, _ = raw_record
    fixed = dataclasses.replace(trial, analysis={"start": 1.0, "offset": "none",
                                                 "initial": "modes:3"})
    path = write_trial(fixed, tmp_path / "fixed.toml")
    back = read_trial(path)
    assert back.analysis == fixed.analysis
    pre = plan(back, end=3.0)  # an option on top of the file's choices
    assert (pre.start, pre.end, pre.offset, pre.initial) == (1.0, 3.0, "none", "modes:3")
    assert set(pre.given) == {"start", "offset", "initial", "end"}
    off = plan(trial, auto=False)
    assert (off.start, off.rate, off.initial, off.offset) == (trial.times[0], None, "release",
                                                              "none")


@pytest.mark.parametrize(
    ("analysis", "given", "error", "match"),
    [
        ({"begin": 1.0}, {}, TrialError, "unknown \\[analysis\\] keys \\['begin'\\]"),
        ({"start": "1 s"}, {}, TrialError, "start must be a int or float"),
        ({"auto": 1}, {}, TrialError, "auto must be a bool"),
        ({}, {"offset": "maybe"}, PreprocessError, "offset must be 'fit' or 'none'"),
        ({}, {"max_samples": 10}, PreprocessError, "max_samples must be an integer >= 256"),
        ({}, {"start": 100.0}, PreprocessError, "holds 0 samples"),
        ({}, {"rate": -1.0}, PreprocessError, "rate must be a positive"),
        ({}, {"speed": 1}, PreprocessError, "unknown preprocessing choices"),
    ],
)
def test_bad_choices_say_what_to_fix(raw_record, analysis, given, error, match):
    trial, _ = raw_record
    with pytest.raises(error, match=match):
        plan(dataclasses.replace(trial, analysis=analysis), **given)


def test_resample_drops_only_samples_near_gaps():
    rng = np.random.default_rng(1)
    steps = 1e-3 * (1 + 0.1 * rng.uniform(-1, 1, 4000))
    steps[2000] = 0.02
    t = np.cumsum(steps)
    y = np.sin(2 * np.pi * 5 * t)
    tr = Trial(times=t, values=y, quantity="displacement", beam=_beam())
    full = tr.resample(0.004)
    holed = tr.resample(0.004, max_gap=0.005)
    gap = (t[1999], t[2000])  # t = cumsum(steps): steps[2000] = t[2000] - t[1999]
    # FIR half length on the 1 ms grid plus 10 median steps of spline influence.
    reach = 0.004 / 4 * (anti_alias_taps(4).size // 2) + 10 * np.median(steps)
    near = (full.times > gap[0] - reach) & (full.times < gap[1] + reach)
    assert holed.times.size == full.times.size - np.count_nonzero(near)
    np.testing.assert_array_equal(holed.times, full.times[~near])
    np.testing.assert_array_equal(holed.values, full.values[~near])
    with pytest.raises(TrialError, match="max_gap must be a positive"):
        tr.resample(0.004, max_gap=0.0)


def _long_decay(duration: float = 120.0, fs: float = 1000.0, **trial_kw) -> Trial:
    """A record that is mostly noise: 10 s of decay of modes 1 and 2, then noise.

    The nominal beam's modes (f1 and the nominal ratio f2/f1), 1 % and 0.3 % damping,
    released at t = 0.5 s; offset 0.3, white noise 0.05 (SI, acceleration).
    """
    beam = _beam()
    probe = Trial(times=np.arange(4) / fs, values=np.zeros(4), quantity="acceleration",
                  beam=beam)
    f1 = nominal_f1(probe)
    f2 = f1 * float(_ratios(probe)[1])
    t = np.arange(round(duration * fs)) / fs
    tt = np.clip(t - 0.5, 0.0, None)
    y = (50 * np.exp(-0.01 * 2 * np.pi * f1 * tt) * np.cos(2 * np.pi * f1 * tt)
         + 20 * np.exp(-0.003 * 2 * np.pi * f2 * tt) * np.cos(2 * np.pi * f2 * tt))
    y = np.where(t < 0.5, 0.0, y) + 0.3 + 0.05 * np.random.default_rng(5).standard_normal(t.size)
    return Trial(times=t, values=y, quantity="acceleration", beam=beam, name="long", **trial_kw)


def test_modes_of_a_record_mostly_noise_are_sought_on_the_motion(monkeypatch):
    trial = _long_decay()
    f1 = nominal_f1(trial)
    f2 = f1 * float(_ratios(trial)[1])
    pre = plan(trial)
    assert pre.modes_seen == pytest.approx([f1, f2], rel=2e-3)
    assert pre.mode_strength[0] > 1e6 and pre.mode_strength[1] > 1e4
    assert pre.band > f2 and pre.n_samples <= MAX_SAMPLES
    # The Hann window over all 120 s (NOISE_TAIL = 0: never trimmed) weights the decay by
    # almost nothing: mode 1 stands ~100 x its floor, not 1e7 x (mode 2 is still found,
    # in the spectrum of the span's first sixteenth, _mode_peak).
    monkeypatch.setattr("bayesbeam.trials.preprocess.NOISE_TAIL", 0.0)
    old = plan(trial)
    assert old.mode_strength[0] < 1e3


def test_harmonics_of_mode_1_are_not_taken_for_mode_2():
    # Shaped like the 40 cm aluminium records: mode 1 decaying at 0.3/s with lines at
    # 6 f1 and 7 f1 that decay with it (a nonlinearity's harmonics, 2 % of mode 1),
    # and mode 2 at 6.58 f1 decaying at 7/s (gone after ~1 s). Over the whole record
    # the line at 7 f1 is the largest ordinate within ±20 % of f1 r2: taken for mode 2
    # before (66 Hz on Al 40 cm #1, where the fitted f2 is 61.9 Hz).
    fs = 1000.0
    trial0 = _long_decay(duration=1.0)
    f1 = nominal_f1(trial0)
    f2 = 6.58 * f1
    t = np.arange(round(20 * fs)) / fs
    rng = np.random.default_rng(11)
    y = 24 * np.exp(-0.3 * t) * np.cos(2 * np.pi * f1 * t)
    y += sum(0.5 * np.exp(-0.3 * t) * np.cos(2 * np.pi * n * f1 * t + n) for n in (6, 7))
    y += 5 * np.exp(-7 * t) * np.cos(2 * np.pi * f2 * t + 1.0)
    y += 0.05 * rng.standard_normal(t.size)
    trial = Trial(times=t, values=y, quantity="acceleration", beam=trial0.beam, name="harm")
    f, amp = periodogram(t, y)
    win = (f > 0.8 * f1 * _ratios(trial)[1]) & (f < 1.2 * f1 * _ratios(trial)[1])
    assert abs(f[win][np.argmax(amp[win])] - 7 * f1) < 0.01 * 7 * f1  # the trap is set
    pre = plan(trial, start=0.0)
    # Mode 2 within the resolution of the spectrum that shows it best (1/T with T >=
    # MODE_PERIODS periods: 2 %).
    assert pre.modes_seen[1] == pytest.approx(f2, rel=0.02)
    assert all(abs(fm / f1 - round(fm / f1)) > 0.01 * round(fm / f1)
               for fm in pre.modes_seen[1:])
    # The lines are reported as what they are, and nothing else is.
    assert [n for n, _, _ in pre.harmonics] == [6, 7]
    assert [fh for _, fh, _ in pre.harmonics] == pytest.approx([6 * f1, 7 * f1], rel=1e-3)
    assert any("6 f1" in ln and "7 f1" in ln for ln in pre.lines())


def test_band_holds_the_nominal_mode_2_when_only_mode_1_is_seen():
    # Mode 1 alone: the band is 1.25 x the nominal f2, not 1.25 x f1 (a rate of 5 f1,
    # at which the anti-alias filter's reach around the stamps' gaps of a raw record
    # dropped three quarters of the samples).
    fs = 1000.0
    trial0 = _long_decay(duration=1.0)
    f1 = nominal_f1(trial0)
    t = np.arange(round(20 * fs)) / fs
    y = 24 * np.exp(-0.3 * t) * np.cos(2 * np.pi * f1 * t)
    y += 0.05 * np.random.default_rng(12).standard_normal(t.size)
    trial = Trial(times=t, values=y, quantity="acceleration", beam=trial0.beam, name="one")
    pre = plan(trial, start=0.0)
    assert len(pre.modes_seen) == 1
    f2 = f1 * float(_ratios(trial)[1])
    assert pre.band == pytest.approx(1.25 * f2, rel=1e-3)
    assert pre.initial == "modes:2"


def test_record_taken_as_given_beyond_the_budget_is_refused():
    trial = _long_decay(duration=20.0, initial={"tip_deflection": 5e-3})
    n = trial.times.size
    with pytest.raises(PreprocessError, match=(
            rf"'long': the analysis would hold {n:,} samples \(the record's own stamps over "
            r"20 s, a trial with a declared initial state taken as given\), more than the "
            r"budget of 16,384; .*--rate 819 or lower, --decimate 2 or more .*--window T0 "
            rf"T1.*--max-samples {n}")):
        prepare(trial)
    with pytest.raises(PreprocessError, match="automatic choices off"):
        prepare(dataclasses.replace(trial, initial={}), auto=False)
    with pytest.raises(PreprocessError, match=r"the given rate 1000 Hz over 20 s"):
        prepare(trial, rate=1000.0)
    # The fixes it names: a budget that holds the record, a lower rate.
    out, pre = prepare(trial, max_samples=n)
    assert out.times.size == n and pre.rate is None
    out, _ = prepare(trial, rate=819.0)
    assert out.times.size <= MAX_SAMPLES
    # The plan itself does not refuse (bayesbeam inspect works on any raw stamps).
    assert plan(trial).n_samples == n
