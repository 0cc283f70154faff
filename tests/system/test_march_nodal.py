"""The P > 1 march preconditioned node-wise (compiled kernel and generic path) equals the
dense Newton march: states, sensitivities, adjoint; its failures are reported; the
Gauss-node transforms it is built on satisfy their identities."""

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis, GaussNodes, gauss_legendre, weighted_gram
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import march
from ecfm_uq.system.solve.linear import NodalPreconditioner, choose_solver, solver_options

EPS = np.array([1.6, 1.5, 1.7, 0.9])
NODAL = {"solver": "gmres", "preconditioner": "nodal"}


@pytest.fixture(scope="module")
def model():
    # three viscosity cells (three linear terms, each with its random coupling) and a
    # random log-viscosity spread: every input of the kernel is exercised
    return BurgersModel(
        n_modes=14,
        n_steps=12,
        T=0.6,
        viscosity_cells=3,
        viscosity_chaos=ChaosBasis(3),
        viscosity_spread=0.6,
    )


def _march(model, **kw):
    kw.setdefault("tol", 1e-12)
    return march(model.system, EPS, model.Theta0, model.dt, model.n_steps, **kw)


@pytest.fixture(scope="module")
def dense(model):
    return _march(model, solver="dense", sensitivities=True, keep_factors=True)


@pytest.mark.parametrize("normalized", [True, False])
def test_gauss_nodes_identities(normalized):
    basis = ChaosBasis(4, normalized=normalized)
    g = GaussNodes(basis)
    W = np.diag(g.weights)
    np.testing.assert_allclose(g.Phi.T @ W @ g.Phi, np.diag(basis.norms2), atol=1e-14)
    np.testing.assert_allclose(g.Phi.T @ g.from_nodes, np.eye(5), atol=1e-13)
    # affine couplings are recovered exactly at the nodes
    G = weighted_gram(basis, lambda w: 2.0 - 3.0 * w, n_points=8)
    np.testing.assert_allclose(g.coupling_values(G), 2.0 - 3.0 * g.nodes, atol=1e-13)
    # others as E[g L_k^2] / w_k, L_k the node's Lagrange polynomial (20-node quadrature)
    G = weighted_gram(basis, np.exp, n_points=12)
    x, w = gauss_legendre(20)
    L = np.array([np.prod([(x - b) / (a - b) for b in g.nodes if b != a], axis=0) for a in g.nodes])
    expected = (L**2 * np.exp(x)) @ w / g.weights
    np.testing.assert_allclose(g.coupling_values(G), expected, rtol=1e-12)
    with pytest.raises(ValueError, match="one-germ basis"):
        GaussNodes(ChaosBasis(2, dim=2))


def test_compiled_march_equals_dense_newton(model, dense):
    assert choose_solver(model.system, solver_options(), steady=False) == "gmres"
    fast = _march(model, sensitivities=True)
    assert fast.solver == "gmres+nodal (compiled)" and fast.success
    scale = np.abs(dense.Theta).max()
    np.testing.assert_allclose(fast.Theta, dense.Theta, rtol=0, atol=1e-11 * scale)
    dscale = np.abs(dense.dTheta).max()
    np.testing.assert_allclose(fast.dTheta, dense.dTheta, rtol=0, atol=1e-9 * dscale)
    assert len(fast.linear_iterations) == model.n_steps
    assert sum(fast.linear_iterations) > 0  # the sensitivities are GMRES solves


def test_newton_krylov_branch_equals_dense_newton(model, dense):
    # chord rate <= 0: every step is Newton-Krylov (the fallback of a slow chord)
    nk = _march(model, solver={"chord_rate": 0.0})
    assert nk.solver == "gmres+nodal (compiled)" and nk.success
    assert sum(nk.linear_iterations) > 0
    assert nk.nit.sum() <= dense.nit.sum() + model.n_steps  # Newton's iteration count
    np.testing.assert_allclose(nk.Theta, dense.Theta, rtol=0, atol=1e-11)


def test_generic_path_with_the_nodal_preconditioner(model, dense):
    # kept factors (an adjoint): the generic Newton-Krylov path with the same preconditioner
    tr = _march(model, solver=NODAL, sensitivities=True, keep_factors=True)
    assert tr.solver == "gmres+nodal"
    np.testing.assert_allclose(tr.Theta, dense.Theta, rtol=0, atol=1e-11)
    np.testing.assert_allclose(tr.dTheta, dense.dTheta, rtol=0, atol=1e-8)
    g = np.random.default_rng(3).standard_normal(tr.Theta.shape)
    np.testing.assert_allclose(tr.adjoint_gradient(g), dense.adjoint_gradient(g), rtol=1e-8)
    # without the compiled kernels "auto" still answers, through the generic path
    slow = _march(model, solver={"compiled": False})
    assert slow.solver == "gmres+nodal"
    np.testing.assert_allclose(slow.Theta, dense.Theta, rtol=0, atol=1e-11)


def test_auto_keeps_dense_where_the_kernel_does_not_apply(model):
    system = model.system
    opts = solver_options()
    assert choose_solver(system, opts, steady=False, keep_factors=True) == "dense"
    assert choose_solver(system, opts, steady=False, constrained=True) == "dense"
    assert choose_solver(system, solver_options(preconditioner="mean"), steady=False) == "dense"
    # a two-germ basis: no P-node rule, so no node-wise march
    from ecfm_uq.system import GalerkinSystem, LinearTerm, QuadraticTerm

    conv = next(t for t in system.terms if isinstance(t, QuadraticTerm))
    N = system.N
    terms = [QuadraticTerm(conv.form), LinearTerm(np.eye(N))]  # fresh terms: bound anew
    two_germs = GalerkinSystem(terms, n_eps=0, basis=ChaosBasis(1, dim=2), M=np.eye(N))
    assert system.gauss_nodes() is not None and two_germs.gauss_nodes() is None
    assert choose_solver(two_germs, opts, steady=False) == "dense"


def test_nodal_preconditioner_is_exact_for_an_affine_linear_system():
    """B = J when every coupling is affine in the germ (the Gauss rule is then exact)."""
    from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm

    rng = np.random.default_rng(5)
    N, basis = 6, ChaosBasis(3)
    A = rng.standard_normal((N, N))
    K0, K1 = A @ A.T + N * np.eye(N), np.diag(rng.uniform(1, 2, N))
    G1 = weighted_gram(basis, lambda w: 0.5 + w, n_points=6)
    system = GalerkinSystem(
        [LinearTerm(K0), LinearTerm(K1, G=G1), LoadTerm.constant(np.ones(N))],
        n_eps=0,
        basis=basis,
        M=np.eye(N),
    )
    op = system.jacobian_operator(system.zeros(), np.zeros(0), dt=0.1)
    X = rng.standard_normal((N, basis.size))
    B = NodalPreconditioner(op)
    np.testing.assert_allclose(B.apply(op.apply(X)), X, atol=1e-12)
    np.testing.assert_allclose(B.apply_transpose(op.apply_transpose(X)), X, atol=1e-12)


def test_nodal_preconditioner_approximates_the_burgers_jacobian(model, dense):
    """With the quadratic term B differs from J by the rule's aliasing only: a few per
    cent for this smooth random viscosity (what makes the chord iteration converge)."""
    Theta = dense.Theta[-1]
    op = model.system.jacobian_operator(Theta, EPS, dt=model.dt)
    J = op.to_dense()
    B = NodalPreconditioner(op)
    n = J.shape[0]
    N, P = model.system.shape
    BinvJ = np.column_stack([B.apply(J[:, j].reshape(N, P)).ravel() for j in range(n)])
    assert np.linalg.norm(np.eye(n) - BinvJ, 2) < 0.1


def test_failures_are_reported(model):
    bad = _march(model, tol=1e-15, maxiter=1)
    assert not bad.success and bad.failed_step == 1
    assert "no convergence in 1 iterations" in bad.message
    with pytest.raises(ConvergenceError, match="Newton failed at step 1"):
        _march(model, tol=1e-15, maxiter=1, strict=True)
    # one GMRES iteration cannot reach the sensitivities' tolerance
    stalled = _march(model, solver={"maxiter": 1}, sensitivities=True)
    assert not stalled.success and "GMRES did not reach its tolerance" in stalled.message


def test_warm_start_same_states_fewer_iterations(model):
    cold = _march(model)
    near = march(model.system, EPS + 0.01, model.Theta0, model.dt, model.n_steps, tol=1e-12)
    warm = _march(model, guess=near)
    assert warm.solver == "gmres+nodal (compiled)"
    np.testing.assert_allclose(warm.Theta, cold.Theta, rtol=0, atol=1e-11)
    assert warm.nit.sum() < cold.nit.sum()
