"""NonlinearTerm: a user's deterministic nonlinearity projected by a Gauss rule (issue 21, item 3).

Independent truths: stochastic collocation of the deterministic problem (Newton on the
same finite-difference model at each Gauss node, or scipy's fsolve), the exact triple
products of QuadraticTerm, central finite differences.
"""

import numpy as np
import pytest
import scipy.optimize as so
import scipy.sparse as sp

from ecfm_uq.chaos import ChaosBasis, gauss_legendre, weighted_gram
from ecfm_uq.errors import ModelEvaluationError
from ecfm_uq.system import (
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    NonlinearTerm,
    QuadraticTerm,
    march,
    solve_steady,
)
from ecfm_uq.system.model.nonlinear_term import nonlinear_rule_points, smolyak_quadrature

N = 15
H = 1.0 / (N + 1)
K = (np.diag(2 * np.ones(N)) - np.diag(np.ones(N - 1), 1) - np.diag(np.ones(N - 1), -1)) / H**2
F = 10.0 * np.ones(N)


def a_of(w):  # random diffusion coefficient of the first germ
    return 1.0 + 0.5 * w[..., 0]


def c_of(w):  # random reaction coefficient (the second germ when there is one)
    return 1.0 + 0.5 * w[..., -1]


def cubic(random_reaction=False, sparse_jac=False, eps_jac=True, **kw):
    """r(u, omega, eps) = eps0 * c(omega) * u^3 (c = 1 unless random_reaction)."""

    def c(w):
        return float(c_of(np.asarray(w))) if random_reaction else 1.0

    def res(u, w, eps):
        return eps[0] * c(w) * u**3

    def jac(u, w, eps):
        d = 3.0 * eps[0] * c(w) * u**2
        return sp.diags(d) if sparse_jac else np.diag(d)

    def deps(u, w, eps):
        return (c(w) * u**3)[:, None]

    return NonlinearTerm(res, jac, eps_jacobian=deps if eps_jac else None, **kw)


def cubic_system(basis, **kw):
    G = weighted_gram(basis, a_of)
    terms = [LinearTerm(K, G=G), cubic(**kw), LoadTerm.constant(F)]
    return GalerkinSystem(terms, n_eps=1, basis=basis)


def node_solution(w, eps0, random_reaction=False):
    """Deterministic solution of a(w) K u + eps0 c(w) u^3 = F by scipy's fsolve."""
    a = a_of(np.asarray(w))
    c = c_of(np.asarray(w)) if random_reaction else 1.0

    def fun(u):
        return a * K @ u + eps0 * c * u**3 - F

    u, _, ier, msg = so.fsolve(
        fun, np.zeros(N), fprime=lambda u: a * K + np.diag(3 * eps0 * c * u**2), full_output=True,
        xtol=1e-13,
    )  # fmt: skip
    # fsolve may stop at "no further improvement": judge the answer by its own residual
    assert np.linalg.norm(fun(u)) <= 1e-11 * np.linalg.norm(F), msg
    return u


def collocation_moments(nodes, weights, eps0, random_reaction=False):
    U = np.array([node_solution(w, eps0, random_reaction) for w in nodes])  # (Q, N)
    mean = weights @ U
    return mean, weights @ U**2 - mean**2


def test_rule_points_cubic_is_2p_plus_1():
    assert [nonlinear_rule_points(p, 3) for p in range(1, 6)] == [3, 5, 7, 9, 11]
    # quadratic: the degree of QuadraticTerm's exact triple products (3p + 2 needs (3p+1)/2)
    assert nonlinear_rule_points(4, 2) == 7


def test_p_node_rule_is_collocation():
    """With the P-node Gauss rule pseudo-spectral Galerkin is collocation at those nodes
    (the affine coupling is integrated exactly by P nodes): the chaos coefficients are the
    interpolant of fsolve's node solutions, to round-off."""
    p, eps0 = 4, 300.0
    basis = ChaosBasis(p)
    system = GalerkinSystem(
        [LinearTerm(K, G=weighted_gram(basis, a_of)), cubic(rule=p + 1), LoadTerm.constant(F)],
        n_eps=1,
        basis=basis,
    )
    sol = solve_steady(system, [eps0])
    assert sol.success
    x, w = gauss_legendre(p + 1)
    U = np.array([node_solution([xi], eps0) for xi in x]).T  # (N, P) node values
    Theta_coll = np.linalg.solve(basis.evaluate(x), U.T).T
    assert np.max(np.abs(sol.Theta - Theta_coll)) <= 1e-10 * np.max(np.abs(Theta_coll))


def test_cubic_reaction_one_germ_matches_collocation():
    eps0 = 300.0  # u^3 changes the solution by ~25 %: a strongly nonlinear regime
    system = cubic_system(ChaosBasis(8))
    sol = solve_steady(system, [eps0])
    assert sol.success
    x, w = gauss_legendre(30)
    mean, var = collocation_moments(x[:, None], w, eps0)
    assert np.max(np.abs(system.mean(sol.Theta) - mean)) <= 1e-8 * np.max(np.abs(mean))
    assert np.max(np.abs(system.variance(sol.Theta) - var)) <= 1e-8 * np.max(var)
    # the nonlinearity matters: linear solution differs by far more than the tolerance
    lin = np.linalg.solve(K, F)
    assert np.max(np.abs(lin - mean)) > 0.1 * np.max(mean)


def test_cubic_reaction_two_germs_sparse_jacobian_matches_collocation():
    eps0 = 300.0
    basis = ChaosBasis(6, dim=2)
    system = cubic_system(basis, random_reaction=True, sparse_jac=True, degree=4)
    sol = solve_steady(system, [eps0])
    assert sol.success
    nodes, weights = ChaosBasis(1, dim=2).quadrature(14)
    mean, var = collocation_moments(nodes, weights, eps0, random_reaction=True)
    assert np.max(np.abs(system.mean(sol.Theta) - mean)) <= 1e-8 * np.max(np.abs(mean))
    assert np.max(np.abs(system.variance(sol.Theta) - var)) <= 1e-8 * np.max(var)


@pytest.mark.parametrize("rule", ["auto", "smolyak"])
def test_quadratic_term_as_nonlinear_term_same_solution(rule):
    rng = np.random.default_rng(3)
    n = 6
    A = rng.normal(size=(n, n, n)) * 0.3
    Asym = A + A.transpose(0, 2, 1)
    Kd = 4 * np.eye(n) + rng.normal(size=(n, n)) * 0.3
    Fv = rng.normal(size=n)
    basis = ChaosBasis(3, dim=2)
    G = weighted_gram(basis, lambda w: 1.0 + 0.4 * w[:, 0] + 0.3 * w[:, 1])

    def res(u, w, eps):
        return np.einsum("ijk,j,k->i", A, u, u)

    def jac(u, w, eps):
        return Asym @ u

    def build(q):
        return GalerkinSystem([LinearTerm(Kd, G=G), q, LoadTerm.constant(Fv)], 1, basis=basis)

    s_quad = build(QuadraticTerm(A))
    s_user = build(NonlinearTerm(res, jac, degree=2, rule=rule))
    Theta = rng.normal(size=(n, basis.size)) * 0.5
    r_quad, r_user = s_quad.residual(Theta, [0.0]), s_user.residual(Theta, [0.0])
    assert np.max(np.abs(r_quad - r_user)) <= 1e-12 * np.max(np.abs(r_quad))
    J_quad, J_user = s_quad.jacobian(Theta, [0.0]), s_user.jacobian(Theta, [0.0])
    assert np.max(np.abs(J_quad - J_user)) <= 1e-12 * np.max(np.abs(J_quad))
    a, b = solve_steady(s_quad, [0.0]), solve_steady(s_user, [0.0])
    assert a.success and b.success
    assert np.max(np.abs(a.Theta - b.Theta)) <= 1e-12 * np.max(np.abs(a.Theta))
    # one point fewer per germ is not exact: the test can tell
    s_low = build(NonlinearTerm(res, jac, rule=nonlinear_rule_points(3, 2) - 1))
    assert np.max(np.abs(s_low.residual(Theta, [0.0]) - r_quad)) > 1e-8


def test_smolyak_rule_is_as_exact_as_the_tensor_rule():
    """Three germs, a cubic with a random rate (degree 4): the Gauss Smolyak rule of level
    floor(5p/2) integrates what the (5p/2 + 1)-point tensor rule integrates exactly."""
    basis = ChaosBasis(2, dim=3)
    smol = cubic_system(basis, random_reaction=True, degree=4, rule="smolyak")
    tens = cubic_system(basis, random_reaction=True, degree=4, rule="tensor")
    Theta, eps = np.random.default_rng(2).normal(size=smol.shape), [3.0]
    r_s, r_t = smol.residual(Theta, eps), tens.residual(Theta, eps)
    assert np.max(np.abs(r_s - r_t)) <= 1e-12 * np.max(np.abs(r_t))
    J_s, J_t = smol.jacobian(Theta, eps), tens.jacobian(Theta, eps)
    assert np.max(np.abs(J_s - J_t)) <= 1e-12 * np.max(np.abs(J_t))
    # the integrand has total degree 1 + 3 * 2 + 2 = 9: level 4 is exact as well, level 3 not
    low = NonlinearTerm(
        smol.terms[1].residual, smol.terms[1].jacobian, rule=smolyak_quadrature(3, basis)
    )
    s_low = GalerkinSystem([LinearTerm(K, G=weighted_gram(basis, a_of)), low], 1, basis=basis)
    r_low = s_low.residual(Theta, eps) - smol.terms[0].apply(Theta, eps)
    assert np.max(np.abs(r_low - smol.terms[1].apply(Theta, eps))) > 1e-6


def test_jacobian_and_transpose_vs_finite_differences():
    basis = ChaosBasis(3, dim=2)
    system = cubic_system(basis, random_reaction=True, degree=4)
    rng = np.random.default_rng(1)
    Theta, eps = rng.normal(size=system.shape), np.array([2.0])
    J = system.jacobian(Theta, eps)
    h = 1e-6
    Jfd = np.zeros_like(J)
    for j in range(Theta.size):
        E = np.zeros(Theta.size)
        E[j] = h
        E = E.reshape(Theta.shape)
        Jfd[:, j] = (system.residual(Theta + E, eps) - system.residual(Theta - E, eps)).ravel() / (
            2 * h
        )
    assert np.max(np.abs(J - Jfd)) <= 1e-6 * np.max(np.abs(J))
    op = system.jacobian_operator(Theta, eps)
    X = rng.normal(size=system.shape)
    assert np.allclose(op.apply(X).ravel(), J @ X.ravel(), rtol=1e-12, atol=1e-9)
    assert np.allclose(op.apply_transpose(X).ravel(), J.T @ X.ravel(), rtol=1e-12, atol=1e-9)
    assert np.allclose(op.to_sparse().toarray(), J, rtol=1e-12, atol=1e-9)
    # eps-Jacobian vs central differences
    D = system.eps_jacobian(Theta, eps)
    Dfd = (system.residual(Theta, eps + h) - system.residual(Theta, eps - h)).ravel() / (2 * h)
    assert np.max(np.abs(D[:, 0] - Dfd)) <= 1e-6 * np.max(np.abs(Dfd))
    mu = rng.normal(size=system.shape)
    assert np.allclose(system.eps_vjp(Theta, eps, mu), D.T @ mu.ravel(), rtol=1e-12)


@pytest.mark.parametrize("solver", ["dense", "gmres"])
def test_eps_sensitivity_vs_finite_differences(solver):
    system = cubic_system(ChaosBasis(3))
    eps0, h = 300.0, 1e-3
    sol = solve_steady(system, [eps0], solver=solver, tol=1e-11)
    assert sol.success
    dTheta = sol.eps_sensitivity()[0][:, :, 0]
    plus = solve_steady(system, [eps0 + h], tol=1e-12).Theta
    minus = solve_steady(system, [eps0 - h], tol=1e-12).Theta
    fd = (plus - minus) / (2 * h)
    assert np.max(np.abs(dTheta - fd)) <= 1e-6 * np.max(np.abs(fd))


def test_adjoint_gradient_equals_forward_sensitivity():
    basis = ChaosBasis(3, dim=2)
    system = cubic_system(basis, random_reaction=True, degree=4)
    sol = solve_steady(system, [100.0])
    assert sol.success
    g = np.random.default_rng(4).normal(size=system.shape)  # z = <g, Theta>
    forward = np.einsum("ik,ikm->m", g, sol.eps_sensitivity()[0])
    assert np.allclose(sol.adjoint_gradient(g), forward, rtol=1e-10, atol=0)
    h = 1e-3
    fd = (
        np.vdot(g, solve_steady(system, [100.0 + h], tol=1e-12).Theta)
        - np.vdot(g, solve_steady(system, [100.0 - h], tol=1e-12).Theta)
    ) / (2 * h)
    assert abs(sol.adjoint_gradient(g)[0] - fd) <= 1e-6 * abs(fd)


def test_dense_jacobians_over_the_memory_budget_are_refused(monkeypatch):
    from ecfm_uq.errors import MemoryBudgetError

    monkeypatch.setenv("ECFM_UQ_MEMORY_BUDGET", "5000")  # bytes: under 5 nodes x 15^2 doubles
    system = cubic_system(ChaosBasis(2))
    with pytest.raises(MemoryBudgetError, match="scipy.sparse"):
        system.jacobian_operator(np.zeros(system.shape), [1.0])
    # sparse node Jacobians are not refused
    sparse = cubic_system(ChaosBasis(2), sparse_jac=True)
    sparse.jacobian_operator(np.zeros(sparse.shape), [1.0])


def test_missing_eps_jacobian_is_reported():
    system = cubic_system(ChaosBasis(2), eps_jac=False)
    sol = solve_steady(system, [10.0])
    assert sol.success
    with pytest.raises(ValueError, match="eps_jacobian"):
        sol.eps_sensitivity()


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_calibration_recovers_the_reaction_rate(formulation):
    """Noise-free data of rate 250 from three sensors; the ECFM formulation solves the
    model under the data constraint (constraint forces at the sensors)."""
    from ecfm_uq.inverse import SteadyProblem, fit

    sensors = [3, 7, 11]
    Gamma = np.eye(N)[:, sensors]
    system = GalerkinSystem([LinearTerm(K), cubic(), LoadTerm.constant(F)], 1, Gamma=Gamma)
    M_obs = np.eye(N)[sensors]
    true = 250.0
    v = M_obs @ solve_steady(system, [true], tol=1e-12).Theta[:, 0]
    res = fit(SteadyProblem(system, M_obs, v), [100.0], formulation=formulation)
    assert res.success
    assert abs(res.eps[0] - true) <= 1e-6 * true


def test_march_matches_quadratic_term():
    """A backward-Euler march through the generic path equals the QuadraticTerm march."""
    rng = np.random.default_rng(5)
    n = 5
    A = rng.normal(size=(n, n, n)) * 0.2
    Asym = A + A.transpose(0, 2, 1)
    basis = ChaosBasis(3)
    G = weighted_gram(basis, a_of)
    Kd = np.diag(np.full(n, 2.0))
    user = NonlinearTerm(
        lambda u, w, e: np.einsum("ijk,j,k->i", A, u, u), lambda u, w, e: Asym @ u, degree=2
    )
    out = []
    for q in (QuadraticTerm(A), user):
        s = GalerkinSystem([LinearTerm(Kd, G=G), q, LoadTerm.constant(np.ones(n))], 1,
                           basis=basis, M=np.eye(n))  # fmt: skip
        tr = march(s, [0.0], np.zeros((n, basis.size)), 0.1, 5, solver="dense", tol=1e-12)
        out.append(tr)
    a, b = (np.asarray(t.Theta) for t in out)
    assert np.max(np.abs(a - b)) <= 1e-11 * np.max(np.abs(a))


def _one(res=None, jac=None, **kw):
    res = res or (lambda u, w, e: u**3)
    jac = jac or (lambda u, w, e: np.diag(3 * u**2))
    return GalerkinSystem([LinearTerm(K), NonlinearTerm(res, jac, **kw), LoadTerm.constant(F)], 1)


def test_bad_callbacks_are_refused():
    Z = np.ones((N, 1))
    with pytest.raises(TypeError, match="`residual` must be callable"):
        NonlinearTerm(np.ones(3), lambda u, w, e: u)
    with pytest.raises(TypeError, match="`jacobian` must be callable"):
        NonlinearTerm(lambda u, w, e: u, None)
    with pytest.raises(ValueError, match=r"`residual`.*shape \(14,\)"):
        _one(res=lambda u, w, e: u[:-1]).residual(Z, [1.0])
    with pytest.raises(ModelEvaluationError, match="`residual` returned NaN"):
        _one(res=lambda u, w, e: u * np.nan).residual(Z, [1.0])
    with pytest.raises(ValueError, match="`jacobian`.*non-square"):
        _one(jac=lambda u, w, e: np.ones((N, N - 1))).jacobian(Z, [1.0])
    with pytest.raises(ModelEvaluationError, match="`jacobian` returned NaN"):
        _one(jac=lambda u, w, e: np.full((N, N), np.inf)).jacobian(Z, [1.0])
    with pytest.raises(ValueError, match="`rule` must be"):
        NonlinearTerm(lambda u, w, e: u, lambda u, w, e: u, rule="smolyak-ish")
    # a failing residual inside a solve is a failed solve, not a raw numpy error
    sol = solve_steady(_one(res=lambda u, w, e: u * np.nan), [1.0])
    assert not sol.success and "NaN" in sol.message
    with pytest.raises(ValueError, match="nodes"):
        cubic_system(ChaosBasis(3, dim=6), degree=6)


def test_nodal_preconditioner_takes_the_users_jacobian():
    """One germ: GMRES with the node-wise preconditioner (the user's Jacobian at the
    P Gauss nodes) gives the dense Newton solution in fewer Krylov iterations than the
    mean-based preconditioner."""
    system = cubic_system(ChaosBasis(4))
    ref = solve_steady(system, [300.0], solver="dense", tol=1e-11)
    runs = {}
    for pre in ("nodal", "mean"):
        sol = solve_steady(
            system, [300.0], solver={"solver": "gmres", "preconditioner": pre}, tol=1e-11
        )
        assert sol.success and sol.solver == f"gmres+{pre}"
        assert np.max(np.abs(sol.Theta - ref.Theta)) <= 1e-9 * np.max(np.abs(ref.Theta))
        runs[pre] = sum(sol.linear_iterations)
    assert runs["nodal"] < runs["mean"]


def test_plan_treats_it_as_nonlinear():
    system = cubic_system(ChaosBasis(3))
    assert not system.is_linear
    assert system.decoupling() is None
    s = GalerkinSystem(
        [LinearTerm(K, G=weighted_gram(ChaosBasis(3), a_of)), cubic(), LoadTerm.constant(F)],
        1, basis=ChaosBasis(3), M=np.eye(N),
    )  # fmt: skip
    tr = march(s, [10.0], np.zeros(s.shape), 0.01, 2)
    assert "compiled" not in tr.solver


def _node_moments(nodes, weights, fun, jac):
    """Collocation by scipy's fsolve at each node: mean and variance."""
    U = []
    for w in nodes:
        u, _, _, msg = so.fsolve(lambda u, w=w: fun(u, w), np.zeros(N), full_output=True,
                                 fprime=lambda u, w=w: jac(u, w), xtol=1e-13)  # fmt: skip
        assert np.linalg.norm(fun(u, w)) <= 1e-10 * np.linalg.norm(F), msg
        U.append(u)
    U = np.array(U)
    mean = weights @ U
    return mean, weights @ U**2 - mean**2


def test_an_exponential_reaction_two_germs_matches_collocation():
    # a(w) K u + 30 c(w) (exp(u) - 1) = F: not polynomial, so the Gauss rule's projection
    # is approximate; raising `degree` (rule points) converges to collocation
    def res(u, w, eps):
        return 30.0 * c_of(np.asarray(w)) * np.expm1(u)

    def jac(u, w, eps):
        return np.diag(30.0 * c_of(np.asarray(w)) * np.exp(u))

    basis = ChaosBasis(5, dim=2)
    G = weighted_gram(basis, a_of)
    system = GalerkinSystem(
        [LinearTerm(K, G=G), NonlinearTerm(res, jac, degree=6), LoadTerm.constant(F)], 0,
        basis=basis,
    )  # fmt: skip
    sol = solve_steady(system, [])
    assert sol.success, sol.message
    nodes, weights = ChaosBasis(1, dim=2).quadrature(12)
    mean, var = _node_moments(
        nodes, weights,
        lambda u, w: a_of(w) * K @ u + res(u, w, None) - F,
        lambda u, w: a_of(w) * K + jac(u, w, None),
    )  # fmt: skip
    # measured 1.7e-13 and 2.8e-10 (order 5, 12 x 12 collocation)
    assert np.max(np.abs(system.mean(sol.Theta) - mean)) <= 1e-10 * np.max(np.abs(mean))
    assert np.max(np.abs(system.variance(sol.Theta) - var)) <= 1e-7 * np.max(var)
    # the nonlinearity matters
    assert np.max(np.abs(np.linalg.solve(K, F) - mean)) > 0.1 * np.max(mean)


def _kd(u, w):
    """Flux-form finite differences of -(a(w) k(u) u')', k(u) = 1 + u^2, u = 0 at both
    ends: the residual and its (tridiagonal) Jacobian."""
    a = float(a_of(np.asarray(w)))
    ue = np.concatenate([[0.0], u, [0.0]])
    um = 0.5 * (ue[1:] + ue[:-1])  # midpoints, N + 1
    k, dk = 1.0 + um**2, 2.0 * um
    du = np.diff(ue)
    flux = a * k * du / H**2  # N + 1
    r = flux[:-1] - flux[1:]
    # d flux_j / d u_j (left end) and d u_{j+1} (right end)
    dl = a * (0.5 * dk * du - k) / H**2
    dr = a * (0.5 * dk * du + k) / H**2
    J = np.zeros((N, N))
    for i in range(N):
        # r_i = flux_i - flux_{i+1}; flux_i depends on u_{i-1} (ue[i]) and u_i (ue[i+1])
        J[i, i] += dr[i] - dl[i + 1]
        if i > 0:
            J[i, i - 1] += dl[i]
        if i < N - 1:
            J[i, i + 1] -= dr[i + 1]
    return r, J


@pytest.mark.parametrize(
    "solver",
    [
        "auto",
        {"solver": "gmres", "preconditioner": "kronecker"},
        {"solver": "gmres", "preconditioner": "mean"},
    ],
)
def test_a_state_dependent_conductivity_matches_collocation(solver):
    def res(u, w, eps):
        return _kd(u, w)[0]

    def jac(u, w, eps):
        return sp.csr_matrix(_kd(u, w)[1])

    rng = np.random.default_rng(0)
    u0, w0 = rng.random(N), np.array([0.3, 0.6])
    fd = np.column_stack([(res(u0 + 1e-6 * e, w0, None) - res(u0 - 1e-6 * e, w0, None)) / 2e-6
                          for e in np.eye(N)])  # fmt: skip
    np.testing.assert_allclose(
        jac(u0, w0, None).toarray(), fd, rtol=1e-6, atol=1e-6 * abs(fd).max()
    )

    basis = ChaosBasis(4, dim=2)
    system = GalerkinSystem(
        [NonlinearTerm(res, jac, degree=3, size=N), LoadTerm.constant(F)], 0, basis=basis
    )  # fmt: skip
    sol = solve_steady(system, [], solver=solver)
    assert sol.success, sol.message
    nodes, weights = ChaosBasis(1, dim=2).quadrature(10)
    mean, var = _node_moments(
        nodes, weights, lambda u, w: res(u, w, None) - F, lambda u, w: _kd(u, w)[1]
    )
    # measured with the dense solver 1.6e-11 and 8.7e-9 (order 4, 10 x 10 collocation)
    assert np.max(np.abs(system.mean(sol.Theta) - mean)) <= 1e-9 * np.max(np.abs(mean))
    assert np.max(np.abs(system.variance(sol.Theta) - var)) <= 1e-6 * np.max(var)
    assert np.max(np.abs(np.linalg.solve(K, F) - mean)) > 0.1 * np.max(mean)
