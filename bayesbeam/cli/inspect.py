"""``bayesbeam inspect``: what the data say before any model.

::

    bayesbeam inspect TRIAL.toml -o OUTDIR [--json] [--periods N] [--modes K]
        [--f1 HZ] [--window T0 T1]

Runs :func:`bayesbeam.trials.amplitude.amplitude_curves` on the trial's raw time stamps
(mode-1 frequency and damping ratio window by window against amplitude, mode 2 where
resolved, the offset, the residual's spectral lines) and writes into ``OUTDIR``:

==============================  =======================================================
``inspect.json``                the record (:meth:`AmplitudeCurves.to_json_dict`) with
                                the trial's name, the wall time and ``state_change``
                                (a change of state within the record:
                                :func:`bayesbeam.trials.state_change.state_change`)
                                and ``second_harmonic`` (the line at 2 f1: in phase,
                                quadrature, and whether the window means follow it:
                                :func:`bayesbeam.trials.harmonics.second_harmonic`;
                                null when not measurable)
``f1_vs_amplitude.png``         (a) f1 against mode-1 displacement amplitude
``zeta1_vs_amplitude.png``      (b) ζ1 against amplitude
``mode2_vs_amplitude.png``      (c) f2/f1 and ζ2 (only when mode 2 is resolved)
``residual_spectrogram.png``    (d) residual spectrogram with the residual lines
``mode1_vs_time.png``           (e) f1 and ζ1 against time, a change of state marked
==============================  =======================================================

The amplitude axis is the tip displacement (mode-1 shape of the trial's beam,
:func:`bayesbeam.trials.amplitude_bins.tip_factor`). A short summary is printed on
stdout (``--json``: the record); progress goes to stderr when the run takes more than
a few seconds.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from bayesbeam._util import one_blas_thread, progress_bar, write_text_atomic
from bayesbeam.cli import options as opts

__all__ = ["InspectCLIError", "register", "run", "summary_text"]


class InspectCLIError(ValueError):
    """Invalid options of ``bayesbeam inspect``; the message says how to fix them."""


def register(subparsers: Any) -> None:
    """Add the ``inspect`` sub-command to an ``argparse`` sub-parser collection.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The object returned by ``ArgumentParser.add_subparsers``.
    """
    sp = subparsers.add_parser(
        "inspect",
        help="model-free frequency and damping against amplitude, residual lines",
        description=(
            "Fit damped sinusoids in sliding windows of a few mode-1 periods on the raw "
            "time stamps; report f1 and ζ1 against amplitude, f2/f1 and ζ2 where mode 2 "
            "is resolved, the offset and the residual's spectral lines. Writes "
            "inspect.json, PNG figures and report.html to OUTDIR. SI units throughout."
        ),
    )
    opts.add_trial_argument(sp)
    sp.add_argument("-o", "--outdir", type=Path, required=True, help="output directory")
    sp.add_argument("--periods", type=float, default=4.0,
                    help="window length in mode-1 periods (default 4)")
    sp.add_argument("--modes", type=int, default=2, help="modes fitted (default 2)")
    sp.add_argument("--f1", type=float, default=None,
                    help="mode-1 frequency in Hz to start from (default: largest "
                         "spectral peak)")
    sp.add_argument("--window", type=float, nargs=2, default=None, metavar=("T0", "T1"),
                    help="keep samples with T0 <= t <= T1 (s, trial time axis)")
    opts.add_json_option(sp, help="print the record as JSON")
    sp.set_defaults(func=run)


def _check(args: argparse.Namespace) -> None:
    if not args.periods >= 1.5:
        raise InspectCLIError(f"--periods must be >= 1.5, got {args.periods}")
    if args.modes < 1:
        raise InspectCLIError(f"--modes must be >= 1, got {args.modes}")
    if args.f1 is not None and not args.f1 > 0:
        raise InspectCLIError(f"--f1 must be a positive frequency in Hz, got {args.f1}")
    opts.check_options(args, InspectCLIError, "window")


class _Progress:
    """Windows done / total with a time estimate (:func:`bayesbeam._util.progress_bar`).

    The bar appears only once the run has taken ``quiet_s`` seconds: a short record
    prints nothing but its result.
    """

    def __init__(self, quiet_s: float = 3.0) -> None:
        self.start = time.perf_counter()
        self.quiet_s = quiet_s
        self.bar: Any = None

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            if time.perf_counter() - self.start < self.quiet_s or done >= total:
                return
            self.bar = progress_bar(total, "inspect: amplitude windows", unit="window")
        self.bar.update(done - self.bar.n)
        if done >= total:
            self.bar.close()


def _fmt(v: float | None, spec: str) -> str:
    return "n/a" if v is None else format(v, spec)


def summary_text(record: dict[str, Any]) -> str:
    """Short text summary of an ``inspect.json`` record.

    Parameters
    ----------
    record : dict
        The record written by :func:`run`.

    Returns
    -------
    str
        f1 and ζ1 at the smallest and largest amplitude bins, f2/f1, offset, residual
        lines.
    """
    bins = record["bins"]
    lines = [f"{record['trial']}: {len(record['windows']['centre_s'])} windows of "
             f"{record['window_s']:.3g} s ({record['quantity']})"]
    for name, b in (("smallest", bins[0]), ("largest", bins[-1])) if bins else ():
        lines.append(
            f"  {name} amplitude bin ({_fmt(b['amplitude_m'], '.3g')} m, {b['n']} windows): "
            f"f1 = {_fmt(b['f1'], '.5f')} ± {_fmt(b['f1_se'], '.1g')} Hz, "
            f"ζ1 = {_fmt(b['zeta1'], '.5f')} ± {_fmt(b['zeta1_se'], '.1g')}")
    ratios = [b["ratio"] for b in bins if b["ratio"] is not None]
    lines.append("  f2/f1 = " + (", ".join(f"{r:.4f}" for r in ratios[-3:]) +
                                 " (largest amplitude bins)" if ratios else "n/a (mode 2 "
                                 "not resolved)"))
    offs = [v for v in record["windows"]["offset"] if v is not None]
    if offs:
        lines.append(f"  offset: {min(offs):.3g} to {max(offs):.3g} "
                     f"(median {sorted(offs)[len(offs) // 2]:.3g}) SI units")
    rl = record["residual_lines"]
    if rl:
        lines.append("  residual lines: " + "; ".join(
            f"{x['frequency_hz']:.2f} Hz ({x['label']}, {x['amplitude']:.2g})" for x in rl))
    else:
        lines.append("  residual lines: none above the threshold")
    sc = record.get("state_change")
    if sc is not None:
        lines.append(f"  {sc['reason']}")
    from bayesbeam.trials.harmonics import harmonic_text

    sh = record.get("second_harmonic")
    lines.append("  " + (harmonic_text(sh) if sh is not None else
                         "second harmonic of mode 1: not measurable (fewer than three "
                         "windows above 5 % of the largest amplitude)"))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Execute ``bayesbeam inspect``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options (see :func:`register`).

    Returns
    -------
    int
        Exit status 0.
    """
    import numpy as np

    from bayesbeam.cli.outdir import stamp
    from bayesbeam.report.amplitude_plots import write_amplitude_figures
    from bayesbeam.trials.amplitude import amplitude_curves, tip_factor
    from bayesbeam.trials.harmonics import second_harmonic
    from bayesbeam.trials.io import read_trial
    from bayesbeam.trials.preprocess import plan
    from bayesbeam.trials.state_change import state_change

    _check(args)
    trial = read_trial(args.trial)
    # The span is chosen as for a fit (a raw record: from just after the release or
    # impact to the end of the motion); the estimator then works on the raw stamps, so
    # the rate, initial-state and offset choices do not apply here.
    given = {} if args.window is None else {"start": args.window[0], "end": args.window[1]}
    pre = plan(trial, **given)
    if pre.start > trial.times[0] or pre.end < trial.times[-1]:
        trial = trial.window(pre.start, pre.end)
    print(f"preprocessing: {pre.lines()[0]}", file=sys.stderr, flush=True)
    tic = time.perf_counter()
    with one_blas_thread():
        curves = amplitude_curves(trial.times, trial.values, f1=args.f1, n_modes=args.modes,
                                  periods=args.periods, quantity=trial.quantity,
                                  tip_factor=tip_factor(trial.beam), progress=_Progress())
    change = state_change(curves)
    f1s = curves.frequency[:, 0]
    f1s = f1s[np.isfinite(f1s)]
    with one_blas_thread():
        harmonic = second_harmonic(trial.times, trial.values,
                                   float(np.median(f1s)) if f1s.size else math.nan)
    span = {k: v for k, v in pre.to_json_dict().items()
            if k in ("start", "end", "start_how", "end_how", "release", "given", "loader")}
    record = {"trial": trial.name, "n_samples": int(trial.times.size),
              "preprocessing": {**span, "note": "raw stamps in the span (no resampling)"},
              **curves.to_json_dict(),
              "state_change": change.to_json_dict(),
              "second_harmonic": None if harmonic is None else harmonic.to_json_dict(),
              "wall_time_s": round(time.perf_counter() - tic, 3),
              **stamp(args, trial)}
    outdir = Path(args.outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    text = json.dumps(record, indent=2, allow_nan=False)
    write_text_atomic(outdir / "inspect.json", text + "\n")
    write_amplitude_figures(curves, outdir, title=trial.name, change=change)
    from bayesbeam.report.html import write_report

    write_report(outdir, title=f"bayesbeam inspect: {trial.name}")
    print(text if args.json else summary_text(record))
    return 0
