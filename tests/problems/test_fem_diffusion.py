"""2-D stochastic diffusion with scikit-fem: Galerkin PCE against tensor Gauss collocation
on the same mesh, and calibration of the conductivity from point sensors."""

import numpy as np
import pytest

pytest.importorskip("skfem")

from ecfm_uq.inverse import SteadyProblem, fit
from ecfm_uq.mc import quadrature_moments
from ecfm_uq.problems.fem_diffusion import build_fem_diffusion
from ecfm_uq.system import solve_steady

EPS_TRUE = np.array([0.1, 0.5])


@pytest.fixture(scope="module")
def problem():
    return build_fem_diffusion(n_cells=10, order=3)


@pytest.fixture(scope="module")
def collocation(problem):
    # 6^4 tensor Gauss nodes: exact to ~1e-10 in the variance for this field
    def sample(omega):
        sys1 = problem.deterministic_system(omega)
        sol = solve_steady(sys1, EPS_TRUE, solver="sparse-direct", strict=True)
        return sol.Theta[:, 0]

    return quadrature_moments(sample, 6, dim=4)


def rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def test_galerkin_mean_and_variance_equal_collocation(problem, collocation):
    system = problem.system
    assert (system.N, system.P) == (81, 35)
    sol = solve_steady(system, EPS_TRUE)
    assert sol.success and sol.solver == "cg+mean"
    mu, var = system.mean(sol.Theta), system.variance(sol.Theta)
    mu_c, var_c = collocation
    assert rel(mu, mu_c) < 1e-8
    assert rel(var, var_c) < 1e-6
    # and the error falls with the chaos order (spectral convergence)
    low = build_fem_diffusion(n_cells=10, order=2)
    sol2 = solve_steady(low.system, EPS_TRUE)
    assert rel(low.system.variance(sol2.Theta), var_c) > 10 * rel(var, var_c)


def test_sensor_matrix_interpolates_p1_fields(problem):
    # a linear function is represented exactly by P1: the probes must read it off exactly
    x, y = problem.mesh.p[:, problem.interior]
    u = 2.0 * x - 3.0 * y + 0.5
    expected = 2.0 * problem.sensors[:, 0] - 3.0 * problem.sensors[:, 1] + 0.5
    np.testing.assert_allclose(problem.M_obs @ u, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_calibration_recovers_the_conductivity(problem, formulation):
    system = problem.system
    v = problem.M_obs @ system.mean(solve_steady(system, EPS_TRUE).Theta)
    res = fit(SteadyProblem(system, problem.M_obs, v), [0.0, 0.0], formulation=formulation)
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, EPS_TRUE, atol=1e-6)
    if formulation == "ecfm":
        # consistent data: the forces vanish at the answer
        assert np.linalg.norm(res.forces) < 1e-6 * np.linalg.norm(v)


def test_ecfm_forces_locate_an_unmodelled_source(problem):
    # data from the model plus a point-like source near sensor 2 (x = 0.75, y = 0.25)
    import scipy.sparse.linalg as spla

    system = problem.system
    base = system.mean(solve_steady(system, EPS_TRUE).Theta)
    x, y = problem.mesh.p[:, problem.interior]
    extra = 0.02 * np.exp(-((x - 0.75) ** 2 + (y - 0.25) ** 2) / (2 * 0.05**2))
    K = (10 ** EPS_TRUE[0]) * problem.K0 + EPS_TRUE[1] * problem.Kb
    shift = spla.spsolve(K.tocsc(), extra)  # mean-field response to the missing load
    v = problem.M_obs @ (base + shift)
    res = fit(SteadyProblem(system, problem.M_obs, v), [0.0, 0.0], formulation="ecfm")
    lam = res.forces
    assert np.argmax(np.abs(lam)) == 2


def test_bad_input_names_the_argument(problem):
    with pytest.raises(ValueError, match="conductivity can reach zero"):
        build_fem_diffusion(4, 1, sigmas=(1.0, 1.0, 0.5, 0.5))
    with pytest.raises(ValueError, match="`sensors` must lie strictly inside"):
        build_fem_diffusion(4, 1, sensors=[[0.5, 1.2]])
    with pytest.raises(ValueError, match="`modes` and `sigmas`"):
        build_fem_diffusion(4, 1, modes=[(1, 0)], sigmas=(0.1, 0.1))
    with pytest.raises(ValueError, match=r"`omega` must have shape \(4,\)"):
        problem.deterministic_system([0.5, 0.5])
    with pytest.raises(ValueError, match=r"`omega` must lie in \[0, 1\]\^4"):
        problem.deterministic_system([0.5, 0.5, 0.5, 1.5])
