"""Inputs of the forward models: parameter columns and ranges, initial conditions, stamps.

Shared by :class:`bayesbeam.physics.forward.Forward` and the models built on it
(:class:`bayesbeam.physics.nonlinear.NonlinearForward`), so that all take and check the
same inputs; :mod:`bayesbeam.physics.forward` re-exports the public names.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "GRID_FILL",
    "ForwardError",
    "grid_with_holes",
    "initial_names",
    "parameter_columns",
]


class ForwardError(ValueError):
    """The forward model was set up or called with invalid input."""


# Admissible ranges of the physical parameters (SI); outside them a set is invalid.
_LOWER = {
    "E": (0.0, False),
    "gamma": (0.0, True),
    "c_d": (0.0, True),
    "a": (0.0, True),
    "b": (0.0, False),
    "tip_mass": (0.0, True),
    "added_mass": (0.0, True),
    "added_mass_position": (0.0, True),
    "root_spring": (0.0, False),
    "stiffness_gradient": (-2.0, False),
    "w0": (-np.inf, False),
    "p0": (-np.inf, False),
}
_UPPER = {"stiffness_gradient": 2.0}

#: A grid with holes is simulated whole when it has at most this many points per sample.
GRID_FILL = 4.0


def grid_with_holes(t: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Return ``(step, index)`` when the times ``t`` (from 0) are ``index * step``.

    Such stamps come from a uniform grid with samples dropped (resampling around the
    gaps of a software-timed record, :meth:`bayesbeam.trials.trial.Trial.resample`):
    propagating the whole grid (``P^k`` products) and keeping ``index`` is cheaper than
    the eigendecomposition route for arbitrary times as long as few points are missing
    (at most :data:`GRID_FILL` grid points per sample). None otherwise.
    """
    step = float(np.min(np.diff(t)))
    k = np.rint(t / step)
    off_grid = np.abs(t - k * step) > 1e-9 * step * np.maximum(k, 1)
    if k[-1] + 1 > GRID_FILL * t.size or np.any(off_grid):
        return None
    return step, k.astype(np.int64)


def initial_names(initial: str) -> tuple[str, ...]:
    """Names of the initial-condition parameters of an ``initial`` kind.

    Parameters
    ----------
    initial : str
        'release', 'impulse', 'modes:K' or 'state'.

    Returns
    -------
    tuple of str
    """
    if initial == "release":
        return ("w0",)
    if initial == "impulse":
        return ("p0",)
    if initial.startswith("modes:"):
        try:
            k = int(initial.split(":", 1)[1])
        except ValueError:
            k = 0
        if k < 1:
            raise ForwardError(f"initial={initial!r}: use 'modes:K' with K a positive integer")
        return tuple(n for i in range(1, k + 1) for n in (f"A{i}", f"B{i}"))
    if initial == "state":
        return ()
    raise ForwardError(
        f"unknown initial condition {initial!r}; use 'release' (tip deflection w0, m), "
        "'impulse' (tip impulse p0, N s), 'modes:K' (first K modal amplitudes at the sensor, m) "
        "or 'state' (a fixed initial_state=(c0, v0))"
    )


def parameter_columns(
    theta: np.ndarray | dict,
    names: tuple[str, ...],
    error: type[ForwardError] = ForwardError,
) -> np.ndarray:
    """Parameter sets as a (B, P) array with columns ``names``.

    Shared by :class:`Forward` and the forward models built on it (e.g.
    :class:`bayesbeam.physics.nonlinear.NonlinearForward`), so that all take the same inputs.

    Parameters
    ----------
    theta : ndarray, shape (B, P) or (P,), or dict of name → array
        Parameter sets (SI units); a dict's values are broadcast together.
    names : tuple of str
        Column names, in order (a model's ``param_names``).
    error : type of ForwardError, optional
        Exception class raised for a missing name or a wrong shape.

    Returns
    -------
    ndarray, shape (B, P)

    Raises
    ------
    ForwardError
        Or the given ``error`` class: a name is missing from a dict, or the shape is not
        (B, P).
    """
    if isinstance(theta, dict):
        missing = [p for p in names if p not in theta]
        if missing:
            raise error(f"missing parameters {missing}; need {list(names)}")
        cols = [np.atleast_1d(np.asarray(theta[p], dtype=float)) for p in names]
        theta = np.column_stack(np.broadcast_arrays(*cols))
    theta = np.asarray(theta, dtype=float)
    if theta.ndim == 1:
        theta = theta[None, :]
    if theta.ndim != 2 or theta.shape[1] != len(names):
        raise error(
            f"theta must have shape (B, {len(names)}) with columns "
            f"{list(names)}, got {theta.shape}"
        )
    return theta
