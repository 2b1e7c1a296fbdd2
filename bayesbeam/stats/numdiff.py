"""Finite-difference gradients and Hessians of vectorised functions, one batched call each.

``f`` maps an array of points ``(k, d) -> (k,)`` (as every ``log_prob`` in this
package does), so all points of a stencil are evaluated in one call. Steps ``h`` are
per coordinate (a scalar is used for all). Formulas (Abramowitz & Stegun 1964, §25.3;
Nocedal & Wright 2006, Numerical Optimization, 2nd ed., §8.1), with ``e_i`` the unit
vectors:

* gradient, central: ``g_i = (f(u + h_i e_i) - f(u - h_i e_i)) / (2 h_i)``, truncation
  error ``h_i² f_iii / 6``;
* Hessian diagonal, three-point: ``H_ii = (f(u + h_i e_i) - 2 f(u) + f(u - h_i e_i)) /
  h_i²``, error ``h_i² f_iiii / 12``;
* Hessian, four-point (off-diagonal, and on the diagonal for the ``"corners"``
  stencil): ``H_ij = (f(+,+) - f(+,-) - f(-,+) + f(-,-)) / (4 h_i h_j)`` with
  ``f(s, t) = f(u + s h_i e_i + t h_j e_j)``, error ``(h_i² f_iiij + h_j² f_ijjj) / 6``.

Rounding adds about ``eps |f| / h`` to a gradient and ``4 eps |f| / h²`` to a Hessian
entry (``eps`` = 2.2e-16), so ``h`` balances the two (e.g. ``h ~ eps^(1/4)`` times the
length scale of ``f`` for Hessians).

Non-finite values of ``f`` (``-inf`` outside a density's support) propagate, without
floating-point warnings, to the derivatives they enter (``nan`` for ``inf - inf``);
callers test the result.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["fd_gradient", "fd_hessian"]

#: Sign pairs ``(s, t)`` of the four-point stencil, in the order its values are stored.
_SIGNS = ((1, 1), (1, -1), (-1, 1), (-1, -1))


def _point_and_steps(u: np.ndarray, h: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point as a float vector and the steps broadcast to its shape, validated."""
    u = np.asarray(u, dtype=float)
    if u.ndim != 1 or u.size == 0:
        raise ValueError(f"u must be a non-empty 1-D vector, got shape {u.shape}")
    h = np.broadcast_to(np.asarray(h, dtype=float), u.shape)
    if not np.all(h > 0) or not np.all(np.isfinite(h)):
        raise ValueError(f"finite-difference steps must be positive and finite, got {h!r}")
    return u, h


def fd_gradient(
    f: Callable[[np.ndarray], np.ndarray],
    u: np.ndarray,
    h: float | np.ndarray,
    *,
    one_sided: bool = False,
) -> tuple[float, np.ndarray]:
    """Value and central-difference gradient of a vectorised function (one call).

    Evaluates ``f`` at ``u`` and ``u ± h_i e_i`` (``2 d + 1`` points, in that order).

    Parameters
    ----------
    f : callable
        Vectorised function ``(k, d) -> (k,)``.
    u : ndarray, shape (d,)
        Point, in the units of ``f``'s argument.
    h : float or ndarray, shape (d,)
        Steps, same units as ``u``; positive.
    one_sided : bool
        Where ``f(u + h_i e_i)`` or ``f(u - h_i e_i)`` is not finite (``u`` on a bound
        of the support), use the forward ``(f(u + h_i e_i) - f(u)) / h_i`` or backward
        ``(f(u) - f(u - h_i e_i)) / h_i`` difference (first order), and 0 where
        neither side is finite. Otherwise the central difference everywhere.

    Returns
    -------
    value : float
        ``f(u)``.
    grad : ndarray, shape (d,)
        Gradient, units of ``f`` per unit of ``u``.

    Raises
    ------
    ValueError
        If ``u`` is not a non-empty vector or a step is not positive and finite.
    """
    u, h = _point_and_steps(u, h)
    d = u.size
    E = np.diag(h)
    v = np.asarray(f(np.vstack([u, u + E, u - E])), dtype=float)
    f0, fp, fm = v[0], v[1 : d + 1], v[d + 1 :]
    with np.errstate(invalid="ignore"):  # inf - inf off the support: see module docstring
        g = (fp - fm) / (2 * h)
        if one_sided:
            g = np.where(np.isfinite(fp) & np.isfinite(fm), g,
                         np.where(np.isfinite(fp), (fp - f0) / h,
                                  np.where(np.isfinite(fm), (f0 - fm) / h, 0.0)))
    return float(f0), g


def fd_hessian(
    f: Callable[[np.ndarray], np.ndarray],
    u: np.ndarray,
    h: float | np.ndarray,
    *,
    stencil: str = "axes",
) -> tuple[float, np.ndarray, np.ndarray]:
    """Value, gradient and Hessian of a vectorised function by central differences (one call).

    Parameters
    ----------
    f : callable
        Vectorised function ``(k, d) -> (k,)``.
    u : ndarray, shape (d,)
        Point, in the units of ``f``'s argument.
    h : float or ndarray, shape (d,)
        Steps, same units as ``u``; positive.
    stencil : {"axes", "corners"}
        ``"axes"`` (``2 d² + 1`` points): ``u``, ``u ± h_i e_i``, then
        ``u ± h_i e_i ± h_j e_j`` for ``i < j``; the gradient is central, the diagonal
        three-point, the off-diagonal four-point (module docstring).
        ``"corners"`` (``2 d (d + 1) + 1`` points): ``u``, then the four points
        ``u ± h_i e_i ± h_j e_j`` for each ``i <= j``; every entry is four-point, so
        the diagonal uses ``f(u ± 2 h_i e_i)`` and two evaluations at ``u`` (an O(h²)
        formula with step ``2 h_i``), and the gradient is
        ``(f(u + 2 h_i e_i) - f(u - 2 h_i e_i)) / (4 h_i)``. The axes stencil is
        cheaper and more accurate; the corners one is kept for the MAP covariance
        of :func:`bayesbeam.inference.fit.laplace_covariance`, whose numbers it defines.

    Returns
    -------
    value : float
        ``f(u)``.
    grad : ndarray, shape (d,)
        Gradient, units of ``f`` per unit of ``u``.
    hess : ndarray, shape (d, d)
        Symmetric Hessian, units of ``f`` per unit of ``u`` squared.

    Raises
    ------
    ValueError
        If ``u`` is not a non-empty vector, a step is not positive and finite, or the
        stencil is unknown.
    """
    u, h = _point_and_steps(u, h)
    d = u.size
    E = np.diag(h)
    if stencil == "axes":
        pairs = [(i, j) for i in range(d) for j in range(i + 1, d)]
        pts = [u[None], u + E, u - E]
        pts += [np.array([u + si * E[i] + sj * E[j] for i, j in pairs]).reshape(-1, d)
                for si, sj in _SIGNS]
        v = np.asarray(f(np.vstack(pts)), dtype=float)
        f0, fp, fm = v[0], v[1 : d + 1], v[d + 1 : 2 * d + 1]
        q = v[2 * d + 1 :].reshape(4, len(pairs))  # q[s, k]: sign pair s of pair k
        with np.errstate(invalid="ignore"):  # inf - inf off the support
            g = (fp - fm) / (2 * h)
            H = np.diag((fp - 2 * f0 + fm) / h**2)
    elif stencil == "corners":
        pairs = [(i, j) for i in range(d) for j in range(i, d)]
        pts = [u[None]] + [(u + si * E[i] + sj * E[j])[None] for i, j in pairs
                           for si, sj in _SIGNS]
        v = np.asarray(f(np.vstack(pts)), dtype=float)
        f0 = v[0]
        q = v[1:].reshape(len(pairs), 4).T
        on_diag = [k for k, (i, j) in enumerate(pairs) if i == j]
        with np.errstate(invalid="ignore"):
            g = (q[0, on_diag] - q[3, on_diag]) / (4 * h)
        H = np.zeros((d, d))
    else:
        raise ValueError(f"stencil must be 'axes' or 'corners', got {stencil!r}")
    with np.errstate(invalid="ignore"):
        for k, (i, j) in enumerate(pairs):
            H[i, j] = H[j, i] = (q[0, k] - q[1, k] - q[2, k] + q[3, k]) / (4 * h[i] * h[j])
    return float(f0), g, H
