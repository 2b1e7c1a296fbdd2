"""The second harmonic of mode 1 (trials.harmonics) on signals whose harmonic is known."""

import numpy as np
import pytest

from bayesbeam.trials.harmonics import second_harmonic

K2 = 5e-4  # per signal unit: the harmonic C/A² is K2/2


def _record(kind, seed=1):
    # A decaying mode 1 (6 Hz) and a faster-decaying mode 2 (39 Hz) on jittered stamps,
    # then: a quadratic sensor (y + K2 y²: line and mean shift), the same line without a
    # mean (a quadratic force or the sensor's motion), or no harmonic.
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.8, 1.2, 8000)) / 1000.0
    psi = 2 * np.pi * 6.0 * t + 0.3
    amp = 10 * np.exp(-0.15 * t)
    a = amp * np.cos(psi) + 0.5 * np.exp(-1.0 * t) * np.cos(2 * np.pi * 39.0 * t)
    y = {"sensor": a + K2 * a**2,
         "force": a + 0.5 * K2 * amp**2 * np.cos(2 * psi),
         "none": a}[kind]
    return t, y + 0.01 * rng.standard_normal(t.size)


@pytest.mark.parametrize("kind, slope", [("sensor", 1.0), ("force", 0.0)])
def test_in_phase_line_and_what_the_mean_does(kind, slope):
    sh = second_harmonic(*_record(kind), 6.0)
    # Within 4 of its own se (the sensor's mode-2 cross terms are in the residual).
    assert abs(sh.ratio - K2 / 2) < 4 * sh.ratio_se and sh.ratio_se < 0.1 * K2 / 2
    assert abs(sh.quadrature_ratio) < 4 * sh.quadrature_ratio_se + 1e-3 * K2
    assert abs(sh.mean_slope - slope) < 4 * sh.mean_slope_se and sh.mean_slope_se < 0.1
    rec = sh.to_json_dict()
    assert rec["n_windows"] == int(sh.used.sum()) >= 3
    assert rec["in_phase_per_amplitude2"] == sh.ratio
    assert "slope" in sh.text()


def test_no_harmonic_reads_zero_and_short_records_give_none():
    t, y = _record("none")
    sh = second_harmonic(t, y, 6.0)
    assert abs(sh.ratio) < 2 * sh.ratio_se  # (seed 1: 0.2 se)
    # No line: the text does not read the window means.
    assert "test nothing" in sh.text() and "slope" not in sh.text()
    assert second_harmonic(t[:1500], y[:1500], 6.0) is None  # two windows only
    assert second_harmonic(t, y, float("nan")) is None
