"""Points whose residual is too large to square (issue 37: `reproduce coverage` printed
hundreds of overflow warnings): a profile's least-squares inner fit and a Newton solve
treat them as infinitely bad / failed, without a warning."""

import warnings

import numpy as np

from ecfm_uq.inverse.statistics.profile_walk import _levenberg_marquardt, _sum_of_squares
from ecfm_uq.problems.reaction import ReactionRod
from ecfm_uq.system import solve_steady
from ecfm_uq.system.plan import SolveStatus


def test_a_residual_too_large_to_square_is_infinite_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _sum_of_squares(np.array([1e200, 3.0])) == np.inf
        assert _sum_of_squares(np.array([3.0, 4.0])) == 25.0


def test_levenberg_marquardt_backs_off_from_an_overflowing_region():
    def fun(x):  # the sum of squares overflows beyond x = 3
        return np.array([x[0] - 1.0, 1e200 * x[0] if x[0] > 3.0 else 0.0])

    def jac(x):
        return np.array([[1.0], [1e200 if x[0] > 3.0 else 0.0]])

    lb, ub = np.array([-np.inf]), np.array([np.inf])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        x, rss, ok = _levenberg_marquardt(fun, jac, np.array([10.0]), lb, ub)
        assert rss == np.inf and not ok  # the start itself: a failed point, said so
        x, rss, ok = _levenberg_marquardt(fun, jac, np.array([2.5]), lb, ub)
    assert ok and abs(x[0] - 1.0) < 1e-8 and rss < 1e-16


def test_a_newton_residual_too_large_to_square_is_a_failed_solve_without_a_warning():
    """Where `reproduce coverage`'s warnings came from: a profile of the reaction rod's
    standard fit tried a point whose Galerkin residual norm overflows."""
    rod = ReactionRod(4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sol = solve_steady(rod.system, [0.5, 1e160])
    assert not sol.success and sol.status is SolveStatus.NON_FINITE
