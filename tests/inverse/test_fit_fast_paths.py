"""The fast paths of a small fit give the numbers of the general ones: the float64 output
check, the one-reduction finiteness test, the scaled SVD shared by the status test and
the standard errors (against numpy's SVD and the normal equations)."""

import numpy as np
import pytest

from ecfm_uq._validation import all_finite, as_model_output
from ecfm_uq.inverse.core.convergence import least_squares_optimality, scaled_svd
from ecfm_uq.inverse.statistics.uncertainty import least_squares_jacobian


def test_float64_output_is_copied_and_other_outputs_take_the_general_path():
    y = np.linspace(0.0, 1.0, 6)
    out = as_model_output(y, name="model", at="here", shape=(6,))
    assert out is not y and np.array_equal(out, y)
    y[0] = 5.0  # a model reusing its buffer cannot change an output already taken
    assert out[0] == 0.0
    for other in (y.astype(np.float32), y.tolist(), y[:, None]):
        got = as_model_output(other, name="model", at="here", shape=(6,))
        assert got.dtype == np.float64 and got.shape == (6,)
        np.testing.assert_array_equal(got, np.asarray(other, dtype=float).reshape(6))
    with pytest.raises(ValueError, match="shape"):
        as_model_output(np.zeros(5), name="model", at="here", shape=(6,))


@pytest.mark.parametrize(
    "values, finite",
    [([1.0, 2.0], True), ([1e200, -1e200, 3.0], True), ([1.0, np.nan], False),
     ([np.inf, 1.0], False), ([-np.inf, np.inf], False), ([], True)],
)  # fmt: skip
def test_all_finite_agrees_with_the_elementwise_test(values, finite):
    a = np.array(values, dtype=float)
    assert all_finite(a) is finite is bool(np.isfinite(a).all())
    assert all_finite(a.reshape(-1, 1)) is finite  # 2-D: the sum's route
    assert all_finite(a[::-1]) is finite  # strided


def test_the_scaled_svd_is_remembered_for_the_same_jacobian_only():
    rng = np.random.default_rng(3)
    J = rng.standard_normal((9, 3)) * [1.0, 1e-4, 1e3]
    norms, U, sv, Vt = scaled_svd(J)
    ref = np.linalg.svd(J / np.linalg.norm(J, axis=0), full_matrices=False)
    np.testing.assert_array_equal(norms, np.linalg.norm(J, axis=0))
    np.testing.assert_array_equal(sv, ref[1])
    assert scaled_svd(J.copy())[1] is U  # same bits: the same factorization
    assert not U.flags.writeable
    K = J.copy()
    K[4, 1] *= 1.5
    assert scaled_svd(K)[1] is not U
    np.testing.assert_allclose(scaled_svd(K)[2], np.linalg.svd(K / np.linalg.norm(K, axis=0),
                                                               compute_uv=False))  # fmt: skip


def test_status_test_then_standard_errors_use_one_factorization_and_are_right():
    rng = np.random.default_rng(4)
    J = rng.standard_normal((12, 2)) * [2.0, 0.01]
    r = rng.standard_normal(12)
    r -= J @ np.linalg.lstsq(J, r, rcond=None)[0]  # a stationary point: J^T r = 0
    opt = least_squares_optimality(r, J, np.array([1.0, 2.0]))
    assert opt.converged
    D = least_squares_jacobian(J)
    np.testing.assert_allclose(D, np.linalg.solve(J.T @ J, J.T), rtol=1e-10)
