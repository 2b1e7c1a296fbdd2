"""``Comparison.save(trial=...)``: the modes of every model and the ζ-vs-f picture.

Stand-in posteriors (clouds of chosen draws, conftest) are scored by ``evaluate`` with a
ready result, so no sampler runs; the modal records must be those of
:func:`bayesbeam.inference.modal.modal_posterior` on each model's own Problem.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from bayesbeam.comparison.compare import compare_scores
from bayesbeam.comparison.scoring import CompareError, evaluate
from bayesbeam.inference.modal import modal_posterior
from bayesbeam.inference.problem import Problem
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_signal
from bayesbeam.trials.trial import Trial

E = 6.2e10
NE = 4
BEAM = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E)
W1 = 1.875104069**2 * math.sqrt(E * BEAM.I / (BEAM.rhoA * BEAM.length**4))
GAMMA = 2 * BEAM.rhoA * W1 * 0.01
C_D = 2 * E * 0.01 / W1


def release_trial() -> Trial:
    """A 0.5 s viscous release on the 4-element beam, 1e-5 m noise (seed 0)."""
    t = np.arange(128) / 256
    y = simulate_signal(BEAM, "viscous", {"E": E, "w0": 0.005, "gamma": GAMMA}, t,
                        n_elements=NE)
    rng = np.random.default_rng(0)
    return Trial(times=t, values=y + 1e-5 * rng.standard_normal(t.size),
                 quantity="displacement", beam=BEAM, name="release")


def test_save_with_trial_writes_modes_and_zeta_vs_f(tmp_path, gaussian_cloud_result):
    trial = release_trial()
    scores, records = [], {}
    for model, damping in (("viscous", GAMMA), ("kv", C_D)):
        pr = Problem(trial, model, n_elements=NE)
        res = gaussian_cloud_result(pr, [E, damping, 0.005, 1e-5], [0.01, 0.1, 0.01, 0.1],
                                    nsteps=20, nwalkers=8)
        # The settings a fit records: the comparison rebuilds each Problem from them.
        res = dataclasses.replace(res, settings={"n_elements": NE, "initial": "release"})
        scores.append(evaluate(trial, model, result=res, problem=pr, n_loo_draws=80,
                               n_proposal=400))
        records[model] = modal_posterior(pr, res).to_json_dict()
    comp = compare_scores(scores, sensitivity_factors=())
    paths = comp.save(tmp_path, fits=False, extra={"x": 1}, trial=trial)
    assert paths["zeta_vs_f"] == tmp_path / "zeta_vs_f.png"
    assert paths["zeta_vs_f"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    d = json.loads((tmp_path / "comparison.json").read_text())
    assert d["x"] == 1 and list(d["modes"]) == ["viscous", "kv"]
    assert d["modes"] == records
    # ζ1 is 1 % for both; ζ2/ζ1 = (f2/f1)^∓1 tells them apart.
    z = {m: [r["damping_ratio"]["q50"] for r in d["modes"][m]["modes"]] for m in records}
    assert z["viscous"][1] < z["viscous"][0] < z["kv"][1]
    # Without the trial nothing changes (no modes, no figure).
    plain = comp.save(tmp_path / "plain", fits=False)
    assert "zeta_vs_f" not in plain and not (tmp_path / "plain" / "zeta_vs_f.png").exists()
    assert "modes" not in json.loads((tmp_path / "plain" / "comparison.json").read_text())
    # Another trial than the compared one is refused.
    short = Trial(times=trial.times[:100], values=trial.values[:100], quantity="displacement",
                  beam=BEAM)
    with pytest.raises(CompareError, match="scored on 128 samples"):
        comp.modal_posteriors(short)
