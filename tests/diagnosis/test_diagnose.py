"""Hide an effect in a synthetic trial and require diagnose() to name it.

Beam: the 0.4 m aluminium strip of the issue (25 x 2 mm, E = 70 GPa, f1 = 10.28 Hz).
No inverse crime: the records come from 32 Hermite elements; the diagnosis starts from 8
(f1..f3 within 2e-3 of 16 elements) and refines its mesh at the MAP, before the first
round and again after every named round. Damping of the base trials: viscous ζ1 = 0.3 %
and Kelvin–Voigt ζ1 = 0.08 % (physics.md §2). Noise: 1 % of the signal's RMS, i.i.d.
Gaussian unless stated.

Signals. Displacement trials are taps (tip impulse, ``initial='impulse'``): the modal
amplitudes then fall as 1/ω_n instead of 1/ω_n² for a release, so the third mode is
visible, which is what separates a broad-kernel SH from viscous + KV (two decay rates
are matched by two coefficients) and a root spring from a stiffness gradient (they
differ in f3/f1). Acceleration trials are releases from a 1 cm tip deflection (the
higher modes dominate an acceleration record anyway). 1 s at 512 Hz, except the
drag and friction trials (3 s at 256 Hz: the amplitude must fall enough to show their
effect on the decay rate).

Hidden-effect sizes (the smallest round numbers at which the data separate each cause
from every other candidate, as each test checks):

======================  =====================================================
cause                   size
======================  =====================================================
kv                      KV with ζ1 = 0.08 % on a viscous beam (baseline viscous)
sh                      broad kernel b = L, ζ1 = 0.2 % (baseline viscous)
tip_mass                5 % of the beam mass
added_mass              5 % of the beam mass at 0.85 L (its own test: data from 64
                        elements with the mass declared in the beam, fitted from 16
                        with mesh refinement)
root_spring             f1 -3 % (acceleration); f1 -10 % (displacement: at -3 % a
                        tap record cannot separate it from a stiffness gradient,
                        Δ log Z ≈ 2.3 < 3)
stiffness_gradient      EI ±20 % along the span (falling toward the tip, g = -0.4)
drag                    quadratic drag with ζ_drag = 0.6 % at a 1 cm tip amplitude
                        (the decay rate starts ~2.6x its small-amplitude value)
friction                dry clamp friction with ζ_friction = 0.3 % at a 1 cm tip
                        amplitude (F = 2.7 mN; its ζ grows as the amplitude falls,
                        the decay rate starts ~0.25x its small-amplitude value; at
                        0.6 % friction stops mode 1 2 s into the record and the
                        decay-rate signature is no longer measurable)
amplitude_stiffness     f1 1 % lower at the initial mode-1 tip amplitude (softening,
                        linear in amplitude); the record from a direct integration of
                        the first mode's nonlinear oscillator (the beam is classically
                        damped, so mode 1 decouples), not from the slow flow
sensor_quadratic        a sensor reading y + k2 y², the quadratic term 2 % of the
                        signal's peak (the linear signal from 32 elements, then squared)
ar1_noise               AR(1) noise with rho = 0.8
sensor_offset           offset of 5 % of the amplitude (sqrt(2) x RMS)
======================  =====================================================

A KV cause may list ``sh`` as equivalent: a narrow-kernel SH is exactly KV
(physics.md §2), so the data can never exclude it.
"""

import argparse
import json
import math

import numpy as np
import pytest
import scipy.optimize as sopt

from bayesbeam.cli.diagnose import register
from bayesbeam.diagnosis.diagnose import CATALOGUE, diagnose
from bayesbeam.diagnosis.search import DiagnoseError
from bayesbeam.inference.problem import BETA1
from bayesbeam.physics.beam import Beam
from bayesbeam.stats.likelihood import stationary_ar1
from bayesbeam.trials.io import write_trial
from bayesbeam.trials.synthetic import simulate_signal
from bayesbeam.trials.trial import BANDWIDTH_PER_RATE, Trial

L, WIDTH, THICK, RHO, E = 0.4, 0.025, 0.002, 2700.0, 70e9
BEAM = Beam.rectangular(L, WIDTH, THICK, RHO * L * WIDTH * THICK, E=E)
EI = E * BEAM.I
W1 = BETA1**2 * np.sqrt(EI / (BEAM.rhoA * L**4))  # rad/s, physics.md §4
GAMMA = 2 * BEAM.rhoA * W1 * 0.003  # viscous ζ1 = gamma / (2 rhoA ω1)
CD = 2 * E * 0.0008 / W1  # KV ζ1 = c_d ω1 / (2 E)
N_EL = 8
# No inverse crime: the records come from a 4x finer mesh than the fits' start, and the
# diagnosis refines its own mesh until the MAP no longer moves with it (mesh.py).
N_DATA = 32
# Cheap but adequate sampler budget for the confirmations (see diagnose's docstring).
BUDGET = dict(n_elements=N_EL, refine_mesh=True, nwalkers=24, target_ess=200.0, min_steps=200,
              max_steps=400, confirm_top=2, loo_draws=300, signatures=False)


@pytest.fixture(autouse=True, scope="module")
def _one_blas_thread():
    # Small batched matrices: OpenBLAS threads cost more than they give (4-7x slower on
    # 2 cores); limit them when threadpoolctl is available.
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        yield
        return
    with threadpool_limits(1):
        yield


def _frequency_equation(x, mu):
    # physics.md §3: tip mass μ; a root spring κ is the same equation with μ = 1/κ.
    return 1 + np.cos(x) * np.cosh(x) + mu * x * (np.cos(x) * np.sinh(x) - np.sin(x) * np.cosh(x))


def root_spring_for(f1_drop):
    """Clamp stiffness k (N m/rad) that lowers f1 by ``f1_drop`` (fraction)."""
    target = BETA1 * np.sqrt(1 - f1_drop)  # ω ∝ (βL)²

    def miss(log_kappa):
        b = sopt.brentq(_frequency_equation, 0.5, BETA1 + 1e-9, args=(np.exp(-log_kappa),))
        return b - target

    kappa = np.exp(sopt.brentq(miss, np.log(0.5), np.log(1e5)))
    return kappa * EI / L


def sh_params(zeta1=0.002, b=L):
    k1 = BETA1 / L
    eta = 2 * EI * zeta1 / W1  # problem.py: eta = c_d I equivalent, ζ1 = eta ω1 / (2 E I)
    return {"a": eta * k1**2 / (-np.expm1(-0.5 * (k1 * b) ** 2)), "b": b}


def _excitation(quantity):
    return ("impulse", {"p0": 8e-3}) if quantity == "displacement" else ("release", {"w0": 0.01})


def make_trial(model, params, quantity, *, seed=0, duration=1.0, fs=512.0, rho=None,
               offset=0.0, quadratic=0.0):
    """Noisy synthetic trial from the package's simulator (see the module docstring).

    ``quadratic``: the signal read through a sensor ``y + k2 y²`` whose quadratic term
    is that fraction of the signal's peak.
    """
    initial, ic = _excitation(quantity)
    t = np.arange(int(round(duration * fs))) / fs
    beam = BEAM.replace(quantity=quantity)
    if "drag" in model or "friction" in model:
        from bayesbeam.physics.nonlinear import NonlinearForward

        fwd = NonlinearForward(beam, model, t, n_elements=N_DATA, initial=initial,
                               bandwidth=BANDWIDTH_PER_RATE * fs)  # the trial's default band
        p = {"E": E, **params, **ic}
        res = fwd.simulate({k: np.array([p[k]]) for k in fwd.param_names})
        assert res.valid[0]
        y = res.y[0]
    else:
        y = simulate_signal(beam, model, {**params, **ic}, t, n_elements=N_DATA, initial=initial)
    y = y + quadratic / np.abs(y).max() * y**2
    rms = np.sqrt(np.mean(y**2))
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(t.size)
    if rho is not None:  # stationary AR(1) with unit marginal variance
        z = stationary_ar1(z, rho)
    y = y + 0.01 * rms * z + offset * np.sqrt(2) * rms
    trial = Trial(times=t, values=y, quantity=quantity, beam=beam, name=f"{model}-{quantity}")
    return trial, initial


BASE = {"gamma": GAMMA, "c_d": CD}


def softening_trial(quantity, *, shift=-0.01, duration=3.0, fs=256.0, seed=0):
    """Trial whose f1 is ``shift`` (relative) off at the initial mode-1 amplitude.

    Not from the slow flow that the diagnosis fits: the uniform beam with viscous + KV
    damping is classically damped (D = gamma G + c_d KV with G = M / rhoA, KV = K / E),
    so its first mode is an oscillator of its own. That oscillator, with the restoring
    force -k_a |q1| q1 added, is integrated directly (LSODA, rtol 1e-11); the record is
    the linear beam (package forward model, the trial's band) plus the nonlinear minus
    the linear first mode at the sensor. Harmonic balance: f1_slope = 2 k_a / (3 π² |s1|
    ω1) Hz per m of tip amplitude (physics.nonlinear).
    """
    import scipy.linalg as sla
    from scipy.integrate import solve_ivp

    from bayesbeam.physics.fem import assemble
    from bayesbeam.physics.forward import Forward

    initial, ic = _excitation(quantity)
    t = np.arange(int(round(duration * fs))) / fs
    beam = BEAM.replace(quantity=quantity)
    lin = Forward(beam, "viscous+kv", t, n_elements=N_DATA, initial=initial,
                  bandwidth=BANDWIDTH_PER_RATE * fs)
    y = lin.simulate({"E": E, **BASE, **ic}).y[0]
    fe = assemble(beam, N_DATA, root_dof=False)
    M, K = np.asarray(fe.M), E * np.asarray(fe.K)
    D = BASE["gamma"] * np.asarray(fe.G) + BASE["c_d"] * np.asarray(fe.KV)
    w2, Phi = sla.eigh(K, M)
    phi = Phi[:, 0]
    w1, two_zw = np.sqrt(w2[0]), float(phi @ D @ phi)
    tip = np.asarray(fe.tip)
    s1, s_sensor = abs(tip @ phi), float(tip @ phi)  # the sensor is at the tip
    if initial == "release":
        u = np.linalg.solve(K, tip)
        q0, v0 = float(phi @ M @ (ic["w0"] * u / (tip @ u))), 0.0
    else:  # a tip impulse p0: velocity M^-1 tip p0, so q1' = φ1·tip p0
        q0, v0 = 0.0, float(phi @ tip) * ic["p0"]
    amp_tip = s1 * np.hypot(q0, v0 / w1)
    slope = shift * (w1 / (2 * np.pi)) / amp_tip
    k_a = slope * 3 * np.pi**2 * s1 * w1 / 2

    def rhs(_, z, k):
        return [z[1], -two_zw * z[1] - w2[0] * z[0] - k * abs(z[0]) * z[0]]

    def mode1(k):
        sol = solve_ivp(rhs, (0.0, t[-1]), [q0, v0], args=(k,), method="LSODA", t_eval=t,
                        rtol=1e-11, atol=1e-14 * max(abs(q0), abs(v0) / w1))
        assert sol.success, sol.message
        q, v = sol.y
        acc = -two_zw * v - w2[0] * q - k * np.abs(q) * q
        return {"displacement": q, "acceleration": acc}[quantity]

    y = y + s_sensor * (mode1(k_a) - mode1(0.0))
    rms = np.sqrt(np.mean(y**2))
    y = y + 0.01 * rms * np.random.default_rng(seed).standard_normal(t.size)
    trial = Trial(times=t, values=y, quantity=quantity, beam=beam,
                  name=f"softening-{quantity}", meta={"f1_slope_hz_per_m": slope})
    return trial, initial


def case(cause, quantity):
    """(trial, initial, baseline) with ``cause`` hidden."""
    if cause == "kv":
        return (*make_trial("viscous+kv", BASE, quantity), "viscous")
    if cause == "sh":
        return (*make_trial("viscous+sh", {"gamma": GAMMA, **sh_params()}, quantity), "viscous")
    if cause == "tip_mass":
        p = {**BASE, "tip_mass": 0.05 * BEAM.beam_mass}
        return (*make_trial("viscous+kv+tip_mass", p, quantity), "viscous+kv")
    if cause == "root_spring":
        drop = 0.03 if quantity == "acceleration" else 0.10
        p = {**BASE, "root_spring": root_spring_for(drop)}
        return (*make_trial("viscous+kv+root_spring", p, quantity), "viscous+kv")
    if cause == "stiffness_gradient":
        p = {**BASE, "stiffness_gradient": -0.4}
        return (*make_trial("viscous+kv+stiffness_gradient", p, quantity), "viscous+kv")
    if cause in ("drag", "friction"):
        from bayesbeam.physics.nonlinear import nonlinear_damping_scales

        # ζ1 = 0.6 % (drag), 0.3 % (friction) at a 1 cm tip amplitude of mode 1.
        k = dict(zip(("drag", "friction"),
                     nonlinear_damping_scales(BEAM, E, 0.01, n_elements=N_DATA), strict=True))
        p = {**BASE, cause: {"drag": 0.006, "friction": 0.003}[cause] / k[cause]}
        return (*make_trial(f"viscous+kv+{cause}", p, quantity, duration=3.0, fs=256.0),
                "viscous+kv")
    if cause == "amplitude_stiffness":
        return (*softening_trial(quantity), "viscous+kv")
    if cause == "sensor_quadratic":
        return (*make_trial("viscous+kv", BASE, quantity, quadratic=0.02), "viscous+kv")
    if cause == "ar1_noise":
        return (*make_trial("viscous+kv", BASE, quantity, rho=0.8), "viscous+kv")
    if cause == "sensor_offset":
        return (*make_trial("viscous+kv", BASE, quantity, offset=0.05), "viscous+kv")
    raise ValueError(cause)


def test_root_spring_size_from_frequency_equation():
    # physics.md §4: κ = 10 gives β1 L = 1.72274152, i.e. f1 lowered by 1 - (1.7227/1.8751)².
    drop = 1 - (1.72274152 / BETA1) ** 2
    assert root_spring_for(drop) == pytest.approx(10 * EI / L, rel=1e-6)


def _smoke_trial():
    """A short displacement record with a sensor offset of 10 % of its RMS."""
    t = np.arange(192) / 256.0
    y = simulate_signal(BEAM, "viscous", {"gamma": GAMMA, "w0": 0.01}, t, n_elements=4)
    rng = np.random.default_rng(1)
    rms = np.sqrt(np.mean(y**2))
    return Trial(times=t, values=y + 0.01 * rms * rng.standard_normal(t.size) + 0.1 * rms,
                 quantity="displacement", beam=BEAM, name="smoke")


def test_smoke_offset_named_and_cli(tmp_path):
    # Fast: a short trial, two candidates, one round, a tiny sampler budget.
    trial = _smoke_trial()
    d = diagnose(trial, "viscous", seed=0, max_rounds=1, candidates=("sensor_offset", "kv"),
                 n_elements=4, refine_mesh=False, nwalkers=12, target_ess=50.0,
                 min_steps=100, max_steps=100, loo_draws=100, signatures=False)
    assert d.named_causes == ("sensor_offset",)
    r = d.rounds[0]
    assert r.delta_log_evidence - 2 * r.delta_log_evidence_err > 3
    assert r.rms_after < r.rms_before
    assert r.signature_agrees
    rec = d.to_json_dict()
    json.dumps(rec, allow_nan=False)  # strict JSON
    assert rec["final_model"] == "viscous+sensor_offset"
    post = rec["final_posterior"]
    assert set(post) == {"E", "gamma", "w0", "sigma", "offset"}
    assert all(set(v) == {"mean", "sd", "q05", "q50", "q95"} for v in post.values())
    assert post["offset"]["q05"] < post["offset"]["q50"] < post["offset"]["q95"]
    assert "sensor_offset" in d.narrative()
    # CLI: same run through the sub-command's own parser.
    path = write_trial(trial, tmp_path / "smoke.toml")
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    args = parser.parse_args(["diagnose", str(path), "--baseline", "viscous", "-o",
                              str(tmp_path / "out"), "--json", "--max-rounds", "1",
                              "--candidates", "sensor_offset", "--elements", "4", "--fixed-mesh",
                              "--max-steps", "100", "--target-ess", "50", "--as-is"])
    assert args.func(args) == 0
    out = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert out["named_causes"] == ["sensor_offset"]
    assert set(out["rounds"][0]) >= {"cause", "equivalent", "delta_log_evidence",
                                     "delta_log_evidence_err", "delta_elpd", "rms_before",
                                     "rms_after"}
    assert out["final_model"] == "viscous+sensor_offset"
    assert set(out["final_posterior"]) == set(post)
    assert (tmp_path / "out" / "report.md").is_file()
    assert (tmp_path / "out" / "signatures_final.png").is_file()
    assert out["final_posterior_units"]["offset"] == "m"  # the trial's signal unit
    # Complete ArviZ trees of the baseline and the final model, which arviz.compare
    # ranks, and their modal posteriors in the record and the ζ-vs-f figure.
    import arviz as az

    trees = {m: az.from_netcdf(tmp_path / "out" / "fits" / m / "posterior.nc")
             for m in ("viscous", "viscous+sensor_offset")}
    for tree in trees.values():
        assert {"posterior", "log_likelihood", "posterior_predictive", "observed_data",
                "prior"} <= set(tree.children)
    ranked = az.compare(trees)
    assert set(ranked.index) == set(trees)
    assert set(out["modes"]) == set(trees)
    assert out["modes"]["viscous"]["modes"][0]["frequency_hz"]["q50"] > 0
    assert (tmp_path / "out" / "zeta_vs_f.png").is_file()
    jsons = sorted((tmp_path / "out").rglob("*.json"))
    assert len(jsons) >= 3  # diagnosis.json and the two fits' summary.json
    assert all(json.loads(p.read_text())["schema_version"] == 1 for p in jsons)


def test_ctrl_c_keeps_the_complete_rounds(tmp_path, monkeypatch, capsys):
    # Ctrl-C in round 2: round 1 (minutes on a whole record) is kept and written, said
    # to be incomplete; the command then ends as interrupted. Same small trial as above.
    import bayesbeam.diagnosis.diagnose as dmod

    trial = _smoke_trial()
    real = dmod._round

    def cut(eng, cur, index, *a, **kw):
        if index == 2:
            raise KeyboardInterrupt
        return real(eng, cur, index, *a, **kw)

    monkeypatch.setattr(dmod, "_round", cut)
    small = {"max_rounds": 2, "candidates": ("sensor_offset", "kv"), "n_elements": 4,
             "refine_mesh": False, "nwalkers": 12, "target_ess": 50.0, "min_steps": 100,
             "max_steps": 100, "loo_draws": 100}
    d = diagnose(trial, "viscous", seed=0, signatures=True, **small)
    assert d.named_causes == ("sensor_offset",) and d.final_model == "viscous+sensor_offset"
    assert d.interrupted == "interrupted in round 2 after 1 complete round(s)"
    assert d.signatures_before is None  # not computed after Ctrl-C
    assert "Incomplete" in d.narrative()
    assert set(d.final_posterior) == {"E", "gamma", "w0", "sigma", "offset"}
    path = write_trial(trial, tmp_path / "smoke.toml")
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    argv = ["diagnose", str(path), "--baseline", "viscous", "-o", str(tmp_path / "out"),
            "--max-rounds", "2", "--candidates", "sensor_offset,kv", "--elements", "4",
            "--fixed-mesh", "--max-steps", "100", "--target-ess", "50", "--as-is",
            "--jobs", "1"]
    args = parser.parse_args(argv)
    with pytest.raises(KeyboardInterrupt):
        args.func(args)
    out = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert out["interrupted"].startswith("interrupted in round 2")
    assert out["named_causes"] == ["sensor_offset"]
    assert (tmp_path / "out" / "report.md").is_file()
    assert "run the same command again with --resume" in capsys.readouterr().err
    # The same command with --resume: round 1's fits come from OUTDIR/steps, round 2 runs.
    monkeypatch.setattr(dmod, "_round", real)
    args = parser.parse_args([*argv, "--resume"])
    assert args.func(args) == 0
    out = json.loads((tmp_path / "out" / "diagnosis.json").read_text())
    assert out.get("interrupted") is None
    assert out["named_causes"] == ["sensor_offset"]
    assert any(n.startswith("resumed:") for n in out["notes"])
    assert not (tmp_path / "out" / "steps").exists()  # complete: removed
    # Interrupted before any round completed: nothing to keep, the interrupt goes on.
    monkeypatch.setattr(dmod, "_round", lambda *a, **kw: (_ for _ in ()).throw(
        KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        diagnose(trial, "viscous", seed=0, signatures=False, **small)


def test_bad_input():
    trial, _ = make_trial("viscous+kv", BASE, "displacement", duration=0.25)
    with pytest.raises(DiagnoseError, match="unknown cause"):
        diagnose(trial, "viscous", candidates=("magnet",))
    with pytest.raises(DiagnoseError, match="max_rounds"):
        diagnose(trial, "viscous", max_rounds=0)


def test_candidates_far_behind_the_best_screen_are_not_sampled():
    from bayesbeam.diagnosis.diagnose import CONFIRM_WINDOW, SCREEN_TIE, to_confirm

    # Round 3 of Al 40 cm #1 (fixed screens): amplitude_stiffness 1174, drag 85,
    # friction 76 nats. Their sampling took 1336 of the round's 2089 worker-seconds of
    # sampling, and neither could beat amplitude_stiffness (Δ log Z 82 and 73 vs 1166).
    assert to_confirm({"drag": 85.4, "friction": 75.7, "amplitude_stiffness": 1174.1},
                      3) == ["amplitude_stiffness"]
    # Within the window: the confirm_top best, and any tie with the best beyond them.
    gains = {"a": 100.0, "b": 100.0 - CONFIRM_WINDOW + 1, "c": 100.0 - CONFIRM_WINDOW - 1}
    assert to_confirm(gains, 3) == ["a", "b"]
    assert to_confirm(gains, 1) == ["a"]
    ties = {"a": 10.0, "b": 10.0 - SCREEN_TIE / 2, "c": 10.0 - SCREEN_TIE / 3}
    assert to_confirm(ties, 1) == ["a", "c", "b"]
    assert to_confirm({}, 3) == []


def test_drag_and_friction_signatures_point_opposite_ways():
    from types import SimpleNamespace

    from bayesbeam.diagnosis.diagnose import signature_support

    # Excess of the mode-1 decay rate at the initial amplitude over the model's: > 0
    # (faster at large amplitude) is drag's signature, < 0 friction's; within 2 se neither.
    for d, drag, fric in ((0.5, True, False), (-0.5, False, True), (0.1, False, False)):
        sig = SimpleNamespace(decay_excess_diff=d, decay_excess_diff_err=0.1)
        ok_d, txt_d = signature_support("drag", sig)
        ok_f, txt_f = signature_support("friction", sig)
        assert (ok_d, ok_f) == (drag, fric)
        assert "positive" in txt_d and "negative" in txt_f
    sig = SimpleNamespace(decay_excess_diff=float("nan"), decay_excess_diff_err=float("inf"))
    assert signature_support("friction", sig)[0] is None


def test_a_better_map_the_chains_already_visited_keeps_the_score():
    from types import SimpleNamespace

    from bayesbeam.diagnosis.diagnose import _chains_reached

    def state(max_lp, new_lp, d=12):
        chain = SimpleNamespace(log_prob=np.array([[max_lp - 7.0, max_lp], [max_lp - 3.0, -1e9]]))
        score = SimpleNamespace(result=SimpleNamespace(chain=chain))
        return SimpleNamespace(score=score, lp=new_lp, problem=SimpleNamespace(ndim=d))

    # The gap is the 1 % quantile of χ²_d / 2, checked here by brute force: 1 % of
    # Gaussian draws in 12 dimensions lie within it of the mode (binomial sd 0.02 %).
    rng = np.random.default_rng(4)
    half_chi2 = 0.5 * np.sum(rng.standard_normal((400_000, 12)) ** 2, axis=1)
    gap = float(np.quantile(half_chi2, 0.01))
    assert abs(np.mean(half_chi2 <= 1.79) - 0.01) < 0.001
    assert _chains_reached(state(100.0, 100.0 + 0.9 * gap))
    assert not _chains_reached(state(100.0, 100.0 + 1.1 * gap))
    assert not _chains_reached(state(100.0, 134.5))  # the chains never found the mode
    assert not _chains_reached(SimpleNamespace(score=None, lp=0.0))
    # In 2 dimensions a sample comes much closer to its mode: the gap shrinks with d.
    assert not _chains_reached(state(100.0, 100.5, d=2))


def test_the_chains_best_point_becomes_the_map():
    # On whole records the MAP search can stop far short (Al 50 cm #0: 250-760 nats);
    # when the chains visit a better point, it (polished) becomes the state's MAP, so
    # that the next round starts from it.
    from types import SimpleNamespace

    from bayesbeam.diagnosis.search import _Engine
    from bayesbeam.physics.models import parse_model

    trial, initial = make_trial("viscous+kv", BASE, "displacement", duration=0.25)
    eng = _Engine(trial, seed=0, n_elements=N_EL, initial=initial, priors=None,
                  sampler={}, notes=[], log=lambda s: None)
    st = eng.state(parse_model("viscous+kv"))
    eng.optimise(st, eng.starts(st, None))
    pb, u_map, lp_map = st.problem, st.u.copy(), st.lp
    poor = u_map.copy()
    poor[pb.names.index("E")] += 1e-3  # a 0.1 % error in E: far down the f1 ridge
    lp_poor = float(pb.log_prob(poor[None])[0])
    assert lp_poor < lp_map - 10
    st.u, st.lp = poor, lp_poor
    near = u_map.copy()
    near[pb.names.index("E")] += 1e-6
    chain = SimpleNamespace(flat_samples=np.array([poor, near]),
                            flat_log_prob=pb.log_prob(np.array([poor, near])))
    score = SimpleNamespace(result=SimpleNamespace(chain=chain), notes=(), log_evidence=0.0,
                            log_evidence_err=0.0, loo=SimpleNamespace(elpd_loo=0.0))
    eng._scored(st, score, [], 1.0)
    assert st.lp >= float(chain.flat_log_prob[1]) and st.lp >= lp_map - 1e-3
    assert st.ll == float(pb.log_likelihood(st.u[None])[0])
    # A chain that never rose above the MAP leaves it alone.
    u_before, lp_before = st.u.copy(), st.lp
    eng._scored(st, score, [], 1.0)
    assert np.array_equal(st.u, u_before) and st.lp == lp_before


@pytest.mark.parametrize("cause", ["added_mass", "drag", "stiffness_gradient"])
def test_a_candidate_that_nests_the_current_model_screens_from_its_map(cause):
    # The candidate's search starts from the current MAP with its new parameters at
    # their neutral values, as it is (no E scan, which re-profiles the amplitudes): on a
    # whole record the scanned copy lost 58-225 nats and the search did not climb back.
    from bayesbeam.diagnosis.search import _Engine
    from bayesbeam.physics.models import parse_model

    trial, initial = make_trial("viscous+kv", BASE, "displacement", duration=0.5)
    eng = _Engine(trial, seed=0, n_elements=N_EL, initial=initial, priors=None,
                  sampler={}, notes=[], log=lambda s: None)
    cur = eng.state(parse_model("viscous+kv"))
    eng.optimise(cur, eng.starts(cur, None))
    st = eng.state(parse_model(f"viscous+kv+{cause}"))
    eng.embed(st, cur.x)
    # A point mass at the clamp and a zero gradient change nothing: the same likelihood
    # to round-off (1e-9 relative of |log L|). Drag at its prior's lower end (ζ1 =
    # 1e-7) is not exactly zero and runs through the slow flow.
    tol = 1e-3 if cause == "drag" else 1e-9 * abs(cur.ll)
    assert st.ll == pytest.approx(cur.ll, abs=tol)
    eng.optimise(st, eng.starts(st, cur.x))
    assert st.ll >= cur.ll - tol


def test_ar1_start_is_the_noise_of_the_current_residual():
    # The AR(1) candidate's start carries the lag-1 correlation and RMS of the current
    # model's residual: from rho at its neutral 0.01 the search ran rho onto its bound
    # on a whole record and stopped 10 300 nats short.
    from bayesbeam.diagnosis.search import _Engine
    from bayesbeam.physics.models import parse_model

    rho, duration, fs = 0.8, 2.0, 512.0
    trial, initial = make_trial("viscous+kv", BASE, "displacement", rho=rho,
                                duration=duration, fs=fs)
    eng = _Engine(trial, seed=0, n_elements=N_EL, initial=initial, priors=None,
                  sampler={}, notes=[], log=lambda s: None)
    cur = eng.state(parse_model("viscous+kv"))
    eng.optimise(cur, eng.starts(cur, None))
    st = eng.state(parse_model("viscous+kv+ar1_noise"))
    names = list(st.problem.names)
    rows = eng.starts(st, cur.x)
    starts_rho = rows[:, names.index("rho")]
    # The generating rho within 4 standard errors of a lag-1 correlation estimate,
    # sqrt((1 - rho^2) / T) (Bartlett), T = 1024 samples; the residual is the noise
    # up to the fitted mean's few degrees of freedom.
    se = np.sqrt((1 - rho**2) / (duration * fs))
    assert np.any(np.abs(starts_rho - rho) < 4 * se), starts_rho
    i = int(np.argmin(np.abs(starts_rho - rho)))
    r = trial.values - st.problem.predict(rows[i : i + 1]).y[0]
    assert rows[i, names.index("sigma")] == pytest.approx(np.sqrt(np.mean(r**2)), rel=1e-12)


def test_softening_signature_and_starts():
    # The data's f1 falls with amplitude beyond the linear model's (signature), and the
    # starts of the extended model put f1_slope at the measured slope.
    from types import SimpleNamespace

    from bayesbeam.diagnosis.diagnose import signature_support
    from bayesbeam.diagnosis.search import _Engine
    from bayesbeam.physics.models import parse_model

    trial, initial = softening_trial("displacement")
    truth = trial.meta["f1_slope_hz_per_m"]
    eng = _Engine(trial, seed=0, n_elements=N_EL, initial=initial, priors=None, sampler={},
                  notes=[], log=lambda s: None)
    feats = eng.features()
    # Measured slope within 30 % of the truth: window estimates of a 3 s record whose f1
    # moves by 1 % (the windows' f and the tip amplitude are each biased by O(ε)).
    assert feats["f1_slope"] == pytest.approx(truth, rel=0.3)
    assert abs(feats["f1_slope"]) > 5 * feats["f1_slope_se"]
    st = eng.state(parse_model("viscous+kv+amplitude_stiffness"))
    rows = eng.starts(st, None)
    col = rows[:, list(st.problem.names).index("f1_slope")]
    assert np.any(np.isclose(col, feats["f1_slope"])) and np.any(col == 0.0)
    sig = SimpleNamespace(amplitude_trends={
        "data": {"f1_hz_per_mm": -0.05, "f1_hz_per_mm_se": 0.005},
        "model": {"f1_hz_per_mm": 0.0, "f1_hz_per_mm_se": 0.001}})
    ok, txt = signature_support("amplitude_stiffness", sig)
    assert ok and "softening" in txt
    sig.amplitude_trends["data"]["f1_hz_per_mm"] = -0.005
    assert signature_support("amplitude_stiffness", sig)[0] is False
    assert signature_support("amplitude_stiffness", SimpleNamespace(amplitude_trends={}))[0] \
        is None


@pytest.mark.parametrize("cause", ["drag", "friction"])
def test_physics_starts_move_the_added_cause_only(cause):
    # A model with drag (friction) gets starts that put drag (friction) at a sizeable
    # fraction of the measured ζ1, and has no parameter of the other.
    from bayesbeam.diagnosis.search import _Engine
    from bayesbeam.physics.models import parse_model

    size = {"drag": 0.1, "friction": 2e-3}[cause]  # kg/m², N
    trial, initial = make_trial(f"viscous+kv+{cause}", {**BASE, cause: size}, "displacement",
                                duration=1.0, fs=256.0)
    eng = _Engine(trial, seed=0, n_elements=4, initial=initial, priors=None, sampler={},
                  notes=[], log=lambda s: None)
    st = eng.state(parse_model(f"viscous+kv+{cause}"))
    other = "friction" if cause == "drag" else "drag"
    names = list(st.problem.names)
    assert cause in names and other not in names
    rows = eng.starts(st, None)
    lo = st.problem.priors[cause].bounds[0]
    assert np.max(rows[:, names.index(cause)]) > 1e4 * lo  # prior ends: ζ1 1e-7 .. 0.05


def test_laplace_is_computed_once_per_map():
    # The Laplace evidence is recorded for the current model every round and comes back
    # from the screen jobs for the candidates: computed again only where the MAP moved.
    from bayesbeam.diagnosis.search import _Engine
    from bayesbeam.physics.models import parse_model
    from bayesbeam.stats.evidence import laplace_evidence

    trial, initial = make_trial("viscous+kv", BASE, "displacement", duration=1.0, fs=256.0)
    eng = _Engine(trial, seed=0, n_elements=4, initial=initial, priors=None, sampler={},
                  notes=[], log=lambda s: None)
    st = eng.state(parse_model("viscous+kv"))
    eng.optimise(st, eng.starts(st, None))
    n0 = st.problem.n_calls
    eng.laplace(st)
    n1 = st.problem.n_calls
    assert n1 > n0 and math.isfinite(st.laplace)
    assert st.laplace == laplace_evidence(st.problem.log_prob, st.u).log_z
    n2 = st.problem.n_calls
    eng.laplace(st)  # the same MAP: no call
    assert st.problem.n_calls == n2
    st.u = st.u + 1e-6 * np.abs(st.u)  # a moved MAP: computed again
    eng.laplace(st)
    assert st.problem.n_calls > n2


@pytest.mark.slow
@pytest.mark.parametrize("quantity", ["displacement", "acceleration"])
# added_mass has its own test below, on data from a finer mesh than the fit's.
@pytest.mark.parametrize("cause", [c for c in CATALOGUE if c != "added_mass"])
def test_hidden_cause_is_named(cause, quantity):
    trial, initial, baseline = case(cause, quantity)
    d = diagnose(trial, baseline, seed=1, initial=initial, **BUDGET)
    assert d.named_causes == (cause,), d.narrative()
    r = d.rounds[0]
    # Separated from every other candidate (the one exception: SH contains KV).
    assert set(r.equivalent) <= ({"sh"} if cause == "kv" else set()), r.equivalent
    if cause in ("drag", "friction"):
        # Opposite signatures: a record with one is never named with the other, in any
        # round, nor is the other listed as equivalent.
        other = "friction" if cause == "drag" else "drag"
        assert other not in d.named_causes and other not in d.final_model.split("+")
        assert all(other not in rr.equivalent for rr in d.rounds), d.narrative()
    assert r.delta_log_evidence - 2 * r.delta_log_evidence_err > 3
    assert r.rms_after <= 1.02 * r.rms_before  # noise-model causes barely move the mean
    # ... and nothing significant is left in round 2, on a mesh checked again at the
    # named model's MAP (without that check a spurious point mass near the clamp was
    # named in round 2 of the sh and stiffness_gradient acceleration records).
    assert d.final_check is not None and d.final_check.cause == "none"
    assert any(n.startswith("mesh after round 1: ") and "converged" in n for n in d.notes)


@pytest.mark.slow
@pytest.mark.parametrize("quantity", ["displacement", "acceleration"])
def test_no_hidden_effect_gives_none(quantity):
    trial, initial, baseline = case("kv", quantity)
    d = diagnose(trial, "viscous+kv", seed=2, initial=initial, **BUDGET)
    assert d.named_causes == ()
    assert d.verdict == "none"
    assert d.to_json_dict()["rounds"] == []


@pytest.mark.slow
@pytest.mark.parametrize("quantity", ["displacement", "acceleration"])
def test_hidden_added_mass_is_named_with_its_position(quantity):
    # A point mass of 5 % of the beam mass at 0.85 L (34 cm from the clamp, inside an
    # element of every mesh of the ladder). No inverse crime: the record comes from a
    # 64-element model with the mass declared in the beam (Beam.masses, assembled by
    # fem), the diagnosis fits from 16 elements with the sampled added_mass and refines
    # its mesh as it sees fit. A tip mass can match f2/f1 but not f3/f1 (+8 % and +9 %
    # here against +3 % and +5 % for a tip mass of the same f2/f1 shift): the data must
    # name added_mass alone, with its position.
    from bayesbeam.physics.beam import PointMass

    initial, ic = _excitation(quantity)
    t = np.arange(512) / 512.0
    beam = BEAM.replace(quantity=quantity)
    x_true, m_true = 0.85 * L, 0.05 * BEAM.beam_mass
    y = simulate_signal(beam.replace(masses=(PointMass(x_true, m_true),)), "viscous+kv",
                        {**BASE, **ic}, t, n_elements=64, initial=initial)
    rng = np.random.default_rng(5)
    y = y + 0.01 * np.sqrt(np.mean(y**2)) * rng.standard_normal(t.size)
    trial = Trial(times=t, values=y, quantity=quantity, beam=beam, name="added-mass")
    # The causes that move frequencies (the damping and noise causes are tested above;
    # leaving them out halves the test's time).
    structural = ("tip_mass", "added_mass", "root_spring", "stiffness_gradient", "ar1_noise")
    d = diagnose(trial, "viscous+kv", seed=1, initial=initial, candidates=structural,
                 **{**BUDGET, "n_elements": 16, "refine_mesh": True})
    assert d.named_causes == ("added_mass",), d.narrative()
    r = d.rounds[0]
    assert "tip_mass" not in r.equivalent and not r.equivalent, r.equivalent
    assert r.delta_log_evidence - 2 * r.delta_log_evidence_err > 3
    # Position and mass within 4 posterior sd of the truth (the short 400-step chains
    # of the test budget estimate the sd to ~20 %; a calibrated posterior puts the truth
    # within 4 sd with probability 0.9999).
    x_mean, x_sd = r.parameter_moves["added_mass_position"]["after"]
    m_mean, m_sd = r.parameter_moves["added_mass"]["after"]
    assert abs(x_mean - x_true) < 4 * x_sd, (x_mean, x_sd)
    assert abs(m_mean - m_true) < 4 * m_sd, (m_mean, m_sd)
    assert d.final_check is not None and d.final_check.cause == "none"


@pytest.mark.slow
def test_two_hidden_effects_are_both_named():
    p = {**BASE, "tip_mass": 0.05 * BEAM.beam_mass}
    trial, initial = make_trial("viscous+kv+tip_mass", p, "acceleration", offset=0.05)
    d = diagnose(trial, "viscous+kv", seed=3, initial=initial, **BUDGET)
    assert set(d.named_causes) == {"tip_mass", "sensor_offset"}
    assert len(d.rounds) == 2
    assert d.final_model == "viscous+kv+tip_mass+sensor_offset"


@pytest.mark.slow
def test_inseparable_pair_is_reported_equivalent():
    # The pair: on the 0.4 m strip a compliant clamp (f1 -4 %) and a stiffness
    # growing along the span fit a release record about equally well.
    p = {**BASE, "root_spring": root_spring_for(0.04)}
    beam = BEAM.replace(quantity="displacement")
    t = np.arange(512) / 512.0
    y = simulate_signal(beam, "viscous+kv+root_spring", {**p, "w0": 0.01}, t, n_elements=N_DATA)
    rng = np.random.default_rng(4)
    y = y + 0.01 * np.sqrt(np.mean(y**2)) * rng.standard_normal(t.size)
    trial = Trial(times=t, values=y, quantity="displacement", beam=beam, name="clamp")
    d = diagnose(trial, "viscous+kv", seed=4, max_rounds=1, **BUDGET)
    pair = {"root_spring", "stiffness_gradient"}
    assert len(d.named_causes) == 1 and d.named_causes[0] in pair
    assert (pair - set(d.named_causes)) <= set(d.rounds[0].equivalent)
    assert "cannot separate" in d.narrative()


def _study(name):
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "studies" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"_study_{name}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_hidden_effects_study_small(tmp_path):
    out = _study("hidden_effects").main(small=True, outdir=tmp_path, progress=False)
    assert all(r["found"] for r in out["rows"])
    assert all(p.is_file() for p in out["paths"])


@pytest.mark.slow
def test_real_data_study_small(tmp_path, real_data_root):
    out = _study("real_data").main(small=True, outdir=tmp_path, progress=False)
    (row,) = out["rows"]
    assert row["record"] == "alu40-0" and row["samples"] > 300
    # The uniform beam leaves strongly correlated residuals on the real strip: one of
    # the two candidates is named in the round, with a gain far beyond its error; the
    # final model's sizes come in physical units.
    (named,) = row["named"]
    assert named["cause"] in {"added_mass", "ar1_noise"}
    assert named["delta_log_evidence"] > 3 + 2 * named["delta_log_evidence_err"]
    assert 40 < row["sizes"]["E"][0] < 90  # GPa (aluminium: 69)
    # Every sampled model is counted, and an unconverged one is said to be.
    assert row["baseline"] in row["sampled"] and set(row["unconverged"]) <= set(row["sampled"])
    assert "chains unconverged" in out["markdown"]
    assert all(p.is_file() for p in out["paths"])
    # Resumed: the record's output is read, not run again (same row, at once).
    again = _study("real_data").main(small=True, outdir=tmp_path, progress=False)
    assert again["rows"] == out["rows"]



def test_resume_takes_the_finished_steps_and_gives_the_uninterrupted_result(tmp_path,
                                                                           monkeypatch):
    # A diagnosis cut by Ctrl-C in its last sampling run keeps every finished step in
    # steps_dir; resumed, it samples only that model and ends with the numbers of a run
    # that was never interrupted.
    import bayesbeam.diagnosis.search as search_mod
    from bayesbeam.diagnosis.search import _Engine

    trial = _smoke_trial()
    small = {"max_rounds": 2, "candidates": ("sensor_offset", "kv"), "n_elements": 4,
             "refine_mesh": False, "nwalkers": 12, "target_ess": 50.0, "min_steps": 100,
             "max_steps": 100, "loo_draws": 100, "signatures": False}
    real = _Engine._sample_and_score
    calls: list[str] = []
    stop = {"at": None}

    def counted(self, st, seed, notes, helpers=0):
        calls.append(st.problem.model.name)
        if len(calls) == stop["at"]:
            raise KeyboardInterrupt
        return real(self, st, seed, notes, helpers=helpers)

    searches: list[int] = []
    real_search = search_mod.best_map
    monkeypatch.setattr(search_mod, "best_map",
                        lambda *a, **k: searches.append(1) or real_search(*a, **k))
    monkeypatch.setattr(_Engine, "_sample_and_score", counted)
    whole = diagnose(trial, "viscous", seed=0, **small)
    n_whole, s_whole = len(calls), len(searches)
    assert n_whole >= 2  # the baseline and the offset in round 1 at least
    calls.clear()
    searches.clear()
    stop["at"] = n_whole
    steps = tmp_path / "steps"
    try:
        cut = diagnose(trial, "viscous", seed=0, steps_dir=steps, **small)
        assert cut.interrupted  # after round 1: it is kept
    except KeyboardInterrupt:
        pass  # in round 1: nothing complete to keep, but its finished steps are on disk
    assert len(calls) == n_whole
    s_cut = len(searches)
    calls.clear()
    searches.clear()
    stop["at"] = None
    resumed = diagnose(trial, "viscous", seed=0, steps_dir=steps, resume=True, **small)
    assert len(calls) == 1  # only the sampling run that was cut
    assert len(searches) == s_whole - s_cut  # only the MAP searches not yet begun
    assert resumed.interrupted is None
    assert resumed.named_causes == whole.named_causes
    assert resumed.final_model == whole.final_model
    for a, b in zip(resumed.rounds, whole.rounds, strict=True):
        assert a.delta_log_evidence == b.delta_log_evidence
        assert a.delta_log_evidence_err == b.delta_log_evidence_err
    assert resumed.final_posterior == whole.final_posterior
    assert any(n.startswith("resumed:") for n in resumed.notes)
    # Without resume the folder is emptied first: everything is computed again.
    calls.clear()
    diagnose(trial, "viscous", seed=0, steps_dir=steps, **small)
    assert len(calls) == n_whole
    with pytest.raises(DiagnoseError, match="steps_dir"):
        diagnose(trial, "viscous", resume=True, **small)


def test_resumed_run_takes_the_mesh_checks(tmp_path, monkeypatch):
    # The mesh checks between rounds are steps too: resumed, the run evaluates no finer
    # mesh again, refines as the uninterrupted one did and ends with its numbers.
    import bayesbeam.inference.mesh as mesh_mod

    t = np.arange(192) / 256.0
    y = simulate_signal(BEAM, "viscous", {"gamma": GAMMA, "w0": 0.01}, t, n_elements=16)
    rms = np.sqrt(np.mean(y**2))
    noise = 1e-3 * rms * np.random.default_rng(1).standard_normal(t.size)
    trial = Trial(times=t, values=y + noise + 0.1 * rms, quantity="displacement",
                  beam=BEAM, name="mesh")
    small = {"max_rounds": 1, "candidates": ("sensor_offset",), "n_elements": 2,
             "refine_mesh": True, "nwalkers": 12, "target_ess": 50.0, "min_steps": 100,
             "max_steps": 100, "loo_draws": 100, "signatures": False}
    checks: list[int] = []
    real = mesh_mod.converge_mesh
    monkeypatch.setattr(mesh_mod, "converge_mesh",
                        lambda *a, **k: checks.append(1) or real(*a, **k))
    steps = tmp_path / "steps"
    whole = diagnose(trial, "viscous", seed=0, steps_dir=steps, **small)
    assert len(checks) == 2  # the baseline's, and after the round
    mesh_notes = [n for n in whole.notes if n.startswith("mesh")]
    # The baseline's check refined the 2-element start (the resumed run must do so too).
    assert mesh_notes[0].startswith("mesh: ") and "converged" in mesh_notes[0]
    assert not mesh_notes[0].startswith("mesh: 2 elements")
    checks.clear()
    again = diagnose(trial, "viscous", seed=0, steps_dir=steps, resume=True, **small)
    assert checks == []
    assert [n for n in again.notes if n.startswith("mesh")] == mesh_notes
    assert again.named_causes == whole.named_causes
    assert again.final_posterior == whole.final_posterior
