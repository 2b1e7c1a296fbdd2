"""Tests of bayesbeam.trials.synthetic: synthetic trials, their files and their noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import ForwardError
from bayesbeam.trials.io import read_trial
from bayesbeam.trials.synthetic import (
    MAX_SIMULATED_SAMPLES,
    simulate_signal,
    simulate_trial,
)

L = 0.3048
E = 6.2e10
BEAM = Beam.rectangular(L, 0.127, 0.72e-3, 0.021, E=E)
W1 = 1.875104069**2 * math.sqrt(E * BEAM.I / (BEAM.rhoA * L**4))  # physics.md §4
GAMMA = 2 * BEAM.rhoA * W1 * 0.01  # ζ1 = 1 % (physics.md §2)
DT = 0.003906


def test_trial_round_trip_through_files(tmp_path):
    out = tmp_path / "syn" / "trial.toml"
    trial = simulate_trial(
        BEAM,
        "viscous",
        {"gamma": GAMMA},
        duration=0.5,
        dt=DT,
        tip_deflection=4e-3,
        noise_sd=1e-5,
        seed=3,
        out=out,
    )
    assert out.is_file() and out.with_suffix(".csv").is_file()
    back = read_trial(out)
    n = int(round(0.5 / DT))
    assert trial.times.size == n == back.times.size
    assert np.array_equal(back.times, np.arange(n) * DT)
    # 17 significant digits in the CSV: SI values come back bit for bit (trial.write_trial).
    assert np.array_equal(back.values, trial.values)
    assert back.quantity == "displacement"
    assert back.sensor_position == pytest.approx(L, rel=1e-15)
    assert back.t0 == 0.0
    assert back.initial["tip_deflection"] == 4e-3
    for name in ("length", "I", "rhoA", "E", "tip_mass"):
        assert getattr(back.beam, name) == pytest.approx(getattr(BEAM, name), rel=1e-15)
    # The generating model and its true parameters survive the file round trip.
    truth = back.meta["synthetic"]
    assert truth["model"] == "viscous"
    assert truth["params"] == {"gamma": GAMMA}
    assert truth["noise_sd"] == 1e-5 and truth["seed"] == 3 and truth["n_elements"] == 16


def test_signal_is_model_plus_seeded_noise():
    times = np.arange(128) * DT
    clean = simulate_signal(BEAM, "viscous", {"gamma": GAMMA, "w0": 5e-3}, times)
    full = simulate_signal(BEAM, "viscous", {"gamma": GAMMA, "w0": 5e-3}, times,
                           bandwidth=np.inf)
    assert full[0] == pytest.approx(5e-3, rel=1e-12)  # release from the static deflection
    # The default sensor band (256 Hz / 2.56 = 100 Hz) keeps modes 1 and 2 only: the
    # record starts at their share of the static deflection (97-99.9 % for a tip load).
    assert 0.97 * 5e-3 < clean[0] < 0.999 * 5e-3
    noisy = simulate_trial(
        BEAM,
        "viscous",
        {"gamma": GAMMA},
        duration=128 * DT,
        dt=DT,
        tip_deflection=5e-3,
        noise_sd=2e-5,
        seed=42,
    )
    expected = clean + 2e-5 * np.random.default_rng(42).standard_normal(128)
    assert np.max(np.abs(noisy.values - expected)) <= 1e-18  # same numbers up to rounding


def test_noise_seed_reproducible():
    kw = {"duration": 0.3, "dt": DT, "noise_sd": 1e-5}
    a = simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, seed=7, **kw)
    b = simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, seed=7, **kw)
    c = simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, seed=8, **kw)
    assert np.array_equal(a.values, b.values)
    assert not np.array_equal(a.values, c.values)
    # The noise has the requested size (76 samples: sd estimate within ~3 standard errors).
    resid = a.values - simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, duration=0.3, dt=DT).values
    assert np.std(resid) == pytest.approx(1e-5, rel=3 / math.sqrt(2 * resid.size))


def test_beam_from_toml_and_other_models(tmp_path):
    path = tmp_path / "beam.toml"
    path.write_text(
        "[beam]\nlength = 0.3048\nwidth = 0.127\nthickness = 0.72e-3\nmass = 0.021\n"
        "E = 6.2e10\nquantity = 'velocity'\n"
    )
    trial = simulate_trial(
        path, "viscous+sh", {"gamma": GAMMA, "a": 1.0, "b": 0.01}, duration=0.2, dt=DT, seed=None
    )
    assert trial.quantity == "velocity"
    # Released at rest: zero velocity, up to the velocity of the modes above the band
    # that SH damping couples to those in it (the ideal filter acts on the coupled
    # eigen-solutions, each of which has a velocity at t = 0).
    unfiltered = simulate_trial(path, "viscous+sh", {"gamma": GAMMA, "a": 1.0, "b": 0.01},
                                duration=0.2, dt=DT, seed=None, bandwidth=np.inf)
    assert unfiltered.values[0] == pytest.approx(0.0, abs=1e-12)
    assert "seed" not in trial.meta["synthetic"]


def test_missing_and_extra_parameters_raise():
    with pytest.raises(ForwardError, match=r"needs \['c_d'\]"):
        simulate_trial(BEAM, "viscous+kv", {"gamma": GAMMA}, duration=0.1)
    with pytest.raises(ForwardError, match=r"\['c_d'\] are not part of model 'viscous'"):
        simulate_trial(BEAM, "viscous", {"gamma": GAMMA, "c_d": 1.0}, duration=0.1)
    with pytest.raises(ForwardError, match=r"needs \['E'\]"):
        simulate_trial(BEAM.replace(E=None), "viscous", {"gamma": GAMMA}, duration=0.1)
    with pytest.raises(ForwardError, match="admissible"):
        simulate_trial(BEAM, "viscous", {"gamma": -1.0}, duration=0.1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"duration": 0.0}, "duration"),
        ({"dt": -1e-3}, "dt"),
        ({"dt": np.nan}, "dt"),
        ({"noise_sd": -1.0}, "noise_sd"),
        ({"noise_sd": np.inf}, "noise_sd"),
        ({"tip_deflection": np.nan}, "tip_deflection"),
        ({"duration": 1e-3}, "fewer than 2 samples"),
    ],
)
def test_bad_settings_raise(kwargs, match):
    with pytest.raises(ForwardError, match=match):
        simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, **kwargs)


def test_sample_count_is_capped_before_anything_is_allocated():
    # 1e9 s at the default dt is 2.56e11 samples (2 TB for the times alone): refused at
    # once, naming the count, the limit and both fixes.
    with pytest.raises(ForwardError, match=r"2\.56e\+11 samples .* above the limit of "
                       r"10,000,000 .*--duration.*--dt"):
        simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, duration=1e9)
    dt = 1e-3
    trial = simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, duration=2e-3, dt=dt)
    assert trial.times.size == 2
    with pytest.raises(ForwardError, match="limit"):
        simulate_trial(BEAM, "viscous", {"gamma": GAMMA}, dt=dt,
                       duration=(MAX_SIMULATED_SAMPLES + 1) * dt)

