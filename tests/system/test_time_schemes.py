"""Fixed-step schemes of ``march``: observed order against a tight reference of the same
Galerkin system (scipy's Radau or DOP853), and the discrete adjoint of BDF2 against central finite
differences of what the march computes."""

import numpy as np
import pytest
from _models import burgers_like, diffusion
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from ecfm_uq.problems.pendulum import build_pendulum
from ecfm_uq.system import (
    GalerkinSystem,
    NonlinearTerm,
    integrate,
    march,
)


def _reference(system, eps, Theta0, T, mass=1.0, stiff=True):
    """The same Galerkin ODE (M = mass * I, orthonormal basis) by scipy at rtol 1e-13:
    Radau for stiff models (the Jacobian handed to it only speeds its Newton iterations
    up; its answer is set by ``f``), DOP853 for the others."""

    def f(t, y):
        return -system.residual(y.reshape(system.shape), eps, None, t).ravel() / mass

    def jac(t, y):
        return -system.jacobian(y.reshape(system.shape), eps, t) / mass

    kw = dict(method="Radau", jac=jac) if stiff else dict(method="DOP853")
    sol = solve_ivp(f, (0, T), Theta0.ravel(), rtol=1e-13, atol=1e-15, **kw)
    return sol.y[:, -1].reshape(system.shape)


def _linear_exact(system, eps, t, mass=1.0):
    """The exact solution from zero of a linear Galerkin ODE ``y' = A y + b`` (``M = mass * I``,
    orthonormal basis): the last column of :math:`\\exp(t [[A, b], [0, 0]])`."""
    n = system.N * system.P
    A = -system.jacobian(system.zeros(), eps) / mass
    b = -system.residual(system.zeros(), eps).ravel() / mass
    E = np.zeros((n + 1, n + 1))
    E[:n, :n], E[:n, n] = A, b
    return expm(t * E)[:n, n].reshape(system.shape)


def _orders(system, eps, Theta0, T, scheme, ns, ref, **kw):
    errs = []
    for n in ns:
        tr = march(system, eps, Theta0, T / n, n, scheme=scheme, tol=1e-13, **kw)
        assert tr.success and tr.scheme == scheme
        errs.append(np.abs(tr.Theta[-1] - ref).max())
    return np.log2(np.array(errs[:-1]) / errs[1:]), errs


@pytest.mark.parametrize("order", [0, 3])
def test_bdf2_is_second_order_on_a_nonlinear_pendulum(order):
    system, Theta0 = build_pendulum(order=order)
    eps, T = [4.0], 2.0
    ref = _reference(system, eps, Theta0, T, stiff=False)
    ns = (20, 40, 80, 160)
    p2, e2 = _orders(system, eps, Theta0, T, "bdf2", ns, ref)
    p1, e1 = _orders(system, eps, Theta0, T, "euler", ns, ref)
    assert p2[-1] >= 1.9 and p2.min() >= 1.8
    assert 0.9 <= p1[-1] <= 1.1
    assert e2[-1] < e1[-1] / 20


@pytest.mark.parametrize("order", [0, 2])
def test_bdf2_is_second_order_with_a_quadratic_term(order):
    system = burgers_like(order)
    eps, T = [1.0], 0.5
    Theta0 = np.zeros(system.shape)
    ref = _reference(system, eps, Theta0, T)
    p2, _ = _orders(system, eps, Theta0, T, "bdf2", (10, 20, 40, 80), ref)
    assert p2[-1] >= 1.9


def test_bdf2_is_second_order_on_sparse_diffusion_with_krylov_solves():
    system, _ = diffusion(N=30, dim=2, order=2, sparse=True)
    eps, T = [0.0, 1.0], 0.02
    Theta0 = np.zeros(system.shape)
    ref = _linear_exact(system, eps, T, mass=1.0 / 31)
    p2, _ = _orders(system, eps, Theta0, T, "bdf2", (10, 20, 40), ref, solver="cg")
    assert p2[-1] >= 1.9


@pytest.mark.parametrize("order", [0, 2])
def test_the_compiled_bdf2_march_equals_the_generic_one(order):
    system = burgers_like(order)
    args = (system, [1.2], np.zeros(system.shape), 0.05, 12)
    kw = dict(scheme="bdf2", sensitivities=True, tol=1e-12)
    fast = march(*args, **kw)
    slow = march(*args, solver={"compiled": False}, **kw)
    assert fast.plan.path == ("compiled-p1" if order == 0 else "compiled-sg")
    assert slow.plan.path == "generic" and "compiled=False" in slow.plan.reason
    np.testing.assert_allclose(fast.Theta, slow.Theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.dTheta, slow.dTheta, rtol=0, atol=1e-9)
    if order == 0:  # the P = 1 kernel keeps its factors: its adjoint is BDF2's too
        fast = march(*args, keep_factors=True, **kw)
        slow = march(*args, keep_factors=True, solver={"compiled": False}, **kw)
        g = fast.Theta**2
        np.testing.assert_allclose(fast.adjoint_gradient(g), slow.adjoint_gradient(g), rtol=1e-12)


def test_integrate_says_why_it_runs_on_the_generic_path():
    system = burgers_like(0)
    tr = integrate(system, [1.0], np.zeros(system.N), [0.0, 0.5])
    assert tr.plan.path == "generic" and "fixed-step schemes only" in tr.plan.reason
    with pytest.raises(ValueError, match="fixed-step schemes only"):
        integrate(system, [1.0], np.zeros(system.N), [0.0, 0.5], solver={"compiled": True})


def _fd_check(objective, eps, h):
    """Central differences of ``objective`` (returns (z, trajectory)) per parameter."""
    out = []
    for m in range(len(eps)):
        e = np.zeros(len(eps))
        e[m] = h
        out.append((objective(eps + e)[0] - objective(eps - e)[0]) / (2 * h))
    return np.array(out)


def test_bdf2_adjoint_equals_sensitivities_and_central_differences_on_the_pendulum():
    system, Theta0 = build_pendulum(order=3)

    def objective(eps):
        tr = march(system, eps, Theta0, 0.05, 40, scheme="bdf2", tol=1e-13,
                   sensitivities=True, keep_factors=True)  # fmt: skip
        return 0.5 * np.sum(tr.Theta**2), tr

    eps = np.array([4.0])
    _, tr = objective(eps)
    g = tr.adjoint_gradient(tr.Theta)
    forward = np.einsum("tnp,tnpe->e", tr.Theta, tr.dTheta)
    np.testing.assert_allclose(g, forward, rtol=1e-10)
    np.testing.assert_allclose(g, _fd_check(objective, eps, 1e-5), rtol=1e-6)


@pytest.mark.parametrize("solver", ["dense", "auto"])
def test_bdf2_adjoint_of_the_ecfm_constraint_equals_central_differences(solver):
    system, M_obs = diffusion(N=20, dim=2, order=2, sparse=True)
    n, dt = 12, 0.01
    V = 0.05 * np.outer(np.sin(np.linspace(0, 2, n + 1)), [1.0, 0.8, 0.6])

    def objective(eps):
        tr = march(system, eps, np.zeros(20), dt, n, scheme="bdf2", constraint=(M_obs, V),
                   keep_factors=True, sensitivities=True, tol=1e-13, solver=solver)  # fmt: skip
        return float(np.sum(tr.lam**2) + np.sum(tr.Theta**2)), tr

    eps = np.array([0.1, 1.3])
    _, tr = objective(eps)
    g = tr.adjoint_gradient(2 * tr.Theta, 2 * tr.lam)
    forward = np.einsum("tnp,tnpe->e", 2 * tr.Theta, tr.dTheta) + np.einsum(
        "tc,tce->e", 2 * tr.lam, tr.dlam
    )
    np.testing.assert_allclose(g, forward, rtol=1e-8)
    np.testing.assert_allclose(g, _fd_check(objective, eps, 1e-4), rtol=1e-6)


def test_bdf2_adjoint_with_a_quadratic_term_and_P_above_one():
    system = burgers_like(2)
    Theta0 = np.zeros(system.shape)

    def objective(eps):
        tr = march(system, eps, Theta0, 0.05, 12, scheme="bdf2", keep_factors=True, tol=1e-13)
        return float(np.sum(tr.Theta[:, :, 0] ** 3)), tr

    eps = np.array([1.5])
    _, tr = objective(eps)
    g_theta = np.zeros_like(tr.Theta)
    g_theta[:, :, 0] = 3 * tr.Theta[:, :, 0] ** 2
    np.testing.assert_allclose(
        tr.adjoint_gradient(g_theta), _fd_check(objective, eps, 1e-5), rtol=1e-6
    )


def test_an_unknown_scheme_is_refused_with_the_choices():
    system = burgers_like(0)
    with pytest.raises(ValueError, match="`scheme` must be one of \\('euler', 'bdf2'\\)"):
        march(system, [1.0], np.zeros(system.N), 0.1, 3, scheme="rk4")


def test_a_failing_bdf2_step_returns_the_steps_before_it():
    # u' = u^2 from u(0) = 1 blows up at t = 1: Newton cannot solve a step past it
    blowup = NonlinearTerm(lambda u, w, e: -(u**2), lambda u, w, e: np.diag(-2 * u),
                           eps_jacobian=lambda u, w, e: np.zeros((1, 1)), size=1)  # fmt: skip
    system = GalerkinSystem([blowup], 1, M=np.eye(1))
    tr = march(system, [0.0], np.ones(1), 0.05, 40, scheme="bdf2", maxiter=8)
    assert not tr.success and "Newton failed at step" in tr.message
    # the implicit step u - (2/3) dt u^2 = psi has no real root once psi > 3 / (8 dt)
    k = tr.failed_step
    assert 0.5 <= tr.times[-1] < 1.0 and len(tr.Theta) == len(tr.times) == k
    assert np.all(np.isfinite(tr.Theta)) and np.all(np.diff(tr.Theta[:, 0, 0]) > 0)
    assert f"t={k * 0.05:.6g}" in tr.message
