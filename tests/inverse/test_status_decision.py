"""One status decision (decide_status) from what was measured: no optimizer's own flag."""

import numpy as np

from ecfm_uq.inverse.core.convergence import Optimality, decide_status, minimize_optimality
from ecfm_uq.inverse.core.optimizers import adam
from ecfm_uq.inverse.core.status import FitStatus


def _opt(ok):
    return Optimality(ok, 0.0 if ok else 1.0, "relative gradient", 1e-10, "")


def test_decide_status_takes_a_measured_model_failure_as_an_input():
    assert decide_status(_opt(True), False) is FitStatus.CONVERGED
    assert decide_status(_opt(False), True) is FitStatus.MAX_ITERATIONS
    assert decide_status(_opt(False), False) is FitStatus.STALLED
    # a model failure at the returned point outranks any optimality measured elsewhere
    assert decide_status(_opt(True), False, failure="march failed") is FitStatus.MODEL_FAILURE
    assert decide_status(None, True) is FitStatus.MODEL_FAILURE  # nothing measured


def test_adam_reports_the_optimality_it_measured_and_its_epochs_are_a_budget():
    # f = x.x from (1, -3): one epoch moves each component by lr (bias correction), to
    # (0.9, -2.9); the gradient there is 2x, relative to f(x0) = 10: max |g| / 10 = 0.58
    res = adam(lambda x: (float(x @ x), 2 * x), [1.0, -3.0], lr=0.1, epochs=1)
    np.testing.assert_allclose(res.optimality, 5.8 / 10.0, rtol=1e-6)
    assert res.status is FitStatus.MAX_ITERATIONS and not res.success
    assert res.method == "adam" and res.formulation == "adam"


def test_minimize_optimality_projects_active_bounds_and_knows_round_off_zero():
    # the gradient pushes x[0] into its lower bound: that component is left out
    opt = minimize_optimality(np.array([3.0, 1e-12]), np.array([0.0, 1.0]), 1.0, 1.0, 1e-10,
                              [(0.0, None), (None, None)])  # fmt: skip
    assert opt.converged and opt.test == "relative gradient" and opt.value == 1e-12
    off = minimize_optimality(np.array([1.0, 0.0]), np.array([0.5, 0.5]), 1e-30, 1.0, 1e-10,
                              None)  # fmt: skip
    assert off.converged and off.test == "round-off zero"
    far = minimize_optimality(np.array([1.0, 0.0]), np.array([0.5, 0.5]), 1.0, 1.0, 1e-10,
                              None)  # fmt: skip
    assert not far.converged and far.value == 1.0
