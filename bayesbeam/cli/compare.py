"""``bayesbeam compare``: fit several models to one trial and rank them.

Several trials (with ``--shared`` / ``--pooled``): which parameters they share, see
:mod:`bayesbeam.cli.compare_joint`.

Writes into ``OUTDIR``: ``comparison.json`` (strict JSON), ``comparison.txt`` (the
table), ``comparison.html``, ``comparison.png`` (log evidence with error bars and
ELPD differences), ``zeta_vs_f.png`` (each model's modal damping ratio against
frequency, 90 % intervals, the record's own estimates overlaid; ``modes`` in the JSON)
and each model's fit in ``OUTDIR/<model>/`` (``posterior.nc``: the complete ArviZ tree,
``summary.json``, and in a serial run the sampler checkpoint ``chain.h5``). Prints the
table, or the JSON record of ``comparison.json`` with ``--json``. ``--jobs N`` fits the
models in N local processes, ``--scheduler ADDRESS`` on a Dask cluster; the numbers are
those of the serial run. See :mod:`bayesbeam.comparison.compare`
for the rules.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from bayesbeam.cli import options as opts
from bayesbeam.inference.settings import FIT_DEFAULTS

__all__ = ["parse_prior_odds", "register", "run"]

DEFAULT_MODELS = "viscous,viscous+kv,viscous+sh"


class CompareCLIError(ValueError):
    """Bad ``bayesbeam compare`` arguments."""


def parse_prior_odds(text: str | None, models: list[str]) -> dict[str, float] | None:
    """Parse ``--prior-odds``: ``"1,1,2"`` (in ``--models`` order) or ``"NAME=W,..."``.

    Parameters
    ----------
    text : str or None
        The option's value.
    models : list of str
        Canonical model names in the order of ``--models``.

    Returns
    -------
    dict or None
        Model name to relative prior odds (unnamed models get 1), or None.

    Raises
    ------
    CompareCLIError
        For malformed numbers, unknown names or a count that does not match.
    """
    if text is None or not text.strip():
        return None
    from bayesbeam.physics.models import parse_model

    items = [t.strip() for t in text.split(",") if t.strip()]
    named = ["=" in t for t in items]
    out: dict[str, float] = {}
    if all(named):
        for t in items:
            name, _, value = t.partition("=")
            key = parse_model(name.strip()).name
            if key not in models:
                raise CompareCLIError(
                    f"--prior-odds names {name.strip()!r}, which is not among --models {models}"
                )
            out[key] = _odds_number(value, t)
        return {m: out.get(m, 1.0) for m in models}
    if any(named):
        raise CompareCLIError(
            "--prior-odds: give either plain numbers in --models order (1,1,2) or NAME=ODDS "
            "pairs, not a mixture"
        )
    if len(items) != len(models):
        raise CompareCLIError(
            f"--prior-odds has {len(items)} numbers for {len(models)} models {models}"
        )
    return {m: _odds_number(v, v) for m, v in zip(models, items, strict=True)}


def _odds_number(value: str, item: str) -> float:
    try:
        v = float(value)
    except ValueError:
        raise CompareCLIError(f"--prior-odds: {item!r} is not a number") from None
    if not (v >= 0 and v != float("inf")):
        raise CompareCLIError(f"--prior-odds: odds must be finite and >= 0, got {item!r}")
    return v


def register(subparsers: Any) -> None:
    """Add the ``compare`` sub-command to ``bayesbeam``'s sub-parsers.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        Sub-parser collection of the ``bayesbeam`` parser.
    """
    sp = subparsers.add_parser(
        "compare",
        help="fit several damping models to one trial and rank them by evidence",
        description=(
            "Fit each model, estimate its log evidence (bridge sampling, with error), "
            "PSIS-LOO, WAIC, AIC and BIC, and rank the models. Models whose log evidences "
            "differ by less than max(2 x combined error, --threshold) are reported as "
            "indistinguishable."
        ),
    )
    sp.add_argument("trial", type=Path, nargs="+",
                    help="trial TOML file; several: compare what they share (--shared)")
    sp.add_argument("--models", default=DEFAULT_MODELS,
                    help=f"comma-separated model names (default {DEFAULT_MODELS})")
    opts.add_outdir_seed_options(sp)
    opts.add_elements_option(sp, help="Hermite elements")
    opts.add_fixed_mesh_option(sp)
    opts.add_preprocessing_options(sp)
    sp.add_argument("--target-ess", type=float, default=FIT_DEFAULTS.target_ess,
                    help="effective sample size per parameter to stop at")
    sp.add_argument("--max-steps", type=int, default=FIT_DEFAULTS.max_steps,
                    help="sampler step budget")
    sp.add_argument("--prior-odds", default=None, metavar="ODDS",
                    help="prior odds of the models: '1,1,2' in --models order, or "
                         "'viscous=2,viscous+kv=1' (default equal)")
    sp.add_argument("--threshold", type=float, default=None,
                    help="tie threshold on |Δ log Z| in nats (default 1; Kass & Raftery 1995)")
    sp.add_argument("--loo-draws", type=int, default=1000,
                    help="posterior draws for the pointwise log-likelihood (LOO, WAIC)")
    opts.add_executor_options(sp)
    opts.add_json_option(sp)
    joint = sp.add_argument_group(
        "several trials", "joint variants of each model (bayesbeam.comparison.joint): as "
        "asked, without the pooling, and with nothing shared")
    joint.add_argument("--shared", default=None, metavar="NAMES",
                       help="comma-separated parameters common to all trials, e.g. E")
    joint.add_argument("--pooled", default=None, metavar="NAMES",
                       help="comma-separated parameters drawn from a log-normal population")
    sp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam compare`` (heavy imports happen here).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed arguments of :func:`register`'s parser; ``models`` and ``prior_odds``
        are checked here before any fit starts.

    Returns
    -------
    int
        Exit status 0 once every model is fitted and the files are written.
    """
    from bayesbeam.cli.outdir import stamp
    from bayesbeam.comparison.compare import compare
    from bayesbeam.jobs.executor import make_executor
    from bayesbeam.physics.models import parse_model

    models = [parse_model(m.strip()).name for m in str(args.models).split(",") if m.strip()]
    if not models:
        raise CompareCLIError("--models is empty; give e.g. viscous,viscous+kv")
    if len(set(models)) != len(models):
        raise CompareCLIError(f"--models lists a model twice: {models}")
    opts.check_options(args, CompareCLIError, "elements")
    if args.max_steps < 1 or args.loo_draws < 2 or not args.target_ess > 0:
        raise CompareCLIError("--max-steps, --target-ess must be positive, --loo-draws >= 2")
    opts.check_options(args, CompareCLIError, *opts.PREPROCESSING)
    trials = args.trial if isinstance(args.trial, list) else [args.trial]
    if len(trials) > 1 or args.shared or args.pooled:
        from bayesbeam.cli.compare_joint import run_joint

        return run_joint(args, models, CompareCLIError)
    args.trial = trials[0]
    trial, pre = opts.prepare_trial(args, CompareCLIError, say=opts.say)
    odds = parse_prior_odds(args.prior_odds, models)
    models = [pre.model_name(m) for m in models]
    if odds is not None:
        odds = {pre.model_name(k): v for k, v in odds.items()}
    outdir = Path(args.outdir)
    # The models are fitted in parallel with --jobs/--scheduler (same numbers as serial).
    with make_executor(args.jobs, args.scheduler) as executor:
        result = compare(
            trial,
            models,
            prior_odds=odds,
            threshold=args.threshold,
            n_loo_draws=args.loo_draws,
            outdir=outdir,
            progress=True,
            executor=executor,
            initial=pre.initial,
            **opts.fit_settings(args),
        )
    extra = {"preprocessing": pre.to_json_dict(), **stamp(args, trial)}
    paths = result.save(outdir, extra=extra, trial=trial)  # modal posteriors need the trial
    if args.json:  # the record of comparison.json, as written
        opts.print_json(json.loads(paths["json"].read_text(encoding="utf-8")))
    else:
        print(result)
        print(f"\nwrote {outdir}/comparison.{{json,txt,html,png}} and one folder per model")
    return 0
