"""Output folders of the commands: one run at a time, and every run named.

A command that writes into ``-o OUTDIR`` (``fit``, ``compare``, ``diagnose``, ``inspect``,
``demo``; ``report`` writes ``report.html`` into the folder it renders) first *claims*
the folder with :func:`claim`:

* the folder is created (an ``-o`` that names an existing file, or a path under a file,
  is refused with a message that says so);
* a lock file ``OUTDIR/.bayesbeam.lock`` is created with ``O_CREAT | O_EXCL`` (atomic
  on local and NFSv3+ file systems). A second run into the same folder finds it and is
  refused (:class:`OutdirBusy`, exit status 4) while the first carries on. A lock left by
  a process that no longer runs on this host (kill -9, power loss) is taken over, with
  a line saying so;
* the run gets an id (``COMMAND-YYYYmmddTHHMMSSZ-PID``) that the command writes into
  each JSON output (``run_id``), so that :mod:`bayesbeam.report.html` can refuse a
  folder holding the outputs of several runs instead of mixing their tables.

The lock is removed when the command ends, however it ends short of kill -9.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import socket
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from bayesbeam._util import SCHEMA_VERSION

__all__ = ["LOCK_NAME", "OutdirBusy", "OutdirError", "check_resume", "claim", "new_run_id",
           "stamp"]

#: Name of the lock file inside a claimed output folder.
LOCK_NAME = ".bayesbeam.lock"


class OutdirError(ValueError):
    """An ``-o`` path that cannot be a folder (an existing file, a path under a file)."""


class OutdirBusy(RuntimeError):
    """Another run holds the output folder (exit status 4)."""


def check_resume(outdir: Path, record: dict[str, Any], error: type[Exception]) -> None:
    """Refuse ``--resume`` when the options differ from those of the run in ``outdir``.

    The run's options are in ``OUTDIR/run.json`` (key ``record``); a chain continued under
    other options would mix two posteriors in one file.

    Parameters
    ----------
    outdir : Path
        The output folder of the run to resume.
    record : dict
        The options of this run, in the form written to ``run.json``.
    error : type of Exception
        Raised, with a message saying how to go on, on a difference or a damaged file.
    """
    path = outdir / "run.json"
    if not path.is_file():
        return
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise error(f"{path} is not valid JSON ({exc}); delete it to resume anyway") from None
    old = old.get("record", old)
    diff = sorted(k for k in record if json.dumps(old.get(k)) != json.dumps(record[k]))
    if diff:
        raise error(
            f"--resume: options {diff} differ from the run in {outdir} "
            f"({', '.join(f'{k}: {old.get(k)!r} -> {record[k]!r}' for k in diff[:3])}); "
            "repeat the original options, or drop --resume to start over"
        )


def new_run_id(command: str) -> str:
    """Name a run: ``COMMAND-YYYYmmddTHHMMSSZ-PID`` (UTC; unique per host and second).

    Parameters
    ----------
    command : str
        The sub-command, e.g. ``"fit"``.

    Returns
    -------
    str
    """
    now = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    return f"{command}-{now}-{os.getpid()}"


def stamp(args: Any, trial: Any = None, *, provenance: bool = True) -> dict[str, Any]:
    """Keys that identify a command's JSON output: schema, run and (optionally) provenance.

    Parameters
    ----------
    args : argparse.Namespace
        The command's options (``run_id`` set by :func:`bayesbeam.cli.main.main`).
    trial : bayesbeam.trials.trial.Trial, optional
        The input record, named with its SHA-256 in the provenance.
    provenance : bool
        Add ``provenance`` (versions, platform, time, input, command line); ``fit``'s
        summary has its own, from the fit.

    Returns
    -------
    dict
        ``schema_version``, ``run_id`` and, with ``provenance``, ``provenance``.
    """
    out: dict[str, Any] = {"schema_version": SCHEMA_VERSION,
                           "run_id": getattr(args, "run_id", None)}
    if provenance:
        import sys

        from bayesbeam.inference.results import make_provenance

        extra: dict[str, Any] = {"argv": sys.argv[1:]}
        if trial is not None:
            extra.update(trial=trial.name, trial_file=str(getattr(args, "trial", "")),
                         data_sha256=trial.sha256)
        out["provenance"] = make_provenance(extra)
    return out


def _make_folder(outdir: Path) -> None:
    if outdir.exists() and not outdir.is_dir():
        raise OutdirError(f"-o {outdir} is an existing file, not a folder; give a folder "
                          "path (it is created if missing)")
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        parent = next((p for p in outdir.parents if p.exists() and not p.is_dir()), None)
        where = f"{parent} is a file" if parent is not None else "a part of it is a file"
        raise OutdirError(f"cannot create folder {outdir}: {where}; give another -o path"
                          ) from None


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (a PermissionError means it does)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _take(lock: Path, record: dict) -> bool:
    """Create the lock file exclusively; False if it exists."""
    try:
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(json.dumps(record) + "\n")
    return True


def _holder(lock: Path) -> dict:
    try:
        return json.loads(lock.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # half-written or unreadable: unknown holder
        return {}


@contextlib.contextmanager
def claim(outdir: str | Path, command: str, *, create: bool = True,
          say: Callable[[str], None] | None = None) -> Iterator[str]:
    """Claim ``outdir`` for one run; yield the run id; release the lock at the end.

    Parameters
    ----------
    outdir : str or Path
        The output folder.
    command : str
        The sub-command (named in the lock and the run id).
    create : bool
        Create a missing folder (``report`` renders an existing one: False, and a
        missing folder is left for the command to report).
    say : callable, optional
        Receives a line when a stale lock is taken over.

    Yields
    ------
    str
        The run id (:func:`new_run_id`).

    Raises
    ------
    OutdirError
        When ``outdir`` cannot be a folder.
    OutdirBusy
        When another live run holds it.
    """
    outdir = Path(outdir)
    run_id = new_run_id(command)
    created = create and not outdir.exists()
    if create:
        _make_folder(outdir)
    elif not outdir.is_dir():
        yield run_id
        return
    lock = outdir / LOCK_NAME
    record = {"run_id": run_id, "command": command, "pid": os.getpid(),
              "host": socket.gethostname(),
              "started": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")}
    for _ in range(3):  # a stale lock removed by a racing run: try again
        if _take(lock, record):
            break
        held = _holder(lock)
        same_host = held.get("host") == record["host"]
        pid = held.get("pid")
        if same_host and isinstance(pid, int) and not _alive(pid):
            with contextlib.suppress(FileNotFoundError):
                lock.unlink()
            if say is not None:
                say(f"note: took over the lock of {held.get('command', 'a')} run (pid {pid}) "
                    f"in {outdir}, which no longer runs")
            continue
        who = (f"{held.get('command', '?')} (pid {pid}, host {held.get('host', '?')}, "
               f"since {held.get('started', '?')})" if held else "an unknown process")
        raise OutdirBusy(
            f"{outdir} is being written by another bayesbeam run: {who}; wait for it to "
            f"finish or choose another -o (if no such run exists, delete {lock})"
        )
    else:
        raise OutdirBusy(f"could not lock {outdir}: {lock} keeps reappearing; choose another -o")
    try:
        yield run_id
    finally:
        if _holder(lock).get("run_id") == run_id:
            with contextlib.suppress(FileNotFoundError):
                lock.unlink()
        if created and not any(outdir.iterdir()):  # a run that failed before writing
            with contextlib.suppress(OSError):
                outdir.rmdir()
