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
* :func:`print_json` prints a strict-JSON record (``--json``);
* :func:`add_executor_options` adds ``--jobs``/``--scheduler`` (where independent fits
  run: :func:`bayesbeam.jobs.executor.make_executor`).

Nothing heavy is imported at import time: the defaults come from
:mod:`bayesbeam.inference.settings` (standard library only), the trial reader is
imported when called.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bayesbeam.inference.settings import (
    COSTLY_ELEMENTS,
    FIT_DEFAULTS,
    MAX_ELEMENTS,
    mesh_cost_text,
)

__all__ = [
    "PREPROCESSING",
    "add_elements_option",
    "add_executor_options",
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

    The value is weighed as it is parsed, before the command reads any file: above
    :data:`~bayesbeam.inference.settings.MAX_ELEMENTS` the command stops with status 2
    and one line naming the memory and time the mesh would take
    (:func:`~bayesbeam.inference.settings.mesh_cost_text`) and the range to use; from
    :data:`~bayesbeam.inference.settings.COSTLY_ELEMENTS` on, a note on stderr says what
    it costs. Values below 1 are refused by :func:`check_options`.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    help : str or None
        Help text of the option.
    """

    class Elements(argparse.Action):
        def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                     values: Any, option_string: str | None = None) -> None:
            setattr(namespace, self.dest, values)
            if values > MAX_ELEMENTS:
                # Refused here, before any file is read: such a mesh asks for gigabytes of
                # dense matrices (issue 18: 500 elements ran 120 s without a line).
                parser.exit(2, (
                    f"{parser.prog}: error: --elements {values} is above the limit of "
                    f"{MAX_ELEMENTS}: {mesh_cost_text(values)}; use 8 to {COSTLY_ELEMENTS} "
                    f"(default {FIT_DEFAULTS.n_elements}; fits refine the mesh themselves "
                    f"where the data need it), at most {MAX_ELEMENTS}\n"))
            if values >= COSTLY_ELEMENTS:
                say(f"note: --elements {values}: {mesh_cost_text(values)}")

    parser.add_argument("--elements", type=int, default=FIT_DEFAULTS.n_elements, help=help,
                        action=Elements)


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
    (exclusive), ``--offset``, ``--max-samples``, ``--as-is``, and ``--skip-checks``
    (the sanity checks of :func:`prepare_trial` warn instead of refusing).

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
    parser.add_argument("--skip-checks", action="store_true",
                        help="go on when the sanity checks before sampling find the beam or "
                             "the record implausible (a density no material has, no "
                             "oscillation above noise, ...): their errors become warnings")


def add_executor_options(parser: argparse.ArgumentParser, *, default_jobs: int | None = 1,
                         jobs_help: str = "worker processes for the fits (default 1: one "
                                          "after another in this process; 0: one per "
                                          "CPU core)") -> None:
    """Add ``--jobs N`` and ``--scheduler ADDRESS``: where independent fits run.

    The values go to :func:`bayesbeam.jobs.executor.make_executor` (local processes, or
    a Dask cluster); the results do not depend on them.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser.
    default_jobs : int or None
        Default of ``--jobs`` (None: the command chooses, e.g. one per core).
    jobs_help : str
        Help text of ``--jobs``.
    """
    parser.add_argument("--jobs", type=int, default=default_jobs, metavar="N", help=jobs_help)
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="Dask scheduler address, e.g. tcp://host:8786 (needs "
                             "bayesbeam[dask]; takes precedence over --jobs)")


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
    "elements": (lambda v: 1 <= v <= MAX_ELEMENTS,
                 f"--elements must be an integer from 1 to {MAX_ELEMENTS} (default "
                 f"{FIT_DEFAULTS.n_elements}), got {{}}"),
    "seed": (lambda v: v >= 0, "--seed must be a non-negative integer, got {}"),
    "decimate": (lambda v: v is None or v >= 1, "--decimate must be an integer >= 1, got {}"),
    "resample": (lambda v: v is None or 0 < v < float("inf"),
                 "--resample must be a positive finite step in s, got {}"),
    "window": (lambda v: v is None or -float("inf") < v[0] < v[1] < float("inf"),
               "--window T0 T1 needs finite times T0 < T1 (s), got {}"),
    "rate": (lambda v: v is None or 0 < v < float("inf"),
             "--rate must be a positive finite number of Hz, got {}"),
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


def helper_options(args: argparse.Namespace) -> dict[str, int]:
    """``sampler_options`` of ``bayesbeam fit --jobs N``: N - 1 helper processes.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options with ``jobs`` (>= 1).

    Returns
    -------
    dict
        ``{"helpers": N - 1}`` (:class:`~bayesbeam.inference.parallel.ParallelLogProb`),
        empty for one process.
    """
    return {"helpers": args.jobs - 1} if args.jobs > 1 else {}


def prepare_trial(args: argparse.Namespace, error: type[Exception] = ValueError,
                  say: Callable[[str], None] | None = None) -> tuple[Any, Any]:
    """Read ``args.trial`` and prepare it for a fit (:func:`bayesbeam.trials.preprocess.prepare`).

    The options of :func:`add_preprocessing_options` fix the corresponding choices;
    the others are made from the record and printed through ``say``.

    Before sampling, the sanity checks of :func:`bayesbeam.trials.checks.check_trial`
    run: the beam's physical plausibility and the record's (constant signal, stamps in
    the wrong unit, mode 1 outside the record) before the plan, the mode-1 line against
    noise and the modulus it implies after it. An error refuses the trial (``error``,
    one line naming the value and the fix) unless ``args.skip_checks``; warnings, and
    errors under ``--skip-checks``, go through ``say`` as ``warning: ...``.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options with ``trial`` and those of :func:`add_preprocessing_options`.
    error : type of Exception
        The command's error class (for ``--decimate`` on non-uniform stamps and for
        the sanity checks' errors).
    say : callable, optional
        Receives one line per choice and per warning (the command prints them on
        stderr); without it warnings are issued with :func:`warnings.warn`.

    Returns
    -------
    tuple of (bayesbeam.trials.trial.Trial, bayesbeam.trials.preprocess.Preprocessing)
        The trial as the fit sees it, and the record of the choices.

    Raises
    ------
    Exception
        ``error`` for a failed sanity check (without ``--skip-checks``).
    """
    from bayesbeam.physics.plausible import plausibility
    from bayesbeam.trials.checks import record_checks, spectrum_checks
    from bayesbeam.trials.io import read_trial
    from bayesbeam.trials.preprocess import prepare

    trial = read_trial(args.trial)
    skip = bool(getattr(args, "skip_checks", False))
    before = plausibility(trial.beam) + record_checks(trial)
    _sanity(before, error, say, skip)
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
    if not any(f.check == "constant" for f in before):  # no spectrum to judge
        # before the choices are printed: a refusal is then the only line on stderr
        _sanity(spectrum_checks(trial, pre), error, say, skip)
    if say is not None:
        for line in pre.lines():
            say(f"preprocessing: {line}")
    return out, pre


def _sanity(findings: list[Any], error: type[Exception], say: Callable[[str], None] | None,
            skip: bool) -> None:
    """Refuse on the checks' errors (unless ``skip``); report the rest as warnings."""
    errors = [f.message for f in findings if f.severity == "error"]
    if errors and not skip:
        raise error("; ".join(errors) + " (if these values are right, rerun with "
                    "--skip-checks)")
    for f in findings:
        line = f"warning: {f.message}" + (" (--skip-checks)" if f.severity == "error" else "")
        if say is not None:
            say(line)
        else:
            warnings.warn(line, UserWarning, stacklevel=3)


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
