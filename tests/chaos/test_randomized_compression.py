"""Field outputs over the memory budget (issue 21 item 5): the randomized SVD against the
exact one and against fields of known rank, the budget taking the randomized path, and
refusals (of the executor's output array and of the compressions) that name the way out."""

import tracemalloc

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.chaos import fit_pce
from ecfm_uq.chaos.regression.compression import compress_outputs, exact_pca_bytes
from ecfm_uq.errors import MemoryBudgetError
from ecfm_uq.executor import evaluate_samples
from ecfm_uq.mc import monte_carlo
from ecfm_uq.memory import set_memory_budget

S_GRID = np.linspace(0.0, 1.0, 2000)
INPUTS = [stats.norm(0, 1), stats.uniform(-1, 2), stats.beta(2, 3)]


def field(x):
    """A decaying, phase-shifted profile: not of finite rank in the inputs."""
    return np.exp(-(1 + 0.3 * x[0]) * S_GRID) * (1 + 0.2 * x[1] * np.sin(2 * np.pi * S_GRID + x[2]))


@pytest.fixture
def env_budget(monkeypatch):
    """Set the budget the way a user does, through ECFM_UQ_MEMORY_BUDGET."""
    previous = set_memory_budget(None)

    def set_env(text):
        monkeypatch.setenv("ECFM_UQ_MEMORY_BUDGET", text)

    yield set_env
    set_memory_budget(previous)


def _field_evaluations(n, seed=1):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.standard_normal(n), rng.uniform(-1, 1, n), rng.beta(2, 3, n)])
    return np.array([field(x) for x in X])


def _sin_largest_angle(A, B):
    """Sine of the largest principal angle between the row spaces of A and B (orthonormal rows)."""
    return float(np.linalg.norm(B - (B @ A.T) @ A, 2))


@pytest.mark.parametrize("tol", [1e-4, 1e-6, 1e-8])
def test_randomized_svd_agrees_with_the_exact_svd(tol):
    Y = _field_evaluations(300)
    U, S, Vt = np.linalg.svd(Y - Y.mean(axis=0), full_matrices=False)  # independent truth
    Z, V, ybar, err, info = compress_outputs(Y, tol, "randomized", return_info=True)
    _, V_ex, _, err_ex = compress_outputs(Y, tol, "exact")
    K = V.shape[0]
    assert info["method"] == "randomized" and info["rank"] == K
    # the same rank by the same energy criterion, and the tolerance met on the data
    assert K == V_ex.shape[0]
    assert err.max() <= tol
    np.testing.assert_allclose(err, err_ex, rtol=1e-6, atol=1e-14)
    # singular values to 1e-10 relative, the subspace to 1e-7 (largest principal angle)
    S_r = np.linalg.svd(Z, compute_uv=False)
    np.testing.assert_allclose(S_r, S[:K], rtol=1e-10)
    np.testing.assert_allclose(V @ V.T, np.eye(K), atol=1e-12)
    assert _sin_largest_angle(Vt[:K], V) < 1e-7
    # the reported error is the residual of the reconstruction, component by component
    resid = Y - ybar - Z @ V
    np.testing.assert_allclose(err, resid.var(axis=0) / Y.var(axis=0), rtol=1e-8)


@pytest.mark.parametrize("rank", [5, 40])
def test_randomized_svd_finds_the_rank_of_a_low_rank_field(rank):
    # Y = 1 mean + U diag(s) V^T with centred orthonormal U: the centred singular values
    # are s exactly; rank 40 needs more than the first sketch of 32 columns
    rng = np.random.default_rng(rank)
    n, m = 400, 3000
    U = np.linalg.qr(rng.standard_normal((n, rank)) - rng.standard_normal((1, rank)))[0]
    U -= U.mean(axis=0)
    U = np.linalg.qr(U)[0]
    V = np.linalg.qr(rng.standard_normal((m, rank)))[0].T
    s = np.logspace(1, -2, rank)
    Y = 2.0 + (U * s) @ V
    Z, Vr, ybar, err, info = compress_outputs(Y, 1e-12, "randomized", return_info=True)
    assert info["rank"] == rank
    assert info["sketch_columns"] == (32 if rank <= 22 else 64)
    np.testing.assert_allclose(np.linalg.svd(Z, compute_uv=False), s, rtol=1e-10)
    assert _sin_largest_angle(V, Vr) < 1e-10
    np.testing.assert_allclose(ybar + Z @ Vr, Y, atol=1e-11)
    assert err.max() <= 1e-12


def test_the_randomized_path_holds_the_evaluations_once(env_budget):
    Y = _field_evaluations(300)
    env_budget(str(2 * Y.nbytes))
    assert exact_pca_bytes(*Y.shape) > 2 * Y.nbytes  # the exact SVD would be refused
    tracemalloc.start()
    try:
        _, V, _, err, info = compress_outputs(Y, 1e-6, return_info=True)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert info["method"] == "randomized" and err.max() <= 1e-6
    # Y itself was allocated before tracing began: everything else stays below one more Y
    assert peak < Y.nbytes


def test_fit_pce_takes_the_randomized_path_under_a_small_budget(env_budget):
    ref = fit_pce(field, INPUTS, "lars", n_samples=300, seed=0)
    assert ref.diagnostics["compression"] == "exact"
    env_budget("12M")  # the exact SVD of 300 x 2000 needs 33 MiB, the randomized 7 MiB
    pce = fit_pce(field, INPUTS, "lars", n_samples=300, seed=0)
    d = pce.diagnostics
    assert d["compression"] == "randomized" and d["compression_error"].max() <= 1e-6
    assert d["n_components"] == ref.diagnostics["n_components"]
    np.testing.assert_allclose(pce.mean, ref.mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pce.variance, ref.variance, rtol=1e-6, atol=1e-14)
    # and against the model: quadrature first-order indices on a few components
    idx = np.arange(1, len(S_GRID), 197)
    quad = fit_pce(lambda x: field(x)[idx], INPUTS, "quadrature", order=8)
    np.testing.assert_allclose(pce.first_order()[:, idx], quad.first_order(), atol=1e-3)


def test_the_randomized_path_can_be_asked_for():
    pce = fit_pce(field, INPUTS, "lars", n_samples=120, seed=0, compress="randomized")
    assert pce.diagnostics["compression"] == "randomized"
    assert pce.diagnostics["compression_info"]["power_iterations"] == 2
    with pytest.raises(TypeError, match="'randomized'"):
        fit_pce(field, INPUTS, "lars", n_samples=50, compress="rsvd")


class _Counting:
    """A model that counts its calls (in-process, workers=1)."""

    def __init__(self, m):
        self.m, self.calls = m, 0

    def __call__(self, x):
        self.calls += 1
        return np.full(self.m, float(np.sum(x)))


def test_the_output_array_is_checked_after_one_run(env_budget):
    env_budget("1M")
    fn = _Counting(10_000)  # 200 runs x 10 000 values = 15 MiB
    with pytest.raises(MemoryBudgetError, match="return only the values you need") as e:
        evaluate_samples(fn, np.random.default_rng(0).random((200, 2)), workers=1)
    assert fn.calls == 1
    assert "evaluate `samples` in slices" in str(e.value) and "200 runs" in str(e.value)
    fn = _Counting(10_000)
    with pytest.raises(MemoryBudgetError, match="return only the values you need"):
        monte_carlo(fn, np.random.default_rng(0).random((200, 2)), workers=1)
    assert fn.calls == 1
    fn = _Counting(10)  # small outputs pass, in order
    y = evaluate_samples(fn, np.arange(12.0)[:, None], workers=1, chunksize=5)
    np.testing.assert_array_equal(y[:, 0], np.arange(12.0))


def test_fit_pce_refusals_name_the_cheaper_call_before_the_other_runs(env_budget):
    bounds = [(0.0, 1.0)] * 3
    env_budget("20M")
    fn = _Counting(4000)  # 300 x 4000: Y 9.2 MiB; exact SVD 57 MiB; randomized fits
    with pytest.raises(MemoryBudgetError, match="compress='randomized'"):
        fit_pce(fn, bounds, "lars", n_samples=300, seed=0, compress="exact")
    assert fn.calls == 1
    fn = _Counting(4000)  # one selection per component: two (P, m) arrays of 1771 terms
    with pytest.raises(MemoryBudgetError, match="let `compress` compress the field"):
        fit_pce(fn, bounds, "lars", order=20, n_samples=300, seed=0, compress=False)
    assert fn.calls == 1
    env_budget("4M")
    fn = _Counting(4000)  # the evaluations alone are over the budget
    with pytest.raises(MemoryBudgetError, match="fewer `n_samples`") as e:
        fit_pce(fn, bounds, "lars", order=2, n_samples=300, seed=0)
    assert fn.calls == 1 and "fewer output values" in str(e.value)


def test_other_field_sized_allocations_are_refused_naming_the_cheaper_call(env_budget):
    from ecfm_uq.chaos import ChaosBasis, PolynomialChaosExpansion
    from ecfm_uq.mc import mc_moments

    env_budget("4M")

    def never(x):
        raise AssertionError("the model must not run")

    # tensor quadrature in 8 inputs: 4^8 nodes by 4^8 terms, 64 GiB of basis values
    with pytest.raises(MemoryBudgetError, match="method='smolyak'"):
        fit_pce(never, [(0.0, 1.0)] * 8, "quadrature", order=3)
    # least squares of a 20 000-value field: Y fits (1.8 MiB), its residual terms do not
    fn = _Counting(20_000)
    with pytest.raises(MemoryBudgetError, match="method='lars'"):
        fit_pce(fn, [(0.0, 1.0)] * 2, "lstsq", order=2, n_samples=12, seed=0)
    assert fn.calls == 1
    # a 5 000-value expansion at 200 points (7.6 MiB), its quantiles, Monte Carlo moments
    pce = PolynomialChaosExpansion(ChaosBasis(2, 2), np.ones((6, 5000)))
    with pytest.raises(MemoryBudgetError, match="evaluate the points in slices"):
        pce.evaluate(np.full((200, 2), 0.5))
    assert pce.evaluate(np.full((20, 2), 0.5)).shape == (20, 5000)  # a slice still answers
    with pytest.raises(MemoryBudgetError, match="fewer `n_samples`"):
        pce.quantile(0.5, n_samples=100)
    with pytest.raises(MemoryBudgetError, match=r"outputs\[:, idx\]"):
        mc_moments(np.ones((100, 5000)))
    # Sobol indices of 40 000 components of 6 terms: four (6, 40 000) arrays, 7.3 MiB
    big = PolynomialChaosExpansion(ChaosBasis(2, 2), np.ones((6, 40_000)), [(0.0, 1.0)] * 2)
    with pytest.raises(MemoryBudgetError, match=r"coefficients\[:, idx\]"):
        big.first_order()
    with pytest.raises(MemoryBudgetError, match="indices of the components you need"):
        big.sobol_germ()
    sub = PolynomialChaosExpansion(big.basis, big.coefficients[:, :100], big.inputs)
    np.testing.assert_allclose(sub.first_order().sum(axis=0), 1.0 - 1.0 / 5.0)


def test_the_output_check_runs_before_the_other_runs_through_an_executor(env_budget):
    from concurrent.futures import ThreadPoolExecutor

    env_budget("1M")
    fn = _Counting(10_000)
    with ThreadPoolExecutor(2) as pool, pytest.raises(MemoryBudgetError, match="200 runs"):
        evaluate_samples(fn, np.random.default_rng(0).random((200, 2)), pool)
    assert fn.calls == 1


def test_an_executor_that_drops_results_is_an_error():
    class Lossy:
        def map(self, f, chunks):
            return [f(c) for c in list(chunks)[:-1]]

    with pytest.raises(RuntimeError, match="returned results for"):
        evaluate_samples(_Counting(3), np.arange(10.0)[:, None], Lossy(), chunksize=3)


def test_gauss_node_outputs_are_checked_after_one_node(env_budget):
    from ecfm_uq.mc import quadrature_moments

    env_budget("1M")
    fn = _Counting(10_000)  # 3 x 64 nodes x 10 000 values = 15 MiB
    with pytest.raises(MemoryBudgetError, match="fewer `n_points`"):
        quadrature_moments(fn, 8, dim=2)
    assert fn.calls == 1
    mean, var = quadrature_moments(_Counting(3), 3, dim=2)  # sum of two U(0, 1)
    np.testing.assert_allclose(mean, 1.0, rtol=1e-14)
    np.testing.assert_allclose(var, 1 / 6, rtol=1e-13)


def test_a_zero_tolerance_keeps_every_direction_and_terminates():
    Y = np.random.default_rng(5).standard_normal((20, 50))
    Z, V, ybar, err, info = compress_outputs(Y, 0.0, "randomized", return_info=True)
    _, V_ex, _, _ = compress_outputs(Y, 0.0, "exact")
    assert info["sketch_columns"] == 20 and V.shape[0] == V_ex.shape[0]
    np.testing.assert_allclose(ybar + Z @ V, Y, atol=1e-12)


# --------------------------------------------------------------------------------------
# evaluations that do not fit even once: compressed as they arrive (one-pass sketch)
# --------------------------------------------------------------------------------------
def _stream(Y, k, block=37):
    from ecfm_uq.chaos.regression.compression import StreamingSketch

    sk = StreamingSketch(*Y.shape, k)
    for a in range(0, len(Y), block):
        sk(a, Y[a : a + block])
    return sk


def test_streaming_sketch_recovers_a_low_rank_field():
    rng = np.random.default_rng(7)
    n, m, rank = 400, 3000, 5
    U = np.linalg.qr(rng.standard_normal((n, rank)))[0]
    U -= U.mean(axis=0)
    U = np.linalg.qr(U)[0]
    V = np.linalg.qr(rng.standard_normal((m, rank)))[0].T
    s = np.logspace(1, -2, rank)
    Y = 2.0 + (U * s) @ V
    Z, Vr, ybar, est, info = _stream(Y, 32).compress(1e-12)
    assert info["rank"] == rank and info["passes"] == 1 and info["tolerance_met"]
    np.testing.assert_allclose(np.linalg.svd(Z, compute_uv=False), s, rtol=1e-9)
    np.testing.assert_allclose(ybar + Z @ Vr, Y, atol=1e-10)
    np.testing.assert_allclose(_stream(Y, 32).variance(), Y.var(axis=0), rtol=1e-10)


@pytest.mark.parametrize("tol", [1e-4, 1e-6, 1e-8])
def test_streaming_sketch_against_the_exact_svd(tol):
    Y = _field_evaluations(300)
    Z, V, ybar, est, info = _stream(Y, 48).compress(tol)
    _, V_ex, _, _ = compress_outputs(Y, tol, "exact")
    # the rank of the exact criterion, give or take one (the error is estimated)
    assert abs(info["rank"] - V_ex.shape[0]) <= 1
    true = (Y - ybar - Z @ V).var(axis=0) / Y.var(axis=0)
    # the estimate has a relative standard deviation of 25 %: within a factor 3 of the
    # measured share, and the measured share within 3 tol
    assert est.max() <= tol and true.max() <= 3 * tol
    assert 1 / 3 < est.max() / true.max() < 3


def test_fit_pce_compresses_the_field_as_it_arrives_when_it_cannot_be_stored(env_budget):
    # q_norm=1.0: fixed candidates, so both fits choose among the same ones (the adaptive
    # default sizes its candidate sets by the memory budget, which differs between them)
    kw = dict(order=8, n_samples=1500, seed=0, q_norm=1.0)
    ref = fit_pce(field, INPUTS, "lars", **kw)
    assert ref.diagnostics["compression"] == "exact"
    env_budget("16M")  # the 1500 x 2000 evaluations alone are 22.9 MiB
    calls = _Counting(1)  # the budget refuses to store them, not to evaluate them
    pce = fit_pce(lambda x: (calls(x), field(x))[1], INPUTS, "lars", **kw)
    d = pce.diagnostics
    assert calls.calls == 1500
    assert d["compression"] == "streaming" and d["compression_info"]["passes"] == 1
    assert d["n_components"] == ref.diagnostics["n_components"]
    assert d["compression_error"].max() <= 1e-6
    np.testing.assert_allclose(pce.mean, ref.mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pce.first_order(), ref.first_order(), atol=1e-8)
    np.testing.assert_allclose(pce.total(), ref.total(), atol=1e-8)
    # compress="randomized" asks for that method: refused there, not silently streamed
    with pytest.raises(MemoryBudgetError, match="compress=True"):
        fit_pce(field, INPUTS, "lars", compress="randomized", **kw)


def test_a_consumer_receives_the_rows_in_order_and_nothing_is_stored():
    seen = []

    def check(n, shape):
        assert (n, shape) == (10, (3,))
        return lambda start, block: seen.append((start, block.copy()))

    out = evaluate_samples(
        _Counting(3), np.arange(10.0)[:, None], workers=1, chunksize=4, check=check
    )
    assert out is None
    rows = np.concatenate([b for _, b in seen])
    assert [a for a, _ in seen] == [0, 1, 5, 9]
    np.testing.assert_array_equal(rows[:, 0], np.arange(10.0))


def test_the_streaming_sketch_stays_within_its_memory_model():
    from ecfm_uq.chaos.regression.compression import StreamingSketch, streaming_bytes

    Y = _field_evaluations(1500)
    tracemalloc.start()
    try:
        sk = StreamingSketch(*Y.shape, 64)
        for a in range(0, len(Y), 60):  # chunks of 0.9 MiB, as the runner sends them
            sk(a, Y[a : a + 60])
        sk.compress(1e-6)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= streaming_bytes(*Y.shape, 64) < Y.nbytes


def test_a_streamed_sketch_too_small_for_the_tolerance_warns():
    # full-rank noise: no rank up to the 8-column sketch meets 1e-6, and the result says so
    Y = np.random.default_rng(3).standard_normal((200, 500))
    with pytest.warns(RuntimeWarning, match="compress_tol"):
        Z, Vr, ybar, est, info = _stream(Y, 8).compress(1e-6)
    assert not info["tolerance_met"] and est.max() > 1e-6
