"""The band-modes path: coupled damping seen through a sensor band, from the eigen-solutions.

References no code here shares with the path: the state-space reduction of the band
(``path='full'``: block Riccati iteration, :mod:`bayesbeam.physics.sensor`, then exact
propagation), LAPACK's eigenvalues of the state matrix, and the plain-Python run of the
compiled kernel.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.physics import propagate
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward
from bayesbeam.physics.modal_coupled import MARGIN, band_eigenpairs

# The benchmark's beam (source study, single ply, f1 ≈ 11 Hz, f2 ≈ 69, f3 ≈ 193 Hz).
BEAM = Beam.rectangular(0.3048, 0.127, 0.72e-3, 0.021, E=6.2e10)
DT = 0.003906
SH = {"E": 6.2e10, "gamma": 0.05, "a": 1.5, "b": 0.01, "w0": 5e-3}


def _sets(fwd: Forward, k: int, seed: int) -> np.ndarray:
    """``k`` parameter sets around SH (ζ1 of ~0.5-3 % per law), columns of ``fwd``."""
    rng = np.random.default_rng(seed)
    base = {**SH, "root_spring": 40.0, "p0": 1e-3}
    cols = []
    for name in fwd.param_names:
        v = np.full(k, base[name])
        if name != "w0" and name != "p0":
            v = v * rng.uniform(0.7, 1.3, k)
        cols.append(v)
    return np.column_stack(cols)


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


@pytest.mark.parametrize("quantity", ["displacement", "velocity", "acceleration"])
@pytest.mark.parametrize("stamps", ["uniform", "lead", "holes", "nonuniform"])
def test_band_modes_equal_the_state_space_reduction(quantity, stamps):
    beam = BEAM.replace(quantity=quantity)
    t = np.arange(1280) * DT
    kw: dict = {}
    if stamps == "lead":
        t, kw = t + 0.0173, {"t0": 0.0}
    elif stamps == "holes":
        t = np.delete(t, [5, 6, 7, 400, 1000])
    elif stamps == "nonuniform":
        t = np.sort(np.random.default_rng(1).uniform(0.0, 5.0, 600))
    fast = Forward(beam, "viscous+sh", t, bandwidth=100.0, **kw)
    full = Forward(beam, "viscous+sh", t, bandwidth=100.0, path="full", **kw)
    theta = _sets(fast, 8, seed=2)
    a, b = fast.simulate(theta), full.simulate(theta)
    assert fast.last_path == "band-modes" and full.last_path == "full"
    assert a.valid.all() and b.valid.all()
    # 1e-9 of the peak: the bar for a path without truncation (both are exact to
    # rounding; measured ~1e-13).
    assert _rel(a.y, b.y) <= 1e-9


def test_band_modes_with_a_structure_that_changes_the_modes():
    # A root spring: mode shapes differ per set (no shared basis).
    t = np.arange(1024) * DT
    fast = Forward(BEAM, "viscous+sh+root_spring", t, bandwidth=100.0)
    full = Forward(BEAM, "viscous+sh+root_spring", t, bandwidth=100.0, path="full")
    theta = _sets(fast, 6, seed=3)
    a, b = fast.simulate(theta), full.simulate(theta)
    assert fast.last_path == "band-modes"
    assert _rel(a.y, b.y) <= 1e-9


def test_basis_responses_equal_the_state_space_reduction():
    t = np.arange(1024) * DT
    kw = {"initial": "modes:2", "bandwidth": 100.0}
    fast = Forward(BEAM, "viscous+sh", t, **kw)
    full = Forward(BEAM, "viscous+sh", t, path="full", **kw)
    theta = _sets(fast.__class__(BEAM, "viscous+sh", t, bandwidth=100.0), 5, seed=4)
    theta = np.column_stack([theta[:, :4], np.ones((5, 4))])
    cols = [4, 5, 6, 7]
    a, b = fast.simulate_basis(theta, cols), full.simulate_basis(theta, cols)
    assert fast.last_path == "band-modes" and a.valid.all()
    assert _rel(a.y, b.y) <= 1e-9
    # ... and the basis reproduces simulate(): the signal is linear in the amplitudes.
    amp = np.random.default_rng(5).normal(size=(5, 4))
    theta[:, cols] = amp
    np.testing.assert_allclose(np.einsum("btp,bp->bt", a.y, amp), fast.simulate(theta).y,
                               rtol=0, atol=1e-10 * np.max(np.abs(a.y)))


def test_eigenvalues_are_those_of_the_state_matrix():
    t = np.arange(64) * DT
    fwd = Forward(BEAM, "viscous+sh", t, bandwidth=100.0)
    theta = _sets(fwd, 4, seed=6)
    omega, C, _ = fwd.modal_system(theta)
    lam, V, _, keep, ok = band_eigenpairs(omega, C, 2 * np.pi * 100.0)
    assert ok.all() and keep.sum(axis=1).tolist() == [2] * 4
    A = propagate.state_matrix(omega, C)
    ref = propagate.eigenvalues(A)
    for k in range(4):
        upper = ref[k][(ref[k].imag > 0) & (np.abs(ref[k]) <= 2 * np.pi * 100.0)]
        mine = lam[k][keep[k]]
        # LAPACK's backward error is ~ε‖A‖ (the 64x64 state's largest entries ~1e5 /s),
        # so its in-band eigenvalues carry ~1e-11 /s: 100 ε ‖A‖_F.
        atol = 100 * np.finfo(float).eps * np.linalg.norm(A[k])
        np.testing.assert_allclose(np.sort(mine), np.sort(upper), rtol=0, atol=atol)
        # T(λ) v = 0 to rounding, row by row.
        for j in np.flatnonzero(keep[k]):
            x, v = lam[k, j], V[k, j]
            res = (x**2 + omega[k] ** 2) * v + x * (C[k] @ v)
            assert np.max(np.abs(res)) <= 1e-12 * abs(x) ** 2


def test_plain_python_kernel_matches_the_compiled_one():
    t = np.arange(64) * DT
    fwd = Forward(BEAM, "viscous+sh", t, bandwidth=100.0)
    omega, C, _ = fwd.modal_system(_sets(fwd, 3, seed=7))
    w = 2 * np.pi * 100.0
    a = band_eigenpairs(omega, C, w, backend="numpy")
    b = band_eigenpairs(omega, C, w, backend="auto")
    np.testing.assert_allclose(a[0], b[0], rtol=1e-13)
    np.testing.assert_allclose(a[1], b[1], rtol=0, atol=1e-13)
    assert (a[3] == b[3]).all() and (a[4] == b[4]).all()


def test_a_mode_at_the_band_edge_is_propagated_in_full():
    t = np.arange(512) * DT
    fwd = Forward(BEAM, "viscous+sh", t, bandwidth=100.0)
    full = Forward(BEAM, "viscous+sh", t, bandwidth=100.0, path="full")
    theta = _sets(fwd, 3, seed=8)
    f2 = fwd.modes(theta[0])[0][1]  # Hz: put the band edge on the second mode of set 0
    for f in (fwd, full):
        f.bandwidth = f2 * (1 + MARGIN / 2)
    a, b = fwd.simulate(theta), full.simulate(theta)
    assert fwd.last_path == "band-modes+full"
    assert _rel(a.y, b.y) <= 1e-9
    # Only the set at the edge: no set took the band-modes path, and the record says so.
    fwd.simulate(theta[:1])
    assert fwd.last_path == "full"


def test_strong_coupling_of_close_modes_is_refused():
    # Two modes 1 % apart coupled far beyond their gap: the iteration cannot separate
    # them, and the set is left to the state-space reduction (ok = False), not guessed.
    omega = np.array([[100.0, 101.0, 5000.0, 9000.0]])
    C = np.diag([1.0, 1.0, 2.0, 3.0])[None].copy()
    C[0, 0, 1] = C[0, 1, 0] = 0.999
    *_, ok = band_eigenpairs(omega, C, 2000.0)
    assert not ok[0]
    # The same pair weakly coupled is accepted and exact.
    C[0, 0, 1] = C[0, 1, 0] = 1e-3
    lam, _, _, keep, ok = band_eigenpairs(omega, C, 2000.0)
    assert ok[0] and keep[0].sum() == 2
    ref = propagate.eigenvalues(propagate.state_matrix(omega, C))[0]
    ref = ref[(ref.imag > 0) & (np.abs(ref) < 2000.0)]
    np.testing.assert_allclose(np.sort(lam[0]), np.sort(ref), rtol=1e-12)


def test_basis_with_a_set_at_the_band_edge_mixes_both_paths():
    t = np.arange(512) * DT
    kw = {"initial": "modes:2", "bandwidth": 100.0}
    fast = Forward(BEAM, "viscous+sh", t, **kw)
    full = Forward(BEAM, "viscous+sh", t, path="full", **kw)
    theta = _sets(Forward(BEAM, "viscous+sh", t, bandwidth=100.0), 4, seed=9)
    f2 = fast.modes(np.r_[theta[0, :4], 1.0, 1.0, 1.0, 1.0])[0][1]
    for f in (fast, full):
        f.bandwidth = f2 * (1 + MARGIN / 2)  # set 0 at the edge, the others not
    theta = np.column_stack([theta[:, :4], np.ones((4, 4))])
    cols = [4, 5, 6, 7]
    a, b = fast.simulate_basis(theta, cols), full.simulate_basis(theta, cols)
    assert fast.last_path == "band-modes+full" and a.valid.all()
    assert _rel(a.y, b.y) <= 1e-9


def test_without_numba_the_band_is_reduced_by_the_state_space_route(monkeypatch):
    # The iteration run as plain Python would be far slower than the numpy reduction.
    from bayesbeam.physics import forward as fw

    monkeypatch.setattr(fw, "numba_available", lambda: False)
    t = np.arange(256) * DT
    fwd = Forward(BEAM, "viscous+sh", t, bandwidth=100.0)
    fwd.simulate(_sets(fwd, 2, seed=10))
    assert fwd.last_path == "full"
