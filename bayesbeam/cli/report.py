"""``bayesbeam report OUTDIR``: one self-contained HTML page of the results in a folder.

::

    bayesbeam report OUTDIR [-o FILE.html] [--title TEXT] [--json]

Renders every fit (``summary.json`` and figures), comparison (``comparison.json``),
diagnosis (``diagnosis*.json``, Markdown narrative) and study summary found under
``OUTDIR`` into ``OUTDIR/report.html`` (figures embedded as base64 PNG; see
:mod:`bayesbeam.report.html`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from bayesbeam.cli import options as opts

__all__ = ["register", "run"]


def register(subparsers: Any) -> None:
    """Add the ``report`` sub-command (renders an existing output folder; no fitting).

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        Where ``report`` goes: the result of ``ArgumentParser.add_subparsers``.
    """
    sp = subparsers.add_parser("report", help="self-contained HTML report of an output folder",
                               description=__doc__.split("\n\n")[0])
    sp.add_argument("outdir", type=Path, help="output folder of a fit, compare, diagnose or demo")
    sp.add_argument("-o", "--output", type=Path, default=None,
                    help="HTML file to write (default OUTDIR/report.html)")
    sp.add_argument("--title", default=None, help="page title")
    opts.add_json_option(sp, help="print {report, bytes} as JSON")
    sp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam report``: write the HTML page and print where it went.

    The page embeds its figures, so it can be moved or mailed on its own.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options: ``outdir`` (folder to render), ``output`` (HTML path or None),
        ``title`` and ``json``.

    Returns
    -------
    int
        Exit status 0; a missing folder raises (reported with status 2).
    """
    from bayesbeam.report.html import write_report

    path = write_report(args.outdir, path=args.output, title=args.title)
    size = path.stat().st_size
    if getattr(args, "json", False):
        print(json.dumps({"report": str(path), "bytes": size}))
    else:
        print(f"wrote {path} ({size / 1e6:.2f} MB, self-contained)")
    return 0
