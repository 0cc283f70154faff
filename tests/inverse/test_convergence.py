"""Convergence read from the optimality conditions (issue 20, item 2): the relative-offset
test against its closed form on a linear model, its independence of units, the refusals
(an asymptote, a budget spent, Adam's fixed epochs), the least-squares default of the
steady and dynamic fits, and the Gauss-Newton standard errors."""

import warnings

import numpy as np
import pytest

from ecfm_uq.inverse import DynamicInverseProblem, FitStatus, SteadyProblem, fit
from ecfm_uq.inverse.core.convergence import (
    OFFSET_TOL,
    gradient_optimality,
    least_squares_optimality,
    polish_least_squares,
)
from ecfm_uq.spectral import SineBasis, load, sensor_matrix, stiffness
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

RNG = np.random.default_rng(20)
X = np.column_stack([np.ones(12), np.linspace(0, 1, 12), np.linspace(0, 1, 12) ** 2])
Y = X @ [1.0, -2.0, 0.5] + 0.1 * RNG.standard_normal(12)
B_HAT = np.linalg.lstsq(X, Y, rcond=None)[0]


def test_relative_offset_is_the_closed_form_of_bates_and_watts():
    """Linear model: Q1^T r(b) = R (b - b_hat) and the orthogonal part is r(b_hat), so the
    offset at b_hat + d is ||X d|| / sqrt(p) / (||r(b_hat)|| / sqrt(n - p))."""
    n, p = X.shape
    at = least_squares_optimality(X @ B_HAT - Y, X, B_HAT)
    assert at.converged and at.value < 1e-12 and at.test == "relative offset"
    d = np.array([1e-3, -2e-3, 5e-4])
    want = np.linalg.norm(X @ d) / np.sqrt(p) / (np.linalg.norm(X @ B_HAT - Y) / np.sqrt(n - p))
    off = least_squares_optimality(X @ (B_HAT + d) - Y, X, B_HAT + d)
    assert off.value == pytest.approx(want, rel=1e-10)
    assert not off.converged and off.value > OFFSET_TOL


def test_the_test_does_not_depend_on_units():
    """Residuals times c (the data's units), parameter k times s_k (its units): the same
    offset and the same decision."""
    d = np.array([1e-7, 3e-7, -1e-7])
    b = B_HAT + d
    base = least_squares_optimality(X @ b - Y, X, b)
    c, s = 1e4, np.array([1e-3, 1e2, 7.0])
    scaled = least_squares_optimality(c * (X @ b - Y), c * X / s, b * s)
    assert scaled.value == pytest.approx(base.value, rel=1e-8)
    assert scaled.converged == base.converged


def test_kkt_on_a_bound_with_the_gradient_pointing_out():
    b = B_HAT.copy()
    b[0] = B_HAT[0] + 0.1  # pushed off the optimum in eps[0], held there by a bound
    r = X @ b - Y
    g0 = (X.T @ r)[0]
    assert g0 > 0
    # the rest re-optimized with eps[0] fixed
    b[1:] = np.linalg.lstsq(X[:, 1:], Y - X[:, 0] * b[0], rcond=None)[0]
    r = X @ b - Y
    bounds = [(b[0], None), (None, None), (None, None)]
    assert least_squares_optimality(r, X, b, bounds=bounds).converged
    assert not least_squares_optimality(r, X, b).converged  # without the bound: not optimal


def test_polish_takes_a_point_near_the_optimum_to_it():
    b0 = B_HAT + [1e-2, -1e-2, 3e-2]
    x, (r, J, _), opt, nfev = polish_least_squares(lambda b: (X @ b - Y, X, None), b0)
    assert opt.converged and nfev <= 4
    np.testing.assert_allclose(x, B_HAT, rtol=1e-10)


def test_newton_decrement_of_a_quadratic_and_the_refusal_of_a_saddle():
    """z = 1/2 x^T H x - b^T x: the decrement at x is 1/2 (Hx - b)^T H^-1 (Hx - b)."""
    H = np.array([[4.0, 1.0], [1.0, 3.0]])
    b = np.array([1.0, 2.0])
    x_star = np.linalg.solve(H, b)
    z = 0.5 * x_star @ H @ x_star - b @ x_star
    assert gradient_optimality(z, H @ x_star - b, H).converged
    x = x_star + [1e-2, 0.0]
    g = H @ x - b
    opt = gradient_optimality(0.5 * x @ H @ x - b @ x, g, H)
    assert not opt.converged
    assert opt.value == pytest.approx(0.5 * g @ np.linalg.solve(H, g), rel=1e-12)  # |z| < 1
    saddle = gradient_optimality(0.0, np.zeros(2), np.diag([1.0, -1.0]))
    assert not saddle.converged and "not positive definite" in saddle.message


# -- steady fits ----------------------------------------------------------------------
BASIS = SineBasis(8)
SENS = np.array([0.25, 0.5, 0.75])
M_OBS = sensor_matrix(BASIS, SENS)


def conductivity_model():
    """-(10^eps0) w'' = 1: the parameter inside the operator."""
    return GalerkinSystem(
        [
            LinearTerm(stiffness(BASIS), Coefficient.power10(0, sign=1.0)),
            LoadTerm.constant(load(BASIS, np.ones_like)),
        ],
        1,
    )


def test_wrong_sign_data_are_not_a_success():
    """Data of the wrong sign: the misfit falls forever as the conductivity grows (an
    asymptote). BFGS used to stop at eps ~ 10 and report success."""
    system = conductivity_model()
    v = -M_OBS @ solve_steady(system, [0.3]).Theta[:, 0]
    for method in ("auto", "BFGS"):
        res = fit(SteadyProblem(system, M_OBS, v), [0.0], method=method, sigma=1e-3)
        assert not res.success and res.status is FitStatus.STALLED, (method, res.message)
        assert res.eps[0] > 5 and res.optimality > OFFSET_TOL
        assert "NOT converged" in res.message


def test_budget_spent_is_max_iterations():
    system = conductivity_model()
    v = M_OBS @ solve_steady(system, [0.3]).Theta[:, 0] * (1 + 1e-3 * np.array([1, -1, 1]))
    res = fit(SteadyProblem(system, M_OBS, v), [2.0], maxiter=2)
    assert res.status is FitStatus.MAX_ITERATIONS and not res.success
    full = fit(SteadyProblem(system, M_OBS, v), [2.0])
    assert full.success and full.optimality <= OFFSET_TOL and full.method == "least-squares"


def two_parameter_model():
    """-(10^eps0) w'' + 20 w = eps1 * x: nonlinear in eps0 (the reaction term makes the
    conductivity change the shape, not only the size, of w)."""
    return GalerkinSystem(
        [
            LinearTerm(stiffness(BASIS), Coefficient.power10(0, sign=1.0)),
            LinearTerm(20 * np.eye(BASIS.size) / 2, name="reaction"),
            LoadTerm.scaled(load(BASIS, lambda x: x), Coefficient.parameter(1)),
        ],
        2,
    )


def test_gauss_newton_standard_errors_are_s2_inverse_jtj():
    """The default covariance is s^2 (J^T J)^-1 with J by central differences of the
    model (independent of the sensitivities); the sandwich is there on request, labelled."""
    system = two_parameter_model()
    M = sensor_matrix(BASIS, np.linspace(0.1, 0.9, 7))
    v = M @ solve_steady(system, [0.2, 3.0]).Theta[:, 0]
    v = v * (1 + 0.05 * np.random.default_rng(1).standard_normal(v.size))
    res = fit(SteadyProblem(system, M, v), [0.0, 1.0])
    assert res.success and res.uncertainty.method == "gauss-newton"

    def pred(e):
        return M @ solve_steady(system, e).Theta[:, 0]

    J = np.column_stack([(pred(res.eps + h) - pred(res.eps - h)) / 2e-6 for h in 1e-6 * np.eye(2)])
    r = pred(res.eps) - v
    s2 = r @ r / (v.size - 2)
    np.testing.assert_allclose(res.uncertainty.cov, s2 * np.linalg.inv(J.T @ J), rtol=1e-6)
    sand = fit(SteadyProblem(system, M, v), [0.0, 1.0], options={"covariance": "sandwich"})
    assert sand.uncertainty.method == "implicit"
    assert not np.allclose(
        sand.uncertainty.cov, res.uncertainty.cov, rtol=1e-3
    )  # a nonlinear model
    with pytest.raises(ValueError, match="covariance"):
        fit(SteadyProblem(system, M, v), [0.0, 1.0], options={"covariance": "hessian"})


# -- dynamic fits ---------------------------------------------------------------------
@pytest.fixture(scope="module")
def burgers():
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=16, n_steps=40)
    V = m.measure(m.solve(np.array([1.75, 1.0]), strict=True))

    def problem():
        return DynamicInverseProblem(
            m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V, solve_tol=m.newton_tol
        )

    return problem


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_twenty_adam_epochs_are_not_a_success(burgers, formulation):
    """Issue 20: 20 Adam epochs from (1.0, 0.2) stop far from the truth (1.75, 1.0)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        res = fit(burgers(), [1.0, 0.2], formulation=formulation, method="adam", maxiter=20)
    assert np.abs(res.eps - [1.75, 1.0]).max() > 0.1
    assert res.status is FitStatus.MAX_ITERATIONS and not res.success
    assert res.optimality > OFFSET_TOL and "NOT converged" in res.message


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
def test_the_dynamic_default_converges(burgers, formulation):
    res = fit(burgers(), [1.0, 0.2], formulation=formulation)
    assert res.method == "least-squares"
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, [1.75, 1.0], rtol=1e-8)


@pytest.mark.parametrize("method", ["auto", "BFGS"])
def test_no_failure_among_fits_at_their_optimum(method):
    """Issue 20: a two-parameter model with the conductivity in the operator, 2 % noise of
    known sigma: every fit ends at its optimum (checked independently: the refit from the
    estimate does not move) and says so, whatever BFGS's line search reported."""
    system = two_parameter_model()
    M = sensor_matrix(BASIS, np.linspace(0.1, 0.9, 6))
    v0 = M @ solve_steady(system, [0.2, 3.0]).Theta[:, 0]
    sigma = 0.02 * np.abs(v0).mean()
    for seed in range(12):
        v = v0 + sigma * np.random.default_rng(seed).standard_normal(v0.size)
        problem = SteadyProblem(system, M, v)
        res = fit(problem, [0.0, 1.0], sigma=sigma, method=method, uncertainty=False)
        assert res.success, (seed, res.message)
        again = fit(problem, res.eps, sigma=sigma, uncertainty=False)
        np.testing.assert_allclose(again.eps, res.eps, rtol=1e-6)


def test_dynamic_gauss_newton_covariance_is_sigma2_inverse_gtg(burgers):
    """Noisy trajectory data, sigma known: the default covariance of a dynamic fit is
    sigma^2 (G^T G)^-1 with G the sensor-trajectory sensitivity, here by central
    differences of the forward model (independent of the sensitivity equations)."""
    p = burgers()
    V = p.V.copy()
    V[1:] += 0.01 * np.random.default_rng(3).standard_normal(V[1:].shape)
    p.V = V
    res = fit(p, [1.6, 0.8], sigma=0.01)
    assert res.success and res.uncertainty.method == "gauss-newton", res.message

    def pred(e):
        return p.predictions(p.solve(e, "standard"))[1:].ravel()

    h = 1e-6
    G = np.column_stack([(pred(res.eps + d) - pred(res.eps - d)) / (2 * h) for d in h * np.eye(2)])
    np.testing.assert_allclose(res.uncertainty.cov, 0.01**2 * np.linalg.inv(G.T @ G), rtol=1e-5)
    sand = fit(p, [1.6, 0.8], sigma=0.01, options={"covariance": "sandwich"})
    assert sand.uncertainty.method == "implicit"


def test_kkt_test_on_a_quadratic_program_with_known_multipliers():
    """min 1/2 ||z - a||^2 s.t. z0 + z1 = 1, z1 >= 0.6 (scaled): the solution and its
    multipliers are known in closed form; a shifted point, an infeasible one and a bound
    held by a multiplier of the wrong sign are refused."""
    from ecfm_uq.inverse.core.convergence import KKT_TOL, kkt_optimality

    a = np.array([2.0, 0.0, 3.0])
    H = np.array([[1.0, 1.0, 0.0]])
    C = np.array([[0.0, 1.0, 0.0]]) / 0.6  # (z1 - 0.6) / 0.6 >= 0

    def check(z):
        f = 0.5 * np.sum((z - a) ** 2)
        return kkt_optimality(z, f, z - a, H @ z - 1.0, H, (C @ z - 1.0), C, f_scale=10.0)

    # with z1 = 0.6 active: z0 = 0.4; grad = (-1.6, 0.6, 0) = y (1, 1, 0) + mu (0, 1/0.6, 0)
    # gives y = -1.6, mu = 1.32 >= 0
    z_star = np.array([0.4, 0.6, 3.0])
    ok = check(z_star)
    assert ok.converged and ok.test == "kkt" and ok.value <= 1e-12
    assert "1 active" in ok.message
    shifted = check(z_star + np.array([1e-3, -1e-3, 1e-3]))  # feasible for the equality only
    assert not shifted.converged
    moved = check(np.array([0.4, 0.6, 3.0 + 1e-3]))  # feasible, not stationary in z2
    assert not moved.converged and moved.value > KKT_TOL
    # without the inequality the optimum is z = (1.5, -0.5, 3): there the bound is
    # violated; at z1 = 0.6 with the bound pulling the wrong way (a = (0, 2, 3)) the
    # multiplier would be negative: not a KKT point
    a[:] = [0.0, 2.0, 3.0]
    wrong_sign = check(np.array([0.4, 0.6, 3.0]))
    assert not wrong_sign.converged
    a[:] = [2.0, 0.0, 3.0]
    assert not check(np.array([1.5, -0.5, 3.0])).converged  # infeasible
    assert np.isinf(check(np.array([1.5, -0.5, 3.0])).value)
    # units: scaling the objective and the equations changes nothing
    f, g = 0.5 * np.sum((z_star - a) ** 2), z_star - a
    scaled = kkt_optimality(z_star, 1e9 * f, 1e9 * g, 1e-6 * (H @ z_star - 1.0), 1e-6 * H,
                            C @ z_star - 1.0, C)  # fmt: skip
    assert scaled.converged


def test_all_at_once_status_comes_from_the_kkt_conditions():
    """The SLSQP fits are judged by the KKT test, not by SLSQP's own success: stopped by
    the iteration budget they are MAX_ITERATIONS, converged they carry the measured
    stationarity."""
    from ecfm_uq.inverse.core.convergence import KKT_TOL

    system = two_parameter_model()
    v = M_OBS @ solve_steady(system, [0.3, 2.0]).Theta[:, 0] * (1 + 1e-2 * np.array([1, -1, 1]))
    problem = SteadyProblem(system, M_OBS, v)
    stopped = fit(problem, [0.0, 1.0], method="all-at-once", maxiter=2)
    assert stopped.status is FitStatus.MAX_ITERATIONS, stopped.message
    assert "KKT" in stopped.message or "infeasible" in stopped.message
    done = fit(problem, [0.0, 1.0], method="all-at-once")
    assert done.status is FitStatus.CONVERGED, done.message
    assert done.optimality <= KKT_TOL and done.method == "SLSQP"
    reduced = fit(problem, [0.0, 1.0])
    np.testing.assert_allclose(done.eps, reduced.eps, rtol=1e-5)


def test_scaled_gradient_test_projects_active_bounds():
    """The random-force fit's test: the gradient in standard-error units, components held
    at a bound by a gradient pointing out of the box dropped (and only those)."""
    from ecfm_uq.inverse.core.convergence import SCALED_GRADIENT_TOL, scaled_gradient_optimality

    assert scaled_gradient_optimality([1e-4, -5e-4]).converged
    off = scaled_gradient_optimality([1e-4, 2e-3])
    assert not off.converged and off.value == 2e-3 and off.tol == SCALED_GRADIENT_TOL
    # x1 at its upper bound 0, pushed up (g < 0: decreasing x1's objective means x1 up)
    held = scaled_gradient_optimality([1e-4, -0.5], [0.3, 0.0], [(None, None), (None, 0.0)])
    assert held.converged
    # the same gradient at the lower bound points into the box: not held, not optimal
    free = scaled_gradient_optimality([1e-4, -0.5], [0.3, 0.0], [(None, None), (0.0, None)])
    assert not free.converged
    assert not scaled_gradient_optimality([np.nan]).converged
