"""fit_joint against independent single-trial fits, and the sharing comparison.

The trials are simulated on a finer mesh (24 elements) than the fits use (16), with white
noise: no inverse crime. The beam is uniform, so the viscous law is classically damped
and the forward model takes its closed-form path (fast enough for the suite).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bayesbeam.comparison.joint import compare_joint
from bayesbeam.inference.fit import fit
from bayesbeam.inference.joint_fit import fit_joint
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

pytestmark = pytest.mark.slow

E_TRUE = 6.2e10
FAST = {"target_ess": 400, "max_steps": 6000, "progress": False}


def _trials(e_factors=(1.0, 1.0, 1.0), seed=0):
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E_TRUE)
    out = []
    for i, f in enumerate(e_factors):
        b = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E_TRUE * f)
        tr = simulate_trial(b, "viscous", {"gamma": 0.2}, duration=1.0, dt=1 / 256,
                            tip_deflection=0.004 + 0.001 * i, noise_sd=2e-5, seed=seed + i,
                            n_elements=24, name=f"t{i}")
        # The user's beam: the nominal E, whatever the record's true one.
        out.append(dataclasses.replace(tr, beam=beam))
    return out


@pytest.fixture(scope="module")
def same_E():
    return _trials()


@pytest.fixture(scope="module")
def joint(same_E):
    return fit_joint(same_E, "viscous", shared=("E",), seed=1, **FAST)


@pytest.fixture(scope="module")
def singles(same_E):
    return [fit(t, "viscous", seed=2, **FAST) for t in same_E]


def _E(result):
    j = result.names.index("E")
    x = result.theta_samples()[..., j].ravel()
    return float(np.mean(x)), float(np.std(x, ddof=1)), result.chain.ess[j]


def test_joint_E_is_the_product_of_the_single_posteriors(joint, singles):
    """The shared-E posterior against the inverse-variance combination of single fits.

    Each trial's other parameters are its own, so the joint posterior of E is the
    product of the single-trial marginals (over the log-uniform prior, flat in log E);
    for near-Gaussian marginals its sd is (Σ sd_i⁻²)^-½ and its mean the weighted mean.
    Tolerances: the sd estimates carry 1/sqrt(2 ESS) <= 3.6 % each at ESS >= 400, so
    15 % is 4 of those; the means are compared in units of the combined sd.
    """
    m_j, sd_j, _ = _E(joint.result)
    stats = [_E(r) for r in singles]
    w = np.array([1 / s**2 for _, s, _ in stats])
    sd_c = 1 / math.sqrt(w.sum())
    m_c = float(np.sum(w * [m for m, _, _ in stats]) / w.sum())
    assert sd_j / sd_c == pytest.approx(1.0, abs=0.15)
    assert abs(m_j - m_c) < 0.5 * sd_c
    # About sqrt(3) narrower than a single trial, and covers the generating value.
    assert sd_j < 0.75 * min(s for _, s, _ in stats)
    q05, q95 = np.quantile(joint.result.theta_samples()[..., 0], [0.05, 0.95])
    assert q05 < E_TRUE < q95 or abs(m_j - E_TRUE) < 3 * sd_j


def test_joint_reports_each_trial_adequate_and_complete(joint):
    assert joint.ok
    # Its MAP is the better of the search's and the chains' best (polished), as a single
    # fit's, and is the log density at the reported point.
    st = joint.result.settings
    assert st["log_prob_map"] >= st["log_prob_map_search"]
    assert st["log_prob_map"] >= float(np.max(joint.result.chain.log_prob)) - 1e-9
    lp = joint.problem.log_prob(joint.result.map_u[None])[0]
    assert lp == pytest.approx(st["log_prob_map"], abs=1e-9)
    d = joint.to_json_dict()
    assert set(d["posterior"]["E"]) >= {"mean", "sd", "q05", "q50", "q95"}
    for lb in joint.labels:
        assert f"gamma[{lb}]" in d["posterior"]
        assert f"sigma[{lb}]" in d["posterior"]  # marginalised, drawn for the report
        assert d["units"][f"sigma[{lb}]"] == "m"
        # sigma drawn from its exact conditional: near the generating 2e-5 (256 samples:
        # sd ~ 4 %; the mesh error of 16 vs 24 elements adds nothing visible).
        assert d["posterior"][f"sigma[{lb}]"]["q50"] == pytest.approx(2e-5, rel=0.15)
    tree = joint.to_inference_data()
    assert tree["posterior"]["gamma"].dims == ("chain", "draw", "trial")
    assert list(tree["posterior"]["trial"].values) == list(joint.labels)
    assert tree["posterior"]["E"].attrs["units"] == "Pa"
    assert tree["log_likelihood"]["y"].sizes["obs"] == sum(t.problem.data.size
                                                           for t in joint.trials)


def test_marginalised_single_fit_keeps_the_posterior(same_E, singles):
    """One trial, sigma and w0 integrated out: same means as the sampled fit within MCSE."""
    one = fit_joint(same_E[:1], "viscous", shared=(), seed=3, **FAST)
    ref = singles[0]
    for name, joint_name in (("E", "E[t0]"), ("gamma", "gamma[t0]")):
        a = one.result.theta_samples()[..., one.result.names.index(joint_name)].ravel()
        b = ref.theta_samples()[..., ref.names.index(name)].ravel()
        ea = one.result.chain.ess[one.result.names.index(joint_name)]
        eb = ref.chain.ess[ref.names.index(name)]
        mcse = math.hypot(np.std(a) / math.sqrt(ea), np.std(b) / math.sqrt(eb))
        # 4 combined Monte Carlo standard errors: a false alarm in ~1e-4 of runs.
        assert abs(np.mean(a) - np.mean(b)) < 4 * mcse, name


@pytest.mark.parametrize("factors, best", [((1.0, 1.0, 1.0), "shared E"),
                                           ((1.0, 1.0, 1.002), "nothing shared")])
def test_sharing_comparison(factors, best):
    """E shared vs each trial its own: the evidence decides, in the right direction.

    A single record pins E to ~2e-6 (relative), so a 2e-3 difference is hundreds of
    sd and separate moduli must win; when all agree, the Occam factor of two extra
    moduli (prior width ~2.8 in log E against a posterior width ~1e-5) favours sharing by
    ~20 nats, far beyond the bridge-sampling error.
    """
    cmp = compare_joint(_trials(factors, seed=10), "viscous", [(("E",), ()), ((), ())],
                        seed=4, **FAST)
    assert cmp.decided, cmp.table()
    assert best in cmp.best, cmp.table()



def test_pooled_spread_sees_trials_that_differ():
    """The population spread of a pooled damping law (sd of log gamma between trials).

    Values a factor 2 apart (sd of the three log gamma 0.57, each trial's gamma known to
    ~1 %): the spread's 90 % interval holds 0.57 and stays far from zero, and the
    population median covers the geometric mean of the trials' values. (Three trials
    with one value do not converge in 6000 steps: near zero spread the centred
    coordinates form a funnel; README, "Several trials".)
    """
    gammas = (0.1, 0.2, 0.4)
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E_TRUE)
    trials = [simulate_trial(beam, "viscous", {"gamma": g}, duration=1.0, dt=1 / 256,
                             tip_deflection=0.004 + 0.001 * i, noise_sd=2e-5, seed=30 + i,
                             n_elements=24, name=f"p{i}") for i, g in enumerate(gammas)]
    jf = fit_joint(trials, "viscous", shared=("E",), pooled=("gamma",), seed=6, **FAST)
    r = jf.result
    spread = r.theta_samples()[..., r.names.index("gamma_spread")].ravel()
    median = r.theta_samples()[..., r.names.index("gamma_median")].ravel()
    q05, q95 = np.quantile(spread, [0.05, 0.95])
    true = float(np.std(np.log(gammas)))
    assert q05 > 0.2 and q05 < true < q95, (q05, q95, true)
    m05, m95 = np.quantile(median, [0.05, 0.95])
    assert m05 < math.exp(np.mean(np.log(gammas))) < m95, (m05, m95)


def test_resumed_joint_fit_reuses_its_searches_and_continues_the_chain(same_E, tmp_path,
                                                                       monkeypatch):
    # An unfinished joint fit (its step budget spent), resumed with more steps, gives the
    # chain of one uninterrupted run, without repeating the per-trial and joint MAP
    # searches (kept in map.json with the generator's state after each).
    import bayesbeam.inference.joint_fit as jfmod
    from bayesbeam.stats.sampling import NotConvergedWarning

    kw = {"shared": ("E",), "seed": 5, "progress": False, "target_ess": 10**6, "min_steps": 0}
    with pytest.warns(NotConvergedWarning):
        whole = fit_joint(same_E, "viscous", max_steps=300, **kw)
    with pytest.warns(NotConvergedWarning):
        fit_joint(same_E, "viscous", max_steps=150, outdir=tmp_path, **kw)
    assert (tmp_path / "map.json").is_file()

    def no_search(*a, **k):
        raise AssertionError("a resumed joint fit searched again")

    for name in ("find_map", "local_map", "escape_bounds"):
        monkeypatch.setattr(jfmod, name, no_search)
    with pytest.warns(NotConvergedWarning):
        resumed = fit_joint(same_E, "viscous", max_steps=300, outdir=tmp_path, resume=True,
                            **kw)
    assert resumed.result.chain.n_steps_total == 300
    np.testing.assert_array_equal(resumed.result.chain.samples, whole.result.chain.samples)
    np.testing.assert_array_equal(resumed.result.map_u, whole.result.map_u)
