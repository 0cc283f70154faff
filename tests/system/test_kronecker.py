"""Ullmann's Kronecker-product preconditioner (issue 21, item 2 and 3).

Truth: its defining identities. Each Jacobian part's Kronecker terms reproduce the part's
action; a Jacobian that is one Kronecker product is inverted exactly (one Krylov
iteration); with deterministic couplings the chaos factor is E[Psi Psi^T], i.e. the
mean-based preconditioner.
"""

import numpy as np
import pytest
import scipy.sparse as sp

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.system import (
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    NonlinearTerm,
    QuadraticTerm,
    SolverOptions,
    solve_steady,
)
from ecfm_uq.system.solve.preconditioners import KroneckerPreconditioner, MeanPreconditioner


def _laplacian(N):
    h = 1.0 / (N + 1)
    return sp.diags([-np.ones(N - 1), 2 * np.ones(N), -np.ones(N - 1)], [-1, 0, 1]) / h**2


def _mixed_system(N=12):
    """A linear term, a quadratic term and a NonlinearTerm on two germs."""
    rng = np.random.default_rng(3)
    basis = ChaosBasis(2, dim=2)
    K = _laplacian(N).tocsr()
    B = rng.standard_normal((N, N, N)) * 0.1

    def res(u, w, eps):
        return (1.0 + 0.5 * w[1]) * u**3

    def jac(u, w, eps):
        return np.diag(3.0 * (1.0 + 0.5 * w[1]) * u**2)

    terms = [
        LinearTerm(K, G=weighted_gram(basis, lambda w: 1.0 + 0.4 * w[:, 0])),
        QuadraticTerm(B),
        NonlinearTerm(res, jac, degree=3),
        LoadTerm.constant(np.ones(N)),
    ]
    return GalerkinSystem(terms, 0, basis=basis, M=np.eye(N))


def test_kronecker_terms_reproduce_every_part():
    system = _mixed_system()
    rng = np.random.default_rng(0)
    Theta = 0.3 * rng.standard_normal(system.shape)
    op = system.jacobian_operator(Theta, [], dt=0.1)
    X = rng.standard_normal(system.shape)
    for part in op.parts:
        Y = sum(np.asarray(Kj @ X) @ Cj for Kj, Cj in part.kronecker_terms())
        np.testing.assert_allclose(Y, part.apply(X), rtol=1e-12, atol=1e-12 * abs(Y).max())


def test_a_single_kronecker_product_is_inverted_exactly():
    N = 40
    basis = ChaosBasis(3, dim=2)
    # G not a multiple of E[Psi Psi^T]: the mean-based preconditioner is not exact
    G = weighted_gram(basis, lambda w: (1.0 + 0.8 * w[:, 0]) * (1.0 + 0.5 * w[:, 1]))
    system = GalerkinSystem([LinearTerm(_laplacian(N), G=G), LoadTerm.constant(np.ones(N))], 0,
                            basis=basis)  # fmt: skip
    op = system.jacobian_operator(system.zeros(), [])
    pre = KroneckerPreconditioner(op, symmetric=True)
    assert pre.fallback is None
    X = np.random.default_rng(1).standard_normal(system.shape)
    np.testing.assert_allclose(pre.apply(op.apply(X)), X, rtol=0, atol=1e-9 * abs(X).max())
    np.testing.assert_allclose(
        pre.apply_transpose(op.apply_transpose(X)), X, rtol=0, atol=1e-9 * abs(X).max()
    )
    kron = solve_steady(system, [], solver=SolverOptions("cg", preconditioner="kronecker"))
    mean = solve_steady(system, [], solver=SolverOptions("cg", preconditioner="mean"))
    assert kron.success and mean.success
    assert kron.linear_iterations[0] <= 2 < mean.linear_iterations[0]
    np.testing.assert_allclose(kron.Theta, mean.Theta, rtol=0, atol=1e-9 * abs(mean.Theta).max())


def test_deterministic_couplings_give_the_mean_based_preconditioner():
    N = 20
    basis = ChaosBasis(2, dim=3)
    E2 = weighted_gram(basis, lambda w: np.ones(len(w)))
    terms = [LinearTerm(_laplacian(N), G=2.0 * E2), LinearTerm(sp.identity(N), G=E2),
             LoadTerm.constant(np.ones(N))]  # fmt: skip
    system = GalerkinSystem(terms, 0, basis=basis, M=sp.identity(N))
    op = system.jacobian_operator(system.zeros(), [], dt=0.5)
    R = np.random.default_rng(2).standard_normal(system.shape)
    kron = KroneckerPreconditioner(op, symmetric=True)
    np.testing.assert_allclose(kron.A, system.E2, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(kron.apply(R), MeanPreconditioner(op, "mean").apply(R), rtol=1e-10)


@pytest.mark.parametrize("method", ["cg", "gmres"])
def test_a_lognormal_conductivity_takes_fewer_iterations_than_with_the_mean(method):
    pytest.importorskip("skfem")
    from ecfm_uq.problems.fem_lognormal import build_fem_lognormal

    system = build_fem_lognormal(12, 3, n_kl=4, sigma=1.0, corr_length=0.5).system
    eps = np.zeros(system.n_eps)
    kron = solve_steady(system, eps, solver=SolverOptions(method, preconditioner="kronecker"))
    mean = solve_steady(system, eps, solver=SolverOptions(method, preconditioner="mean"))
    assert kron.success and mean.success
    assert sum(kron.linear_iterations) < 0.85 * sum(mean.linear_iterations)
    scale = abs(mean.Theta).max()
    np.testing.assert_allclose(kron.Theta, mean.Theta, rtol=0, atol=1e-8 * scale)
