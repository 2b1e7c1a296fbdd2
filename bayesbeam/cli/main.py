"""Command-line interface: ``bayesbeam COMMAND ...`` (also ``python -m bayesbeam``).

Every command takes ``--json`` to print machine-readable output (stdout holds only
that; progress, notes and warnings go to stderr, one line each). Every failure ends in
one line on stderr, ``bayesbeam COMMAND: error: ...``, that names the file or value and
the fix, and one of these exit statuses (:data:`EXIT`):

====  ===========================================================================
0     success (a run that did not converge or is not adequate says so on stderr)
1     internal error: a bug. The line says where the full traceback was written
2     bad input: options, trial, beam or prior files, data the checks refuse, a damaged
      checkpoint given to ``--resume``
3     input/output failure: disk full, file too large, permissions
4     the output folder is in use by another run (see :mod:`bayesbeam.cli.outdir`)
5     out of memory
130   interrupted (Ctrl-C); finished work is kept and ``--resume`` continues it
====  ===========================================================================

``--debug`` re-raises instead, with Python's traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import errno
import json
import os
import sys
import tempfile
import traceback
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bayesbeam._util import SCHEMA_VERSION, finite_json
from bayesbeam.cli import options as opts

__all__ = ["EXIT", "main"]

#: Exit statuses of :func:`main` (the module docstring says when each is used).
EXIT = {"ok": 0, "internal": 1, "input": 2, "io": 3, "busy": 4, "memory": 5,
        "interrupted": 130}


class CLIError(ValueError):
    """Bad command-line input."""


def _parse_sets(items: Sequence[str]) -> dict[str, float]:
    out: dict[str, float] = {}
    for item in items or ():
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise CLIError(f"--set expects NAME=VALUE (SI units), got {item!r}")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise CLIError(f"--set {name}: {value!r} is not a number (SI units)") from None
    return out


def _emit(args: argparse.Namespace, payload: dict[str, Any], text: str) -> None:
    if args.json:
        # Strict JSON: a NaN (e.g. the bench's band-limited row has no difference to the
        # full propagation) becomes null.
        print(json.dumps(finite_json({"schema_version": SCHEMA_VERSION, **payload}), indent=2,
                         default=float, allow_nan=False))
    else:
        print(text)


# -- commands ----------------------------------------------------------------------
def _cmd_modes(args: argparse.Namespace) -> int:
    from bayesbeam.physics.beam import Beam
    from bayesbeam.physics.forward import modal_properties

    if args.n_modes < 1:
        raise CLIError(f"--n-modes must be a positive integer (how many modes to print), "
                       f"got {args.n_modes}")
    opts.check_options(args, CLIError, "elements")
    beam = Beam.from_toml(args.beam)
    f, z, n_over = modal_properties(beam, args.model, _parse_sets(args.set),
                                    n_elements=args.elements, return_overdamped=True)
    k = min(args.n_modes, f.size)
    lines = [f"{'mode':>4} {'frequency [Hz]':>16} {'damping ratio':>14}"]
    lines += [f"{i + 1:>4} {f[i]:16.6g} {z[i]:14.6g}" for i in range(k)]
    payload: dict[str, Any] = {"frequencies_hz": f[:k].tolist(),
                               "damping_ratios": z[:k].tolist(), "overdamped_modes": n_over}
    if n_over:
        # Without this line a damping above critical would print an empty table.
        why = ("damping above critical: real eigenvalues, they decay without oscillating "
               "and have no frequency")
        if f.size == 0:
            note = f"all {n_over} modes of the model are overdamped ({why}): none to list"
        else:
            verb = "is" if n_over == 1 else "are"
            note = (f"{n_over} of the model's {n_over + f.size} modes {verb} overdamped "
                    f"({why}); listed are the {f.size} underdamped ones")
        payload["note"] = note
        opts.say(f"note: {note}")
    _emit(args, payload, "\n".join(lines))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from bayesbeam.trials.synthetic import simulate_trial

    # duration, dt, noise sd, tip deflection and the sample count are checked by
    # simulate_trial, before it allocates anything.
    opts.check_options(args, CLIError, "elements", "seed")
    trial = simulate_trial(
        args.beam,
        args.model,
        _parse_sets(args.set),
        duration=args.duration,
        dt=args.dt,
        tip_deflection=args.tip_deflection,
        noise_sd=args.noise_sd,
        seed=args.seed,
        n_elements=args.elements,
        out=args.output,
    )
    _emit(
        args,
        {"trial": str(args.output), "n_samples": int(trial.times.size),
         "quantity": trial.quantity},
        f"wrote {args.output} ({trial.times.size} samples of {trial.quantity})",
    )
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from bayesbeam.jobs.bench import format_bench, run_bench

    res = run_bench(n_elements=args.elements, repeats=args.repeats)
    _emit(args, res, format_bench(res))
    return 0


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="bayesbeam",
        description="Bayesian damping identification for cantilever beams (SI units).",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    from bayesbeam._util import distribution_version

    p.add_argument("--version", action="version",
                   version=f"bayesbeam {distribution_version('bayesbeam')}")
    sub = p.add_subparsers(dest="command", required=True)

    sp = sub.add_parser("modes", help="natural frequencies and modal damping ratios")
    sp.add_argument("beam", type=Path, help="beam TOML file ([beam] table, SI units)")
    sp.add_argument("--model", default="viscous", help="e.g. viscous, viscous+kv, viscous+sh")
    sp.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="parameter value in SI units (E in Pa, gamma, c_d, a, b)")
    opts.add_elements_option(sp, help=None)
    sp.add_argument("--n-modes", type=int, default=6, help="how many modes to print")
    opts.add_json_option(sp)
    sp.set_defaults(func=_cmd_modes)

    sp = sub.add_parser("simulate", help="write a synthetic trial (TOML + CSV)")
    sp.add_argument("beam", type=Path)
    sp.add_argument("--model", default="viscous")
    sp.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    sp.add_argument("--duration", type=float, default=5.0, help="s")
    sp.add_argument("--dt", type=float, default=0.003906, help="sample interval, s")
    sp.add_argument("--tip-deflection", type=float, default=0.005, help="release deflection, m")
    sp.add_argument("--noise-sd", type=float, default=0.0, help="Gaussian noise sd, SI units")
    sp.add_argument("--seed", type=int, default=0)
    opts.add_elements_option(sp, help=None)
    sp.add_argument("-o", "--output", type=Path, required=True, help="trial TOML to write")
    opts.add_json_option(sp)
    sp.set_defaults(func=_cmd_simulate)

    sp = sub.add_parser("bench", help="forward-model benchmark")
    opts.add_elements_option(sp, help=None)
    sp.add_argument("--repeats", type=int, default=7)
    opts.add_json_option(sp)
    sp.set_defaults(func=_cmd_bench)

    # Commands of the later stages live in their own modules (each imports its heavy
    # dependencies only when run).
    from bayesbeam.cli import compare, demo, diagnose, fit, inspect, report

    for mod in (fit, compare, diagnose, report, demo, inspect):
        mod.register(sub)
    return p


def _one_line(message: Any, *_: Any, **__: Any) -> None:
    """``warnings.showwarning`` of the CLI: ``warning: message`` on stderr, no source line."""
    print(f"warning: {message}", file=sys.stderr, flush=True)


def _write_traceback(command: str) -> Path | None:
    """Write the current exception's traceback to a file in the temp folder; its path."""
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    try:
        fd, name = tempfile.mkstemp(prefix=f"bayesbeam-{command}-{stamp}-", suffix=".txt")
        with open(fd, "w", encoding="utf-8") as fh:
            fh.write(f"bayesbeam {command}: argv {sys.argv!r}\n\n")
            fh.write(traceback.format_exc())
    except OSError:  # nowhere to write it (the disk may be full): the caller prints it
        return None
    return Path(name)


def _os_error(err: OSError) -> tuple[int, str]:
    """Exit status and message of an operating-system error (names the file)."""
    where = f" ({err.filename})" if err.filename else ""
    # HDF5's messages run over several lines: the system's wording of the errno is enough.
    what = (os.strerror(err.errno) if err.errno else str(err).splitlines()[0][:200]
            if str(err) else type(err).__name__)
    if err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return EXIT["io"], (f"{what}{where}: free disk space (or raise the quota) and run "
                            "again; files written before are whole, and fits continue "
                            "with --resume")
    if err.errno == errno.ENAMETOOLONG:
        return EXIT["input"], f"file name too long{where[:80]}...): use a shorter path"
    if isinstance(err, FileNotFoundError | IsADirectoryError | NotADirectoryError):
        return EXIT["input"], f"{what}{where}: check the path"
    if isinstance(err, PermissionError):
        return EXIT["io"], f"{what}{where}: check the file's permissions or choose another path"
    return EXIT["io"], f"{what}{where}"


def _run(args: argparse.Namespace) -> int:
    """Run the command inside its claimed output folder (see :mod:`bayesbeam.cli.outdir`)."""
    from bayesbeam.cli.outdir import claim

    outdir = getattr(args, "outdir", None)
    if outdir is None:
        args.run_id = None
        return int(args.func(args))
    with claim(outdir, args.command, create=args.command != "report",
               say=opts.say) as run_id:
        args.run_id = run_id
        return int(args.func(args))


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status, one of :data:`EXIT` (see the module docstring).
    """
    parser = _build_parser()
    args = parser.parse_args(argv)
    from bayesbeam.cli.outdir import OutdirBusy

    def fail(status: int, message: str) -> int:
        print(f"bayesbeam {args.command}: error: {message}", file=sys.stderr)
        return status

    with warnings.catch_warnings():
        warnings.showwarning = _one_line  # restored on exit (tests call main in-process)
        try:
            return _run(args)
        except KeyboardInterrupt:
            print("interrupted; finished work is kept (fits resume with --resume)",
                  file=sys.stderr)
            return EXIT["interrupted"]
        except BrokenPipeError:  # stdout closed early (e.g. piped into `head`)
            with contextlib.suppress(OSError):
                sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - no flush error at exit
            return EXIT["ok"]
        except Exception as err:
            if args.debug:
                raise
            if isinstance(err, OutdirBusy):
                return fail(EXIT["busy"], str(err))
            if isinstance(err, MemoryError):
                return fail(EXIT["memory"], "out of memory; analyse fewer samples (--rate, "
                            "--max-samples, --window) or use fewer --elements")
            if isinstance(err, UnicodeError):
                return fail(EXIT["input"], f"a file is not UTF-8 text ({err}); save it as UTF-8")
            if isinstance(err, ValueError):
                return fail(EXIT["input"], str(err))
            if isinstance(err, OSError):
                return fail(*_os_error(err))
            path = _write_traceback(args.command)
            if path is None:
                traceback.print_exc()
                where = "the traceback is above"
            else:
                where = f"the full traceback is in {path}"
            return fail(EXIT["internal"], f"internal error ({type(err).__name__}: {err}); "
                        f"this is a bug: {where}; please report it with that traceback")
