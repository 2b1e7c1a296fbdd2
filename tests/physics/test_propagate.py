"""Tests of bayesbeam.physics.propagate: exact response of the first-order modal system.

References used here are independent of the module: scipy.linalg.expm (Padé, Al-Mohy &
Higham 2009), scipy's DOP853 integrator, closed-form single-mode decays, and energy
dissipation (physics.md §4). Modal data are made here: frequencies of a uniform Hermite
cantilever (the source's single-ply geometry, 16 elements, ω up to 3.1e5 rad/s) and a dense
positive semidefinite damping matrix whose diagonal grows like ω²/(ω + ω_c) (spatial
hysteresis, physics.md §2: ∝ k⁴ for low modes, ∝ k² for high ones), so the benchmark's
stiffness (largest |λ| ≈ 1e6 1/s, ‖A dt‖₁ ≈ 5e3 at dt = 3.906 ms) is reproduced.
"""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import eigh, expm

from bayesbeam.physics import propagate as pg
from bayesbeam.physics.expm import PropagationError, expm_batched

DT = 0.003906  # s, the benchmark's sample interval (256 Hz)


# --------------------------------------------------------------------------- modal data


def cantilever_omega(n_el=16, E=6.2e10, L=0.3048, width=0.127, th=0.72e-3, mass=0.021):
    """Undamped ω (rad/s) of a uniform clamped Hermite-element beam (textbook element matrices)."""
    rhoA = mass / L
    EI = E * width * th**3 / 12
    h = L / n_el
    Me = (rhoA * h / 420) * np.array(
        [
            [156, 22 * h, 54, -13 * h],
            [22 * h, 4 * h * h, 13 * h, -3 * h * h],
            [54, 13 * h, 156, -22 * h],
            [-13 * h, -3 * h * h, -22 * h, 4 * h * h],
        ]
    )
    Ke = (EI / h**3) * np.array(
        [
            [12, 6 * h, -12, 6 * h],
            [6 * h, 4 * h * h, -6 * h, 2 * h * h],
            [-12, -6 * h, 12, -6 * h],
            [6 * h, 2 * h * h, -6 * h, 4 * h * h],
        ]
    )
    nd = 2 * (n_el + 1)
    M = np.zeros((nd, nd))
    K = np.zeros((nd, nd))
    for e in range(n_el):
        M[2 * e : 2 * e + 4, 2 * e : 2 * e + 4] += Me
        K[2 * e : 2 * e + 4, 2 * e : 2 * e + 4] += Ke
    return np.sqrt(eigh(K[2:, 2:], M[2:, 2:], eigvals_only=True))


def modal_damping(omega, rng, beta=1.8, omega_c=1e4):
    """Dense symmetric PSD C (1/s): viscous γI plus β g gᵀ∘G with G a random Gram matrix."""
    m = omega.size
    R = rng.standard_normal((m, m))
    G = R.T @ R / m
    g = np.sqrt(omega**2 / (omega + omega_c))
    C = beta * g[0] ** 2 * np.eye(m) + beta * g[:, None] * G * g[None, :]
    return 0.5 * (C + C.T)


def stiff_batch(B, seed, n_el=16):
    rng = np.random.default_rng(seed)
    om0 = cantilever_omega(n_el)
    omega = np.array([om0 * math.exp(0.05 * rng.standard_normal()) for _ in range(B)])
    C = np.array([modal_damping(w, rng) for w in omega])
    return pg.state_matrix(omega, C), rng


def single_mode(omega, zeta):
    return pg.state_matrix(np.array([[omega]]), np.array([[[2 * zeta * omega]]]))


def rel_fro(X, R):
    return np.linalg.norm(X - R, axis=(-2, -1)) / np.linalg.norm(R, axis=(-2, -1))


# --------------------------------------------------------------------------- state matrix


def test_state_matrix_blocks():
    rng = np.random.default_rng(1)
    omega = rng.uniform(1, 10, (2, 3))
    C = np.array([modal_damping(w, rng) for w in omega])
    A = pg.state_matrix(omega, C)
    assert A.shape == (2, 6, 6)
    np.testing.assert_array_equal(A[:, :3, :3], 0.0)
    np.testing.assert_array_equal(A[:, :3, 3:], np.stack([np.diag(w) for w in omega]))
    np.testing.assert_array_equal(A[:, 3:, :3], -np.stack([np.diag(w) for w in omega]))
    np.testing.assert_array_equal(A[:, 3:, 3:], -C)


@pytest.mark.parametrize(
    "omega, C, match",
    [
        (np.array([[1.0, -2.0]]), np.zeros((1, 2, 2)), "non-negative"),
        (np.array([[1.0, np.nan]]), np.zeros((1, 2, 2)), "finite"),
        (np.array([[1.0, 2.0]]), np.zeros((1, 3, 3)), "shape"),
        (np.array([[1.0, 2.0]]), np.array([[[1.0, 0.5], [0.0, 1.0]]]), "symmetric"),
        (np.array([1.0, 2.0]), np.zeros((1, 2, 2)), "2-D"),
    ],
)
def test_state_matrix_rejects(omega, C, match):
    with pytest.raises(PropagationError, match=match):
        pg.state_matrix(omega, C)


def test_state_matrix_unchecked_lets_bad_sets_reach_the_mask():
    omega = np.array([[10.0], [np.nan]])
    A = pg.state_matrix(omega, np.ones((2, 1, 1)), check=False)
    y, valid = pg.response_uniform(A, [1.0, 0.0], [1.0, 0.0], 0.01, 4, return_valid=True)
    assert valid.tolist() == [True, False] and np.isnan(y[1]).all()
    with pytest.raises(PropagationError, match="shape"):
        pg.state_matrix(omega, np.ones((2, 2, 2)), check=False)


# --------------------------------------------------------------------------- expm


def test_expm_matches_scipy_on_stiff_state_matrices():
    A, _ = stiff_batch(6, seed=2)
    for dt in (DT / 64, DT / 8, DT):  # ‖A dt‖₁ from ~1e2 to ~8e3 (the benchmark's)
        E = expm_batched(A * dt)
        R = np.array([expm(a * dt) for a in A])
        # Both are backward stable; each squaring doubles the rounding error of an
        # (almost) norm-preserving exponential, so each has an error ≈ 2^s·u (relative
        # backward error ≈ u/θ). Measured against an 80-bit Taylor reference at
        # ‖A dt‖₁ = 8e3: 5e-13 here, 2e-13 for scipy. 1e-12 is the brief's bound; the
        # difference grows ∝ ‖A dt‖ (4e-12 at 6e4).
        assert rel_fro(E, R).max() <= 1e-12


def test_expm_matches_scipy_on_mild_matrices():
    rng = np.random.default_rng(3)
    mats = [rng.standard_normal((8, 8)) * scale for scale in (1e-6, 1e-3, 0.1, 1.0, 3.0)]
    mats.append(np.zeros((8, 8)))
    A = np.array(mats)
    E = expm_batched(A)
    R = np.array([expm(a) for a in A])
    # Few or no squarings: both at a few u·‖e^A‖ (non-normal random matrices; 1e-12 bound).
    assert rel_fro(E, R).max() <= 1e-12
    np.testing.assert_array_equal(E[-1], np.eye(8))  # exp(0) = I exactly


def test_expm_huge_norm_is_prescaled():
    # ‖A‖ ~ 1e12 goes through the power-of-two pre-scaling; exp(diag(-1e12, 0)) = diag(0, 1)
    # exactly in double precision (e^-1e12 underflows).
    A = np.diag([-1e12, 0.0])[None]
    np.testing.assert_allclose(expm_batched(A)[0], np.diag([0.0, 1.0]), atol=1e-15)
    with pytest.raises(PropagationError, match="not finite"):
        expm_batched(np.full((1, 2, 2), 1e300))  # would need > 128 squarings
    E, valid = expm_batched(
        np.array([np.eye(2), np.full((2, 2), 1e300), [[0, np.nan], [0, 0]], 800 * np.eye(2)]),
        return_valid=True,
    )
    assert valid.tolist() == [True, False, False, False]  # e^800 overflows
    assert np.isnan(E[1:]).all() and np.allclose(E[0], math.e * np.eye(2), rtol=1e-15)


def test_expm_rejects_bad_input():
    with pytest.raises(PropagationError, match="not finite"):
        expm_batched(np.array([[[0.0, np.inf], [0.0, 0.0]]]))
    with pytest.raises(PropagationError, match="square"):
        expm_batched(np.zeros((1, 2, 3)))
    with pytest.raises(PropagationError, match="3-D"):
        expm_batched(np.zeros((2, 2)))
    with pytest.raises(PropagationError, match="real"):
        expm_batched(np.zeros((1, 2, 2), dtype=complex))


# --------------------------------------------------------------------------- analytic decay


def analytic_free_decay(omega, zeta, q0, t):
    """q(t) of q'' + 2ζω q' + ω² q = 0, q(0) = q0, q'(0) = 0 (closed forms for all ζ)."""
    if zeta < 1:
        wd = omega * math.sqrt(1 - zeta**2)
        return (
            q0
            * np.exp(-zeta * omega * t)
            * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * t))
        )
    if zeta == 1:
        return q0 * np.exp(-omega * t) * (1 + omega * t)
    r = omega * math.sqrt(zeta**2 - 1)
    l1, l2 = -zeta * omega + r, -zeta * omega - r
    return q0 * (l2 * np.exp(l1 * t) - l1 * np.exp(l2 * t)) / (l2 - l1)


@pytest.mark.parametrize("zeta", [0.0, 0.02, 0.5, 1.0, 3.0])
def test_single_mode_analytic(zeta):
    omega, q0, n = 2 * math.pi * 11.4, 1e-3, 1280
    A = single_mode(omega, zeta)
    z0 = np.array([omega * q0, 0.0])  # z = [ω q; q']
    h = np.array([1 / omega, 0.0])  # displacement output q
    t = DT * np.arange(n)
    ref = analytic_free_decay(omega, zeta, q0, t)
    y = pg.response_uniform(A, z0, h, DT, n)[0]
    # P = expm(A dt) has a relative error ~u (‖A dt‖ = 0.28, no squaring), P^k z0 then
    # gains ~u per step (P is a contraction): ≲ 1280·1e-16 ≈ 1e-13; the closed form has
    # ~ωt·u ≈ 4e-14 from its phase. 1e-12 of q0 is the brief's bound.
    assert np.abs(y - ref).max() <= 1e-12 * q0
    # Same through the eigendecomposition at the same times; at ζ = 1 the eigenvectors
    # coincide, so "auto" must fall back to direct exponentials and still be right.
    y2 = pg.response_times(A, z0, h, t)[0]
    assert np.abs(y2 - ref).max() <= 1e-12 * q0


def test_eigenvalues_single_mode_and_sorting():
    omega, zeta = 70.0, 0.03
    lam = pg.eigenvalues(single_mode(omega, zeta))[0]
    wd = omega * math.sqrt(1 - zeta**2)
    # Roots of λ² + 2ζωλ + ω² = 0; 1e-13 relative (LAPACK's eig on a 2×2 is ~u accurate).
    np.testing.assert_allclose(lam, [-zeta * omega - 1j * wd, -zeta * omega + 1j * wd], rtol=1e-13)
    A, _ = stiff_batch(2, seed=4)
    lam = pg.eigenvalues(A)
    assert lam.shape == (2, 64) and lam.dtype == complex
    assert np.all(np.diff(np.abs(lam), axis=1) >= 0)
    assert np.all(lam.real <= 0)  # PSD damping: no growing mode


# --------------------------------------------------------------------------- uniform grid


def test_response_uniform_matches_direct_expm_on_stiff_system():
    A, rng = stiff_batch(2, seed=5)
    s = A.shape[1]
    z0 = rng.standard_normal((2, s))
    h = rng.standard_normal((2, s))
    n = 1280
    y = pg.response_uniform(A, z0, h, DT, n)
    ks = np.r_[np.arange(40), [63, 64, 65, 127, 128, 500, 777, 1024, 1279]]
    for b in range(2):
        ref = np.array([h[b] @ expm(A[b] * (k * DT)) @ z0[b] for k in ks])
        # The reference exponential has its own error of about u·‖A‖·t ≈ 1e-9 (a backward
        # error u·‖A‖ acting for t ≤ 5 s); ours is at ~1e-11 (P^k from a contraction).
        # 1e-8 relative to the signal amplitude, below the brief's 1e-7.
        assert np.abs(y[b, ks] - ref).max() <= 1e-8 * np.abs(ref).max()


def test_response_uniform_matches_tight_integrator():
    # A small, non-stiff system so that DOP853 at rtol 1e-13 is an accurate, independent
    # reference (its global error here is ~1e-11 of the amplitude).
    rng = np.random.default_rng(6)
    omega = np.array([[7.0, 19.0, 41.0]])
    C = modal_damping(omega[0], rng, beta=0.3, omega_c=10.0)[None]
    A = pg.state_matrix(omega, C)
    z0 = rng.standard_normal(6)
    h = rng.standard_normal(6)
    n, dt = 400, 0.01
    t = dt * np.arange(n)
    sol = solve_ivp(
        lambda _, z: A[0] @ z, (0, t[-1]), z0, method="DOP853", t_eval=t, rtol=1e-13, atol=1e-15
    )
    ref = h @ sol.y
    y = pg.response_uniform(A, z0, h, dt, n)[0]
    assert np.abs(y - ref).max() <= 1e-9 * np.abs(ref).max()  # brief: ≤ 1e-7


def test_energy_is_non_increasing():
    # Output every state component (h = unit rows): ½|z|² is the energy (physics.md §4),
    # d/dt ½|z|² = -q'ᵀ C q' ≤ 0 for PSD C.
    A, rng = stiff_batch(1, seed=7)
    s = A.shape[1]
    z0 = rng.standard_normal(s)
    Z = pg.response_uniform(np.repeat(A, s, axis=0), z0, np.eye(s), DT, 300)
    energy = 0.5 * (Z**2).sum(axis=0)
    # Allowed increase per step: rounding of ~s·u of the energy.
    assert np.all(np.diff(energy) <= 1e-13 * energy[0])
    assert energy[-1] < energy[0]


def test_batch_equals_one_by_one():
    A, rng = stiff_batch(20, seed=8)  # several internal chunks (8 sets each)
    s = A.shape[1]
    z0 = rng.standard_normal((20, s))
    h = rng.standard_normal(s)  # one shared output vector (s,)
    y = pg.response_uniform(A, z0, h, DT, 333)
    for b in (0, 7, 16, 19):
        yb = pg.response_uniform(A[b : b + 1], z0[b], h, DT, 333)[0]
        # Degree and squarings are chosen per set and BLAS multiplies each matrix on its
        # own, so the results agree to the last bit (measured); allow 1e-14 for a BLAS that
        # orders sums differently. A per-batch choice would differ by ~1e-11.
        assert np.abs(y[b] - yb).max() <= 1e-14 * np.abs(yb).max()


@pytest.mark.parametrize("threads", [1, 2, None])
def test_threads_do_not_change_the_result(threads):
    A, rng = stiff_batch(18, seed=9, n_el=4)
    z0 = rng.standard_normal((18, A.shape[1]))
    h = rng.standard_normal((18, A.shape[1]))
    y1 = pg.response_uniform(A, z0, h, DT, 100)
    y2 = pg.response_uniform(A, z0, h, DT, 100, threads=threads)
    np.testing.assert_array_equal(y1, y2)


def test_response_uniform_small_n_and_empty():
    A, rng = stiff_batch(2, seed=10, n_el=2)
    z0 = rng.standard_normal((2, A.shape[1]))
    h = rng.standard_normal((2, A.shape[1]))
    np.testing.assert_allclose(pg.response_uniform(A, z0, h, DT, 1)[:, 0], (h * z0).sum(1))
    assert pg.response_uniform(A, z0, h, DT, 0).shape == (2, 0)
    y = pg.response_uniform(A, z0, h, DT, 3)
    ref = [[h[b] @ expm(A[b] * k * DT) @ z0[b] for k in range(3)] for b in range(2)]
    np.testing.assert_allclose(y, ref, rtol=1e-12, atol=1e-14 * np.abs(ref).max())


# --------------------------------------------------------------------------- arbitrary times


def test_response_times_nonuniform():
    A, rng = stiff_batch(3, seed=11)
    s = A.shape[1]
    z0 = rng.standard_normal((3, s))
    h = rng.standard_normal((3, s))
    n = 1280
    grid = DT * np.arange(n)
    y_uni = pg.response_uniform(A, z0, h, DT, n)
    # Uniform times in scrambled order.
    perm = rng.permutation(n)
    y_t = pg.response_times(A, z0, h, grid[perm])
    scale = np.abs(y_uni).max()
    # Eigendecomposition error ~u·κ·(…): ≤ 1e-9 of the amplitude (brief's bound).
    assert np.abs(y_t - y_uni[:, perm]).max() <= 1e-9 * scale
    # Jittered times against direct exponentials at those times.
    t = grid[::97] + rng.uniform(0, DT, grid[::97].size)
    y_j = pg.response_times(A, z0, h, t)
    for b in range(3):
        ref = np.array([h[b] @ expm(A[b] * tk) @ z0[b] for tk in t])
        assert np.abs(y_j[b] - ref).max() <= 1e-9 * scale
    # The exact fallback agrees with the eigendecomposition.
    y_e = pg.response_times(A[:1], z0[:1], h[:1], t, method="expm")
    assert np.abs(y_e - y_j[:1]).max() <= 1e-9 * scale


def test_response_times_auto_falls_back_only_where_needed():
    # A batch mixing a critically damped mode (coalescing eigenvectors) with normal ones.
    omega = 40.0
    A = np.concatenate([single_mode(omega, z) for z in (0.05, 1.0, 1 + 1e-14, 2.0)])
    t = np.sort(np.random.default_rng(14).uniform(0, 0.5, 200))
    q0 = 2e-3
    y = pg.response_times(A, [omega * q0, 0.0], [1 / omega, 0.0], t)
    for b, zeta in enumerate((0.05, 1.0, 1.0, 2.0)):
        # Closed forms (ζ = 1 + 1e-14 differs from ζ = 1 by ~1e-14 relative); 1e-12 of q0
        # as in the single-mode test.
        assert np.abs(y[b] - analytic_free_decay(omega, zeta, q0, t)).max() <= 1e-12 * q0


def test_response_times_eig_flags_ill_conditioned_sets():
    # Critical damping: the two eigenvectors coincide; "eig" must not return garbage.
    A = single_mode(50.0, 1.0)
    t = np.array([0.0, 0.01, 0.1])
    y, valid = pg.response_times(
        A, [50.0, 0.0], [1 / 50.0, 0.0], t, method="eig", return_valid=True
    )
    assert not valid[0] and np.isnan(y).all()
    with pytest.raises(PropagationError, match="not finite"):
        pg.response_times(A, [50.0, 0.0], [1 / 50.0, 0.0], t, method="eig")


@pytest.mark.parametrize(
    "t, match",
    [([0.0, -1.0], "non-negative"), ([0.0, np.nan], "finite"), ([[0.0]], "1-D")],
)
def test_response_times_rejects_bad_times(t, match):
    A = single_mode(10.0, 0.1)
    with pytest.raises(PropagationError, match=match):
        pg.response_times(A, [1.0, 0.0], [1.0, 0.0], t)


# --------------------------------------------------------------------------- no silent NaN


def test_non_finite_sets_raise_or_are_masked():
    A, rng = stiff_batch(3, seed=12, n_el=2)
    s = A.shape[1]
    z0 = rng.standard_normal((3, s))
    h = rng.standard_normal((3, s))
    A_bad = A.copy()
    A_bad[1, 0, 0] = np.nan
    for fn, extra in ((pg.response_uniform, (DT, 50)), (pg.response_times, (DT * np.arange(50),))):
        with pytest.raises(PropagationError, match=r"set\(s\) \[1\]"):
            fn(A_bad, z0, h, *extra)
        y, valid = fn(A_bad, z0, h, *extra, return_valid=True)
        assert valid.tolist() == [True, False, True]
        assert np.isnan(y[1]).all() and np.isfinite(y[[0, 2]]).all()
        np.testing.assert_array_equal(y[[0, 2]], fn(A[[0, 2]], z0[[0, 2]], h[[0, 2]], *extra))
    z_bad = z0.copy()
    z_bad[2, 0] = np.inf
    _, valid = pg.response_uniform(A, z_bad, h, DT, 10, return_valid=True)
    assert valid.tolist() == [True, True, False]


def test_growing_response_is_reported():
    # A negative-definite "damping" (not dissipative) makes the response overflow.
    A = single_mode(10.0, -40.0)
    with pytest.raises(PropagationError, match="not finite"):
        pg.response_uniform(A, [1.0, 0.0], [1.0, 0.0], 1.0, 400)
    y, valid = pg.response_uniform(A, [1.0, 0.0], [1.0, 0.0], 1.0, 400, return_valid=True)
    assert not valid[0] and np.isnan(y).all()
    _, valid = pg.response_times(A, [1.0, 0.0], [1.0, 0.0], [0.0, 400.0], return_valid=True)
    assert not valid[0]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(dt=0.0), "dt"),
        (dict(dt=np.inf), "dt"),
        (dict(n=-1), "n must"),
        (dict(n=2.5), "n must"),
        (dict(z0=np.zeros(3)), "z0"),
        (dict(h=np.zeros((2, 2))), "h must"),
        (dict(backend="cuda"), "backend"),
        (dict(threads=0), "threads"),
    ],
)
def test_response_uniform_rejects(kwargs, match):
    args = dict(A=single_mode(10.0, 0.1), z0=np.ones(2), h=np.ones(2), dt=0.01, n=5)
    args.update(kwargs)
    with pytest.raises(PropagationError, match=match):
        pg.response_uniform(**args)


# --------------------------------------------------------------------------- numba backend


def test_numba_backend_unavailable_is_reported(monkeypatch):
    monkeypatch.setattr(pg, "numba_available", lambda: False)
    with pytest.raises(PropagationError, match="numba"):
        pg.response_uniform(single_mode(10.0, 0.1), [1, 0], [1, 0], 0.01, 5, backend="numba")
    # "auto" falls back to numpy silently (same results by construction).
    y = pg.response_uniform(single_mode(10.0, 0.1), [1, 0], [1, 0], 0.01, 5, backend="auto")
    assert y.shape == (1, 5)


def test_numba_kernel_logic_in_plain_python():
    # The kernel is plain Python until numba compiles it; run it uncompiled on a small
    # system (fast enough) so its logic is checked even where numba is not installed.
    A, rng = stiff_batch(3, seed=15, n_el=2)
    s = A.shape[1]
    z0 = rng.standard_normal((3, s))
    h = rng.standard_normal((3, s))
    A[1, 0, 1] = np.inf  # an invalid set: reported, not propagated
    y0, v0 = pg.response_uniform(A, z0, h, DT, 77, return_valid=True)
    degrees = np.array(sorted(pg._THETA), dtype=np.int64)
    theta = np.array([pg._THETA[d] for d in degrees])
    y1, v1 = pg._uniform_kernel_py(
        np.where(np.isfinite(A), A, 0.0), z0, h, DT, 77, pg._plan(77), theta, degrees,
        pg._inv_factorials(24), pg._PRESCALE_NORM, pg._MAX_SQUARINGS,
    )  # fmt: skip
    assert v0.tolist() == [True, False, True] and v1.tolist() == [True, True, True]
    # Same algorithm, sums ordered differently: ~u per step, 77 steps.
    assert np.abs(y1[v0] - y0[v0]).max() <= 1e-12 * np.abs(y0[v0]).max()


@pytest.mark.slow
def test_numba_backend_matches_numpy():
    pytest.importorskip("numba")  # optional accelerator; compiled on first use (~10 s)
    A, rng = stiff_batch(5, seed=13)
    s = A.shape[1]
    z0 = rng.standard_normal((5, s))
    h = rng.standard_normal((5, s))
    A[3, 0, 0] = np.nan
    y0, v0 = pg.response_uniform(A, z0, h, DT, 1280, return_valid=True)
    y1, v1 = pg.response_uniform(A, z0, h, DT, 1280, return_valid=True, backend="numba", threads=2)
    assert v0.tolist() == v1.tolist() == [True, True, True, False, True]
    ok = v0
    # Same algorithm and choices; sums are ordered differently (and scipy's BLAS is not
    # numpy's), so P differs by ~u and P^k z0 by up to ~k·u: measured 3e-12 at k = 1279.
    assert np.abs(y1[ok] - y0[ok]).max() <= 1e-10 * np.abs(y0[ok]).max()
