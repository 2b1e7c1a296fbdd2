"""Command-line options shared by the ``bayesbeam`` sub-commands, and their checks.

Each sub-command module (:mod:`bayesbeam.cli.main`, :mod:`bayesbeam.cli.fit`,
:mod:`bayesbeam.cli.compare`, :mod:`bayesbeam.cli.diagnose`, :mod:`bayesbeam.cli.demo`,
:mod:`bayesbeam.cli.report`) builds its parser from these pieces, so an option that
two commands share has one name, default, help text and error message:

* ``add_*`` functions add options to an ``argparse`` parser;
* :func:`check_options` validates the parsed values and raises the calling command's
  error class (a :class:`ValueError`, reported by :func:`bayesbeam.cli.main.main` with exit
  status 2);
* :func:`fit_settings` maps the sampler options to the keywords of
  :func:`bayesbeam.inference.fit.fit`, :func:`bayesbeam.comparison.compare.compare` and
  :func:`bayesbeam.diagnosis.diagnose.diagnose`;
* :func:`prepare_trial` reads the trial and applies ``--window`` and
  ``--decimate``/``--resample``;
* :func:`print_json` prints a strict-JSON record (``--json``).

Nothing heavy is imported at import time: the defaults come from
:mod:`bayesbeam.inference.settings` (standard library only), the trial reader is
imported when called.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bayesbeam.inference.settings import FIT_DEFAULTS

__all__ = [
    "PREPROCESSING",
    "add_elements_option",
    "add_fixed_mesh_option",
    "add_json_option",
    "add_outdir_seed_options",
    "add_preprocessing_options",
    "add_trial_argument",
    "check_options",
    "fit_settings",
    "initial_condition",
    "prepare_trial",
    "say",
    "print_json",
]


def initial_condition(text: str) -> str:
    """Parse ``--initial``: ``release``, ``impulse`` or ``modes:K`` (an ``argparse`` type).

    Parameters
    ----------
    text : str
        The option's value.

    Returns
    -------
    str
        ``text`` unchanged (the model checks ``K`` when it builds the problem).

    Raises
    ------
    argparse.ArgumentTypeError
        For any other value.
    """
    if text in ("release", "impulse") or text.startswith("modes:"):
        return text
    raise argparse.ArgumentTypeError(
        f"{text!r}: use 'release', 'impulse' or 'modes:K' (K a positive integer)"
    )


def add_trial_argument(parser: argparse.ArgumentParser, help: str = "trial TOML file") -> None:
    """Add the positional ``trial`` argument (a trial TOML path).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    help : str
        Help text of the argument.
    """
    parser.add_argument("trial", type=Path, help=help)


def add_outdir_seed_options(parser: argparse.ArgumentParser) -> None:
    """Add ``-o/--outdir`` (required output directory) and ``--seed`` (default 0).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    """
    parser.add_argument("-o", "--outdir", type=Path, required=True, help="output directory")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random choice")


def add_elements_option(
    parser: argparse.ArgumentParser,
    help: str | None = f"Hermite elements (default {FIT_DEFAULTS.n_elements})",
) -> None:
    """Add ``--elements`` (Hermite beam elements, default ``FIT_DEFAULTS.n_elements``).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    help : str or None
        Help text of the option.
    """
    parser.add_argument("--elements", type=int, default=FIT_DEFAULTS.n_elements, help=help)


def add_fixed_mesh_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--fixed-mesh``: keep ``--elements`` instead of refining it at the MAP.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    """
    parser.add_argument(
        "--fixed-mesh", action="store_true",
        help="keep --elements as the mesh (the convergence check is still reported); by "
             "default the mesh is refined until the prediction at the MAP no longer changes",
    )


def add_preprocessing_options(parser: argparse.ArgumentParser) -> None:
    """Add the options that fix what :mod:`bayesbeam.trials.preprocess` would choose.

    ``--initial``, ``--window``, ``--decimate`` | ``--resample`` | ``--rate``
    (exclusive), ``--offset``, ``--max-samples`` and ``--as-is``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    """
    parser.add_argument("--initial", type=initial_condition, default=None,
                        help="initial condition: release, impulse or modes:K (default: the "
                             "trial's declared one, else modes:K for the modes in band)")
    pre = parser.add_mutually_exclusive_group()
    pre.add_argument("--decimate", type=int, default=None, metavar="Q",
                     help="decimate by Q with a zero-phase anti-alias FIR (uniform stamps)")
    pre.add_argument("--resample", type=float, default=None, metavar="DT",
                     help="resample to step DT s with an anti-alias filter (any stamps)")
    pre.add_argument("--rate", type=float, default=None, metavar="HZ",
                     help="analysis rate in Hz (default: chosen from the modes in the record)")
    parser.add_argument("--window", type=float, nargs=2, default=None, metavar=("T0", "T1"),
                        help="analysis span T0 <= t <= T1 (s, trial time axis; default: from "
                             "the release/impact to the end of the motion)")
    parser.add_argument("--offset", choices=("fit", "none"), default=None,
                        help="fit a constant signal offset (default for records without a "
                             "declared initial state) or not")
    parser.add_argument("--max-samples", type=int, default=None, metavar="N",
                        help="sample budget that sets the default rate (default 16384)")
    parser.add_argument("--as-is", action="store_true",
                        help="no automatic choices: the record as it is (options above still "
                             "apply)")


def add_json_option(parser: argparse.ArgumentParser,
                    help: str = "machine-readable output") -> None:
    """Add the ``--json`` flag (print a JSON record instead of text).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    help : str
        Help text saying what the command prints as JSON.
    """
    parser.add_argument("--json", action="store_true", help=help)


#: Range checks of shared options: option dest -> (test of the parsed value, message).
_CHECKS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "elements": (lambda v: v >= 1, "--elements must be a positive integer, got {}"),
    "seed": (lambda v: v >= 0, "--seed must be a non-negative integer, got {}"),
    "decimate": (lambda v: v is None or v >= 1, "--decimate must be an integer >= 1, got {}"),
    "resample": (lambda v: v is None or v > 0, "--resample must be a positive step in s, got {}"),
    "window": (lambda v: v is None or v[0] < v[1], "--window T0 T1 needs T0 < T1, got {}"),
    "rate": (lambda v: v is None or v > 0, "--rate must be a positive number of Hz, got {}"),
    "max_samples": (lambda v: v is None or v >= 256,
                    "--max-samples must be an integer >= 256, got {}"),
}

#: The options of :func:`add_preprocessing_options` that :func:`check_options` checks.
PREPROCESSING = ("decimate", "resample", "window", "rate", "max_samples")


def check_options(args: argparse.Namespace, error: type[Exception], *names: str) -> None:
    """Check shared options in the order given; raise on the first out of range.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options.
    error : type of Exception
        The command's error class, raised with a message that names the option.
    *names : str
        Option destinations among ``elements``, ``seed``, ``decimate``, ``resample``,
        ``window`` (:data:`PREPROCESSING` holds the last three).

    Raises
    ------
    Exception
        ``error`` for the first value out of range.
    """
    for name in names:
        test, message = _CHECKS[name]
        value = getattr(args, name)
        if not test(value):
            raise error(message.format(value))


def fit_settings(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of the fitting functions from ``--seed``, ``--elements``, ...

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options with ``seed``, ``elements``, ``target_ess``, ``max_steps`` and
        (fit, compare, diagnose) ``fixed_mesh``.

    Returns
    -------
    dict
        ``seed``, ``n_elements``, ``target_ess``, ``max_steps`` and (with
        ``fixed_mesh``) ``refine_mesh``.
    """
    out = {
        "seed": args.seed,
        "n_elements": args.elements,
        "target_ess": args.target_ess,
        "max_steps": args.max_steps,
    }
    if hasattr(args, "fixed_mesh"):  # the commands that fit (fit, compare, diagnose)
        out["refine_mesh"] = not args.fixed_mesh
    return out


def prepare_trial(args: argparse.Namespace, error: type[Exception] = ValueError,
                  say: Callable[[str], None] | None = None) -> tuple[Any, Any]:
    """Read ``args.trial`` and prepare it for a fit (:func:`bayesbeam.trials.preprocess.prepare`).

    The options of :func:`add_preprocessing_options` fix the corresponding choices;
    the others are made from the record and printed through ``say``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options with ``trial`` and those of :func:`add_preprocessing_options`.
    error : type of Exception
        The command's error class (for ``--decimate`` on non-uniform stamps).
    say : callable, optional
        Receives one line per choice (the command prints them on stderr).

    Returns
    -------
    tuple of (bayesbeam.trials.trial.Trial, bayesbeam.trials.preprocess.Preprocessing)
        The trial as the fit sees it, and the record of the choices.
    """
    from bayesbeam.trials.io import read_trial
    from bayesbeam.trials.preprocess import prepare

    trial = read_trial(args.trial)
    given: dict[str, Any] = {
        "initial": args.initial, "offset": args.offset, "max_samples": args.max_samples,
        "auto": False if args.as_is else None, "rate": args.rate,
    }
    if args.window is not None:
        given["start"], given["end"] = args.window
    if args.resample is not None:
        given["rate"] = 1.0 / args.resample
    elif args.decimate is not None:
        if not trial.is_uniform:
            raise error("--decimate needs uniform stamps; these are not: use --resample DT "
                        "or --rate HZ")
        given["rate"] = 1.0 / (args.decimate * trial.dt)
    out, pre = prepare(trial, **given)
    if say is not None:
        for line in pre.lines():
            say(f"preprocessing: {line}")
    return out, pre


def say(line: str) -> None:
    """Print a progress or preprocessing line on stderr (stdout stays the result or JSON).

    Parameters
    ----------
    line : str
    """
    print(line, file=sys.stderr, flush=True)


def print_json(record: Any) -> None:
    """Print ``record`` as indented strict JSON (no NaN or infinity) on stdout.

    Parameters
    ----------
    record : object
        A JSON-serialisable record.
    """
    print(json.dumps(record, indent=2, allow_nan=False))
