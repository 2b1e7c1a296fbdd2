"""Private helpers below every layer of the package (standard library only at import).

* :func:`distribution_version`: the installed version of a distribution, or
  ``"0+unknown"`` when it is not installed (``bayesbeam.__version__`` and the
  provenance records);
* :func:`lazy_exports`: the PEP 562 ``__getattr__`` / ``__dir__`` pair with which
  ``bayesbeam`` and its subpackages expose their public names without importing every
  module at ``import bayesbeam``;

* :func:`json_default`: the ``default=`` hook of :func:`json.dumps` for numpy scalars
  and arrays, paths, mappings, sets and tuples (used by :mod:`bayesbeam.inference.results` and
  :mod:`bayesbeam.jobs.executor`);
* :func:`finite_or_none`: one number as strict JSON (``None`` when not finite), and
  :func:`finite_json`: a copy of a whole record with non-finite floats replaced by
  ``None`` so that it can be written as strict JSON (the records of
  :mod:`bayesbeam.inference.results`, :mod:`bayesbeam.comparison`,
  :mod:`bayesbeam.diagnosis` and :mod:`bayesbeam.jobs`);
* :func:`file_sha256`: the SHA-256 of a file's bytes (provenance and cache keys);
* :func:`read_toml`: a TOML file as a dict, with an error that names the file, says
  what is wrong and how to fix it, in the caller's error class;
* :func:`atomic_path` and :func:`write_text_atomic`: write a file under a temporary
  name in its folder and rename it into place, so that an interrupted or failed write
  (disk full, kill -9) leaves the previous file whole, never a truncated one;
* :func:`progress_bar`: the one progress bar of every long loop (``tqdm``): a bar on a
  terminal, a widget in Jupyter, a plain line every ``log_interval`` s in a log file;
* :func:`interval_digits` and :func:`fmt_interval`: enough significant digits that a
  value and the ends of its interval print as different numbers;
* :func:`compiled_kernel` and :func:`numba_available`: numba, where it imports, the one
  place that compiles the package's plain-Python kernels (the ``*_kernel`` modules of
  :mod:`bayesbeam.physics` and :mod:`bayesbeam.stats`), so that the package imports and
  runs without numba and the tests can check the kernels' logic uncompiled.

Only the standard library is imported at import time (numpy when a value needs it, tqdm
when a bar is made).
This module imports nothing from bayesbeam: every layer may use it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib
import importlib.metadata
import math
import os
import sys
import threading
from collections.abc import Callable, Iterator, Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

__all__ = [
    "SCHEMA_VERSION",
    "atomic_path",
    "compiled_kernel",
    "distribution_version",
    "file_sha256",
    "finite_json",
    "finite_or_none",
    "fmt_interval",
    "interval_digits",
    "json_default",
    "lazy_exports",
    "numba_available",
    "one_blas_thread",
    "job_guard",
    "progress_bar",
    "progress_note",
    "stderr_is_live",
    "read_toml",
    "write_text_atomic",
]


#: Version of the layout of the JSON outputs (``schema_version`` in each); raised when a
#: key changes meaning or goes away (new keys may appear without it).
SCHEMA_VERSION = 1


def one_blas_thread() -> Any:
    """Context manager limiting BLAS to one thread (``threadpoolctl``).

    The package's linear algebra is on many small matrices, where BLAS threads cost more
    than they give (3-7x slower on 2 busy cores). The one home of that limit.

    Returns
    -------
    threadpoolctl.threadpool_limits
        Use as ``with one_blas_thread(): ...``.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


#: One fit job at a time per process (re-entrant: a diagnosis job runs fits itself). The
#: warning filters that a job uses to record the sampler's warnings and the BLAS thread
#: limit are process-wide, so jobs in threads of one process (a threaded Dask worker)
#: must not overlap; parallelism comes from processes.
_JOB_LOCK = threading.RLock()


@contextlib.contextmanager
def job_guard() -> Iterator[None]:
    """Run one executor job (a fit, a comparison, a diagnosis) alone, on one BLAS thread.

    Alone in its process: other jobs in threads of the same process wait.

    One thread per job keeps parallel workers from oversubscribing the cores (the
    matrices are small: threads cost more than they give) and the floating-point
    reduction order the same wherever the job runs.

    Yields
    ------
    None
    """
    with _JOB_LOCK, one_blas_thread():
        yield


def distribution_version(dist: str, missing: str = "0+unknown") -> str:
    """Installed version of a distribution.

    Parameters
    ----------
    dist : str
        Distribution name, e.g. ``"bayesbeam"`` or ``"numpy"``.
    missing : str, optional
        What to return when it is not installed (a source tree run without
        ``pip install``).

    Returns
    -------
    str
        Its version, or ``missing``.
    """
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return missing


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Build a package's ``__getattr__`` and ``__dir__`` importing names on first use (PEP 562).

    Parameters
    ----------
    package : str
        The importing package's ``__name__``.
    exports : mapping of str to str
        Public name -> module that defines it, relative to ``package`` (``".fit"``)
        or absolute.

    Returns
    -------
    getattr, dir : callable
        To assign to the package's ``__getattr__`` and ``__dir__``.
    """

    def __getattr__(name: str) -> Any:
        try:
            module = exports[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        return getattr(importlib.import_module(module, package), name)

    def __dir__() -> list[str]:
        return sorted(set(exports) | set(vars(importlib.import_module(package))))

    return __getattr__, __dir__


def json_default(obj: Any) -> Any:
    """``json.dumps`` default: numpy scalars/arrays, paths and mappings to JSON types.

    Parameters
    ----------
    obj : object
        A value :mod:`json` cannot write by itself.

    Returns
    -------
    object
        A list (arrays, sets, tuples), a Python scalar (numpy scalars), a str (paths)
        or a dict (mappings).

    Raises
    ------
    TypeError
        For any other type; the message names it.
    """
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, Mapping):
        return dict(obj)
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON: {obj!r}")


def finite_or_none(x: Any) -> float | None:
    """One number for strict JSON: a float, or ``None`` when it is not finite.

    Parameters
    ----------
    x : float, int, numpy scalar or None
        The number (``None`` stays ``None``: a value that was never computed).

    Returns
    -------
    float or None
        ``float(x)``, or ``None`` for NaN, ±inf and ``None``.
    """
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def finite_json(obj: Any) -> Any:
    """Copy ``obj`` for strict JSON: non-finite floats become ``None``.

    Mapping keys become ``str``, tuples and numpy arrays lists, numpy scalars Python
    scalars, dataclass instances dicts and paths ``str``; other values are kept as
    they are.

    Parameters
    ----------
    obj : object
        A record made of mappings, lists, tuples, numpy arrays, dataclasses, paths and
        scalars.

    Returns
    -------
    object
        The converted copy.
    """
    if isinstance(obj, float):
        return finite_or_none(obj)
    # A numpy value can only exist once numpy is imported; this module does not import it.
    np = sys.modules.get("numpy")
    if np is not None and isinstance(obj, np.ndarray | np.generic):
        return finite_json(obj.tolist())
    if isinstance(obj, Mapping):
        return {str(k): finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return finite_json(dataclasses.asdict(obj))
    if isinstance(obj, Path):
        return str(obj)
    return obj


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (provenance records and cache keys).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    str
        The digest, 64 lowercase hex digits.

    Raises
    ------
    OSError
        When the file cannot be read (the callers check that it exists first).
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_toml(
    path: str | Path, *, what: str = "TOML file", error: type[ValueError] = ValueError
) -> dict[str, Any]:
    """Read a TOML file into a dict; a missing, unreadable or invalid file raises ``error``.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for the message (``"trial file"``, ``"prior file"``, ...).
    error : type of ValueError
        The caller's error class (each command maps its own class to an exit status).

    Returns
    -------
    dict
        The TOML document.

    Raises
    ------
    ValueError
        ``error``, with a one-line message that names the file, says what is wrong
        and how to fix it.
    """
    import tomllib

    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise error(f"cannot read {what} {path}: not found; check the path") from None
    except UnicodeDecodeError as err:
        raise error(
            f"{what} {path} is not UTF-8 text (byte {err.object[err.start:err.start + 1]!r} at "
            f"position {err.start}); save it as UTF-8"
        ) from None
    except tomllib.TOMLDecodeError as err:
        raise error(
            f"{what} {path} is not valid TOML ({err}); fix the syntax there (https://toml.io)"
        ) from None
    except OSError as err:
        raise error(f"cannot read {what} {path}: {err.strerror or err}") from None


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it to ``path``.

    The temporary file keeps ``path``'s suffix (matplotlib and netCDF writers choose
    their format by it) and lives in the same folder, so the final ``os.replace`` is
    atomic on POSIX and Windows: readers see the old file or the new one, never a
    partial one. On any exception the temporary file is removed and the exception
    propagates; the previous ``path`` is untouched.

    Parameters
    ----------
    path : str or Path
        The file to (re)write.

    Yields
    ------
    Path
        Where the caller writes the new content.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        if tmp.exists():
            with open(tmp, "rb") as fh:  # the bytes reach the disk before the rename
                os.fsync(fh.fileno())
            os.replace(tmp, path)
    except OSError as err:
        if err.errno is None or (err.filename and Path(err.filename) != tmp):
            raise
        # Name the file the user knows, not the temporary one (or none, from a library).
        raise OSError(err.errno, os.strerror(err.errno), str(path)) from err
    finally:
        with contextlib.suppress(FileNotFoundError):  # gone when renamed: nothing to clean
            tmp.unlink()


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_path`.

    Parameters
    ----------
    path : str or Path
        The file to (re)write.
    text : str
        Its whole content.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


# --------------------------------------------------------------------------- progress


def _in_notebook() -> bool:
    """Tell whether this runs inside a Jupyter kernel (IPython's ``ZMQInteractiveShell``)."""
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = getattr(ipython, "get_ipython", lambda: None)()
    return type(shell).__name__ == "ZMQInteractiveShell"


class _LineLog:
    """A text stream for tqdm in a log file: each refresh becomes one full line.

    tqdm redraws its line with carriage returns, which a log file or a CI console keeps as
    one ever-growing line; here every non-empty refresh is written as its own line.
    """

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self._last = ""

    def write(self, text: str) -> int:
        for part in text.replace("\r", "\n").split("\n"):
            part = part.strip()
            if part and part != self._last:
                self.stream.write(part + "\n")
                self._last = part
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(total: float | None, desc: str, *, enabled: bool = True, unit: str = "it",
                 log_interval: float = 30.0, **kwargs: Any) -> Any:
    """Make a ``tqdm`` progress bar on stderr that works on a terminal, in Jupyter and in a log.

    On a terminal: tqdm's bar, redrawn at most every 0.5 s, with its time estimate. In a
    Jupyter kernel with ``ipywidgets``: the notebook widget (plain tqdm text without it).
    Otherwise (stderr redirected to a file or a pipe): one full line at most every
    ``log_interval`` s, so a log shows the progress without carriage-return debris.

    Parameters
    ----------
    total : float or None
        Number of units to do (None: unknown, no percentage).
    desc : str
        What runs (stage and model), shown before the bar.
    enabled : bool, default True
        False gives a disabled bar (every call is a no-op).
    unit : str, default "it"
    log_interval : float, default 30.0
        Seconds between two lines when stderr is not a terminal.
    **kwargs
        Passed to ``tqdm`` (e.g. ``initial``, ``postfix``).

    Returns
    -------
    tqdm.tqdm
        Use as a context manager; ``update``, ``set_postfix_str``, ``close``.
    """
    from tqdm import tqdm as bar_class

    stream: Any = sys.stderr
    tty = bool(getattr(stream, "isatty", lambda: False)())
    notebook = _in_notebook()
    if notebook and importlib.util.find_spec("ipywidgets") is not None:
        from tqdm.notebook import tqdm as bar_class  # noqa: F811 (the widget)
    elif not tty and not notebook:
        stream = _LineLog(stream)
    opts: dict[str, Any] = {
        "mininterval": 0.5 if (tty or notebook) else float(log_interval),
        "dynamic_ncols": tty,
        "ascii": None if tty else True,
    }
    opts.update(kwargs)
    return bar_class(total=total, desc=desc, unit=unit, file=stream, disable=not enabled,
                     leave=True, **opts)


def stderr_is_live() -> bool:
    """Tell whether progress shows live: stderr is a terminal, or this runs in Jupyter."""
    return bool(getattr(sys.stderr, "isatty", lambda: False)()) or _in_notebook()


def progress_note(bar: Any, text: str) -> None:
    """Show ``text`` (the current model, trial, last result) beside a progress bar.

    On a terminal or in Jupyter it shows at once; in a log (stderr a file or a pipe) the
    next throttled line carries it, since a line per note would defeat the interval of
    :func:`progress_bar`.

    Parameters
    ----------
    bar : tqdm.tqdm
        From :func:`progress_bar`.
    text : str
    """
    bar.set_postfix_str(text, refresh=stderr_is_live())


# --------------------------------------------------------------------------- intervals


#: The posterior summaries' interval: its lower end, median and upper end (a central 90 %
#: interval), keyed as in every summary (``q05``, ``q50``, ``q95``).
INTERVAL_QUANTILES: dict[str, float] = {"q05": 0.05, "q50": 0.5, "q95": 0.95}


def interval_digits(value: float, lo: float, hi: float, minimum: int = 3,
                    maximum: int = 12) -> int:
    """Significant digits that print ``value``, ``lo`` and ``hi`` as different numbers.

    The interval's width must show in the printed figures: with ``d`` significant
    digits the last digit of ``x`` is worth ``10**(floor(log10|x|) - d + 1)``, and it must
    be at most a tenth of the smallest gap between the three numbers (e.g. E = 70.00e9
    [69.98e9, 70.02e9] needs 5 digits, where four print 7.000e10 three times).

    Parameters
    ----------
    value, lo, hi : float
        The estimate and its interval ends.
    minimum, maximum : int, default 3 and 12
        Bounds of the answer.

    Returns
    -------
    int
    """
    xs = [float(v) for v in (value, lo, hi)]
    if not all(math.isfinite(x) for x in xs):
        return minimum
    gaps = [abs(a - b) for a, b in ((xs[0], xs[1]), (xs[2], xs[0]), (xs[2], xs[1]))]
    gaps = [g for g in gaps if g > 0]
    big = max(abs(x) for x in xs)
    if not gaps or big == 0:
        return minimum
    need = math.floor(math.log10(big)) - math.floor(math.log10(min(gaps) / 10)) + 1
    return int(min(maximum, max(minimum, need)))


def fmt_interval(value: float, lo: float, hi: float, minimum: int = 3) -> tuple[str, str, str]:
    """``value``, ``lo``, ``hi`` as strings with :func:`interval_digits` significant digits.

    Parameters
    ----------
    value, lo, hi : float
    minimum : int, default 3

    Returns
    -------
    tuple of str
    """
    d = interval_digits(value, lo, hi, minimum=minimum)
    # "#": keep trailing zeros, so 70.00e9 does not print as 7e+10 beside 6.998e+10.
    return tuple(f"{float(x):#.{d}g}" for x in (value, lo, hi))  # type: ignore[return-value]


@lru_cache(maxsize=1)
def numba_available() -> bool:
    """Whether numba imports here (a dependency; a platform without it runs numpy).

    Returns
    -------
    bool
    """
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


@lru_cache(maxsize=None)
def compiled_kernel(kernel: Callable, fastmath: tuple[str, ...] = ("contract",)
                    ) -> Callable | None:
    """Compile a plain-Python kernel with numba, once per process (cached on disk).

    Parameters
    ----------
    kernel : callable
        A kernel body (module docstring).
    fastmath : tuple of str
        numba's ``fastmath`` flags. The default, ``contract`` (fused multiply-add: one
        rounding less per product, no reassociation), measured 15 % faster on the closed
        form's sum. ``("contract", "reassoc")`` also lets the compiler vectorise dot
        products by summing in another order: for kernels whose result does not depend
        on the order beyond rounding (an iteration to a fixed point,
        :mod:`~bayesbeam.physics.sensor_kernel`: measured 1.5x there). ``()``: IEEE
        arithmetic exactly as written (the propagation kernel).

    Returns
    -------
    callable or None
        The compiled kernel (typed and compiled on its first call, ~1 s; later processes
        load it from numba's cache), or None where numba is not importable.

    Notes
    -----
    ``nogil`` so that callers may run batches in threads; serial (``parallel=False``): the
    callers already batch sets and the target machines have 2 cores.
    """
    if not numba_available():
        return None
    import numba

    return numba.njit(nogil=True, cache=True, fastmath=set(fastmath) or False,
                      error_model="numpy")(kernel)
