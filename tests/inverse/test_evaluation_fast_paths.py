"""The per-evaluation fast paths of a ModelProblem fit give the general paths' numbers
bit for bit, and still refuse what the general paths refuse: the residual with predict
inlined, the central-difference Jacobian without the stacked stencil, the array checks
that skip conversions of float64 arrays, the result that converts only foreign types,
the covariance of one float variance and the verdict's norms."""

import math
import warnings

import numpy as np
import pytest

from ecfm_uq._validation import all_finite, as_finite_array
from ecfm_uq.errors import ModelEvaluationError
from ecfm_uq.inverse import FitStatus, InverseResult, ModelProblem
from ecfm_uq.inverse.core.finite_differences import fd_jacobian, fd_steps
from ecfm_uq.inverse.problems.noise_model import noise_model
from ecfm_uq.inverse.statistics.uncertainty import delta_method_covariance
from ecfm_uq.inverse.statistics.verdict import residual_verdict

X = np.linspace(0.0, 5.0, 22)
V = 2.0 * np.exp(-0.7 * X) + 0.01 * np.sin(7 * X)


def decay(e):
    return e[0] * np.exp(-e[1] * X)


def as_list(e):  # the general route: a list is converted and checked by predict
    return decay(e).tolist()


@pytest.mark.parametrize("sigma", [None, 0.02, np.full(22, 0.03)])
def test_residual_of_a_float64_model_is_the_general_routes_bit_for_bit(sigma):
    noise = noise_model(sigma, 22)
    fast = ModelProblem(decay, V).residual_function(noise)
    general = ModelProblem(as_list, V).residual_function(noise)
    for e in ([1.0, 1.0], [2.1, 0.69], [0.3, -0.2]):
        r1, J1, y1 = fast(np.array(e))
        r2, J2, y2 = general(np.array(e))
        assert r1.tobytes() == r2.tobytes() and y1.tobytes() == y2.tobytes()
        assert J1().tobytes() == J2().tobytes()
        # the same residual as predict's, written out
        expected = decay(np.array(e)) - V if sigma is None else noise.whiten(decay(e) - V)
        assert r1.tobytes() == np.asarray(expected).tobytes()


def test_residual_fast_path_refuses_non_finite_values_and_keeps_huge_finite_ones():
    calls = []

    def model(e):
        calls.append(1)
        y = decay(e)
        if len(calls) == 2:
            y[3] = np.nan
        if len(calls) == 3:
            y[:] = 1e200  # finite: the squares overflow, the values are fine
        return y

    res = ModelProblem(model, V).residual_function(noise_model(None, 22))
    res(np.array([1.0, 1.0]))
    with pytest.raises(ModelEvaluationError, match="non-finite"):
        res(np.array([1.0, 1.0]))
    with np.errstate(over="ignore"):  # the sum of squares overflows (as the loss would)
        r, _, y = res(np.array([1.0, 1.0]))
    assert np.all(y == 1e200) and np.all(np.isfinite(r))
    # the first call (the start) raises the user's error, as predict(first=True) does
    bad = ModelProblem(lambda e: np.full(22, np.inf), V).residual_function(noise_model(None, 22))
    with pytest.raises(ValueError, match="start from parameters"):
        bad(np.array([1.0, 1.0]))


def test_residual_copies_a_reused_output_buffer_and_reshapes_2d_data():
    buf = np.zeros(22)

    def model(e):
        buf[:] = decay(e)
        return buf

    res = ModelProblem(model, V).residual_function(noise_model(None, 22))
    r1, _, y1 = res(np.array([1.0, 1.0]))
    res(np.array([2.0, 0.5]))
    assert np.array_equal(y1, decay(np.array([1.0, 1.0])))  # not overwritten
    grid = ModelProblem(lambda e: decay(e).reshape(2, 11), V.reshape(2, 11))
    r, _, y = grid.residual_function(noise_model(None, 22))(np.array([1.0, 1.0]))
    assert r.shape == y.shape == (22,)
    assert r.tobytes() == (decay(np.array([1.0, 1.0])) - V).tobytes()


def test_predict_fast_path_equals_the_general_one_and_refuses_nan():
    e = np.array([1.3, 0.4])
    assert (
        ModelProblem(decay, V).predict(e).tobytes() == ModelProblem(as_list, V).predict(e).tobytes()
    )
    with pytest.raises(ModelEvaluationError, match="non-finite"):
        ModelProblem(lambda e: np.full(22, np.nan), V).predict(e)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # huge finite predictions: no overflow warning
        assert ModelProblem(lambda e: np.full(22, 1e200), V).predict(e)[0] == 1e200


@pytest.mark.parametrize("columns", [None, [1], [2, 0]])
def test_central_differences_equal_the_stacked_stencil_bit_for_bit(columns):
    def f(e):
        return np.array([np.sin(e[0]) * e[1], e[2] ** 3, np.exp(e[0] - e[2]), e @ e])

    x = np.array([0.7, -1.3, 0.0])
    fast = fd_jacobian(f, x, method="3-point", typical=[1.0, 1.0, 2.0], columns=columns)
    stacked = fd_jacobian(
        f, x, method="3-point", typical=[1.0, 1.0, 2.0], columns=columns,
        map_points=lambda pts: np.array([f(p) for p in pts]),
    )  # fmt: skip
    assert fast.tobytes() == stacked.tobytes()
    # and the stencil written out (the module's table)
    h = fd_steps(x, "3-point", [1.0, 1.0, 2.0])
    cols = range(3) if columns is None else columns
    for c, j in enumerate(cols):
        up, down = x.copy(), x.copy()
        up[j] += h[j]
        down[j] -= h[j]
        assert fast[:, c].tobytes() == ((f(up) - f(down)) / (2 * h[j])).tobytes()


def test_fd_steps_of_a_scalar_and_of_zeros():
    assert fd_steps(0.0, "2-point").tolist() == math.sqrt(np.finfo(float).eps)  # 0-d
    assert fd_steps(np.array([0.0, -4.0]), "2-point", [0.0, 1.0]).tolist() == [
        math.sqrt(np.finfo(float).eps),
        4 * math.sqrt(np.finfo(float).eps),
    ]


def test_as_finite_array_returns_a_float64_array_itself_and_still_checks_it():
    a = np.arange(6.0).reshape(2, 3)
    assert as_finite_array("a", a, shape=(2, 3)) is a
    assert as_finite_array("a", a, shape=(None, 3)) is a
    with pytest.raises(ValueError, match="shape"):
        as_finite_array("a", a, shape=(3, 2))
    with pytest.raises(ValueError, match="1-D"):
        as_finite_array("a", a, ndim=1)
    a[1, 2] = np.inf
    with pytest.raises(ValueError, match="NaN or inf"):
        as_finite_array("a", a)
    assert as_finite_array("b", [1, 2]).dtype == np.float64  # converted, as before
    with pytest.raises(TypeError, match="array-like"):
        as_finite_array("b", "12")


@pytest.mark.parametrize("bad", [np.nan, np.inf, None])
def test_all_finite_of_contiguous_and_strided_2d_arrays(bad):
    a = np.arange(12.0).reshape(3, 4)
    if bad is not None:
        a[2, 1] = bad
    expected = bool(np.isfinite(a).all())
    assert all_finite(a) is expected
    assert all_finite(a.T) is expected  # not C-contiguous: the sum's route
    assert all_finite(np.full((2, 2), 1e300)) is True  # the sum overflows, the values do not


def test_result_converts_foreign_types_and_keeps_its_own():
    eps, hist = np.array([1.0, 2.0]), np.zeros((1, 2))
    mine = InverseResult(eps=eps, loss=0.5, status=FitStatus.CONVERGED, message="m", nit=3,
                         nfev=4, optimality=1e-9, eps_history=hist)  # fmt: skip
    assert mine.eps is eps and mine.eps_history is hist and mine.loss == 0.5
    user = InverseResult(eps=[1, 2], loss=np.float64(0.5), status=FitStatus.CONVERGED.value,
                         message=7, nit=np.int64(3), nfev=True, njev=2.0,
                         optimality=np.float32(0.25), eps_history=[[1.0, 2.0]],
                         loss_history=[0.5])  # fmt: skip
    assert user.eps.dtype == np.float64 and user.eps.tolist() == [1.0, 2.0]
    assert type(user.loss) is float and user.status is FitStatus.CONVERGED
    assert user.message == "7" and type(user.nit) is int and user.nfev == 1
    assert type(user.njev) is int and type(user.optimality) is float
    assert isinstance(user.eps_history, np.ndarray) and isinstance(user.loss_history, np.ndarray)
    f32 = InverseResult(eps=np.array([1.0], dtype=np.float32), loss=0.0, status=FitStatus.CONVERGED,
                        message="", nit=0, nfev=0)  # fmt: skip
    assert f32.eps.dtype == np.float64


def test_covariance_of_one_float_variance_equals_the_array_routes():
    D = np.random.default_rng(5).standard_normal((2, 9))
    fast = delta_method_covariance(D, 0.37)
    assert fast.tobytes() == delta_method_covariance(D, np.array(0.37)).tobytes()
    assert fast.tobytes() == delta_method_covariance(D, np.float64(0.37)).tobytes()
    np.testing.assert_allclose(fast, 0.37 * D @ D.T, rtol=1e-15)
    for bad, match in ((-1.0, "positive"), (0.0, "positive"), (np.nan, "non-finite")):
        with pytest.raises(ValueError, match=match):
            delta_method_covariance(D, bad)


def test_verdict_force_to_data_is_the_ratio_of_norms():
    rng = np.random.default_rng(2)
    e, v = rng.standard_normal(30), rng.standard_normal(30)
    got = residual_verdict(e, v).details["force_to_data"]
    assert got == float(np.linalg.norm(e) / np.linalg.norm(v))
    assert residual_verdict(e, np.zeros(30)).details["force_to_data"] == float(
        np.linalg.norm(e) / 1e-300
    )
