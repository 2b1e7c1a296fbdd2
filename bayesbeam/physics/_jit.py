"""numba, where it imports: one place that compiles the package's plain-Python kernels.

The kernels (:mod:`~bayesbeam.physics.propagate_kernel`,
:mod:`~bayesbeam.physics.modal_kernel`, :mod:`~bayesbeam.physics.sensor_kernel`,
:mod:`~bayesbeam.physics.slow_flow_kernel`) are plain Python on numpy arrays, so that
the package imports and runs without numba and the tests can check their logic
uncompiled; each caller compiles its kernel here on first use.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

__all__ = ["compiled_kernel", "numba_available"]


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
