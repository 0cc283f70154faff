"""The library decides its BLAS threads (issue 21 item 4), whatever the caller set."""

import numpy  # noqa: F401  (load the BLAS libraries threadpoolctl sees)
import pytest
import scipy.linalg  # noqa: F401
from threadpoolctl import threadpool_info, threadpool_limits

from ecfm_uq.threads import LARGE_DENSE, blas_threads, library_threads, set_blas_threads


def blas():
    return {p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}


@pytest.fixture
def two_threads():
    with threadpool_limits(limits=2, user_api="blas"):
        if blas() != {2}:
            pytest.skip("BLAS cannot run 2 threads here")
        yield
    set_blas_threads(None)


def test_small_work_runs_single_threaded_and_large_work_keeps_the_threads(two_threads):
    with blas_threads():
        assert blas() == {1}
        with blas_threads(10 * LARGE_DENSE):  # nested: the outer decision holds
            assert blas() == {1}
    assert blas() == {2}
    with blas_threads(LARGE_DENSE):
        assert blas() == {2}


def test_decorator_and_override(two_threads):
    @library_threads(size=lambda n: n)
    def threads_seen(n):
        return blas()

    assert threads_seen(10) == {1} and threads_seen(LARGE_DENSE) == {2}
    set_blas_threads(2)
    assert threads_seen(10) == {2}
    set_blas_threads(None)
    assert threads_seen(10) == {1}
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="`threads`"):
            set_blas_threads(bad)


def test_no_dense_work_switches_nothing_and_nested_calls_decide(two_threads):
    from ecfm_uq.threads import NO_DENSE

    with blas_threads(NO_DENSE):
        assert blas() == {2}  # the caller's threads, untouched
        with blas_threads():  # an engine call inside (a user's model solving a system)
            assert blas() == {1}
        assert blas() == {2}
    assert blas() == {2}


def test_a_model_problem_fit_leaves_the_callers_threads(two_threads):
    import numpy as np

    from ecfm_uq.inverse import ModelProblem, fit

    seen = []
    x = np.linspace(0.0, 1.0, 8)

    def model(e):
        seen.append(frozenset(blas()))
        return e[0] + e[1] * x

    res = fit(ModelProblem(model, 1.0 + 2.0 * x + 0.01 * np.sin(7 * x)), [0.5, 0.5])
    assert res.success and set(seen) == {frozenset({2})}
    assert blas() == {2}
