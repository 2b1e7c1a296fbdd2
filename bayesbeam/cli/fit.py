"""``bayesbeam fit``: Bayesian calibration of one damping model on one trial.

::

    bayesbeam fit TRIAL.toml [TRIAL2.toml ...] --model M -o OUTDIR [--seed S] [--json] [--resume]
        [--shared E,...] [--pooled c_d,...] [--no-marginalise]
        [--priors PRIORS.toml] [--elements N] [--target-ess X] [--max-steps N]
        [--initial release|impulse|modes:K] [--decimate Q | --resample DT]
        [--window T0 T1]

Steps: read the trial (:func:`bayesbeam.trials.io.read_trial`); optionally cut a time
window and then decimate (anti-alias FIR) or resample (for non-uniform stamps);
:func:`bayesbeam.inference.fit.fit` with the HDF5 checkpoint ``OUTDIR/chain.h5`` (Ctrl-C keeps
the finished steps; ``--resume`` continues them); then write into ``OUTDIR``:

==========================  ===========================================================
``posterior.nc``            complete ArviZ tree (NetCDF), units on every variable:
                            posterior thinned to about 1000
                            draws, pointwise log-likelihood of those draws,
                            posterior predictive, observed data, prior draws
``summary.json``            summary and diagnostics of the full (unthinned) chain;
                            ``modes``: f_k (Hz) and ζ_k per mode, with the data's
                            own estimates (:mod:`bayesbeam.inference.modal`)
``corner.png``              corner plot of the physical posterior
``trace.png``               walker traces
``fit.png``                 data, posterior-predictive band, residuals
``residual_spectrum.png``   residual spectrum with the model's modal frequencies
``zeta_vs_f.png``           ζ_k against f_k (log-log, 90 % intervals, data overlay,
                            slopes of viscous and Kelvin–Voigt damping)
``f1_vs_amplitude.png``     where the record has three windows or more: f1, ζ1 (and
                            mode 2) against the mode-1 amplitude, the residual's
                            spectrogram and mode 1 against time, the model's curves
                            over the data's (:mod:`bayesbeam.report.amplitude_plots`);
                            the closing line names every figure written
``run.json``                the options of the run, checked on ``--resume``
``chain.h5``                emcee checkpoint
==========================  ===========================================================

Output: the summary table (or, with ``--json``, the record of
:meth:`bayesbeam.inference.results.FitResult.to_json_dict`: ``model``, ``posterior``
({name: {mean, sd, q05, q50, q95}}), ``ess_min``, ``tau_max``, ``rhat_max``,
``converged``, ``seconds`` (sampling wall time), plus ``total_seconds`` (the whole
command), ``modes``, diagnostics, MAP, priors, settings and provenance). A run that stops at
``--max-steps`` before converging prints ``WARNING: ... NOT CONVERGED: <reason>`` on
stderr and still exits 0 with all files written.

Several trials (or ``--shared`` / ``--pooled``): a joint fit, see
:mod:`bayesbeam.cli.fit_joint`.

Preprocessing order: the window is applied first, so no data outside it reaches the
fit through the decimation filter (:meth:`bayesbeam.trials.trial.Trial.decimate` drops the
filter's edge samples inside the window instead).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from bayesbeam._util import SCHEMA_VERSION
from bayesbeam.cli import options as opts
from bayesbeam.inference.settings import FIT_DEFAULTS

__all__ = ["FitCLIError", "register", "run"]


class FitCLIError(ValueError):
    """Invalid options of ``bayesbeam fit``; the message says how to fix them."""


def register(subparsers: Any) -> None:
    """Add ``bayesbeam fit`` and its options (model, sampler budget, preprocessing).

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``bayesbeam`` sub-commands (``ArgumentParser.add_subparsers``); ``fit`` is
        added to them with :func:`run` as its handler.
    """
    sp = subparsers.add_parser(
        "fit",
        help="sample the posterior of one damping model on one trial (emcee)",
        description=(
            "Bayesian calibration of one model on one trial: data-driven MAP, then emcee "
            "until the autocorrelation-based convergence criteria hold or --max-steps. "
            "Writes posterior.nc, summary.json, corner.png, trace.png, fit.png and "
            "residual_spectrum.png to OUTDIR. SI units throughout."
        ),
    )
    sp.add_argument("trial", type=Path, nargs="+",
                    help="trial TOML file (see data/README.md); several: a joint fit")
    sp.add_argument("--model", required=True,
                    help="damping laws and extensions joined by '+', e.g. viscous+kv")
    opts.add_outdir_seed_options(sp)
    sp.add_argument("--resume", action="store_true",
                    help="continue the checkpoint OUTDIR/chain.h5 (same options required)")
    sp.add_argument("--priors", type=Path, default=None,
                    help="TOML file with [priors.NAME] dist=... tables overriding the defaults "
                         "(with several trials: every trial's; a pooled NAME sets the "
                         "population median's prior)")
    opts.add_elements_option(sp)
    opts.add_fixed_mesh_option(sp)
    sp.add_argument("--target-ess", type=float, default=FIT_DEFAULTS.target_ess,
                    help=f"bulk ESS required for every parameter "
                         f"(default {FIT_DEFAULTS.target_ess:g})")
    sp.add_argument("--max-steps", type=int, default=FIT_DEFAULTS.max_steps,
                    help=f"emcee step budget (default {FIT_DEFAULTS.max_steps})")
    sp.add_argument("--jobs", type=int, default=1, metavar="N",
                    help="processes that share each batch of the sampler (default 1; 2 "
                         "made a whole-record sampling run with drag 1.2x faster on a 2-core "
                         "machine; the chain is the same, bit for bit)")
    opts.add_preprocessing_options(sp)
    opts.add_json_option(sp, help="print the summary as JSON")
    joint = sp.add_argument_group(
        "joint fit of several trials",
        "one model on every trial given (bayesbeam.inference.joint); every parameter not "
        "named here is per trial, named NAME[TRIAL] in the output")
    joint.add_argument("--shared", default=None, metavar="NAMES",
                       help="comma-separated parameters common to all trials, e.g. E")
    joint.add_argument("--pooled", default=None, metavar="NAMES",
                       help="comma-separated positive parameters drawn per trial from a "
                            "log-normal population (median and spread sampled), e.g. c_d,gamma")
    joint.add_argument("--no-marginalise", action="store_true",
                       help="sample each trial's sigma and initial amplitudes instead of "
                            "integrating them out in closed form (by default they are "
                            "integrated out wherever that is exact and sampled otherwise, "
                            "e.g. for drag or friction)")
    sp.set_defaults(func=run)


def _check_args(args: argparse.Namespace) -> None:
    opts.check_options(args, FitCLIError, "elements", "seed")
    if not args.target_ess > 0:
        raise FitCLIError(f"--target-ess must be positive, got {args.target_ess}")
    if args.max_steps < 1:
        raise FitCLIError(f"--max-steps must be a positive integer, got {args.max_steps}")
    cores = os.cpu_count() or 1
    if not 1 <= args.jobs <= cores:
        raise FitCLIError(f"--jobs must be a number of processes from 1 to this machine's "
                          f"{cores} cores, got {args.jobs}")
    opts.check_options(args, FitCLIError, *opts.PREPROCESSING)


def _run_record(args: argparse.Namespace, trial: Any, priors: Any, model: str,
                initial: str) -> dict[str, Any]:
    """Collect the options that must not change between a run and its ``--resume``."""
    return {
        "trial_sha256": trial.sha256,
        "processing": list(trial.source.get("processing", [])),
        "n_samples": int(trial.times.size),
        "model": model,
        "seed": int(args.seed),
        "n_elements": int(args.elements),
        "initial": initial,
        "priors": None if priors is None else priors.to_dict(),
    }


def _truths(trial: Any, problem: Any) -> list[float | None] | None:
    """Return the true values of a synthetic trial (trials.synthetic), for the corner plot."""
    syn = trial.meta.get("synthetic") or trial.source
    if not isinstance(syn, dict):  # e.g. a user's `synthetic = true` in [meta]
        return None
    params = syn.get("params")
    if syn.get("generator") != "bayesbeam.trials.synthetic" or not isinstance(params, dict):
        return None
    known = {k: float(v) for k, v in params.items()}
    if "tip_deflection" in trial.initial:
        known.setdefault("w0", float(trial.initial["tip_deflection"]))
    if "noise_sd" in syn and float(syn["noise_sd"]) > 0:
        known.setdefault("sigma", float(syn["noise_sd"]))
    if "E" not in known and trial.beam.E is not None:
        known["E"] = float(trial.beam.E)
    if "eta" in problem.names and "a" in known and "b" in known:
        known["eta"] = known["a"] * float(problem.eta_per_a([known["b"]])[0])
    out = [known.get(n) for n in problem.names]
    return out if any(v is not None for v in out) else None


def _mode_freqs(problem: Any, result: Any) -> Any:
    """Natural frequencies (Hz) of the model at the posterior median, or None."""
    import numpy as np

    modes = getattr(problem.forward, "modes", None)
    if modes is None:
        return None
    theta = np.median(result.theta_samples().reshape(-1, result.chain.ndim), axis=0)
    try:
        f, _ = modes(problem.forward_params(theta[None])[0])
    except ValueError:  # e.g. an overdamped median set: plot without marks
        return None
    return f


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam fit`` (see the module docstring).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of :func:`register`'s parser.

    Returns
    -------
    int
        0 on success (also when not converged: a warning line says so).
    """
    t_start = time.perf_counter()
    _check_args(args)
    trials = args.trial if isinstance(args.trial, list) else [args.trial]
    if len(trials) > 1 or args.shared or args.pooled:
        from bayesbeam.cli.fit_joint import run_joint

        return run_joint(args, FitCLIError)
    if args.no_marginalise:
        raise FitCLIError("--no-marginalise applies to joint fits (several trials, --shared "
                          "or --pooled); a single fit samples sigma and the amplitudes")
    args.trial = trials[0]
    import numpy as np

    from bayesbeam._util import write_text_atomic
    from bayesbeam.cli.outdir import check_resume, stamp
    from bayesbeam.inference.fit import fit
    from bayesbeam.inference.predictive import PPC_DRAWS, posterior_predictive
    from bayesbeam.inference.problem import Problem, default_priors
    from bayesbeam.physics.models import parse_model
    from bayesbeam.report.amplitude_plots import write_model_overlays
    from bayesbeam.report.plots import plot_fit, plot_residual_spectrum
    from bayesbeam.stats.checkpoint import saved_steps
    from bayesbeam.stats.priors import PriorSet
    from bayesbeam.stats.sampling import NotConvergedWarning

    parse_model(args.model)  # a bad name fails before the record is read
    trial, pre = opts.prepare_trial(args, FitCLIError, say=opts.say)
    model = parse_model(pre.model_name(args.model))
    initial = pre.initial
    priors = None
    if args.priors is not None:
        base = default_priors(trial, model, n_elements=args.elements, initial=initial)
        priors = PriorSet.from_toml(args.priors, base=base)
    outdir = Path(args.outdir)
    record = _run_record(args, trial, priors, model.name, initial)
    if args.resume:
        check_resume(outdir, record, FitCLIError)
        saved_steps(outdir / "chain.h5")  # a damaged checkpoint fails now, not after the MAP
    outdir.mkdir(parents=True, exist_ok=True)
    run_id = getattr(args, "run_id", None)
    write_text_atomic(outdir / "run.json", json.dumps(
        {"schema_version": SCHEMA_VERSION, "record": record, "argv": sys.argv[1:],
         "run_id": run_id}, indent=2) + "\n")
    problem = Problem(trial, model, priors, n_elements=args.elements, initial=initial)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NotConvergedWarning)
        result = fit(
            trial,
            model,
            priors=priors,
            initial=initial,
            outdir=outdir,
            resume=args.resume,
            problem=problem,
            progress=True,
            sampler_options=opts.helper_options(args),
            **opts.fit_settings(args),
        )
    other = [w for w in caught if not issubclass(w.category, NotConvergedWarning)]
    for w in other:  # re-issue what this block was not meant to swallow
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    reasons = [str(w.message) for w in caught if issubclass(w.category, NotConvergedWarning)]
    problem = problem.with_mesh(int(result.settings["n_elements"]))  # the converged mesh

    rng = np.random.default_rng([args.seed, 1])  # independent of the sampler's stream
    # The complete ArviZ tree (FitResult.to_inference_data with the fitted problem):
    # thinned draws with their pointwise log-likelihood, posterior predictive, observed
    # data on the time axis, prior draws; every variable with its units.
    fitted = result.with_problem(problem)
    tree = fitted.to_inference_data(rng=rng)
    fitted.save(outdir, idata=tree)
    payload = result.to_json_dict()
    payload.update(stamp(args, provenance=False))  # the fit's own provenance is kept
    payload["preprocessing"] = pre.to_json_dict()
    payload["total_seconds"] = time.perf_counter() - t_start
    payload["posterior_nc_draws"] = int(tree["posterior"].sizes["chain"]
                                        * tree["posterior"].sizes["draw"])
    # f_k and zeta_k of the first modes with uncertainty (and the data's own estimates).
    from bayesbeam.inference.modal import modal_posterior
    from bayesbeam.inference.modal_plots import plot_zeta_vs_f

    modal = modal_posterior(problem, result)
    payload["modes"] = modal.to_json_dict()
    # summary.json describes the full chain (posterior.nc holds the thinned draws).
    write_text_atomic(outdir / "summary.json", json.dumps(payload, indent=2, allow_nan=False)
                      + "\n")
    result.plot_corner(outdir / "corner.png", truths=_truths(trial, problem))
    result.plot_trace(outdir / "trace.png")
    _, y_model, y_rep = posterior_predictive(problem, result, PPC_DRAWS, rng)
    plot_fit(trial, problem, result, outdir / "fit.png", rng=rng, draws=(y_model, y_rep))
    resid = np.asarray(trial.values) - np.median(y_model, axis=0)
    plot_residual_spectrum(trial, resid, outdir / "residual_spectrum.png",
                           mode_freqs_hz=_mode_freqs(problem, result))
    figures = ["corner.png", "trace.png", "fit.png", "residual_spectrum.png"]
    figures += [p.name for p in write_model_overlays(
        trial, {model.name: np.median(y_model, axis=0)}, outdir, say=opts.say)]
    if plot_zeta_vs_f(modal, outdir / "zeta_vs_f.png", title=f"{trial.name}: {model.name}") is None:
        opts.say(f"{model.name}: no zeta_vs_f.png: {modal.reason}")
    else:
        figures.append("zeta_vs_f.png")
    payload["total_seconds"] = time.perf_counter() - t_start
    payload["outdir"] = str(outdir)

    if args.json:
        opts.print_json(payload)
    else:
        print(result)
        print(f"results in {outdir}/ (posterior.nc, summary.json, {', '.join(figures)}); "
              f"{payload['total_seconds']:.1f} s in total")
    if not result.chain.converged:
        why = reasons[0] if reasons else "convergence criteria not met"
        print(f"WARNING: {model.name}: NOT CONVERGED: {why}", file=sys.stderr)
    return 0
