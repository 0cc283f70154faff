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
