"""Fit/spectrum plots and the residual whiteness summary."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import stats

from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.report.plots import (
    PlotError,
    plot_fit,
    plot_residual_spectrum,
    residual_summary,
)
from bayesbeam.trials.synthetic import simulate_trial
from bayesbeam.trials.trial import Trial

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _beam():
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)


@pytest.fixture(scope="module")
def setup(gaussian_cloud_result):
    beam = _beam()
    tr = simulate_trial(beam, "viscous", {"gamma": 0.2}, duration=0.5, dt=1 / 256,
                        noise_sd=1e-5, seed=3, n_elements=6)
    pr = Problem(tr, "viscous", n_elements=6)
    truth = [6.2e10, 0.2, 0.005, 1e-5]
    sd_u = np.array([1e-6, 1e-3, 1e-5, 1e-2])
    return tr, pr, gaussian_cloud_result(pr, truth, sd_u)


def _is_png(path):
    data = path.read_bytes()
    return len(data) > 1000 and data[:8] == PNG_MAGIC


def test_plot_fit_writes_png(setup, tmp_path):
    tr, pr, res = setup
    p = plot_fit(tr, pr, res, tmp_path / "fit.png", n_draws=20, rng=np.random.default_rng(0))
    assert _is_png(p)


def test_plot_residual_spectrum_writes_png_uniform_and_jittered(tmp_path):
    rng = np.random.default_rng(0)
    t = np.arange(600) / 256
    trial = Trial(times=t, values=np.zeros(t.size), quantity="displacement", beam=_beam())
    p = plot_residual_spectrum(trial, rng.standard_normal(t.size) * 1e-5,
                               tmp_path / "s.png", mode_freqs_hz=[11.4, 71.2, 500.0])
    assert _is_png(p)
    tj = np.sort(t + rng.uniform(-0.3, 0.3, t.size) / 256)
    trial_j = Trial(times=tj, values=np.zeros(t.size), quantity="velocity", beam=_beam())
    p = plot_residual_spectrum(trial_j, rng.standard_normal(t.size), tmp_path / "j.png")
    assert _is_png(p)


def test_plots_do_not_import_pyplot(tmp_path):
    # The object API must leave pyplot (global figure state, backend choice) alone.
    code = (
        "import sys, numpy as np\n"
        "from bayesbeam.physics.beam import Beam\n"
        "from bayesbeam.trials.trial import Trial\n"
        "from bayesbeam.report.plots import plot_residual_spectrum\n"
        "t = np.arange(64) / 256\n"
        "b = Beam.rectangular(0.3, 0.1, 1e-3, 0.02, E=6e10)\n"
        "tr = Trial(times=t, values=np.zeros(64), quantity='displacement', beam=b)\n"
        f"plot_residual_spectrum(tr, np.sin(t), {str(tmp_path / 'x.png')!r})\n"
        "assert 'matplotlib.pyplot' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_residual_summary_white_noise_not_flagged(seed):
    rng = np.random.default_rng(seed)
    t = np.arange(1280) / 256
    s = residual_summary(rng.standard_normal(t.size), t)
    assert not s["structured"]
    assert s["dof"] == 20
    # For white noise each r_k ~ N(0, 1/n): |r_k| < 4/sqrt(n) with overwhelming probability.
    assert np.max(np.abs(s["autocorr"])) < 4 / np.sqrt(t.size)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_residual_summary_flags_ar1(seed):
    rng = np.random.default_rng(seed)
    n, rho = 1280, 0.5
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0]
    for i in range(1, n):
        x[i] = rho * x[i - 1] + np.sqrt(1 - rho**2) * e[i]
    s = residual_summary(x, np.arange(n) / 256)
    assert s["structured"]
    assert s["p_value"] < 1e-10  # Q ~ n rho^2 ~ 320 against chi2(20): p ~ 1e-55
    # Lag-1 estimate: sd ~ sqrt((1 - rho^2)/n) ~ 0.024; 5 sd.
    assert s["autocorr"][0] == pytest.approx(rho, abs=0.12)


def test_residual_summary_matches_chi2_calibration():
    # Under white noise the p-value is ~uniform: about 1 % of 400 series flagged at 1 %.
    # Binomial(400, 0.01): P(count > 12) < 1e-3.
    rng = np.random.default_rng(11)
    t = np.arange(512) / 256.0
    flagged = sum(residual_summary(rng.standard_normal(t.size), t)["structured"]
                  for _ in range(400))
    assert flagged <= 12
    assert stats.binom.sf(12, 400, 0.01) < 1e-3


def test_residual_summary_rejects_bad_input():
    with pytest.raises(PlotError, match="equal length"):
        residual_summary(np.zeros(10), np.arange(9.0))
    with pytest.raises(PlotError, match="at least 8"):
        residual_summary(np.zeros(5), np.arange(5.0))


def test_residual_spectrum_caption_states_the_residual_rms(tmp_path, monkeypatch):
    """The caption's RMS is the residuals' (it once printed an alias frequency: a loop
    over modes above Nyquist reused the residuals' variable)."""
    from matplotlib.figure import Figure

    captions = []
    real_savefig = Figure.savefig

    def keep_caption(fig, *args, **kwargs):
        captions.extend(t.get_text() for t in fig.texts)
        return real_savefig(fig, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", keep_caption)
    t = np.arange(1280) * 0.004
    trial = Trial(times=t, values=np.zeros_like(t), quantity="displacement", beam=_beam(),
                  name="x")
    resid = 1.3e-5 * np.random.default_rng(3).standard_normal(t.size)
    plot_residual_spectrum(trial, resid, tmp_path / "r.png",
                           mode_freqs_hz=np.array([11.0, 69.0, 193.0, 378.0]))  # 2 > Nyquist
    (caption,) = captions
    rms = float(caption.split("RMS ")[1].split()[0])
    assert rms == pytest.approx(np.sqrt(np.mean(resid**2)), rel=1e-2)  # 3 printed digits
    assert caption.split("RMS ")[1].split()[1] == "m"
