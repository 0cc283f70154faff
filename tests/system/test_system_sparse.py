"""Sparse operators and the structured solvers (dense, decoupled, sparse-direct, cg, gmres).

Independent truth: the dense block solve of the same system (the v0.1 path, itself tested
against deterministic solves and collocation), dense assembly of the operator, central
differences, and the closed-form structure of the mean-based preconditioner.
"""

import numpy as np
import pytest
import scipy.sparse as sp
from _models import diffusion, fd_stiffness
from hypothesis import given, settings
from hypothesis import strategies as st

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.errors import MemoryBudgetError, SingularSystemError
from ecfm_uq.memory import set_memory_budget
from ecfm_uq.system import (
    Coefficient,
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    QuadraticTerm,
    SolverOptions,
    march,
    solve_steady,
)
from ecfm_uq.system.solve.linear import choose_solver, solver_options

EPS = np.array([0.1, 1.3])
TIGHT = {"rtol": 1e-12}


def rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


@pytest.mark.parametrize("solver", ["sparse-direct", "cg", "gmres"])
def test_sparse_steady_equals_dense(solver):
    dense, _ = diffusion(sparse=False)
    sparse, _ = diffusion(sparse=True)
    ref = solve_steady(dense, EPS, solver="dense")
    sol = solve_steady(sparse, EPS, solver=solver_options(solver, **TIGHT))
    assert ref.success and sol.success, sol.message
    assert sol.solver.startswith(solver)
    assert rel(sol.Theta, ref.Theta) < 1e-10
    assert rel(sol.eps_sensitivity()[0], ref.eps_sensitivity()[0]) < 1e-10
    assert rel(sol.lam_sensitivity(), ref.lam_sensitivity()) < 1e-10
    if solver == "sparse-direct":
        assert sol.linear_iterations == []
    else:
        assert len(sol.linear_iterations) > 0 and max(sol.linear_iterations) < 60


@pytest.mark.parametrize("solver", ["sparse-direct", "cg", "gmres"])
def test_sparse_ecfm_constraint_equals_dense(solver):
    dense, M_obs = diffusion(sparse=False)
    sparse, _ = diffusion(sparse=True)
    v = M_obs @ dense.mean(solve_steady(dense, [0.3, 1.0]).Theta) * 1.05  # misspecified
    ref = solve_steady(dense, EPS, constraint=(M_obs, v), solver="dense")
    sol = solve_steady(
        sparse, EPS, constraint=(sp.csr_matrix(M_obs), v), solver=solver_options(solver, **TIGHT)
    )
    assert ref.success and sol.success, sol.message
    assert rel(sol.Theta, ref.Theta) < 1e-10 and rel(sol.lam, ref.lam) < 1e-10
    (dT, dl), (dT0, dl0) = sol.eps_sensitivity(), ref.eps_sensitivity()
    assert rel(dT, dT0) < 1e-10 and rel(dl, dl0) < 1e-10


@pytest.mark.parametrize("solver", ["sparse-direct", "cg", "gmres"])
def test_sparse_march_equals_dense(solver):
    dense, M_obs = diffusion(sparse=False, N=12)
    sparse, _ = diffusion(sparse=True, N=12)
    ref = march(dense, EPS, np.zeros(12), 0.02, 4, sensitivities=True, solver="dense")
    tr = march(
        sparse,
        EPS,
        np.zeros(12),
        0.02,
        4,
        sensitivities=True,
        solver=solver_options(solver, **TIGHT),
    )
    assert tr.success and tr.solver.startswith(solver)
    assert rel(tr.Theta, ref.Theta) < 1e-10 and rel(tr.dTheta, ref.dTheta) < 1e-10
    # under the data constraint at every step
    V = np.tile(M_obs @ np.full(12, 0.01), (5, 1))
    ref = march(dense, EPS, np.zeros(12), 0.02, 4, constraint=(M_obs, V), sensitivities=True)
    tr = march(
        sparse,
        EPS,
        np.zeros(12),
        0.02,
        4,
        constraint=(sp.csr_matrix(M_obs), V),
        sensitivities=True,
        solver=solver_options(solver, **TIGHT),
    )
    assert tr.success, tr.message
    assert rel(tr.lam, ref.lam) < 1e-10 and rel(tr.dlam, ref.dlam) < 1e-9


def burgers_like(N=10, order=2, sparse=False):
    """Random-viscosity 1-D Burgers-type steady system with a random quadratic coupling."""
    rng = np.random.default_rng(3)
    basis = ChaosBasis(order, 2)
    A = rng.standard_normal((N, N, N)) * 0.05
    K = fd_stiffness(N)
    G = weighted_gram(basis, lambda w: 1.0 + 0.5 * (w[:, 0] - 0.5))
    terms = [
        LinearTerm(K if sparse else K.toarray(), Coefficient.power10(0, sign=-1.0), G=G),
        QuadraticTerm(A),
        LoadTerm.scaled(np.sin(np.pi * np.arange(1, N + 1) / (N + 1)), Coefficient.parameter(1)),
    ]
    return GalerkinSystem(terms, 2, basis=basis)


def test_newton_krylov_on_a_quadratic_system_equals_dense_newton():
    ref = solve_steady(burgers_like(), [-0.5, 3.0], solver="dense")
    for kind in ("mean", "decoupled"):
        sol = solve_steady(
            burgers_like(sparse=True),
            [-0.5, 3.0],
            solver=solver_options("gmres", preconditioner=kind, **TIGHT),
        )
        assert ref.success and sol.success and sol.nit == ref.nit
        assert sol.solver == f"gmres+{kind}"
        assert rel(sol.Theta, ref.Theta) < 1e-10
        assert rel(sol.eps_sensitivity()[0], ref.eps_sensitivity()[0]) < 1e-9
    with pytest.raises(ValueError, match="`solver`='cg'.*quadratic.*gmres"):
        solve_steady(burgers_like(), [-0.5, 3.0], solver="cg")


@settings(max_examples=25, deadline=None)
@given(
    N=st.integers(3, 9),
    dim=st.integers(1, 3),
    order=st.integers(0, 3),
    seed=st.integers(0, 10_000),
    quadratic=st.booleans(),
)
def test_operator_forms_agree(N, dim, order, seed, quadratic):
    # matrix-free action == dense assembly == sparse assembly == finite differences
    rng = np.random.default_rng(seed)
    basis = ChaosBasis(order, dim)
    terms = [LinearTerm(sp.csr_matrix(fd_stiffness(N)), 2.0)]
    for k in range(dim):
        G = weighted_gram(basis, lambda w, k=k: (w[:, k] if w.ndim == 2 else w) ** 2)
        terms.append(LinearTerm(rng.standard_normal((N, N)), G=G))
    if quadratic:
        terms.append(QuadraticTerm(rng.standard_normal((N, N, N)), 0.3))
    terms.append(LoadTerm.constant(rng.standard_normal(N)))
    system = GalerkinSystem(terms, 0, basis=basis, M=sp.identity(N))
    Theta = rng.standard_normal(system.shape)
    X = rng.standard_normal(system.shape)
    op = system.jacobian_operator(Theta, [], dt=0.1)
    Jd = op.to_dense()
    np.testing.assert_allclose(op.to_sparse().toarray(), Jd, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(op.matvec(X.ravel()), Jd @ X.ravel(), rtol=1e-12, atol=1e-11)
    h = 1e-6
    fd = (system.residual(Theta + h * X, []) - system.residual(Theta - h * X, [])).ravel() / (
        2 * h
    ) + (system.apply_mass(X) / 0.1).ravel()
    np.testing.assert_allclose(op.matvec(X.ravel()), fd, rtol=1e-6, atol=1e-6)
    # the mean block is the (0, 0) chaos block over E[Psi_0^2]
    mean = op.mean_block()
    mean = mean.toarray() if sp.issparse(mean) else mean
    P = system.P
    np.testing.assert_allclose(mean * system.E2[0, 0], Jd[::P, ::P], rtol=1e-12, atol=1e-11)


def test_krylov_iterations_do_not_grow_with_N():
    its = []
    for N in (20, 80, 320):
        system, _ = diffusion(N=N, dim=3, order=3)
        sol = solve_steady(system, EPS, solver="cg")
        assert sol.success
        its.append(sol.linear_iterations[0])
    assert max(its) - min(its) <= 2, its


def test_auto_choice():
    dense, _ = diffusion(sparse=False)
    sparse, _ = diffusion(sparse=True)
    opts = SolverOptions()
    assert choose_solver(dense, opts) == "dense"  # small dense input: the v0.1 path
    assert choose_solver(sparse, opts) == "cg"  # symmetric, sparse, P > 1
    assert choose_solver(burgers_like(sparse=True), opts) == "gmres"
    one = GalerkinSystem([LinearTerm(fd_stiffness(5)), LoadTerm.constant(np.ones(5))], 0)
    assert choose_solver(one, opts) == "sparse-direct"
    single = GalerkinSystem(
        [
            LinearTerm(fd_stiffness(5)),
            LinearTerm(fd_stiffness(5), G=weighted_gram(ChaosBasis(3), lambda w: w)),
            LoadTerm.constant(np.ones(5)),
        ],
        0,
        basis=ChaosBasis(3),
    )
    assert choose_solver(single, opts) == "decoupled"
    assert solve_steady(single, []).solver == "decoupled"


def test_memory_budget_refuses_dense_and_auto_avoids_it():
    dense, _ = diffusion(sparse=False, N=40, dim=3, order=3)  # NP = 800
    previous = set_memory_budget(4e6)  # 4 MB: the dense Jacobian needs 5 MB
    try:
        with pytest.raises(MemoryBudgetError, match=r"dense Jacobian.*NP = 800.*solver='cg'"):
            solve_steady(dense, EPS, solver="dense")
        sol = solve_steady(dense, EPS)  # auto: matrix-free instead
        assert sol.success and sol.solver == "cg+mean"
        set_memory_budget(1e3)
        with pytest.raises(MemoryBudgetError, match="Krylov work vectors"):
            solve_steady(dense, EPS)
    finally:
        set_memory_budget(previous)


def test_bad_sparse_input_names_the_argument():
    with pytest.raises(ValueError, match="`K` must be square"):
        LinearTerm(sp.csr_matrix(np.ones((3, 4))))
    K = sp.csr_matrix(np.eye(3))
    K.data[0] = np.nan
    with pytest.raises(ValueError, match="`K` contains NaN"):
        LinearTerm(K)
    terms = [LinearTerm(fd_stiffness(5)), LoadTerm.constant(np.ones(5))]
    with pytest.raises(ValueError, match="`Gamma` must have 5 rows"):
        GalerkinSystem(terms, 0, Gamma=sp.csr_matrix(np.ones((4, 2))))
    with pytest.raises(ValueError, match=r"`M` must have shape \(5, 5\)"):
        GalerkinSystem(terms, 0, M=sp.identity(4))
    system = GalerkinSystem(terms, 0, Gamma=sp.identity(5, format="csr")[:, :2])
    with pytest.raises(ValueError, match=r"`M_obs` must have shape \(2, 5\)"):
        solve_steady(system, [], constraint=(sp.csr_matrix(np.ones((2, 4))), np.ones(2)))
    with pytest.raises(ValueError, match="unknown `solver`"):
        solve_steady(system, [], solver="lu")
    with pytest.raises(ValueError, match="unknown `preconditioner`"):
        SolverOptions("cg", preconditioner="ilu")
    with pytest.raises(TypeError, match="`solver` must be"):
        solve_steady(system, [], solver=3)


def test_cg_refuses_nonsymmetric_and_indefinite_systems():
    N = 8
    basis = ChaosBasis(2, 2)
    nonsym = sp.csr_matrix(fd_stiffness(N) + sp.diags([0.5], [1], shape=(N, N)))
    system = GalerkinSystem([LinearTerm(nonsym), LoadTerm.constant(np.ones(N))], 0, basis=basis)
    with pytest.raises(ValueError, match="`solver`='cg'.*non-symmetric.*gmres"):
        solve_steady(system, [], solver="cg")
    assert solve_steady(system, [], solver="gmres").success
    # symmetric but indefinite: the mean block is SPD, the random part makes J indefinite
    G = weighted_gram(basis, lambda w: 8.0 * (w[:, 0] - 0.5))
    indefinite = GalerkinSystem(
        [
            LinearTerm(fd_stiffness(N)),
            LinearTerm(fd_stiffness(N), G=G),
            LoadTerm.constant(np.ones(N)),
        ],
        0,
        basis=basis,
    )
    # with the mean block as preconditioner, CG meets the negative curvature; (the
    # decoupled preconditioner is the exact inverse here, and CG then solves it in one step)
    with pytest.raises(ValueError, match="positive definite.*curvature.*gmres"):
        solve_steady(indefinite, [], solver=SolverOptions("cg", preconditioner="mean"))


def test_singular_preconditioner_and_unconverged_krylov_are_clear():
    N = 8
    basis = ChaosBasis(2, 2)
    G = weighted_gram(basis, lambda w: w[:, 0] - 0.5)  # zero mean: the mean block vanishes
    system = GalerkinSystem(
        [LinearTerm(fd_stiffness(N), G=G), LoadTerm.constant(np.ones(N))], 0, basis=basis
    )
    with pytest.raises(SingularSystemError, match="`preconditioner`='mean'.*singular"):
        solve_steady(system, [], solver=SolverOptions("gmres", preconditioner="mean"))
    # in the couplings' eigenbasis the zero mean shows as vanishing modes: J is singular
    with pytest.raises(SingularSystemError, match="`preconditioner`='decoupled'.*singular"):
        solve_steady(system, [], solver="gmres")
    slow, _ = diffusion(N=30, dim=2, order=3)
    sol = solve_steady(slow, EPS, solver=SolverOptions("cg", preconditioner="none", maxiter=3))
    assert not sol.success
    assert "cg did not reach" in sol.message and "after 3 iterations" in sol.message


def test_amg_preconditioner_matches_splu():
    system, _ = diffusion(N=200, dim=2, order=2)
    a = solve_steady(system, EPS, solver=SolverOptions("cg", preconditioner="mean"))
    b = solve_steady(system, EPS, solver=SolverOptions("cg", preconditioner="mean-amg"))
    assert b.solver == "cg+mean-amg" and a.success and b.success
    assert rel(b.Theta, a.Theta) < 1e-9


def test_variance_equals_covariance_diagonal():
    system, _ = diffusion(N=10)
    Theta = solve_steady(system, EPS).Theta
    np.testing.assert_allclose(
        system.variance(Theta), np.diag(system.covariance(Theta)), rtol=1e-12, atol=1e-16
    )


def test_inverse_layer_takes_a_sparse_sensor_matrix():
    from ecfm_uq.inverse import SteadyProblem, fit, sensor_moments

    system, M_obs = diffusion(N=12, dim=1, order=0)  # P = 1: the noisy fits need it
    v = M_obs @ system.mean(solve_steady(system, [0.2, 1.1]).Theta)
    for kw in (
        {"eps0": [0.0, 1.0], "formulation": "ecfm"},
        {"eps0": np.zeros(2), "method": "all-at-once"},
    ):
        dense = fit(SteadyProblem(system, M_obs, v), **kw)
        sparse = fit(SteadyProblem(system, sp.csr_matrix(M_obs), v), **kw)
        assert dense.success and sparse.success
        np.testing.assert_allclose(sparse.eps, dense.eps, rtol=1e-12)
    system, M_obs = diffusion(N=12, dim=1, order=2)
    Theta = solve_steady(system, [0.2, 1.1]).Theta
    for a, b in zip(
        sensor_moments(system, sp.csr_matrix(M_obs), Theta),
        sensor_moments(system, M_obs, Theta),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)


def test_sparse_load_vectors_are_accepted():
    F = np.linspace(0.0, 1.0, 6)
    for Fs in (sp.csr_matrix(F[:, None]), sp.csr_matrix(F[None, :])):
        term = LoadTerm.constant(Fs).bind(np.ones(1))
        np.testing.assert_array_equal(term.apply(np.zeros((6, 1)), []), -F[:, None])
    with pytest.raises(ValueError, match="`F` must be a vector"):
        LoadTerm.constant(sp.identity(3))


@settings(max_examples=20, deadline=None)
@given(
    N=st.integers(3, 10),
    dim=st.integers(1, 3),
    order=st.integers(1, 3),
    seed=st.integers(0, 10_000),
    constrained=st.booleans(),
)
def test_every_solver_gives_the_dense_solution(N, dim, order, seed, constrained):
    # random SPD diffusion-type systems: a positive mean operator plus random symmetric
    # perturbations small enough to keep J positive definite
    rng = np.random.default_rng(seed)
    basis = ChaosBasis(order, dim)
    A = rng.standard_normal((N, N))
    K0 = A @ A.T + N * np.eye(N)
    terms = [LinearTerm(sp.csr_matrix(K0), Coefficient.power10(0, sign=1.0))]
    for k in range(dim):
        B = rng.standard_normal((N, N))
        G = weighted_gram(basis, lambda w, k=k: (w[:, k] if w.ndim == 2 else w) - 0.5)
        terms.append(LinearTerm(sp.csr_matrix(0.1 * (B + B.T)), G=G))
    terms.append(LoadTerm.scaled(rng.standard_normal(N), Coefficient.parameter(1)))
    Gamma = np.eye(N)[:, :2]
    system = GalerkinSystem(terms, 2, basis=basis, Gamma=sp.csr_matrix(Gamma))
    constraint = (Gamma.T, np.array([0.1, -0.2])) if constrained else None
    ref = solve_steady(system, EPS, constraint=constraint, solver="dense")
    assert ref.success
    for solver in ("sparse-direct", "cg", "gmres"):
        sol = solve_steady(
            system, EPS, constraint=constraint, solver=solver_options(solver, **TIGHT)
        )
        assert sol.success, (solver, sol.message)
        assert rel(sol.Theta, ref.Theta) < 1e-10
        if constrained:
            assert rel(sol.lam, ref.lam) < 1e-10


# -- the decoupled preconditioner ------------------------------------------------------
def test_decoupled_preconditioner_is_exact_for_a_linear_single_germ_system():
    # one germ: every coupling E[(w - 1/2) Psi Psi^T] shares the Gauss-node eigenbasis, so
    # the preconditioner is the inverse of J and the Krylov method stops after one step
    system, M_obs = diffusion(dim=1, order=4)
    ref = solve_steady(system, EPS, solver="dense")
    for name in ("cg", "gmres"):
        sol = solve_steady(system, EPS, solver=SolverOptions(name, preconditioner="decoupled"))
        assert sol.success and sol.solver == f"{name}+decoupled"
        assert max(sol.linear_iterations) <= 2
        assert rel(sol.Theta, ref.Theta) < 1e-10
        assert rel(sol.eps_sensitivity()[0], ref.eps_sensitivity()[0]) < 1e-10
    # "auto" takes it for one germ, and the mean block when the couplings do not commute
    assert solve_steady(system, EPS, solver="cg").solver == "cg+decoupled"
    two, _ = diffusion(dim=2)
    assert solve_steady(two, EPS, solver="cg").solver == "cg+mean"


def test_decoupled_preconditioner_refuses_couplings_without_a_common_eigenbasis():
    two, _ = diffusion(dim=2)
    with pytest.raises(ValueError, match="`preconditioner`='decoupled'.*common eigenbasis"):
        solve_steady(two, EPS, solver=SolverOptions("cg", preconditioner="decoupled"))


def test_decoupled_preconditioner_on_burgers_with_a_random_viscosity():
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(
        n_modes=16, n_steps=10, T=0.4, viscosity_chaos=ChaosBasis(3), viscosity_spread=0.5
    )
    eps = np.array([1.75, 1.0])
    args = (m.system, eps, m.Theta0, m.dt, m.n_steps)
    ref = march(*args, tol=1e-11, solver="dense", keep_factors=True)
    runs = {
        kind: march(
            *args,
            tol=1e-11,
            keep_factors=True,
            solver=SolverOptions("gmres", preconditioner=kind, rtol=1e-12),
        )
        for kind in ("mean", "decoupled")
    }
    g = np.random.default_rng(0).standard_normal(ref.Theta.shape)
    for kind, tr in runs.items():
        assert tr.success and tr.solver == f"gmres+{kind}", tr.message
        assert rel(tr.Theta, ref.Theta) < 1e-9
        # the transposed preconditioner serves the adjoint
        assert rel(tr.adjoint_gradient(g), ref.adjoint_gradient(g)) < 1e-8
    # exact on the random viscosity, only the convection's fluctuation left to GMRES
    its = {k: np.mean(tr.linear_iterations) for k, tr in runs.items()}
    assert its["decoupled"] < 0.6 * its["mean"], its
