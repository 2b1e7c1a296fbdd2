"""``bayesbeam diagnose``: show what a model gets wrong, name the cause, measure the gain.

::

    bayesbeam diagnose TRIAL.toml --baseline viscous+kv -o OUTDIR [--json] [--seed S]
        [--max-rounds N] [--candidates kv,tip_mass,...] [--elements N]
        [--initial release|impulse|modes:K] [--decimate Q | --resample DT]
        [--window T0 T1] [--priors PRIORS.toml] [--max-steps N] [--target-ess X]
        [--jobs N | --scheduler tcp://host:port] [--resume]

Runs :func:`bayesbeam.diagnosis.diagnose.diagnose` (procedure and thresholds in its module
docstring) and writes into ``OUTDIR``:

===========================  ==========================================================
``diagnosis.json``           the record: ``named_causes`` (in the order found, empty
                             when none), ``rounds`` (``cause``, ``equivalent``,
                             ``delta_log_evidence``, ``delta_log_evidence_err``,
                             ``delta_elpd``, ``rms_before``, ``rms_after``, ...),
                             ``final_model``, ``final_posterior`` (+ ``_units``),
                             ``modes`` (f_k, ζ_k posteriors of the baseline and the
                             final model), signatures, thresholds, notes
``report.md``                short narrative: what the baseline gets wrong, the named
                             causes, the gains
``signatures_baseline.png``  residual signatures of the baseline fit
``signatures_final.png``     residual signatures of the final model's fit
``zeta_vs_f.png``            ζ_k against f_k of the baseline and the final model
``fits/MODEL/``              ``posterior.nc`` (complete ArviZ tree) and ``summary.json``
                             of the baseline and the final model
``steps/``                   every finished step (MAP search, Laplace evidence, mesh
                             check, sampled and scored model), written as it arrives
                             (:mod:`bayesbeam.diagnosis.resume`): after Ctrl-C or a
                             kill, the same command with ``--resume`` takes them and
                             computes only the rest. Emptied at the start of a run
                             without ``--resume``; removed once the diagnosis is
                             complete (a sampled model's file holds its chains: tens of
                             MB on a whole record)
===========================  ==========================================================

``--json`` prints ``diagnosis.json`` on stdout; otherwise the narrative is printed.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

from bayesbeam._util import atomic_path, one_blas_thread, write_text_atomic
from bayesbeam.cli import options as opts
from bayesbeam.inference.settings import DIAGNOSIS_DEFAULTS

__all__ = ["DiagnoseCLIError", "register", "run"]


#: What to do after an interruption (every finished step is in OUTDIR/steps).
_RESUME_HINT = ("to go on, run the same command again with --resume: the finished MAP "
                "searches, mesh checks and sampled models are taken from OUTDIR/steps")


class DiagnoseCLIError(ValueError):
    """Invalid options of ``bayesbeam diagnose``; the message says how to fix them."""


def register(subparsers: Any) -> None:
    """Add the ``diagnose`` sub-command to an ``argparse`` sub-parser collection.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The object returned by ``ArgumentParser.add_subparsers``.
    """
    sp = subparsers.add_parser(
        "diagnose",
        help="name the cause of a model discrepancy from a catalogue and measure the gain",
        description=(
            "Fit the baseline, try every catalogue extension (kv, sh, tip_mass, added_mass, "
            "root_spring, stiffness_gradient, drag, friction, amplitude_stiffness, "
            "sensor_quadratic, ar1_noise, "
            "sensor_offset), name "
            "the one "
            "with the largest significant gain in log evidence (Δ log Z - 2 err > 3 nats), "
            "extend the model and repeat. Writes diagnosis.json, report.md and signature "
            "figures to OUTDIR. SI units throughout."
        ),
    )
    opts.add_trial_argument(sp)
    sp.add_argument("--baseline", default="viscous+kv",
                    help="starting model, laws and extensions joined by '+' (default "
                         "viscous+kv)")
    opts.add_outdir_seed_options(sp)
    sp.add_argument("--max-rounds", type=int, default=3, help="most causes named (default 3)")
    sp.add_argument("--candidates", default=None,
                    help="comma-separated subset of the catalogue (default: all)")
    opts.add_elements_option(sp)
    opts.add_fixed_mesh_option(sp)
    opts.add_preprocessing_options(sp)
    sp.add_argument("--priors", type=Path, default=None,
                    help="TOML file with [priors.NAME] tables, applied to every model "
                         "that has the parameter")
    sp.add_argument("--max-steps", type=int, default=DIAGNOSIS_DEFAULTS.max_steps,
                    help=f"emcee steps per sampled model (default {DIAGNOSIS_DEFAULTS.max_steps})")
    sp.add_argument("--target-ess", type=float, default=DIAGNOSIS_DEFAULTS.target_ess,
                    help=f"bulk ESS target per sampled model "
                         f"(default {DIAGNOSIS_DEFAULTS.target_ess:g})")
    # One worker per core by default: a round's screens and samplings are independent
    # and give bit-for-bit the serial numbers, and a whole record's diagnosis takes
    # tens of minutes in one process.
    opts.add_executor_options(
        sp, default_jobs=0,
        jobs_help="worker processes for each round's candidate searches and sampling "
                  "runs (default 0: one per CPU core; 1: in this process; the numbers "
                  "are the same)")
    opts.add_json_option(sp, help="print the record as JSON")
    sp.add_argument("--resume", action="store_true",
                    help="take the finished steps of an earlier run into the same OUTDIR "
                         "(same record and settings) from OUTDIR/steps, and compute only "
                         "the rest")
    sp.set_defaults(func=run)


def _check(args: argparse.Namespace) -> list[str] | None:
    from bayesbeam.diagnosis.diagnose import CATALOGUE

    opts.check_options(args, DiagnoseCLIError, "seed")
    if args.max_rounds < 1:
        raise DiagnoseCLIError(f"--max-rounds must be >= 1, got {args.max_rounds}")
    opts.check_options(args, DiagnoseCLIError, "elements")
    if args.max_steps < 1 or not args.target_ess > 0:
        raise DiagnoseCLIError("--max-steps and --target-ess must be positive")
    opts.check_options(args, DiagnoseCLIError, *opts.PREPROCESSING)
    if args.candidates is None:
        return None
    cands = [c.strip() for c in args.candidates.split(",") if c.strip()]
    bad = [c for c in cands if c not in CATALOGUE]
    if bad or not cands:
        raise DiagnoseCLIError(
            f"--candidates: unknown cause(s) {bad}; choose from {', '.join(CATALOGUE)}"
        )
    return cands


def _predictions(trial: Any, d: Any, seed: int) -> dict[str, Any]:
    """Posterior-median signal of the baseline and the final model (the sampled fits)."""
    import numpy as np

    from bayesbeam.inference.predictive import posterior_predictive
    from bayesbeam.inference.problem import Problem

    out = {}
    rng = np.random.default_rng([seed, 2])
    for name in dict.fromkeys((d.baseline, d.final_model)):
        res = d.fits.get(name)
        if res is None:
            continue
        problem = Problem(trial, name, res.priors, n_elements=int(res.settings["n_elements"]),
                          initial=str(res.settings["initial"]))
        _, y_model, _ = posterior_predictive(problem, res, 50, rng)
        out[name] = np.median(y_model, axis=0)
    return out


def _save_fits(trial: Any, d: Any, outdir: Path) -> dict[str, Any]:
    """Write the baseline's and the final model's complete ArviZ trees and summaries.

    Into ``outdir/fits/MODEL/`` (``posterior.nc``, ``summary.json``), as ``fit`` writes
    them, so that ``arviz.loo`` / ``arviz.compare`` work on a diagnosis too.

    Returns
    -------
    dict
        ``{model: FitResult}`` with the problem attached (for the modal posteriors).
    """
    import numpy as np

    out = {}
    for name in dict.fromkeys((d.baseline, d.final_model)):
        res = d.fits.get(name)
        if res is None:
            continue
        res = res.with_problem(trial)
        res.save(outdir / "fits" / name, rng=np.random.default_rng(res.chain.seed))
        out[name] = res
    return out


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam diagnose``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options (see :func:`register`).

    Returns
    -------
    int
        Exit status 0.
    """
    from bayesbeam.cli.outdir import stamp
    from bayesbeam.diagnosis.diagnose import CATALOGUE, diagnose
    from bayesbeam.diagnosis.signatures import plot_signatures
    from bayesbeam.inference.modal import modal_posterior
    from bayesbeam.inference.modal_plots import plot_zeta_vs_f
    from bayesbeam.jobs.executor import make_executor
    from bayesbeam.physics.models import parse_model
    from bayesbeam.report.amplitude_plots import write_model_overlays
    from bayesbeam.stats.priors import PriorSet

    cands = _check(args)
    parse_model(args.baseline)  # a bad name fails before the record is read
    trial, pre = opts.prepare_trial(args, DiagnoseCLIError, say=opts.say)
    model = parse_model(pre.model_name(args.baseline))
    priors = None
    if args.priors is not None:
        priors = dict(PriorSet.from_toml(args.priors))
    outdir = Path(args.outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    # --jobs/--scheduler: each round's candidate searches and sampling runs in parallel
    # (the same numbers as serial).
    if args.resume and not any((outdir / "steps").glob("*.pkl")):
        opts.say(f"--resume: no finished steps in {outdir / 'steps'}; starting from the "
                 "beginning")
    try:
        with one_blas_thread(), make_executor(args.jobs, args.scheduler) as executor:
            d = diagnose(
                trial, model, max_rounds=args.max_rounds,
                candidates=tuple(cands) if cands else CATALOGUE, initial=pre.initial,
                priors=priors, progress=opts.say, executor=executor,
                steps_dir=outdir / "steps", resume=args.resume, **opts.fit_settings(args),
            )
    except KeyboardInterrupt:
        print(f"bayesbeam diagnose: interrupted before a round was complete; {_RESUME_HINT}",
              file=sys.stderr)
        raise
    record = d.to_json_dict()
    record["preprocessing"] = pre.to_json_dict()
    fitted = _save_fits(trial, d, outdir)
    modal = {name: modal_posterior(res.problem, res) for name, res in fitted.items()}
    record["modes"] = {name: m.to_json_dict() for name, m in modal.items()}
    record.update(stamp(args, trial))
    text = json.dumps(record, indent=2, allow_nan=False)
    write_text_atomic(outdir / "diagnosis.json", text + "\n")
    write_text_atomic(outdir / "report.md", d.narrative())
    if d.interrupted:  # what is complete is written; the figures would only delay the stop
        print(f"bayesbeam diagnose: {d.interrupted}: they are in {outdir / 'diagnosis.json'} "
              f"and report.md; {_RESUME_HINT}", file=sys.stderr)
        raise KeyboardInterrupt
    for label, sig in (("baseline", d.signatures_before), ("final", d.signatures_after)):
        if sig is not None:
            fig = plot_signatures(sig, title=f"{trial.name}: {sig.model} ({label})")
            with atomic_path(outdir / f"signatures_{label}.png") as tmp:
                fig.savefig(tmp, dpi=110)
    if modal:
        plot_zeta_vs_f(modal, outdir / "zeta_vs_f.png",
                       title=f"{trial.name}: damping ratio against frequency")
    write_model_overlays(trial, _predictions(trial, d, args.seed), outdir, say=opts.say)
    shutil.rmtree(outdir / "steps", ignore_errors=True)  # complete: nothing to resume
    if args.json:
        print(text)
    else:
        print(d.narrative())
        print(f"wrote {outdir / 'diagnosis.json'}, report.md and signature figures")
    return 0
