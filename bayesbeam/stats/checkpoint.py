"""HDF5 checkpoints of :func:`bayesbeam.stats.sampling.run_emcee`: an emcee backend plus metadata.

The chain is kept in memory and mirrored to an HDF5 file in emcee's
:class:`~emcee.backends.HDFBackend` layout (group ``mcmc``: chain,
log-probabilities, acceptance counts, and the RNG state after the last saved step
as attributes; readable with ``emcee.backends.HDFBackend(path, read_only=True)``).
Group ``bayesbeam`` holds the run's bookkeeping: ``seed``, ``names`` (JSON),
``n_calls`` and ``seconds``, so that a resumed run can check it continues the same
run and keep counting.

New steps are appended by :meth:`CheckpointBackend.flush`, which the sampler loop
calls after every check; :meth:`CheckpointBackend.save_step` also flushes when
``flush_seconds`` of sampling have passed since the last write. emcee's own
HDFBackend reopens the file on every step, which costs milliseconds per step;
batching avoids that. A process killed *while* h5py writes (a short window per
flush) can leave the file unreadable; that is an HDF5 limitation.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import emcee
import h5py
import numpy as np

__all__ = ["CheckpointBackend", "SamplingError", "open_checkpoint", "read_meta", "write_meta"]


class SamplingError(ValueError):
    """Invalid sampler input or log-probability output; the message says how to fix it.

    Defined here, the first module of the sampler that raises it, and imported by
    :mod:`bayesbeam.stats.sampling` (import it from there).
    """

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
        self.path = path
        self.h5 = emcee.backends.HDFBackend(str(path))
        self.flush_seconds = flush_seconds
        self._flushed = 0
        self._last_flush = time.monotonic()

    def reset(self, nwalkers: int, ndim: int) -> None:
        """Start an empty chain in memory and in the file."""
        super().reset(nwalkers, ndim)
        self.h5.reset(nwalkers, ndim)
        self._flushed = 0

    def load(self) -> None:
        """Read the saved steps and RNG state from the file into memory."""
        nwalkers, ndim = (int(v) for v in self.h5.shape)
        super().reset(nwalkers, ndim)
        it = int(self.h5.iteration)
        if it > 0:
            self.chain = np.array(self.h5.get_chain(), dtype=self.dtype)
            self.log_prob = np.array(self.h5.get_log_prob(), dtype=self.dtype)
            self.accepted = np.array(self.h5.accepted, dtype=self.dtype)
            self.random_state = self.h5.random_state
            self.iteration = it
        self._flushed = it

    def save_step(self, state: emcee.State, accepted: np.ndarray) -> None:
        """Store a step in memory; flush if ``flush_seconds`` have passed."""
        super().save_step(state, accepted)
        if time.monotonic() - self._last_flush >= self.flush_seconds:
            self.flush()

    def flush(self) -> None:
        """Append the steps not yet in the file; the iteration counter goes last."""
        self._last_flush = time.monotonic()
        n0, n1 = self._flushed, self.iteration
        if n1 <= n0:
            return
        with self.h5.open("a") as f:
            g = f[self.h5.name]
            for key in ("chain", "log_prob"):
                if g[key].shape[0] < n1:
                    g[key].resize(n1, axis=0)
            g["chain"][n0:n1] = self.chain[n0:n1]
            g["log_prob"][n0:n1] = self.log_prob[n0:n1]
            g["accepted"][:] = self.accepted
            for i, v in enumerate(self.random_state):
                g.attrs[f"random_state_{i}"] = v
            g.attrs["iteration"] = n1
        self._flushed = n1

    def write_progress(self, n_calls: int, seconds: float) -> None:
        """Record the work done so far, for a resumed run's totals; call after :meth:`flush`.

        Parameters
        ----------
        n_calls : int
            Log-probability evaluations so far, earlier processes included.
        seconds : float
            Sampling wall-clock seconds so far, earlier processes included.
        """
        write_meta(self.path, {"n_calls": n_calls, "seconds": seconds})


def write_meta(path: Path, meta: dict[str, Any]) -> None:
    """Set attributes of the ``bayesbeam`` group of ``path`` (created if missing).

    Parameters
    ----------
    path : pathlib.Path
        HDF5 file.
    meta : dict
        Attribute names and h5py-storable values.
    """
    with h5py.File(path, "a") as f:
        g = f.require_group(_META)
        for k, v in meta.items():
            g.attrs[k] = v


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
        If a checkpoint to resume has another shape, seed or parameter names.
    """
    names = tuple(names)
    prior_calls, prior_seconds = 0, 0.0
    backend = CheckpointBackend(path, flush_seconds)
    if resume and backend.h5.initialized:
        if tuple(backend.h5.shape) != (nwalkers, ndim):
            raise SamplingError(
                f"checkpoint {path} has (nwalkers, ndim) = {tuple(backend.h5.shape)}, but u0 "
                f"has {(nwalkers, ndim)}; use the same walkers or resume=False"
            )
        meta = read_meta(path)
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
        prior_calls = int(meta.get("n_calls", 0))
        prior_seconds = float(meta.get("seconds", 0.0))
        backend.load()
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        backend.reset(nwalkers, ndim)
    write_meta(path, {"seed": seed, "names": json.dumps(list(names))})
    return backend, prior_calls, prior_seconds
