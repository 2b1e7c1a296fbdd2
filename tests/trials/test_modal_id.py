"""Modal identification: estimators checked against closed forms and brute force."""

import json
import math

import numpy as np
import pytest

from bayesbeam.trials.modal_id import (
    band_modal_estimate,
    damped_sinusoids,
    decay_rate_vs_amplitude,
    periodogram,
    spectral_peak,
    windowed_sinusoids,
)


def test_periodogram_amplitude_and_peak():
    t = np.arange(1024) / 256.0
    f0 = 40 * 256.0 / 1024  # on a bin of the unpadded FFT
    f, amp = periodogram(t, 2.0 * np.sin(2 * np.pi * f0 * t))
    # Hann window normalised by its coherent gain: a bin-centred tone of amplitude 2
    # peaks at 2 (to the window's leakage of the negative-frequency image, < 1e-3).
    assert amp.max() == pytest.approx(2.0, rel=1e-3)
    assert spectral_peak(f, amp, f0 * 1.05) == pytest.approx(f0, abs=1e-3)


def _modes_signal(t, rng, noise):
    y = (np.exp(-0.3 * t) * np.cos(2 * np.pi * 10.3 * t + 0.4)
         + 0.05 * np.exp(-2.0 * t) * np.sin(2 * np.pi * 64.4 * t))
    return y + noise * rng.standard_normal(t.size)


def test_damped_sinusoids_accuracy_and_errors():
    t = np.arange(512) / 512.0
    rng = np.random.default_rng(3)
    est = [damped_sinusoids(t, _modes_signal(t, rng, 0.01), [10.0, 62.0]) for _ in range(40)]
    f1 = np.array([e[0].frequency for e in est])
    s1 = np.array([e[0].decay_rate for e in est])
    f2 = np.array([e[1].frequency for e in est])
    # Unbiased within 4 standard errors of the 40-run mean.
    assert abs(f1.mean() - 10.3) < 4 * f1.std() / math.sqrt(40)
    assert abs(s1.mean() - 0.3) < 4 * s1.std() / math.sqrt(40)
    assert abs(f2.mean() - 64.4) < 4 * f2.std() / math.sqrt(40)
    # The reported standard errors match the scatter over noise realisations within a
    # factor 1.6 (40 runs estimate an sd to ~11 %; the AR(1) inflation is conservative).
    for vals, key, k in ((f1, "frequency_se", 0), (s1, "decay_rate_se", 0),
                         (f2, "frequency_se", 1)):
        se = np.mean([getattr(e[k], key) for e in est])
        assert 1 / 1.6 < se / vals.std() < 1.6
    # A mode that is not in the record is reported as not measurable.
    none = damped_sinusoids(t, _modes_signal(t, rng, 0.01), [10.0, 62.0, 150.0])
    assert none[2] is None


def test_band_modal_estimate_long_record():
    t = np.arange(20 * 200) / 200.0
    y = np.exp(-0.2 * t) * np.cos(2 * np.pi * 5.0 * t)
    est = band_modal_estimate(t, y, 5.0)
    # Noise-free, 100 periods: the phase slope gives f to 1e-4 relative and the
    # log-envelope slope σ to 2 % (edge trims, filter ripple).
    assert est.frequency == pytest.approx(5.0, rel=1e-4)
    assert est.decay_rate == pytest.approx(0.2, rel=0.02)
    assert est.damping_ratio == pytest.approx(0.2 / math.hypot(0.2, 2 * np.pi * 5.0), rel=0.02)


@pytest.mark.parametrize("c", [1.5, 0.0, -0.5])
def test_decay_rate_vs_amplitude_recovers_excess(c):
    # Closed form of dA/dt = -σ0 A - κ A² with c = κ A0/σ0 (drag-like for c > 0; c < 0
    # makes the rate grow as the amplitude falls, friction-like).
    t = np.arange(3 * 256) / 256.0
    s0, f = 0.25, 10.28
    env = np.exp(-s0 * t) / (1 + c * (1 - np.exp(-s0 * t)))
    rng = np.random.default_rng(4)
    y = env * np.cos(2 * np.pi * f * t) + 0.003 * rng.standard_normal(t.size)
    d = decay_rate_vs_amplitude(t, y, f, other=[6.267 * f])
    # Within 4 reported standard errors, and 0.25 absolute (noise 0.3 % of A0 gives a
    # standard error of ~0.07 for c = 1.5).
    assert abs(d.excess - c) < max(4 * d.excess_se, 0.02)
    assert abs(d.excess - c) < 0.25
    assert d.rate0 == pytest.approx(s0, rel=0.15)
    assert d.amplitude.size >= 3
    json.dumps(d.to_json_dict())


def test_a_short_lived_mode_is_measured_on_its_own_window():
    # A 20 s record at 700 Hz shaped like Al 40 cm #0: mode 1 at 9.4 Hz decaying at
    # 0.3/s whose frequency drifts by 1 % as it decays (an effect no damped sinusoid
    # holds), mode 2 at 61.86 Hz decaying at 7/s (gone after 1 s). Over the whole
    # record the drift's correlated residual inflates mode 2's standard error until it
    # is "not measurable"; the window that holds mode 2's life measures it.
    rng = np.random.default_rng(0)
    fs, f2, s2 = 700.0, 61.86, 7.0
    t = np.arange(0.0, 20.0, 1.0 / fs)
    f1_t = 9.4 * (1 - 0.01 * np.exp(-0.3 * t))
    phase = 2 * np.pi * np.cumsum(f1_t) / fs
    y = (24 * np.exp(-0.3 * t) * np.cos(phase + 0.3)
         + 5 * np.exp(-s2 * t) * np.cos(2 * np.pi * f2 * t + 1.0)
         + 0.05 * rng.standard_normal(t.size))
    whole = damped_sinusoids(t, y, [9.4, 62.0])
    assert whole[1] is None  # the failure the windows exist for
    est, windows = windowed_sinusoids(t, y, [9.4, 62.0])
    e2 = est[1]
    assert e2 is not None
    # Within 4 of its own standard errors of the generating values (the estimator
    # reaches the Cramér-Rao bound on its window; 4 se: a 6e-5 false-alarm rate).
    assert abs(e2.frequency - f2) < 4 * e2.frequency_se
    assert abs(e2.decay_rate - s2) < 4 * e2.decay_rate_se
    # Mode 1 keeps the whole record's estimate (its mean over the record).
    assert est[0] == whole[0]
    assert windows[0] == t[-1] - t[0]
    # The window is reported: the same fit on it gives the same estimate.
    m = t - t[0] <= windows[1] * (1 + 1e-12)
    assert damped_sinusoids(t[m], y[m], [9.4, 62.0])[1] == e2
    assert windows[1] < 0.25 * windows[0]  # mode 2 lives ~1 s of the 20 s
