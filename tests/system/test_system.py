"""The Galerkin system and its solvers against independent truth: hand-written Newton,
Gauss collocation of deterministic solves, finite differences (Taylor tests)."""

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness, triple
from ecfm_uq.system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    QuadraticTerm,
    march,
    solve_continuation,
    solve_steady,
)

N = 8
B = SineBasis(N)
M = mass(B)
K = stiffness(B)
A = triple(B, (0, 0, 1))
F1 = load(B, lambda x: np.sin(np.pi * x) + x)
SENSORS = np.array([0.25, 0.5, 0.75])
M_OBS = sensor_matrix(B, SENSORS)
GAMMA = hat_forces(B, SENSORS, 0.25)


def burgers_like(basis=None, G=None):
    """Steady viscous Burgers-type system with nu = 10^-eps0 and source scale eps1."""
    terms = [
        LinearTerm(K, Coefficient.power10(0), G=G),
        QuadraticTerm(A),
        LoadTerm.scaled(F1, Coefficient.parameter(1)),
    ]
    return GalerkinSystem(terms, 2, basis=basis, Gamma=GAMMA, M=M, name="burgers-like")


def plain_newton(eps, lam=None):
    """Independent dense Newton for R = nu K th + A:th th - e2 F - Gamma lam."""
    lam = np.zeros(3) if lam is None else lam
    nu = 10 ** -eps[0]
    th = np.zeros(N)
    for _ in range(50):
        r = nu * K @ th + np.einsum("ijk,j,k->i", A, th, th) - eps[1] * F1 - GAMMA @ lam
        if np.linalg.norm(r) < 1e-13:
            break
        J = nu * K + np.einsum("ijk,k->ij", A, th) + np.einsum("ikj,k->ij", A, th)
        th = th - np.linalg.solve(J, r)
    return th


EPS = np.array([0.5, 2.0])


def test_deterministic_solve_matches_plain_newton():
    sol = solve_steady(burgers_like(), EPS)
    assert sol.success
    np.testing.assert_allclose(sol.Theta[:, 0], plain_newton(EPS), atol=1e-12)


def test_order_zero_chaos_equals_deterministic_to_roundoff():
    det = solve_steady(burgers_like(), EPS)
    chaos = solve_steady(burgers_like(basis=ChaosBasis(0)), EPS)
    assert chaos.Theta.shape == (N, 1)
    np.testing.assert_allclose(chaos.Theta, det.Theta, atol=1e-14, rtol=0)


def test_forces_enter_as_minus_gamma_lambda():
    lam = np.array([0.3, -0.2, 0.1])
    sol = solve_steady(burgers_like(), EPS, lam)
    np.testing.assert_allclose(sol.Theta[:, 0], plain_newton(EPS, lam), atol=1e-12)


def _stochastic_system(order):
    # viscosity 10^-(eps0 + 0.5 w), w ~ U(0,1): random coefficient through E[g Psi Psi]
    basis = ChaosBasis(order)
    G = weighted_gram(basis, lambda w: 10.0 ** (-0.5 * w))
    return burgers_like(basis=basis, G=G), basis


def test_galerkin_moments_converge_to_collocation_of_deterministic_solves():
    from ecfm_uq.chaos import gauss_legendre

    nodes, weights = gauss_legendre(24)
    samples = []
    for w in nodes:
        e = np.array([EPS[0] + 0.5 * w, EPS[1]])
        samples.append(plain_newton(e))
    samples = np.array(samples)
    mean_ref = weights @ samples
    var_ref = weights @ (samples - mean_ref) ** 2
    errs = []
    for order in (1, 3, 6):
        system, _ = _stochastic_system(order)
        sol = solve_steady(system, EPS)
        assert sol.success
        mean = system.mean(sol.Theta)
        var = np.diag(system.covariance(sol.Theta))
        errs.append(
            (
                np.abs(mean - mean_ref).max() / np.abs(mean_ref).max(),
                np.abs(var - var_ref).max() / np.abs(var_ref).max(),
            )
        )
    errs = np.array(errs)
    # spectral convergence in the chaos order for a smooth (analytic) dependence on w
    assert errs[-1, 0] < 1e-6 and errs[-1, 1] < 1e-4
    assert np.all(np.diff(errs[:, 0]) < 0) and np.all(np.diff(errs[:, 1]) < 0)


def _fd_jacobian(f, x, h=1e-6):
    cols = []
    for m in range(x.size):
        e = np.zeros_like(x)
        e[m] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.array(cols).T


@pytest.mark.parametrize("order", [0, 3])
def test_jacobians_against_central_differences(order):
    system, _ = (burgers_like(), None) if order == 0 else _stochastic_system(order)
    rng = np.random.default_rng(1)
    Theta = rng.normal(size=system.shape)
    J = system.jacobian(Theta, EPS)
    Jfd = _fd_jacobian(
        lambda z: system.residual(z.reshape(system.shape), EPS).ravel(), Theta.ravel()
    )
    np.testing.assert_allclose(J, Jfd, atol=1e-6 * np.abs(J).max())
    D = system.eps_jacobian(Theta, EPS)
    Dfd = _fd_jacobian(lambda e: system.residual(Theta, e).ravel(), EPS)
    np.testing.assert_allclose(D, Dfd, atol=1e-6 * np.abs(D).max())


def _taylor_orders(f, df, x, direction, hs):
    """Remainder |f(x + h d) - f(x) - h df d| for each h; should fall like h^2."""
    f0 = f(x)
    rem = [np.linalg.norm(f(x + h * direction) - f0 - h * df @ direction) for h in hs]
    return np.log(rem[0] / rem[-1]) / np.log(hs[0] / hs[-1])


HS = np.array([1e-2, 5e-3, 2.5e-3])
DIR = np.array([0.6, -0.8])


@pytest.mark.parametrize("order", [0, 2])
def test_steady_eps_sensitivity_taylor(order):
    system, _ = (burgers_like(), None) if order == 0 else _stochastic_system(order)
    sol = solve_steady(system, EPS)
    dTheta, dlam = sol.eps_sensitivity()
    assert dlam is None
    f = lambda e: solve_steady(system, e).Theta.ravel()
    rate = _taylor_orders(f, dTheta.reshape(-1, 2), EPS, DIR, HS)
    assert rate > 1.9


def test_steady_lam_sensitivity_taylor():
    system, _ = _stochastic_system(2)
    lam = np.array([0.2, 0.1, -0.3])
    sol = solve_steady(system, EPS, lam)
    dL = sol.lam_sensitivity().reshape(-1, 3)
    f = lambda lm: solve_steady(system, EPS, lm).Theta.ravel()
    rate = _taylor_orders(f, dL, lam, np.array([1.0, -0.5, 0.2]), HS)
    assert rate > 1.9


def test_constrained_solve_hits_data_and_forces_have_taylor_sensitivity():
    system = burgers_like()
    v = M_OBS @ plain_newton(np.array([0.4, 1.5]))
    sol = solve_steady(system, EPS, constraint=(M_OBS, v))
    assert sol.success and sol.constrained
    np.testing.assert_allclose(M_OBS @ sol.Theta[:, 0], v, atol=1e-12)
    # the forces reproduce the state through the unconstrained solve
    np.testing.assert_allclose(solve_steady(system, EPS, sol.lam).Theta, sol.Theta, atol=1e-11)
    _, dlam = sol.eps_sensitivity()
    f = lambda e: solve_steady(system, e, constraint=(M_OBS, v)).lam
    assert _taylor_orders(f, dlam, EPS, DIR, HS) > 1.9


def test_consistent_data_needs_zero_force():
    system = burgers_like()
    v = M_OBS @ plain_newton(EPS)
    sol = solve_steady(system, EPS, constraint=(M_OBS, v))
    assert np.abs(sol.lam).max() < 1e-10


def _unsteady():
    Ft = lambda t: F1 * np.cos(2 * np.pi * t)
    terms = [
        LinearTerm(K, Coefficient.power10(0)),
        QuadraticTerm(A),
        LoadTerm.scaled(Ft, Coefficient.parameter(1)),
    ]
    return GalerkinSystem(terms, 2, Gamma=GAMMA, M=M, name="unsteady")


TH0 = np.linspace(1, 0.2, N) * 0.3


def test_march_sensitivities_taylor():
    system = _unsteady()
    tr = march(system, EPS, TH0, 0.05, 10, sensitivities=True)
    assert tr.success and tr.nit.max() <= 6
    dT = tr.dTheta.reshape(tr.Theta.shape[0], -1, 2).reshape(-1, 2)
    f = lambda e: march(system, e, TH0, 0.05, 10).Theta.ravel()
    assert _taylor_orders(f, dT, EPS, DIR, HS) > 1.9


def test_march_with_data_constraint_tracks_data_and_sensitivities():
    system = _unsteady()
    true = march(system, np.array([0.3, 1.0]), TH0, 0.05, 10)
    V = np.einsum("cn,tn->tc", M_OBS, true.Theta[:, :, 0])
    tr = march(system, EPS, TH0, 0.05, 10, constraint=(M_OBS, V), sensitivities=True)
    assert tr.success
    np.testing.assert_allclose(
        np.einsum("cn,tn->tc", M_OBS, tr.Theta[:, :, 0])[1:], V[1:], atol=1e-11
    )
    f = lambda e: march(system, e, TH0, 0.05, 10, constraint=(M_OBS, V)).lam.ravel()
    dl = tr.dlam.reshape(-1, 2)
    assert _taylor_orders(f, dl, EPS, DIR, HS) > 1.9
    # consistent parameters need no force
    tr_true = march(system, np.array([0.3, 1.0]), TH0, 0.05, 10, constraint=(M_OBS, V))
    assert np.abs(tr_true.lam).max() < 1e-9


def test_backward_euler_matches_independent_implementation():
    system = _unsteady()
    dt, steps = 0.05, 5
    tr = march(system, EPS, TH0, dt, steps)
    th = TH0.copy()
    nu = 10 ** -EPS[0]
    for s in range(steps):
        t1 = (s + 1) * dt
        prev = th.copy()
        for _ in range(30):
            r = (
                M @ (th - prev) / dt
                + nu * K @ th
                + np.einsum("ijk,j,k->i", A, th, th)
                - EPS[1] * F1 * np.cos(2 * np.pi * t1)
            )
            if np.linalg.norm(r) < 1e-13:
                break
            J = M / dt + nu * K + np.einsum("ijk,k->ij", A, th) + np.einsum("ikj,k->ij", A, th)
            th = th - np.linalg.solve(J, r)
    np.testing.assert_allclose(tr.Theta[-1, :, 0], th, atol=1e-12)


def test_newton_failure_is_reported_with_step_and_residual():
    system = _unsteady()
    tr = march(system, EPS, TH0, 0.05, 10, maxiter=1, tol=1e-14)
    assert not tr.success
    assert tr.failed_step == 1
    assert "step 1" in tr.message and "||R||" in tr.message
    assert tr.Theta.shape[0] == 1 and np.all(np.isfinite(tr.Theta))
    with pytest.raises(ConvergenceError, match="step 1"):
        march(system, EPS, TH0, 0.05, 10, maxiter=1, tol=1e-14, strict=True)
    sol = solve_steady(burgers_like(), EPS, maxiter=1, tol=1e-14)
    assert not sol.success and "1 iterations" in sol.message
    with pytest.raises(ConvergenceError):
        sol.eps_sensitivity()


def test_singular_jacobian_is_reported():
    system = GalerkinSystem([LinearTerm(np.zeros((2, 2))), LoadTerm.constant([1.0, 1.0])], 0)
    sol = solve_steady(system, [])
    assert not sol.success and "singular" in sol.message


def test_bad_input_names_the_argument():
    system = burgers_like()
    with pytest.raises(ValueError, match="eps"):
        solve_steady(system, [1.0])
    with pytest.raises(ValueError, match="eps"):
        solve_steady(system, [np.nan, 1.0])
    with pytest.raises(ValueError, match="lam"):
        solve_steady(system, EPS, [1.0])
    with pytest.raises(ValueError, match="v"):
        solve_steady(system, EPS, constraint=(M_OBS, np.ones(2)))
    with pytest.raises(ValueError, match="dt"):
        march(_unsteady(), EPS, TH0, -0.1, 3)
    with pytest.raises(ValueError, match="Theta0"):
        march(_unsteady(), EPS, np.ones(3), 0.1, 3)
    with pytest.raises(ValueError, match="V|v"):
        march(_unsteady(), EPS, TH0, 0.1, 3, constraint=(M_OBS, np.ones((3, 3))))
    no_gamma = GalerkinSystem([LinearTerm(K), LoadTerm.constant(F1)], 0)
    with pytest.raises(ValueError, match="Gamma"):
        solve_steady(no_gamma, [], constraint=(M_OBS, np.ones(3)))
    with pytest.raises(ValueError, match="lam"):
        solve_steady(no_gamma, [], [1.0])
    with pytest.raises(ValueError, match="mass"):
        march(no_gamma, [], np.zeros(N), 0.1, 2)
    with pytest.raises(TypeError, match="coef"):
        LinearTerm(K, coef="x")
    with pytest.raises(ValueError, match="N"):
        GalerkinSystem([LinearTerm(K), LinearTerm(np.eye(3))], 0)


def _linear_stochastic(order, second_germ_power=1):
    basis = ChaosBasis(order)
    G1 = weighted_gram(basis, lambda w: w**second_germ_power)
    terms = [
        LinearTerm(K, Coefficient.power10(0, sign=1.0)),
        LinearTerm(M, coef=Coefficient.parameter(1), G=G1),
        LoadTerm.constant(F1),
    ]
    return GalerkinSystem(terms, 2, basis=basis, Gamma=GAMMA)


def test_affine_germ_system_decouples_and_matches_the_dense_block_solve():
    system = _linear_stochastic(5)
    assert system.decoupling() is not None
    lam = np.array([0.1, -0.2, 0.3])
    fast = solve_steady(system, EPS, lam)
    dense = solve_steady(system, EPS, lam, structure="dense")
    assert fast.success and "decoupled" in fast.message
    np.testing.assert_allclose(fast.Theta, dense.Theta, atol=1e-12 * np.abs(dense.Theta).max())
    for a, b in zip(fast.eps_sensitivity()[0:1], dense.eps_sensitivity()[0:1], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-11 * np.abs(b).max())
    np.testing.assert_allclose(
        fast.lam_sensitivity(), dense.lam_sensitivity(), atol=1e-11, rtol=1e-10
    )


def test_decoupled_solve_is_gauss_collocation():
    # Galerkin of order p with an affine germ == collocation at the p + 1 Gauss nodes
    from ecfm_uq.chaos import gauss_legendre

    order = 4
    system = _linear_stochastic(order)
    sol = solve_steady(system, EPS)
    nodes, weights = gauss_legendre(order + 1)
    th = np.array([np.linalg.solve(10 ** EPS[0] * K + EPS[1] * w * M, F1) for w in nodes])
    Psi = system.basis.evaluate(nodes)
    np.testing.assert_allclose(sol.Theta, (th.T * weights) @ Psi, atol=1e-12)


def test_non_commuting_couplings_fall_back_to_dense():
    # E[w Psi Psi] and E[w^2 Psi Psi] commute only up to truncation; w^2 and the Jacobi
    # matrix of w do not share eigenvectors in a truncated basis
    basis = ChaosBasis(3)
    terms = [
        LinearTerm(K, G=weighted_gram(basis, lambda w: 1 + w)),
        LinearTerm(M, G=weighted_gram(basis, lambda w: w**3)),
        LoadTerm.constant(F1),
    ]
    system = GalerkinSystem(terms, 0, basis=basis)
    assert system.decoupling() is None
    sol = solve_steady(system, [])
    assert sol.success and "decoupled" not in sol.message
    with pytest.raises(ValueError, match="structure"):
        solve_steady(system, [], structure="fast")


def test_non_finite_jacobian_is_a_failure_not_a_nan_state():
    class BrokenForm:
        size = 2

        def apply(self, X, Y):
            return np.zeros_like(X)

        def matrix(self, x):
            return np.full((2, 2), np.nan)

    bad = GalerkinSystem(
        [LinearTerm(np.eye(2)), QuadraticTerm(BrokenForm()), LoadTerm.constant([1.0, 0.0])], 0
    )
    sol = solve_steady(bad, [])
    assert not sol.success and "not finite" in sol.message


def test_forces_on_a_system_without_gamma_are_rejected_in_the_residual():
    no_gamma = GalerkinSystem([LinearTerm(K), LoadTerm.constant(F1)], 0)
    with pytest.raises(ValueError, match="Gamma"):
        no_gamma.residual(no_gamma.zeros(), [], lam=np.ones(2))


@pytest.mark.parametrize("structure", ["auto", "dense"])
def test_jacobian_solve_reuses_the_factors_and_equals_a_fresh_dense_solve(structure):
    system = _linear_stochastic(3)
    sol = solve_steady(system, EPS, structure=structure)
    rng = np.random.default_rng(3)
    B = rng.normal(size=(system.N * system.P, 2))
    X = sol.jacobian_solve(B)
    np.testing.assert_allclose(X, np.linalg.solve(system.jacobian(sol.Theta, EPS), B), rtol=1e-10)
    with pytest.raises(ValueError, match="rhs"):
        sol.jacobian_solve(np.ones(3))
    constrained = solve_steady(burgers_like(), EPS, constraint=(M_OBS, np.zeros(3)))
    with pytest.raises(ValueError, match="constrained"):
        constrained.jacobian_solve(np.ones(N))


def test_continuation_reaches_a_solution_plain_newton_misses():
    # R = theta + theta^2 - s: at s = 400 Newton from zero needs 10 iterations
    system = GalerkinSystem(
        [LinearTerm(np.eye(1)), QuadraticTerm(np.ones((1, 1, 1))), LoadTerm.linear([[1.0]])], 1
    )
    assert not solve_steady(system, [400.0], maxiter=7).success
    sol, steps = solve_continuation(system, [0.0], [400.0], maxiter=7)
    assert sol.success and steps > 1
    np.testing.assert_allclose(sol.Theta[0, 0], (-1 + np.sqrt(1 + 1600)) / 2, rtol=1e-12)
    failed, _ = solve_continuation(system, [0.0], [400.0], maxiter=1, max_halvings=1)
    assert not failed.success and "continuation step" in failed.message
    with pytest.raises(ConvergenceError, match="continuation"):
        solve_continuation(system, [0.0], [400.0], maxiter=1, max_halvings=1, strict=True)
