"""``bayesbeam fit T1.toml T2.toml ... --shared E [--pooled c_d]``: one model on several trials.

The joint path of ``bayesbeam fit`` (:func:`bayesbeam.inference.joint_fit.fit_joint`): taken
when more than one trial is given, or ``--shared`` / ``--pooled``. Each trial is read and
prepared as for a single fit (window, decimation, the sanity checks). Writes into OUTDIR:

==========================  ===========================================================
``summary.json``            joint summary: ``posterior`` (shared names as in a single
                            fit, per-trial names ``NAME[TRIAL]``, population
                            ``NAME_median`` / ``NAME_spread``), diagnostics, ``joint``
                            (labels, shared, pooled, marginalised), ``adequate`` and
                            ``trials`` (per label: trial, adequacy, posterior)
``posterior.nc``            ArviZ tree with a ``trial`` dimension (see
                            :meth:`~bayesbeam.inference.joint_fit.JointFit.to_inference_data`)
``corner.png``              corner plot of the shared and population parameters
``trace.png``               walker traces of every sampled parameter
``fit_TRIAL.png``           per trial: data, predictive band, residuals
``run.json``                the options of the run
``chain.h5``                emcee checkpoint (``--resume`` continues it)
==========================  ===========================================================
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bayesbeam._util import SCHEMA_VERSION
from bayesbeam.cli import options as opts

__all__ = ["run_joint", "split_names"]


def split_names(text: str | None) -> tuple[str, ...]:
    """Names of a comma-separated option value (``"E,c_d"`` -> ``("E", "c_d")``)."""
    if not text:
        return ()
    return tuple(n.strip() for n in text.split(",") if n.strip())


def prepare_trials(args: argparse.Namespace, models: list[str], error: type[Exception]
                   ) -> tuple[list[Any], list[Any], list[str], str | list[str]]:
    """Read and prepare the trials of a several-trial command (``fit``, ``compare``).

    Each trial is preprocessed on its own (:func:`bayesbeam.cli.options.prepare_trial`).
    Every model name becomes the one the preprocessing asks for (a raw record's sensor
    offset), which must be the same for all trials; each trial keeps its own initial
    condition (records of different length resolve different numbers of modes).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options; ``trial`` is the list of paths.
    models : list of str
        Model names as given.
    error : type of Exception
        The command's error class.

    Returns
    -------
    trials, pres : list
        The prepared trials and their preprocessing records.
    models : list of str
        The model names for these trials.
    initial : str or list of str
        One kind for all trials, or one per trial where they differ.
    """
    trials, pres = [], []
    for p in args.trial:
        one = argparse.Namespace(**{**vars(args), "trial": p})
        trial, pre = opts.prepare_trial(one, error, say=opts.say)
        trials.append(trial)
        pres.append(pre)
    named = []
    for m in models:
        per = {pre.model_name(m) for pre in pres}
        if len(per) != 1:
            raise error(f"the preprocessing gives the trials different models {sorted(per)} "
                        "(a sensor offset added to some); use the same models for all")
        named.append(per.pop())
    per_trial = [pre.initial for pre in pres]
    initial: str | list[str] = per_trial[0] if len(set(per_trial)) == 1 else per_trial
    return trials, pres, named, initial


def _pooled_hint(pooled: Sequence[str], shared: Sequence[str],
                 posterior: dict[str, dict[str, float]], compare: str) -> str:
    """Return the line after an unconverged pooled fit: what mixes slowly, what to try.

    A pooled parameter whose spread is small against what one trial resolves of it is a
    funnel for the sampler (studies/README.md: beam 1's pooled damping laws mixed with τ
    734 steps and met the convergence rule at 39,100; with the laws shared, τ was 155 at
    4,000 steps), so the spreads' intervals are printed for the
    user to judge, with the limit to compare against (``compare``: the start of the
    ``bayesbeam compare`` command line for these trials and model).
    """
    spreads = "; ".join(
        f"{n}_spread {q['q50']:.3g} [{q['q05']:.3g}, {q['q95']:.3g}]"
        for n in pooled for q in [posterior[f"{n}_spread"]])
    names = ",".join(pooled)
    now = f"--shared {','.join(shared)} " if shared else ""
    return (f"note: pooled parameters mix slowly where a spread (sd of the log between "
            f"trials) is small against what one trial resolves: {spreads} (median, 90 % "
            f"interval). Where an interval reaches near zero, --shared "
            f"{','.join([*shared, *pooled])} fits that limit in far fewer steps, and "
            f"`{compare} {now}--pooled {names}` ranks pooled, per-trial and shared by "
            "evidence; or raise --max-steps")


def _file_label(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)


def run_joint(args: argparse.Namespace, error: type[Exception]) -> int:
    """Execute the joint path of ``bayesbeam fit`` (see the module docstring).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of ``bayesbeam fit`` (``trial`` is a list of paths).
    error : type of Exception
        The command's error class.

    Returns
    -------
    int
        0 on success (also when not converged or inadequate: a warning line says so).
    """
    t_start = time.perf_counter()
    import numpy as np

    from bayesbeam._util import write_text_atomic
    from bayesbeam.cli.outdir import check_resume, stamp
    from bayesbeam.inference.joint import JointError
    from bayesbeam.inference.joint_fit import fit_joint
    from bayesbeam.inference.predictive import PPC_DRAWS, posterior_predictive
    from bayesbeam.inference.problem import default_priors
    from bayesbeam.physics.models import parse_model
    from bayesbeam.report.plots import plot_fit
    from bayesbeam.stats.priors import PriorSet
    from bayesbeam.stats.sampling import NotConvergedWarning

    parse_model(args.model)
    paths = list(args.trial)
    if len({p.resolve() for p in paths}) != len(paths):
        raise error(f"a trial is given twice in {[str(p) for p in paths]}; give each once")
    trials, pres, named, initial = prepare_trials(args, [args.model], error)
    model = parse_model(named[0])
    shared, pooled = split_names(args.shared), split_names(args.pooled)
    overrides = None
    if args.priors is not None:  # the file's entries, applied to every trial
        base = default_priors(trials[0], model, n_elements=args.elements, initial=pres[0].initial)
        full = PriorSet.from_toml(args.priors, base=base)
        overrides = {n: full[n] for n in full if full[n] != base[n]}
    outdir = Path(args.outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    record = {"trial_sha256": [t.sha256 for t in trials], "model": model.name,
              "shared": list(shared), "pooled": list(pooled),
              "marginalise": not args.no_marginalise, "seed": int(args.seed),
              "n_elements": int(args.elements), "initial": initial,
              "priors": None if overrides is None else {n: p.to_dict()
                                                        for n, p in overrides.items()}}
    run_path = outdir / "run.json"
    if args.resume:
        check_resume(outdir, record, error)
    write_text_atomic(run_path, json.dumps({"schema_version": SCHEMA_VERSION, "record": record,
                                            "argv": sys.argv[1:]}, indent=2) + "\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", NotConvergedWarning)
        try:
            jf = fit_joint(trials, model, shared=shared, pooled=pooled,
                           marginalise=False if args.no_marginalise else None,
                           initial=initial, outdir=outdir,
                           resume=args.resume, progress=True, priors=overrides,
                           sampler_options=opts.helper_options(args),
                           **opts.fit_settings(args))
        except JointError as exc:
            raise error(str(exc)) from None
    for w in caught:
        if not issubclass(w.category, NotConvergedWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    reasons = [str(w.message) for w in caught if issubclass(w.category, NotConvergedWarning)]
    rng = np.random.default_rng([args.seed, 1])
    tree = jf.to_inference_data(rng=rng)
    tree.to_netcdf(outdir / "posterior.nc")
    payload = jf.to_json_dict()
    payload.update(stamp(args, provenance=False))
    payload["preprocessing"] = {lb: pre.to_json_dict() for lb, pre in zip(jf.labels, pres,
                                                                           strict=True)}
    jp = jf.problem
    top = [*jp.shared, *(f"{n}_{s}" for n in jp.pooled for s in ("median", "spread"))]
    figures = ["corner.png"] if top else []
    if top:
        jf.result.plot_corner(outdir / "corner.png", names=top)
    jf.result.plot_trace(outdir / "trace.png")
    figures.append("trace.png")
    for lb, view, trial in zip(jf.labels, jf.trials, trials, strict=True):
        pb = view.problem
        _, y_model, y_rep = posterior_predictive(pb, view, PPC_DRAWS, rng)
        path = outdir / f"fit_{_file_label(lb)}.png"
        plot_fit(trial, pb, view, path, rng=rng, draws=(y_model, y_rep),
                 title=f"{lb}: joint fit of {len(trials)} trials, model {view.model!r}, "
                       f"{y_model.shape[0]} posterior draws")
        figures.append(path.name)
    payload["figures"] = figures
    payload["total_seconds"] = time.perf_counter() - t_start
    payload["outdir"] = str(outdir)
    write_text_atomic(outdir / "summary.json", json.dumps(payload, indent=2, allow_nan=False)
                      + "\n")
    if args.json:
        opts.print_json(payload)
    else:
        print(jf)
        print(f"results in {outdir}/ (posterior.nc, summary.json, {', '.join(figures)}); "
              f"{payload['total_seconds']:.1f} s in total")
    if not jf.result.chain.converged:
        why = reasons[0] if reasons else "convergence criteria not met"
        print(f"WARNING: joint {model.name}: NOT CONVERGED: {why}", file=sys.stderr)
        if jp.pooled:
            compare = (f"bayesbeam compare {' '.join(map(str, args.trial))} --models "
                       f"{model.name}")
            print(_pooled_hint(jp.pooled, jp.shared, payload["posterior"], compare),
                  file=sys.stderr)
    if not jf.ok:
        bad = [lb for lb, v in zip(jf.labels, jf.trials, strict=True) if not v.adequacy.get("ok")]
        print(f"WARNING: joint {model.name}: the model does not reproduce {bad} to their noise "
              "(see summary.json trials.*.adequacy)", file=sys.stderr)
    return 0
