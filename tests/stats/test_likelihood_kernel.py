"""The AR(1) likelihood's kernel: its plain-Python logic, and the compiled route against numpy."""

import numpy as np
import pytest

from bayesbeam.stats import likelihood as lik
from bayesbeam.stats.likelihood import ar1_loglik
from bayesbeam.stats.likelihood_kernel import _ar1_sum_py


def _gappy_times(rng, T):
    # Unit steps with some double and triple ones: three distinct lags.
    return np.cumsum(rng.choice([1.0, 2.0, 3.0], size=T, p=[0.9, 0.07, 0.03])) * 1e-3


def test_kernel_is_the_weighted_sum_of_squared_innovations():
    rng = np.random.default_rng(0)
    B, T, K = 3, 50, 3
    r = rng.standard_normal((B, T))
    phi, w = rng.uniform(0, 0.9, (B, K)), rng.uniform(1, 3, (B, K))
    index = rng.integers(0, K, T - 1)
    expected = [sum(w[b, index[t - 1]] * (r[b, t] - phi[b, index[t - 1]] * r[b, t - 1]) ** 2
                    for t in range(1, T)) for b in range(B)]
    np.testing.assert_allclose(_ar1_sum_py(r, phi, w, index), expected, rtol=1e-13)


def _cases(rng):
    T = 400
    r = rng.standard_normal((4, T))
    t = _gappy_times(rng, T)
    sig, rho = rng.uniform(0.5, 2, 4), rng.uniform(0.1, 0.95, 4)
    yield "uniform", (r, sig, rho), {}
    yield "gaps", (r, sig, rho), {"times": t}
    yield "one series", (r[0], 1.3, 0.7), {"times": t}
    # one residual series scored under five parameter sets (sigma, rho widen the batch)
    yield "broadcast", (r[0], np.linspace(0.5, 2, 5), np.linspace(0.1, 0.9, 5)), {"times": t}
    yield "outside support", (r, np.array([1.0, -1.0, 1.0, 1.0]),
                              np.array([0.5, 0.5, 1.0, -0.2])), {"times": t}


@pytest.mark.parametrize("case", ["uniform", "gaps", "one series", "broadcast", "outside support"])
def test_compiled_route_matches_the_numpy_route(case, monkeypatch):
    if lik.compiled_kernel(_ar1_sum_py) is None:
        pytest.skip("numba is not importable here: only the numpy route runs")
    args, kw = dict((n, (a, k)) for n, a, k in _cases(np.random.default_rng(1)))[case]
    compiled = ar1_loglik(*args, **kw)
    monkeypatch.setattr(lik, "compiled_kernel", lambda *a, **k: None)
    numpy_route = ar1_loglik(*args, **kw)
    assert compiled.shape == numpy_route.shape
    # Same terms summed in another order: rounding of a sum of T = 400 terms of O(1).
    np.testing.assert_allclose(compiled, numpy_route, rtol=1e-12, atol=0)
    assert np.array_equal(np.isinf(compiled), np.isinf(numpy_route))
