"""Fit settings: one set of defaults, read by every entry point."""

import dataclasses
import inspect

import numpy as np
import pytest
from scipy.signal import lfilter

from bayesbeam.inference.settings import (
    COSTLY_ELEMENTS,
    DIAGNOSIS_DEFAULTS,
    DIAGNOSIS_STOPPING,
    FIT_DEFAULTS,
    MAX_ELEMENTS,
    FitSettings,
    fit_settings,
    mesh_cost,
    mesh_cost_text,
    walker_count,
)


def test_fit_settings_take_the_defaults_and_reject_unknown_names():
    full = fit_settings({"max_steps": 50}, caller="evaluate")
    assert tuple(full) == tuple(f.name for f in dataclasses.fields(FitSettings))
    assert full == {"n_elements": 16, "refine_mesh": True, "initial": "release", "nwalkers": None,
                    "target_ess": 1000.0, "max_steps": 50, "min_steps": 300}
    with pytest.raises(TypeError, match=r"evaluate\(\) got an unexpected keyword .*'max_step'"):
        fit_settings({"max_step": 50}, caller="evaluate")


def test_diagnosis_budget_is_an_override_of_the_defaults():
    assert DIAGNOSIS_DEFAULTS == dataclasses.replace(
        FIT_DEFAULTS, target_ess=300.0, max_steps=2000, min_steps=200)


def test_the_diagnosis_stopping_rule_stops_where_its_ess_is_not_optimistic():
    # 68 walkers (a whole-record model's count) of unit AR(1) series in 3 parameters
    # with tau = (1 + phi) / (1 - phi) = 45 steps, the tau of the diagnosis's whole-record
    # chains; the true effective sample size of n kept steps is 68 n / tau (closed
    # forms). Checked every 100 steps as run_emcee does, the diagnosis's rule must stop
    # within its 2000-step budget (the full fit's rule does not, on most seeds), at a
    # kept length of at least 10 true tau, and where it stops the bulk ESS it reports
    # must not overstate the truth: the smallest over the parameters (the figure
    # compared with the target and reported as ess_min) at most the true ESS, and the
    # mean over parameters and seeds at most 1.0x it (each parameter's estimate
    # scatters by ~0.17 at this length, measured: the mean of 12 is known to ~0.05).
    from bayesbeam.stats.convergence import check_convergence

    tau, walkers = 45.0, 68
    phi = (tau - 1) / (tau + 1)
    ratios = []
    for seed in range(4):
        z = np.random.default_rng(seed).standard_normal((2400, walkers, 3))
        x = lfilter([np.sqrt(1 - phi**2)], [1, -phi], z, axis=0)[400:]  # stationary
        prev = None
        for n in range(100, 2001, 100):
            check = check_convergence(x[:n], prev, **DIAGNOSIS_STOPPING, burn_in_taus=3.0,
                                      min_steps=DIAGNOSIS_DEFAULTS.min_steps,
                                      max_steps=DIAGNOSIS_DEFAULTS.max_steps,
                                      target_ess=DIAGNOSIS_DEFAULTS.target_ess)
            prev = check.tau
            if check.converged:
                break
        assert check.converged, f"seed {seed}: the rule ran to the budget"
        kept = n - check.burn_in
        assert kept >= 10 * tau, (seed, n)
        ratio = check.ess / (walkers * kept / tau)
        assert np.min(ratio) <= 1.0, (seed, ratio)
        ratios.extend(ratio)
    assert np.mean(ratios) <= 1.0, ratios


@pytest.mark.parametrize(("nwalkers", "ndim", "expected"),
                         [(None, 3, 32), (None, 9, 36), (None, 0, 32), (24, 20, 24), (25, 2, 26)])
def test_walker_count(nwalkers, ndim, expected):
    assert walker_count(nwalkers, ndim) == expected


def _defaults(func, names):
    params = inspect.signature(func).parameters
    return {n: params[n].default for n in names}


def test_every_entry_point_reads_its_defaults_from_one_object():
    from bayesbeam.cli import main as cli_main
    from bayesbeam.diagnosis.diagnose import diagnose
    from bayesbeam.inference.fit import fit
    from bayesbeam.jobs.tasks import DEFAULT_SETTINGS

    names = [f.name for f in dataclasses.fields(FitSettings)]
    assert _defaults(fit, names) == dataclasses.asdict(FIT_DEFAULTS)
    assert _defaults(diagnose, names) == dataclasses.asdict(DIAGNOSIS_DEFAULTS)
    assert {n: DEFAULT_SETTINGS[n] for n in names} == dataclasses.asdict(FIT_DEFAULTS)

    parser = cli_main._build_parser()
    for command, argv, budget in (
        ("fit", ["t.toml", "--model", "viscous", "-o", "o"], FIT_DEFAULTS),
        ("compare", ["t.toml", "-o", "o"], FIT_DEFAULTS),
        ("diagnose", ["t.toml", "-o", "o"], DIAGNOSIS_DEFAULTS),
    ):
        args = parser.parse_args([command, *argv])
        assert (args.elements, args.target_ess, args.max_steps) == (
            budget.n_elements, budget.target_ess, budget.max_steps), command


def test_mesh_cost_grows_with_the_dense_state():
    # Memory: about 5.5 float64 arrays of (4N)^2 per parameter set; 4 x for 2 x the mesh,
    # and in proportion to the sets.
    mem16, t16 = mesh_cost(16)
    mem32, t32 = mesh_cost(32)
    assert mem16 == pytest.approx(5.5 * 8 * 64**2 * 32)
    assert mem32 == pytest.approx(4 * mem16)
    assert mesh_cost(16, n_sets=64)[0] == pytest.approx(2 * mem16)
    assert t16 < t32 < mesh_cost(200)[1]
    # The calibration points (2-core machine): ~0.9 GB and ~12 s per step at 200.
    mem, t = mesh_cost(200)
    assert 0.85e9 < mem < 0.95e9 and 11 < t < 13
    assert mesh_cost_text(500).startswith("2000 dense states: about 5.6 GB and 90 s per "
                                          "evaluation of 32 parameter sets")


def test_element_limits_bracket_the_mesh_ladder():
    from bayesbeam.inference.mesh import LADDER

    # Automatic refinement reaches the ladder's finest mesh; the limit leaves room for a
    # start beyond it, the note starts within it.
    assert FIT_DEFAULTS.n_elements < COSTLY_ELEMENTS <= LADDER[-1] < MAX_ELEMENTS
    assert MAX_ELEMENTS <= 2 * LADDER[-1] + 8
