"""A dynamic calibration marched by BDF2: adjoint gradients equal central differences of the
discrete objective, and the estimate is recovered from BDF2 data."""

import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis
from ecfm_uq.inverse import fit
from ecfm_uq.inverse.core.finite_differences import fd_gradient
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import march

TRUE = np.array([1.75, 1.0])


@pytest.fixture(scope="module")
def problem():
    model = BurgersModel(
        n_modes=10, n_steps=16, T=0.8, viscosity_chaos=ChaosBasis(2), viscosity_spread=0.4
    )
    system = model.system
    tr = march(system, TRUE, model.Theta0, model.dt, model.n_steps, scheme="bdf2", tol=1e-13)
    V = (tr.Theta @ system.E1) @ model.M_obs.T
    return DynamicInverseProblem(
        system, model.Theta0, model.dt, model.n_steps, model.M_obs, V, solve_tol=1e-13,
        gradient="adjoint", scheme="bdf2",
    )  # fmt: skip


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_bdf2_adjoint_gradient_equals_central_differences(problem, formulation):
    fg = problem.objective(formulation)
    x = np.array([1.6, 1.3])
    _, g = fg(x)
    fd = fd_gradient(lambda e: fg(e)[0], x, 1e-5)  # central differences
    np.testing.assert_allclose(g, fd, rtol=1e-6)


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_bdf2_calibration_recovers_the_parameters(problem, formulation):
    res = fit(problem, [1.5, 0.8], formulation=formulation, uncertainty=False)
    assert res.success
    np.testing.assert_allclose(res.eps, TRUE, rtol=1e-6)


def test_the_euler_calibration_of_bdf2_data_is_biased(problem):
    """The scheme matters: backward Euler misreads second-order data (so the test above
    does not pass by accident)."""
    euler = DynamicInverseProblem(
        problem.system, problem.Theta0, problem.dt, problem.n_steps, problem.M_obs,
        problem.V, solve_tol=1e-13,
    )  # fmt: skip
    res = fit(euler, [1.5, 0.8], formulation="standard", uncertainty=False)
    assert np.abs(res.eps - TRUE).max() > 1e-4


def test_an_unknown_scheme_is_refused(problem):
    with pytest.raises(ValueError, match="`scheme` must be one of"):
        DynamicInverseProblem(
            problem.system, problem.Theta0, problem.dt, problem.n_steps, problem.M_obs,
            problem.V, scheme="crank-nicolson",
        )  # fmt: skip
