"""Batched matrix exponential of real matrices, and the input checks of the propagators.

The lowest layer of the exact time response (:mod:`bayesbeam.physics.propagate` builds on it):

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
* ``_expm_chain`` — the same exponential followed by further squarings ``E^(2^j)``, on a
  per-thread workspace; :func:`bayesbeam.physics.propagate.response_uniform` continues that chain.

Invalid input raises :class:`PropagationError` (a ValueError), re-exported by
:mod:`bayesbeam.physics.propagate`. The underscored helpers and constants are shared with
:mod:`bayesbeam.physics.propagate` only.
"""

from __future__ import annotations

import math
import threading

import numpy as np

__all__ = ["PropagationError", "expm_batched"]


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


def _raise_invalid(valid: np.ndarray, what: str) -> None:
    bad = np.flatnonzero(~valid)
    raise PropagationError(
        f"{what} is not finite for parameter set(s) {bad[:10].tolist()}"
        f"{' ...' if bad.size > 10 else ''} of {valid.size}: check those parameters "
        "(non-finite matrices, or a damping matrix that is not positive semidefinite so "
        "the response grows), or pass return_valid=True to get a mask instead"
    )


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
