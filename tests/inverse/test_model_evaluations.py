"""A ModelProblem fit's ``nfev`` is the number of times the model ran: MINPACK's and the
trust region's evaluations, the columns MINPACK differences and the status test's
central-difference stencil included (the truth: a counter inside the model)."""

import numpy as np
import pytest

from ecfm_uq.inverse import ModelProblem, fit

X = np.linspace(0.0, 5.0, 22)
Y = 2.0 * np.exp(-0.7 * X) + 0.05 * np.sin(9 * X)


@pytest.mark.parametrize("jac", ["2-point", "3-point"])
@pytest.mark.parametrize("kw", [{}, {"method": "trf"}, {"bounds": [(0.0, 5.0), (0.0, 3.0)]}])
def test_nfev_counts_every_model_evaluation(jac, kw):
    calls = []

    def model(e):
        calls.append(1)
        return e[0] * np.exp(-e[1] * X)

    res = fit(ModelProblem(model, Y, jac=jac), [1.0, 1.0], **kw)
    assert res.success, res.message
    assert res.nfev == len(calls)


def test_a_given_jacobian_is_not_a_model_evaluation():
    calls = []

    def model(e):
        calls.append(1)
        return e[0] * np.exp(-e[1] * X)

    def jac(e):
        g = np.exp(-e[1] * X)
        return np.column_stack([g, -e[0] * X * g])

    res = fit(ModelProblem(model, Y, jac=jac), [1.0, 1.0])
    assert res.success and res.nfev == len(calls)


GROWTH_X = np.linspace(0.0, 100.0, 30)
GROWTH_Y = 2.0 * np.exp(0.05 * GROWTH_X) + np.sin(GROWTH_X)


def growth(e):
    return e[0] * np.exp(e[1] * GROWTH_X)


@pytest.mark.parametrize("jac", ["2-point", "cs"])
@pytest.mark.parametrize("method", ["lm", "trf"])
def test_a_start_where_the_model_blows_up_is_refused_by_name(jac, method):
    """exp(500 ...) at the start: predictions ~1e217, a residual whose square overflows.
    A ValueError naming eps0 before any optimizer runs (it was a LinAlgError or an
    IndexError from the status test's SVD, with overflow warnings)."""
    with pytest.raises(ValueError, match="`eps0`.*too large to be squared"):
        fit(ModelProblem(growth, GROWTH_Y, jac=jac), [1.0, 5.0], method=method)


@pytest.mark.filterwarnings("error::RuntimeWarning")
@pytest.mark.parametrize("jac", ["2-point", "cs"])
def test_trials_that_overflow_are_failed_points_without_warnings(jac):
    """From b = 3.5 (predictions ~1e152) the optimizer's trials overflow the sum of
    squares: failed points, a status and a message, no warning and no exception."""
    res = fit(ModelProblem(growth, GROWTH_Y, jac=jac), [1.0, 3.5])
    assert res.status.name in ("CONVERGED", "STALLED", "MAX_ITERATIONS"), res.message
    assert np.all(np.isfinite(res.eps))
