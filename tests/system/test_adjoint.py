"""Adjoint gradients: equal to the forward-sensitivity gradients, and a Taylor test
(remainders falling like h^2) for every objective, steady and time-dependent, P = 1 and
P > 1, on the many-parameter test cases (Fisher-KPP source in 8 x 8 = 64 modes, Burgers
viscosity in 20 cells)."""

import numpy as np
import pytest
import scipy.sparse as sp
from _models import diffusion

from ecfm_uq.chaos import ChaosBasis
from ecfm_uq.inverse import DynamicInverseProblem
from ecfm_uq.inverse.core.gradients import choose_gradient
from ecfm_uq.inverse.formulations.steady import ecfm_objective, standard_objective
from ecfm_uq.inverse.statistics.diagnostics import taylor_remainders
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.problems.fisher_kpp import build_kpp, make_data, sensor_grid
from ecfm_uq.system import solve_steady, solver_options

STEPS = np.array([1e-2, 5e-3, 2.5e-3])


def assert_second_order(fun_and_grad, x, direction):
    r = taylor_remainders(fun_and_grad, x, direction, STEPS)
    rates = np.log(r[:-1] / r[1:]) / np.log(2.0)
    assert np.all(rates > 1.8), (r, rates)


def _steady_pair(objective, system, M_obs, v, eps, **kw):
    fwd = objective(system, M_obs, v, eps, gradient="forward", **kw)
    adj = objective(system, M_obs, v, eps, gradient="adjoint", **kw)
    return fwd, adj


@pytest.fixture(scope="module")
def kpp64():
    # the paper's state basis and data, 25 sensors, the source in 64 modes
    problem = build_kpp(n_state=10, n_source=8, sensors=sensor_grid(5))
    data = make_data(problem, sigma=0.05, seed=1)
    return problem, data


def test_kpp_64_modes_adjoint_equals_forward_and_passes_taylor(kpp64):
    problem, data = kpp64
    system = problem.system
    assert system.n_eps == 64
    rng = np.random.default_rng(0)
    eps = rng.uniform(0.0, 3.0, 64)
    for objective, kw in ((standard_objective, {}), (ecfm_objective, {})):
        (z1, g1, _), (z2, g2, _) = _steady_pair(objective, system, problem.M_obs, data.v, eps, **kw)
        assert z1 == z2
        np.testing.assert_allclose(g2, g1, rtol=1e-8, atol=1e-10 * np.abs(g1).max())

        def fg(e, objective=objective):
            z, g, _ = objective(system, problem.M_obs, data.v, e, gradient="adjoint")
            return z, g

        assert_second_order(fg, eps, rng.standard_normal(64))


def _diffusion(sparse):
    return diffusion(N=16, dim=2 if sparse else 1, order=3, sparse=sparse)


@pytest.mark.parametrize(
    ("solver", "sparse"),
    [
        ("dense", False),
        ("decoupled", False),
        ("sparse-direct", True),
        ("cg", True),
        ("gmres", True),
    ],
)
def test_steady_adjoint_equals_forward_for_every_solver(solver, sparse):
    system, M_obs = _diffusion(sparse)
    M_obs = sp.csr_matrix(M_obs) if sparse else M_obs
    eps = np.array([0.2, 1.1])
    v = M_obs @ system.mean(solve_steady(system, [0.0, 1.0]).Theta)
    opts = {"solver": solver_options(solver, rtol=1e-12)}
    objectives = [standard_objective] + ([ecfm_objective] if solver != "decoupled" else [])
    for objective in objectives:
        (_, g1, _), (_, g2, sol) = _steady_pair(objective, system, M_obs, v, eps, **opts)
        assert sol.solver.startswith(solver if solver != "decoupled" else "decoupled")
        np.testing.assert_allclose(g2, g1, rtol=1e-9)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
@pytest.mark.parametrize("chaos_order", [None, 2])
def test_dynamic_adjoint_burgers_viscosity_in_20_cells(formulation, chaos_order):
    chaos = None if chaos_order is None else ChaosBasis(chaos_order)
    model = BurgersModel(
        n_modes=12,
        n_steps=15,
        T=0.6,
        viscosity_cells=20,
        viscosity_chaos=chaos,
        viscosity_spread=0.3 if chaos else 0.0,
    )
    assert model.system.n_eps == 21
    rng = np.random.default_rng(4)
    eps_true = np.concatenate([1.5 + 0.3 * rng.standard_normal(20), [1.0]])
    V = model.solve(eps_true).Theta @ model.system.E1 @ model.M_obs.T
    kw = {"solve_tol": 1e-12}
    fwd = DynamicInverseProblem(
        model.system,
        model.Theta0,
        model.dt,
        model.n_steps,
        model.M_obs,
        V,
        gradient="forward",
        **kw,
    )
    adj = DynamicInverseProblem(
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V, gradient="auto", **kw
    )
    assert adj.gradient == "adjoint"  # n_eps = 21 > 1 output
    eps = eps_true + 0.1 * rng.standard_normal(21)
    z1, g1 = fwd.objective(formulation)(eps)
    z2, g2 = adj.objective(formulation)(eps)
    # with P > 1 the forward march runs node-preconditioned iterations, the adjoint one
    # keeps dense factors: the same states to the Newton tolerance, not to the last bit
    assert z1 == pytest.approx(z2, rel=1e-10)
    np.testing.assert_allclose(g2, g1, rtol=1e-8, atol=1e-12 * np.abs(g1).max())
    assert_second_order(adj.objective(formulation), eps, rng.standard_normal(21))


def test_choose_gradient():
    assert choose_gradient("auto", 64) == "adjoint"
    assert choose_gradient("auto", 1) == "forward"
    assert choose_gradient("forward", 64) == "forward"
    with pytest.raises(ValueError, match="unknown `gradient`"):
        choose_gradient("reverse", 3)


def test_adjoint_needs_kept_factors_and_matching_shapes():
    from ecfm_uq.system import march

    model = BurgersModel(n_modes=6, n_steps=3, T=0.3)
    traj = march(model.system, [1.5, 1.0], model.Theta0, model.dt, 3)
    with pytest.raises(ValueError, match="keep_factors=True"):
        traj.adjoint_gradient(np.zeros(traj.Theta.shape))
    traj = march(model.system, [1.5, 1.0], model.Theta0, model.dt, 3, keep_factors=True)
    with pytest.raises(ValueError, match="`g_theta` must have shape"):
        traj.adjoint_gradient(np.zeros((2, 6, 1)))
    with pytest.raises(ValueError, match="`g_lam` is only defined"):
        traj.adjoint_gradient(np.zeros(traj.Theta.shape), np.zeros((4, 4)))


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_adjoint_on_the_matrix_free_fem_model_with_patch_conductivity(formulation):
    pytest.importorskip("skfem")
    from ecfm_uq.problems.fem_diffusion import build_fem_diffusion

    problem = build_fem_diffusion(8, 2, patches=3)
    system, M_obs = problem.system, problem.M_obs
    assert system.n_eps == 10
    # the patch operators partition the Laplacian
    K = sum(K for K, _, name in problem.mean_terms if name.startswith("a0 patch"))
    assert abs(K - problem.K0).max() < 1e-13 * abs(problem.K0).max()
    rng = np.random.default_rng(5)
    v = M_obs @ system.mean(solve_steady(system, 0.2 * rng.standard_normal(10)).Theta)
    eps = 0.2 * rng.standard_normal(10)
    objective = standard_objective if formulation == "standard" else ecfm_objective
    opts = {"solver": solver_options("cg", rtol=1e-12)}
    (_, g1, sol), (_, g2, _) = _steady_pair(objective, system, M_obs, v, eps, **opts)
    assert sol.solver == "cg+mean"
    np.testing.assert_allclose(g2, g1, rtol=1e-8, atol=1e-10 * np.abs(g1).max())

    def fg(e):
        z, g, _ = objective(system, M_obs, v, e, gradient="adjoint", **opts)
        return z, g

    assert_second_order(fg, eps, rng.standard_normal(10))
