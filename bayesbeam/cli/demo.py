"""``bayesbeam demo``: the source replication on the shipped data (the README's first command).

::

    bayesbeam demo [-o OUTDIR] [--jobs N] [--quick] [--scheduler tcp://host:port]
        [--data DIR] [--force] [--json]

Fits ``viscous``, ``viscous+kv`` and ``viscous+sh`` to the 15 shipped trials (3 beams ×
5 release tests), ranks them per trial and per beam by log evidence, diagnoses one
trial, prints the summary table and writes ``OUTDIR/report.html`` (see
:mod:`bayesbeam.jobs.demo` for the settings, chosen to finish in about five minutes on two
cores). Progress lines go to stderr; a re-run reuses the finished fits in ``OUTDIR``.
"""

from __future__ import annotations

import argparse
import json
import textwrap
from pathlib import Path
from typing import Any

from bayesbeam.cli import options as opts

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``demo`` sub-command to an ``argparse`` sub-parser collection.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.
    """
    sp = subparsers.add_parser(
        "demo", help="source replication on the shipped data: fits, comparison, report",
        description=__doc__.split("\n\n")[0],
    )
    sp.add_argument("-o", "--outdir", type=Path, default=Path("bayesbeam-demo"),
                    help="output folder (default ./bayesbeam-demo)")
    opts.add_executor_options(sp, default_jobs=None,
                              jobs_help="worker processes (default: one per CPU core)")
    sp.add_argument("--quick", action="store_true",
                    help="first trial of each beam only, shorter chains (about a minute)")
    sp.add_argument("--data", type=Path, default=None,
                    help="folder of the trials (default: the example trials installed with "
                         "the package)")
    sp.add_argument("--force", action="store_true", help="recompute cached results")
    opts.add_json_option(sp, help="print replication.json instead")
    sp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam demo``: run :func:`bayesbeam.jobs.demo.run_demo` and print its summary.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options: ``outdir``, ``jobs``, ``quick``, ``scheduler``, ``data``,
        ``force`` and ``json``.

    Returns
    -------
    int
        Exit status 0 (errors raise and :func:`bayesbeam.cli.main.main` reports them).
    """
    from bayesbeam.jobs.demo import run_demo

    rep = run_demo(args.outdir, jobs=args.jobs, quick=args.quick, scheduler=args.scheduler,
                   data_dir=args.data, force=args.force,
                   run_id=getattr(args, "run_id", None))
    if getattr(args, "json", False):
        print(json.dumps(rep.record, indent=2, allow_nan=False, default=str))
        return 0
    t = rep.record["timing"]
    print(rep.table)
    print()
    print(textwrap.fill(rep.record["conclusions"], 100))
    if rep.diagnosis:
        causes = rep.diagnosis.get("named_causes") or []
        print(f"Diagnosis of {rep.diagnosis.get('trial')} from {rep.diagnosis.get('baseline')}: "
              f"named causes: {', '.join(causes) if causes else 'none'} "
              f"(final model {rep.diagnosis.get('final_model')}).")
    print()
    print(textwrap.fill(rep.record["settings_text"], 100))
    print(f"Time: {t['total_s']:.0f} s in all ({t['fits_and_diagnosis_s']:.0f} s fits + "
          f"diagnosis, {t['fits_computed']} fits computed, {t['fits_cached']} cached; "
          f"{t['comparisons_s']:.0f} s comparisons; {t['report_s']:.0f} s report).")
    if rep.report is not None:
        print(f"Report: {rep.report}")
    return 0
