"""``Forward.simulate_basis``: the responses to each amplitude alone, one reduction shared.

The reference is independent of the shared path: one :meth:`Forward.simulate` per
amplitude, at that amplitude 1 and the others 0, each running its own modal system, band
reduction and propagation. Superposition (the signal is linear in the initial state) is
checked on top: the basis combined with the sets' own amplitudes is their signal.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.physics.beam import Beam
from bayesbeam.physics.forward import Forward, ForwardError

L, W, TH, RHO, E = 0.5, 0.02, 2e-3, 2700.0, 70e9


def _beam() -> Beam:
    return Beam.rectangular(length=L, width=W, thickness=TH, mass=L * W * TH * RHO,
                            E=E).replace(quantity="acceleration")


def _sets(fwd: Forward, rng: np.random.Generator, n: int = 5) -> np.ndarray:
    """Parameter sets around an aluminium strip with a few grams attached (SI)."""
    base = {"E": E, "gamma": 0.1, "c_d": 3e6, "a": 2e-3, "b": 0.05, "added_mass": 4e-3,
            "added_mass_position": 0.8 * L, "w0": 5e-3, "A1": 2.0, "B1": -1.0, "A2": 0.5,
            "B2": 0.3, "A3": -0.1, "B3": 0.05}
    cols = []
    for name in fwd.param_names:
        v = base[name] * rng.uniform(0.8, 1.2, n)
        cols.append(v)
    return np.column_stack(cols)


def _one_by_one(fwd: Forward, theta: np.ndarray, columns: list[int]) -> np.ndarray:
    out = []
    for j in columns:
        th = theta.copy()
        th[:, columns] = 0.0
        th[:, j] = 1.0
        res = fwd.simulate(th)
        assert res.valid.all()
        out.append(res.y)
    return np.stack(out, axis=-1)


CASES = [
    # (model, initial, bandwidth, stamps): a point mass couples the viscous damping
    # (the band's invariant-subspace reduction); SH couples every mode; no band: the
    # full propagation; a lead time and stamps with a hole: the other grids.
    ("viscous+kv+added_mass", "modes:3", 150.0, "uniform"),
    ("viscous+sh", "modes:2", 150.0, "uniform"),
    ("viscous+kv+added_mass", "modes:2", None, "uniform"),
    ("viscous+kv+added_mass", "modes:2", 150.0, "holes"),
    ("viscous+kv", "modes:3", 150.0, "uniform"),  # classical: the closed form
    ("viscous+kv+added_mass", "release", 150.0, "uniform"),  # one amplitude
]


@pytest.mark.parametrize(("model", "initial", "band", "stamps"), CASES)
def test_basis_is_each_amplitude_alone(model, initial, band, stamps):
    t = np.arange(1024) / 512.0
    if stamps == "holes":
        t = np.delete(t, np.s_[300:340]) + 0.0123  # a gap, and a lead time from t0 = 0
    fwd = Forward(_beam(), model, t, n_elements=10, initial=initial, bandwidth=band,
                  t0=0.0 if stamps == "holes" else None)
    theta = _sets(fwd, np.random.default_rng(3))
    columns = [j for j, n in enumerate(fwd.param_names) if n == "w0" or n[0] in "AB"]
    basis = fwd.simulate_basis(theta, columns)
    ref = _one_by_one(fwd, theta, columns)
    assert basis.valid.all()
    assert basis.y.shape == (theta.shape[0], t.size, len(columns))
    # 1e-10 of each response's peak: the shared and the separate runs differ only by
    # the rounding of the reduction's iteration (stopped at 1e-12) and the stepping.
    peak = np.max(np.abs(ref), axis=1, keepdims=True)
    assert np.max(np.abs(basis.y - ref) / peak) <= 1e-10
    # Superposition: the sets' own amplitudes on the basis give their signal.
    direct = fwd.simulate(theta)
    combined = np.einsum("btp,bp->bt", basis.y, theta[:, columns])
    assert np.max(np.abs(combined - direct.y)) <= 1e-9 * np.max(np.abs(direct.y))


def test_invalid_sets_are_flagged_not_raised():
    t = np.arange(512) / 512.0
    fwd = Forward(_beam(), "viscous+kv+added_mass", t, n_elements=10, initial="modes:2",
                  bandwidth=150.0)
    theta = _sets(fwd, np.random.default_rng(4), n=4)
    theta[1, fwd.param_names.index("E")] = -1.0  # inadmissible
    theta[2, fwd.param_names.index("added_mass_position")] = 2 * L  # off the span
    columns = [j for j, n in enumerate(fwd.param_names) if n[0] in "AB"]
    res = fwd.simulate_basis(theta, columns)
    assert res.valid.tolist() == [True, False, False, True]
    assert np.all(res.y[~res.valid] == 0.0) and np.all(np.isfinite(res.y))


def test_a_column_that_is_not_an_amplitude_is_refused():
    fwd = Forward(_beam(), "viscous+kv", np.arange(64) / 512.0, n_elements=6)
    with pytest.raises(ForwardError, match="not amplitudes"):
        fwd.simulate_basis(np.ones((1, len(fwd.param_names))), [0])


def test_no_amplitude_gives_an_empty_basis():
    fwd = Forward(_beam(), "viscous+kv+added_mass", np.arange(64) / 512.0, n_elements=6)
    theta = _sets(fwd, np.random.default_rng(5), n=3)
    res = fwd.simulate_basis(theta, [])
    assert res.y.shape == (3, 64, 0) and res.valid.shape == (3,) and res.valid.all()
