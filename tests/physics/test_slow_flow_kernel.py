"""Compiled slow flow (physics.slow_flow_kernel) against the vectorised numpy route.

The numpy route of :class:`~bayesbeam.physics.nonlinear.NonlinearForward` is itself checked
against a direct LSODA integration of the full nonlinear FE system in test_nonlinear.py;
here the compiled route must reproduce it to rounding, on every kind of stamps, sensor
and force, and the kernels' logic is run uncompiled too.
"""

import numpy as np
import pytest

import bayesbeam.physics.nonlinear as nl
import bayesbeam.physics.propagate as pg
from bayesbeam.physics.beam import Beam
from bayesbeam.physics.nonlinear import NonlinearError, NonlinearForward, _sampling_step

L_, W_, T_ = 0.4, 0.0508, 0.002
MASS = 2700 * L_ * W_ * T_
DT = 1 / 512
# Rounding budget of the compiled route against the numpy one, relative to the signal's
# peak: the RK4 sums run in another order (a few ulp of ρ, amplified by at most the
# ~500 steps of the flow) and the exponentials are products of e^{λ dt} re-anchored every
# 32 samples (≤ 32 roundings, ~7e-15): 1e-12 leaves a margin of ~7 over the worst case
# measured (1.4e-13, acceleration with drag).
TOL = 1e-12

needs_numba = pytest.mark.skipif(not pg.numba_available(), reason="numba not installed")


def beam(quantity):
    return Beam.rectangular(L_, W_, T_, MASS, E=70e9, tip_mass=0.01, sensor_position=0.34,
                            quantity=quantity)


def sets(fwd, rng, n=6, **force):
    """Random admissible sets around a lightly damped strip released from 5 mm."""
    base = {"E": 70e9, "gamma": 0.01, "c_d": 2e-5, "w0": 5e-3, **force}
    X = np.array([[base.get(name, 0.0) for name in fwd.param_names]] * n)
    for j, name in enumerate(fwd.param_names):
        if name in ("gamma", "c_d", "drag", "friction", "f1_slope", "w0"):
            X[:, j] *= 1 + 0.3 * rng.uniform(-1, 1, n)
    return X


def both_routes(quantity, model, times, X, **kw):
    y = {}
    for backend in ("numpy", "numba"):
        fwd = NonlinearForward(beam(quantity), model, times, n_elements=8, backend=backend,
                               **kw)
        r = fwd.simulate(X)
        assert r.valid.all()
        y[backend] = r.y
    return y["numpy"], y["numba"]


CASES = [
    ("viscous+kv+drag", {"drag": 0.2}),
    ("viscous+kv+friction", {"friction": 0.02}),  # stops mode 1 inside the record
    ("viscous+kv+amplitude_stiffness", {"f1_slope": -40.0}),
    ("viscous+kv+drag+friction+amplitude_stiffness",
     {"drag": 0.1, "friction": 0.005, "f1_slope": 25.0}),
]


@needs_numba
@pytest.mark.parametrize("quantity", ["displacement", "velocity", "acceleration"])
@pytest.mark.parametrize(("model", "force"), CASES)
def test_compiled_route_matches_numpy_route(quantity, model, force):
    times = DT * np.arange(3000)
    fwd = NonlinearForward(beam(quantity), model, times, n_elements=8)
    X = sets(fwd, np.random.default_rng(3), **force)
    y_np, y_nb = both_routes(quantity, model, times, X)
    peak = np.abs(y_np).max(axis=1, keepdims=True)
    assert (np.abs(y_nb - y_np) / peak).max() <= TOL


@needs_numba
def test_friction_stops_the_mode_in_both_routes():
    # Strong friction brings ρ to 0 inside the record: the compiled interpolation must take
    # the straight line in that step and hold the mode at rest afterwards, as numpy does.
    times = DT * np.arange(3000)
    model = "viscous+kv+friction"
    fwd = NonlinearForward(beam("displacement"), model, times, n_elements=8)
    X = sets(fwd, np.random.default_rng(5), friction=0.05)
    y_np, y_nb = both_routes("displacement", model, times, X)
    peak = np.abs(y_np).max()
    assert np.abs(y_np[:, -500:]).max() < 0.05 * peak  # mode 1 has stopped: only the rest
    assert np.abs(y_nb - y_np).max() <= TOL * peak


@needs_numba
@pytest.mark.parametrize("stamps", ["holes", "jittered"])
def test_compiled_route_on_non_uniform_stamps(stamps):
    # A record resampled around gaps (a uniform grid with holes: products of e^{λ dt}
    # across the grid, an exact exponential after each hole) and stamps off any grid (an
    # exact exponential per sample).
    rng = np.random.default_rng(9)
    times = DT * np.arange(3000)
    if stamps == "holes":
        times = np.delete(times, np.r_[400:460, 1700:1703])
    else:
        times = times + rng.uniform(0, 0.3 * DT, times.size)
    model = "viscous+kv+drag+amplitude_stiffness"
    fwd = NonlinearForward(beam("acceleration"), model, times, t0=0.0, n_elements=8)
    X = sets(fwd, rng, drag=0.15, f1_slope=-30.0)
    y_np, y_nb = both_routes("acceleration", model, times, X, t0=0.0)
    peak = np.abs(y_np).max(axis=1, keepdims=True)
    assert (np.abs(y_nb - y_np) / peak).max() <= TOL


def test_sampling_step_spans_the_grid():
    tau = 0.25 + DT * np.delete(np.arange(1000), np.r_[10:20])
    assert _sampling_step(tau) == pytest.approx(DT, rel=1e-15)
    off = tau + np.random.default_rng(0).uniform(0, 0.1 * DT, tau.size)
    assert _sampling_step(off) == np.min(np.diff(off))
    assert _sampling_step(np.array([0.5])) == 1.0


def test_kernels_logic_in_plain_python(monkeypatch):
    # The kernels are plain Python until numba compiles them: run the compiled route
    # uncompiled on a short record, so that their logic is checked even without numba.
    monkeypatch.setattr(pg, "numba_available", lambda: True)
    monkeypatch.setattr(nl, "compiled_kernel", lambda kernel: kernel)
    times = DT * np.arange(200)
    model = "viscous+kv+drag+friction+amplitude_stiffness"
    fwd = NonlinearForward(beam("velocity"), model, times, n_elements=4, n_modes=2)
    X = sets(fwd, np.random.default_rng(1), n=2, drag=0.3, friction=0.01, f1_slope=40.0)
    y = {}
    for backend in ("numpy", "numba"):
        f = NonlinearForward(beam("velocity"), model, times, n_elements=4, n_modes=2,
                             steps_per_period=4.0, backend=backend)
        y[backend] = f.simulate(X).y
    peak = np.abs(y["numpy"]).max()
    assert np.abs(y["numba"] - y["numpy"]).max() <= TOL * peak


def test_backend_is_checked(monkeypatch):
    times = DT * np.arange(50)
    with pytest.raises(NonlinearError, match="backend"):
        NonlinearForward(beam("displacement"), "viscous+drag", times, backend="fortran")
    monkeypatch.setattr(pg, "numba_available", lambda: False)
    with pytest.raises(NonlinearError, match="numba"):
        NonlinearForward(beam("displacement"), "viscous+drag", times, backend="numba")
    fwd = NonlinearForward(beam("displacement"), "viscous+drag", times)
    assert fwd.backend == "numpy"
