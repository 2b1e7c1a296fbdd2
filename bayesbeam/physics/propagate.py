"""Exact time response of the first-order modal system, batched over parameter sets.

The Galerkin model ``M c'' + D c' + K c = 0`` written in undamped modal coordinates
``c = Φ q`` (Φ M-orthonormal, ``Φᵀ K Φ = Ω²``) and the state ``z = [Ω q; q']`` is

    z' = A z,        A = [[0, Ω], [-Ω, -C]],        C = Φᵀ D Φ            (physics.md §4)

with Ω = diag(ω) ≥ 0 (rad/s) and C symmetric positive semidefinite (1/s). In these
coordinates ``½|z|² = ½ qᵀΩ²q + ½ q'ᵀq'`` is the mechanical energy and
``d/dt ½|z|² = -q'ᵀ C q' ≤ 0``, so ``expm(A t)`` is a contraction in the 2-norm: that keeps
the repeated products below accurate over thousands of steps. The output is
``y(t) = h · z(t)`` (displacement ``h = [s_q Ω⁻¹, 0]``, velocity ``[0, s_q]``,
acceleration ``[-s_q Ω, -s_q C]`` with ``s_q = N(x_s) Φ``).

There is no time-stepping error; everything is exact up to rounding.

* :func:`~bayesbeam.physics.expm.expm_batched` (in :mod:`bayesbeam.physics.expm`) — scaling and
  squaring with a Taylor series, degree and squarings chosen per matrix so that the
  truncation has a relative backward error ≤ 2^-53 (Al-Mohy & Higham 2009).
* :func:`response_uniform` — ``y_k = h · P^k z0`` with ``P = expm(A dt)`` by a
  baby-step/giant-step product: rows ``hᵀ P^b`` (b < 2^κ) by doubling with the squares
  ``P^(2^j)`` (which continue the squaring chain of the exponential), columns
  ``P^(2^κ a) z0`` by ~n/2^κ matrix–vector products, and ``Y = R Lᵀ`` in one batched
  product. The error of ``P`` propagates at most linearly in k because ``P`` is a
  contraction: ~4e-12 of the signal amplitude after 1280 benchmark steps.
* :func:`response_times` — arbitrary (non-uniform) times via the eigendecomposition of A,
  with a guard against cancellation (near critical damping the eigenvectors coalesce)
  that falls back to one exact exponential per sample time.

Invalid input (non-finite, wrong shape) raises :class:`PropagationError` (a ValueError).
The response functions can instead report bad parameter sets in a ``valid`` mask
(``return_valid=True``); the rows of invalid sets are then NaN, so that a caller that
ignores the mask fails loudly instead of silently. Every set's result is independent of the
other sets in its batch (all choices are made per set).

Compiled path: numba (a dependency of the package) runs the same algorithm compiled with
``response_uniform(..., backend="numba")`` (a serial kernel per set, the batch split over
``threads``). The pure-numpy path is the reference, the default here, and what runs on a
platform where numba does not import.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache, wraps
from typing import Any

import numpy as np

from bayesbeam._util import compiled_kernel, numba_available, one_blas_thread
from bayesbeam.physics.expm import (
    _MAX_SQUARINGS,
    _PRESCALE_NORM,
    _THETA,
    PropagationError,
    _check_A,
    _chunk_size,
    _expm_chain,
    _finite_real,
    _inv_factorials,
    _raise_invalid,
)
from bayesbeam.physics.propagate_kernel import _uniform_kernel_py

__all__ = [
    "eigenvalues",
    "numba_available",
    "response_times",
    "response_uniform",
    "single_blas_thread",
    "state_matrix",
]


def single_blas_thread(func: Callable[..., Any]) -> Callable[..., Any]:
    """Run ``func`` with BLAS limited to one thread (decorator).

    The propagator's work is many small (64×64) products; OpenBLAS splits each over its
    threads with no gain and twice the CPU time (measured 2.3× slower wall time for
    batched forward calls on a loaded 2-core machine). Samplers, benchmarks and process
    pools therefore run with one BLAS thread per process.

    Parameters
    ----------
    func : callable

    Returns
    -------
    callable
    """
    @wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with one_blas_thread():
            return func(*args, **kwargs)

    return wrapper


# Cancellation factor Σ|a_j| / (|h||z0|) of the modal sum above which response_times does
# not trust the eigendecomposition (its rounding error is about u times it: ≲ 1e-10).
_MAX_CANCELLATION = 1e6
_EPS = float(np.finfo(float).eps)


# --------------------------------------------------------------------------- validation


def _check_vec(name: str, v, B: int, s: int) -> np.ndarray:
    a = _finite_real(name, v, (1, 2))
    if a.shape[-1] != s or (a.ndim == 2 and a.shape[0] != B):
        raise PropagationError(
            f"{name} must have shape ({B}, {s}) or ({s},) to match A {(B, s, s)}, got {a.shape}"
        )
    return np.ascontiguousarray(np.broadcast_to(a, (B, s)))


def _finite_rows(*arrays: np.ndarray) -> np.ndarray:
    """Rows (first axis) whose entries are all finite."""
    ok = np.ones(arrays[0].shape[0], dtype=bool)
    for a in arrays:
        flat = a.reshape(a.shape[0], -1)
        with np.errstate(over="ignore", invalid="ignore"):
            quick = np.isfinite(flat.sum(axis=1))  # one pass; a sum can only overflow...
        for b in np.flatnonzero(~quick):  # ...so look again where it is not finite
            quick[b] = np.isfinite(flat[b]).all()
        ok &= quick
    return ok


def _check_system(A, z0, h) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Check state matrices (B, s, s) and return them with z0 and h as (B, s)."""
    A = _check_A(A)
    B, s, _ = A.shape
    return A, _check_vec("z0", z0, B, s), _check_vec("h", h, B, s)


def _usable_rows(A: np.ndarray, z0: np.ndarray, h: np.ndarray, return_valid: bool):
    """Mask (B,) of the sets with finite input; raises for bad sets unless return_valid."""
    ok = _finite_rows(A, z0, h)
    if not return_valid and not ok.all():
        _raise_invalid(ok, "A, z0 or h")
    return ok


def _zero_unusable(ok: np.ndarray, A: np.ndarray, z0: np.ndarray, h: np.ndarray):
    """Zero the sets with non-finite input, so they compute harmlessly (masked later)."""
    return (
        np.where(ok[:, None, None], A, 0.0),
        np.where(ok[:, None], z0, 0.0),
        np.where(ok[:, None], h, 0.0),
    )


def _finish(y: np.ndarray, valid: np.ndarray, return_valid: bool):
    """Return ``(y, valid)`` with NaN rows for invalid sets, or ``y`` after raising for them."""
    if not return_valid:
        if not valid.all():
            _raise_invalid(valid, "the response")
        return y
    y[~valid] = np.nan
    return y, valid


# --------------------------------------------------------------------------- state matrix


def state_matrix(omega, C, *, check: bool = True) -> np.ndarray:
    """First-order modal state matrix ``A = [[0, Ω], [-Ω, -C]]``.

    Parameters
    ----------
    omega : array_like, shape (B, m)
        Undamped modal angular frequencies ω ≥ 0 in rad/s (Ω = diag(ω)).
    C : array_like, shape (B, m, m)
        Modal damping matrices ``Φᵀ D Φ`` in 1/s; symmetric (it is symmetrised here after
        a check) and, for a dissipative model, positive semidefinite.
    check : bool, optional
        If False, skip the value checks (finite, ω ≥ 0, symmetry; shapes are still
        checked) so that a bad parameter set reaches the response functions, whose
        ``return_valid=True`` then reports it per set instead of failing the whole batch.

    Returns
    -------
    numpy.ndarray, shape (B, 2m, 2m)
        State matrices in 1/s for the state ``z = [Ω q; q']`` (physics.md §4).

    Raises
    ------
    PropagationError
        On non-finite or negative ω, non-finite C, mismatched shapes, or a C that is not
        symmetric to 1e-8 relative.
    """
    w = _finite_real("omega", omega, (2,))
    c = _finite_real("C", C, (3,))
    B, m = w.shape
    if c.shape != (B, m, m):
        raise PropagationError(
            f"C must have shape {(B, m, m)} to match omega {w.shape}, got {c.shape}"
        )
    ct = np.swapaxes(c, 1, 2)
    if check and (not np.isfinite(w).all() or (w < 0).any()):
        raise PropagationError("omega must be finite and non-negative (rad/s)")
    if check and not np.isfinite(c).all():
        raise PropagationError("C must be finite")
    asym = np.abs(c - ct).max(axis=(1, 2), initial=0.0)
    scale = np.abs(c).max(axis=(1, 2), initial=0.0)
    if check and (asym > 1e-8 * scale).any():
        raise PropagationError(
            "C must be symmetric (Φᵀ D Φ with symmetric D, physics.md §1); "
            f"largest relative asymmetry {float((asym / np.where(scale > 0, scale, 1)).max()):.3g}"
        )
    A = np.zeros((B, 2 * m, 2 * m))
    i = np.arange(m)
    A[:, i, m + i] = w
    A[:, m + i, i] = -w
    A[:, m:, m:] = -0.5 * (c + ct)
    return A


# --------------------------------------------------------------------------- uniform grid


def _plan(n: int) -> int:
    """Choose κ, the number of extra squarings of the baby-step/giant-step product.

    There are then 2^κ baby steps and ceil(n / 2^κ) giant steps.

    Cost model in units of one 64×64 product (~8 µs), measured on the development machine:
    a squaring 1, a giant-step mat-vec 0.085, a doubling step with r rows 0.15 + 0.02 r.
    For n = 1280 it picks κ = 5 (32 baby steps, 40 giant steps).
    """
    best_k, best_cost = 0, math.inf
    for k in range(0, max(1, math.ceil(math.log2(max(n, 1)))) + 1):
        giant = 0.085 * (math.ceil(n / 2**k) - 1)
        cost = k + giant + sum(0.15 + 0.02 * 2**j for j in range(k))
        if cost < best_cost:
            best_k, best_cost = k, cost
    return best_k


def _uniform_numpy(A, z0, h, dt, n):
    k = _plan(n)

    def run(sl):
        with np.errstate(over="ignore", invalid="ignore"):  # detected via `valid`
            return _uniform_chunk(A[sl], z0[sl], h[sl], dt, n, k)

    return run


def _default_threads() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


@lru_cache(maxsize=8)
def _executor(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=threads, thread_name_prefix="bayesbeam-propagate")


def _run_split(run, B: int, n: int, pieces: list[slice], threads: int):
    """Evaluate ``run(slice) -> (y, valid)`` on the pieces, on ``threads`` threads."""
    y = np.empty((B, n))
    valid = np.empty(B, dtype=bool)
    if threads > 1 and len(pieces) > 1:
        results = list(_executor(threads).map(run, pieces))
    else:
        results = [run(sl) for sl in pieces]
    for sl, (yi, vi) in zip(pieces, results, strict=True):
        y[sl] = yi
        valid[sl] = vi
    return y, valid


def _uniform_chunk(A, z0, h, dt, n, k):
    B, s, _ = A.shape
    powers, valid = _expm_chain(A, extra=k, scale=dt)
    nb = 2**k
    ng = -(-n // nb)
    # Left rows hᵀ P^b, b = 0..nb-1, by doubling: [L; L P^(2^j)].
    L = h[:, None, :]
    for j in range(k):
        L = np.concatenate([L, L @ powers[j]], axis=1)
    # Right columns P^(nb a) z0, a = 0..ng-1 (stored as rows of R).
    Q = powers[k]
    R = np.empty((B, ng, s))
    R[:, 0] = z0
    for a in range(1, ng):
        R[:, a] = (Q @ R[:, a - 1, :, None])[..., 0]
    Y = (R @ np.swapaxes(L, 1, 2)).reshape(B, ng * nb)[:, :n]
    return Y, valid


def response_uniform(
    A,
    z0,
    h,
    dt: float,
    n: int,
    *,
    return_valid: bool = False,
    backend: str = "numpy",
    threads: int | None = 1,
):
    """Output ``y_k = h · expm(A k dt) z0`` on a uniform grid ``k = 0, ..., n-1``.

    Exact (no time-stepping error): ``P = expm(A dt)`` by :func:`expm_batched`'s algorithm,
    then a baby-step/giant-step product, ~2√n batched mat-vecs plus log2(√n) squarings
    instead of n sequential steps.

    Parameters
    ----------
    A : array_like, shape (B, s, s)
        State matrices in 1/s (see :func:`state_matrix`).
    z0 : array_like, shape (B, s) or (s,)
        Initial states ``[Ω q0; q0']``.
    h : array_like, shape (B, s) or (s,)
        Output row vectors (units of the measured quantity per unit state).
    dt : float
        Sample interval in s, finite and > 0.
    n : int
        Number of samples, ≥ 0 (sample k is at time k dt; k = 0 is the initial state).
    return_valid : bool, optional
        If True, return ``(y, valid)``: sets whose matrices/vectors are non-finite or whose
        response is not finite (e.g. a non-PSD C that makes it grow without bound) get
        ``valid[b] = False`` and a NaN row. If False (default) such sets raise.
    backend : {"numpy", "numba", "auto"}, optional
        ``"numba"`` uses the compiled kernel (requires numba; parallel over sets),
        ``"auto"`` uses it when numba is importable, ``"numpy"`` (default) is the pure-numpy
        reference. The numba kernel is compiled on first use (~10 s, cached on disk).
    threads : int or None, optional
        Threads over which the batch is split (numpy and the compiled kernel release the
        GIL). None: one per available CPU. Default 1, the right choice inside a process
        pool (emcee ``pool=``, dask) where the cores are already busy.

    Returns
    -------
    y : numpy.ndarray, shape (B, n)
        Output samples.
    valid : numpy.ndarray of bool, shape (B,)
        Only with ``return_valid=True``.

    Raises
    ------
    PropagationError
        On malformed input (shapes, dt, n), non-finite values without ``return_valid``,
        or an unavailable backend.
    """
    A, z0, h = _check_system(A, z0, h)
    B, s, _ = A.shape
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise PropagationError(f"dt must be a number in s, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise PropagationError(f"dt must be finite and > 0 (s), got {dt!r}")
    if isinstance(n, bool) or int(n) != n or n < 0:
        raise PropagationError(f"n must be a non-negative integer number of samples, got {n!r}")
    n = int(n)
    ok = _usable_rows(A, z0, h, return_valid)
    if B == 0 or n == 0 or s == 0:
        y = np.zeros((B, n))
        return (y, ok) if return_valid else y
    if not ok.all():
        A, z0, h = _zero_unusable(ok, A, z0, h)
    use = _pick_backend(backend)
    if threads is None:
        threads = _default_threads()
    elif isinstance(threads, bool) or not isinstance(threads, int | np.integer) or threads < 1:
        raise PropagationError(f"threads must be an integer >= 1 or None, got {threads!r}")
    if use == "numba":
        # Serial compiled kernel; one contiguous piece per thread (it releases the GIL).
        run = _uniform_numba(A, z0, h, dt, n)
        edges = np.linspace(0, B, min(threads, B) + 1).round().astype(int)
        pieces = [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]
    else:
        run = _uniform_numpy(A, z0, h, dt, n)
        ch = _chunk_size(s)
        pieces = [slice(i, i + ch) for i in range(0, B, ch)]
    y, valid = _run_split(run, B, n, pieces, threads)
    valid &= ok & np.isfinite(y).all(axis=1)
    return _finish(y, valid, return_valid)


# --------------------------------------------------------------------------- arbitrary times


def _times_direct(A: np.ndarray, z0: np.ndarray, h: np.ndarray, t: np.ndarray):
    """``h · expm(A t_k) z0`` for one matrix A (s, s), one exponential per time."""
    y = np.empty(t.size)
    ok = True
    chunk = _chunk_size(A.shape[0])
    for i in range(0, t.size, chunk):
        tc = t[i : i + chunk]
        (E,), v = _expm_chain(A[None] * tc[:, None, None])
        ok &= bool(v.all())
        y[i : i + chunk] = (E @ z0) @ h
    return y, ok


def _eig_coefficients(A: np.ndarray, z0: np.ndarray, h: np.ndarray):
    """Eigenvalues λ (B, s) and modal weights a_j = (h v_j)(w_j z0) (B, s), complex.

    A set whose eigendecomposition fails or whose eigenvector matrix is exactly singular
    gets NaN weights (not an exception for the whole batch).
    """
    try:
        lam, V = np.linalg.eig(A)
    except np.linalg.LinAlgError:  # QR iteration failed for some set: do them one by one
        B, s, _ = A.shape
        lam = np.full((B, s), np.nan, dtype=complex)
        V = np.full((B, s, s), np.nan, dtype=complex)
        for b in range(B):
            try:
                lam[b], V[b] = np.linalg.eig(A[b])
            except np.linalg.LinAlgError:
                continue  # stays NaN: reported as unusable by the caller
    lam = lam.astype(complex)
    V = V.astype(complex)
    rhs = z0.astype(complex)[..., None]
    try:
        c = np.linalg.solve(V, rhs)[..., 0]
    except np.linalg.LinAlgError:
        c = np.full(z0.shape, np.nan, dtype=complex)
        for b in range(A.shape[0]):
            try:
                c[b] = np.linalg.solve(V[b], rhs[b])[:, 0]
            except np.linalg.LinAlgError:
                continue  # stays NaN: reported as ill-conditioned by the caller
    # einsum, not matmul: numpy's complex matmul with a one-row operand is very slow.
    return lam, np.einsum("bi,bij->bj", h, V) * c


def _modal_sum(lam: np.ndarray, coef: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``Re Σ_j coef_j exp(λ_j t)`` for (B, s) λ, coef and times (T,) -> (B, T)."""
    # Conjugate pairs contribute equal real parts: keep Im λ ≥ 0, doubling Im λ > 0
    # (LAPACK's geev returns exactly conjugate pairs for real input).
    coef = coef * np.where(lam.imag > 0, 2.0, np.where(lam.imag == 0, 1.0, 0.0))
    # Terms that have decayed below 1e-17 of Σ|a| by the first positive time (stiff,
    # overdamped modes: e^(Re λ dt) ~ e^-300) only matter at t = 0, where e^0 = 1: add them
    # there as a constant and leave them out of the exponentials (a 2-3x saving, exact to
    # rounding).
    t_pos = t[t > 0]
    if t_pos.size:
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            late = np.abs(coef) * np.exp(lam.real * t_pos.min())
        drop = (late < 1e-17 * np.abs(coef).sum(axis=1, keepdims=True)) | (coef == 0)
    else:
        drop = coef == 0
    at_zero = np.where(drop, coef.real, 0.0).sum(axis=1)
    order = np.argsort(drop, axis=1, kind="stable")
    keep = max(1, int((~drop).sum(axis=1).max()))
    sel = order[:, :keep]
    lam = np.take_along_axis(lam, sel, axis=1)
    coef = np.where(np.take_along_axis(drop, sel, axis=1), 0, np.take_along_axis(coef, sel, 1))
    # Re(e^{λt} a) = Re e^{λt} Re a - Im e^{λt} Im a: one real product on the interleaved
    # (Re, Im) view of the complex exponentials (numpy's complex matmul with these shapes
    # does not use BLAS and is ~1000x slower).
    w = np.empty((coef.shape[0], keep, 2))
    w[:, :, 0] = coef.real
    w[:, :, 1] = -coef.imag
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        E = np.exp(t[None, :, None] * lam[:, None, :])
        y = (E.view(float) @ w.reshape(-1, 2 * keep, 1))[:, :, 0]
    y[:, t == 0] += at_zero[:, None]
    return y


def response_times(
    A,
    z0,
    h,
    t,
    *,
    method: str = "auto",
    max_cancellation: float = _MAX_CANCELLATION,
    return_valid: bool = False,
):
    """Output ``y(t) = h · expm(A t) z0`` at arbitrary (non-uniform, unsorted) times.

    ``method="eig"`` uses ``A = V Λ V⁻¹``: ``y(t) = Re Σ_j a_j e^{λ_j t}`` with
    ``a_j = (h v_j)(w_j z0)``, one LAPACK ``geev`` per set (~1 ms for s = 64) and O(T s)
    after that. Its rounding error, relative to ``|h| |z0|``, is about u times the
    cancellation factor ``Σ_j |a_j| / (|h| |z0|)`` (≈ κ(V): 2–6 in modal coordinates,
    physics.md §4, but unbounded near critical damping where eigenvectors coalesce), plus
    the effect of eig's backward error u‖A‖ on the eigenvalues over the time span
    (measured: 7e-12 of the amplitude on the benchmark matrices over 5 s).
    ``method="auto"`` (default) uses the eigendecomposition for sets whose cancellation
    factor is ≤ ``max_cancellation`` and which reproduce ``y(0) = h·z0``, and the exact
    ``method="expm"`` for the others: one matrix exponential per sample time (accurate to
    ~1e-12, no accumulation, but about T exponentials per set, ~0.3 s for T = 1280).

    Parameters
    ----------
    A : array_like, shape (B, s, s)
        State matrices in 1/s.
    z0 : array_like, shape (B, s) or (s,)
        Initial states.
    h : array_like, shape (B, s) or (s,)
        Output row vectors.
    t : array_like, shape (T,)
        Sample times in s, finite and ≥ 0, in any order.
    method : {"auto", "eig", "expm"}, optional
        See above.
    max_cancellation : float, optional
        Cancellation factor above which ``"auto"`` switches a set to ``"expm"`` and
        ``"eig"`` reports it invalid (default 1e6, i.e. ≲1e-10 relative rounding error).
    return_valid : bool, optional
        As in :func:`response_uniform`: return ``(y, valid)`` with NaN rows for invalid
        sets instead of raising.

    Returns
    -------
    y : numpy.ndarray, shape (B, T)
        Output at the requested times.
    valid : numpy.ndarray of bool, shape (B,)
        Only with ``return_valid=True``.

    Raises
    ------
    PropagationError
        On malformed input (shapes, negative or non-finite times, unknown method) or
        non-finite values without ``return_valid``.
    """
    A, z0, h = _check_system(A, z0, h)
    B, s, _ = A.shape
    t = _finite_real("t", t, (1,))
    if not np.isfinite(t).all() or (t < 0).any():
        raise PropagationError("t must hold finite, non-negative sample times in s")
    if method not in ("auto", "eig", "expm"):
        raise PropagationError(f"method must be 'auto', 'eig' or 'expm', got {method!r}")
    ok = _usable_rows(A, z0, h, return_valid)
    T = t.size
    y = np.zeros((B, T))
    valid = ok.copy()
    if B and T and s:
        A, z0, h = _zero_unusable(ok, A, z0, h)
        direct = np.zeros(B, dtype=bool) if method != "expm" else np.ones(B, dtype=bool)
        if method != "expm":
            lam, coef = _eig_coefficients(A, z0, h)
            # Cancellation factor Σ_j |a_j| / (|h| |z0|): the rounding error of the modal sum
            # relative to the signal scale is about u times this (it is ~κ(V) when the
            # eigenvectors are ill-conditioned, near critical damping). Also require the
            # sum to reproduce y(0) = h·z0 (a cheap check of the decomposition).
            scale = np.linalg.norm(h, axis=1) * np.linalg.norm(z0, axis=1)
            amp = np.abs(coef).sum(axis=1)
            resid0 = np.abs(coef.sum(axis=1).real - (h * z0).sum(axis=1))
            with np.errstate(divide="ignore", invalid="ignore"):
                amp = np.where(scale > 0, amp / scale, np.where(amp > 0, np.inf, 0.0))
                resid0 = np.where(scale > 0, resid0 / scale, np.where(resid0 > 0, np.inf, 0.0))
            # NaN (failed or singular decomposition) compares False: counts as bad.
            good = (amp <= max_cancellation) & (resid0 <= 1e3 * _EPS * np.maximum(amp, 1.0))
            if method == "auto":
                direct = ~good
            else:
                valid &= good
            idx = np.flatnonzero(good)
            if idx.size:
                y[idx] = _modal_sum(lam[idx], coef[idx], t)
        for b in np.flatnonzero(direct & ok):
            y[b], good_b = _times_direct(A[b], z0[b], h[b], t)
            valid[b] &= good_b
        valid &= np.isfinite(y).all(axis=1)
    return _finish(y, valid, return_valid)


# --------------------------------------------------------------------------- eigenvalues


def eigenvalues(A) -> np.ndarray:
    """Eigenvalues of a batch of state matrices, sorted by modulus (then imaginary part).

    Parameters
    ----------
    A : array_like, shape (B, s, s)
        Real matrices, 1/s.

    Returns
    -------
    numpy.ndarray of complex, shape (B, s)
        Eigenvalues λ in 1/s; for a mode, ``|λ|/2π`` is its frequency in Hz and
        ``-Re λ/|λ|`` its damping ratio. Conjugate pairs are adjacent (negative imaginary
        part first).

    Raises
    ------
    PropagationError
        If A is not a finite real (B, s, s) array.
    """
    A = _check_A(A)
    if not np.isfinite(A).all():
        _raise_invalid(_finite_rows(A), "A")
    lam = np.linalg.eigvals(A).astype(complex)
    order = np.lexsort((lam.imag, np.abs(lam)), axis=-1)
    return np.take_along_axis(lam, order, axis=-1)


# --------------------------------------------------------------------------- numba backend
#
# The kernel (bayesbeam.physics.propagate_kernel) is plain Python so that this module imports
# without numba; it is compiled (nogil, cached on disk) on first use, and the batch is
# split over threads.


def _pick_backend(backend: str) -> str:
    if backend not in ("numpy", "numba", "auto"):
        raise PropagationError(f"backend must be 'numpy', 'numba' or 'auto', got {backend!r}")
    if backend == "numpy":
        return "numpy"
    if numba_available():
        return "numba"
    if backend == "numba":
        raise PropagationError("backend='numba' needs numba installed; use backend='numpy'")
    return "numpy"


def _uniform_numba(A, z0, h, dt, n):
    kernel = compiled_kernel(_uniform_kernel_py, ())
    degrees = np.array(sorted(_THETA), dtype=np.int64)
    theta = np.array([_THETA[d] for d in degrees])
    consts = (_plan(n), theta, degrees, _inv_factorials(int(degrees.max())))
    consts += (_PRESCALE_NORM, _MAX_SQUARINGS)

    def run(sl):
        return kernel(A[sl], z0[sl], h[sl], float(dt), int(n), *consts)

    return run
