"""The one finite-difference helper (``fd_jacobian``) against a closed-form Jacobian, for
every stencil and every way of calling it (with ``f(x)`` given, a subset of columns,
points evaluated together)."""

import numpy as np
import pytest

from ecfm_uq.inverse.core.finite_differences import FD_METHODS, fd_jacobian


def f(x):
    return np.array([np.sin(x[0]) * x[1], np.exp(x[0] - x[1]), x[0] ** 3, 1e9 * x[1] ** 2])


def jac(x):
    return np.array(
        [
            [np.cos(x[0]) * x[1], np.sin(x[0])],
            [np.exp(x[0] - x[1]), -np.exp(x[0] - x[1])],
            [3 * x[0] ** 2, 0.0],
            [0.0, 2e9 * x[1]],
        ]
    )


X = np.array([0.7, 1e-3])  # a parameter of size 1e-3: steps relative to each one
# error of each stencil relative to each column's largest entry: O(h), O(h^2), O(h^4)
# and the complex step's round-off
RTOL = {"2-point": 1e-6, "3-point": 1e-9, "5-point": 1e-11, "cs": 1e-14}


@pytest.mark.parametrize("method", FD_METHODS)
def test_every_stencil_matches_the_closed_form(method):
    J = fd_jacobian(f, X, method=method)
    ref = jac(X)
    scale = np.abs(ref).max(axis=0)
    assert np.all(np.abs(J - ref) <= RTOL[method] * scale), (J - ref) / scale


def test_one_sided_with_f_of_x_given_is_the_same_computation():
    # the optimizer's case (f(x) known) costs p calls and gives the very same numbers
    calls = []

    def counted(x):
        calls.append(x.copy())
        return f(x)

    J = fd_jacobian(counted, X, f0=f(X))
    assert len(calls) == X.size
    np.testing.assert_array_equal(J, fd_jacobian(f, X))


@pytest.mark.parametrize("method", FD_METHODS[:3])
def test_columns_and_points_evaluated_together_agree(method):
    full = fd_jacobian(f, X, method=method)
    np.testing.assert_array_equal(fd_jacobian(f, X, method=method, columns=[1]), full[:, [1]])
    together = fd_jacobian(
        f, X, method=method, map_points=lambda pts: np.array([f(p) for p in pts])
    )
    np.testing.assert_array_equal(together, full)
