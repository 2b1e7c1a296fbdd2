"""Closed-form response of classically damped modes, batched over parameter sets.

When the modal damping matrix ``C = Φᵀ D Φ`` is diagonal (viscous damping ∝ M and
Kelvin–Voigt damping ∝ K on a beam whose structure does not vary between sets, physics.md
§1–§2), the modal system ``z' = A z`` of :mod:`bayesbeam.physics.propagate` splits into
independent oscillators ``q_k'' + c_k q_k' + ω_k² q_k = 0``, and the sensor signal is a sum
of damped exponentials with no propagation at all:

    y(t) = Σ_k s_k x_k(t),      x_k'' + c_k x_k' + ω_k² x_k = 0,

where ``x_k`` is the modal displacement, velocity or acceleration (each obeys the mode's
own equation) and ``s_k = N(x_s) φ_k`` the sensor's modal row. With ``σ = c/2``:

* underdamped (``ω > σ``, ``d = sqrt((ω - σ)(ω + σ))``): ``x(t) = Re[A e^{λt}]``,
  ``λ = -σ + i d``, ``A = x0 - i (x0' + σ x0) / d``;
* overdamped (``σ > ω``, ``δ = sqrt((σ - ω)(σ + ω))``): two real roots
  ``λ1 = -ω² / (σ + δ)`` (the slow one, written without cancellation) and
  ``λ2 = -(σ + δ)``, ``x(t) = a1 e^{λ1 t} + a2 e^{λ2 t}`` with
  ``a1 = (x0' - λ2 x0) / (2δ)``, ``a2 = (λ1 x0 - x0') / (2δ)``;
* near critical damping (``|d|`` or ``δ`` below :data:`NEAR_CRITICAL` ``· ω``) the
  coefficients above grow as ``1/d`` and their sum cancels, so those modes use the
  stable form ``x(t) = e^{-σt} [x0 C(t) + (x0' + σ x0) S(t)]`` with ``C = cos dt``,
  ``S = sin(dt)/d`` (``S = t`` at exactly critical damping), or ``C = cosh δt``,
  ``S = sinh(δt)/δ`` written with ``expm1`` (no overflow, no cancellation).

The sensor band (:func:`bayesbeam.physics.sensor.band_limit`) keeps exactly the
eigen-solutions ``e^{λt}`` with ``|λ| <= w_band``: here each root is a term of its own,
so a term is kept or dropped by its own ``|λ|`` (an overdamped mode whose band edge falls
between its two roots keeps its slow root only, as the eigenvector route does). A
near-critical mode split by the band edge is not handled here (its one-root coefficient
is ill-conditioned for every method): such sets are returned with ``ok = False`` so that
the caller propagates them in full.

Evaluation. For a uniform grid ``t_j = t_first + j dt`` the exponentials factor as
``e^{λ t_j} = [e^{λ (t_first + a nb dt)}] [e^{λ b dt}]`` with ``j = a nb + b``: the ``nb``
baby steps and ``ng ≈ T / nb`` giant steps of every term are products of
``r = e^{λ dt}`` built by doubling, and the sum over terms is one real matrix product per
set of ``(ng, 2J) @ (2J, nb)`` (see :func:`term_sum_uniform` for the measured choice
against direct ``exp``, ~50x slower). With numba (a dependency; the numpy route stays for
platforms without it) the same factorisation runs compiled, term by term, in
:mod:`bayesbeam.physics.modal_kernel`. Arbitrary stamps take one complex exponential per
term and stamp.
"""

from __future__ import annotations

import math

import numpy as np

from bayesbeam._util import compiled_kernel
from bayesbeam.physics.modal_kernel import _term_sum_kernel_py
from bayesbeam.physics.propagate import _finite_rows, _pick_backend

__all__ = [
    "NEAR_CRITICAL",
    "closed_form_response",
    "compiled_kernel",
    "modal_terms",
    "term_sum_times",
    "term_sum_uniform",
    "terms_response",
]

#: Relative distance ``|d| / ω`` (or ``δ / ω``) to critical damping below which a mode
#: uses the stable direct form: the exponential form's rounding error is about
#: ``u ω / d`` of the mode's amplitude, ≤ 2e-13 above this.
NEAR_CRITICAL = 1e-3

#: Terms smaller than this fraction of a set's total amplitude at the first positive
#: stamp are left out of the exponentials (they only matter at t = 0), as in
#: :func:`bayesbeam.physics.propagate.response_times`: exact to rounding.
_NEGLIGIBLE = 1e-17

#: Largest phase ``|Im λ| t`` (rad) the closed form evaluates; see closed_form_response.
_MAX_PHASE = 1e12


def _quantity_initial(
    omega: np.ndarray, c: np.ndarray, q0: np.ndarray, v0: np.ndarray, quantity: str
) -> tuple[np.ndarray, np.ndarray]:
    """Return the initial value and derivative of the modal quantity the sensor measures."""
    if quantity == "displacement":
        return q0, v0
    a0 = -omega**2 * q0 - c * v0
    if quantity == "velocity":
        return v0, a0
    if quantity == "acceleration":
        return a0, -omega**2 * v0 - c * a0
    raise ValueError(
        f"quantity must be 'displacement', 'velocity' or 'acceleration', got {quantity!r}"
    )


def modal_terms(
    omega: np.ndarray,
    c: np.ndarray,
    y0: np.ndarray,
    dy0: np.ndarray,
    w_band: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Exponential terms of independent damped modes: ``y(t) = Re Σ_j a_j e^{λ_j t}``.

    Parameters
    ----------
    omega : ndarray, shape (B, m)
        Undamped angular frequencies, rad/s, ≥ 0.
    c : ndarray, shape (B, m)
        Modal damping (the diagonal of ``Φᵀ D Φ``), 1/s, ≥ 0.
    y0, dy0 : ndarray, shape (B, m)
        Each mode's contribution to the output at t = 0 and its time derivative (units of
        the output, and per s).
    w_band : float or None
        Sensor band in rad/s: terms with ``|λ| > w_band`` are dropped. None: all kept.

    Returns
    -------
    lam, coef : ndarray of complex, shape (B, 2m)
        Roots (1/s) and coefficients; column ``k`` holds mode k's underdamped root
        (``Im λ > 0``) or slow overdamped root, column ``m + k`` its fast overdamped root;
        dropped or unused terms have ``coef = 0``.
    near : ndarray of bool, shape (B, m)
        Modes near critical damping, for :func:`_near_critical_sum` (their ``coef`` is 0).
    split : ndarray of bool, shape (B,)
        Sets with a near-critical mode whose two roots the band edge separates.
    """
    sigma = 0.5 * c
    under = omega > sigma
    gap = np.abs(omega - sigma) * (omega + sigma)
    root = np.sqrt(gap)  # d (underdamped) or δ (overdamped), without cancellation
    near = root < NEAR_CRITICAL * omega
    with np.errstate(divide="ignore", invalid="ignore"):
        # Underdamped: A = y0 - i (y0' + σ y0) / d.
        a_under = y0 - 1j * (dy0 + sigma * y0) / root
        fast = sigma + root  # |λ2| of an overdamped mode
        lam1 = -omega**2 / fast
        a1 = (dy0 + fast * y0) / (2 * root)
        a2 = (lam1 * y0 - dy0) / (2 * root)
    lam = np.concatenate([np.where(under, -sigma + 1j * root, lam1), -fast + 0j], axis=1)
    coef = np.concatenate([np.where(under, a_under, a1), np.where(under, 0.0, a2)], axis=1)
    far = ~near
    coef = np.where(np.concatenate([far, far & ~under], axis=1), coef, 0.0)
    split = np.zeros(omega.shape[0], dtype=bool)
    if w_band is not None:
        mag = np.abs(lam)
        coef = np.where(mag <= w_band, coef, 0.0)
        # A near-critical overdamped mode whose fast root is out of band and slow one in.
        split = (near & ~under & (fast > w_band) & (-lam1 <= w_band)).any(axis=1)
        near = near & (np.where(under, omega, fast) <= w_band)
    return lam, coef, near, split


def _compact(
    lam: np.ndarray, coef: np.ndarray, t_min: float, order: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Drop zero terms and terms decayed below 1e-17 of the total by ``t_min`` (> 0).

    Returns the remaining ``lam``, ``coef`` (B, J) with J the largest count over the sets,
    ordered per set by decreasing lifetime (padding terms have ``coef = 0`` and come
    last), their lifetimes (:func:`_lifetimes`, -inf for padding), and each set's sum of
    dropped real parts (B,), which belong to t = 0 only. With ``order=False`` the terms
    keep their columns (dropped ones get ``coef = 0``, lifetime -inf): the compiled
    kernel skips them itself, and the sort costs as much as its whole sum at 1,280 stamps.
    """
    amp = np.abs(coef)
    with np.errstate(under="ignore"):
        late = amp * np.exp(lam.real * t_min) if t_min > 0 else amp
    drop = (late < _NEGLIGIBLE * amp.sum(axis=1, keepdims=True)) | (coef == 0)
    at_zero = np.where(drop, coef.real, 0.0).sum(axis=1)
    keep = max(1, int((~drop).sum(axis=1).max(initial=0)))
    coef = np.where(drop, 0.0, coef)
    life = np.where(drop, -np.inf, _lifetimes(lam, coef))
    if not order:
        return lam, coef, life, at_zero
    idx = np.argsort(-life, axis=1, kind="stable")[:, :keep]
    lam = np.take_along_axis(np.where(drop, 0.0, lam), idx, axis=1)
    coef = np.take_along_axis(coef, idx, axis=1)
    return lam, coef, np.take_along_axis(life, idx, axis=1), at_zero


def _lifetimes(lam: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """Time (s) after which ``|coef_j e^{λ_j t}|`` stays below 1e-17 of ``Σ_j |coef_j|``.

    inf for undamped terms, -inf for zero ones; shape (B, J).
    """
    amp = np.abs(coef)
    total = amp.sum(axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        life = np.log(amp / (_NEGLIGIBLE * total)) / -lam.real
    life = np.where(lam.real < 0, life, np.inf)
    return np.where(amp > 0, np.nan_to_num(life, nan=np.inf), -np.inf)


def _powers(
    first: np.ndarray, factor: np.ndarray, n: int, alive: np.ndarray | None = None
) -> np.ndarray:
    """``first · factor^i`` for i = 0..n-1, shape (B, n, J), by doubling.

    Block ``[filled, 2 filled)`` is block ``[0, filled)`` times ``factor^filled``, the
    factor squared once per block: ``log2 n`` vectorised products. With ``alive`` (n,),
    non-increasing, row i is computed only in its first ``alive[i]`` terms (the others
    are left undefined: the caller never reads them).
    """
    B, J = first.shape
    out = np.empty((B, n, J), dtype=complex)
    out[:, 0] = first
    filled, f = 1, factor[:, None, :]
    while filled < n:
        k = min(filled, n - filled)
        cols = J if alive is None else int(alive[filled])
        np.multiply(out[:, :k, :cols], f[:, :, :cols],
                    out=out[:, filled : filled + k, :cols])
        filled += k
        if filled < n:
            f = f * f
    return out


#: Sets per block of :func:`term_sum_uniform`: keeps a block's powers and output in cache
#: (fresh large arrays cost page faults that were measured to dominate on a loaded machine).
_SETS_PER_BLOCK = 8


def term_sum_uniform(
    lam: np.ndarray, coef: np.ndarray, t_first: float, dt: float, n: int,
    life: np.ndarray | None = None, backend: str = "auto",
) -> np.ndarray:
    """``Re Σ_j coef_j e^{λ_j (t_first + k dt)}`` for k = 0..n-1.

    Parameters
    ----------
    lam, coef : ndarray of complex, shape (B, J)
        Roots (1/s, ``Re λ <= 0``) and coefficients.
    t_first : float
        First stamp in s, ≥ 0.
    dt : float
        Step in s, > 0.
    n : int
        Number of stamps.
    life : ndarray, shape (B, J), optional
        :func:`_lifetimes` of the terms, if already known.
    backend : {"auto", "numba", "numpy"}
        ``"numba"``: the compiled kernel
        (:func:`bayesbeam.physics.modal_kernel._term_sum_kernel_py`; needs numba),
        ``"numpy"``: the numpy route below, ``"auto"``: numba when importable.

    Returns
    -------
    ndarray, shape (B, n)

    Raises
    ------
    bayesbeam.physics.expm.PropagationError
        For an unknown ``backend``, or ``"numba"`` without numba (a ValueError).

    Notes
    -----
    Both routes leave a term out of the stamps after its lifetime (:func:`_lifetimes`:
    below 1e-17 of the amplitude from then on) and agree to ~1e-13 of ``Σ_j |coef_j|``
    (measured 7e-14 at 10,240 stamps, mostly the numpy route's stepping).
    The compiled kernel, term by term with an exact exponential every 1,024 stamps, is
    within ~4e-14 of each term's amplitude at any length (its Notes). Numpy route:
    with ``r = e^{λ dt}`` (one exponential per term), baby steps ``r^b`` (b < nb) and giant
    steps ``coef e^{λ t_first} r^{nb a}`` (a < ng) by :func:`_powers`, then one real
    product ``(ng, 2J) @ (2J, nb)`` per set on the interleaved (Re, Im) views:
    ``Re(g b) = Re g Re b - Im g Im b`` is the product of ``g`` with ``conj(b)``'s
    (Re, Im) pairs. The rounding of ``r`` grows linearly in the power, as in any stepping
    (``k u``: ≤ 2.3e-12 of the amplitude at 10,240 stamps); the products add ``log2 T``
    roundings. Measured on 64 sets of 32 terms (2-core development machine under load,
    one BLAS thread, CPU time per set): direct complex ``exp`` of every (term, stamp)
    (:func:`term_sum_times`) 2.3 ms at 1,280 stamps and 20 ms at 10,240 (numpy's complex
    ``exp`` is not vectorised, ~50 ns each); this route 47 µs and 190 µs; the compiled
    kernel 25 µs and 100–130 µs.
    """
    if _pick_backend(backend) == "numba":
        return _term_sum_numba(lam, coef, t_first, dt, n, life)
    B, J = lam.shape
    nb = 2 ** max(0, round(math.log2(max(n, 1)) / 2))
    ng = -(-n // nb)
    y = np.empty((B, ng * nb))
    # Giant row a starts at t_first + a nb dt; a term whose lifetime ends before then is
    # below 1e-17 of the amplitude for the whole row and is left out of it (exact to
    # rounding; heavily damped Kelvin–Voigt modes die long before the record ends).
    # Terms are ordered by lifetime (_compact), so row a needs the first `alive` ones.
    row_start = t_first + nb * dt * np.arange(ng)
    life = _lifetimes(lam, coef) if life is None else life
    with np.errstate(invalid="ignore"):  # inf - inf: equal lifetimes, in order
        unordered = np.any(np.diff(life, axis=1) > 0)
    if unordered:  # not yet ordered by decreasing lifetime
        order = np.argsort(-life, axis=1, kind="stable")
        lam, coef, life = (np.take_along_axis(x, order, axis=1) for x in (lam, coef, life))
    # Terms alive in each giant row (over the whole batch: its sets are alike), rounded
    # up to multiples of 8 so that a block needs only a few matrix products.
    alive = (life[:, :, None] > row_start[None, None, :]).sum(axis=1).max(axis=0)
    alive = np.minimum(-(-np.maximum(alive, 1) // 8) * 8, J)
    groups = np.flatnonzero(np.r_[True, alive[1:] != alive[:-1]])
    bounds = [(int(a0), int(a1), int(alive[a0]))
              for a0, a1 in zip(groups, np.r_[groups[1:], ng], strict=True)]
    with np.errstate(under="ignore"):
        r = np.exp(lam * dt)
        start = coef * np.exp(lam * t_first) if t_first > 0 else coef
    for i in range(0, B, _SETS_PER_BLOCK):
        sl = slice(i, i + _SETS_PER_BLOCK)
        with np.errstate(under="ignore"):
            # conj(r)^b = conj(r^b): the right factor's (Re, Im) pairs are (Re b, -Im b).
            baby = _powers(np.ones_like(r[sl]), r[sl].conj(), nb)
            giant = _powers(start[sl], baby[:, -1].conj() * r[sl], ng, alive)
        out = y[sl].reshape(-1, ng, nb)
        # (B, ng, 2J) rows times (B, 2J, nb) columns: both BLAS-ready without copies.
        gv = giant.view(float)
        bv = baby.view(float).transpose(0, 2, 1)
        for a0, a1, k in bounds:
            np.matmul(gv[:, a0:a1, : 2 * k], bv[:, : 2 * k], out=out[:, a0:a1])
    return y[:, :n]


def _term_sum_numba(
    lam: np.ndarray, coef: np.ndarray, t_first: float, dt: float, n: int,
    life: np.ndarray | None,
) -> np.ndarray:
    """Return the compiled route of :func:`term_sum_uniform` (same arguments) → (B, n)."""
    life = _lifetimes(lam, coef) if life is None else life
    # Stamps k with t_first + k dt < life: inf (undamped) → n, -inf (zero term) → 0; a
    # lifetime beyond ~1e308 dt (nearly undamped) overflows to inf, also → n.
    with np.errstate(over="ignore"):
        steps = np.clip(np.ceil((life - t_first) / dt), 0, n).astype(np.int64)
    parts = (np.ascontiguousarray(x, dtype=float)
             for x in (lam.real, lam.imag, coef.real, coef.imag))
    return compiled_kernel(_term_sum_kernel_py)(*parts, steps, float(t_first), float(dt), int(n))


def term_sum_times(lam: np.ndarray, coef: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``Re Σ_j coef_j e^{λ_j t}`` at arbitrary stamps ``t`` (T,) ≥ 0 → (B, T)."""
    B, J = lam.shape
    w = np.empty((B, J, 2))
    w[:, :, 0] = coef.real
    w[:, :, 1] = -coef.imag
    with np.errstate(under="ignore"):
        E = np.exp(t[None, :, None] * lam[:, None, :])
    return (E.view(float) @ w.reshape(B, 2 * J, 1))[:, :, 0]


def _near_critical_sum(
    omega: np.ndarray, c: np.ndarray, y0: np.ndarray, dy0: np.ndarray, near: np.ndarray,
    t: np.ndarray,
) -> np.ndarray:
    """Stable direct form of the near-critical modes, summed per set → (B, T)."""
    y = np.zeros((omega.shape[0], t.size))
    for b, k in zip(*np.nonzero(near), strict=True):
        w, s = float(omega[b, k]), 0.5 * float(c[b, k])
        x0, beta = float(y0[b, k]), float(dy0[b, k]) + s * float(y0[b, k])
        r = math.sqrt(abs(w - s) * (w + s))
        if w > s:  # underdamped: e^{-σt} (x0 cos dt + β sin(dt)/d); S = t when d = 0
            decay = np.exp(-s * t)
            sine = np.sin(r * t) / r if r > 0 else t
            y[b] += decay * (x0 * np.cos(r * t) + beta * sine)
        else:  # overdamped: e^{(-σ+δ)t} [(1 + e^{-2δt}) / 2, -expm1(-2δt) / (2δ)]
            slow = np.exp((r - s) * t)
            e2 = np.exp(-2 * r * t)
            sinh = -np.expm1(-2 * r * t) / (2 * r) if r > 0 else t
            y[b] += slow * (x0 * 0.5 * (1 + e2) + beta * sinh)
    return y


def closed_form_response(
    omega: np.ndarray,
    c: np.ndarray,
    q0: np.ndarray,
    v0: np.ndarray,
    s: np.ndarray,
    quantity: str,
    *,
    times: np.ndarray | None = None,
    uniform: tuple[float, float, int] | None = None,
    w_band: float | None = None,
    backend: str = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Sensor signal of classically damped modes in closed form.

    Parameters
    ----------
    omega : ndarray, shape (B, m)
        Undamped angular frequencies, rad/s.
    c : ndarray, shape (B, m)
        Diagonal modal damping, 1/s.
    q0, v0 : ndarray, shape (B, m)
        Modal displacement (m·kg^½) and velocity at t = 0 (``z0 = [Ω q0; v0]``).
    s : ndarray, shape (B, m) or (m,)
        Sensor modal row ``N(x_s) Φ``.
    quantity : str
        'displacement', 'velocity' or 'acceleration'.
    times : ndarray, shape (T,), optional
        Stamps in s from t = 0, all ≥ 0. Give this or ``uniform``.
    uniform : tuple (t_first, dt, n), optional
        Stamps ``t_first + k dt``, k = 0..n-1 (s).
    w_band : float or None
        Sensor band in rad/s (see the module docstring).
    backend : {"auto", "numba", "numpy"}
        Route of a uniform grid's sum (:func:`term_sum_uniform`).

    Returns
    -------
    y : ndarray, shape (B, T)
        Output in SI units of the quantity.
    ok : ndarray of bool, shape (B,)
        False where the input or the result is not finite, where a near-critical mode
        is split by the band, or where a kept term's phase ``|Im λ| t`` exceeds 1e12 rad
        (the caller propagates those sets in full).
    """
    s = np.broadcast_to(s, omega.shape)
    x0, dx0 = _quantity_initial(omega, c, q0, v0, quantity)
    y0, dy0 = s * x0, s * dx0
    ok = np.isfinite(omega).all(axis=1) & np.isfinite(c).all(axis=1)
    ok &= np.isfinite(y0).all(axis=1) & np.isfinite(dy0).all(axis=1)
    if not ok.all():  # unusable sets compute harmlessly on zeros (flagged, not used)
        omega, c = np.where(ok[:, None], omega, 1.0), np.where(ok[:, None], c, 0.0)
        y0, dy0 = np.where(ok[:, None], y0, 0.0), np.where(ok[:, None], dy0, 0.0)
    lam, coef, near, split = modal_terms(omega, c, y0, dy0, w_band)
    y, ok_terms, t = terms_response(lam, coef, times=times, uniform=uniform, backend=backend)
    ok &= ~split & ok_terms
    if near.any():
        y += _near_critical_sum(omega, c, y0, dy0, near, t)
        ok &= _finite_rows(y)
    return y, ok


def terms_response(
    lam: np.ndarray, coef: np.ndarray, *, times: np.ndarray | None = None,
    uniform: tuple[float, float, int] | None = None, backend: str = "auto",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``y(t) = Re Σ_j coef_j e^{λ_j t}`` at the stamps, with the checks of the closed form.

    Parameters
    ----------
    lam, coef : ndarray of complex, shape (B, J)
        Roots (1/s, ``Re λ <= 0``) and coefficients (units of the output); terms with
        ``coef = 0`` are left out.
    times : ndarray, shape (T,), optional
        Stamps in s from t = 0, all ≥ 0. Give this or ``uniform``.
    uniform : tuple (t_first, dt, n), optional
        Stamps ``t_first + k dt``, k = 0..n-1 (s).
    backend : {"auto", "numba", "numpy"}
        Route of a uniform grid's sum (:func:`term_sum_uniform`).

    Returns
    -------
    y : ndarray, shape (B, T)
    ok : ndarray of bool, shape (B,)
        False where a kept term's phase ``|Im λ| t`` exceeds 1e12 rad or where ``y`` is
        not finite.
    t : ndarray, shape (T,)
        The stamps (s).
    """
    if (times is None) == (uniform is None):
        raise ValueError("give exactly one of times and uniform")
    if uniform is not None:
        t_first, dt, n = uniform
        t = t_first + dt * np.arange(n)
    else:
        t = np.asarray(times, dtype=float)
    # A phase ω t beyond 1e12 rad carries a rounding of ≥ 2e-4 rad (absurd parameters,
    # e.g. E = 1e300): such sets go to the full path, which flags them when they overflow.
    phase = np.abs(np.where(coef != 0, lam.imag, 0.0)).max(axis=1, initial=0.0)
    ok = phase * float(np.max(t, initial=0.0)) <= _MAX_PHASE
    positive = t[t > 0]
    use = _pick_backend(backend)
    # Only the numpy route of a uniform grid needs the terms ordered by lifetime.
    lam, coef, life, at_zero = _compact(
        lam, coef, float(positive.min()) if positive.size else 0.0,
        order=uniform is None or use == "numpy")
    if uniform is not None:
        y = term_sum_uniform(lam, coef, t_first, dt, n, life, use)
    else:
        y = term_sum_times(lam, coef, t)
    y[:, t == 0] += at_zero[:, None]
    ok &= _finite_rows(y)
    return y, ok, t
