"""``bayesbeam compare T1.toml T2.toml ... --shared E [--pooled c_d]``: what the trials share.

The several-trial path of ``bayesbeam compare``
(:func:`bayesbeam.comparison.joint.compare_joint`). For each model of ``--models`` it fits
the joint variants

* ``--shared`` (and ``--pooled``, when given) as asked,
* the same without the pooling (when ``--pooled`` is given): every trial its own value,
* the pooled parameters shared instead (when ``--pooled`` is given): one value for all
  trials, the pooling's other limit,
* nothing shared: every trial on its own (when ``--shared`` is given),

and ranks them by bridge-sampling evidence with the package's tie rule; PSIS-LOO over
all trials' samples is reported beside it. Writes ``comparison.json`` (one record per
model: ``variants``, ``best``, ``tied``, ``decided``, ``delta_log_z`` ± ``_err``,
``verdict``) and ``comparison.txt`` into OUTDIR, and each variant's joint fit summary
in ``OUTDIR/<model>/<variant>/summary.json``. ``--jobs N`` (or ``--scheduler``) fits the
variants in parallel.
"""

from __future__ import annotations

import argparse
import json
import re
import warnings
from pathlib import Path

from bayesbeam._util import SCHEMA_VERSION
from bayesbeam.cli import options as opts
from bayesbeam.cli.fit_joint import prepare_trials, split_names

__all__ = ["run_joint"]


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+-]+", "_", text).strip("_")


def run_joint(args: argparse.Namespace, models: list[str], error: type[Exception]) -> int:
    """Execute the several-trial path of ``bayesbeam compare`` (module docstring).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options of ``bayesbeam compare`` (``trial`` is a list of paths).
    models : list of str
        Canonical model names of ``--models``.
    error : type of Exception
        The command's error class.

    Returns
    -------
    int
        0 once every variant is fitted and the files are written.
    """
    from bayesbeam._util import write_text_atomic
    from bayesbeam.cli.outdir import stamp
    from bayesbeam.comparison.joint import compare_joint, variant_name
    from bayesbeam.inference.joint import JointError
    from bayesbeam.jobs.executor import make_executor
    from bayesbeam.stats.sampling import NotConvergedWarning

    if args.prior_odds:
        raise error("--prior-odds applies to one trial; several trials compare joint variants "
                    "with equal prior odds")
    shared, pooled = split_names(args.shared), split_names(args.pooled)
    if not shared and not pooled:
        raise error("several trials: give --shared (e.g. --shared E) and/or --pooled; the "
                    "comparison is of what the trials share")
    trials, _, models, initial = prepare_trials(args, models, error)
    variants = [(shared, pooled)]
    if pooled:
        # Partial pooling between its two limits: every trial its own value, and one
        # value for all (a spread of zero, which the pooled fit cannot reach exactly).
        variants.append((shared, ()))
        variants.append(((*shared, *pooled), ()))
    if shared:
        variants.append(((), ()))
    outdir = Path(args.outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    threshold = 1.0 if args.threshold is None else float(args.threshold)
    records, texts = {}, []
    for model in models:
        opts.say(f"compare: {model}: {len(variants)} joint variants on {len(trials)} trials")
        # --jobs/--scheduler fit the variants in parallel (same numbers as serial; a
        # worker's warnings come back as the scores' notes, shown in the table).
        with warnings.catch_warnings(record=True) as caught, \
                make_executor(args.jobs, args.scheduler) as executor:
            warnings.simplefilter("always", NotConvergedWarning)
            try:
                settings = opts.fit_settings(args)  # holds the seed
                cmp = compare_joint(trials, model, variants, threshold=threshold,
                                    progress=True, executor=executor, initial=initial,
                                    **settings)
            except JointError as exc:
                raise error(str(exc)) from None
        for w in caught:
            if issubclass(w.category, NotConvergedWarning):
                opts.say(f"WARNING: {model}: a joint fit did NOT converge: {w.message}")
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        for s in cmp.scores:
            sub = outdir / _slug(model) / _slug(variant_name("", s.fit.problem.shared,
                                                             s.fit.problem.pooled))
            sub.mkdir(parents=True, exist_ok=True)
            write_text_atomic(sub / "summary.json", json.dumps(
                {"schema_version": SCHEMA_VERSION, **s.fit.to_json_dict()}, indent=2,
                allow_nan=False) + "\n")
        records[model] = cmp.to_json_dict()
        texts.append(f"== {model} ==\n{cmp.table()}")
    payload = {"schema_version": SCHEMA_VERSION, "trials": [t.name for t in trials],
               "models": records}
    payload.update(stamp(args))
    write_text_atomic(outdir / "comparison.json",
                      json.dumps(payload, indent=2, allow_nan=False) + "\n")
    write_text_atomic(outdir / "comparison.txt", "\n\n".join(texts) + "\n")
    if args.json:
        opts.print_json(payload)
    else:
        print("\n\n".join(texts))
    return 0
