"""Spatial-hysteresis damping operator S(b) of the Banks–Inman model (physics.md §1–2).

For cubic-Hermite shape functions φ_i on a mesh of ``[0, L]`` the operator is

    S_ij(b) = ½ ∫∫_{[0,L]²} g_b(x − ξ) [φ_i'(x) − φ_i'(ξ)] [φ_j'(x) − φ_j'(ξ)] dξ dx,

with ``g_b`` the unit-area Gaussian of standard deviation ``b`` (m). The damping matrix of
the model is ``a S(b)`` (a in N s). S is symmetric positive semidefinite.

Why not a Gauss rule per element pair: the kernel is as narrow as 1e-5 L, and a rule that
does not resolve it is wrong by up to 98 % (physics.md §2). Instead, with u = x − ξ,

    S(b) = ∫_0^L 2 g_b(u) D(u) du,
    D_ij(u) = ½ ∫_0^{L−u} [ψ_i(ξ+u) − ψ_i(ξ)] [ψ_j(ξ+u) − ψ_j(ξ)] dξ,   ψ = φ'.

ψ is a continuous piecewise quadratic, so D is a piecewise polynomial of degree ≤ 5 in u
whose breakpoints are the node differences ``x_k − x_m``. Per mesh we sample D exactly
(Gauss–Legendre in ξ on cells split at the nodes of both ξ and ξ + u) at Chebyshev points
of every piece and store its Chebyshev coefficients. On the first piece D(u) = O(u²)
exactly; there we interpolate D / s² (s = u / width) so that the u⁰ and u¹ terms are zero
by construction. Otherwise their roundoff would be amplified by (h / b)² for narrow
kernels (S ≈ (b²/2) ∫ψ'ψ' there, physics.md §2).

Per b only the Gaussian moments of the basis on each piece are needed, then one
contraction with the stored coefficients. The moments come from composite Gauss–Legendre
panels no wider than b, split at the piece edges and cut at 12 b (the Gaussian is below
1e-31 of its peak there); two shortcuts give the same numbers to roundoff: a closed form
(half-normal moments) when only the first piece sees the kernel, and fixed nodes when b
exceeds every piece width. For a projection Φᵀ S Φ the coefficients are projected once per
Φ (cached), so a batch of b costs the moments plus one matrix product.

Units: S_ij carries the units of its dof pair, 1/m for (w, w), 1 for (w, θ), m for (θ, θ);
a S(b) is then a damping matrix in N s/m, N s and N m s.
"""

from __future__ import annotations

import math

import numpy as np

from bayesbeam._util import compiled_kernel
from bayesbeam.physics.hysteresis_kernel import _panel_moments_kernel_py

__all__ = ["HysteresisError", "HysteresisOperator"]


class HysteresisError(ValueError):
    """Invalid input to the hysteresis operator; the message says what and how to fix it."""


# --- quadrature constants -------------------------------------------------------------
# Degree of the piecewise polynomial D(u) (product of two quadratics integrated over an
# interval with limits linear in u) and the number of Chebyshev samples that fix it.
_DEG = 5
_NCOEF = _DEG + 1
_CHEB_T = np.cos(np.pi * (np.arange(_NCOEF) + 0.5) / _NCOEF)  # first-kind nodes, (6,)
# Interpolation matrix: Chebyshev coefficients c_k = sum_l _CHEB_A[k, l] f(tau_l).
_CHEB_A = (
    np.where(np.arange(_NCOEF)[:, None] == 0, 1.0, 2.0)
    / _NCOEF
    * np.cos(np.outer(np.arange(_NCOEF), np.arccos(_CHEB_T)))
)
# Gauss–Legendre in ξ: the integrand is a polynomial of degree 4 per cell, 3 points are exact.
_XI_X, _XI_W = np.polynomial.legendre.leggauss(3)
# Gauss–Legendre in u: 8 points on a panel of width <= b integrate a Gaussian times a
# degree-7 polynomial to roundoff (the 16th-derivative error term is ~1e-17 of the panel
# integral; the three moment paths agree to 1e-16, and the tests check S against brute
# force). Panels stop at _CUT * b: exp(-_CUT**2 / 2) = 5e-32.
_U_X, _U_W = np.polynomial.legendre.leggauss(8)
_U_X = 0.5 * (_U_X + 1.0)  # on [0, 1]
_U_W = 0.5 * _U_W
_PANEL = 1.0  # widest panel, in units of b
_CUT = 12.0  # truncation of the Gaussian, in units of b
# Breakpoints closer than this (relative to L) are merged: D is C^1, so a hidden breakpoint
# at distance d changes the fit by ~(d / h)^2 relative — negligible at 1e-11.
_MERGE_TOL = 1e-11
# Refuse meshes whose coefficient table would exceed this many bytes (see Notes of the class).
_MAX_BYTES = 1.0e9
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def _hermite_slopes(t: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Slopes dφ/dx of the four cubic-Hermite shape functions of an element.

    Parameters
    ----------
    t : ndarray
        Local coordinate (x − x_left) / h, any shape.
    h : ndarray
        Element length in m, broadcastable to ``t``.

    Returns
    -------
    ndarray
        Shape ``t.shape + (4,)``: slopes of the shape functions of (w_left, θ_left,
        w_right, θ_right); the w ones in 1/m, the θ ones dimensionless.
    """
    a = 6.0 * t * (t - 1.0) / h  # d/dx of 1 - 3t² + 2t³
    return np.stack([a, 1.0 + t * (3.0 * t - 4.0), -a, t * (3.0 * t - 2.0)], axis=-1)


class HysteresisOperator:
    """Spatial-hysteresis matrix S(b) on a cubic-Hermite mesh, cheap to evaluate per b.

    Precomputes, once per mesh, the piecewise-polynomial correlation D(u) of the shape-
    function slopes (module docstring), so that ``S(b)`` costs only Gaussian moments and
    one contraction.

    Parameters
    ----------
    nodes : array_like, shape (N+1,)
        Element edges in m, strictly increasing; ``nodes[0]`` is the clamp and
        ``nodes[-1] - nodes[0]`` the length L. Any (non-uniform) spacing is allowed.
    root_dof : bool, optional
        False (default): rigid clamp, both root dofs removed, n = 2N. True: the root
        rotation θ0 is kept as the first dof (root spring), n = 2N + 1. Dof order is that
        of ``bayesbeam.physics.fem``: (θ0,) then (w_k, θ_k) for nodes k = 1..N.

    Attributes
    ----------
    nodes : ndarray, shape (N+1,)
        The element edges (m).
    root_dof : bool
        Whether the root rotation dof is kept.
    n : int
        Number of dofs.
    length : float
        Beam length L in m.
    breakpoints : ndarray, shape (P+1,)
        Breakpoints of D(u) in m: 0, the distinct node differences, L.

    Notes
    -----
    Accuracy: better than 1e-12 relative (Frobenius) against an independent brute-force
    quadrature for b from 1e-5 L to 10 L (tests/test_hysteresis.py); any b > 0 is accepted.
    Memory: the table holds 6 n² numbers per piece; a uniform mesh has N pieces, a
    non-uniform one up to N(N+1)/2, so very fine non-uniform meshes are refused with
    :class:`HysteresisError`.

    Examples
    --------
    >>> op = HysteresisOperator(np.linspace(0.0, 0.3048, 17))
    >>> S = op.matrix(7e-4)          # (32, 32), multiply by a (N s) for the damping matrix
    """

    def __init__(self, nodes: np.ndarray, root_dof: bool = False) -> None:
        x = np.asarray(nodes, dtype=float)
        if x.ndim != 1 or x.size < 2:
            raise HysteresisError(
                f"nodes must be a 1-D array of at least 2 element edges (m), got shape {x.shape}"
            )
        if not np.all(np.isfinite(x)):
            raise HysteresisError("nodes must be finite numbers (element edges in m)")
        if np.any(np.diff(x) <= 0.0):
            raise HysteresisError(
                "nodes must be strictly increasing (element edges in m from the clamp); "
                "remove duplicate or unsorted entries"
            )
        if not isinstance(root_dof, (bool, np.bool_)):
            raise HysteresisError(f"root_dof must be True or False, got {root_dof!r}")
        self.nodes = x.copy()
        self.nodes.setflags(write=False)
        self.root_dof = bool(root_dof)
        self._x = x - x[0]  # S depends only on relative positions
        self.length = float(self._x[-1])
        n_el = x.size - 1
        self.n = 2 * n_el + (1 if self.root_dof else 0)

        # Global dof of (w_left, θ_left, w_right, θ_right) per element; removed clamp
        # dofs point at a dummy index n that is dropped after assembly.
        off = 1 if self.root_dof else 0
        node_w = np.concatenate([[self.n], 2 * np.arange(n_el) + off])
        node_t = np.concatenate([[0 if self.root_dof else self.n], 2 * np.arange(n_el) + 1 + off])
        self._dofs = np.stack([node_w[:-1], node_t[:-1], node_w[1:], node_t[1:]], axis=1)

        self.breakpoints = self._breakpoints()
        self.breakpoints.setflags(write=False)
        n_pieces = self.breakpoints.size - 1
        size = n_pieces * _NCOEF * self.n**2 * 8.0
        if size > _MAX_BYTES:
            raise HysteresisError(
                f"this mesh ({n_el} elements, {n_pieces} distinct node spacings) needs "
                f"{size / 1e9:.1f} GB of coefficients; use fewer elements or a mesh whose node "
                "differences repeat (uniform spacing within segments)"
            )
        self._coef = self._fit_coefficients()  # (P, 6, n, n)
        self._prepare_moments()
        self._coef_flat = self._coef.reshape(n_pieces * _NCOEF, self.n * self.n)
        self._proj_cache: list[tuple[np.ndarray, np.ndarray]] = []

    # -- precomputation -------------------------------------------------------------------
    def _breakpoints(self) -> np.ndarray:
        """Sorted distinct node differences 0 = β_0 < β_1 < ... < β_P = L (m)."""
        x = self._x
        d = np.sort((x[None, :] - x[:, None])[np.triu_indices(x.size, 1)])  # all > 0
        keep = np.concatenate([[True], np.diff(d) > _MERGE_TOL * self.length])
        beta = d[keep]
        beta[-1] = self.length  # the largest difference is L itself
        return np.concatenate([[0.0], beta])

    def _sample_d(self, u: np.ndarray) -> np.ndarray:
        """D(u) evaluated exactly (up to roundoff) at the lags ``u`` (m), shape (S, n, n)."""
        x, L, n = self._x, self.length, self.n
        n_el = x.size - 1
        h = np.diff(x)
        n_s = u.size
        # ξ-cells: split [0, L - u] at the nodes of ξ and of ξ + u; clipped duplicates give
        # empty cells with zero weight.
        br = np.concatenate([np.broadcast_to(x, (n_s, x.size)), x[None, :] - u[:, None]], axis=1)
        br = np.clip(br, 0.0, (L - u)[:, None])
        br.sort(axis=1)
        mid = 0.5 * (br[:, 1:] + br[:, :-1])  # (S, C)
        half = 0.5 * (br[:, 1:] - br[:, :-1])
        e1 = np.clip(np.searchsorted(x, mid, side="right") - 1, 0, n_el - 1)
        e2 = np.clip(np.searchsorted(x, mid + u[:, None], side="right") - 1, 0, n_el - 1)
        xi = mid[..., None] + half[..., None] * _XI_X  # (S, C, 3)
        wq = half[..., None] * _XI_W
        p1 = _hermite_slopes((xi - x[e1][..., None]) / h[e1][..., None], h[e1][..., None])
        p2 = _hermite_slopes(
            (xi + u[:, None, None] - x[e2][..., None]) / h[e2][..., None], h[e2][..., None]
        )
        v = np.concatenate([p2, -p1], axis=-1)  # (S, C, 3, 8): ψ(ξ+u) − ψ(ξ) by local dof
        loc = 0.5 * np.einsum("scq,scqa,scqb->scab", wq, v, v)  # (S, C, 8, 8)
        idx = np.concatenate([self._dofs[e2], self._dofs[e1]], axis=-1)  # (S, C, 8)
        m1 = n + 1
        flat = (
            np.arange(n_s)[:, None, None, None] * m1 * m1
            + idx[..., :, None] * m1
            + idx[..., None, :]
        )
        out = np.bincount(flat.ravel(), weights=loc.ravel(), minlength=n_s * m1 * m1)
        return out.reshape(n_s, m1, m1)[:, :n, :n]

    def _fit_coefficients(self) -> np.ndarray:
        """Chebyshev coefficients of D on every piece, shape (P, 6, n, n).

        Piece p ≥ 1: D(u) = Σ_k C[p, k] T_k(τ); piece 0: D(u) = s² Σ_k C[0, k] T_k(τ),
        with s = (u − β_p) / w_p ∈ [0, 1] and τ = 2 s − 1.
        """
        beta = self.breakpoints
        lo, w = beta[:-1], np.diff(beta)
        s = 0.5 * (_CHEB_T + 1.0)  # (6,) in (0, 1)
        n_pieces = lo.size
        # Sample in chunks to bound the temporary (S, 2N+1, 8, 8) arrays (~32 MB).
        per_sample = (2 * self._x.size) * 64 * 3 + (self.n + 1) ** 2
        chunk = max(1, int(4e6 // per_sample))
        u_all = (lo[:, None] + w[:, None] * s[None, :]).ravel()
        d = np.empty((u_all.size, self.n, self.n))
        for start in range(0, u_all.size, chunk):
            d[start : start + chunk] = self._sample_d(u_all[start : start + chunk])
        d = d.reshape(n_pieces, _NCOEF, self.n, self.n)
        # D(u) = O(u²) on the first piece: interpolate D / s² (a cubic), so that the u⁰ and
        # u¹ coefficients are exactly zero (module docstring).
        d[0] /= (s**2)[:, None, None]
        coef = np.einsum("kl,plij->pkij", _CHEB_A, d)
        return 0.5 * (coef + coef.transpose(0, 1, 3, 2))

    # -- per-b evaluation --------------------------------------------------------------
    def _prepare_moments(self) -> None:
        """Per-mesh constants of the three moment paths of :meth:`_moments`."""
        beta = self.breakpoints
        self._lo = beta[:-1]
        self._wp = np.diff(beta)
        # Narrow path (_CUT * b <= beta_1, only the first piece sees the kernel): with
        # p = b / w_0 and s = p r, the basis s² T_k(2s - 1) = sum_j a[k, j] s^j, so the
        # moment is sum_j a[k, j] p^j E|Z|^j (half-normal moments; the tail beyond 12 b is
        # below 1e-28 relative). Terms fall off with j since p <= 1/12, so this is stable.
        a = np.zeros((_NCOEF, _NCOEF + 2))
        for k in range(_NCOEF):
            c = np.polynomial.Chebyshev.basis(k, domain=[0.0, 1.0]).convert(
                kind=np.polynomial.Polynomial
            )
            a[k, 2 : 2 + c.coef.size] = c.coef
        j = np.arange(_NCOEF + 2)
        abs_moments = np.array([2.0 ** (i / 2) * math.gamma((i + 1) / 2) for i in j])
        self._narrow_e = (a * abs_moments / math.sqrt(math.pi)).T  # (8, 6)
        self._narrow_max = beta[1] / _CUT
        # Wide path (b >= every piece width: one panel per piece): fixed nodes and weights.
        self._wide_min = self._wp.max() / _PANEL
        s = np.broadcast_to(_U_X, (self._wp.size, _U_X.size)).copy()  # (P, 8)
        self._wide_u = self._lo[:, None] + self._wp[:, None] * s
        w = (2.0 * _INV_SQRT_2PI) * self._wp[:, None] * _U_W  # (P, 8)
        w[0] *= s[0] ** 2
        self._wide_w = w[..., None] * np.polynomial.chebyshev.chebvander(2.0 * s - 1.0, _DEG)

    def _moments(self, b: np.ndarray) -> tuple[np.ndarray, int]:
        """Gaussian moments of the piece bases, shape (B, P_act, 6), and P_act.

        ``m[k, p, j] = ∫_{piece p} 2 g_{b_k}(u) B_pj(u) du`` with the basis B_pj of
        :meth:`_fit_coefficients`; pieces starting beyond ``_CUT * max(b)`` are dropped
        (the Gaussian is below 1e-31 of its peak there). Three paths give the same
        numbers to roundoff: narrow kernels in closed form, wide kernels on fixed nodes,
        and the rest on composite Gauss–Legendre panels no wider than b, split at the
        piece edges.
        """
        n_pieces = self._wp.size
        b_min, b_max = float(b.min()), float(b.max())
        if b_max <= self._narrow_max:  # all narrow (the common single-b case too)
            return self._moments_narrow(b)[:, None, :], 1
        if b_min >= self._wide_min:
            return self._moments_wide(b), n_pieces
        if b.size == 1:
            n_act = self._n_active(b_max)
            return self._moments_panels(b, n_act), n_act
        narrow = b <= self._narrow_max
        wide = b >= self._wide_min
        n_act = n_pieces if np.any(wide) else self._n_active(b_max)
        m = np.zeros((b.size, n_act, _NCOEF))
        if np.any(narrow):
            m[narrow, 0] = self._moments_narrow(b[narrow])
        if np.any(wide):
            m[wide] = self._moments_wide(b[wide])
        rest = ~(narrow | wide)
        if np.any(rest):
            m[rest] = self._moments_panels(b[rest], n_act)
        return m, n_act

    def _n_active(self, b_max: float) -> int:
        """Count the pieces that start below the kernel cut-off ``_CUT * b_max``."""
        cut = min(self.length, _CUT * b_max)
        return max(1, min(int(np.searchsorted(self.breakpoints, cut)), self._wp.size))

    def _moments_narrow(self, b: np.ndarray) -> np.ndarray:
        """First-piece moments in closed form (valid for b <= beta_1 / _CUT), (B, 6)."""
        p = b / self._wp[0]
        return (p[:, None] ** np.arange(_NCOEF + 2)) @ self._narrow_e

    def _moments_wide(self, b: np.ndarray) -> np.ndarray:
        """Moments on fixed nodes, one panel per piece (valid for b >= every piece), (B, P, 6)."""
        r = self._wide_u / b[:, None, None]  # (B, P, 8)
        g = np.exp(-0.5 * r * r) / b[:, None, None]
        return np.matmul(g.transpose(1, 0, 2), self._wide_w).transpose(1, 0, 2)

    def _moments_panels(self, b: np.ndarray, n_act: int, backend: str = "auto") -> np.ndarray:
        """Moments by composite Gauss–Legendre (panels <= b, split at piece edges), (B, P, 6).

        ``backend``: "auto" runs the compiled kernel
        (:func:`~bayesbeam.physics.hysteresis_kernel._panel_moments_kernel_py`) where numba
        imports, else the batched numpy route below; "numpy" forces the latter. The two
        sum in different orders (1e-16 relative apart).
        """
        kernel = compiled_kernel(_panel_moments_kernel_py) if backend == "auto" else None
        if kernel is not None:
            return kernel(np.ascontiguousarray(b, dtype=float), self._lo, self._wp,
                          self.length, _CUT, _PANEL, _U_X, _U_W, n_act, _NCOEF)
        n_b = b.size
        lo = self._lo[:n_act]
        wpiece = self._wp[:n_act]
        # Per (batch item, piece): the covered span, its panel count and panel width.
        span = np.minimum(lo + wpiece, np.minimum(self.length, _CUT * b)[:, None]) - lo
        span = span.ravel()
        scale = np.repeat(b, n_act)
        counts = np.ceil(np.maximum(span, 0.0) / (_PANEL * scale)).astype(np.intp)
        w_r = np.tile(wpiece, n_b) / scale  # piece width in units of b
        frac = span / (np.maximum(counts, 1) * scale * w_r)  # panel width / piece width
        lo_r = np.tile(lo, n_b) / scale  # piece start in units of b
        # Expand to panels.
        pair = np.repeat(np.arange(n_b * n_act), counts)
        first = np.cumsum(counts) - counts
        j = np.arange(pair.size) - first[pair]
        s = frac[pair, None] * (j[:, None] + _U_X)  # (Q, 8) local coordinate in the piece
        r = lo_r[pair, None] + w_r[pair, None] * s
        wg = ((2.0 * _INV_SQRT_2PI) * frac * w_r)[pair, None] * _U_W * np.exp(-0.5 * r * r)
        # The first piece takes the basis s² T_k(τ) (its panels lead each batch item).
        if n_b == 1:
            wg[: counts[0]] *= s[: counts[0]] ** 2
        else:
            first_piece = pair % n_act == 0
            wg[first_piece] *= s[first_piece] ** 2
        tau = 2.0 * s - 1.0
        t = np.empty((_NCOEF,) + s.shape)
        t[0] = wg
        t[1] = wg * tau
        tau2 = 2.0 * tau
        for kk in range(2, _NCOEF):  # Chebyshev recurrence, weighted
            t[kk] = tau2 * t[kk - 1] - t[kk - 2]
        per_panel = t.sum(axis=2)  # (6, Q)
        nz = np.flatnonzero(counts)
        m = np.zeros((n_b * n_act, _NCOEF))
        m[nz] = np.add.reduceat(per_panel, first[nz], axis=1).T
        return m.reshape(n_b, n_act, _NCOEF)

    @staticmethod
    def _check_b(b: np.ndarray | float) -> np.ndarray:
        arr = np.asarray(b, dtype=float)
        if arr.ndim > 1:
            raise HysteresisError(f"b must be a scalar or a 1-D array (m), got shape {arr.shape}")
        arr = np.atleast_1d(arr)
        if arr.size == 0:
            raise HysteresisError("b is empty; pass at least one kernel width (m)")
        bad = ~(np.isfinite(arr) & (arr > 0.0))
        if np.any(bad):
            raise HysteresisError(
                f"kernel width b must be finite and positive (m), got {arr[bad][:3]}"
            )
        return arr

    def matrices(self, b: np.ndarray) -> np.ndarray:
        """S(b_k) for a batch of kernel widths.

        Parameters
        ----------
        b : array_like, shape (B,)
            Kernel standard deviations in m, each > 0.

        Returns
        -------
        ndarray, shape (B, n, n)
            Symmetric PSD matrices S(b_k) (units per dof pair, see the module
            docstring; multiply by a, in N s, for the damping matrix).
        """
        bb = self._check_b(b)
        m, n_act = self._moments(bb)
        out = m.reshape(bb.size, -1) @ self._coef_flat[: n_act * _NCOEF]
        out = out.reshape(bb.size, self.n, self.n)
        return 0.5 * (out + out.transpose(0, 2, 1))

    def matrix(self, b: float) -> np.ndarray:
        """S(b) of physics.md §1.

        Parameters
        ----------
        b : float
            Kernel standard deviation in m, > 0.

        Returns
        -------
        ndarray, shape (n, n)
            Symmetric positive semidefinite S(b) (units per dof pair, module docstring).
        """
        bb = np.asarray(b, dtype=float)
        if bb.ndim != 0:
            raise HysteresisError(
                f"matrix() takes a scalar b (m); use matrices() for arrays, got shape {bb.shape}"
            )
        return self.matrices(bb.reshape(1))[0]

    def _projected_coef(self, phi: np.ndarray) -> np.ndarray:
        """Φᵀ C[p, k] Φ for every coefficient, shape (P*6, m*m); cached by content of Φ."""
        for cached_phi, pc in self._proj_cache:
            if cached_phi.shape == phi.shape and np.array_equal(cached_phi, phi):
                return pc
        c = self._coef.reshape(-1, self.n, self.n)
        pc = np.matmul(phi.T, np.matmul(c, phi))  # (P*6, m, m)
        pc = 0.5 * (pc + pc.transpose(0, 2, 1))
        pc = pc.reshape(c.shape[0], -1)
        self._proj_cache.insert(0, (phi.copy(), pc))
        del self._proj_cache[4:]  # a few mode sets at most (e.g. one per model)
        return pc

    def projected(self, b: np.ndarray, Phi: np.ndarray) -> np.ndarray:  # noqa: N803
        """Modal projections Φᵀ S(b_k) Φ for a batch of kernel widths.

        Parameters
        ----------
        b : array_like, shape (B,)
            Kernel standard deviations in m, each > 0.
        Phi : ndarray, shape (n, m) or (B, n, m)
            Mode shapes (columns). With one Φ for the whole batch its projected
            coefficients are computed once and cached (by content, last 4 Φ), so each b
            costs only the Gaussian moments and one product; a per-item Φ of shape
            (B, n, m) is also accepted (then S(b_k) is formed and projected).

        Returns
        -------
        ndarray, shape (B, m, m)
            Symmetric PSD matrices Φᵀ S(b_k) Φ.
        """
        bb = self._check_b(b)
        phi = np.asarray(Phi, dtype=float)
        if phi.ndim not in (2, 3) or phi.shape[-2] != self.n:
            raise HysteresisError(
                f"Phi must have shape (n, m) or (B, n, m) with n = {self.n} dofs, got {phi.shape}"
            )
        if phi.ndim == 3:
            if phi.shape[0] != bb.size:
                raise HysteresisError(
                    f"Phi has {phi.shape[0]} items but b has {bb.size}; they must match"
                )
            s = self.matrices(bb)
            out = np.matmul(phi.transpose(0, 2, 1), np.matmul(s, phi))
            return 0.5 * (out + out.transpose(0, 2, 1))
        pc = self._projected_coef(phi)
        m, n_act = self._moments(bb)
        out = m.reshape(bb.size, -1) @ pc[: n_act * _NCOEF]
        k = phi.shape[1]
        out = out.reshape(bb.size, k, k)
        return 0.5 * (out + out.transpose(0, 2, 1))
