"""A problem's vectorised log density, each batch shared with helper processes.

emcee's ensemble moves propose for half the walkers at a time: one vectorised call of
``nwalkers / 2`` points per half-step. On a whole measured record that call is long
(Al 60 cm #1, 14118 samples, with drag and a point mass: ~70 ms for 34 points) and
runs on one core; where a diagnosis samples one model alone, or ``bayesbeam fit`` runs,
the machine's other cores wait. Threads do not help (the batch code holds the GIL
between small numpy calls: 0.33-0.95x, measured and removed); processes do, because the
rows of a batch are independent: :class:`ParallelLogProb` sends a share of each batch to
helper processes that hold their own copy of the log density (a problem's bound
``log_prob``, pickled once with its problem, at start) and evaluates the rest here.
:func:`~bayesbeam.inference.coordinates.sample_in_coordinates` wraps its log density in
one when asked for ``helpers``. The values are the problem's own, bit for bit: the forward
model's per-set choices (the slow flow's RK4 grid, the band reduction's iterations)
ignore the batch they come in.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import pickle
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["ParallelLogProb", "check_helpers"]

#: A batch is split only when its serial evaluation took at least this long (s): a
#: process round trip costs ~1 ms, and a viscous+kv batch on a whole record ~10 ms.
MIN_SECONDS = 0.02
#: Nor when it has fewer rows than this per process.
MIN_ROWS = 2

_LOG_PROB: Any = None


def check_helpers(helpers: Any) -> int:
    """Return ``helpers`` if it is a helper-process count (an int >= 0).

    Parameters
    ----------
    helpers : object

    Returns
    -------
    int

    Raises
    ------
    ValueError
        When it is negative or not an integer (a bool included).
    """
    if isinstance(helpers, bool) or not isinstance(helpers, int) or helpers < 0:
        raise ValueError(f"helpers must be a non-negative integer (helper processes that "
                         f"share the sampler's batches), got {helpers!r}")
    return helpers


def _start_helper(blob: bytes) -> None:
    """Start a helper: one BLAS thread (as the parent's jobs), the log density unpickled."""
    global _LOG_PROB
    from bayesbeam._util import one_blas_thread

    one_blas_thread()  # a process-wide limit, kept for the helper's life
    _LOG_PROB = pickle.loads(blob)


def _helper_log_prob(U: np.ndarray) -> np.ndarray:
    return np.asarray(_LOG_PROB(U), dtype=float)


class ParallelLogProb:
    """A vectorised log density with each long batch shared with ``helpers`` processes.

    The helpers start (spawned, ``log_prob`` pickled to them) at the first batch whose
    serial evaluation took :data:`MIN_SECONDS` or more, so that a cheap problem never
    pays for them. Use as a context manager (the helpers stop on exit) or call
    :meth:`close`.

    Parameters
    ----------
    log_prob : callable
        Picklable (e.g. the bound ``log_prob`` of a Problem or JointProblem) and
        vectorised: ``(k, ndim) -> (k,)``.
    helpers : int
        Helper processes (0: every batch here, as ``log_prob`` itself).

    Raises
    ------
    ValueError
        When ``helpers`` is negative or not an integer.
    """

    def __init__(self, log_prob: Callable[[np.ndarray], np.ndarray], helpers: int = 1) -> None:
        self.log_prob = log_prob
        self.helpers = check_helpers(helpers)
        self._pool: cf.ProcessPoolExecutor | None = None
        self._decided = helpers == 0  # whether the serial-or-split choice is made
        self.batches_split = 0

    def __call__(self, U: np.ndarray) -> np.ndarray:
        """Log density of each row of ``U``, shape (k, ndim) -> (k,)."""
        U = np.atleast_2d(np.asarray(U, dtype=float))
        parts = self.helpers + 1
        if self._pool is None or len(U) < MIN_ROWS * parts:
            t0 = time.perf_counter()
            out = np.asarray(self.log_prob(U), dtype=float)
            if not self._decided and len(U) >= MIN_ROWS * parts:
                self._decided = True
                if time.perf_counter() - t0 >= MIN_SECONDS:
                    self._start()
            return out
        chunks = np.array_split(U, parts)
        try:
            futures = [self._pool.submit(_helper_log_prob, c) for c in chunks[1:]]
            here = np.asarray(self.log_prob(chunks[0]), dtype=float)
            rest = [f.result() for f in futures]
        except cf.process.BrokenProcessPool:
            # A helper killed (out of memory, a signal): its rows are computed here.
            warnings.warn("a helper process of the parallel log density stopped; "
                          "going on in this process alone", RuntimeWarning, stacklevel=2)
            self.close()
            return np.asarray(self.log_prob(U), dtype=float)
        self.batches_split += 1
        return np.concatenate([here, *rest])

    def _start(self) -> None:
        blob = pickle.dumps(self.log_prob)
        self._pool = cf.ProcessPoolExecutor(
            max_workers=self.helpers, mp_context=multiprocessing.get_context("spawn"),
            initializer=_start_helper, initargs=(blob,))

    def close(self) -> None:
        """Stop the helpers (idempotent); later batches run in this process."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __enter__(self) -> ParallelLogProb:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
