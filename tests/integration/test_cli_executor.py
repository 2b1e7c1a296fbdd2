"""``--jobs`` / ``--scheduler`` of ``bayesbeam compare`` and ``bayesbeam diagnose``.

The options come from one helper (:func:`bayesbeam.cli.options.add_executor_options`,
as the demo's), reach :func:`bayesbeam.jobs.executor.make_executor`, and a bad value
ends in one line and exit status 2 before any fit. That parallel runs give the serial
numbers is tested on the library functions (tests/comparison, tests/diagnosis).
"""

from __future__ import annotations

import argparse

import pytest

from bayesbeam.cli import compare as cli_compare
from bayesbeam.cli import diagnose as cli_diagnose
from bayesbeam.cli.main import main
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial


@pytest.fixture(scope="module")
def trial_file(tmp_path_factory):
    beam = Beam.rectangular(0.3048, 0.127, 1.47e-3, 0.046, E=62e9)
    path = tmp_path_factory.mktemp("trial") / "tiny.toml"
    simulate_trial(beam, "viscous", {"gamma": 0.1}, duration=0.5, dt=1 / 256,
                   tip_deflection=0.008, noise_sd=1e-5, seed=3, n_elements=6, name="tiny",
                   out=path)
    return path


@pytest.mark.parametrize("module", [cli_compare, cli_diagnose])
def test_executor_options_parse(module, trial_file, tmp_path):
    parser = argparse.ArgumentParser()
    module.register(parser.add_subparsers())
    name = module.__name__.rsplit(".", 1)[-1]
    args = parser.parse_args([name, str(trial_file), "-o", str(tmp_path)])
    # compare runs serially unless asked; diagnose uses one process per core (0), since
    # a whole record's diagnosis takes tens of minutes and its numbers do not change.
    want = 0 if module is cli_diagnose else 1
    assert args.jobs == want and args.scheduler is None
    args = parser.parse_args([name, str(trial_file), "-o", str(tmp_path), "--jobs", "3",
                              "--scheduler", "tcp://127.0.0.1:8786"])
    assert args.jobs == 3 and args.scheduler == "tcp://127.0.0.1:8786"


@pytest.mark.parametrize("command", ["compare", "diagnose"])
def test_bad_scheduler_is_one_line_and_status_2(command, trial_file, tmp_path, capsys):
    # Not an address: refused when the executor is made, before any fit.
    status = main([command, str(trial_file), "-o", str(tmp_path / "out"), "--as-is",
                   "--scheduler", "localhost"])
    err = capsys.readouterr().err
    assert status == 2
    assert "scheduler must be a Dask scheduler address" in err
    assert not (tmp_path / "out" / "comparison.json").exists()
    assert not (tmp_path / "out" / "diagnosis.json").exists()
