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
