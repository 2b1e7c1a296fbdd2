"""Compiled kernel of the uniform-grid modal sum (bayesbeam.physics.modal_kernel) vs numpy route.

The closed form's ``term_sum_uniform`` has two routes: the numba kernel (default where numba
imports) and the pure-numpy baby-step/giant-step products (kept for platforms without
numba). Both are exact to rounding; these tests check that they agree, that the kernel body
is right as plain Python (without numba), and that the numpy route stays selectable.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.physics import modal_closed as mc
from bayesbeam.physics import propagate as pg
from bayesbeam.physics.expm import PropagationError
from bayesbeam.physics.modal_kernel import BABY, GIANTS, _rotations_kernel_py

DT = 0.003906  # s, the benchmark's sample step (Nyquist 804 rad/s)

#: Agreement of the two routes, relative to each set's amplitude Σ_j |coef_j|: both are
#: exact to rounding (kernel ≲ 4e-14, numpy route ≲ 2.3e-12 at 10,240 stamps, their
#: docstrings); the issue's requirement is 1e-12, measured 6e-14 at 10,240 stamps.
TOL = 1e-12


def random_terms(B: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Terms of every kind, (B, 12) each: roots λ (1/s) and coefficients.

    Columns: 4 lightly damped underdamped roots (one undamped), 3 overdamped real roots,
    3 heavily damped roots (dead within a few samples, Kelvin–Voigt's high modes), 2 zero
    (padding) terms.
    """
    rng = np.random.default_rng(seed)
    lam = np.empty((B, 12), dtype=complex)
    lam[:, :4] = -rng.uniform(0.01, 5.0, (B, 4)) + 1j * rng.uniform(5.0, 800.0, (B, 4))
    lam[:, 0] = 1j * rng.uniform(5.0, 800.0, B)  # undamped: alive for the whole record
    lam[:, 4:7] = -rng.uniform(1.0, 50.0, (B, 3))
    lam[:, 7:10] = -rng.uniform(200.0, 3000.0, (B, 3)) + 1j * rng.uniform(0.0, 800.0, (B, 3))
    lam[:, 10:] = 0.0
    coef = rng.standard_normal((B, 12)) + 1j * rng.standard_normal((B, 12))
    coef[:, 10:] = 0.0
    return lam, coef


def amplitude(coef: np.ndarray) -> np.ndarray:
    return np.abs(coef).sum(axis=1, keepdims=True)


@pytest.mark.parametrize("n", [1, 1280, 10240])
@pytest.mark.parametrize("t_first", [0.0, 0.37])
def test_compiled_kernel_matches_numpy_route(n, t_first):
    pytest.importorskip("numba")
    lam, coef = random_terms(16, seed=n + int(100 * t_first))
    y_numba = mc.term_sum_uniform(lam, coef, t_first, DT, n, backend="numba")
    y_numpy = mc.term_sum_uniform(lam, coef, t_first, DT, n, backend="numpy")
    assert y_numba.shape == y_numpy.shape == (16, n)
    err = np.abs(y_numba - y_numpy) / amplitude(coef)
    assert err.max() <= TOL
    # The sums are not trivially small (a comparison of zeros would pass anything).
    assert np.abs(y_numpy).max() > 0.1 * amplitude(coef).min()


def test_compiled_kernel_matches_direct_exponentials():
    # Against one complex exp per (term, stamp): no stepping at all (term_sum_times).
    pytest.importorskip("numba")
    lam, coef = random_terms(4, seed=3)
    n = 3 * GIANTS * BABY + 77  # several exact anchors and a partial last block
    t = 0.2 + DT * np.arange(n)
    y = mc.term_sum_uniform(lam, coef, 0.2, DT, n, backend="numba")
    ref = mc.term_sum_times(lam, coef, t)
    # The kernel's bound (~4e-14) plus the conditioning u |λ| t of the exponentials
    # themselves (|λ| t ≲ 800 · 13 ≈ 1e4: ~1e-12).
    assert (np.abs(y - ref) / amplitude(coef)).max() <= 3e-12


def test_kernel_logic_in_plain_python(monkeypatch):
    # The kernel is plain Python until numba compiles it: run the whole compiled route
    # uncompiled (lifetime cut-off included) on a small batch, so that its logic is
    # checked even where numba is not installed.
    monkeypatch.setattr(pg, "numba_available", lambda: True)
    monkeypatch.setattr(mc, "compiled_kernel", lambda kernel: kernel)
    lam, coef = random_terms(2, seed=7)
    n = GIANTS * BABY + 50  # one re-anchoring and a partial block
    y_py = mc.term_sum_uniform(lam, coef, 0.1, DT, n, backend="numba")
    y_numpy = mc.term_sum_uniform(lam, coef, 0.1, DT, n, backend="numpy")
    assert (np.abs(y_py - y_numpy) / amplitude(coef)).max() <= TOL


def test_lifetime_cut_off_leaves_out_only_dead_terms(monkeypatch):
    # A term that dies within the first samples contributes to them and to nothing after:
    # its lifetime (below 1e-17 of the amplitude) is respected, not rounded to a block.
    monkeypatch.setattr(pg, "numba_available", lambda: True)
    monkeypatch.setattr(mc, "compiled_kernel", lambda kernel: kernel)
    lam = np.array([[-0.5 + 300j, -2000.0 + 0j]])
    coef = np.array([[1.0 + 0.5j, 3.0 + 0j]])
    n = 40
    y = mc.term_sum_uniform(lam, coef, 0.0, DT, n, backend="numba")
    alone = mc.term_sum_uniform(lam[:, :1], coef[:, :1], 0.0, DT, n, backend="numba")
    life = mc._lifetimes(lam, coef)[0, 1]
    dead = np.arange(n) * DT >= life
    assert 0 < dead.argmax() < n  # the fast term dies inside the record
    assert np.array_equal(y[0, dead], alone[0, dead])
    assert np.abs(y[0, ~dead] - alone[0, ~dead]).max() > 1e-12  # ... and counted before


def test_numpy_route_is_kept_and_used_without_numba(monkeypatch):
    lam, coef = random_terms(3, seed=11)
    y_numpy = mc.term_sum_uniform(lam, coef, 0.0, DT, 300, backend="numpy")
    ref = mc.term_sum_times(lam, coef, DT * np.arange(300))
    assert (np.abs(y_numpy - ref) / amplitude(coef)).max() <= TOL
    monkeypatch.setattr(pg, "numba_available", lambda: False)
    # "auto" without numba is the numpy route, exactly.
    y_auto = mc.term_sum_uniform(lam, coef, 0.0, DT, 300)
    assert np.array_equal(y_auto, y_numpy)
    with pytest.raises(PropagationError, match="numba"):
        mc.term_sum_uniform(lam, coef, 0.0, DT, 300, backend="numba")


def test_unknown_backend_is_rejected():
    lam, coef = random_terms(1, seed=0)
    with pytest.raises(PropagationError, match="backend"):
        mc.term_sum_uniform(lam, coef, 0.0, DT, 10, backend="fortran")


def test_closed_form_response_backends_agree():
    # The whole closed form (terms, band, compaction) with either route.
    pytest.importorskip("numba")
    rng = np.random.default_rng(5)
    B, m = 6, 8
    omega = np.sort(rng.uniform(50.0, 2000.0, (B, m)), axis=1)
    c = 0.02 * omega + 2e-6 * omega**2  # viscous + Kelvin–Voigt: high modes overdamped
    q0, v0 = rng.standard_normal((B, m)), rng.standard_normal((B, m))
    s = rng.standard_normal(m)
    kw = dict(uniform=(0.05, DT, 2000), w_band=1500.0)
    y1, ok1 = mc.closed_form_response(omega, c, q0, v0, s, "velocity", backend="numba", **kw)
    y0, ok0 = mc.closed_form_response(omega, c, q0, v0, s, "velocity", backend="numpy", **kw)
    assert ok1.all() and ok0.all()
    scale = np.abs(y0).max(axis=1, keepdims=True)
    assert (np.abs(y1 - y0) / scale).max() <= TOL


def test_bare_rotations_kernel_in_plain_python():
    # The benchmark's bare loop (plain Python here): Re Σ_j r_j^k, checked against powers.
    rng = np.random.default_rng(2)
    w = rng.uniform(0.0, np.pi, (2, 3))
    rot = np.exp(1j * w)
    n = 2 * BABY + 9
    y = _rotations_kernel_py(rot.real.copy(), rot.imag.copy(), n)
    ref = np.cos(w[:, :, None] * np.arange(n)).sum(axis=1)
    # Doubling and ~n / BABY giant products: a few hundred roundings of unit terms.
    assert np.abs(y - ref).max() <= 1e-12
