"""Sobol indices by sampling (Saltelli 2010, Jansen 1999) against closed forms."""

import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from ecfm_uq.mc import sobol_indices

G_A = np.array([0, 1, 4.5, 9] + [99] * 16, dtype=float)


def g_function(X):
    return np.prod((np.abs(4.0 * X - 2.0) + G_A) / (1.0 + G_A), axis=-1)


def g_reference():
    Vi = 1.0 / (3.0 * (1.0 + G_A) ** 2)
    V = np.prod(1.0 + Vi) - 1.0
    T = np.array([Vi[i] * np.prod(np.delete(1.0 + Vi, i)) for i in range(len(G_A))]) / V
    return Vi / V, T


def ishigami(X):
    return (
        np.sin(X[..., 0]) + 7.0 * np.sin(X[..., 1]) ** 2 + 0.1 * X[..., 2] ** 4 * np.sin(X[..., 0])
    )


def ishigami_reference():
    a, b, pi = 7.0, 0.1, math.pi
    V = a**2 / 8 + b * pi**4 / 5 + b**2 * pi**8 / 18 + 0.5
    V1, V2, V13 = (1 + b * pi**4 / 5) ** 2 / 2, a**2 / 8, b**2 * pi**8 * (1 / 18 - 1 / 50)
    return np.array([V1, V2, 0.0]) / V, np.array([V1 + V13, V2, V13]) / V


def test_g_function_20_inputs_errors_and_interval_coverage():
    S0, T0 = g_reference()
    errors, inside = [], []
    for seed in range(8):
        r = sobol_indices(g_function, [(0, 1)] * 20, 2**13, seed=seed, vectorized=True)
        assert r.n_evaluations == 2**13 * 22
        assert r.first_order_interval.shape == (2, 20) and r.total_interval.shape == (2, 20)
        errors.append(max(np.abs(r.first_order - S0).max(), np.abs(r.total - T0).max()))
        for est, ref in ((r.first_order_interval, S0), (r.total_interval, T0)):
            inside.append((est[0] <= ref) & (ref <= est[1]))
    assert max(errors) <= 0.02
    assert np.mean(inside) >= 0.90


def test_ishigami_random_design_within_its_intervals():
    S0, T0 = ishigami_reference()
    inside = []
    for seed in range(10):
        r = sobol_indices(
            ishigami, [(-np.pi, np.pi)] * 3, 4096, seed=seed, design="random", vectorized=True
        )
        inside.append((r.first_order_interval[0] <= S0) & (S0 <= r.first_order_interval[1]))
        inside.append((r.total_interval[0] <= T0) & (T0 <= r.total_interval[1]))
        # the interval is about 2 x 1.96 standard errors wide and the errors that size
        assert np.all(np.abs(r.total - T0) < 5 * r.total_se)
    assert 0.85 <= np.mean(inside) <= 1.0


def test_per_point_and_vectorized_models_and_executors_agree():
    def one(x):
        return ishigami(np.asarray(x))

    a = sobol_indices(one, [(-np.pi, np.pi)] * 3, 256, seed=3)
    b = sobol_indices(ishigami, [(-np.pi, np.pi)] * 3, 256, seed=3, vectorized=True)
    with ThreadPoolExecutor(2) as pool:
        c = sobol_indices(one, [(-np.pi, np.pi)] * 3, 256, seed=3, executor=pool, chunksize=50)
    np.testing.assert_allclose(a.first_order, b.first_order, rtol=1e-12)
    np.testing.assert_allclose(a.total, c.total, rtol=1e-12)


def test_vector_output_gives_one_column_of_indices_per_component():
    f = lambda X: np.stack([X[:, 0] + 2 * X[:, 1], X[:, 1]], axis=1)  # noqa: E731
    r = sobol_indices(f, [(0, 1), (0, 1)], 1024, seed=0, vectorized=True)
    assert r.first_order.shape == (2, 2) and r.total_interval.shape == (2, 2, 2)
    np.testing.assert_allclose(r.first_order[:, 0], [0.2, 0.8], atol=0.02)
    np.testing.assert_allclose(r.total[:, 1], [0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize(
    "kwargs,exc,match",
    [
        (dict(n=1000), ValueError, "power of 2.*n=1024"),
        (dict(level=1.5), ValueError, "level"),
        (dict(design="lhs"), ValueError, "design"),
    ],
)
def test_bad_arguments_are_named(kwargs, exc, match):
    args = dict(n=64, seed=0, vectorized=True)
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        sobol_indices(ishigami, [(-np.pi, np.pi)] * 3, **args)


def test_constant_output_and_dependent_inputs_are_refused():
    from scipy import stats

    from ecfm_uq.chaos import Inputs

    with pytest.raises(ValueError, match="zero variance"):
        sobol_indices(lambda X: np.ones(len(X)), [(0, 1)] * 2, 64, seed=0, vectorized=True)
    dep = Inputs([stats.norm(), stats.norm()], correlation=[[1, 0.5], [0.5, 1]])
    with pytest.raises(ValueError, match="dependent"):
        sobol_indices(lambda X: X[:, 0], dep, 64, seed=0, vectorized=True)


def test_pce_page_verification_recipe_runs_and_the_surrogate_lies_in_the_intervals():
    import pathlib
    import re

    text = (pathlib.Path(__file__).parents[2] / "docs" / "pce.md").read_text()
    code = re.findall(r"```py\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code.replace("print(", "_ = ("), "pce.md", "exec"), ns)
    lo, hi = ns["mc"].total_interval
    T = ns["pce"].total()
    assert np.all((lo <= T) & (T <= hi))
    _, T0 = ishigami_reference()
    np.testing.assert_allclose(ns["mc"].total, T0, atol=0.02)


def test_a_dask_client_gives_identical_indices():
    distributed = pytest.importorskip("distributed")
    bounds = [(-np.pi, np.pi)] * 3
    serial = sobol_indices(ishigami, bounds, 512, seed=0, vectorized=True)
    with (
        distributed.LocalCluster(
            n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        out = sobol_indices(
            ishigami, bounds, 512, seed=0, executor=client, vectorized=True, chunksize=200
        )
    np.testing.assert_array_equal(out.total, serial.total)
    np.testing.assert_array_equal(out.first_order_interval, serial.first_order_interval)


def test_bootstrap_intervals_agree_with_the_asymptotic_ones_and_cover_the_truth():
    S0, T0 = ishigami_reference()
    inside, ratio = [], []
    for seed in range(6):
        kw = dict(seed=seed, design="random", vectorized=True)
        a = sobol_indices(ishigami, [(-np.pi, np.pi)] * 3, 2048, **kw)
        b = sobol_indices(ishigami, [(-np.pi, np.pi)] * 3, 2048, interval="bootstrap", **kw)
        np.testing.assert_array_equal(a.total, b.total)  # same runs, other intervals
        ratio.append(b.total_se / a.total_se)
        inside.append((b.total_interval[0] <= T0) & (T0 <= b.total_interval[1]))
        inside.append((b.first_order_interval[0] <= S0) & (S0 <= b.first_order_interval[1]))
    # two estimates of one standard error: equal up to the bootstrap's own noise
    assert 0.8 < np.median(ratio) < 1.25
    assert np.mean(inside) >= 0.85
    with pytest.raises(ValueError, match="interval"):
        sobol_indices(ishigami, [(-np.pi, np.pi)] * 3, 64, seed=0, interval="bca")
