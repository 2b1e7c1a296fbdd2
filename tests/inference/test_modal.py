"""Modal posteriors (f_k, ζ_k per mode) against closed forms, with stand-in fits.

No sampling: the "posteriors" are clouds of chosen draws (conftest's stand-in FitResults),
so every number of the record can be checked draw by draw. The references are the
closed forms of physics.md: the uniform cantilever's ω_n = (β_n L)² sqrt(E I/(rhoA L⁴))
(§4, with the 16-element Hermite errors given there), viscous damping's
ζ_n = gamma/(2 rhoA ω_n) and Kelvin–Voigt's ζ_n = c_d ω_n/(2 E) (§2). For these classical
(proportional) laws the eigenvalues are λ = -ζω ± iω sqrt(1 - ζ²), so |λ| = ω and
ζ_n f_n = gamma/(4π rhoA), ζ_n / f_n = π c_d / E hold to round-off at every draw.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bayesbeam.inference.modal import (
    MATCH_RTOL,
    ModalError,
    ModalPosterior,
    data_modes,
    modal_posterior,
)
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import modal_properties
from bayesbeam.stats.families import LogUniform, Uniform
from bayesbeam.trials.synthetic import simulate_signal
from bayesbeam.trials.trial import Trial

NE = 16
E = 6.2e10
# physics.md §4: β_n L of the uniform cantilever and the relative frequency errors of cubic
# Hermite elements at 16 elements (from above: Rayleigh–Ritz).
BETA_L = np.array([1.875104069, 4.694091133, 7.854757438, 10.99554073])
ERR_16 = np.array([1.3e-7, 5.1e-6, 4.0e-5, 1.5e-4])
BEAM = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E)
W1 = BETA_L[0] ** 2 * math.sqrt(E * BEAM.I / (BEAM.rhoA * BEAM.length**4))
GAMMA = 2 * BEAM.rhoA * W1 * 0.01  # ζ1 = 1 %
C_D = 2 * E * 0.01 / W1  # ζ1 = 1 %
BAND = 300.0  # Hz: modes 1-3 (11.4, 71.2, 199 Hz) inside, mode 4 (391 Hz) outside


def _analytic_f(E_draws: np.ndarray, k: int) -> np.ndarray:
    """f_k (Hz) of the uniform cantilever, physics.md §4."""
    return BETA_L[k] ** 2 * np.sqrt(E_draws * BEAM.I / (BEAM.rhoA * BEAM.length**4)) / (2 * np.pi)


def _trial(model="viscous", params=None, bandwidth=BAND):
    """A 1 s release record at 1024 Hz (displacement) with a little noise."""
    t = np.arange(1024) / 1024
    p = {"E": E, "w0": 0.005, "gamma": GAMMA} if params is None else params
    y = simulate_signal(BEAM, model, p, t, n_elements=NE, bandwidth=np.inf)
    rng = np.random.default_rng(3)
    return Trial(times=t, values=y + 1e-7 * rng.standard_normal(t.size),
                 quantity="displacement", beam=BEAM, bandwidth=bandwidth, name="release")


@pytest.fixture(scope="module")
def viscous_trial():
    return _trial()


def _draws(rec: ModalPosterior, result) -> np.ndarray:
    """Physical draws of the record's rows (the chain flattened step-major)."""
    return result.theta_samples().reshape(-1, result.chain.ndim)[rec.draw_index]


def test_viscous_modes_follow_the_closed_forms(viscous_trial, gaussian_cloud_result):
    pr = Problem(viscous_trial, "viscous", n_elements=NE)
    assert pr.names == ("E", "gamma", "w0", "sigma")
    res = gaussian_cloud_result(pr, [E, GAMMA, 0.005, 1e-7], [0.05, 0.3, 0.01, 0.1])
    rec = modal_posterior(pr, res, data=False)
    # 40 x 16 draws, 400 evenly spaced; K = 3 modes below the 300 Hz band.
    assert rec.available and rec.reason is None
    assert rec.frequency_hz.shape == rec.damping_ratio.shape == (400, 3)
    assert rec.n_requested == 400 and rec.n_invalid == rec.n_overdamped == 0
    assert rec.draw_index[0] == 0 and rec.draw_index[-1] == 639
    X = _draws(rec, res)
    E_d, g_d = X[:, 0], X[:, 1]
    for k in range(3):
        rel = rec.frequency_hz[:, k] / _analytic_f(E_d, k) - 1
        assert np.all(rel > -1e-9) and np.all(rel < 1.1 * ERR_16[k] + 1e-9), k
        # ζ_k = gamma/(2 rhoA ω_k) with ω_k = 2π f_k: ζ_k f_k = gamma/(4π rhoA) per draw.
        np.testing.assert_allclose(rec.damping_ratio[:, k] * rec.frequency_hz[:, k],
                                   g_d / (4 * np.pi * BEAM.rhoA), rtol=1e-9)
    # The transform of each draw, from an independent entry point (modal_properties builds
    # its own forward model): f_k = sqrt(E) f_k(E = 1), ζ_k = gamma/(2 rhoA 2π f_k).
    f_unit, _ = modal_properties(BEAM, "viscous", {"E": 1.0, "gamma": 0.0}, n_elements=NE)
    f_exp = np.sqrt(E_d)[:, None] * f_unit[None, :3]
    z_exp = g_d[:, None] / (2 * BEAM.rhoA * 2 * np.pi * f_exp)
    np.testing.assert_allclose(rec.frequency_hz, f_exp, rtol=1e-9)
    np.testing.assert_allclose(rec.damping_ratio, z_exp, rtol=1e-9)
    # Quantiles of the record are those of the transformed draws.
    for k, row in enumerate(rec.summary()):
        assert row["mode"] == k + 1
        for name, arr in (("frequency_hz", f_exp), ("damping_ratio", z_exp)):
            q = np.quantile(arr[:, k], [0.05, 0.5, 0.95])
            np.testing.assert_allclose([row[name][s] for s in ("q05", "q50", "q95")], q,
                                       rtol=1e-9)
            assert row[name]["mean"] == pytest.approx(arr[:, k].mean(), rel=1e-9)
            assert row[name]["sd"] == pytest.approx(arr[:, k].std(ddof=1), rel=1e-7)


def test_kelvin_voigt_modes_follow_the_closed_form(viscous_trial, gaussian_cloud_result):
    pr = Problem(viscous_trial, "kv", n_elements=NE)
    res = gaussian_cloud_result(pr, [E, C_D, 0.005, 1e-7], [0.05, 0.3, 0.01, 0.1],
                                nsteps=10, nwalkers=10)
    rec = modal_posterior(pr, res, data=False)
    assert rec.frequency_hz.shape == (100, 3)  # fewer draws than asked: all of them
    X = _draws(rec, res)
    E_d, c_d = X[:, 0], X[:, 1]
    for k in range(3):
        rel = rec.frequency_hz[:, k] / _analytic_f(E_d, k) - 1
        assert np.all(rel > -1e-9) and np.all(rel < 1.1 * ERR_16[k] + 1e-9), k
        # ζ_k = c_d ω_k/(2E): ζ_k / f_k = π c_d / E per draw (grows with frequency).
        np.testing.assert_allclose(rec.damping_ratio[:, k] / rec.frequency_hz[:, k],
                                   np.pi * c_d / E_d, rtol=1e-9)
        # and against the analytic ω_k, within the mesh's frequency error
        z_an = c_d * 2 * np.pi * _analytic_f(E_d, k) / (2 * E_d)
        assert np.all(np.abs(rec.damping_ratio[:, k] / z_an - 1) < 1.1 * ERR_16[k] + 1e-9)
    # The mesh's top modes are overdamped under KV (ζ ∝ ω); they lie far above mode 3, so
    # no draw is lost, and the note says so.
    assert rec.n_overdamped == 0
    assert any("overdamped modes above mode 3" in n for n in rec.notes)


def test_overdamped_first_mode_is_counted_not_dropped_silently(viscous_trial,
                                                               result_from_samples):
    # A wide gamma prior so that ζ1 = 2 (mode 1 overdamped: real eigenvalues) is inside it.
    g_lo, g_hi = GAMMA * 1e-3, GAMMA * 1e3
    pr = Problem(viscous_trial, "viscous", {"gamma": LogUniform(g_lo, g_hi)}, n_elements=NE)
    th = np.tile([E, GAMMA, 0.005, 1e-7], (4, 5, 1))
    th[1::2, :, 1] = 200 * GAMMA  # ζ1 = 2, ζ2 = 2 f1/f2 = 0.32: mode 2 still oscillates
    res = result_from_samples(pr, pr.priors.to_u(th.reshape(-1, 4)).reshape(4, 5, 4))
    rec = modal_posterior(pr, res, data=False)
    assert rec.n_requested == 20
    assert rec.n_overdamped == 10 and rec.n_invalid == 0
    assert rec.n_draws == 10 and rec.frequency_hz.shape == (10, 3)
    # Only the draws of steps 0 and 2 (rows 0-4 and 10-14 of the flattened chain) remain.
    assert rec.draw_index.tolist() == [0, 1, 2, 3, 4, 10, 11, 12, 13, 14]
    # ζ1 = 1 % at the analytic ω1; the mesh's ω1 lies 1.3e-7 above it (physics.md §4)
    np.testing.assert_allclose(rec.damping_ratio[:, 0], 0.01, rtol=2e-7)
    assert any("10 of 20 draws left out: an overdamped mode" in n for n in rec.notes)
    d = rec.to_json_dict()
    assert d["n_overdamped"] == 10 and d["n_draws"] == 10
    # MATCH_RTOL is far below the ratio of neighbouring cantilever modes (f2/f1 = 6.3).
    assert MATCH_RTOL < (BETA_L[1] / BETA_L[0]) ** 2 - 1


def test_all_draws_overdamped_gives_a_reason_not_a_record(viscous_trial, result_from_samples):
    pr = Problem(viscous_trial, "viscous", {"gamma": LogUniform(GAMMA, GAMMA * 1e3)},
                 n_elements=NE)
    th = np.tile([E, 200 * GAMMA, 0.005, 1e-7], (2, 3, 1))
    res = result_from_samples(pr, pr.priors.to_u(th.reshape(-1, 4)).reshape(2, 3, 4))
    rec = modal_posterior(pr, res)
    assert not rec.available
    assert "no draw gives 3 underdamped modes" in rec.reason
    assert rec.summary() == [] and rec.n_overdamped == 6
    d = json.loads(json.dumps(rec.to_json_dict(), allow_nan=False))
    assert d["available"] is False and d["modes"] == [] and d["reason"] == rec.reason
    assert "none" in str(rec)


def test_inadmissible_draws_are_counted(viscous_trial, result_from_samples):
    # A uniform gamma prior that reaches below zero: negative gamma is inadmissible.
    pr = Problem(viscous_trial, "viscous", {"gamma": Uniform(-GAMMA, 2 * GAMMA)},
                 n_elements=NE)
    th = np.tile([E, GAMMA, 0.005, 1e-7], (3, 4, 1))
    th[:, :2, 1] = -0.5 * GAMMA  # two walkers at negative gamma in every step
    res = result_from_samples(pr, pr.priors.to_u(th.reshape(-1, 4)).reshape(3, 4, 4))
    rec = modal_posterior(pr, res, data=False)
    assert rec.n_invalid == 6 and rec.n_overdamped == 0 and rec.n_draws == 6
    assert any("6 of 12 draws left out: outside the admissible range" in n for n in rec.notes)
    np.testing.assert_allclose(rec.damping_ratio[:, 0], 0.01, rtol=2e-7)


def test_spatial_hysteresis_draws_equal_the_modes_of_their_parameters(viscous_trial,
                                                                      gaussian_cloud_result):
    # Non-classical damping: the record is the eigenvalue map (eq. 1) of each draw, with
    # a recovered from eta (Problem.derived), checked through an independent entry point.
    ne = 6
    pr = Problem(viscous_trial, "viscous+sh", n_elements=ne)
    assert pr.names == ("E", "gamma", "eta", "b", "w0", "sigma")
    truth = [E, GAMMA, 2 * E * BEAM.I * 0.005 / W1, 0.05, 0.005, 1e-7]
    res = gaussian_cloud_result(pr, truth, [0.03, 0.2, 0.2, 0.2, 0.01, 0.1], nsteps=3,
                                nwalkers=6)
    rec = modal_posterior(pr, res, n_draws=12, data=False)
    assert rec.n_draws == 12 and rec.n_modes == 3
    X = _draws(rec, res)
    a = pr.derived(X)["a"]
    for i in range(rec.n_draws):
        p = {"E": X[i, 0], "gamma": X[i, 1], "a": a[i], "b": X[i, 3]}
        f, z = modal_properties(BEAM, "viscous+sh", p, n_elements=ne)
        np.testing.assert_allclose(rec.frequency_hz[i], f[:3], rtol=1e-9)
        np.testing.assert_allclose(rec.damping_ratio[i], z[:3], rtol=1e-9)


def test_nonlinear_model_reports_its_linear_part(viscous_trial, gaussian_cloud_result):
    pr = Problem(viscous_trial, "viscous+drag", n_elements=8)
    assert pr.names[:3] == ("E", "gamma", "drag")
    drag = float(np.sqrt(pr.priors["drag"].lo * pr.priors["drag"].hi))
    res = gaussian_cloud_result(pr, [E, GAMMA, drag, 0.005, 1e-7], [0.05, 0.3, 0.5, 0.01, 0.1],
                                nsteps=4, nwalkers=10)
    rec = modal_posterior(pr, res, data=False)
    assert rec.available and rec.source == "linear part"
    assert any("linear part" in n and "drag" in n for n in rec.notes)
    X = _draws(rec, res)
    np.testing.assert_allclose(rec.damping_ratio * rec.frequency_hz,
                               np.repeat(X[:, 1:2] / (4 * np.pi * BEAM.rhoA), 3, axis=1),
                               rtol=1e-9)


def test_number_of_modes_follows_the_sensor_band(gaussian_cloud_result):
    # A band below f1 still gives the minimum of two modes, and says they are outside it.
    tr = _trial(bandwidth=5.0)
    pr = Problem(tr, "viscous", n_elements=8)
    res = gaussian_cloud_result(pr, [E, GAMMA, 0.005, 1e-7], [0.01, 0.1, 0.01, 0.1],
                                nsteps=2, nwalkers=8)
    rec = modal_posterior(pr, res, data=False)
    assert rec.n_modes == 2 and rec.sensor_band_hz == 5.0
    assert any("modes [1, 2] lie above the sensor band" in n for n in rec.notes)
    assert modal_posterior(pr, res, n_modes=5, data=False).frequency_hz.shape == (16, 5)
    # No band at all (inf): at most six modes; the JSON writes the band as null.
    tr_inf = _trial(bandwidth=math.inf)
    pr_inf = Problem(tr_inf, "viscous", n_elements=8)
    res_inf = gaussian_cloud_result(pr_inf, [E, GAMMA, 0.005, 1e-7], [0.01, 0.1, 0.01, 0.1],
                                    nsteps=2, nwalkers=8)
    rec_inf = modal_posterior(pr_inf, res_inf, data=False)
    assert rec_inf.n_modes == 6
    assert rec_inf.to_json_dict()["sensor_band_hz"] is None


def test_bad_input_is_refused(viscous_trial, gaussian_cloud_result):
    pr = Problem(viscous_trial, "viscous", n_elements=8)
    res = gaussian_cloud_result(pr, [E, GAMMA, 0.005, 1e-7], [0.01, 0.1, 0.01, 0.1],
                                nsteps=2, nwalkers=8)
    other = Problem(viscous_trial, "kv", n_elements=8)
    with pytest.raises(ModalError, match="not the problem's"):
        modal_posterior(other, res)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ModalError, match="n_draws must be a positive integer"):
            modal_posterior(pr, res, n_draws=bad)
    with pytest.raises(ModalError, match="n_modes"):
        modal_posterior(pr, res, n_modes=0)
    with pytest.raises(ModalError, match="has 16 modes"):  # 8 elements, 2 dofs a node
        modal_posterior(pr, res, n_modes=17)


def test_record_is_immutable_and_strict_json(viscous_trial, gaussian_cloud_result):
    pr = Problem(viscous_trial, "viscous", n_elements=NE)
    res = gaussian_cloud_result(pr, [E, GAMMA, 0.005, 1e-7], [0.02, 0.1, 0.01, 0.1],
                                nsteps=4, nwalkers=8)
    rec = modal_posterior(pr, res)
    with pytest.raises(ValueError, match="read-only"):
        rec.frequency_hz[0, 0] = 1.0
    with pytest.raises(AttributeError):
        rec.model = "kv"
    d = json.loads(json.dumps(rec.to_json_dict(), allow_nan=False))
    assert d["available"] is True and d["source"] == "model" and d["n_modes"] == 3
    assert [m["mode"] for m in d["modes"]] == [1, 2, 3]
    for m in d["modes"]:
        for q in ("frequency_hz", "damping_ratio"):
            assert set(m[q]) == {"mean", "sd", "q05", "q50", "q95"}
    assert d["data"]["method"] == "damped_sinusoids" and len(d["data"]["modes"]) == 3
    with pytest.raises(ModalError, match=r"\(draws, K\)"):
        ModalPosterior(model="x", frequency_hz=np.ones((3, 2)), damping_ratio=np.ones((3, 1)),
                       draw_index=np.arange(3), n_requested=3)


def test_data_modes_recover_the_simulated_modes(viscous_trial):
    # The record was simulated with ζ_k = gamma/(2 rhoA ω_k) at the 16-element ω_k; the
    # damped-sinusoid estimates must find them within their 90 % intervals (noise 0.1 µm
    # on 5 mm: tight) and the frequencies to 1e-5.
    f_fe, z_fe = modal_properties(BEAM, "viscous", {"E": E, "gamma": GAMMA}, n_elements=NE)
    dm = data_modes(viscous_trial.times, viscous_trial.values, f_fe[:3] * 1.01, [0.02] * 3)
    np.testing.assert_allclose(dm.frequency_hz[:2], f_fe[:2], rtol=1e-5)
    fi, zi = dm.frequency_90, dm.damping_90
    for k in range(2):
        assert zi[k, 0] - 1e-6 <= z_fe[k] <= zi[k, 1] + 1e-6, (k, zi[k], z_fe[k])
        assert fi[k, 0] < dm.frequency_hz[k] < fi[k, 1]
    assert np.all(dm.damping_ratio_se[:2] > 0)
    # Modes above 0.8 x Nyquist are not fitted, and the note says so.
    dm2 = data_modes(viscous_trial.times, viscous_trial.values, [f_fe[0], 450.0])
    assert np.isfinite(dm2.frequency_hz[0]) and np.isnan(dm2.frequency_hz[1])
    assert any("not measured" in n for n in dm2.notes)
    assert dm2.to_json_dict()["modes"][1] is None
