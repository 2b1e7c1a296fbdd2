"""Cubic-Hermite Euler–Bernoulli finite elements for a cantilever (physics.md §1, §3).

:func:`assemble` turns a :class:`~bayesbeam.physics.beam.Beam` into an :class:`FEModel`
holding the Galerkin matrices of the weak form in physics.md §1:

* ``M``  = ∫ rhoA(x) φ_i φ_j dx + m_t φ_i(L) φ_j(L) + J_t φ_i'(L) φ_j'(L)   (kg);
* ``K``  = ∫ e(x) I(x) φ_i'' φ_j'' dx, **per unit E**: ``E * K`` is the bending
  stiffness (N/m), ``e(x)`` the dimensionless spanwise E factor of the beam;
* ``K_grad`` = ∫ (x/L - 1/2) e(x) I(x) φ_i'' φ_j'' dx, so that an extra linear
  stiffness gradient ``g`` (the ``stiffness_gradient`` parameter) gives
  ``E * (K + g * K_grad)`` exactly;
* ``K_root`` = φ_i'(0) φ_j'(0), the unit rotational root spring (times k_θ in N m/rad);
* ``G``  = ∫ φ_i φ_j dx (viscous damping ``gamma * G``);
* ``KV`` = ∫ I(x) φ_i'' φ_j'' dx (Kelvin–Voigt damping ``c_d * KV``; the KV moment
  is ``c_d I w_xxt`` and carries no E factor, physics.md §1).

The root spring of the beam is **not** added to ``K``: K is per unit E and the
clamp stiffness may be a parameter, so callers form
``K_total = E * (K + g * K_grad) + k_theta * K_root`` themselves.

Degrees of freedom: nodes 1..N each carry (w, θ) in that order; with a root
rotation dof (root spring) θ_0 comes first, so ``n = 2N`` or ``2N + 1``. The
root displacement is always clamped.

Element edges lie on :attr:`Beam.breakpoints`, so every property factor is
linear (gradient) or constant inside each element and a 5-point Gauss–Legendre
rule (exact to degree 9) integrates every matrix exactly: the highest integrand
degree is 7 (linear rhoA times two cubics in ``M``).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.linalg as sla

from bayesbeam.physics.beam import Beam

__all__ = ["FEMError", "FEModel", "assemble", "first_mode_integrals", "mesh_nodes",
           "release_gain", "spring_eigenvalue", "static_tip_shape"]

# Gauss–Legendre rule on [0, 1]: 5 points integrate polynomials up to degree 9
# exactly; the integrands here reach degree 7 (linear factor x cubic x cubic) in M
# and degree 4 (two linear factors x linear x linear) or 5 (with the gradient
# weight) in K and K_grad.
_GL_T, _GL_W = np.polynomial.legendre.leggauss(5)
_GAUSS_XI = 0.5 * (_GL_T + 1.0)
_GAUSS_W = 0.5 * _GL_W


class FEMError(ValueError):
    """Invalid input to the finite element model; the message says what and how to fix it."""


def _check_beam(beam: object) -> Beam:
    if not isinstance(beam, Beam):
        raise FEMError(f"beam must be a bayesbeam.physics.beam.Beam, got {type(beam).__name__}")
    return beam


def _check_n_elements(n_elements: object) -> int:
    if isinstance(n_elements, bool) or not isinstance(n_elements, numbers.Integral):
        raise FEMError(
            f"n_elements must be a positive integer (number of finite elements), got {n_elements!r}"
        )
    n = int(n_elements)
    if n < 1:
        raise FEMError(f"n_elements must be a positive integer, got {n}")
    return n


def mesh_nodes(beam: Beam, n_elements: int) -> np.ndarray:
    """Node positions with element edges on the beam's breakpoints.

    The span is cut into pieces at :attr:`Beam.breakpoints` (segment edges);
    each piece gets at least one element and the rest are handed out one at a
    time to the piece whose elements are currently longest, which distributes
    them roughly in proportion to the piece lengths (a uniform beam gets a
    uniform mesh). Elements within a piece are equal.

    Parameters
    ----------
    beam : Beam
        The beam.
    n_elements : int
        Number of elements N, at least the number of pieces
        ``len(beam.breakpoints) + 1``.

    Returns
    -------
    ndarray, shape (N + 1,)
        Strictly increasing node positions in m, from 0 to L.

    Raises
    ------
    FEMError
        If ``n_elements`` is not a positive integer or is smaller than the
        number of pieces.
    """
    beam = _check_beam(beam)
    n = _check_n_elements(n_elements)
    L = float(beam.length)
    edges = np.concatenate(([0.0], np.asarray(beam.breakpoints, dtype=float), [L]))
    lengths = np.diff(edges)
    n_pieces = lengths.size
    if n < n_pieces:
        raise FEMError(
            f"n_elements={n} is too small: the beam has {n_pieces} pieces between segment "
            f"edges and each needs at least one element; use n_elements >= {n_pieces}"
        )
    counts = np.ones(n_pieces, dtype=int)
    for _ in range(n - n_pieces):
        # Greedy: refine the piece with the longest elements (first one on ties),
        # which keeps the largest element as small as possible.
        counts[int(np.argmax(lengths / counts))] += 1
    parts = [np.linspace(edges[k], edges[k + 1], counts[k] + 1)[:-1] for k in range(n_pieces)]
    nodes = np.concatenate(parts + [np.array([L])])
    return nodes


def _hermite(xi: np.ndarray, h: np.ndarray, derivative: int) -> np.ndarray:
    """Cubic Hermite shape functions (w_a, θ_a, w_b, θ_b) of an element of length h.

    Parameters
    ----------
    xi : ndarray, shape (...,)
        Local coordinate in [0, 1].
    h : ndarray, broadcastable to ``xi``
        Element length in m.
    derivative : {0, 1, 2}
        Order of the x derivative.

    Returns
    -------
    ndarray, shape (..., 4)
        Values (derivative 0: dimensionless for w dofs, m for θ dofs), first
        derivatives (1/m, dimensionless) or second derivatives (1/m², 1/m).
    """
    xi, h = np.broadcast_arrays(np.asarray(xi, dtype=float), np.asarray(h, dtype=float))
    if derivative == 0:
        cols = (
            1.0 - 3.0 * xi**2 + 2.0 * xi**3,
            h * (xi - 2.0 * xi**2 + xi**3),
            3.0 * xi**2 - 2.0 * xi**3,
            h * (xi**3 - xi**2),
        )
    elif derivative == 1:
        cols = (
            (-6.0 * xi + 6.0 * xi**2) / h,
            1.0 - 4.0 * xi + 3.0 * xi**2,
            (6.0 * xi - 6.0 * xi**2) / h,
            3.0 * xi**2 - 2.0 * xi,
        )
    else:
        cols = (
            (-6.0 + 12.0 * xi) / h**2,
            (-4.0 + 6.0 * xi) / h,
            (6.0 - 12.0 * xi) / h**2,
            (-2.0 + 6.0 * xi) / h,
        )
    return np.stack(cols, axis=-1)


def _free_dofs(n_nodes: int, root_dof: bool) -> np.ndarray:
    # Full numbering: node k has w at 2k and θ at 2k + 1. The clamp removes w_0
    # always and θ_0 unless a root spring keeps it; θ_0 is then first, as the
    # contract asks.
    first = 1 if root_dof else 2
    return np.arange(first, 2 * n_nodes)


@dataclass(frozen=True, eq=False)
class FEModel:
    """Finite element matrices of a cantilever (read-only arrays, SI units).

    Attributes
    ----------
    nodes : ndarray, shape (N + 1,)
        Node positions in m (0 to L).
    root_dof : bool
        True: the root rotation θ_0 is a dof (root spring, added by the caller
        as ``k_theta * K_root``); False: rigid clamp.
    M : ndarray, shape (n, n)
        Mass matrix, including the beam's tip mass and rotary inertia and its
        declared point masses (``Beam.masses``) (kg, kg m, kg m² for w–w, w–θ, θ–θ
        entries).
    M_tip : ndarray, shape (n, n)
        Unit tip-mass matrix φ_i(L) φ_j(L) (per kg of tip mass).
    K : ndarray, shape (n, n)
        Stiffness per unit E, ∫ e(x) I(x) φ_i'' φ_j'' dx (m⁴ times the shape
        function units; ``E * K`` is in N/m, N, N m for w–w, w–θ, θ–θ). The
        root spring is NOT included.
    K_grad : ndarray, shape (n, n)
        ∫ (x/L - 1/2) e(x) I(x) φ_i'' φ_j'' dx (units of K); stiffness with an extra
        linear gradient g is ``E * (K + g * K_grad)``.
    K_root : ndarray, shape (n, n)
        Unit rotational root spring φ_i'(0) φ_j'(0) (times k_theta in
        N m/rad); zero if not
        ``root_dof``.
    G : ndarray, shape (n, n)
        ∫ φ_i φ_j dx (m, m², m³ for w–w, w–θ, θ–θ); viscous damping matrix is ``gamma * G``.
    KV : ndarray, shape (n, n)
        ∫ I(x) φ_i'' φ_j'' dx (units of K); Kelvin–Voigt damping is ``c_d * KV``.
    tip : ndarray, shape (n,)
        Displacement interpolation row at x = L, ``shape([L])[0]``.

    Notes
    -----
    Two private per-element arrays (shape (N, 2, 2), m³; times E in N m/rad) hold
    the natural (deformation-mode) stiffness of each element, used by
    :func:`static_tip_shape` to solve the statically determinate tip-load
    problem without the ill-conditioned global K.
    """

    nodes: np.ndarray
    root_dof: bool
    M: np.ndarray
    M_tip: np.ndarray
    K: np.ndarray
    K_grad: np.ndarray
    K_root: np.ndarray
    G: np.ndarray
    KV: np.ndarray
    tip: np.ndarray
    _k_nat: np.ndarray | None = field(default=None, repr=False)
    _k_nat_grad: np.ndarray | None = field(default=None, repr=False)

    @property
    def length(self) -> float:
        """Beam length L in m."""
        return float(self.nodes[-1])

    @property
    def n_elements(self) -> int:
        """Number of elements N."""
        return int(self.nodes.size - 1)

    @property
    def n_dof(self) -> int:
        """Number of dofs n (2N, or 2N + 1 with a root rotation dof)."""
        return int(self.M.shape[0])

    def shape(self, x: np.ndarray | float, derivative: int = 0) -> np.ndarray:
        """Interpolation rows: field (or its derivative) at ``x`` = row @ dofs.

        Parameters
        ----------
        x : float or array_like, shape (p,)
            Positions in m, within [0, L]. At an interior node the element to
            the right is used (this only matters for ``derivative=2``, which
            jumps there; w and w' are continuous).
        derivative : {0, 1, 2}
            0: displacement rows N(x) (dimensionless / m per dof, the sensor
            vector); 1: slope rows N'(x) (1/m, dimensionless); 2: curvature rows
            N''(x) (1/m², 1/m).

        Returns
        -------
        ndarray, shape (p, n)
            One row per position (p = 1 for a scalar ``x``).

        Raises
        ------
        FEMError
            If ``x`` is not finite or lies outside [0, L], or ``derivative`` is
            not 0, 1 or 2.
        """
        if isinstance(derivative, bool) or derivative not in (0, 1, 2):
            raise FEMError(f"derivative must be 0, 1 or 2, got {derivative!r}")
        xa = np.atleast_1d(np.asarray(x, dtype=float))
        if xa.ndim != 1:
            raise FEMError(f"x must be a scalar or a 1-D array of positions, got shape {xa.shape}")
        L = self.length
        tol = 1e-12 * L
        if not np.all(np.isfinite(xa)) or np.any(xa < -tol) or np.any(xa > L + tol):
            raise FEMError(f"positions x must lie in [0, L] = [0, {L}] m, got {xa!r}")
        xa = np.clip(xa, 0.0, L)
        nodes = self.nodes
        ne = nodes.size - 1
        elem = np.clip(np.searchsorted(nodes, xa, side="right") - 1, 0, ne - 1)
        h = nodes[elem + 1] - nodes[elem]
        xi = (xa - nodes[elem]) / h
        local = _hermite(xi, h, derivative)  # (p, 4)
        full = np.zeros((xa.size, 2 * (ne + 1)))
        rows = np.arange(xa.size)[:, None]
        full[rows, 2 * elem[:, None] + np.arange(4)] = local
        return full[:, _free_dofs(ne + 1, self.root_dof)]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    a.setflags(write=False)
    return a


def assemble(beam: Beam, n_elements: int = 16, *, root_dof: bool | None = None) -> FEModel:
    """Assemble the cubic-Hermite finite element matrices of a cantilever.

    Matrices follow physics.md §1 with the §3 extensions: spanwise E(x), I(x),
    rhoA(x) from :meth:`Beam.factors`, tip mass and rotary inertia added into
    ``M``, and an optional root rotation dof.

    The beam's ``root_spring`` is NOT added to ``K`` (K is per unit E and the
    clamp stiffness may be a fitted parameter): the total stiffness is
    ``E * (K + g * K_grad) + k_theta * K_root``.

    Parameters
    ----------
    beam : Beam
        The beam (reference I in m⁴, rhoA in kg/m, factors, tip mass, clamp).
    n_elements : int, optional
        Number of elements N (default 16); element edges are placed on the
        segment edges, see :func:`mesh_nodes`.
    root_dof : bool or None, optional
        Keep the root rotation as a dof. Default: ``beam.root_spring is not
        None``.

    Returns
    -------
    FEModel
        Matrices of size n = 2N (or 2N + 1 with ``root_dof``).

    Raises
    ------
    FEMError
        For a non-Beam ``beam``, a bad ``n_elements`` or a non-bool ``root_dof``.
    """
    beam = _check_beam(beam)
    if root_dof is None:
        root_dof = beam.root_spring is not None
    elif not isinstance(root_dof, (bool, np.bool_)):
        raise FEMError(f"root_dof must be True, False or None, got {root_dof!r}")
    root_dof = bool(root_dof)
    nodes = mesh_nodes(beam, n_elements)
    L = float(beam.length)
    ne = nodes.size - 1
    a = nodes[:-1]
    h = np.diff(nodes)  # (ne,)

    # Gauss points inside every element (never on an edge, so Beam.factors sees
    # the element's own segment).
    x = a[:, None] + h[:, None] * _GAUSS_XI[None, :]  # (ne, q)
    wq = h[:, None] * _GAUSS_W[None, :]  # (ne, q) weights in m
    f = beam.factors(x.ravel())
    f_e, f_i, f_r = (f[k].reshape(x.shape) for k in ("E", "I", "rhoA"))
    rhoA = beam.rhoA * f_r  # kg/m
    I_x = beam.I * f_i  # m^4
    eI = f_e * I_x  # EI per unit E, m^4
    s = x / L - 0.5  # gradient weight (Beam's Gradient convention)

    N0 = _hermite(_GAUSS_XI[None, :], h[:, None], 0)  # (ne, q, 4)
    N2 = _hermite(_GAUSS_XI[None, :], h[:, None], 2)

    def integrate(weight: np.ndarray, P: np.ndarray) -> np.ndarray:
        return np.einsum("eq,eqi,eqj->eij", weight, P, P)

    # Natural stiffness: curvature N''·u_e = N2'' d1 + N4'' d2 with the chord
    # rotations d1 = θ_a - (w_b - w_a)/h, d2 = θ_b - (w_b - w_a)/h, so
    # K_e = Bᵀ k B with k = ∫ e I [N2'', N4'']ᵀ [N2'', N4''] (2x2, well conditioned).
    k_nat = integrate(wq * eI, N2[..., [1, 3]])
    k_nat_grad = integrate(wq * s * eI, N2[..., [1, 3]])
    elem = {
        "M": integrate(wq * rhoA, N0),
        "G": integrate(wq, N0),
        "K": integrate(wq * eI, N2),
        "K_grad": integrate(wq * s * eI, N2),
        "KV": integrate(wq * I_x, N2),
    }
    n_full = 2 * (ne + 1)
    idx = 2 * np.arange(ne)[:, None] + np.arange(4)[None, :]  # (ne, 4)
    free = _free_dofs(ne + 1, root_dof)
    mats: dict[str, np.ndarray] = {}
    for name, Ke in elem.items():
        full = np.zeros((n_full, n_full))
        np.add.at(full, (idx[:, :, None], idx[:, None, :]), Ke)
        full = full[np.ix_(free, free)]
        # Symmetric by construction; symmetrise to remove summation-order roundoff.
        mats[name] = 0.5 * (full + full.T)

    n = free.size
    tip_w = np.zeros(n)
    tip_w[-2] = 1.0  # w_N
    tip_t = np.zeros(n)
    tip_t[-1] = 1.0  # θ_N
    M_tip = np.outer(tip_w, tip_w)
    M = mats["M"] + beam.tip_mass * M_tip + beam.tip_inertia * np.outer(tip_t, tip_t)
    K_root = np.zeros((n, n))
    if root_dof:
        K_root[0, 0] = 1.0  # θ_0 is dof 0 and φ_0'(0) = 1
    fe = FEModel(
        nodes=_readonly(nodes),
        root_dof=root_dof,
        M=_readonly(M),
        M_tip=_readonly(M_tip),
        K=_readonly(mats["K"]),
        K_grad=_readonly(mats["K_grad"]),
        K_root=_readonly(K_root),
        G=_readonly(mats["G"]),
        KV=_readonly(mats["KV"]),
        tip=_readonly(tip_w),
        _k_nat=_readonly(k_nat),
        _k_nat_grad=_readonly(k_nat_grad),
    )
    if not beam.masses:
        return fe
    # Declared attachments: a point mass m at x adds m N(x)ᵀ N(x) (its kinetic energy
    # ½ m w_t(x)², exact for the Hermite field at any x, on a node or inside an element).
    rows = fe.shape(np.array([pm.position for pm in beam.masses]))
    mass = np.array([pm.mass for pm in beam.masses])
    M = M + np.einsum("k,ki,kj->ij", mass, rows, rows)
    return replace(fe, M=_readonly(0.5 * (M + M.T)))


def static_tip_shape(
    fe: FEModel, E: float, k_root: float = 0.0, *, gradient: float = 0.0
) -> np.ndarray:
    """Return the static deflection under a unit tip load, ``K_total⁻¹ · tip``.

    Used for release from a static tip deflection: scale the result by
    ``w0 / (fe.tip @ u)`` to start from tip deflection ``w0``.

    A cantilever is statically determinate, so instead of factorising the
    ill-conditioned global stiffness (condition number ~N⁴; a Cholesky solve
    loses ~1e-11 relative at 16-32 elements) the solution is built exactly in
    the same finite element space: statics gives each element's end moments
    (bending moment P (L - x) at its ends), the 2x2 natural element stiffness
    gives its chord rotations, and compatibility accumulates w and θ from the
    root. This is algebraically identical to ``K_total⁻¹ · tip`` and accurate to
    a few ulp.

    Parameters
    ----------
    fe : FEModel
        The finite element model.
    E : float
        Young's modulus in Pa (> 0).
    k_root : float, optional
        Rotational root spring stiffness k_theta in N m/rad. Must be > 0 when
        ``fe.root_dof`` (otherwise the beam is a mechanism) and 0 when not.
    gradient : float, optional
        Extra linear stiffness gradient g in (-2, 2): ``K_total = E (K + g K_grad)
        + k_root K_root``.

    Returns
    -------
    ndarray, shape (n,)
        Dof vector in m/N (displacements) and rad/N (rotations); its tip
        deflection is ``fe.tip @ u`` (= L³/(3EI) for a uniform clamped beam).

    Raises
    ------
    FEMError
        For a non-positive E, a root spring that does not match ``fe.root_dof``
        or a gradient outside (-2, 2).
    """
    if not isinstance(fe, FEModel) or fe._k_nat is None or fe._k_nat_grad is None:
        raise FEMError("fe must be an FEModel made by bayesbeam.physics.fem.assemble")
    E = _finite_float("E", E)
    k_root = _finite_float("k_root", k_root)
    gradient = _finite_float("gradient", gradient)
    if E <= 0:
        raise FEMError(f"E must be a positive Young's modulus in Pa, got {E!r}")
    if k_root < 0:
        raise FEMError(f"k_root must be a non-negative stiffness in N m/rad, got {k_root!r}")
    if fe.root_dof and k_root == 0:
        raise FEMError(
            "the model has a root rotation dof but k_root = 0: the beam would swing freely; "
            "give the root spring stiffness k_root > 0 (N m/rad)"
        )
    if not fe.root_dof and k_root != 0:
        raise FEMError(
            "k_root was given but the model is rigidly clamped (root_dof=False); "
            "assemble with root_dof=True to include a root spring"
        )
    if not -2.0 < gradient < 2.0:
        raise FEMError(f"gradient must lie in (-2, 2), got {gradient!r}")
    nodes = fe.nodes
    L = fe.length
    h = np.diff(nodes)
    k = E * (fe._k_nat + gradient * fe._k_nat_grad)  # (N, 2, 2), N m/rad
    # Element end moments for a unit tip load (equilibrium of B_eᵀ s_e with the
    # chord-rotation B of assemble): s = (-(L - x_a), L - x_b), in N m per N.
    s_end = np.stack((-(L - nodes[:-1]), L - nodes[1:]), axis=-1)
    d = np.linalg.solve(k, s_end[..., None])[..., 0]  # chord rotations, rad per N
    ne = h.size
    w = np.zeros(ne + 1)
    theta = np.zeros(ne + 1)
    # Root: k_theta θ_0 balances the root moment L (per unit load).
    theta[0] = L / k_root if fe.root_dof else 0.0
    for e in range(ne):
        chord = theta[e] - d[e, 0]
        w[e + 1] = w[e] + h[e] * chord
        theta[e + 1] = chord + d[e, 1]
    full = np.empty(2 * (ne + 1))
    full[0::2] = w
    full[1::2] = theta
    return full[_free_dofs(ne + 1, fe.root_dof)]


def spring_eigenvalue(fe: FEModel, ratio: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First eigenvalue per unit E with a root spring, and its elasticity in the spring.

    With stiffness ``E K + k K_root`` (K per unit E, ``K_root`` the unit root spring),
    ``ω1² = E μ(k/E)``, where ``μ(r)`` is the lowest eigenvalue of ``(K + r K_root, M)``:
    the first natural frequency depends on E and the clamp stiffness k only through E
    and their ratio, whatever the beam's spanwise properties and attached masses. Its
    elasticity ``e(r) = d log μ / d log r = r φ'(0)² / μ`` (φ the mass-normalised first
    mode; Hellmann–Feynman) lies in (0, 1): μ is concave and increasing in r (a minimum
    of Rayleigh quotients linear in r) with ``μ(0) >= 0``. ``e → 1`` as the clamp
    softens (a rigid beam rotating on its spring, ω1² = 3k/(rhoA L³) for a uniform
    beam) and ``e → 0`` as it stiffens (the rigid clamp).

    Parameters
    ----------
    fe : FEModel
        Assembled with ``root_dof=True``.
    ratio : array_like, shape (p,)
        ``r = k/E`` in m³/rad (N m/rad over Pa), positive.

    Returns
    -------
    mu : ndarray, shape (p,)
        ``ω1²/E`` in rad²/(s² Pa).
    elasticity : ndarray, shape (p,)
        ``d log μ / d log r``, dimensionless.

    Raises
    ------
    FEMError
        Without a root rotation dof, or for a ratio that is not positive and finite.
    """
    r = _spring_ratios(fe, ratio, "spring_eigenvalue")
    mu = np.empty(r.size)
    slope = np.empty(r.size)
    for i, ri in enumerate(r):
        mu[i], phi = _first_mode(fe, ri)
        slope[i] = phi @ fe.K_root @ phi  # eigh: φᵀ M φ = 1
    return mu, r * slope / mu


def first_mode_integrals(
    fe: FEModel, ratio: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First eigenvalue per unit E and the first mode's viscous and Kelvin–Voigt integrals.

    With φ1 the mass-normalised first mode of ``(K + r K_root, M)`` (stiffness
    ``E K + k K_root``, ``r = k/E``), the first mode's damping ratio under the damping
    matrix ``gamma G + c_d KV`` is, to first order in the damping (the diagonal term of
    the modal damping matrix; physics.md §2),

        ζ1 = (gamma g + c_d κ) / (2 ω1),   g = φ1ᵀ G φ1,   κ = φ1ᵀ KV φ1,   ω1² = E μ,

    exact for any spanwise E, I, rhoA and attached masses: ``g = 1/rhoA`` only for a
    uniform beam without masses (a mass, or a lighter segment, takes part of the modal
    mass and changes the viscous share), and ``κ = μ (1 - e)`` only for a uniform E
    (:func:`spring_eigenvalue`'s elasticity e: the spring's share of the strain energy,
    which the Kelvin–Voigt law does not damp).

    Parameters
    ----------
    fe : FEModel
    ratio : array_like, shape (p,), optional
        ``r = k/E`` in m³/rad, positive, for a model with the root rotation dof; None
        for one without (a rigid clamp: ``K`` alone).

    Returns
    -------
    mu : ndarray, shape (p,) (or (1,) for ``ratio=None``)
        ``ω1²/E`` in rad²/(s² Pa).
    g : ndarray, same shape
        ``φ1ᵀ G φ1`` in m/kg.
    kappa : ndarray, same shape
        ``φ1ᵀ KV φ1`` in rad²/(s² Pa) (``KV`` has the units of ``K`` per unit E).

    Raises
    ------
    FEMError
        For ``ratio=None`` with a root rotation dof (the beam would be free to rotate),
        or as :func:`spring_eigenvalue`.
    """
    if ratio is None:
        if fe.root_dof:
            raise FEMError("first_mode_integrals needs the spring-to-E ratio of a model with "
                           "the root rotation dof (ratio=None is the rigid clamp)")
        r = np.array([np.nan])
    else:
        r = _spring_ratios(fe, ratio, "first_mode_integrals")
    out = np.empty((3, r.size))
    for i, ri in enumerate(r):
        mu, phi = _first_mode(fe, None if ratio is None else ri)
        out[:, i] = mu, phi @ fe.G @ phi, phi @ fe.KV @ phi
    return out[0], out[1], out[2]


def _first_mode(fe: FEModel, ratio: float | None) -> tuple[float, np.ndarray]:
    """Lowest eigenpair of ``(K + ratio K_root, M)`` (``K`` alone for None), φᵀ M φ = 1."""
    K = fe.K if ratio is None else fe.K + ratio * fe.K_root
    w, phi = sla.eigh(K, fe.M, subset_by_index=[0, 0])
    return float(w[0]), phi[:, 0]


def release_gain(fe: FEModel, ratio: np.ndarray, sensor_x: float) -> np.ndarray:
    """First mode's displacement at the sensor per unit tip deflection released.

    Released from the static shape under a tip load (unit tip deflection, ``ŝ``), the
    first mode starts with ``q1 = φ1ᵀ M ŝ`` and shows ``φ1(x_s) q1`` at the sensor (φ1
    mass-normalised; the product does not depend on its sign). With stiffness
    ``E K + k K_root`` both ``ŝ`` and φ1 depend on E and k only through ``r = k/E``.

    Parameters
    ----------
    fe : FEModel
        Assembled with ``root_dof=True``.
    ratio : array_like, shape (p,)
        ``r = k/E`` in m³/rad, positive.
    sensor_x : float
        Sensor position in m from the clamp.

    Returns
    -------
    ndarray, shape (p,)
        Dimensionless (m at the sensor per m at the tip).

    Raises
    ------
    FEMError
        As :func:`spring_eigenvalue`.
    """
    r = _spring_ratios(fe, ratio, "release_gain")
    row = fe.shape(np.array([sensor_x]))[0]
    out = np.empty(r.size)
    for i, ri in enumerate(r):
        _, phi = _first_mode(fe, ri)
        shape = static_tip_shape(fe, 1.0, ri)
        shape = shape / (fe.tip @ shape)
        out[i] = (row @ phi) * (phi @ fe.M @ shape)
    return out


def _spring_ratios(fe: FEModel, ratio: Any, caller: str) -> np.ndarray:
    """Return ``ratio`` as positive finite k/E values, shape (p,), for a model with θ_0."""
    if not fe.root_dof:
        raise FEMError(f"{caller} needs the root rotation dof: assemble(beam, n, "
                       "root_dof=True)")
    r = np.atleast_1d(np.asarray(ratio, dtype=float))
    if not (np.all(np.isfinite(r)) and np.all(r > 0)):
        raise FEMError(f"the spring-to-E ratio must be positive and finite, got {ratio!r}")
    return r


def _finite_float(name: str, value: object) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise FEMError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v):
        raise FEMError(f"{name} must be finite, got {value!r}")
    return v
