"""``bayesbeam fit`` and ``bayesbeam compare`` on several trials (joint fits)."""

from __future__ import annotations

import argparse
import json
import math

import arviz
import pytest

from bayesbeam.cli import compare as compare_cli
from bayesbeam.cli import fit as fit_cli
from bayesbeam.inference.problem import BETA1
from bayesbeam.physics.beam import Beam
from bayesbeam.trials.synthetic import simulate_trial

E = 6.2e10


def _run(module, argv):
    p = argparse.ArgumentParser(prog="bayesbeam")
    module.register(p.add_subparsers(dest="command"))
    return module.run(p.parse_args(argv))


@pytest.fixture(scope="module")
def trial_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("joint")
    beam = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=E)
    w1 = BETA1**2 * math.sqrt(E * beam.I / (beam.rhoA * beam.length**4))
    paths = []
    for i in range(3):
        p = d / f"rel{i + 1}.toml"
        simulate_trial(beam, "viscous", {"gamma": 2 * beam.rhoA * w1 * 0.01 * (1 + 0.1 * i)},
                       duration=0.5, dt=1 / 256, noise_sd=2e-5, seed=i, n_elements=8,
                       tip_deflection=0.005, name=f"rel{i + 1}", out=p)
        paths.append(str(p))
    return paths


@pytest.mark.slow
def test_joint_fit_json_has_single_fit_keys_and_trial_names(trial_files, tmp_path, capsys):
    out = tmp_path / "joint"
    priors = tmp_path / "priors.toml"  # a prior file applies to every trial
    priors.write_text('[priors.E]\ndist = "loguniform"\nlo = 5e10\nhi = 8e10\n')
    assert _run(fit_cli, ["fit", *trial_files, "--model", "viscous", "--shared", "E", "-o",
                          str(out), "--json", "--elements", "6", "--max-steps", "400",
                          "--target-ess", "100", "--fixed-mesh", "--priors", str(priors)]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert set(payload["posterior"]["E"]) == {"mean", "sd", "q05", "q50", "q95"}
    assert 5e10 <= payload["posterior"]["E"]["q05"] <= payload["posterior"]["E"]["q95"] <= 8e10
    record = json.loads((out / "run.json").read_text())["record"]
    assert record["priors"]["E"]["lo"] == 5e10
    for lb in ("rel1", "rel2", "rel3"):
        assert f"gamma[{lb}]" in payload["posterior"]
        assert f"w0[{lb}]" in payload["posterior"]  # integrated out, drawn for the report
        assert lb in payload["trials"]
    assert payload["joint"]["shared"] == ["E"]
    assert payload["joint"]["marginal_note"].startswith("sigma and the amplitudes integrated out")
    assert payload["units"]["E"] == "Pa"
    for f in ("summary.json", "posterior.nc", "corner.png", "trace.png", "fit_rel1.png",
              "run.json"):
        assert (out / f).is_file(), f
    tree = arviz.from_netcdf(out / "posterior.nc")
    assert tree["posterior"]["gamma"].dims == ("chain", "draw", "trial")
    assert tree["posterior"]["E"].dims == ("chain", "draw")


def test_joint_fit_bad_name_is_one_clear_line(trial_files, tmp_path):
    with pytest.raises(fit_cli.FitCLIError, match="not parameters of model"):
        _run(fit_cli, ["fit", *trial_files[:2], "--model", "viscous", "--shared", "EE",
                       "-o", str(tmp_path / "x"), "--elements", "6", "--fixed-mesh"])


def test_joint_fit_prior_of_unknown_name_is_one_clear_line(trial_files, tmp_path):
    priors = tmp_path / "priors.toml"
    priors.write_text('[priors.c_d]\ndist = "loguniform"\nlo = 1e5\nhi = 1e7\n')
    with pytest.raises(ValueError, match="unknown parameter"):
        _run(fit_cli, ["fit", *trial_files[:2], "--model", "viscous", "--shared", "E",
                       "-o", str(tmp_path / "x"), "--elements", "6", "--fixed-mesh",
                       "--priors", str(priors)])


def test_compare_several_trials_needs_shared(trial_files, tmp_path):
    with pytest.raises(compare_cli.CompareCLIError, match="--shared"):
        _run(compare_cli, ["compare", *trial_files[:2], "--models", "viscous", "-o",
                           str(tmp_path / "c")])


def test_compare_several_trials_fits_each_as_prepared(trial_files, tmp_path, monkeypatch):
    # The variants are fitted with each trial's own initial condition (here the declared
    # release) and the model its preprocessing asks for, as `fit` with several trials
    # does; before, `compare` left them to the fitting defaults.
    import bayesbeam.comparison.joint as cj

    seen = {}

    class Stop(Exception):
        pass

    def fake(trials, model, variants, **kw):
        seen.update(kw, model=model, n=len(trials))
        raise Stop

    monkeypatch.setattr(cj, "compare_joint", fake)
    with pytest.raises(Stop):
        _run(compare_cli, ["compare", *trial_files[:2], "--models", "viscous", "--shared",
                           "E", "-o", str(tmp_path / "c")])
    assert seen["initial"] == "release" and seen["model"] == "viscous" and seen["n"] == 2


def test_compare_pooled_is_ranked_against_both_of_its_limits(trial_files, tmp_path,
                                                             monkeypatch):
    # --pooled: the pooled fit, every trial its own value, one value for all trials
    # (shared), and, with --shared, every trial on its own.
    import bayesbeam.comparison.joint as cj

    seen = []

    class Stop(Exception):
        pass

    def fake(trials, model, variants, **kw):
        seen.extend(variants)
        raise Stop

    monkeypatch.setattr(cj, "compare_joint", fake)
    with pytest.raises(Stop):
        _run(compare_cli, ["compare", *trial_files[:2], "--models", "viscous", "--shared",
                           "E", "--pooled", "gamma", "-o", str(tmp_path / "c")])
    assert [(tuple(s), tuple(p)) for s, p in seen] == [
        (("E",), ("gamma",)), (("E",), ()), (("E", "gamma"), ()), ((), ())]
    seen.clear()
    with pytest.raises(Stop):
        _run(compare_cli, ["compare", *trial_files[:2], "--models", "viscous", "--pooled",
                           "gamma", "-o", str(tmp_path / "d")])
    assert [(tuple(s), tuple(p)) for s, p in seen] == [
        ((), ("gamma",)), ((), ()), (("gamma",), ())]


@pytest.mark.slow
def test_compare_several_trials_ranks_sharing(trial_files, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert _run(compare_cli, ["compare", *trial_files, "--models", "viscous", "--shared", "E",
                              "-o", str(out), "--json", "--elements", "6", "--fixed-mesh",
                              "--max-steps", "1500", "--target-ess", "200"]) == 0
    payload = json.loads(capsys.readouterr().out)
    rec = payload["models"]["viscous"]
    names = [v["name"] for v in rec["variants"]]
    assert names == ["viscous | shared E", "viscous | nothing shared"]
    # Every trial has the generating E: sharing it wins (Occam factor of two moduli).
    assert rec["best"] == "viscous | shared E"
    assert all(math.isfinite(v["log_z_err"]) for v in rec["variants"])
    assert (out / "comparison.txt").is_file()


def test_unconverged_pooled_fit_says_what_mixes_slowly(trial_files, tmp_path, capsys):
    # A pooled fit cut short: the warning, then the spreads' intervals and the limit to
    # try (sharing) with the command that ranks the two.
    assert _run(fit_cli, ["fit", *trial_files[:2], "--model", "viscous", "--shared", "E",
                          "--pooled", "gamma", "-o", str(tmp_path / "p"), "--elements", "4",
                          "--max-steps", "100", "--target-ess", "1000",
                          "--fixed-mesh"]) == 0
    cap = capsys.readouterr()
    err = cap.err
    assert "NOT CONVERGED" in err
    # The closing line names every file written, once.
    line = next(ln for ln in cap.out.splitlines() if ln.startswith("results in "))
    names = line.split("(", 1)[1].split(")", 1)[0].split(", ")
    assert len(names) == len(set(names)) and "fit_rel1.png" in names
    assert all((tmp_path / "p" / n).is_file() for n in names), names
    payload = json.loads((tmp_path / "p" / "summary.json").read_text())
    q = payload["posterior"]["gamma_spread"]
    assert f"gamma_spread {q['q50']:.3g} [{q['q05']:.3g}, {q['q95']:.3g}]" in err
    assert "--shared E,gamma" in err
    assert (f"compare {trial_files[0]} {trial_files[1]} --models viscous --shared E "
            "--pooled gamma`") in err
