"""The finished steps of a diagnosis kept on disk, so that an interrupted one resumes.

A diagnosis of a whole record runs for tens of minutes: each round screens every
candidate (MAP searches and Laplace evidences), samples the best few (emcee, bridge
sampling, PSIS-LOO) and checks the mesh at the new model's MAP. Each of those steps is
a deterministic function of its inputs (the record, the model, the mesh, the start
points or the MAP, and the seed: the searches and mesh checks use no random numbers
and each sampling run has its own seed,
:class:`~bayesbeam.diagnosis.search._Engine`). :class:`StepStore` writes each finished
step's result to ``FOLDER/KIND-KEY.pkl`` as it arrives, under a key that hashes all of
those inputs together with the run's settings; ``bayesbeam diagnose --resume`` replays
the procedure and takes every step it finds there instead of computing it again, so
the resumed diagnosis takes the decisions (and reports the numbers) of an uninterrupted
one and computes only what was not finished.

The files are Python pickles of this package's own records: read only folders that a
diagnosis wrote.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["StepStore", "step_key"]


def step_key(context: Mapping[str, Any], **inputs: Any) -> str:
    """Return the hex SHA-256 of a step's inputs and the run's context.

    Arrays enter by dtype, shape and bytes (a float that differs in its last bit is
    another input); other values by their canonical JSON (``str`` for what JSON cannot
    write, e.g. a prior object, whose ``repr`` holds its parameters).

    Parameters
    ----------
    context : mapping
        The run's settings (record hash, seed, mesh, priors, sampler budget, ...).
    **inputs
        The step's own inputs (model name, start points, MAP, seed, ...).

    Returns
    -------
    str
    """
    h = hashlib.sha256()

    def add(name: str, value: Any) -> None:
        h.update(name.encode("utf-8") + b"\0")
        if isinstance(value, np.ndarray):
            a = np.ascontiguousarray(value)
            h.update(f"{a.dtype.str}{a.shape}".encode() + a.tobytes())
        else:
            h.update(json.dumps(value, sort_keys=True, default=str).encode("utf-8"))
        h.update(b"\0")

    add("context", dict(context))
    for name in sorted(inputs):
        add(name, inputs[name])
    return h.hexdigest()


class StepStore:
    """Results of a diagnosis's finished steps, read from and written to one folder.

    Parameters
    ----------
    folder : path
        Where the steps are kept (created on the first write).
    context : mapping
        The run's settings, part of every key (:func:`step_key`).
    read : bool
        Take finished steps from ``folder`` (a resumed run). False: the folder is
        emptied first, so that nothing from an earlier run is taken.
    """

    def __init__(self, folder: str | Path, context: Mapping[str, Any], *, read: bool) -> None:
        self.folder = Path(folder)
        self.context = dict(context)
        self.read = bool(read)
        self.hits = 0
        if not self.read and self.folder.exists():
            shutil.rmtree(self.folder)

    def _path(self, kind: str, key: str) -> Path:
        return self.folder / f"{kind}-{key[:32]}.pkl"

    def key(self, **inputs: Any) -> str:
        """:func:`step_key` of ``inputs`` in this run's context."""
        return step_key(self.context, **inputs)

    def get(self, kind: str, key: str) -> Any:
        """Return the stored result of step ``kind``/``key``, or None.

        A file that cannot be read back (cut short by a kill, or from another version
        of the package) counts as absent: the step runs again.
        """
        if not self.read:
            return None
        path = self._path(kind, key)
        if not path.is_file():
            return None
        try:
            with path.open("rb") as f:
                stored_key, value = pickle.load(f)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError,
                TypeError, ValueError):
            return None
        if stored_key != key:
            return None
        self.hits += 1
        return value

    def put(self, kind: str, key: str, value: Any) -> None:
        """Write step ``kind``/``key``'s result (atomically: a kill leaves no half file)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        path = self._path(kind, key)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        with tmp.open("wb") as f:
            pickle.dump((key, value), f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
