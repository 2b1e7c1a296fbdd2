"""Problem: log posterior assembly, parameter maps, noise models and default priors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats

from bayesbeam.inference.problem import BETA1, Problem, default_priors, reference_modulus
from bayesbeam.physics.beam import Beam
from bayesbeam.stats.families import LogUniform, Normal, Uniform
from bayesbeam.trials.synthetic import simulate_signal, simulate_trial
from bayesbeam.trials.trial import Trial

E_TRUE = 6.2e10
NE = 6  # elements: enough for these checks, which compare the Problem with itself/by hand


def _beam(**kw):
    return Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, **kw)


def _w1(beam, E=E_TRUE):
    return BETA1**2 * math.sqrt(E * beam.I / (beam.rhoA * beam.length**4))


@pytest.fixture(scope="module")
def trial():
    return simulate_trial(_beam(E=E_TRUE), "viscous", {"gamma": 0.2}, duration=0.25,
                          dt=1 / 256, noise_sd=1e-5, seed=5, n_elements=NE)


def _log_prior_by_hand(priors, X):
    out = 0.0
    for name, x in zip(priors.names, X, strict=True):
        p = priors[name]
        if isinstance(p, LogUniform):  # u = log x uniform on [log lo, log hi]
            out += -math.log(math.log(p.hi / p.lo)) if p.lo <= x <= p.hi else -math.inf
        elif isinstance(p, Uniform):  # u = x
            out += -math.log(p.hi - p.lo) if p.lo <= x <= p.hi else -math.inf
        elif isinstance(p, Normal):
            out += stats.norm.logpdf(x, p.mu, p.sd)
        else:  # pragma: no cover - not used by these defaults
            raise AssertionError(type(p))
    return out


def test_log_prob_is_prior_plus_gaussian_loglik_by_hand(trial):
    pr = Problem(trial, "viscous", n_elements=NE)
    assert pr.names == ("E", "gamma", "w0", "sigma")
    X = np.array([[6.2e10, 0.2, 0.005, 1e-5], [6.1e10, 0.35, 0.0049, 2.3e-5]])
    lp = pr.log_prob(pr.priors.to_u(X))
    for k in range(2):
        E, gamma, w0, sigma = X[k]
        y = simulate_signal(trial.beam, "viscous", {"E": E, "gamma": gamma, "w0": w0},
                            trial.times, n_elements=NE)
        ll = np.sum(stats.norm.logpdf(trial.values, y, sigma))
        # Same numbers through two code paths: agreement to rounding (1e-9 relative of ~1e3).
        assert lp[k] == pytest.approx(_log_prior_by_hand(pr.priors, X[k]) + ll, rel=1e-9)


def test_offset_shifts_the_prediction_and_enters_the_likelihood(trial):
    pr = Problem(trial, "viscous+sensor_offset", n_elements=NE)
    assert pr.names[-1] == "offset"
    X0 = np.array([[6.2e10, 0.2, 0.005, 1e-5, 0.0]])
    X1 = X0.copy()
    X1[0, -1] = 3e-4
    d = pr.predict(X1).y - pr.predict(X0).y
    np.testing.assert_allclose(d, 3e-4, rtol=1e-12, atol=0)
    y1 = pr.predict(X1).y[0]
    ll = np.sum(stats.norm.logpdf(trial.values, y1, 1e-5))
    assert pr.log_likelihood(pr.priors.to_u(X1))[0] == pytest.approx(ll, rel=1e-9)


def _ar1_by_hand(r, sigma, rho, times):
    """Dense Gaussian with covariance sigma² rho^(|t_i - t_j| / median step)."""
    ref = np.median(np.diff(times))
    lag = np.abs(times[:, None] - times[None, :]) / ref
    cov = sigma**2 * rho**lag
    return stats.multivariate_normal(np.zeros(r.size), cov).logpdf(r)


@pytest.mark.parametrize("jitter", [False, True])
def test_ar1_model_uses_the_ar1_likelihood(jitter):
    beam = _beam(E=E_TRUE)
    rng = np.random.default_rng(2)
    t = np.arange(48) / 256
    if jitter:  # sorted, jittered stamps (non-uniform: the OU form of the AR(1))
        t = np.sort(t + rng.uniform(-0.3, 0.3, t.size) / 256)
    y = simulate_signal(beam, "viscous", {"gamma": 0.2, "w0": 0.005}, t, n_elements=4)
    tr = Trial(times=t, values=y + 1e-5 * rng.standard_normal(t.size),
               quantity="displacement", beam=beam)
    pr = Problem(tr, "viscous+ar1_noise", n_elements=4)
    assert pr.names[-1] == "rho"
    X = np.array([6.2e10, 0.2, 0.005, 2e-5, 0.6])
    r = tr.values - pr.predict(X[None]).y[0]
    want = _ar1_by_hand(r, 2e-5, 0.6, t)
    assert pr.log_likelihood(pr.priors.to_u(X[None]))[0] == pytest.approx(want, rel=1e-9)
    # and differs from the i.i.d. value (the correlation matters)
    assert abs(want - np.sum(stats.norm.logpdf(r, 0, 2e-5))) > 1.0
    # pointwise terms sum to the joint (sequential decomposition)
    pw = pr.log_likelihood_pointwise(pr.priors.to_u(X[None]))[0]
    assert np.sum(pw) == pytest.approx(want, rel=1e-9)


def test_invalid_sets_give_minus_inf_not_nan(trial):
    pr = Problem(trial, "viscous", priors={"E": Normal(6.2e10, 1e11)}, n_elements=NE)
    U = pr.priors.to_u(np.array([[6.2e10, 0.2, 0.005, 1e-5]] * 4))
    U[0, 0] = -1e9  # E < 0: allowed by this prior, rejected by the forward model
    U[1, 1] = 50.0  # log gamma far above the prior's upper bound
    U[2, 3] = np.nan  # NaN input
    lp = pr.log_prob(U)
    assert not np.any(np.isnan(lp))
    assert np.all(lp[:3] == -np.inf)
    assert np.isfinite(lp[3])
    assert np.all(pr.log_likelihood(U[:1]) == -np.inf)


def test_pointwise_log_likelihood_in_batches_sums_to_the_total(trial):
    # More points than one forward-model batch, an invalid one on each side of the
    # batch boundary: rows sum to log_likelihood (same residuals, another order of
    # summation over T = 64 terms of size ~10: rounding ~1e-14 relative, rtol 1e-10),
    # invalid points give -inf rows, and the batches do not mix rows.
    from bayesbeam.inference.problem import POINTWISE_BATCH

    pr = Problem(trial, "viscous", priors={"E": Normal(6.2e10, 1e11)}, n_elements=NE)
    k = POINTWISE_BATCH + 10
    rng = np.random.default_rng(4)
    X = np.array([6.2e10, 0.2, 0.005, 1e-5]) * (1 + 1e-3 * rng.standard_normal((k, 4)))
    U = pr.priors.to_u(X)
    bad = [POINTWISE_BATCH - 1, POINTWISE_BATCH + 3]
    U[bad, 0] = -1e9  # E < 0: rejected by the forward model
    pw = pr.log_likelihood_pointwise(U)
    assert pw.shape == (k, trial.times.size)
    assert np.all(pw[bad] == -np.inf)
    ok = np.setdiff1d(np.arange(k), bad)
    np.testing.assert_allclose(pw[ok].sum(axis=1), pr.log_likelihood(U[ok]), rtol=1e-10)
    assert pr.signal_unit == "m"


def _analytic_mode1():
    """First cantilever mode φ(s), s = x/L, and its derivatives (Euler–Bernoulli)."""
    b = BETA1
    sig = (math.cosh(b) + math.cos(b)) / (math.sinh(b) + math.sin(b))
    d1 = lambda s: b * (math.sinh(b * s) + math.sin(b * s)  # noqa: E731
                        - sig * (math.cosh(b * s) - math.cos(b * s)))
    d2 = lambda s: b**2 * (math.cosh(b * s) + math.cos(b * s)  # noqa: E731
                           - sig * (math.sinh(b * s) + math.sin(b * s)))
    return d1, d2


def test_eta_map_exact_in_both_kernel_limits(trial):
    pr = Problem(trial, "viscous+sh", n_elements=16)
    L = trial.beam.length
    # Narrow kernel: S(b) -> (b²/2) ∫ φ'' φ'' (physics.md §2), so eta/a -> b²/2. The
    # boundary layer at the clamp lowers it by O(b/L); at b = 1e-6 L that is < 1e-5.
    b = 1e-6 * L
    assert pr.eta_per_a([b])[0] == pytest.approx(b * b / 2, rel=1e-5)
    # Wide kernel (b >> L): g_b ≈ 1/(b sqrt(2π)) on the beam, so
    # s1 = [L ∫φ'² - (∫φ')²] / (b sqrt(2π) ∫φ''²) with the exact mode (x = s L).
    d1, d2 = _analytic_mode1()
    i11 = integrate.quad(lambda s: d1(s) ** 2, 0, 1)[0] / L**2 * L
    i1 = integrate.quad(d1, 0, 1)[0] / L * L
    i22 = integrate.quad(lambda s: d2(s) ** 2, 0, 1)[0] / L**4 * L
    b = 1000 * L
    want = (L * i11 - i1**2) / (b * math.sqrt(2 * math.pi) * i22)
    # Tolerance: the Gaussian's curvature over the beam, (L/b)² = 1e-6, plus the FE
    # mode error at 16 elements (~1e-7, physics.md §4); 1e-4 leaves margin.
    assert pr.eta_per_a([b])[0] == pytest.approx(want, rel=1e-4)


def test_eta_a_round_trip_and_derived(trial):
    pr = Problem(trial, "viscous+sh", n_elements=NE)
    names = list(pr.names)
    X = np.zeros((3, len(names)))
    X[:, names.index("E")] = 6.2e10
    X[:, names.index("gamma")] = 0.1
    X[:, names.index("eta")] = [1e-5, 3e-5, 2e-4]
    X[:, names.index("b")] = [1e-3, 0.01, 0.5]
    X[:, names.index("w0")] = 0.005
    X[:, names.index("sigma")] = 1e-5
    P = pr.forward_params(X)
    a = P[:, pr.forward.param_names.index("a")]
    np.testing.assert_allclose(a * pr.eta_per_a(X[:, names.index("b")]), X[:, names.index("eta")],
                               rtol=1e-13)
    np.testing.assert_allclose(pr.derived(X)["a"], a, rtol=0)


def test_sh_first_mode_damping_is_set_by_eta_alone():
    # The point of the parameterisation: at fixed eta the SH damping ratio of mode 1 is
    # eta ω1 / (2 E I) whatever b is (uniform beam, no other damping).
    from bayesbeam.physics.forward import modal_properties

    beam = _beam(E=E_TRUE)
    tr = simulate_trial(beam, "viscous", {"gamma": 0.0}, duration=0.1, dt=1 / 256,
                        n_elements=8)
    pr = Problem(tr, "sh", n_elements=8)
    eta = 2 * E_TRUE * beam.I * 0.01 / _w1(beam)  # ζ1 = 1 %
    zetas = []
    for b in (1e-3, 0.03, 0.3):
        a = eta / pr.eta_per_a([b])[0]
        _, z = modal_properties(beam, "sh", {"a": a, "b": b}, n_elements=8)
        zetas.append(z[0])
    # Light damping: modal ζ from the complex eigenvalue equals the Rayleigh quotient
    # ratio to O(ζ²) = 1e-4 relative.
    np.testing.assert_allclose(zetas, 0.01, rtol=2e-3)


@pytest.mark.parametrize("quantity", ["displacement", "velocity", "acceleration"])
@pytest.mark.parametrize("nominal_E", [True, False])
def test_default_priors_contain_typical_truths_and_are_proper(quantity, nominal_E):
    beam = _beam(E=E_TRUE, quantity=quantity)
    w1 = _w1(beam)
    truth = {
        "E": E_TRUE,
        "gamma": 2 * beam.rhoA * w1 * 0.01,  # ζ1 = 1 % viscous (physics.md §2)
        "c_d": 2 * E_TRUE * 0.005 / w1,  # ζ1 = 0.5 % Kelvin–Voigt
        "b": 0.01,
        "w0": 0.005,
        "sigma": {"displacement": 1e-5, "velocity": 1e-3, "acceleration": 0.1}[quantity],
    }
    a = 4 * E_TRUE * beam.I * 0.005 / (w1 * truth["b"] ** 2)
    tr = simulate_trial(beam, "viscous+kv+sh", {k: truth[k] for k in ("gamma", "c_d", "b")}
                        | {"a": a}, duration=2.0, dt=1 / 256, noise_sd=truth["sigma"],
                        seed=1, n_elements=8)
    if not nominal_E:  # E_ref then comes from the data's first spectral peak
        tr = Trial(times=tr.times, values=tr.values, quantity=quantity,
                   beam=_beam(quantity=quantity))
        # 2 s record, interpolated peak: the first frequency within ~0.5 % -> E within 1 %
        assert reference_modulus(tr, n_elements=8) == pytest.approx(E_TRUE, rel=0.01)
    pr = Problem(tr, "viscous+kv+sh", n_elements=8)
    truth["eta"] = a * pr.eta_per_a([truth["b"]])[0]
    pri = default_priors(tr, "viscous+kv+sh", n_elements=8)
    assert pri == pr.priors
    for name, x in truth.items():
        lo, hi = pri[name].bounds
        assert lo < x < hi, (name, lo, x, hi)
        # not squeezed against a bound: at least a factor 3 (0.5 in u) inside on the log scale
        if isinstance(pri[name], LogUniform):
            assert math.log(x / lo) > 1 and math.log(hi / x) > 1, name
    for name in pri.names:
        p = pri[name]
        lo_u, hi_u = p.bounds_u
        if isinstance(p, (LogUniform, Uniform)):
            assert math.isfinite(lo_u) and math.isfinite(hi_u), name
            mass = integrate.quad(lambda u, p=p: math.exp(p.log_pdf_u(u)), lo_u, hi_u)[0]
        else:
            mass = integrate.quad(lambda u, p=p: math.exp(p.log_pdf_u(u)), -np.inf, np.inf)[0]
        assert mass == pytest.approx(1.0, rel=1e-6), name  # proper, normalised in u


@pytest.mark.parametrize("quantity, sensor", [("displacement", None), ("acceleration", None),
                                              ("acceleration", 0.8)])
def test_drag_friction_priors_span_their_stated_zeta_range_at_the_true_amplitude(quantity,
                                                                                 sensor):
    # The drag/friction priors are stated as ζ1 in [1e-7, 0.05] at the record's mode-1
    # amplitude. On a release from w0 the mode-1 tip amplitude is w0 up to the static
    # shape's mode-1 participation (> 0.97 on a cantilever), whatever the signal's
    # peak: an acceleration release's first sample is dominated by the higher modes.
    # Tolerance: the measured amplitude (band-pass envelope, extrapolated over the
    # trimmed start) is within 20 %, so the ζ ends within a factor 1.25.
    from bayesbeam.physics.nonlinear import nonlinear_damping_scales

    # sensor: position as a fraction of the span (None: tip); the stated amplitude is the
    # tip's, so a sensor inboard (mode-1 shape ~0.6 of the tip's at 0.8 L) must be scaled.
    beam = _beam(E=E_TRUE, quantity=quantity)
    if sensor is not None:
        beam = beam.replace(sensor_position=sensor * beam.length)
    w0 = 0.01
    # Kelvin–Voigt damping as on a real strip: with viscous damping alone the 8-element
    # model's undamped top modes alias at 256 Hz into peaks larger than mode 1's, which
    # a real (anti-alias filtered) record does not have.
    w1 = _w1(beam)
    tr = simulate_trial(beam, "viscous+kv", {"gamma": 2 * beam.rhoA * w1 * 0.003,
                                             "c_d": 2 * E_TRUE * 0.002 / w1},
                        duration=2.0, dt=1 / 256, tip_deflection=w0, noise_sd=1e-6, seed=3,
                        n_elements=8)
    if sensor is None:  # at the tip, the peak would mislead
        assert np.max(np.abs(tr.values)) / _w1(beam) ** (2 if quantity == "acceleration" else 0) \
            > (1.5 * w0 if quantity == "acceleration" else 0.99 * w0)
    pri = default_priors(tr, "viscous+kv+drag+friction", n_elements=8, initial="release")
    k_drag, k_fric = nonlinear_damping_scales(beam, E_TRUE, w0, n_elements=8)
    for name, k in (("drag", k_drag), ("friction", k_fric)):
        lo, hi = pri[name].bounds
        assert k * lo == pytest.approx(1e-7, rel=0.25), name
        assert k * hi == pytest.approx(0.05, rel=0.25), name
    # Each prior is present only when its part is in the model, and the same alone.
    for name in ("drag", "friction"):
        alone = default_priors(tr, f"viscous+kv+{name}", n_elements=8, initial="release")
        other = ({"drag", "friction"} - {name}).pop()
        assert other not in alone.names and alone[name].bounds == pri[name].bounds
