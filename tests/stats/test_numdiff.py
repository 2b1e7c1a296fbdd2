"""Finite differences against analytic derivatives: O(h²) convergence, exactness, bounds."""

import numpy as np
import pytest

from bayesbeam.stats.numdiff import fd_gradient, fd_hessian

A = np.array([0.7, -1.3, 2.1])


def f(U):
    """Smooth test function with all third and fourth derivatives non-zero."""
    U = np.atleast_2d(U)
    return np.sin(A @ U.T) + U[:, 0] * U[:, 1] ** 2 + np.exp(0.5 * U[:, 2]) * U[:, 0]


def grad_f(u):
    c = np.cos(A @ u)
    return c * A + np.array([u[1] ** 2 + np.exp(0.5 * u[2]), 2 * u[0] * u[1],
                             0.5 * np.exp(0.5 * u[2]) * u[0]])


def hess_f(u):
    H = -np.sin(A @ u) * np.outer(A, A)
    e = np.exp(0.5 * u[2])
    H += np.array([[0.0, 2 * u[1], 0.5 * e],
                   [2 * u[1], 2 * u[0], 0.0],
                   [0.5 * e, 0.0, 0.25 * e * u[0]]])
    return H


U0 = np.array([0.3, -0.8, 0.5])


def slope(errors, steps):
    """Log-log slope of the error against the step (least squares)."""
    return np.polyfit(np.log(steps), np.log(errors), 1)[0]


# Steps where truncation (~h² |f'''| ~ 1e-4..1e-6) dominates rounding (~eps/h² < 1e-9):
# the error must then fall as h², a slope of 2 (within 0.1 for these smooth terms).
STEPS = np.array([2e-2, 1e-2, 5e-3, 2.5e-3])


def test_gradient_converges_at_second_order():
    errs = [np.max(np.abs(fd_gradient(f, U0, h)[1] - grad_f(U0))) for h in STEPS]
    assert slope(errs, STEPS) == pytest.approx(2.0, abs=0.1)
    v, g = fd_gradient(f, U0, 1e-5)
    assert v == f(U0)[0]
    # h = 1e-5: truncation h²/6 |f'''| ~ 1e-10, rounding eps |f| / h ~ 1e-11.
    np.testing.assert_allclose(g, grad_f(U0), rtol=0, atol=1e-9)


@pytest.mark.parametrize("stencil", ["axes", "corners"])
def test_hessian_converges_at_second_order(stencil):
    errs = [np.max(np.abs(fd_hessian(f, U0, h, stencil=stencil)[2] - hess_f(U0)))
            for h in STEPS]
    assert slope(errs, STEPS) == pytest.approx(2.0, abs=0.1)
    # Per-coordinate steps: h = 1e-3 gives truncation ~h²/6 |f''''| ~ 1e-6 and rounding
    # ~4 eps |f| / h² ~ 1e-9.
    h = np.array([1e-3, 2e-3, 5e-4])
    v, g, H = fd_hessian(f, U0, h, stencil=stencil)
    assert v == f(U0)[0]
    np.testing.assert_allclose(H, hess_f(U0), rtol=0, atol=1e-5)
    np.testing.assert_allclose(g, grad_f(U0), rtol=0, atol=1e-5)
    assert np.array_equal(H, H.T)


def test_quadratic_is_exact_to_rounding():
    # Third and higher derivatives vanish: only rounding remains, at most about
    # 4 eps max|f| / h² per Hessian entry (here ~1e-8) and eps max|f| / h per gradient.
    rng = np.random.default_rng(3)
    M = rng.standard_normal((4, 4))
    P = M @ M.T
    b = rng.standard_normal(4)

    def q(U):
        return -0.5 * np.einsum("ki,ij,kj->k", U, P, U) + U @ b

    u, h = rng.standard_normal(4), 1e-3
    fmax = np.max(np.abs(q(u + 2 * h * np.array(np.meshgrid(*[[-1, 1]] * 4)).reshape(4, -1).T)))
    eps = np.finfo(float).eps
    for stencil in ("axes", "corners"):
        _, g, H = fd_hessian(q, u, h, stencil=stencil)
        np.testing.assert_allclose(H, -P, rtol=0, atol=8 * eps * fmax / h**2)
        np.testing.assert_allclose(g, b - P @ u, rtol=0, atol=4 * eps * fmax / h)


def test_one_batched_call_with_the_documented_stencil_sizes():
    calls = []

    def counted(U):
        calls.append(U.shape)
        return f(U)

    d = U0.size
    fd_gradient(counted, U0, 1e-4)
    fd_hessian(counted, U0, 1e-3)
    fd_hessian(counted, U0, 1e-3, stencil="corners")
    assert calls == [(2 * d + 1, d), (2 * d * d + 1, d), (2 * d * (d + 1) + 1, d)]
    _, g, H = fd_hessian(lambda U: np.sin(U[:, 0]), np.array([0.2]), 1e-3)
    assert H.shape == (1, 1) and g.shape == (1,)


def test_one_sided_gradient_on_a_bound():
    # Support u0 >= 0 (e.g. a correlation on its lower bound): the central difference
    # is -inf there; the one-sided one is the forward difference, first order:
    # error <= h/2 max|f''| = h/2 (f'' = -sin(u0 + 1) in u0, |.| <= 1).
    def g(U):
        val = np.sin(U[:, 0] + 1.0) + U[:, 1] ** 2
        return np.where(U[:, 0] >= 0, val, -np.inf)

    u, h = np.array([0.0, 0.4]), 1e-6
    _, central = fd_gradient(g, u, h)
    assert central[0] == np.inf and central[1] == pytest.approx(0.8, abs=1e-8)
    _, grad = fd_gradient(g, u, h, one_sided=True)
    assert grad[0] == pytest.approx(np.cos(1.0), abs=h / 2 + 1e-9)
    assert grad[1] == central[1]
    # Both sides outside: 0 (the optimiser gets no push from that coordinate).
    _, grad = fd_gradient(lambda U: np.where(np.abs(U[:, 0]) < 1e-9, 0.0, -np.inf),
                          np.array([0.0]), 1e-6, one_sided=True)
    assert grad[0] == 0.0


def test_invalid_input_raises():
    with pytest.raises(ValueError, match="stencil"):
        fd_hessian(f, U0, 1e-3, stencil="star")
    with pytest.raises(ValueError, match="positive"):
        fd_gradient(f, U0, 0.0)
    with pytest.raises(ValueError, match="positive"):
        fd_hessian(f, U0, np.array([1e-3, -1e-3, 1e-3]))
    with pytest.raises(ValueError, match="1-D"):
        fd_gradient(f, np.zeros((2, 2)), 1e-3)
