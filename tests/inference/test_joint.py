"""JointProblem: names, parameter maps, the marginal likelihood and the pooled coordinates."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from bayesbeam.inference.joint import JointError, JointProblem, PoolCoordinates, trial_labels
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.stats.likelihood import ar1_loglik, iid_loglik
from bayesbeam.trials.synthetic import simulate_trial

E_TRUE = 6.2e10
NE = 6  # the checks compare the joint problem with single problems on the same mesh


def _beam(length=0.3048):
    return Beam.rectangular(length, 0.127, 0.72e-3, 0.021, E=E_TRUE)


@pytest.fixture(scope="module")
def trials():
    # Generated on a finer mesh than the problems use (no inverse crime in what follows).
    return [simulate_trial(_beam(L), "viscous", {"gamma": g}, duration=0.5, dt=1 / 256,
                           tip_deflection=d, noise_sd=1e-5, seed=i, n_elements=12,
                           name=f"t{i}")
            for i, (L, g, d) in enumerate([(0.3048, 0.2, 0.005), (0.28, 0.25, 0.006),
                                           (0.3048, 0.18, 0.004)])]


def test_names_shared_pooled_per_trial(trials):
    jp = JointProblem(trials, "viscous", shared=("E",), pooled=("gamma",), n_elements=NE)
    assert jp.names == ("E", "gamma_median", "gamma_spread", "gamma_z[t0]", "gamma_z[t1]",
                        "gamma_z[t2]")
    assert jp.marginalised == ("sigma", "w0")
    jq = JointProblem(trials, "viscous", shared=("E",), marginalise=False, n_elements=NE)
    assert jq.names == ("E", "gamma[t0]", "w0[t0]", "sigma[t0]", "gamma[t1]", "w0[t1]",
                        "sigma[t1]", "gamma[t2]", "w0[t2]", "sigma[t2]")
    # Different lengths centre the trials' E priors differently... here beam.E is given,
    # so all are the same; the shared prior is that prior.
    assert jq.priors["E"] == jq.problems[0].priors["E"]


def test_prior_overrides_apply_to_every_trial(trials):
    from bayesbeam.stats.families import LogUniform

    narrow = LogUniform(5e10, 8e10)
    jp = JointProblem(trials, "viscous", shared=("E",), pooled=("gamma",), n_elements=NE,
                      priors={"E": narrow, "gamma": {"dist": "loguniform", "lo": 0.01,
                                                     "hi": 1.0}})
    assert jp.priors["E"] == narrow
    assert all(pb.priors["E"] == narrow for pb in jp.problems)
    assert jp.priors["gamma_median"] == LogUniform(0.01, 1.0)
    assert jp.overrides.keys() == {"E", "gamma"}
    default = JointProblem(trials, "viscous", shared=("E",), n_elements=NE)
    assert default.priors["E"] != narrow
    with pytest.raises(ValueError, match="does not have"):
        JointProblem(trials, "viscous", shared=("E",), n_elements=NE, priors={"c_d": narrow})


def test_added_mass_shared_by_its_distance_from_the_tip(trials):
    # t0 and t2 are 0.3048 m long, t1 0.28 m: one distance from the free end d puts the
    # mass at L_i - d from each clamp.
    from bayesbeam.inference.joint import TIP_DISTANCE

    jp = JointProblem(trials, "viscous+added_mass", n_elements=NE,
                      shared=("E", "added_mass", TIP_DISTANCE))
    assert TIP_DISTANCE in jp.names
    assert not any(n.startswith("added_mass_position") for n in jp.names)
    # Uniform(0, L_i) on each position: d in [0, min L_i].
    assert (jp.priors[TIP_DISTANCE].lo, jp.priors[TIP_DISTANCE].hi) == (0.0, 0.28)
    x = np.zeros((1, jp.ndim))
    x[0, jp.names.index(TIP_DISTANCE)] = 0.06
    for i, length in enumerate((0.3048, 0.28, 0.3048)):
        col = jp.problems[i].names.index("added_mass_position")
        assert jp.trial_theta(x, i)[0, col] == pytest.approx(length - 0.06, abs=1e-15)
    per = []
    for pb in jp.problems:
        v = np.full(pb.ndim, 0.5)
        v[pb.names.index("added_mass_position")] = float(pb.trial.beam.length) - 0.05
        per.append(v)
    assert jp.joint_theta(per)[jp.names.index(TIP_DISTANCE)] == pytest.approx(0.05)
    # The joint likelihood is the sum of the single problems' at positions L_i - d
    # (marginalise=False: every column sampled, each Problem evaluated on its own).
    jq = JointProblem(trials, "viscous+added_mass", n_elements=NE, marginalise=False,
                      shared=("E", "added_mass", TIP_DISTANCE))
    rng = np.random.default_rng(1)
    X = np.empty((4, jq.ndim))
    for j, n in enumerate(jq.names):
        X[:, j] = {"E": E_TRUE, "added_mass": 2e-3, TIP_DISTANCE: 0.06}.get(
            n.split("[")[0], np.nan)
    for i, (g, w) in enumerate([(0.2, 0.005), (0.25, 0.006), (0.18, 0.004)]):
        for n, v in (("gamma", g), ("w0", w), ("sigma", 1e-5)):
            X[:, jq.names.index(f"{n}[t{i}]")] = v
    X[:, jq.names.index(TIP_DISTANCE)] = rng.uniform(0.02, 0.2, 4)
    U = jq.priors.to_u(X)
    X = jq.theta(U)  # the values the joint problem sees (the u round trip moves an ulp)
    total = np.zeros(4)
    for i, pb in enumerate(jq.problems):
        own = np.array([[{"E": E_TRUE, "added_mass": 2e-3}.get(n, np.nan) for n in pb.names]
                        for _ in range(4)])
        for n in ("gamma", "w0", "sigma"):
            own[:, pb.names.index(n)] = X[:, jq.names.index(f"{n}[t{i}]")]
        own[:, pb.names.index("added_mass_position")] = (
            float(pb.trial.beam.length) - X[:, jq.names.index(TIP_DISTANCE)])
        total += pb.log_likelihood_theta(own)
    # Tolerance: an added mass couples the modes, so the band reduction iterates to 1e-12
    # relative (sensor.TOLERANCE) and the two paths' signals agree to that; with these
    # residuals far above the noise, |Δll| / |ll| ~ 2e-12 |y| / |r| stays below 1e-10. A
    # wrong position map (d for L - d) moves the sum by orders of magnitude more.
    np.testing.assert_allclose(jq.log_likelihood(U), total, rtol=1e-9)
    with pytest.raises(JointError, match="not both"):
        JointProblem(trials, "viscous+added_mass", n_elements=NE,
                     shared=("added_mass_position", TIP_DISTANCE))
    with pytest.raises(JointError, match="needs a model with added_mass"):
        JointProblem(trials, "viscous", n_elements=NE, shared=(TIP_DISTANCE,))
    with pytest.raises(JointError, match="no common distance"):
        JointProblem(trials, "viscous+added_mass", n_elements=NE, shared=(TIP_DISTANCE,),
                     priors={"added_mass_position": {"dist": "uniform", "lo": 0.0,
                                                     "hi": 0.01}})


def test_labels_unique():
    class T:
        def __init__(self, name):
            self.name = name
    assert trial_labels([T("a"), T("a"), T("b")]) == ("a", "a#2", "b")


def test_trial_theta_round_trip(trials):
    jp = JointProblem(trials, "viscous", shared=("E",), pooled=("gamma",), n_elements=NE)
    per = [np.array([E_TRUE, g, 0.005, 1e-5]) for g in (0.2, 0.25, 0.18)]
    x = jp.joint_theta(per)
    for i, p in enumerate(per):
        xi = jp.trial_theta(x[None], i)[0]
        np.testing.assert_allclose(xi[:2], p[:2], rtol=1e-12)
        assert np.all(np.isnan(xi[2:]))  # marginalised columns


def test_no_marginalise_is_sum_of_single_problems(trials):
    jq = JointProblem(trials, "viscous", shared=("E",), marginalise=False, n_elements=NE)
    rng = np.random.default_rng(0)
    per = [np.array([E_TRUE * (1 + 1e-3 * rng.standard_normal()), 0.2, 0.005, 1.2e-5])
           for _ in trials]
    for p in per:
        p[0] = per[0][0]  # one shared E
    x = jq.joint_theta(per)
    ll = jq.log_likelihood(jq.priors.to_u(x[None]))[0]
    want = sum(pb.log_likelihood_theta(p[None])[0] for pb, p in zip(jq.problems, per,
                                                                      strict=True))
    # The same residuals through two code paths: rounding only (1e-12 of |ll| ~ 1e4).
    assert ll == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize("model", ["viscous", "viscous+ar1_noise"])
def test_marginal_matches_numerical_integration(trials, model):
    """The closed-form marginal over sigma and w0 of one trial against 2-D quadrature.

    The integrand is the single Problem's own likelihood, evaluated through the linearity
    of the signal in w0 (checked here first to 1e-9); the quadrature covers the whole
    posterior mass of (w0, log sigma), and the tolerance 1e-6 of the likelihood is the
    issue's (quad's own error is ~1e-10 here).
    """
    tr = trials[1]
    jp = JointProblem([tr], model, shared=(), n_elements=NE)
    pb = Problem(tr, model, n_elements=NE)
    E, gamma, rho = E_TRUE * 1.0005, 0.24, 0.35
    extra = [rho] if "ar1" in model else []

    def loglik(r, s):
        return ar1_loglik(r, s, rho) if extra else iid_loglik(r, s)

    b = pb.predict(np.array([[E, gamma, 1.0, 1.0, *extra]])).y[0]
    assert pb.log_likelihood_theta(np.array([[E, gamma, 0.0061, 1.3e-5, *extra]]))[0] == (
        pytest.approx(loglik(tr.values - 0.0061 * b, 1.3e-5), rel=1e-9))
    got = jp.log_likelihood(jp.priors.to_u(np.array([[E, gamma, *extra]])))[0]
    y = np.asarray(tr.values)
    ps, pw = pb.priors["sigma"], pb.priors["w0"]
    w_hat = float(b @ y / (b @ b))
    s_hat = float(np.sqrt(np.sum((y - w_hat * b) ** 2) / y.size))
    sd_w = 3 * s_hat / math.sqrt(b @ b)  # x3: AR(1) noise widens the amplitude's posterior
    # The Gaussian log-likelihood is K - T log s - q(w) / (2 s²) with q quadratic in w:
    # read K and q off four evaluations of the likelihood itself, so that quad's ~1e6
    # integrand calls cost O(1) (checked against the likelihood at another point).
    # Evaluations at the data's own scales (w near w_hat, s = s_hat, 2 s_hat) keep the
    # differences well conditioned.
    T, sa = y.size, s_hat
    ws = np.array([0.5, 1.0, 1.5]) * w_hat
    la = np.array([loglik(y - w * b, sa) for w in ws])
    lb = loglik(y - ws[0] * b, 2 * sa)
    qa0 = (T * math.log(2.0) - (la[0] - lb)) * 8.0 / 3.0  # q(ws[0]) / sa²
    K = la[0] + T * math.log(sa) + qa0 / 2
    coef = np.polyfit(ws, 2 * (K - T * math.log(sa) - la), 2)  # q(w) / sa², exact at 3 points

    def ll(w, s):
        return K - T * math.log(s) - np.polyval(coef, w) * sa * sa / (2 * s * s)

    assert ll(0.0061, 1.3e-5) == pytest.approx(loglik(y - 0.0061 * b, 1.3e-5), rel=1e-9)
    shift = ll(w_hat, s_hat)  # scale the integrand near 1

    def f(log_s, w):
        return math.exp(ll(w, math.exp(log_s)) - shift) / math.log(ps.hi / ps.lo)

    val, err = integrate.dblquad(
        f, w_hat - 12 * sd_w, w_hat + 12 * sd_w,
        math.log(max(ps.lo, s_hat / 3)), math.log(min(ps.hi, s_hat * 3)),
        epsabs=0, epsrel=1e-11)
    want = math.log(val) + shift - math.log(pw.hi - pw.lo)
    assert abs(got - want) < 1e-6, (got, want, err / val)


def test_complete_draws_are_near_the_truth(trials):
    jp = JointProblem(trials[:1], "viscous", shared=(), n_elements=NE)
    U = np.repeat(jp.priors.to_u(np.array([[E_TRUE, 0.2]])), 2000, axis=0)
    X = jp.complete(U, np.random.default_rng(3))[0]
    sigma, w0 = X[:, 3], X[:, 2]
    # 128 samples: sigma's posterior sd is ~ sigma/sqrt(2 T) = 6 % of it; the mesh (6 vs
    # 12 elements) and the draws' scatter stay inside 25 %.
    assert np.median(sigma) == pytest.approx(1e-5, rel=0.25)
    assert np.median(w0) == pytest.approx(0.005, rel=0.02)
    again = jp.complete(U, np.random.default_rng(3))[0]
    np.testing.assert_array_equal(X, again)


def _fd_log_det(to_u, v, h=1e-6):
    """log |det ∂u/∂v| at ``v`` by central differences of ``to_u``."""
    J = np.empty((v.size, v.size))
    for j in range(v.size):
        e = np.zeros(v.size)
        e[j] = h
        J[:, j] = (to_u(v + e) - to_u(v - e)) / (2 * h)
    return np.linalg.slogdet(J)[1]


def test_pool_coordinates_round_trip_and_jacobian(trials):
    jp = JointProblem(trials, "viscous", shared=("E",), pooled=("gamma",), n_elements=NE)
    pc = PoolCoordinates(jp)
    rng = np.random.default_rng(1)
    U = jp.priors.sample_u(rng, 5)
    np.testing.assert_allclose(pc.to_u(pc.to_v(U)), U, rtol=1e-12, atol=1e-12)
    # log |du/dv| by finite differences of to_u at one point.
    v = pc.to_v(U[:1])[0]
    assert pc.log_jacobian(v) == pytest.approx(_fd_log_det(pc.to_u, v), abs=1e-6)


@pytest.mark.parametrize("kw, match", [
    ({"shared": ("nope",)}, "not parameters of model"),
    ({"shared": ("E",), "pooled": ("E",)}, "both shared and pooled"),
    ({"shared": ("sigma",), "marginalise": True}, "cannot be integrated out"),
    ({"shared": (), "pooled": ("w0",), "marginalise": False}, "prior on log"),
])
def test_bad_names_say_how_to_fix(trials, kw, match):
    with pytest.raises(JointError, match=match):
        JointProblem(trials, "viscous", n_elements=NE, **kw)


def test_no_trials_is_an_error():
    with pytest.raises(JointError, match="at least one trial"):
        JointProblem([], "viscous")


def test_sampler_coordinates_of_a_joint_fit_round_trip_and_jacobian(trials):
    """Centred pooled values, then every trial's damping-law coordinates (on per-trial
    and pooled laws alike): bijection, Jacobian by finite differences."""
    from bayesbeam.inference.joint_fit import _Coordinates

    jp = JointProblem(trials, "viscous+kv", shared=("E",), pooled=("c_d",), n_elements=NE)
    co = _Coordinates(jp)
    jq = JointProblem(trials, "viscous+kv", shared=("E",), n_elements=NE)
    cq = _Coordinates(jq)
    jr = JointProblem(trials, "viscous+kv", shared=("E",), pooled=("gamma", "c_d"),
                      n_elements=NE)
    cr = _Coordinates(jr)
    for c in (co, cq, cr):
        assert len(c.laws) == len(trials)
    # Pooled laws: the maps act on the z columns (which hold log x after the pool map).
    assert list(cr.laws[0].group) == [jr.names.index("gamma_z[t0]"),
                                      jr.names.index("c_d_z[t0]")]
    for c, p in ((co, jp), (cq, jq), (cr, jr)):
        U = p.priors.sample_u(np.random.default_rng(2), 4)
        np.testing.assert_allclose(c.to_u(c.to_v(U)), U, rtol=1e-10, atol=1e-10)
        v = c.to_v(U[:1])[0]
        assert c.log_jacobian(v) == pytest.approx(_fd_log_det(c.to_u, v), abs=1e-5)


@pytest.mark.parametrize("model", ["viscous+drag", "viscous+friction"])
def test_amplitude_dependent_model_is_not_marginalised(trials, model):
    # The closed-form marginal integrates a signal linear in the amplitudes; drag and
    # friction are not. Refused when asked for, sampled by default (the sum of the single
    # problems), and the reason is said.
    with pytest.raises(JointError, match="--no-marginalise"):
        JointProblem(trials, model, shared=("E",), marginalise=True, n_elements=NE)
    jq = JointProblem(trials, model, shared=("E",), n_elements=NE)
    assert not jq.marginalise and jq.marginalised == ()
    assert "amplitude-dependent" in jq.marginal_note
    assert any(n.startswith("sigma[") for n in jq.names)


def test_marginalise_default_is_exact_where_it_can_be(trials):
    # Linear model: integrated out by default; sigma shared: sampled by default (an
    # obstacle, not an error), and an explicit False is said as such.
    jp = JointProblem(trials, "viscous", shared=("E",), n_elements=NE)
    assert jp.marginalise and "integrated out" in jp.marginal_note
    js = JointProblem(trials, "viscous", shared=("E", "sigma"), n_elements=NE)
    assert not js.marginalise and "sigma" in js.names
    assert "shared" in js.marginal_note
    jf = JointProblem(trials, "viscous", shared=("E",), marginalise=False, n_elements=NE)
    assert jf.marginal_note.endswith("(marginalise=False)")


def test_trials_with_their_own_initial_kinds(trials):
    # Records of different length resolve different numbers of modes: each trial keeps
    # its own free amplitudes. With E shared, the joint marginal likelihood is the sum of
    # each trial's own (a one-trial JointProblem with that trial's kind) at the same E; a
    # column map that mixed up the trials' amplitude columns would not give it.
    kinds = ["modes:1", "modes:2", "release"]
    jp = JointProblem(trials, "viscous", shared=("E",), n_elements=NE, initial=kinds)
    assert jp.initial == tuple(kinds)
    from bayesbeam.inference.problem import amplitude_names

    assert [len(amplitude_names(pb.names)) for pb in jp.problems] == [2, 4, 1]
    assert not any(n.startswith(("A_", "B_", "w0")) for n in jp.names)  # integrated out
    X = np.empty((3, jp.ndim))
    X[:, jp.names.index("E")] = E_TRUE * np.array([0.999, 1.0, 1.001])
    for i, g in enumerate((0.2, 0.25, 0.18)):
        X[:, jp.names.index(f"gamma[t{i}]")] = g * np.array([0.9, 1.0, 1.1])
    U = jp.priors.to_u(X)
    X = jp.theta(U)
    total = np.zeros(3)
    for i, (tr, kind) in enumerate(zip(trials, kinds, strict=True)):
        one = JointProblem([tr], "viscous", shared=(), n_elements=NE, initial=kind)
        x1 = np.column_stack([X[:, jp.names.index("E")], X[:, jp.names.index(f"gamma[t{i}]")]])
        assert one.names == (f"E[t{i}]", f"gamma[t{i}]")
        total += one.log_likelihood(one.priors.to_u(x1))
    # Same arithmetic on the same arrays, summed in another order: rounding only.
    np.testing.assert_allclose(jp.log_likelihood(U), total, rtol=1e-12)
    # Completed draws hold each trial's own amplitudes, finite.
    done = jp.complete(U, np.random.default_rng(0))
    assert [d.shape[1] for d in done] == [pb.ndim for pb in jp.problems]
    assert all(np.all(np.isfinite(d)) for d in done)
    with pytest.raises(JointError, match="one per trial"):
        JointProblem(trials, "viscous", n_elements=NE, initial=kinds[:2])


def test_clamp_coordinates_in_a_joint_fit(trials):
    """E and the clamp spring, both shared or both per trial, move as log ω1² and log k
    (one map per pair); a pair split between shared and per trial stays in u."""
    from bayesbeam.inference.joint_fit import _Coordinates

    same = [trials[0], trials[2]]  # one beam: the shared spring's priors agree
    js = JointProblem(same, "viscous+kv+root_spring", shared=("E", "root_spring"),
                      n_elements=NE)
    jt = JointProblem(same, "viscous+kv+root_spring", shared=(), n_elements=NE)
    jm = JointProblem(same, "viscous+kv+root_spring", shared=("E",), n_elements=NE)
    cs, ct, cm = _Coordinates(js), _Coordinates(jt), _Coordinates(jm)
    assert [(c.iE, c.ik) for c in cs.clamps] == [(js.names.index("E"),
                                                  js.names.index("root_spring"))]
    assert len(ct.clamps) == 2 and not cm.clamps
    # Each trial's laws take their scales at its pair's E and ω1 (only with a map).
    assert [m.coupled for m in cs.laws] == [cs.clamps[0]] * 2
    assert [m.coupled.iE for m in ct.laws] == [jt.names.index(f"E[{lb}]") for lb in jt.labels]
    assert [m.coupled for m in cm.laws] == [None, None]
    assert "clamp spring" in cs.describe()
    for c, p in ((cs, js), (ct, jt)):
        U = p.priors.sample_u(np.random.default_rng(4), 6)
        np.testing.assert_allclose(c.to_u(c.to_v(U)), U, rtol=0, atol=1e-10)
        for v in c.to_v(U[:2]):
            assert c.log_jacobian(v) == pytest.approx(_fd_log_det(c.to_u, v), abs=1e-5)
