"""A vectorised log density evaluated on slices of its batch in threads.

The forward models release the GIL where the work is (numpy's loops over the batch, the
compiled kernels, ``nogil``), and every parameter set's value is computed without the
others in its batch, so a batch split into slices and evaluated in threads gives the
serial values to rounding: products that BLAS blocks by the size of the whole batch
change in the last bit (measured: 5e-15 relative on a spatial-hysteresis model). The
same seed and thread count give the same chain. A lone sampling run (one model
confirmed while the other worker processes of a diagnosis idle) then uses the idle
cores.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["batch_threads"]

#: Fewest parameter sets per slice: below it a thread's overhead outweighs its share.
MIN_SLICE = 4


@contextlib.contextmanager
def batch_threads(log_prob: Callable[[np.ndarray], np.ndarray], threads: int
                  ) -> Iterator[Callable[[np.ndarray], np.ndarray]]:
    """Yield ``log_prob`` evaluated on ``threads`` slices of each batch, in threads.

    Parameters
    ----------
    log_prob : callable
        Vectorised: ``(n, d) -> (n,)``, each row's value independent of the other rows.
    threads : int
        Threads (1: ``log_prob`` itself, no pool). Batches smaller than
        ``threads * MIN_SLICE`` rows are evaluated in one piece.

    Yields
    ------
    callable
        Same signature and values as ``log_prob``.

    Raises
    ------
    ValueError
        If ``threads`` is not a positive integer.
    """
    if isinstance(threads, bool) or not isinstance(threads, int | np.integer) or threads < 1:
        raise ValueError(f"threads must be a positive integer, got {threads!r}")
    if threads == 1:
        yield log_prob
        return
    with ThreadPoolExecutor(max_workers=int(threads), thread_name_prefix="bayesbeam-lp") as pool:

        def split(U: np.ndarray) -> np.ndarray:
            U = np.atleast_2d(U)
            k = min(int(threads), U.shape[0] // MIN_SLICE)
            if k < 2:
                return log_prob(U)
            return np.concatenate(list(pool.map(log_prob, np.array_split(U, k))))

        yield split
