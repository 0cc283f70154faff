"""Newton's termination does not depend on the model's units (issue 21, item 1).

A 1-D finite-difference Poisson matrix in plain units has entries 1/h^2 ~ 4e6 at
N = 2000, so round-off alone leaves a residual ~1e-8, above the absolute tol = 1e-10:
every solver must still stop at the round-off floor of the model's own scale and match
scipy's spsolve, in plain units and scaled by 1e-9 and 1e9.
"""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ecfm_uq.chaos import ChaosBasis, weighted_gram
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, QuadraticTerm, march, solve_steady
from ecfm_uq.system.solve.plan import SolveStatus, newton_converged, residual_floor


def _poisson(N):
    h = 1.0 / (N + 1)
    K = sp.diags([-np.ones(N - 1), 2 * np.ones(N), -np.ones(N - 1)], [-1, 0, 1], format="csr")
    x = np.linspace(h, 1 - h, N)
    return K / h**2, np.pi**2 * np.sin(np.pi * x) + 1.0


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
@pytest.mark.parametrize("solver", ["auto", "dense", "sparse-direct", "cg", "gmres"])
def test_poisson_in_any_units_matches_spsolve(units, solver):
    K, F = _poisson(2000)
    K = units * K
    ref = spla.spsolve(K.tocsc(), F)
    system = GalerkinSystem([LinearTerm(K), LoadTerm.constant(F)], 0)
    sol = solve_steady(system, [], solver=solver)
    assert sol.success and sol.status == SolveStatus.CONVERGED, sol.message
    np.testing.assert_allclose(sol.Theta[:, 0], ref, rtol=0, atol=1e-8 * np.abs(ref).max())
    # the absolute test alone could not have stopped: round-off sits above tol = 1e-10
    assert sol.residual_norm > 1e-10


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
def test_random_poisson_in_any_units_matches_spsolve_of_the_galerkin_matrix(units):
    # conductivity 1 + 0.3 w1 + 0.2 w2 (two germs): "auto" takes a Krylov method
    N = 400
    K, F = _poisson(N)
    K = units * K
    basis = ChaosBasis(2, dim=2)
    G1 = weighted_gram(basis, lambda w: 1.0 + 0.3 * w[:, 0])
    G2 = weighted_gram(basis, lambda w: 0.2 * w[:, 1])
    terms = [LinearTerm(K, G=G1), LinearTerm(K, G=G2), LoadTerm.constant(F)]
    system = GalerkinSystem(terms, 0, basis=basis)
    sol = solve_steady(system, [])
    assert sol.success, sol.message
    assert sol.solver.startswith(("cg", "gmres"))
    A = system.jacobian_operator(system.zeros(), []).to_sparse().tocsc()
    b = -system.residual(system.zeros(), []).ravel()
    ref = spla.spsolve(A, b).reshape(N, system.P)
    np.testing.assert_allclose(sol.Theta, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def test_well_scaled_models_still_stop_on_the_absolute_tol():
    # the floor only counts where it exceeds tol: here it is far below
    assert residual_floor(1.0, 1e-10) == 0.0
    assert not newton_converged(2e-10, 1e-10, residual_floor(1.0, 1e-10))
    # a model of scale 1e8 cannot get below ~2e-7: that is converged
    floor = residual_floor(1e8, 1e-10)
    assert floor == pytest.approx(10 * np.finfo(float).eps * 1e8)
    assert newton_converged(1e-7, 1e-10, floor) and not newton_converged(1e-5, 1e-10, floor)


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
@pytest.mark.parametrize("compiled", [True, False])
def test_a_march_of_the_whole_model_in_any_units_matches_backward_euler(units, compiled):
    # M, K and F all scaled: the states are the same, the residual's round-off scales
    N, dt, n_steps = 100, 1e-3, 5
    K, F = _poisson(N)
    M = sp.identity(N, format="csr")
    x = np.linspace(0, 1, N + 2)[1:-1]
    theta0 = np.sin(2 * np.pi * x)
    A = (M / dt + K).tocsc()
    ref = [theta0]
    for _ in range(n_steps):
        ref.append(spla.spsolve(A, M @ ref[-1] / dt + F))
    terms = [LinearTerm((units * K).toarray()), LoadTerm.constant(units * F)]
    system = GalerkinSystem(terms, 0, M=units * M.toarray())
    tr = march(system, [], theta0, dt, n_steps, solver={"compiled": compiled})
    assert tr.success and tr.solver == ("dense (compiled)" if compiled else "dense"), tr.message
    scale = np.abs(ref).max()
    np.testing.assert_allclose(tr.Theta[:, :, 0], ref, rtol=0, atol=1e-8 * scale)


def _random_burgers_like(units, N=24):
    """A nonlinear one-germ model (the compiled P > 1 march takes it), all terms x units."""
    K, F = _poisson(N)
    A = np.zeros((N, N, N))
    for i in range(1, N - 1):  # a centred u u_x
        A[i, i, i + 1], A[i, i, i - 1] = 0.25 * (N + 1), -0.25 * (N + 1)
    basis = ChaosBasis(3)
    G = weighted_gram(basis, lambda w: 1.0 + 0.3 * np.ravel(w))
    terms = [
        LinearTerm(units * 0.05 * K.toarray(), G=G),
        QuadraticTerm(units * A),
        LoadTerm.constant(units * 10 * F),
    ]
    return GalerkinSystem(terms, 0, basis=basis, M=units * np.eye(N))


@pytest.mark.parametrize("units", [1e-9, 1e3, 1e9])
def test_the_compiled_stochastic_march_in_any_units_matches_the_dense_march(units):
    # x1e9: the round-off floor (~1e-5 here) is far above tol = 1e-10; x1e-9: tol is
    # taken relative to the step's scale (plan.scaled_tol), in the kernel as in Python
    dt, n_steps = 2e-3, 4
    ref = march(_random_burgers_like(1.0), [], np.zeros(24), dt, n_steps, solver="dense")
    tr = march(_random_burgers_like(units), [], np.zeros(24), dt, n_steps)
    assert ref.success and tr.success, tr.message
    assert tr.solver == "gmres+nodal (compiled)"
    scale = np.abs(ref.Theta).max()
    np.testing.assert_allclose(tr.Theta, ref.Theta, rtol=0, atol=1e-8 * scale)


def _random_poisson_system(N, units, M=None):
    """Conductivity 10^eps0 (1 + 0.3 w1) + 0.2 w2 on the plain-units Poisson matrix."""
    from ecfm_uq.system import Coefficient

    K, F = _poisson(N)
    K = units * K
    basis = ChaosBasis(2, dim=2)
    G1 = weighted_gram(basis, lambda w: 1.0 + 0.3 * w[:, 0])
    G2 = weighted_gram(basis, lambda w: 0.2 * w[:, 1])
    terms = [
        LinearTerm(K, coef=Coefficient.power10(0, sign=1.0), G=G1),
        LinearTerm(K, G=G2),
        LoadTerm.constant(units * F),
    ]
    return GalerkinSystem(terms, 1, basis=basis, M=M)


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
@pytest.mark.parametrize(
    "solver",
    [
        "dense",
        "sparse-direct",
        "cg",
        "gmres",
        {"solver": "cg", "preconditioner": "mean"},
        {"solver": "cg", "preconditioner": "kronecker"},
    ],
)
def test_a_random_model_in_any_units_matches_spsolve_in_every_solver(units, solver):
    system = _random_poisson_system(300, units)
    eps = [0.1]
    sol = solve_steady(system, eps, solver=solver)
    assert sol.success, sol.message
    A = system.jacobian_operator(system.zeros(), eps).to_sparse().tocsc()
    ref = spla.spsolve(A, -system.residual(system.zeros(), eps).ravel()).reshape(system.shape)
    np.testing.assert_allclose(sol.Theta, ref, rtol=0, atol=1e-8 * np.abs(ref).max())


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
@pytest.mark.parametrize("solver", ["dense", "sparse-direct", "cg", "gmres"])
def test_a_random_march_in_any_units_matches_backward_euler_in_every_solver(units, solver):
    N, dt, n_steps = 150, 1e-3, 8
    system = _random_poisson_system(N, units, M=units * sp.identity(N, format="csr"))
    eps = [0.0]
    tr = march(system, eps, np.zeros(system.shape), dt, n_steps, solver=solver)
    assert tr.success, tr.message
    A = system.jacobian_operator(system.zeros(), eps, dt=dt).to_sparse().tocsc()
    Mdt = system.mass_matrix(sparse=True) / dt
    lu = spla.splu(A)
    b = -system.residual(system.zeros(), eps).ravel()
    x = np.zeros(A.shape[0])
    for s in range(n_steps):
        x = lu.solve(Mdt @ x + b)
        np.testing.assert_allclose(tr.Theta[s + 1].ravel(), x, rtol=0, atol=1e-8 * abs(x).max())


@pytest.mark.parametrize("units", [1.0, 1e-9, 1e9])
def test_a_calibration_in_any_units_recovers_the_parameter(units):
    from ecfm_uq.inverse import SteadyProblem, fit

    N = 200
    system = _random_poisson_system(N, units)
    M_obs = np.zeros((5, N))
    M_obs[np.arange(5), np.linspace(20, 180, 5).astype(int)] = 1.0
    truth = 0.3
    v = M_obs @ system.mean(solve_steady(system, [truth]).Theta)  # exact data
    res = fit(SteadyProblem(system, M_obs, v), [0.0], formulation="standard")
    assert res.success, res.message
    assert abs(res.eps[0] - truth) < 1e-8


@pytest.mark.parametrize("solver", ["dense", "gmres"])
def test_a_nonlinear_model_times_any_constant_gives_the_same_answer(solver):
    """Steady and transient, a cubic reaction written as a NonlinearTerm: the equations
    x1e-9 and x1e9 converge to the plain-units answer (to round-off), with success."""
    from ecfm_uq.system import NonlinearTerm

    K, F = _poisson(40)
    K = K.toarray() / 1e3
    basis = ChaosBasis(3, dim=2)
    G = weighted_gram(basis, lambda w: 1.0 + 0.5 * w[:, 0])
    out = {}
    for c in (1.0, 1e-9, 1e9):

        def res(u, w, eps, c=c):
            return c * 30.0 * (1.0 + 0.5 * w[1]) * u**3

        def jac(u, w, eps, c=c):
            return np.diag(c * 90.0 * (1.0 + 0.5 * w[1]) * u**2)

        terms = [LinearTerm(c * K, G=G), NonlinearTerm(res, jac), LoadTerm.constant(c * F)]
        system = GalerkinSystem(terms, 0, basis=basis, M=c * np.eye(40))
        sol = solve_steady(system, [], solver=solver)
        tr = march(system, [], np.zeros(system.shape), 1e-2, 4, solver=solver)
        assert sol.success and tr.success, (c, sol.message, tr.message)
        out[c] = (sol.Theta, tr.Theta)
    for c in (1e-9, 1e9):
        for got, ref in zip(out[c], out[1.0], strict=True):
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
