"""The sensor band of the forward model (ideal anti-alias filter on the eigen-solutions).

References that no code here shares with the filter: (i) once the modes above the band
have decayed, the band-limited signal must equal the full one (nothing in band is
touched); (ii) the fast route for classically damped sets and the eigenvector route for
coupled ones must give the same signal; (iii) a least-squares decomposition of the signal
into the system's eigen-solutions finds those above the band removed and the others
untouched.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.physics import propagate
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward, ForwardError
from bayesbeam.physics.sensor import (
    _eigen_projection,
    _inverse_left,
    _inverse_right,
    _modal_inverse_blocks,
    band_limit,
)

L, W, TH, RHO = 0.4, 0.0508, 0.002, 2700.0
E = 70e9
T = np.arange(2048) / 512.0


def _beam(quantity: str = "acceleration") -> Beam:
    return Beam.rectangular(length=L, width=W, thickness=TH, mass=L * W * TH * RHO,
                            E=E).replace(quantity=quantity)


KV = {"E": E, "gamma": 0.106, "c_d": 4.33e6, "w0": 0.005}
SH = {"E": E, "gamma": 0.05, "a": 2e-3, "b": 0.05, "w0": 0.005}


@pytest.mark.parametrize("quantity", ["displacement", "acceleration"])
def test_band_limited_equals_full_once_high_modes_decay(quantity):
    full = Forward(_beam(quantity), "viscous+kv", T, n_elements=24).simulate(KV)
    band = Forward(_beam(quantity), "viscous+kv", T, n_elements=24, bandwidth=200.0).simulate(KV)
    assert full.valid[0] and band.valid[0]
    peak = np.max(np.abs(full.y[0]))
    late = T >= 0.5  # Kelvin-Voigt: modes 4+ (>= 354 Hz) decay at >= 150 /s, e^-75 by 0.5 s
    # 1e-9 of the peak: propagation round-off of the 48-dof full system (physics.md §4).
    assert np.max(np.abs(full.y[0, late] - band.y[0, late])) <= 1e-9 * peak
    # ...and the filter did remove something at the start.
    assert np.max(np.abs(full.y[0, :20] - band.y[0, :20])) > 1e-3 * peak


def _eigen_coefficients(fwd: Forward, params: dict, y: np.ndarray):
    """Least-squares amplitudes of every eigen-solution e^{λt} of the system in ``y``."""
    A, _, _ = fwd.state_space(fwd._columns(params))
    lam = propagate.eigenvalues(A)[0]
    t = fwd.times - fwd.times[0]
    basis = np.exp(np.outer(t, lam))
    coef, *_ = np.linalg.lstsq(basis, y.astype(complex), rcond=None)
    return lam, coef


@pytest.mark.parametrize(("model", "params"), [("viscous+kv", KV), ("viscous+sh", SH)])
def test_band_limit_removes_exactly_the_eigen_solutions_above_the_band(model, params):
    # Four elements: 8 modes, 16 eigen-solutions, so the signal is an exact sum of 16
    # exponentials and a least-squares decomposition on 2048 samples recovers each one
    # (SH couples the modes: its eigen-solutions are not those of the undamped modes).
    bw = 120.0  # between modes 2 (64 Hz) and 3 (181 Hz)
    full = Forward(_beam("displacement"), model, T, n_elements=4)
    band = Forward(_beam("displacement"), model, T, n_elements=4, bandwidth=bw)
    lam, c_full = _eigen_coefficients(full, params, full.simulate(params).y[0])
    _, c_band = _eigen_coefficients(full, params, band.simulate(params).y[0])
    inb = np.abs(lam) <= 2 * np.pi * bw
    assert np.count_nonzero(inb) == 4  # modes 1 and 2, each a conjugate pair
    # Solutions that decay by more than e^-2 per sample are indistinguishable from one
    # another on the samples (their columns are ~[1, 0, 0, ...]); they are left out.
    seen = np.abs(lam.real) * (T[1] - T[0]) < 2.0
    out = ~inb & seen
    scale = np.max(np.abs(c_full))
    assert np.max(np.abs(c_full[out])) > 1e-4 * scale  # present without the filter
    # 1e-8 of the largest amplitude: conditioning of the exponential basis.
    assert np.max(np.abs(c_band[out])) <= 1e-8 * scale
    np.testing.assert_allclose(c_band[inb], c_full[inb], rtol=0, atol=1e-8 * scale)


def test_classical_and_eigenvector_routes_agree():
    fwd = Forward(_beam(), "viscous+kv", T, n_elements=16)
    theta = fwd._columns(KV)
    omega, C, phi, z0 = fwd.modal_initial_state(theta)
    h = fwd._output(omega, C, phi)
    wb = 2 * np.pi * 200.0
    A = propagate.state_matrix(omega, C)
    A1, z1, h1 = band_limit(A, z0, h, omega, C, wb)
    # Coupling the kept modes to the first dropped one by 1e-8 of their frequency gap
    # (above the fast route's 1e-10) sends the set down the eigenvector route; its own
    # effect on the signal is of order 1e-8.
    kept = int(np.count_nonzero(omega[0] <= wb))
    Cp = C.copy()
    for i in range(kept):
        Cp[0, i, kept] = Cp[0, kept, i] = 1e-8 * (omega[0, kept] - omega[0, i])
    Ap = propagate.state_matrix(omega, Cp)
    A2, z2, h2 = band_limit(Ap, z0, h, omega, Cp, wb)
    assert A1.shape[1] < A.shape[1]  # the fast route drops the modes
    # The coupled set takes the invariant-subspace reduction: as small a system.
    assert A2.shape == A1.shape
    # ... and the eigenvector route, forced, projects the full state.
    z3 = _eigen_projection(Ap[0], z0[0], wb)[None]
    y1 = propagate.response_uniform(A1, z1, h1, T[1] - T[0], T.size)
    y2 = propagate.response_uniform(A2, z2, h2, T[1] - T[0], T.size)
    y3 = propagate.response_uniform(Ap, z3, h, T[1] - T[0], T.size)
    assert np.max(np.abs(y1 - y2)) <= 1e-6 * np.max(np.abs(y1))
    # Reduction and eigenvectors are two exact routes to one projection: round-off.
    assert np.max(np.abs(y2 - y3)) <= 1e-10 * np.max(np.abs(y3))


def test_unlimited_band_is_the_full_model():
    y0 = Forward(_beam(), "viscous+kv", T[:256], n_elements=12).simulate(KV).y
    y1 = Forward(_beam(), "viscous+kv", T[:256], n_elements=12,
                 bandwidth=float("inf")).simulate(KV).y
    np.testing.assert_array_equal(y0, y1)


@pytest.mark.parametrize("bad", [0.0, -5.0, float("nan"), "100", True])
def test_bad_bandwidth_is_refused(bad):
    with pytest.raises(ForwardError, match="bandwidth"):
        Forward(_beam(), "viscous", T[:10], n_elements=4, bandwidth=bad)


def _modal_inverse(A):
    """The dense inverse from its closed-form blocks (sensor._modal_inverse_blocks)."""
    P, wi = _modal_inverse_blocks(A)
    r = wi.shape[1]
    out = np.zeros_like(A)
    out[:, :r, :r] = P
    i = np.arange(r)
    out[:, i, r + i] = -wi
    out[:, r + i, i] = wi
    return out


def test_closed_form_inverse_of_a_modal_state_matrix():
    # A [[0, Ω], [-Ω, -C]] with a full symmetric C and frequencies over four decades (the
    # dropped block of a beam's modes): the closed form must be the inverse to round-off
    # of the stiffest entries, checked by A A⁻¹ = I (no inverse computed by LU here).
    rng = np.random.default_rng(3)
    m = 12
    w = np.sort(rng.uniform(1.0, 1e4, size=(3, m)), axis=1)
    G = rng.standard_normal((3, m, m))
    C = 1e-2 * (G @ np.swapaxes(G, 1, 2)) * np.sqrt(w[:, :, None] * w[:, None, :])
    A = propagate.state_matrix(w, C)
    P = A @ _modal_inverse(A)
    scale = np.abs(A).max(axis=(1, 2)) * np.abs(_modal_inverse(A)).max(axis=(1, 2))
    # Round-off of a product of two 2m-square matrices: ~2m ulp of the entries' scale.
    assert np.max(np.abs(P - np.eye(2 * m)) / scale[:, None, None]) < 4 * m * 2.3e-16
    # Applied through its blocks (the invariant-subspace iteration's products): the
    # products with the dense inverse, to the round-off of a length-2m dot product.
    Pb, wi = _modal_inverse_blocks(A)
    Z = rng.standard_normal((3, 2 * m, 4))
    dense = _modal_inverse(A) @ Z
    tol = 4 * m * 2.3e-16 * np.abs(_modal_inverse(A)).max() * np.abs(Z).max()
    assert np.max(np.abs(_inverse_left(Pb, wi, Z) - dense)) < tol
    Zt = np.swapaxes(Z, 1, 2)
    assert np.max(np.abs(_inverse_right(Pb, wi, Zt) - Zt @ _modal_inverse(A))) < tol


@pytest.mark.parametrize("backend", ["numba", "python"])
def test_invariant_reduction_routes_agree(backend, monkeypatch):
    # Spatial hysteresis couples every mode: the kept modes' reduction iterates. The
    # compiled kernel (sensor_kernel), the same kernel run as plain Python, and the
    # batched numpy iteration are one algorithm: the same reduced system to rounding
    # (1e-13 of each block's largest entry; measured 1e-19 at 64 modes).
    import bayesbeam.physics.sensor as sensor_mod
    from bayesbeam.physics.propagate import numba_available
    from bayesbeam.physics.sensor_kernel import _riccati_kernel_py

    if backend == "numba" and not numba_available():
        pytest.skip("numba does not import here")
    fwd = Forward(_beam(), "viscous+sh", T, n_elements=6)
    rng = np.random.default_rng(4)
    theta = np.tile(fwd._columns(SH), (3, 1))
    theta[:, 1] *= rng.uniform(0.5, 2.0, 3)  # gamma
    omega, C, phi, z0 = fwd.modal_initial_state(theta)
    h = fwd._output(omega, C, phi)
    A = propagate.state_matrix(omega, C)
    wb = 2 * np.pi * 120.0
    ref = band_limit(A, z0, h, omega, C, wb, backend="numpy")
    assert ref[0].shape[1] == 4  # reduced to modes 1 and 2 by the iteration
    if backend == "python":  # the kernel's logic, uncompiled
        monkeypatch.setattr(sensor_mod, "compiled_kernel", lambda kernel, *flags: kernel)
        monkeypatch.setattr(sensor_mod, "_use_numba", lambda backend: True)
        assert sensor_mod.compiled_kernel(_riccati_kernel_py) is _riccati_kernel_py
    out = band_limit(A, z0, h, omega, C, wb, backend="auto" if backend == "python" else "numba")
    for a, b in zip(out, ref, strict=True):
        assert a.shape == b.shape
        assert np.max(np.abs(a - b)) <= 1e-13 * np.max(np.abs(b))


def _riccati_blocks(coupling, seed=5, B=3, m=8, kept=2):
    """Modal state matrices of m modes (1-1e4 rad/s) with a symmetric damping whose
    diagonal gives ζ = 1 % and whose off-diagonal part is ``coupling`` x sqrt(ω_i ω_j);
    split at ``kept`` modes as sensor._invariant_reduction splits them."""
    rng = np.random.default_rng(seed)
    w = np.sort(rng.uniform(1.0, 1e4, size=(B, m)), axis=1)
    w[:, kept:] = np.maximum(w[:, kept:], 2.0 * w[:, kept - 1 : kept])  # a gap at the band
    G = rng.standard_normal((B, m, m))
    off = coupling * 0.5 * (G + np.swapaxes(G, 1, 2)) * np.sqrt(w[:, :, None] * w[:, None, :])
    idx = np.arange(m)
    off[:, idx, idx] = 0.0
    C = off + np.einsum("bi,ij->bij", 0.02 * w, np.eye(m))
    A = propagate.state_matrix(w, C)
    K = np.r_[np.arange(kept), m + np.arange(kept)]
    D = np.r_[np.arange(kept, m), m + np.arange(kept, m)]
    blk = {"A11": A[:, K[:, None], K], "A12": A[:, K[:, None], D], "A21": A[:, D[:, None], K],
           "A22": A[:, D[:, None], D], "wd": w[:, kept:],
           "ndd": A[:, (m + np.arange(kept, m))[:, None], m + np.arange(kept, m)]}
    return A, {k: np.ascontiguousarray(v) for k, v in blk.items()}


@pytest.mark.parametrize("route", ["kernel", "numpy"])
def test_decoupled_iteration_solves_the_riccati_equations(route):
    # Weak coupling (off-diagonal damping 1e-3 of the frequencies): the mode-decoupled
    # iteration converges, and its X, Y satisfy both Riccati equations to round-off of
    # their largest term (checked by substitution, not against another solver) and agree
    # with the plain fixed-point iteration's to the tolerance both stop at.
    from bayesbeam.physics.sensor import (
        DECOUPLED_ITERATIONS,
        DECOUPLED_RATIO,
        MAX_ITERATIONS,
        TOLERANCE,
        _decoupled_numpy,
        _inverse_blocks,
    )
    from bayesbeam.physics.sensor_kernel import _decoupled_kernel_py, _riccati_kernel_py

    _, b = _riccati_blocks(1e-3)
    args = (b["wd"], b["ndd"], b["A11"], b["A12"], b["A21"])
    if route == "kernel":  # uncompiled: the kernel's own logic
        X, Y, done = _decoupled_kernel_py(*args, DECOUPLED_ITERATIONS, TOLERANCE,
                                          DECOUPLED_RATIO)
    else:
        X, Y, done = _decoupled_numpy(*args)
    assert done.all()
    A11, A12, A21, A22 = b["A11"], b["A12"], b["A21"], b["A22"]
    rx = A22 @ X - X @ A11 - X @ A12 @ X + A21
    ry = A11 @ Y - Y @ A22 - Y @ A21 @ Y + A12
    scale_x = np.abs(A22 @ X).max() + np.abs(A21).max()
    scale_y = np.abs(Y @ A22).max() + np.abs(A12).max()
    # Round-off of length-2m dot products of the largest terms, with the 1e-12 stop.
    assert np.abs(rx).max() < 1e-11 * scale_x
    assert np.abs(ry).max() < 1e-11 * scale_y
    P, wi = _inverse_blocks(b["wd"], b["ndd"])
    X0, Y0, done0 = _riccati_kernel_py(P, wi, A11, A12, A21, MAX_ITERATIONS, TOLERANCE)
    assert done0.all()
    assert np.abs(X - X0).max() < 1e-10 * np.abs(X0).max()
    assert np.abs(Y - Y0).max() < 1e-10 * np.abs(Y0).max()


@pytest.mark.parametrize("seed", [5, 6])
@pytest.mark.parametrize("route", ["kernel", "numpy"])
def test_strong_coupling_leaves_the_plain_iteration_to_band_limit(route, seed, monkeypatch):
    # Off-diagonal damping of 0.6 of the frequencies: a decoupled step shrinks the
    # change by less than DECOUPLED_RATIO, so that iteration gives up (done False) and
    # band_limit's result comes from the plain iteration: still the spectral projection
    # of the eigenvector route (_eigen_projection), to 1e-9 of the signal.
    import bayesbeam.physics.sensor as sensor_mod
    from bayesbeam.physics.sensor import (
        DECOUPLED_ITERATIONS,
        DECOUPLED_RATIO,
        TOLERANCE,
        _decoupled_numpy,
    )
    from bayesbeam.physics.sensor_kernel import _decoupled_kernel_py

    m = 6
    A, b = _riccati_blocks(0.6, seed=seed, B=1, m=m)
    args = (b["wd"], b["ndd"], b["A11"], b["A12"], b["A21"])
    if route == "kernel":
        _, _, done = _decoupled_kernel_py(*args, DECOUPLED_ITERATIONS, TOLERANCE,
                                          DECOUPLED_RATIO)
        monkeypatch.setattr(sensor_mod, "compiled_kernel", lambda kernel, *flags: kernel)
        monkeypatch.setattr(sensor_mod, "_use_numba", lambda backend: True)
        backend = "numba"
    else:
        _, _, done = _decoupled_numpy(*args)
        backend = "numpy"
    assert not done.any()
    w = np.diagonal(A[:, :m, m:], axis1=1, axis2=2)
    C = -A[:, m:, m:]
    wb = 0.5 * (w[0, 1] + w[0, 2])  # between modes 2 and 3
    assert (np.abs(np.linalg.eigvals(A[0])) <= wb).sum() == 4  # two modes' roots in band
    rng = np.random.default_rng(9)
    z0, h = rng.standard_normal((1, 2 * m)), rng.standard_normal((1, 2 * m))
    Ar, zr, hr = band_limit(A.copy(), z0.copy(), h.copy(), w, C, wb, backend=backend)
    assert Ar.shape[1] == 4  # reduced (by the plain iteration), not projected in full
    ref = _eigen_projection(A[0], z0[0], wb)
    # The reduced system's output at t = 0 is that of the projected state: y = h P z0.
    assert abs(hr[0] @ zr[0] - h[0] @ ref) < 1e-9 * np.abs(h[0]).sum() * np.abs(ref).max()
