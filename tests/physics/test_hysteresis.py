"""Tests of the spatial-hysteresis operator S(b) (physics.md §1–2, issue 2 item 4).

Every reference here is computed independently of bayesbeam.physics.hysteresis: the Hermite shape
functions are rebuilt by solving their interpolation conditions, and S(b) is integrated by
brute force from its definition (fine panels that resolve the kernel, no polynomial fit and
no Gaussian moments).
"""

import math

import numpy as np
import pytest
from scipy import integrate, linalg

from bayesbeam.physics.hysteresis import HysteresisError, HysteresisOperator

L = 0.3048  # m, the source beams' free length
UNIFORM4 = np.linspace(0.0, L, 5)
NONUNIFORM4 = np.array([0.0, 0.041, 0.1063, 0.2207, L])  # no two node differences equal


# --- independent reference ----------------------------------------------------------------
def _hermite_coefficients(h):
    """Monomial coefficients (in s = x - x_left) of the 4 Hermite cubics, column per function.

    Solves N(0), N'(0), N(h), N'(h) = unit vectors: independent of any hand-written formula.
    """
    v = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [1, h, h**2, h**3], [0, 1, 2 * h, 3 * h**2]])
    return np.linalg.solve(v, np.eye(4))


def _slopes(nodes, root_dof, x):
    """Dense (len(x), n) matrix of ψ_i(x) = φ_i'(x) in the fem dof order."""
    n_el = nodes.size - 1
    off = 1 if root_dof else 0
    out = np.zeros((x.size, 2 * n_el + off))
    el_of = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, n_el - 1)
    for el in range(n_el):
        rows = np.flatnonzero(el_of == el)
        c = _hermite_coefficients(nodes[el + 1] - nodes[el])
        s = (x[rows] - nodes[el])[:, None]
        d = c[1] + 2 * c[2] * s + 3 * c[3] * s**2  # (rows, 4)
        dofs = []
        for node in (el, el + 1):
            if node == 0:
                dofs += [None, 0 if root_dof else None]
            else:
                dofs += [2 * (node - 1) + off, 2 * (node - 1) + 1 + off]
        for a, g in enumerate(dofs):
            if g is not None:
                out[rows, g] += d[:, a]
    return out


def _gauss(b, u):
    return np.exp(-0.5 * (u / b) ** 2) / (b * math.sqrt(2 * math.pi))


def _brute_force_u(nodes, root_dof, b):
    """S(b) = ∫_0^L 2 g_b(u) D(u) du by composite Gauss–Legendre in u (panels <= b/4 near 0,
    split at every node difference) with D(u) = ½∫ Δ Δᵀ dξ integrated exactly per ξ-cell
    (cells split at the nodes of ξ and ξ + u, 5-point Gauss for a degree-4 integrand)."""
    length = nodes[-1]
    diffs = (nodes[None, :] - nodes[:, None])[np.triu_indices(nodes.size, 1)]
    fine = np.arange(0.0, min(length, 40 * b), b / 4)  # g_b < 1e-300 beyond 40 b
    coarse = np.linspace(0.0, length, 65)  # resolves the kernel when b is wide
    edges = np.unique(np.concatenate([[0.0], diffs, fine, coarse]))
    edges = edges[edges <= min(length, 40 * b) + length / 64]
    gx, gw = np.polynomial.legendre.leggauss(12)
    a, w = edges[:-1], np.diff(edges)
    u = (a[:, None] + 0.5 * w[:, None] * (gx + 1)).ravel()
    wu = (0.5 * w[:, None] * gw).ravel() * 2 * _gauss(b, u)
    xx, xw = np.polynomial.legendre.leggauss(5)
    n = _slopes(nodes, root_dof, nodes[:1]).shape[1]
    s = np.zeros((n, n))
    for uk, wk in zip(u, wu, strict=True):
        br = np.unique(np.clip(np.concatenate([nodes, nodes - uk]), 0.0, length - uk))
        lo, wid = br[:-1], np.diff(br)
        xi = (lo[:, None] + 0.5 * wid[:, None] * (xx + 1)).ravel()
        wx = (0.5 * wid[:, None] * xw).ravel()
        # ψ(ξ+u) evaluated inside the same element as the cell midpoint maps to: the cells
        # never straddle a node, so the dense row evaluation is exact.
        delta = _slopes(nodes, root_dof, xi + uk) - _slopes(nodes, root_dof, xi)
        s += wk * 0.5 * (delta.T * wx) @ delta
    return s


def _brute_force_xy(nodes, root_dof, b, npts=12):
    """S(b) directly over (x, ξ): tensor Gauss–Legendre on panels split at the nodes and no
    wider than b/2, so the Gaussian is resolved; only usable for b >~ 0.01 L (cost ~ 1/b²)."""
    edges = [nodes[0]]
    for lo, hi in zip(nodes[:-1], nodes[1:], strict=True):
        k = max(1, math.ceil((hi - lo) / (0.5 * b)))
        edges.extend(np.linspace(lo, hi, k + 1)[1:])
    edges = np.array(edges)
    gx, gw = np.polynomial.legendre.leggauss(npts)
    a, w = edges[:-1], np.diff(edges)
    x = (a[:, None] + 0.5 * w[:, None] * (gx + 1)).ravel()
    wx = (0.5 * w[:, None] * gw).ravel()
    psi = _slopes(nodes, root_dof, x)  # (Q, n)
    n = psi.shape[1]
    s = np.zeros((n, n))
    for i0 in range(0, x.size, 256):
        sl = slice(i0, i0 + 256)
        kern = _gauss(b, x[sl, None] - x[None, :]) * wx[sl, None] * wx[None, :]  # (q, Q)
        delta = psi[sl, None, :] - psi[None, :, :]  # (q, Q, n)
        s += 0.5 * np.einsum("pq,pqi,pqj->ij", kern, delta, delta)
    return s


def _relerr(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def _uniform_cantilever(n_el):
    """Stiffness ∫φ_i''φ_j'' and mass ∫φ_iφ_j of a uniform clamped beam (unit E I, rhoA),
    from the solved Hermite coefficients and 6-point Gauss per element (exact)."""
    nodes = np.linspace(0.0, L, n_el + 1)
    n = 2 * n_el
    k = np.zeros((n + 2, n + 2))
    m = np.zeros((n + 2, n + 2))
    gx, gw = np.polynomial.legendre.leggauss(6)
    for el in range(n_el):
        h = nodes[el + 1] - nodes[el]
        c = _hermite_coefficients(h)
        s = 0.5 * h * (gx + 1)
        val = c[0] + c[1] * s[:, None] + c[2] * s[:, None] ** 2 + c[3] * s[:, None] ** 3
        curv = 2 * c[2] + 6 * c[3] * s[:, None]
        w = 0.5 * h * gw
        sl = slice(2 * el, 2 * el + 4)
        k[sl, sl] += (curv.T * w) @ curv
        m[sl, sl] += (val.T * w) @ val
    return nodes, k[2:, 2:], m[2:, 2:]


# --- tests ----------------------------------------------------------------------------
@pytest.mark.parametrize("root_dof", [False, True])
def test_symmetric_and_psd(root_dof):
    nodes = np.linspace(0.0, L, 17)
    op = HysteresisOperator(nodes, root_dof=root_dof)
    assert op.n == 32 + root_dof
    for b in L * np.array([1e-5, 1e-3, 0.03, 0.3, 3.0, 10.0]):
        s = op.matrix(b)
        assert s.shape == (op.n, op.n)
        np.testing.assert_array_equal(s, s.T)  # symmetrised exactly by construction
        ev = np.linalg.eigvalsh(s)
        # PSD up to roundoff of a matrix assembled to ~1e-14 relative.
        assert ev[0] >= -1e-12 * ev[-1]


@pytest.mark.parametrize(
    ("nodes", "root_dof"), [(UNIFORM4, False), (NONUNIFORM4, False), (NONUNIFORM4, True)]
)
@pytest.mark.parametrize("b_over_l", [1e-5, 1e-3, 0.03, 0.3, 3.0])
def test_matches_brute_force(nodes, root_dof, b_over_l):
    b = b_over_l * L
    op = HysteresisOperator(nodes, root_dof=root_dof)
    ref = _brute_force_u(nodes, root_dof, b)
    # Issue 2 requirement: 1e-9 relative Frobenius. The reference itself is good to about
    # 1e-12 (roundoff of ψ(ξ+u) − ψ(ξ) at u ~ b, relative ε h / b).
    assert _relerr(op.matrix(b), ref) <= 1e-9


@pytest.mark.parametrize("b_over_l", [0.03, 0.3, 3.0])
@pytest.mark.parametrize("nodes", [UNIFORM4, NONUNIFORM4])
def test_matches_direct_double_integral(nodes, b_over_l):
    # Checks the change of variables u = x − ξ itself against the plain (x, ξ) definition.
    b = b_over_l * L
    op = HysteresisOperator(nodes, root_dof=True)
    ref = _brute_force_xy(nodes, True, b)
    # Tensor Gauss on panels <= b/2 converges to ~1e-14; requirement is 1e-9.
    assert _relerr(op.matrix(b), ref) <= 1e-9


# Realistic non-uniform mesh: three segments (e.g. a cutout) meshed uniformly within each,
# which gives 100 distinct node differences.
SEGMENTED16 = np.concatenate(
    [np.linspace(0.0, 0.1, 6), np.linspace(0.1, 0.2, 7)[1:], np.linspace(0.2, L, 6)[1:]]
)


@pytest.mark.slow
@pytest.mark.parametrize("b", [1e-5 * L, 7e-4, 0.01, 0.3 * L, 10 * L])
def test_matches_brute_force_segmented_16_elements(b):
    op = HysteresisOperator(SEGMENTED16, root_dof=True)
    assert _relerr(op.matrix(b), _brute_force_u(SEGMENTED16, True, b)) <= 1e-9  # issue 2


def test_brute_force_covers_every_evaluation_path():
    # b/L = 0.1 on the 4-element meshes: wider than 1/12 of the smallest spacing and
    # narrower than the widest element (panelled quadrature, as 0.03 L); 1e-3 L is the
    # narrow closed form, 3 L the wide fixed-node rule. Mixed in one batch they must give
    # the same as one by one (up to the summation order of the final product: 1e-14).
    op = HysteresisOperator(NONUNIFORM4)
    bs = L * np.array([0.1, 1e-3, 3.0])
    batch = op.matrices(bs)
    for b, s in zip(bs, batch, strict=True):
        assert _relerr(s, op.matrix(b)) <= 1e-14
    # Only b = 0.1 L is not already covered by test_matches_brute_force; 1e-9 as there.
    assert _relerr(batch[0], _brute_force_u(NONUNIFORM4, False, bs[0])) <= 1e-9


def test_scaling_with_length():
    # Units check (physics.md §1): scaling x -> λx and b -> λb, the slope of a w-dof shape
    # function scales as 1/λ and of a θ-dof as 1, the area element as λ² and g_b as 1/λ,
    # so S_ww ∝ 1/λ, S_wθ ∝ 1, S_θθ ∝ λ. Exact up to roundoff (1e-12).
    lam = 3.7
    s1 = HysteresisOperator(NONUNIFORM4, root_dof=True).matrix(0.05)
    s2 = HysteresisOperator(lam * NONUNIFORM4, root_dof=True).matrix(0.05 * lam)
    # dof 0 is θ0, then (w, θ) per node: odd indices are w dofs.
    p = np.where(np.arange(s1.shape[0]) % 2 == 1, 1.0 / lam, 1.0)
    expected = s1 * np.outer(p, p) * lam
    assert _relerr(s2, expected) <= 1e-12


# --- narrow-kernel limit (physics.md §2) ----------------------------------------------------
def _modes(n_el, count):
    nodes, k, m = _uniform_cantilever(n_el)
    _, vec = linalg.eigh(k, m)
    return nodes, k, vec[:, :count]


def test_narrow_kernel_limit_matrix():
    # S(b) / (b²/2) -> ∫φ''φ'' as b -> 0, with a first-order boundary-layer error (the
    # kernel loses its neighbours within ~b of both ends): the relative error must fall
    # in proportion to b.
    nodes, k, _ = _modes(16, 1)
    op = HysteresisOperator(nodes)
    errs = [_relerr(op.matrix(b) / (0.5 * b * b), k) for b in (1e-5, 1e-6, 1e-7)]
    # Measured ~5.3e-4, 5.3e-5, 5.3e-6: first order; allow 10 % on each tenfold step.
    assert errs[0] < 1e-3
    for e_big, e_small in zip(errs[:-1], errs[1:], strict=True):
        assert 9.0 < e_big / e_small < 11.0


def test_narrow_kernel_modal_damping_ratio():
    # Issue 2: modal damping of a S(b) over that of Kelvin–Voigt with c_d I = a b²/2 is
    # 0.999 at b = 1e-4 m (L = 0.3048 m, 16 elements) and tends to 1 as b -> 0.
    # Boundary layer, derived from D(u) = ½∫(ψ(ξ+u) − ψ(ξ))² for smooth ψ = w':
    #   D(u) = (u²/2) ∫w''² − (u³/4) (w''(0)² + w''(L)²) + O(u⁴),  ∫_0^∞ 2 g_b u³ = E|Z|³ b³,
    # so ratio = 1 − (E|Z|³ / 2) b (w''(0)² + w''(L)²) / ∫w''² + O(b²), E|Z|³ = 2 sqrt(2/π).
    nodes, k, phi = _modes(16, 4)
    op = HysteresisOperator(nodes)
    h = nodes[1] - nodes[0]
    c = _hermite_coefficients(h)
    curv_root = (2 * c[2])[2:]  # w''(0) from node-1 dofs of the first element
    curv_tip = 2 * c[2] + 6 * c[3] * h  # w''(L) from the last element's 4 dofs
    ez3 = 2.0 * math.sqrt(2.0 / math.pi)
    deviations = []
    for b in (1e-4, 1e-5, 1e-6):
        s = op.matrix(b)
        for v in phi.T:
            kv = v @ k @ v
            ratio = (v @ s @ v) / (0.5 * b * b * kv)
            layer = (curv_root @ v[:2]) ** 2 + (curv_tip @ v[-4:]) ** 2
            predicted = 1.0 - 0.5 * ez3 * b * layer / kv
            # O(b²) remainder: measured <= 1.2e-6 at 1e-4 m, <= 6e-8 at 1e-5 m.
            assert abs(ratio - predicted) < 5e-6
            if b == 1e-4:
                assert abs(ratio - 0.999) <= 1e-3  # issue 2 value (measured 0.99895)
            deviations.append(1.0 - ratio)
    dev = np.array(deviations).reshape(3, -1)
    assert np.all(dev > 0)  # the missing neighbours near the root only remove damping
    assert np.all(dev[1:] < 0.11 * dev[:-1])  # -> 1 linearly in b


def test_continuous_sine_against_closed_form():
    # Beyond the FE basis: w(x) = sin(kx) (root slope k, so root_dof=True) on [0, L]; its
    # quadratic form ½∫∫ g_b (w'(x) − w'(ξ))² = ∫_0^L 2 g_b(u) E(u) du with E(u) in closed
    # form. The Hermite interpolant's cᵀ S c must converge to it at the interpolation
    # order h⁴ (measured gaps 3e-3 at 16 and 2e-4 at 32 elements, 3 wavelengths).
    # Also the infinite-beam law k²(1 − exp(−k²b²/2)) (physics.md §2) holds to O(b/L).
    k = 2 * math.pi * 3 / L

    def e_of_u(u):
        def anti(x):  # antiderivative of (cos k(x+u) − cos kx)² minus its mean 1 − cos ku
            return (
                np.sin(2 * k * x + 2 * k * u) / (4 * k)
                + np.sin(2 * k * x) / (4 * k)
                - np.sin(2 * k * x + k * u) / (2 * k)
            )

        ell = L - u
        return 0.5 * k**2 * (ell * (1 - np.cos(k * u)) + anti(ell) - anti(0.0))

    ops = {}
    for n_el in (16, 32):
        nodes = np.linspace(0.0, L, n_el + 1)
        c = np.empty(2 * n_el + 1)
        c[0] = k
        c[1::2] = np.sin(k * nodes[1:])
        c[2::2] = k * np.cos(k * nodes[1:])
        ops[n_el] = (HysteresisOperator(nodes, root_dof=True), c)
    for b in (0.005 * L, 0.05 * L, 0.5 * L):
        exact, _ = integrate.quad(
            lambda u, b=b: 2 * _gauss(b, u) * e_of_u(u),
            0.0,
            L,
            epsabs=0,
            epsrel=1e-13,
            limit=200,
        )
        gap = {n: abs((c @ op.matrix(b) @ c) / exact - 1) for n, (op, c) in ops.items()}
        assert gap[32] < 5e-4
        assert 3.6 < math.log2(gap[16] / gap[32]) < 4.4  # measured 3.8–3.9
        law = 0.5 * L * k**2 * (1 - math.exp(-0.5 * (k * b) ** 2))
        if b < 0.1 * L:
            assert abs(exact / law - 1) < 2 * b / L  # boundary layers of width ~b at each end


# --- projection ---------------------------------------------------------------------------
def test_projected_equals_projection_of_matrix():
    rng = np.random.default_rng(20240611)
    nodes, _, modes = _modes(16, 10)
    op = HysteresisOperator(nodes)
    bs = L * np.exp(rng.uniform(math.log(1e-5), math.log(10.0), 64))
    for phi in (modes, rng.standard_normal((op.n, 7)), np.eye(op.n)):
        out = op.projected(bs, phi)
        assert out.shape == (bs.size, phi.shape[1], phi.shape[1])
        for b, p in zip(bs, out, strict=True):
            ref = phi.T @ op.matrix(b) @ phi
            # Same moments, different summation order: roundoff only (brief: 1e-13).
            assert _relerr(p, ref) <= 1e-13
            np.testing.assert_array_equal(p, p.T)
        again = op.projected(bs, phi.copy())  # cached by content
        np.testing.assert_array_equal(again, out)


def test_projected_cache_sees_in_place_changes_and_per_item_phi():
    rng = np.random.default_rng(7)
    op = HysteresisOperator(NONUNIFORM4, root_dof=True)
    phi = rng.standard_normal((op.n, 3))
    bs = np.array([1e-4, 0.02, 1.0])
    first = op.projected(bs, phi)
    phi *= 2.0  # mutate in place: the cache must not return the stale projection
    np.testing.assert_allclose(op.projected(bs, phi), 4.0 * first, rtol=1e-13, atol=0)
    per_item = rng.standard_normal((bs.size, op.n, 3))
    out = op.projected(bs, per_item)
    for b, p, s in zip(bs, per_item, out, strict=True):
        assert _relerr(s, p.T @ op.matrix(b) @ p) <= 1e-13  # roundoff only


# --- validation -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    "nodes",
    [[0.0], [0.0, 0.1, 0.1, 0.3], [0.0, 0.2, 0.1], [0.0, np.nan, 0.3], [[0.0, 0.3]]],
)
def test_bad_nodes_raise(nodes):
    with pytest.raises(HysteresisError, match="nodes"):
        HysteresisOperator(np.array(nodes))


@pytest.mark.parametrize("b", [0.0, -1e-3, np.nan, np.inf])
def test_bad_b_raises(b):
    op = HysteresisOperator(UNIFORM4)
    with pytest.raises(ValueError, match="positive"):
        op.matrix(b)
    with pytest.raises(ValueError, match="positive"):
        op.projected(np.array([1e-3, b]), np.eye(op.n))


def test_bad_shapes_raise():
    op = HysteresisOperator(UNIFORM4)
    with pytest.raises(HysteresisError, match="scalar"):
        op.matrix(np.array([1e-3, 2e-3]))
    with pytest.raises(HysteresisError, match="Phi"):
        op.projected(np.array([1e-3]), np.eye(op.n + 1))
    with pytest.raises(HysteresisError, match="match"):
        op.projected(np.array([1e-3, 2e-3]), np.ones((3, op.n, 2)))


def test_huge_coefficient_table_is_refused():
    # 80 random elements: ~3200 distinct node differences x 6 x 160² doubles ≈ 4 GB.
    rng = np.random.default_rng(3)
    nodes = np.concatenate([[0.0], np.sort(rng.uniform(0.0, L, 79)), [L]])
    with pytest.raises(HysteresisError, match="GB"):
        HysteresisOperator(nodes)


@pytest.mark.parametrize("root_dof", [False, True])
def test_compiled_panel_moments_match_the_numpy_route(root_dof):
    # The kernel sums the same nodes in another order: 1e-14 relative is ~50 roundings
    # of the largest moment (measured 3e-16). Widths cover one to all seven active pieces.
    from bayesbeam.physics import hysteresis as hys
    from bayesbeam.physics.hysteresis_kernel import _panel_moments_kernel_py

    op = HysteresisOperator(np.linspace(0.0, 0.3048, 17), root_dof=root_dof)
    b = np.random.default_rng(3).uniform(0.0009, 0.011, 40)
    n_act = op._n_active(float(b.max()))
    ref = op._moments_panels(b, n_act, backend="numpy")
    plain = _panel_moments_kernel_py(b, op._lo, op._wp, op.length, hys._CUT, hys._PANEL,
                                     hys._U_X, hys._U_W, n_act, hys._NCOEF)
    for got in (op._moments_panels(b, n_act), plain):
        assert np.max(np.abs(got - ref)) <= 1e-14 * np.max(np.abs(ref))
