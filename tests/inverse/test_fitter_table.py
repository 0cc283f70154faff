"""A formulation added through one class and one row of ``FITTERS``.

The example is a weighted least-squares fit of a :class:`ModelProblem` (Gauss-Newton
steps on :math:`W^{1/2}(m(\\epsilon) - v)`, the weights an option): it is fitted through
:func:`fit`, its status is decided by ``decide_status`` from the optimality it measures,
and its options are checked by name before any model call. Truth: numpy's closed form of
weighted least squares for a linear model.
"""

import numpy as np
import pytest

from ecfm_uq.inverse import FitStatus, ModelProblem, fit
from ecfm_uq.inverse import fitting as fitting_module
from ecfm_uq.inverse.core.convergence import least_squares_optimality
from ecfm_uq.inverse.core.fitter import Fitter, Outcome
from ecfm_uq.inverse.core.result import Uncertainty
from ecfm_uq.inverse.core.settings import FitSettings
from ecfm_uq.inverse.problems.noise_model import noise_model


class WeightedLeastSquares(Fitter):
    """``formulation="wls"`` of a ModelProblem: Gauss-Newton on the weighted residual."""

    kind, formulation, default_method = "model", "wls", "gauss-newton"
    methods = ("gauss-newton",)
    options = {"weights": None}

    def check_options(self, problem, settings):
        options = super().check_options(problem, settings)
        w = options["weights"]
        if w is None or np.shape(w) != (problem.n_data,) or np.any(np.asarray(w) <= 0):
            raise ValueError(
                f"options['weights'] must be {problem.n_data} positive numbers, got {w!r}"
            )
        return options

    def run(self, problem, eps0, settings):
        root_w = np.sqrt(np.asarray(self.check_options(problem, settings)["weights"]))
        maxiter = 50 if settings.maxiter is None else settings.maxiter
        eps = np.asarray(eps0, dtype=float)

        def residual(e):
            y = problem.predict(e)
            return root_w * (y - problem.v), root_w[:, None] * problem.jacobian(e, y)

        r, J = residual(eps)
        path, nit = [eps], 0
        opt = least_squares_optimality(r, J, eps, tol=settings.tol or 1e-10)
        while not opt.converged and nit < maxiter:
            eps = eps - np.linalg.lstsq(J, r, rcond=None)[0]
            r, J = residual(eps)
            path, nit = path + [eps], nit + 1
            opt = least_squares_optimality(r, J, eps, tol=settings.tol or 1e-10)
        return Outcome(
            eps=eps, loss=0.5 * float(r @ r), opt=opt, exhausted=nit >= maxiter,
            label="wls", method="gauss-newton", message=opt.message, nit=nit,
            nfev=nit + 1, eps_history=np.array(path),
            uncertainty=Uncertainty.failed("not computed by this example"),
            likelihood="no likelihood in this example",
        )  # fmt: skip


@pytest.fixture
def with_wls(monkeypatch):
    """The one table row that adds the formulation."""
    monkeypatch.setitem(fitting_module.FITTERS, ("model", "wls"), WeightedLeastSquares())


def _line(seed=0):
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 2.0, 15)
    X = np.column_stack([np.ones_like(x), x, x**2])
    w = rng.uniform(0.5, 4.0, x.size)
    y = X @ [1.0, -0.5, 0.3] + rng.normal(0, 0.1, x.size) / np.sqrt(w)
    return X, y, w


def test_a_new_formulation_is_fitted_through_fit_against_numpys_weighted_least_squares(
    with_wls,
):
    X, y, w = _line()
    problem = ModelProblem(lambda e: X @ e, y, jac=lambda e: X)
    res = fit(problem, np.zeros(3), formulation="wls", options={"weights": w})
    truth = np.linalg.lstsq(np.sqrt(w)[:, None] * X, np.sqrt(w) * y, rcond=None)[0]
    np.testing.assert_allclose(res.eps, truth, rtol=1e-10, atol=1e-12)
    assert res.status is FitStatus.CONVERGED and res.success
    assert res.formulation == "wls" and res.method == "gauss-newton"
    assert res.optimality is not None and res.optimality <= 1e-10
    # differs from the unweighted fit (the weights were used)
    plain = np.linalg.lstsq(X, y, rcond=None)[0]
    assert np.max(np.abs(res.eps - plain)) > 1e-4
    # what fit adds to every result: the bounds, the likelihood the fitter gave
    assert res.bounds is None and res.likelihood == "no likelihood in this example"


def test_the_new_formulations_status_is_decided_from_its_measurement(with_wls):
    x = np.linspace(0.0, 1.0, 20)
    y = 2.0 * np.exp(-1.5 * x)
    w = np.ones_like(x)

    def model(e):
        return e[0] * np.exp(-e[1] * x)

    problem = ModelProblem(model, y, jac="3-point")
    cut = fit(problem, [1.0, 0.1], formulation="wls", maxiter=1, options={"weights": w})
    assert cut.status is FitStatus.MAX_ITERATIONS and not cut.success and cut.nit == 1
    full = fit(problem, [1.0, 0.1], formulation="wls", options={"weights": w})
    assert full.status is FitStatus.CONVERGED
    np.testing.assert_allclose(full.eps, [2.0, 1.5], rtol=1e-7)


def test_the_new_formulations_options_are_checked_by_name_before_any_model_call(with_wls):
    calls = []

    def model(e):
        calls.append(e)
        return np.asarray(e, dtype=float)

    problem = ModelProblem(model, [1.0, 2.0])
    with pytest.raises(TypeError, match=r"unknown name\(s\) \['weight'\].*known: \['weights'\]"):
        fit(problem, [0.0, 0.0], formulation="wls", options={"weight": [1, 1]})
    with pytest.raises(ValueError, match=r"options\['weights'\] must be 2 positive"):
        fit(problem, [0.0, 0.0], formulation="wls", options={"weights": [1.0]})
    with pytest.raises(ValueError, match=r"unknown `method` 'lm' for formulation='wls'"):
        fit(problem, [0.0, 0.0], formulation="wls", method="lm", options={"weights": [1, 1]})
    assert calls == []


def test_without_its_row_the_formulation_is_unknown():
    problem = ModelProblem(lambda e: e, [1.0, 2.0])
    with pytest.raises(ValueError, match=r"unknown `formulation` 'wls' for a model problem"):
        fit(problem, [0.0, 0.0], formulation="wls")


def test_the_table_is_what_fit_dispatches_on():
    table = fitting_module.FITTERS
    assert all(f.kind == kind and f.formulation == name for (kind, name), f in table.items())
    assert fitting_module.FORMULATIONS == {
        "model": ("standard",),
        "ode": ("standard", "ecfm", "ecfm-random"),
        "steady": ("standard", "ecfm", "ecfm-random", "noisy-ecfm"),
        "dynamic": ("standard", "ecfm"),
        "replicated": ("standard", "inner-outer", "penalty", "ecfm"),
    }


def test_a_check_inside_warm_starts_kept_leaves_the_warm_starts_as_they_were():
    from ecfm_uq.inverse import DynamicInverseProblem
    from ecfm_uq.problems.burgers import BurgersModel

    m = BurgersModel(n_modes=8, n_steps=6, T=0.3)
    V = m.true_data([1.75, 1.0])
    kept, moved, clean = (
        DynamicInverseProblem(m.system, m.Theta0, m.dt, m.n_steps, m.M_obs, V) for _ in range(3)
    )
    for problem in (kept, moved, clean):
        problem.solve([1.7, 0.9], "standard")
    with kept.warm_starts_kept():
        kept.solve([1.0, 2.0], "standard")  # a check far away
    moved.solve([1.0, 2.0], "standard")  # the same check, outside the context
    after_kept, after_moved, after_clean = (
        p.solve([1.72, 0.95], "standard").Theta for p in (kept, moved, clean)
    )
    # the next solve starts from the first trajectory, as if the check had not run
    np.testing.assert_array_equal(after_kept, after_clean)
    # the control: a check outside the context moves the warm start (round-off apart)
    assert not np.array_equal(after_moved, after_clean)


def _settings(**kw):
    base = dict(formulation="standard", method="auto", sigma=None, bounds=None, tol=None,
                maxiter=None, options={}, uncertainty=True, alpha=0.05)  # fmt: skip
    return FitSettings(**{**base, **kw})


def test_the_model_row_measures_and_fit_decides_the_status_with_the_uncertainty_as_told():
    """The ModelProblem row's fitter returns an Outcome carrying the drivers' measured
    optimality (no status), the uncertainty already told its estimate and names (fit
    keeps that object), and its estimate is numpy's linear least squares."""
    x = np.linspace(0.0, 1.0, 9)
    rng = np.random.default_rng(3)
    v = 1.0 + 2.0 * x + 0.01 * rng.standard_normal(x.size)
    problem = ModelProblem(lambda e: e[0] + e[1] * x, v, names=["a", "b"])
    outcome = fitting_module.FITTERS["model", "standard"].run(problem, [0.0, 0.0], _settings())
    assert isinstance(outcome, Outcome) and not hasattr(outcome, "status")
    assert type(outcome.opt).__name__ == "Optimality" and outcome.opt.converged
    truth = np.linalg.lstsq(np.column_stack((np.ones_like(x), x)), v, rcond=None)[0]
    np.testing.assert_allclose(outcome.eps, truth, rtol=1e-7)
    unc = outcome.uncertainty
    assert unc.names == ["a", "b"] and np.array_equal(unc.eps, outcome.eps)
    assert fitting_module._with_estimate(unc, outcome.eps, problem.names) is unc
    res = fit(problem, [0.0, 0.0])
    assert res.status is FitStatus.CONVERGED and res.optimality == outcome.optimality
    # the known-sigma branch: the derivative in the data given and the noise as given
    sig = np.full(x.size, 0.01)
    known = fitting_module.FITTERS["model", "standard"].run(
        problem, [0.0, 0.0], _settings(sigma=noise_model(sig, x.size))
    )
    J = np.column_stack((np.ones_like(x), x))
    np.testing.assert_allclose(known.uncertainty.jacobian, np.linalg.pinv(J), atol=1e-7)
    np.testing.assert_allclose(known.uncertainty.sigma, sig)
