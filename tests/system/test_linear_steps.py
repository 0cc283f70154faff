"""A linear system costs one Krylov solve; a linear march warm-starts each step (issue 21).

Truth: scipy's ``spsolve`` of the assembled Galerkin matrix (steady) and backward Euler
with ``splu`` of the assembled step matrix (transient).
"""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ecfm_uq.chaos import ChaosBasis, expectation_tensor, weighted_gram
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, march, solve_steady
from ecfm_uq.system.model.terms import _sparse_coupling, _without_roundoff
from ecfm_uq.system.stepping import _warm_start


def _random_heat(N=300, order=3, units=1.0):
    """1-D finite differences, conductivity 1 + 0.3 w1 + 0.2 w2 + 0.1 w3 (three germs)."""
    h = 1.0 / (N + 1)
    K = sp.diags([-np.ones(N - 1), 2 * np.ones(N), -np.ones(N - 1)], [-1, 0, 1], format="csr")
    K = units * K / h**2
    x = np.linspace(h, 1 - h, N)
    F = units * (np.sin(np.pi * x) + 1.0)
    basis = ChaosBasis(order, dim=3)
    terms = [LinearTerm(K, G=weighted_gram(basis, lambda w: 1.0 + 0.3 * w[:, 0]))]
    for k, a in ((1, 0.2), (2, 0.1)):
        terms.append(LinearTerm(K, G=weighted_gram(basis, lambda w, k=k, a=a: a * w[:, k])))
    terms.append(LoadTerm.constant(F))
    return GalerkinSystem(terms, 0, basis=basis, M=units * sp.identity(N, format="csr"))


@pytest.mark.parametrize("solver", ["cg", "gmres"])
def test_a_linear_steady_system_costs_one_krylov_solve(solver):
    system = _random_heat()
    sol = solve_steady(system, [], solver=solver)
    assert sol.success, sol.message
    assert len(sol.linear_iterations) == 1  # before: a second solve after convergence
    A = system.jacobian_operator(system.zeros(), []).to_sparse().tocsc()
    ref = spla.spsolve(A, -system.residual(system.zeros(), []).ravel())
    np.testing.assert_allclose(sol.Theta.ravel(), ref, rtol=0, atol=1e-9 * abs(ref).max())


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
def test_a_linear_march_matches_backward_euler_with_at_most_one_solve_a_step(units):
    system = _random_heat(units=units)
    N, P = system.shape
    dt, n_steps = 2e-3, 40
    tr = march(system, [], np.zeros((N, P)), dt, n_steps, solver="cg")
    assert tr.success, tr.message
    # one Krylov solve per step at most (warm starts may need none late in the march)
    assert len(tr.linear_iterations) <= n_steps
    assert np.all(tr.nit <= 1)
    A = system.jacobian_operator(system.zeros(), [], dt=dt).to_sparse().tocsc()
    Mdt = system.mass_matrix(sparse=True) / dt
    lu = spla.splu(A)
    b0 = -system.residual(system.zeros(), []).ravel()  # the load (linear part is zero there)
    x = np.zeros(N * P)
    for s in range(n_steps):
        x = lu.solve(Mdt @ x + b0)
        np.testing.assert_allclose(
            tr.Theta[s + 1].ravel(), x, rtol=0, atol=1e-8 * abs(x).max(), err_msg=f"step {s}"
        )


def test_warm_starts_cut_the_krylov_work_of_a_march():
    system = _random_heat()
    N, P = system.shape
    tr = march(system, [], np.zeros((N, P)), 2e-3, 40, solver="cg")
    # the same march without warm starts: every step from the previous state, i.e. the
    # steps one at a time (each a one-step march from the last state)
    cold, Theta = [], np.zeros((N, P))
    for _ in range(40):
        one = march(system, [], Theta, 2e-3, 1, solver="cg")
        cold += list(one.linear_iterations)
        Theta = one.Theta[-1]
    np.testing.assert_allclose(tr.Theta[-1], Theta, rtol=0, atol=1e-8 * abs(Theta).max())
    assert sum(tr.linear_iterations) < 0.9 * sum(cold)


def test_the_warm_start_is_no_worse_than_the_last_state_or_extrapolation():
    system = _random_heat(N=50)
    N, P = system.shape
    dt = 2e-3
    tr = march(system, [], np.zeros((N, P)), dt, 4, solver="cg")

    prev = tr.Theta[3]

    def fun(z):
        r = system.apply_mass(z.reshape(N, P) - prev).ravel() / dt
        r = r + system.residual(z.reshape(N, P), []).ravel()
        return r, system.jacobian_operator(z.reshape(N, P), [], dt=dt)

    z0, (r0, _) = _warm_start(fun, tr.Theta[1:4])
    np.testing.assert_allclose(r0, fun(z0)[0], rtol=0, atol=1e-12 * np.linalg.norm(r0))
    last, extrapolated = tr.Theta[3].ravel(), (2 * tr.Theta[3] - tr.Theta[2]).ravel()
    rn = np.linalg.norm(fun(z0)[0])
    assert rn <= np.linalg.norm(fun(last)[0]) and rn <= np.linalg.norm(fun(extrapolated)[0])
    assert rn < 0.2 * np.linalg.norm(fun(last)[0])  # a smooth transient is well predicted


def test_round_off_does_not_make_a_coupling_dense():
    basis = ChaosBasis(3, dim=4)
    G = weighted_gram(basis, lambda w: w[:, 1] - 0.5)  # germs on [0, 1]: a centred one
    Gs = _sparse_coupling(_without_roundoff(G))
    assert Gs is not None
    # exactly the entries of multi-indices differing by one degree in germ 2
    mi = np.asarray(basis.indices)
    diff = np.abs(mi[:, None, :] - mi[None, :, :])
    true = (diff[:, :, 1] == 1) & (diff.sum(axis=2) == 1)
    assert Gs.nnz == np.count_nonzero(true)
    np.testing.assert_allclose(Gs.toarray(), G, rtol=0, atol=1e-13 * abs(G).max())
    # the term bound to a system drops them everywhere: in the matrix-free product and in
    # the assembled Jacobian of the sparse direct solver alike
    K = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(20, 20), format="csr")
    term = LinearTerm(K, G=G).bind(np.asarray(expectation_tensor(basis, 2), dtype=float))
    assert np.count_nonzero(term.G) == Gs.nnz
    assert term.kron("sparse").nnz == K.nnz * Gs.nnz


def test_a_krylov_solve_that_falls_short_says_what_it_reached_and_what_is_attainable():
    from ecfm_uq.system import SolverOptions

    system = _random_heat(N=200)
    sol = solve_steady(system, [], solver=SolverOptions("cg", preconditioner="none", maxiter=3))
    assert not sol.success
    msg = sol.message
    assert (
        "did not reach rtol=" in msg and "relative residual" in msg and "after 3 iterations" in msg
    )
    assert "floating point can reach about" in msg
