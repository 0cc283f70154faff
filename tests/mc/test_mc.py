"""Monte Carlo with executors, moments and quadrature references (ecfm_uq.mc)."""

import functools
from concurrent.futures import ThreadPoolExecutor

import distributed
import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis
from ecfm_uq.errors import SingularSystemError
from ecfm_uq.mc import (
    Moments,
    batch_errors,
    draw_germ,
    loglog_slope,
    mc_moments,
    monte_carlo,
    pseudospectral_projection,
    quadrature_moments,
    relative_error,
)
from ecfm_uq.problems.beam import BeamModel


def powers(w, k=3):
    """(w, w^2, ..., w^k): moments known in closed form for w ~ U(0, 1)."""
    return np.array([w**j for j in range(1, k + 1)], dtype=float)


def nan_at_half(w):
    return np.array([np.nan if w > 0.5 else w])


def _closed_form(k=3):
    j = np.arange(1, k + 1)
    mean = 1.0 / (j + 1)
    return mean, 1.0 / (2 * j + 1) - mean**2


@pytest.fixture(scope="module")
def beam():
    return BeamModel()


def test_serial_pool_and_threads_agree():
    w = draw_germ(300, seed=3)
    serial = monte_carlo(powers, w, workers=1)
    assert serial.shape == (300, 3)
    np.testing.assert_array_equal(serial, np.stack([powers(x) for x in w]))
    pooled = monte_carlo(powers, w, workers=2, chunksize=40)
    np.testing.assert_array_equal(pooled, serial)
    with ThreadPoolExecutor(2) as ex:
        threaded = monte_carlo(functools.partial(powers, k=3), w, ex, chunksize=7)
    np.testing.assert_array_equal(threaded, serial)


def test_dask_client_gives_identical_numbers(beam):
    fn = beam.response_function(1.0)
    w = draw_germ(200, seed=11)
    serial = monte_carlo(fn, w, workers=1)
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        out = monte_carlo(fn, w, client, chunksize=32)
    np.testing.assert_array_equal(out, serial)


def test_a_client_s_futures_are_taken_one_by_one_not_gathered():
    """A dask-like client (map returns futures, gather exists): the rows are filled from
    each future in order; gathering every chunk first would hold them all at once."""
    from concurrent.futures import ThreadPoolExecutor

    from ecfm_uq.executor import evaluate_samples

    class Client:
        def __init__(self, pool):
            self.pool = pool

        def map(self, f, parts):
            return [self.pool.submit(f, p) for p in parts]

        def gather(self, futures):
            raise AssertionError("gather holds every chunk's result at once")

    w = draw_germ(50, seed=3)
    with ThreadPoolExecutor(2) as pool:
        out = evaluate_samples(powers, w, Client(pool), chunksize=8)
    np.testing.assert_array_equal(out, evaluate_samples(powers, w, workers=1))


def test_moments_against_closed_form():
    w = draw_germ(40000, seed=5)
    y = monte_carlo(powers, w, workers=1)
    m = mc_moments(y)
    assert isinstance(m, Moments)
    mean, var = _closed_form()
    assert np.all(np.abs(m.mean - mean) < 3 * m.se_mean)
    assert np.all(np.abs(m.var - var) < 3 * m.se_var)
    # w ~ U(0,1): Var(w) = 1/12, mu4 = 1/80, so the standard error of s^2 is about
    # sqrt((1/80 - 1/144) / n)
    assert m.se_var[0] == pytest.approx(np.sqrt((1 / 80 - 1 / 144) / 40000), rel=0.02)


def test_standard_errors_are_calibrated():
    # over many independent ensembles the error / standard error is ~ N(0, 1)
    rng = np.random.default_rng(0)
    z_mean, z_var = [], []
    mean, var = _closed_form(2)
    for _ in range(400):
        m = mc_moments(np.stack([powers(x, 2) for x in rng.random(200)]))
        z_mean.append((m.mean - mean) / m.se_mean)
        z_var.append((m.var - var) / m.se_var)
    assert np.std(z_mean) == pytest.approx(1.0, abs=0.1)
    assert np.std(z_var) == pytest.approx(1.0, abs=0.15)


def test_quadrature_moments_exact_for_polynomials():
    mean, var = quadrature_moments(powers, 4)  # degree 6 integrand, 4 nodes exact to 7
    m_ref, v_ref = _closed_form()
    np.testing.assert_allclose(mean, m_ref, rtol=1e-14)
    np.testing.assert_allclose(var, v_ref, rtol=1e-13)


def test_pseudospectral_projection_recovers_polynomial():
    # w^3 in the orthonormal shifted-Legendre basis, recovered exactly with 4 nodes
    chaos = ChaosBasis(3)
    Theta = pseudospectral_projection(lambda w: powers(w, 3), chaos)
    grid = np.linspace(0, 1, 7)
    np.testing.assert_allclose(
        Theta @ chaos.evaluate(grid).T, np.stack([powers(g) for g in grid]).T, atol=1e-14
    )
    # the unnormalised (paper's) basis gives the same function
    chaos_u = ChaosBasis(3, normalized=False)
    Tu = pseudospectral_projection(lambda w: powers(w, 3), chaos_u)
    np.testing.assert_allclose(
        Tu @ chaos_u.evaluate(grid).T, Theta @ chaos.evaluate(grid).T, atol=1e-14
    )


def test_collocation_equals_galerkin_for_the_beam(beam):
    # affine in one germ: Galerkin order p == collocation at p + 1 Gauss nodes
    Theta = beam.solve(1.0).Theta
    fn = functools.partial(beam.solve_deterministic, eps=1.0)
    np.testing.assert_allclose(
        pseudospectral_projection(fn, beam.chaos), Theta, rtol=1e-10, atol=1e-10
    )


def test_mc_error_falls_like_inverse_sqrt_n():
    y = monte_carlo(powers, draw_germ(20000, seed=9), workers=1)
    mean, var = _closed_form()
    sizes = [20, 50, 100, 200, 500, 1000, 2000]
    em, ev, nb = batch_errors(y, mean, var, sizes)
    assert list(nb) == [1000, 400, 200, 100, 40, 20, 10]
    assert loglog_slope(sizes, em) == pytest.approx(-0.5, abs=0.1)
    assert loglog_slope(sizes, ev) == pytest.approx(-0.5, abs=0.1)


def test_loglog_slope_exact():
    x = np.array([1.0, 10.0, 100.0])
    assert loglog_slope(x, 3 * x**-0.5) == pytest.approx(-0.5, rel=1e-12)


def test_relative_error():
    assert relative_error([1.0, 2.1], [1.0, 2.0]) == pytest.approx(0.05)
    with pytest.raises(ValueError, match="zero"):
        relative_error([1.0], [0.0])
    with pytest.raises(ValueError, match="shape"):
        relative_error([1.0, 2.0], [1.0])


# -- bad input ---------------------------------------------------------------------------
def test_bad_inputs():
    with pytest.raises(TypeError, match="fn"):
        monte_carlo(3, [0.1])
    with pytest.raises(ValueError, match="samples"):
        monte_carlo(powers, [])
    with pytest.raises(ValueError, match="samples"):
        monte_carlo(powers, [0.1, np.nan])
    with pytest.raises(TypeError, match="picklable"):
        monte_carlo(lambda w: w, [0.1, 0.2], workers=2)
    with pytest.raises(TypeError, match="executor"):
        monte_carlo(powers, [0.1], executor=object())
    with pytest.raises(ValueError, match="workers"):
        monte_carlo(powers, [0.1], workers=0)
    with pytest.raises(ValueError, match="chunksize"):
        monte_carlo(powers, [0.1], chunksize=0)
    with pytest.raises(ValueError, match="sample 2"):
        monte_carlo(nan_at_half, [0.1, 0.2, 0.7], workers=1)
    with pytest.raises(ValueError, match="shapes"):
        monte_carlo(lambda w: np.zeros(1 + int(w > 0.5)), [0.1, 0.9], workers=1, chunksize=1)
    with pytest.raises(ValueError, match="2 samples"):
        mc_moments([[1.0]])
    with pytest.raises(ValueError, match="outputs"):
        mc_moments([[1.0], [np.inf]])
    with pytest.raises(ValueError, match="sizes"):
        batch_errors(np.ones((10, 1)), [1.0], [1.0], [20])
    with pytest.raises(ValueError, match="n"):
        draw_germ(0)


def fail_above_half(w):
    if w > 0.5:
        raise ArithmeticError(f"model failed at omega={w}")
    return np.array([w])


def test_worker_error_propagates():
    with pytest.raises(ArithmeticError, match="omega=0.7"):
        monte_carlo(fail_above_half, [0.1, 0.7, 0.2, 0.3], workers=2, chunksize=1)


def test_sampler_refuses_buckling(beam):
    # a load above buckling is refused when the sampler is built, not inside the workers
    with pytest.raises(SingularSystemError):
        beam.response_function(3.0)


def test_quadrature_moments_refuse_outputs_over_the_budget_after_one_node():
    from ecfm_uq.errors import MemoryBudgetError
    from ecfm_uq.memory import set_memory_budget

    calls = []

    def field(omega):
        calls.append(omega)
        return np.full(10_000, float(np.sum(omega)))

    previous = set_memory_budget(1e6)  # 3 x 16 nodes x 10^4 values x 8 B = 3.8 MB
    try:
        with pytest.raises(MemoryBudgetError, match="Gauss nodes"):
            quadrature_moments(field, 4, dim=2)
    finally:
        set_memory_budget(previous)
    assert len(calls) == 1  # refused from the first output, before the other 15 ran


def test_quadrature_references_refuse_non_finite_outputs():
    # a model that returns NaN at a Gauss node must not give a NaN mean or PCE silently
    with pytest.raises(ValueError, match="NaN or inf"):
        quadrature_moments(nan_at_half, 4)
    with pytest.raises(ValueError, match="NaN or inf"):
        pseudospectral_projection(nan_at_half, ChaosBasis(3))
