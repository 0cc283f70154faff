"""OdeProblem without `jac`: the sensitivities from complex steps of `rhs` (when it is
analytic) or from differences, against the closed form of exponential decay
y' = -k y, y(t) = y0 exp(-k t), against solve_ivp with finite differences of the whole
solution (scipy's route), and the fit against curve_fit on the closed form."""

import numpy as np
import pytest
from scipy import optimize
from scipy.integrate import solve_ivp

from ecfm_uq.inverse import OdeProblem, fit

T = np.linspace(0.5, 4.0, 8)
TRUTH = np.array([0.7, 3.0])  # k, y0
RTOL = 1e-11


def decay(t, y, e):
    return -e[0] * y


def decay_abs(t, y, e):  # the same ODE for y > 0, written with abs: not complex-analytic
    return -e[0] * np.abs(y)


def closed_form(e, t=T):
    return e[1] * np.exp(-e[0] * t)


def closed_jacobian(e, t=T):
    x = np.exp(-e[0] * t)
    return np.column_stack([-t * e[1] * x, x])


def problem(rhs=decay, data=None, **kw):
    data = closed_form(TRUTH) if data is None else data
    return OdeProblem(rhs, lambda e: e[1:2], T, data[:, None], t0=0.0, rtol=RTOL,
                      atol=1e-13, **kw)  # fmt: skip


@pytest.mark.parametrize("vectorized", [None, False])
def test_complex_step_sensitivities_are_the_closed_form_derivatives(vectorized):
    pb = problem(vectorized=vectorized)
    pb.check(TRUTH)
    assert pb.sensitivity_method == "complex-step"
    assert pb.vectorized is (vectorized is None)
    eps = np.array([0.9, 2.5])
    J, exact = pb.predict_jacobian(eps), closed_jacobian(eps)
    # the solve is accurate to its rtol; so are its sensitivities (same steps)
    assert np.max(np.abs(J - exact)) <= 1e-9 * np.max(np.abs(exact))
    np.testing.assert_allclose(pb.predict(eps), closed_form(eps), rtol=1e-9)


def test_complex_step_matches_finite_differences_of_scipys_solution():
    pb = problem()
    pb.check(TRUTH)
    eps = np.array([0.9, 2.5])

    def solution(e):  # what scipy users difference: solve_ivp of the plain ODE
        s = solve_ivp(lambda t, y: decay(t, y, e), (0.0, T[-1]), e[1:2], method="DOP853",
                      t_eval=T, rtol=1e-13, atol=1e-15)  # fmt: skip
        return s.y[0]

    F = optimize.approx_fprime(eps, solution, 1e-6 * eps)  # (8, 2), one-sided
    J = pb.predict_jacobian(eps)
    assert np.max(np.abs(J - F)) <= 1e-5 * np.max(np.abs(J))
    assert np.max(np.abs(J - F)) > 0  # two different computations


def test_a_rhs_that_is_not_analytic_falls_back_to_differences():
    pb = problem(decay_abs)
    pb.check(TRUTH)
    assert pb.sensitivity_method == "differences"
    eps = np.array([0.9, 2.5])
    exact = closed_jacobian(eps)
    J = pb.predict_jacobian(eps)
    assert np.max(np.abs(J - exact)) <= 1e-6 * np.max(np.abs(exact))  # differenced: ~1e-8
    with pytest.raises(ValueError, match="complex-analytic"):
        problem(decay_abs, sensitivities="complex-step").check(TRUTH)


def test_differences_on_request_and_bad_values_refused():
    pb = problem(sensitivities="differences")
    pb.check(TRUTH)
    assert pb.sensitivity_method == "differences"
    with pytest.raises(ValueError, match="`sensitivities`"):
        problem(sensitivities="cs")
    with pytest.raises(ValueError, match="`sensitivities`"):
        problem(jac=(lambda t, y, e: -e[0] * np.eye(1), lambda t, y, e: np.array([[-y[0], 0.0]])),
                sensitivities="differences")  # fmt: skip


@pytest.mark.parametrize("sensitivities", [None, "differences"])
def test_fit_without_jac_equals_curve_fit_on_the_closed_form(sensitivities):
    rng = np.random.default_rng(1)
    data = closed_form(TRUTH) * (1 + 0.02 * rng.standard_normal(T.size))
    res = fit(problem(data=data, sensitivities=sensitivities), [1.0, 2.0])
    popt, pcov = optimize.curve_fit(lambda t, k, y0: closed_form([k, y0], t), T, data,
                                    p0=[1.0, 2.0], xtol=1e-14, ftol=1e-14)  # fmt: skip
    assert res.status.name == "CONVERGED"
    np.testing.assert_allclose(res.eps, popt, rtol=1e-7)
    np.testing.assert_allclose(res.uncertainty.stderr, np.sqrt(np.diag(pcov)), rtol=1e-5)
