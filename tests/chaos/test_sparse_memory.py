"""Sparse regression within the memory budget: candidate sizing, the Gram form of the
selection (never the n x P candidate matrix), refusals that name the cheaper call."""

import math
import tracemalloc

import numpy as np
import pytest

import ecfm_uq.chaos.regression.compression as compression
import ecfm_uq.chaos.regression.fit as regression_fit
from ecfm_uq.chaos import ChaosBasis, fit_pce
from ecfm_uq.chaos.regression import candidate_degree
from ecfm_uq.errors import MemoryBudgetError
from ecfm_uq.memory import check_covariance, set_memory_budget

# f(x) = prod_k (1 + a_k phi(x_k)), phi(x) = (e^x - (e - 1)) / sigma on U(0, 1): E f = 1,
# Var f = prod(1 + a_k^2) - 1, S_k = a_k^2 / Var f (closed forms)
A8 = np.array([0.8, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.05])
SIGMA = math.sqrt((math.e**2 - 1) / 2 - (math.e - 1) ** 2)
VAR8 = float(np.prod(1 + A8**2) - 1)
S8 = A8**2 / VAR8


def product_model(x):
    return float(np.prod(1.0 + A8 * (np.exp(x) - (math.e - 1)) / SIGMA))


@pytest.fixture
def budget():
    previous = set_memory_budget(None)
    yield set_memory_budget
    set_memory_budget(previous)


def test_candidate_degree_keeps_the_ten_per_run_rule_when_memory_is_plentiful():
    # comb(17 + 3, 3) = 1140 <= 10 * 120 < comb(18 + 3, 3) = 1330
    assert candidate_degree(120, 3, budget=2**40) == (17, "samples")
    # 1 input: the basis stays small, degree 30 is the cap
    assert candidate_degree(1000, 1, budget=2**40) == (30, "max_degree")


def test_candidate_degree_is_limited_by_work_and_by_memory():
    # n = 1e5, 8 inputs: W = 3 n P^2 + 15 P (n/2 > P) P^2 is 3.1e12 <= 4e12 at degree 6
    # (P = 3003) and 1.6e13 at degree 7 (P = 6435): degree 6, not 16
    assert candidate_degree(100_000, 8, budget=2**40) == (6, "work")
    # n = 2 000: W(degree 8, P = 12 870 > n) = 3 n^2 P + 15 P (n/2)^2 = 3.5e11: the ten-per-run
    # rule still decides (degree 9 has 24 310 > 20 000 terms), as before
    assert candidate_degree(2_000, 8, budget=2**40) == (8, "samples")
    # 32 P^2 bytes within half of 64 MiB: P <= 1024, degree 4 (P = 495; degree 5 has 1287)
    assert candidate_degree(20_000, 8, budget=64 * 2**20) == (4, "memory")


@pytest.mark.parametrize("method", ["lars", "omp"])
def test_gram_form_selects_what_the_design_form_selects(method, monkeypatch):
    # one problem, both forms: the same columns and, to round-off, the same coefficients
    x = np.random.default_rng(3).random((1500, 4))
    y = np.array([product_model(np.r_[xi, 0.5 * np.ones(4)]) for xi in x])
    # q_norm=1.0: the fixed total-degree candidates, the path with a Gram form
    kw = dict(samples=x, evaluations=y, order=4, q_norm=1.0)
    ref = fit_pce(None, [(0.0, 1.0)] * 4, method, **kw)
    monkeypatch.setattr(regression_fit, "_EXACT_DESIGN_BYTES", 0)
    new = fit_pce(None, [(0.0, 1.0)] * 4, method, **kw)
    assert ref.diagnostics["selection"] == "design" and new.diagnostics["selection"] == "gram"
    assert ref.diagnostics["n_terms"] == new.diagnostics["n_terms"]
    np.testing.assert_array_equal(ref.coefficients != 0, new.coefficients != 0)
    np.testing.assert_allclose(new.coefficients, ref.coefficients, rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(
        new.diagnostics["corrected_loo_error"], ref.diagnostics["corrected_loo_error"], rtol=1e-6
    )


def test_tight_budget_fits_eight_inputs_without_the_candidate_matrix(budget):
    n, limit = 20_000, 64 * 2**20
    budget(limit)
    tracemalloc.start()
    try:
        pce = fit_pce(product_model, [(0.0, 1.0)] * 8, "lars", n_samples=n, seed=0, q_norm=1.0)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    d = pce.diagnostics
    P = ChaosBasis(d["candidate_degree"], 8).size
    assert d["selection"] == "gram" and d["candidate_limit"] == "memory"
    # the n x P candidate matrix alone would exceed the budget; the fit never held it
    assert 8 * n * P > limit
    assert peak < 8 * n * P and peak < limit
    # the earlier default (P <= 10 n: degree 11, 75 582 terms) would need 11 GiB
    assert 8 * n * ChaosBasis(11, 8).size > 2**33
    # a least-squares mean is off by about the residual's standard error, sqrt(LOO Var / n)
    se = math.sqrt(float(d["corrected_loo_error"]) * VAR8 / n)
    assert abs(float(pce.mean) - 1.0) < 4 * se
    assert abs(float(pce.variance) / VAR8 - 1.0) < 1e-2
    assert np.abs(pce.first_order() - S8).max() < 5e-3


def test_explicit_order_over_the_budget_is_refused_before_the_model_runs(budget):
    def never(x):
        raise AssertionError("the model must not run")

    budget(2**20)
    with pytest.raises(MemoryBudgetError, match="smaller `order`"):
        fit_pce(never, [(0.0, 1.0)] * 8, "lars", order=6, n_samples=5000, seed=0, q_norm=1.0)
    with pytest.raises(MemoryBudgetError, match="method='lars'"):
        fit_pce(never, [(0.0, 1.0)] * 8, "lstsq", order=4, n_samples=5000, seed=0)


def test_compression_refuses_a_field_over_the_budget_naming_compress_false(budget):
    budget(2**20)
    # the exact SVD is what is refused (issue 21: "auto" now falls back to a randomized SVD)
    with pytest.raises(MemoryBudgetError, match="compress=False"):
        compression.compress_outputs(np.zeros((400, 400)), 1e-6, "exact")


def test_covariance_check_names_variance(budget):
    budget(2**20)
    # 2 arrays of 1000^2 floats = 15.3 MiB > 1 MiB
    with pytest.raises(MemoryBudgetError, match=r"variance\(Theta\)"):
        check_covariance(1000)
    assert check_covariance(100) == 2 * 8 * 100**2


def test_pce_covariance_of_a_large_field_is_refused_naming_variance(budget):
    from ecfm_uq.chaos import PolynomialChaosExpansion

    pce = PolynomialChaosExpansion(ChaosBasis(2, 2), np.ones((6, 1000)), [(0.0, 1.0)] * 2)
    budget(2**20)
    with pytest.raises(MemoryBudgetError, match="pce.variance"):
        _ = pce.covariance
    np.testing.assert_allclose(pce.variance, 5.0)  # the cheaper call still answers


def test_galerkin_covariance_is_refused_over_the_budget(budget):
    from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm

    N = 1000
    system = GalerkinSystem(
        [LinearTerm(np.eye(N)), LoadTerm.constant(np.ones(N))], 0, basis=ChaosBasis(2, 2)
    )
    Theta = np.random.default_rng(0).random((N, system.P))
    budget(2**20)
    with pytest.raises(MemoryBudgetError, match="variance"):
        system.covariance(Theta)
