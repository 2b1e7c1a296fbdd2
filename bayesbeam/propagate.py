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

* :func:`expm_batched` — scaling and squaring with a truncated Taylor series evaluated by
  Paterson–Stockmeyer. Per matrix, the degree m ∈ {8, ..., 24} and the number of
  squarings s are chosen from the norms of A³ and A⁴ (Al-Mohy & Higham, SIAM J. Matrix
  Anal. Appl. 31 (2009) 970, Thm 4.2) so that the truncation has a relative backward error
  ≤ u = 2^-53 (θ_m: Higham, *Functions of Matrices* (2008) Table A.3): the lowest degree
  that needs no squaring, else m = 24. No LAPACK solve is needed, which matters: numpy's
  batched ``solve`` costs about eight 64×64 products. Rounding in the squaring phase
  grows like 2^s u: on the benchmark matrices (‖A dt‖₁ ≈ 5e3, s ≈ 11) the result is
  within ~4e-13 (Frobenius, relative) of an 80-bit reference; scipy.linalg.expm (Padé 13,
  fewer squarings) is at ~2e-13.
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

Optional acceleration: with numba installed, ``response_uniform(..., backend="numba")``
runs the same algorithm compiled (a serial kernel per set, the batch split over
``threads``). The pure-numpy path is the reference and is always available.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache, wraps
from typing import Any

import numpy as np

__all__ = [
    "PropagationError",
    "eigenvalues",
    "expm_batched",
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
    from threadpoolctl import threadpool_limits

    @wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return wrapper

class PropagationError(ValueError):
    """Invalid input to the time-response routines; the message says what and how to fix it."""


# θ_m: largest ‖2^-s A‖ (in the α_p sense) for which the degree-m Taylor polynomial has a
# relative backward error ≤ u = 2^-53 (Higham 2008, Table A.3; the same values as
# scipy.sparse.linalg._expm_multiply._theta).
_THETA = {8: 5.00e-2, 12: 3.00e-1, 16: 7.81e-1, 20: 1.44, 24: 2.22}
_M_MAX = 24
# Paterson–Stockmeyer block size: powers X², X³, X⁴ are formed once; degree m = 4 r then
# costs 3 + (r - 1) matrix products. Benchmark matrices (‖A dt‖₁ ≈ 5e3): m = 24 and 10–11
# squarings, 18–19 products in all.
_Q = 4
# Refuse matrices whose scaled norm would need more than this many squarings
# (‖A t‖ > ~1e38): no physical beam gets there and the loop would be pointless.
_MAX_SQUARINGS = 128
# Norm above which A is pre-scaled by a power of two before forming its powers: keeps
# A0^24 < 2^(30·24) and the folded coefficients f^24 > 2^-800 inside double range.
_PRESCALE_NORM = 2.0**30
# Matrix elements per numpy chunk: 8 sets of 64×64 (256 KiB per work array) keep the
# working set of a chunk in one core's L2 cache; whole batches of 64 were ~1.4× slower,
# chunks of 16 ~3 % slower.
_CHUNK_ELEMENTS = 8 * 64 * 64
# Cancellation factor Σ|a_j| / (|h||z0|) of the modal sum above which response_times does
# not trust the eigendecomposition (its rounding error is about u times it: ≲ 1e-10).
_MAX_CANCELLATION = 1e6
_EPS = float(np.finfo(float).eps)


def _inv_factorials(m: int) -> np.ndarray:
    return np.array([1.0 / math.factorial(k) for k in range(m + 1)])


# --------------------------------------------------------------------------- validation


def _finite_real(name: str, x, ndim: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(x)
    if np.iscomplexobj(a):
        raise PropagationError(f"{name} must be real, got a complex array")
    try:
        a = np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        raise PropagationError(f"{name} must be a numeric array, got {type(x).__name__}") from None
    if a.ndim not in ndim:
        want = " or ".join(f"{d}-D" for d in ndim)
        raise PropagationError(f"{name} must be a {want} array, got shape {a.shape}")
    return a


def _check_A(A) -> np.ndarray:
    a = _finite_real("A", A, (3,))
    if a.shape[1] != a.shape[2]:
        raise PropagationError(
            f"A must be a batch of square matrices (B, s, s), got shape {a.shape}; "
            "pass a single matrix as A[None]"
        )
    return np.ascontiguousarray(a)


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


def _raise_invalid(valid: np.ndarray, what: str) -> None:
    bad = np.flatnonzero(~valid)
    raise PropagationError(
        f"{what} is not finite for parameter set(s) {bad[:10].tolist()}"
        f"{' ...' if bad.size > 10 else ''} of {valid.size}: check those parameters "
        "(non-finite matrices, or a damping matrix that is not positive semidefinite so "
        "the response grows), or pass return_valid=True to get a mask instead"
    )


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


# --------------------------------------------------------------------------- exponential


def _chunk_size(s: int) -> int:
    """Return the number of sets per numpy batch: ~256 KiB per (B, s, s) array (8 at s = 64)."""
    return int(min(256, max(1, _CHUNK_ELEMENTS // max(1, s * s))))


_LOCAL = threading.local()


def _workspace(B: int, s: int, extra: int) -> dict:
    """Per-thread work arrays, reused between calls.

    Freshly allocated arrays of this size are returned to the OS when freed, so every call
    would page-fault them in again: that cost as much as the arithmetic (measured).
    """
    ws = getattr(_LOCAL, "ws", None)
    if ws is None or ws["s"] != s or ws["B"] < B or ws["extra"] < extra:
        Bc = max(B, ws["B"] if ws is not None and ws["s"] == s else 0)
        ex = max(extra, ws["extra"] if ws is not None and ws["s"] == s else 0)
        ws = {
            "B": Bc,
            "s": s,
            "extra": ex,
            "pw": np.empty((Bc, _Q, s, s)),
            "p": np.empty((Bc, s, s)),
            "tmp": np.empty((Bc, s, s)),
            "blk": np.empty((Bc, s, s)),
            "blocks": np.empty((Bc, max(_THETA) // _Q, s, s)),
            "powers": np.empty((ex + 1, Bc, s, s)),
        }
        _LOCAL.ws = ws
    return ws


def _expm_chain(
    A: np.ndarray, extra: int = 0, scale: float = 1.0
) -> tuple[list[np.ndarray], np.ndarray]:
    """Scaling-and-squaring exponential of ``A scale``, plus ``extra`` further squares.

    Returns ``([E, E^2, E^4, ..., E^(2^extra)], valid)`` with ``E = expm(A scale)``; rows
    with ``valid == False`` (non-finite input or result, absurd norm) hold garbage. The
    returned arrays are views of this thread's workspace: use them before the next call.
    Works best on chunks of :func:`_chunk_size` matrices (the working set stays in cache).
    Overflow is not warned about: it is detected and reported through ``valid``.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        return _expm_chain_impl(A, extra, scale)


def _norm1(X: np.ndarray, buf: np.ndarray) -> np.ndarray:
    """1-norms (max column sum) of a batch (B, s, s), using ``buf`` for |X|."""
    return np.abs(X, out=buf).sum(axis=1).max(axis=1)


def _expm_chain_impl(A: np.ndarray, extra: int, scale: float):
    B, s, _ = A.shape
    ws = _workspace(B, s, extra)
    pw = ws["pw"][:B]  # A0, A0², A0³, A0⁴ with A0 = A scale 2^-s0
    p, tmp, blk = ws["p"][:B], ws["tmp"][:B], ws["blk"][:B]
    X = pw[:, 0]
    np.multiply(A, scale, out=X)
    valid = np.isfinite(X.sum(axis=(1, 2)))
    if not valid.all():
        X[~valid] = 0.0
    # Exact power-of-two pre-scaling, only for very large norms, so that neither the powers
    # A0^k nor the folded coefficients c_k 2^(e k) below can over- or underflow.
    norm = _norm1(X, blk)
    with np.errstate(divide="ignore"):
        s0 = np.where(norm > _PRESCALE_NORM, np.ceil(np.log2(norm / _PRESCALE_NORM)), 0.0)
    s0 = s0.astype(np.int64)
    if (s0 > _MAX_SQUARINGS).any():
        valid &= s0 <= _MAX_SQUARINGS
        s0[s0 > _MAX_SQUARINGS] = 0
    if s0.any():
        X *= np.exp2(-s0.astype(float))[:, None, None]
    np.matmul(X, X, out=pw[:, 1])
    np.matmul(pw[:, 1], X, out=pw[:, 2])
    np.matmul(pw[:, 1], pw[:, 1], out=pw[:, 3])
    # α_3 = max(‖A³‖^(1/3), ‖A⁴‖^(1/4)) bounds the Taylor remainder for degree m ≥ 5
    # (Al-Mohy & Higham 2009, Thm 4.2 with p = 3); ≤ ‖A‖ and often much smaller.
    alpha = np.maximum(_norm1(pw[:, 2], blk) ** (1 / 3), _norm1(pw[:, 3], blk) ** (1 / 4))
    valid &= np.isfinite(alpha)
    alpha[~valid] = 0.0
    # Degree and squarings per matrix (so each set's result is independent of the batch):
    # the lowest degree m ≤ 24 with α ≤ θ_m if one suffices without squaring, otherwise
    # m = 24 and s = ceil(log2(α/θ_24)). Per product, m = 16 would be ~0.5 cheaper on
    # average, but a single degree for all stiff sets keeps the batched Horner loop free
    # of idle steps, and θ_24 = 2.8 θ_16 means 1.5 fewer squarings: their rounding error
    # grows like 2^s u.
    with np.errstate(divide="ignore"):
        s_tot = np.where(alpha > 0, np.ceil(np.log2(alpha / _THETA[_M_MAX])), 0.0)
    s_tot = np.clip(s0 + s_tot, 0, None).astype(np.int64)
    m_b = np.full(B, _M_MAX, dtype=np.int64)
    for m in sorted(_THETA, reverse=True):
        m_b[(s0 == 0) & (alpha <= _THETA[m])] = m
    m_max = int(m_b.max())
    r = m_max // _Q
    # Taylor polynomial of X f (f = 2^(s0 - s)) by Paterson–Stockmeyer in A0⁴:
    # T_m(X) = Σ_j Bj (A0⁴)^j,  Bj = Σ_{i<4} c_{4j+i} f^(4j+i) A0^i  (+ c_m f^m A0⁴ in the
    # top block). The scale f goes into the coefficients (exact: f is a power of two), so
    # no scaled copies of the powers are made. Matrices of lower degree get zero blocks
    # above their own top block; a zero block leaves the Horner recursion unchanged.
    f = np.exp2((s0 - s_tot).astype(float))
    k = np.arange(m_max + 1)
    coef = _inv_factorials(m_max)[None, :] * f[:, None] ** k[None, :]  # (B, m_max+1)
    coef[k[None, :] > m_b[:, None]] = 0.0
    top = coef[np.arange(B), m_b]
    coef[np.arange(B), m_b] = 0.0
    coef = coef[:, : _Q * r].reshape(B, r, _Q)
    W = np.zeros((B, r, _Q))
    W[:, :, :3] = coef[:, :, 1:]
    W[np.arange(B), m_b // _Q - 1, 3] = top
    diag = coef[:, :, 0]  # (B, r) identity coefficients
    flat = pw.reshape(B, _Q, s * s)

    # All blocks in one batched product (reads the powers once), identity terms on the
    # diagonal, then Horner: p = B_{r-1}; p = p A0⁴ + B_j.
    blocks = ws["blocks"][:B, :r]
    np.matmul(W, flat, out=blocks.reshape(B, r, s * s))
    blocks.reshape(B, r, s * s)[:, :, :: s + 1] += diag[:, :, None]
    A4 = pw[:, 3]
    p[...] = blocks[:, r - 1]
    for j in range(r - 2, -1, -1):
        np.matmul(p, A4, out=tmp)
        tmp += blocks[:, j]
        p, tmp = tmp, p
    for step in range(int(s_tot.max(initial=0))):
        mask = s_tot > step
        if mask.all():
            np.matmul(p, p, out=tmp)
            p, tmp = tmp, p
        else:
            idx = np.flatnonzero(mask)
            p[idx] = p[idx] @ p[idx]
    powers = ws["powers"][:, :B]
    powers[0] = p
    for j in range(extra):
        np.matmul(powers[j], powers[j], out=powers[j + 1])
    valid &= np.isfinite(powers[extra].sum(axis=(1, 2)))
    return [powers[j] for j in range(extra + 1)], valid


def expm_batched(A, *, return_valid: bool = False):
    """Matrix exponential of a batch of real matrices.

    Scaling and squaring with a Taylor polynomial (degree 8–24, Paterson–Stockmeyer
    evaluation), the degree and the number of squarings chosen from the norms of A², A³, A⁴
    so that the truncation has a relative backward error ≤ 2^-53 (Al-Mohy & Higham 2009).
    Each matrix gets its own number of squarings.

    Parameters
    ----------
    A : array_like, shape (B, s, s)
        Real matrices (for a state matrix times a time step: dimensionless).

    return_valid : bool, optional
        If True, return ``(E, valid)``: matrices that are not finite or whose exponential
        overflows get ``valid[b] = False`` and a NaN ``E[b]`` instead of an exception.

    Returns
    -------
    E : numpy.ndarray, shape (B, s, s)
        ``expm(A[b])`` for every b. On the benchmark state matrices (‖A dt‖₁ ≈ 5e3) it
        agrees with :func:`scipy.linalg.expm` to ≲ 5e-13 relative (Frobenius).
    valid : numpy.ndarray of bool, shape (B,)
        Only with ``return_valid=True``.

    Raises
    ------
    PropagationError
        If A is not a real (B, s, s) array; without ``return_valid`` also if it is not
        finite or its norm exceeds ~1e38 (more than 128 squarings).
    """
    A = _check_A(A)
    if A.shape[0] == 0 or A.shape[1] == 0:
        E = A.copy()
        return (E, np.ones(A.shape[0], dtype=bool)) if return_valid else E
    out = np.empty_like(A)
    valid = np.empty(A.shape[0], dtype=bool)
    ch = _chunk_size(A.shape[1])
    for i in range(0, A.shape[0], ch):
        (out[i : i + ch],), valid[i : i + ch] = _expm_chain(A[i : i + ch])
    valid &= np.isfinite(out.reshape(out.shape[0], -1)).all(axis=1)
    if return_valid:
        out[~valid] = np.nan
        return out, valid
    if not valid.all():
        _raise_invalid(valid, "A (or expm(A))")
    return out


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
    A = _check_A(A)
    B, s, _ = A.shape
    z0 = _check_vec("z0", z0, B, s)
    h = _check_vec("h", h, B, s)
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise PropagationError(f"dt must be a number in s, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise PropagationError(f"dt must be finite and > 0 (s), got {dt!r}")
    if isinstance(n, bool) or int(n) != n or n < 0:
        raise PropagationError(f"n must be a non-negative integer number of samples, got {n!r}")
    n = int(n)
    ok = _finite_rows(A, z0, h)
    if not return_valid and not ok.all():
        _raise_invalid(ok, "A, z0 or h")
    if B == 0 or n == 0 or s == 0:
        y = np.zeros((B, n))
        return (y, ok) if return_valid else y
    if not ok.all():  # compute the bad sets harmlessly (zeros); they are masked below
        A = np.where(ok[:, None, None], A, 0.0)
        z0 = np.where(ok[:, None], z0, 0.0)
        h = np.where(ok[:, None], h, 0.0)
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
    if not return_valid:
        if not valid.all():
            _raise_invalid(valid, "the response")
        return y
    y[~valid] = np.nan
    return y, valid


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
    A = _check_A(A)
    B, s, _ = A.shape
    z0 = _check_vec("z0", z0, B, s)
    h = _check_vec("h", h, B, s)
    t = _finite_real("t", t, (1,))
    if not np.isfinite(t).all() or (t < 0).any():
        raise PropagationError("t must hold finite, non-negative sample times in s")
    if method not in ("auto", "eig", "expm"):
        raise PropagationError(f"method must be 'auto', 'eig' or 'expm', got {method!r}")
    ok = _finite_rows(A, z0, h)
    if not return_valid and not ok.all():
        _raise_invalid(ok, "A, z0 or h")
    T = t.size
    y = np.zeros((B, T))
    valid = ok.copy()
    if B and T and s:
        A = np.where(ok[:, None, None], A, 0.0)
        z0 = np.where(ok[:, None], z0, 0.0)
        h = np.where(ok[:, None], h, 0.0)
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
    if not return_valid:
        if not valid.all():
            _raise_invalid(valid, "the response")
        return y
    y[~valid] = np.nan
    return y, valid


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
# The same algorithm as _expm_chain + _uniform_chunk, one parameter set per loop iteration.
# Written as a plain Python function so that this module imports without numba; it is
# compiled (nogil, cached on disk) on first use, and the batch is split over threads.


def _uniform_kernel_py(A, z0, h, dt, n, k, theta, degrees, inv_fact, prescale, max_sq):
    B, s = z0.shape
    y = np.zeros((B, n))
    valid = np.zeros(B, dtype=np.bool_)
    nb = 2**k
    ng = (n + nb - 1) // nb
    for b in range(B):
        X = A[b] * dt
        norm = 0.0
        for j in range(s):
            col = 0.0
            for i in range(s):
                col += abs(X[i, j])
            norm = max(norm, col)
        if not np.isfinite(norm):
            continue
        s0 = 0
        if norm > prescale:
            s0 = int(math.ceil(math.log2(norm / prescale)))
            if s0 > max_sq:
                continue
            X = X * 2.0 ** (-s0)
        A2 = X @ X
        A3 = A2 @ X
        A4 = A2 @ A2
        n3 = 0.0
        n4 = 0.0
        for j in range(s):
            c3 = 0.0
            c4 = 0.0
            for i in range(s):
                c3 += abs(A3[i, j])
                c4 += abs(A4[i, j])
            n3 = max(n3, c3)
            n4 = max(n4, c4)
        alpha = max(n3 ** (1.0 / 3.0), n4**0.25)
        if not np.isfinite(alpha):
            continue
        m = degrees[degrees.size - 1]
        sq = 0
        if alpha > 0.0:
            sq = max(0, s0 + int(math.ceil(math.log2(alpha / theta[degrees.size - 1]))))
        if s0 == 0:
            for d in range(degrees.size - 1, -1, -1):
                if alpha <= theta[d]:
                    m = degrees[d]
        r = m // 4
        f = 2.0 ** (s0 - sq)
        coef = np.empty(m + 1)
        for i in range(m + 1):
            coef[i] = inv_fact[i] * f**i
        p = np.empty((s, s))
        for j in range(r - 1, -1, -1):
            top = coef[m] if j == r - 1 else 0.0
            if j < r - 1:
                p = p @ A4
            c1 = coef[4 * j + 1]
            c2 = coef[4 * j + 2]
            c3 = coef[4 * j + 3]
            for i in range(s):
                for q in range(s):
                    v = c1 * X[i, q] + c2 * A2[i, q] + c3 * A3[i, q] + top * A4[i, q]
                    if j < r - 1:
                        v += p[i, q]
                    p[i, q] = v
                p[i, i] += coef[4 * j]
        for _ in range(sq):
            p = p @ p
        pw = np.empty((k + 1, s, s))
        pw[0] = p
        for j in range(k):
            pw[j + 1] = pw[j] @ pw[j]
        L = np.empty((nb, s))
        L[0] = h[b]
        for j in range(k):
            w = 2**j
            L[w : 2 * w] = L[:w] @ pw[j]
        R = np.empty((ng, s))
        R[0] = z0[b]
        Q = pw[k]
        for a in range(1, ng):
            R[a] = Q @ R[a - 1]
        Y = R @ L.T
        ok = True
        for a in range(ng):
            for i in range(nb):
                idx = a * nb + i
                if idx < n:
                    v = Y[a, i]
                    if not np.isfinite(v):
                        ok = False
                    y[b, idx] = v
        valid[b] = ok
    return y, valid


@lru_cache(maxsize=1)
def _numba_kernel():
    try:
        import numba
    except ImportError:
        return None
    return numba.njit(nogil=True, cache=True)(_uniform_kernel_py)


def numba_available() -> bool:
    """Whether the optional numba backend can be used.

    Returns
    -------
    bool
        True if numba imports (the kernel is compiled on first use, a few seconds).
    """
    return _numba_kernel() is not None


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
    kernel = _numba_kernel()
    degrees = np.array(sorted(_THETA), dtype=np.int64)
    theta = np.array([_THETA[d] for d in degrees])
    consts = (_plan(n), theta, degrees, _inv_factorials(int(degrees.max())))
    consts += (_PRESCALE_NORM, _MAX_SQUARINGS)

    def run(sl):
        return kernel(A[sl], z0[sl], h[sl], float(dt), int(n), *consts)

    return run
