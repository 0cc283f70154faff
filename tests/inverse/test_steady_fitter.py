"""The steady standard/ECFM rows are Fitters that report what they measured (issue 37,
items 1 and 2): an Outcome with the optimality conditions, the budget and the model
failure at the returned point; ``fit`` alone decides the status from them. The random-
force ECFM keeps its standard fit as an Outcome, as the ODE one does; Adam's iterations
report their measurement like every driver. Truths: the linear model's least-squares
estimate in closed form, the closed-form Adam step, an injected model failure."""

import dataclasses

import numpy as np
import pytest

import ecfm_uq.inverse.formulations.steady as steady
from ecfm_uq.errors import ConvergenceError
from ecfm_uq.inverse import FitStatus, SteadyProblem, adam, fit
from ecfm_uq.inverse.core import drivers
from ecfm_uq.inverse.core.convergence import Optimality, decide_status
from ecfm_uq.inverse.core.fitter import Outcome, holds
from ecfm_uq.inverse.core.optimizers import run_adam
from ecfm_uq.inverse.core.settings import FitSettings
from ecfm_uq.inverse.fitting import FITTERS
from ecfm_uq.spectral import SineBasis, hat_forces, load, sensor_matrix, stiffness
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, solve_steady

B = SineBasis(16)
K = stiffness(B)
F = np.column_stack([load(B, np.ones_like), load(B, lambda x: x)])
SENS = np.linspace(0.1, 0.9, 9)
M_OBS = sensor_matrix(B, SENS)
SYSTEM = GalerkinSystem([LinearTerm(K), LoadTerm.linear(F)], 2, Gamma=hat_forces(B, SENS, 0.1))
V = M_OBS @ solve_steady(SYSTEM, [3.0, -2.0]).Theta[:, 0]
V = V + 0.01 * np.random.default_rng(0).standard_normal(V.size)
PROBLEM = SteadyProblem(SYSTEM, M_OBS, V)


def settings(formulation="standard", method="auto", maxiter=None, sigma=0.01):
    return FitSettings(formulation, method, sigma, None, None, maxiter, {}, True, 0.05)


def closed_form_estimate():
    """The model is linear in eps: readings = M K^-1 F eps, least squares by lstsq."""
    G = M_OBS @ np.linalg.solve(K, F)
    return np.linalg.lstsq(G, V, rcond=None)[0]


@pytest.mark.parametrize("formulation", ["standard", "ecfm"])
@pytest.mark.parametrize("method", ["least-squares", "BFGS"])
def test_a_steady_row_returns_the_measurement_and_fit_decides_from_it(formulation, method):
    s = settings(formulation, method)
    out = FITTERS["steady", formulation].run(PROBLEM, [1.0, 1.0], s)
    assert type(out) is Outcome
    assert isinstance(out.opt, Optimality) and out.opt.converged
    assert out.failure is None and out.exhausted is False
    assert out.label == formulation and out.method == method
    res = fit(PROBLEM, [1.0, 1.0], formulation=formulation, method=method, sigma=0.01)
    assert res.status is decide_status(out.opt, out.exhausted, out.failure)
    assert res.status is FitStatus.CONVERGED and res.optimality == out.opt.value
    np.testing.assert_array_equal(res.eps, out.eps)
    if formulation == "standard":  # the least-squares estimate, in closed form
        np.testing.assert_allclose(out.eps, closed_form_estimate(), rtol=1e-7)


def test_a_spent_budget_is_measured_as_exhausted():
    out = FITTERS["steady", "standard"].run(PROBLEM, [1.0, 1.0], settings(maxiter=1))
    assert out.exhausted and not holds(out.opt, out.failure) and out.opt is not None
    res = fit(PROBLEM, [1.0, 1.0], maxiter=1, sigma=0.01)
    assert res.status is FitStatus.MAX_ITERATIONS


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # scipy's steps towards inf
@pytest.mark.parametrize("method", ["least-squares", "BFGS"])
def test_a_model_that_fails_at_the_returned_point_is_a_measured_failure(monkeypatch, method):
    calls = [0]
    residual, objective = steady._RESIDUALS["standard"], steady._OBJECTIVES["standard"]

    def failing(f):
        def g(*args, **kwargs):
            calls[0] += 1
            if calls[0] > 1:  # every model solve after the one at eps0 fails
                raise ConvergenceError("injected: the model cannot be solved")
            return f(*args, **kwargs)

        return g

    monkeypatch.setitem(steady._RESIDUALS, "standard", failing(residual))
    monkeypatch.setitem(steady._OBJECTIVES, "standard", failing(objective))
    out = FITTERS["steady", "standard"].run(PROBLEM, [1.0, 1.0], settings(method=method))
    assert isinstance(out.failure, ConvergenceError) and "injected" in str(out.failure)
    assert out.loss == np.inf and not holds(out.opt, out.failure)
    calls[0] = 0
    res = fit(PROBLEM, [1.0, 1.0], method=method, sigma=0.01)
    assert res.status is FitStatus.MODEL_FAILURE and not res.success


def test_the_random_force_fit_keeps_the_standard_fits_outcome():
    res = fit(PROBLEM, [1.0, 1.0], formulation="ecfm-random", sigma=0.01)
    std = res.extra["standard"]
    assert type(std) is Outcome and holds(std.opt, std.failure)
    standard = fit(PROBLEM, [1.0, 1.0], sigma=0.01)
    np.testing.assert_array_equal(std.eps, standard.eps)
    assert std.loss == standard.loss and std.optimality == standard.optimality
    np.testing.assert_allclose(std.eps, closed_form_estimate(), rtol=1e-7)


def test_no_status_is_read_back_from_a_driver_or_a_result():
    assert not hasattr(Outcome, "from_result")
    fields = {f.name for f in dataclasses.fields(drivers.Outcome)}
    assert "status" not in fields and not hasattr(drivers.Outcome, "status")
    assert not hasattr(drivers.Outcome, "success")


def test_adam_reports_its_measurement_and_adam_decides_the_status_once():
    # f = x.x from (1, -3): one epoch moves each component by lr (bias correction), to
    # (0.9, -2.9); the gradient there is 2x, relative to f(x0) = 10: max |g| / 10 = 0.58
    out = run_adam(lambda x: (float(x @ x), 2 * x), [1.0, -3.0], lr=0.1, epochs=1)
    assert isinstance(out, drivers.Outcome) and out.exhausted and out.final_error is None
    np.testing.assert_allclose(out.x, [0.9, -2.9], rtol=1e-7)
    np.testing.assert_allclose(out.opt.value, 0.58, rtol=1e-6)
    res = adam(lambda x: (float(x @ x), 2 * x), [1.0, -3.0], lr=0.1, epochs=1)
    assert res.status is decide_status(out.opt, out.exhausted, out.final_error)
    np.testing.assert_array_equal(res.eps, out.x)
    np.testing.assert_array_equal(res.extra["grad_history"], out.payload["grad_history"])

    def fails_third(x, calls=[]):  # noqa: B006 (the call count)
        calls.append(1)
        if len(calls) == 3:
            raise ConvergenceError("injected")
        return float(x @ x), 2 * x

    out = run_adam(fails_third, [1.0, -1.0], lr=0.1, epochs=10)
    assert isinstance(out.final_error, ConvergenceError) and out.opt is None
    assert out.nit == 1 and out.nfev == 3 and "epoch 2" in out.message
