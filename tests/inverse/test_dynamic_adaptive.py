"""Dynamic calibration on an error-controlled, frozen step sequence (scheme="adaptive").

Independent truths: central differences of the discrete objective on the frozen grid,
the closed-form logistic solution, and ``integrate(rtol=1e-12)`` (the variable-order NDF,
another code) for the chaos (P > 1) models."""

import numpy as np
import pytest
from _models import diffusion, logistic

from ecfm_uq.inverse import fit
from ecfm_uq.inverse.core.finite_differences import fd_gradient
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
from ecfm_uq.system import integrate, march
from ecfm_uq.system.step_control import step_errors

TRUE = np.array([1.5, 2.0])  # growth rate a, capacity K
U0, T, N_DATA = 0.1, 6.0, 8


def closed_form(t, a, K):
    return K / (1 + (K / U0 - 1) * np.exp(-a * t))


def logistic_problem(order=0, **kw):
    system = logistic(order)
    t = np.linspace(0.0, T, N_DATA + 1)
    if order == 0:
        V = closed_form(t, *TRUE)[:, None]
    else:
        ref = integrate(system, TRUE, np.outer([U0], np.eye(system.P)[0]), t, rtol=1e-12,
                        atol=1e-14)  # fmt: skip
        V = ref.Theta @ system.E1
    return DynamicInverseProblem(system, [U0], T / N_DATA, N_DATA, np.eye(1), V, **kw)


@pytest.mark.parametrize("order", [0, 2])
@pytest.mark.parametrize("gradient", ["adjoint", "forward"])
def test_the_gradient_is_the_derivative_of_the_discrete_objective_on_the_frozen_grid(
    order, gradient
):
    problem = logistic_problem(order, scheme="adaptive", rtol=1e-3, gradient=gradient)
    x = np.array([1.3, 2.3])
    seq = problem.freeze_steps(x)
    assert seq.n_steps > N_DATA  # a genuinely variable grid, not the data grid
    fg = problem.objective("standard")
    _, g = fg(x)
    fd = fd_gradient(lambda e: fg(e)[0], x, 1e-5)  # central differences
    np.testing.assert_allclose(g, fd, rtol=1e-6)
    assert problem.steps is seq  # nothing moved the grid


@pytest.fixture(scope="module")
def logistic_fit():
    problem = logistic_problem(0, scheme="adaptive", rtol=1e-5)
    return problem, fit(problem, [1.2, 2.5], uncertainty=False)


def test_the_calibration_recovers_the_closed_form_parameters(logistic_fit):
    """Data from the exact solution: the estimate is as accurate as the steps asked for
    (3e-5 measured at rtol=1e-5), where backward Euler on the data grid is 24 % off."""
    problem, res = logistic_fit
    assert res.success
    np.testing.assert_allclose(res.eps, TRUE, rtol=1e-4)
    euler = logistic_problem(0)
    off = fit(euler, [1.2, 2.5], uncertainty=False).eps
    assert np.abs(off / TRUE - 1).max() > 1e-2


def test_the_step_sequence_is_reported_and_meets_the_tolerance_at_the_estimate(logistic_fit):
    problem, res = logistic_fit
    steps = res.extra["steps"]
    assert steps["met"] and steps["max_error"] <= 1.0 and steps["n_data"] == N_DATA
    # eps0 = (1.2, 2.5) grows more slowly than the estimate: its grid was refined there
    assert steps["refrozen"]
    np.testing.assert_array_equal(steps["times"], problem.steps.times)
    assert steps["n_steps"] == problem.steps.n_steps > N_DATA
    # independently of the fit: march the estimate on the reported grid
    tr = march(problem.system, res.eps, [U0], times=steps["times"], scheme="bdf2")
    assert step_errors(tr, steps["rtol"], steps["atol"]).max() <= 1.0
    # rtol bounds each step's local error; the global error at the data times, summed
    # over the ~160 steps, stays within 100 rtol of the exact solution (2.7e-4 measured)
    t = problem.t0 + problem.dt * np.arange(N_DATA + 1)
    np.testing.assert_allclose(
        tr.Theta[problem.steps.data_index, 0, 0], closed_form(t, *res.eps), rtol=100 * 1e-5
    )


def test_a_chaos_pde_calibration_recovers_the_parameters():
    """P = 3: diffusion with a random conductivity (tests/_models.diffusion, 12 nodes)
    from zero, three sensors, data from integrate(rtol=1e-12); backward Euler on the data
    grid is 0.2 off in the load."""
    system, M_obs = diffusion(N=12, dim=1, order=2, sparse=False)
    assert system.P == 3
    true = np.array([0.0, 1.0])  # log10 conductivity, load
    t = np.linspace(0.0, 0.2, 6)
    ref = integrate(system, true, np.zeros(system.shape), t, rtol=1e-12, atol=1e-14)
    V = ref.Theta @ system.E1 @ M_obs.T

    def calibrate(**kw):
        problem = DynamicInverseProblem(system, np.zeros(system.N), 0.04, 5, M_obs, V, **kw)
        return fit(problem, [0.3, 0.7], uncertainty=False)

    res = calibrate(scheme="adaptive", rtol=1e-5, atol=1e-8)
    assert res.success and res.extra["steps"]["met"]
    np.testing.assert_allclose(res.eps, true, atol=1e-3)
    assert np.abs(calibrate().eps - true).max() > 0.1


def test_bad_arguments_name_themselves():
    problem = logistic_problem(0)
    args = (problem.system, [U0], problem.dt, N_DATA, np.eye(1), problem.V)
    with pytest.raises(ValueError, match="`rtol` must be positive"):
        DynamicInverseProblem(*args, scheme="adaptive", rtol=0.0)
    with pytest.raises(ValueError, match="`rtol` must be positive"):
        DynamicInverseProblem(*args, scheme="adaptive", rtol=-1e-6)
    with pytest.raises(ValueError, match="`atol` must be >= 0"):
        DynamicInverseProblem(*args, scheme="adaptive", atol=-1.0)
    with pytest.raises(ValueError, match=r"`scheme` must be one of .*'adaptive'"):
        DynamicInverseProblem(*args, scheme="rk45")
    with pytest.raises(ValueError, match=r"`rtol`/`atol` set the steps of scheme='adaptive'"):
        DynamicInverseProblem(*args, scheme="bdf2", rtol=1e-6)
    adaptive = DynamicInverseProblem(*args, scheme="adaptive")
    with pytest.raises(ValueError, match="no frozen steps"):
        adaptive.check_steps(TRUE)
    with pytest.raises(ValueError, match="`force_basis` must be 'constant'"):
        DynamicInverseProblem(*args, scheme="adaptive", force_basis="cubic")
    with pytest.raises(ValueError, match="positive width"):
        DynamicInverseProblem(*args, scheme="adaptive", force_basis={"rbf": -1.0})
