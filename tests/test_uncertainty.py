"""Delta-method covariance against a refit Jacobian and Gauss-Newton (linear case)."""

import numpy as np
import pytest

from ecfm_uq.inverse.uncertainty import (
    confidence_intervals,
    delta_method_covariance,
    estimate_jacobian,
    gauss_newton_covariance,
)


def _linear_case():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(12, 3))
    v = rng.normal(size=12)
    return J, v


def test_delta_equals_gauss_newton_linear():
    J, _ = _linear_case()
    sigma2 = 0.04
    # g(eps, v) = J^T (J eps - v): dg/deps = J^T J, dg/dv = -J^T
    D = estimate_jacobian(J.T @ J, -J.T)
    np.testing.assert_allclose(
        delta_method_covariance(D, sigma2), gauss_newton_covariance(J, sigma2), rtol=1e-10
    )


def test_delta_equals_refit_finite_differences():
    J, v = _linear_case()

    def refit(v):
        return np.linalg.lstsq(J, v, rcond=None)[0]

    h = 1e-6
    D_fd = np.column_stack(
        [(refit(v + h * e) - refit(v - h * e)) / (2 * h) for e in np.eye(v.size)]
    )
    Sigma = np.diag(np.linspace(0.01, 0.05, v.size))
    cov_fd = D_fd @ Sigma @ D_fd.T
    D = estimate_jacobian(J.T @ J, -J.T)
    np.testing.assert_allclose(delta_method_covariance(D, np.diag(Sigma)), cov_fd, rtol=1e-5)


def test_intervals_and_bad_input():
    se, ci = confidence_intervals([1.0], [[4.0]])
    assert se[0] == 2.0
    np.testing.assert_allclose(ci[0], [1 - 1.959964 * 2, 1 + 1.959964 * 2], rtol=1e-6)
    with pytest.raises(ValueError, match="level"):
        confidence_intervals([1.0], [[4.0]], level=1.5)
    with pytest.raises(ValueError, match="singular"):
        estimate_jacobian(np.zeros((2, 2)), np.ones((2, 3)))
