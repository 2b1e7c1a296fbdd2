"""Fit settings: one set of defaults, read by every entry point."""

import dataclasses
import inspect

import pytest

from bayesbeam.inference.settings import (
    DIAGNOSIS_DEFAULTS,
    FIT_DEFAULTS,
    FitSettings,
    fit_settings,
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
