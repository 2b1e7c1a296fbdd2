"""Command-line interface: ``bayesbeam COMMAND ...`` (also ``python -m bayesbeam``).

Every command takes ``--json`` to print machine-readable output. Input errors print a
one-line message saying what is wrong and exit with status 2 (``--debug`` shows the
traceback).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bayesbeam.cli import options as opts

__all__ = ["main"]


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
        print(json.dumps(payload, indent=2, default=float))
    else:
        print(text)


# -- commands ----------------------------------------------------------------------
def _cmd_modes(args: argparse.Namespace) -> int:
    from bayesbeam.physics.beam import Beam
    from bayesbeam.physics.forward import modal_properties

    beam = Beam.from_toml(args.beam)
    f, z = modal_properties(beam, args.model, _parse_sets(args.set), n_elements=args.elements)
    k = min(args.n_modes, f.size)
    lines = [f"{'mode':>4} {'frequency [Hz]':>16} {'damping ratio':>14}"]
    lines += [f"{i + 1:>4} {f[i]:16.6g} {z[i]:14.6g}" for i in range(k)]
    _emit(args, {"frequencies_hz": f[:k].tolist(), "damping_ratios": z[:k].tolist()},
          "\n".join(lines))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from bayesbeam.trials.synthetic import simulate_trial

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


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line.

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0 success, 2 bad input, 130 interrupted.
    """
    parser = _build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("interrupted; finished work is kept (fits resume with --resume)", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, PermissionError, IsADirectoryError) as err:
        if args.debug:
            raise
        print(f"bayesbeam {args.command}: error: {err}", file=sys.stderr)
        return 2
