"""HDF5 checkpoints of :func:`bayesbeam.stats.sampling.run_emcee`: an emcee backend plus metadata.

The chain is kept in memory and mirrored to an HDF5 file in emcee's
:class:`~emcee.backends.HDFBackend` layout (group ``mcmc``: chain,
log-probabilities, acceptance counts, and the RNG state after the last saved step
as attributes; readable with ``emcee.backends.HDFBackend(path, read_only=True)``).
Group ``bayesbeam`` holds the run's bookkeeping: ``seed``, ``names`` (JSON),
``n_calls`` and ``seconds``, so that a resumed run can check it continues the same
run and keep counting.

:meth:`CheckpointBackend.flush` writes the whole file under a temporary name in the
same folder and renames it into place (``os.replace``; the bytes are synced first).
A kill -9, a full disk or any write error therefore leaves the previous checkpoint
whole: no finished and flushed step is ever lost, and a resumed run continues
bit-identically from the last flush. The sampler flushes when ``flush_seconds`` of
sampling have passed, after a convergence check unless that write is slow (over
:data:`CHEAP_WRITE`, 0.1 s) and would take more than :data:`MAX_OVERHEAD` (5 %) of the
time since the last one, and when the run ends or is
interrupted. Rewriting costs about 5 ms per MB of chain (measured, median of 5 writes
on the 2-core machine under load: 6.7 MB in 38 ms, 67 MB, a 20,000-step chain of 32
walkers and 12 parameters, in 0.34 s).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import emcee
import h5py
import numpy as np

from bayesbeam._util import atomic_path

__all__ = [
    "CheckpointBackend",
    "SamplingError",
    "open_checkpoint",
    "read_meta",
    "saved_steps",
]


class SamplingError(ValueError):
    """Invalid sampler input or log-probability output; the message says how to fix it.

    Defined here, the first module of the sampler that raises it, and imported by
    :mod:`bayesbeam.stats.sampling` (import it from there).
    """

#: Largest share of the sampling time that checkpoint writes after checks may take ...
MAX_OVERHEAD = 0.05
#: ... once a write takes this long (s; about 20 MB of chain): cheaper ones always happen.
CHEAP_WRITE = 0.1

_META = "bayesbeam"  # HDF5 group holding this module's bookkeeping next to emcee's "mcmc"


class CheckpointBackend(emcee.backends.Backend):
    """In-memory emcee backend mirrored to an HDF5 file in HDFBackend's layout.

    Parameters
    ----------
    path : pathlib.Path
        HDF5 file.
    flush_seconds : float
        Longest stretch of sampling between writes; ``0`` writes every step.
    """

    def __init__(self, path: Path, flush_seconds: float):
        super().__init__()
        self.path = Path(path)
        self.flush_seconds = flush_seconds
        #: Attributes of the file's ``bayesbeam`` group (seed, names, n_calls, seconds).
        self.meta: dict[str, Any] = {}
        self._flushed = 0
        self._last_flush = time.monotonic()
        self._flush_cost = 0.0  # seconds the last write took

    def reset(self, nwalkers: int, ndim: int) -> None:
        """Start an empty chain in memory, and replace the file by an empty checkpoint."""
        super().reset(nwalkers, ndim)
        self._flushed = 0
        self.flush(force=True)

    def load(self) -> None:
        """Read the saved steps, RNG state and bookkeeping from the file into memory.

        Raises
        ------
        SamplingError
            If the file is not a checkpoint this module can read (truncated, another
            format, another layout); the message says how to start over.
        """
        try:
            with h5py.File(self.path, "r") as f:
                g = f["mcmc"]
                nwalkers, ndim = int(g.attrs["nwalkers"]), int(g.attrs["ndim"])
                it = int(g.attrs["iteration"])
                super().reset(nwalkers, ndim)
                if it > 0:
                    self.chain = np.array(g["chain"][:it], dtype=self.dtype)
                    self.log_prob = np.array(g["log_prob"][:it], dtype=self.dtype)
                    self.accepted = np.array(g["accepted"], dtype=self.dtype)
                    self.random_state = [v for k, v in sorted(g.attrs.items())
                                         if k.startswith("random_state_")]
                    self.iteration = it
                self.meta = dict(f[_META].attrs.items()) if _META in f else {}
        except (OSError, KeyError, ValueError) as err:
            raise SamplingError(
                f"checkpoint {self.path} cannot be read ({err}): it is truncated or not a "
                "bayesbeam checkpoint; delete it, or run without --resume to start over"
            ) from None
        self._flushed = it

    @property
    def shape(self) -> tuple[int, int]:
        """``(nwalkers, ndim)`` of the chain in memory."""
        return int(self.nwalkers), int(self.ndim)

    def save_step(self, state: emcee.State, accepted: np.ndarray) -> None:
        """Store a step in memory; flush if ``flush_seconds`` have passed."""
        super().save_step(state, accepted)
        if time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self, force: bool = False) -> None:
        """Write the file anew (temporary file, then rename) if it misses steps.

        Parameters
        ----------
        force : bool
            Write even when no step was added (new bookkeeping in :attr:`meta`).
        """
        start = self._last_flush = time.monotonic()
        n = int(self.iteration)
        if n <= self._flushed and not force:
            return
        nwalkers, ndim = self.shape
        # The HDF5 image is built in memory and written as plain bytes: a failing write
        # (full disk) is an ordinary OSError, never an HDF5 file left half-open.
        buf = io.BytesIO()
        with h5py.File(buf, "w") as f:
            g = f.create_group("mcmc")
            g.attrs["version"] = emcee.__version__
            g.attrs["nwalkers"] = nwalkers
            g.attrs["ndim"] = ndim
            g.attrs["has_blobs"] = False
            g.attrs["iteration"] = n
            g.create_dataset("accepted", data=np.asarray(self.accepted, dtype=float))
            g.create_dataset("chain", data=self.chain[:n].astype(self.dtype),
                             maxshape=(None, nwalkers, ndim))
            g.create_dataset("log_prob", data=self.log_prob[:n].astype(self.dtype),
                             maxshape=(None, nwalkers))
            if n > 0 and self.random_state is not None:
                for i, v in enumerate(self.random_state):
                    g.attrs[f"random_state_{i}"] = v
            m = f.create_group(_META)
            for k, v in self.meta.items():
                m.attrs[k] = v
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.path) as tmp:
            tmp.write_bytes(buf.getvalue())
        self._flushed = n
        self._flush_cost = time.monotonic() - start

    def write_progress(self, n_calls: int, seconds: float, *, final: bool = False) -> None:
        """Record the work done so far (for a resumed run's totals) and write the file.

        Called after every convergence check. The whole file is rewritten, so a long
        chain costs more per write (5 ms per MB measured, 0.34 s for 67 MB): between
        checks a write that takes more than :data:`CHEAP_WRITE` is skipped until
        :data:`MAX_OVERHEAD` of the time since the last write covers it;
        ``flush_seconds`` still bounds the work a kill can lose.

        Parameters
        ----------
        n_calls : int
            Log-probability evaluations so far, earlier processes included.
        seconds : float
            Sampling wall-clock seconds so far, earlier processes included.
        final : bool
            The run ends (or is interrupted): write in any case.
        """
        self.meta.update(n_calls=int(n_calls), seconds=float(seconds))
        cost = self._flush_cost
        if final or cost < CHEAP_WRITE or cost <= MAX_OVERHEAD * (
                time.monotonic() - self._last_flush):
            self.flush(force=True)


def saved_steps(path: Path) -> int:
    """Return the number of steps saved in the checkpoint ``path`` (0 if there is none).

    A cheap check before a resumed run spends time on its start (MAP search, mesh).

    Parameters
    ----------
    path : pathlib.Path
        HDF5 file.

    Returns
    -------
    int

    Raises
    ------
    SamplingError
        If the file exists but is not a readable checkpoint.
    """
    path = Path(path)
    if not path.exists():
        return 0
    backend = CheckpointBackend(path, flush_seconds=math.inf)
    backend.load()
    return int(backend.iteration)


def read_meta(path: Path) -> dict[str, Any]:
    """Attributes of the ``bayesbeam`` group of ``path``; empty if there is none.

    Parameters
    ----------
    path : pathlib.Path
        HDF5 file.

    Returns
    -------
    dict
    """
    with h5py.File(path, "r") as f:
        if _META not in f:
            return {}
        return {k: v for k, v in f[_META].attrs.items()}


def open_checkpoint(
    path: Path,
    *,
    nwalkers: int,
    ndim: int,
    seed: int,
    names: Sequence[str],
    resume: bool,
    flush_seconds: float,
    space: str = "u",
) -> tuple[CheckpointBackend, int, float]:
    """Open ``path`` for a run: continue its chain (``resume``) or start it afresh.

    Parameters
    ----------
    path : pathlib.Path
        HDF5 file; its parent directory is created if needed.
    nwalkers, ndim : int
        Ensemble shape; a resumed checkpoint must have the same.
    seed : int
        Sampler seed; a resumed checkpoint must have been started with it.
    names : sequence of str
        Parameter names; a resumed checkpoint must have the same.
    resume : bool
        Continue the chain in ``path``; a missing or empty file starts afresh.
        ``False`` overwrites it.
    flush_seconds : float
        See :class:`CheckpointBackend`.
    space : str
        The coordinates the walkers move in (a description); a resumed checkpoint that
        records other coordinates is refused: its positions would mean other points.
        Checkpoints written before this record existed carry none and are taken as
        they are.

    Returns
    -------
    backend : CheckpointBackend
        Holding the saved steps and RNG state when resumed, else empty.
    prior_calls : int
        Log-probability evaluations of the earlier processes (0 if fresh).
    prior_seconds : float
        Sampling seconds of the earlier processes (0 if fresh).

    Raises
    ------
    SamplingError
        If a checkpoint to resume has another shape, seed, parameter names or
        coordinates.
    """
    names = tuple(names)
    prior_calls, prior_seconds = 0, 0.0
    backend = CheckpointBackend(path, flush_seconds)
    for stale in path.parent.glob(f".{path.stem}.*.tmp{path.suffix}"):  # a killed flush's
        with contextlib.suppress(OSError):
            stale.unlink()
    if resume and path.exists():
        backend.load()
    if resume and backend.iteration > 0:
        if backend.shape != (nwalkers, ndim):
            raise SamplingError(
                f"checkpoint {path} has (nwalkers, ndim) = {backend.shape}, but u0 "
                f"has {(nwalkers, ndim)}; use the same walkers or resume=False"
            )
        meta = backend.meta
        if "seed" in meta and int(meta["seed"]) != seed:
            raise SamplingError(
                f"checkpoint {path} was started with seed={int(meta['seed'])}; pass "
                "that seed to resume it, or resume=False to start over"
            )
        if "names" in meta and tuple(json.loads(meta["names"])) != names:
            raise SamplingError(
                f"checkpoint {path} has parameters {json.loads(meta['names'])}, "
                f"not {list(names)}; resume=False starts over"
            )
        if "space" in meta and str(meta["space"]) != space:
            raise SamplingError(
                f"checkpoint {path} was sampled in other coordinates ({meta['space']!r}, "
                f"now {space!r}; a newer version of the package reparameterises this "
                "model); resume=False starts over"
            )
        prior_calls = int(meta.get("n_calls", 0))
        prior_seconds = float(meta.get("seconds", 0.0))
        backend.meta.update(seed=seed, names=json.dumps(list(names)), space=space)
    else:
        backend.meta = {"seed": seed, "names": json.dumps(list(names)), "space": space}
        backend.reset(nwalkers, ndim)
    return backend, prior_calls, prior_seconds
