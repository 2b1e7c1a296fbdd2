"""``bayesbeam report OUTDIR``: one self-contained HTML page of the results in a folder.

::

    bayesbeam report OUTDIR [-o FILE.html] [--title TEXT] [--json]

Renders every fit (``summary.json`` and figures), comparison (``comparison.json``),
diagnosis (``diagnosis*.json``, Markdown narrative) and study summary found under
``OUTDIR`` into ``OUTDIR/report.html`` (figures embedded as base64 PNG; see
:mod:`bayesbeam.report`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``report`` sub-command to an ``argparse`` sub-parser collection.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers``.
    """
    sp = subparsers.add_parser("report", help="self-contained HTML report of an output folder",
                               description=__doc__.split("\n\n")[0])
    sp.add_argument("outdir", type=Path, help="output folder of a fit, compare, diagnose or demo")
    sp.add_argument("-o", "--output", type=Path, default=None,
                    help="HTML file to write (default OUTDIR/report.html)")
    sp.add_argument("--title", default=None, help="page title")
    sp.add_argument("--json", action="store_true", help="print {report, bytes} as JSON")
    sp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam report``.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        0 on success.
    """
    from bayesbeam.report import write_report

    path = write_report(args.outdir, path=args.output, title=args.title)
    size = path.stat().st_size
    if getattr(args, "json", False):
        print(json.dumps({"report": str(path), "bytes": size}))
    else:
        print(f"wrote {path} ({size / 1e6:.2f} MB, self-contained)")
    return 0
