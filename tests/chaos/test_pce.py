"""PolynomialChaosExpansion, UniformInputs and fit_pce against closed forms.

References are analytic (Ishigami, Sobol' g, polynomial and linear models with Hoeffding
decompositions worked out by hand), chaospy's own implementations of E/Var/Sens_m/Sens_t,
brute-force leave-one-out refits, and the stochastic Galerkin solver (which equals tensor
Gauss collocation for operators affine in the germ).
"""

import functools
from concurrent.futures import ThreadPoolExecutor

import chaospy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ecfm_uq.chaos import (
    ChaosBasis,
    PolynomialChaosExpansion,
    UniformInputs,
    fit_pce,
    smolyak_rule,
    weighted_gram,
)
from ecfm_uq.chaos.regression import loo_nested
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, solve_steady

PI = np.pi

# --------------------------------------------------------------------------------------
# analytic models
# --------------------------------------------------------------------------------------
ISH_A, ISH_B = 7.0, 0.1


def ishigami(x):
    return np.sin(x[0]) + ISH_A * np.sin(x[1]) ** 2 + ISH_B * x[2] ** 4 * np.sin(x[0])


def ishigami_reference():
    a, b = ISH_A, ISH_B
    V = a**2 / 8 + b * PI**4 / 5 + b**2 * PI**8 / 18 + 0.5
    V1 = (1 + b * PI**4 / 5) ** 2 / 2
    V2 = a**2 / 8
    V13 = b**2 * PI**8 * (1 / 18 - 1 / 50)
    S = np.array([V1, V2, 0.0]) / V
    T = np.array([V1 + V13, V2, V13]) / V
    return a / 2, V, S, T


G_A = np.array([0.0, 1.0, 4.5, 9.0, 99.0, 99.0])


def sobol_g(x):
    return np.prod((np.abs(4 * x - 2) + G_A) / (1 + G_A))


def sobol_g_reference():
    Vi = 1 / (3 * (1 + G_A) ** 2)
    V = np.prod(1 + Vi) - 1
    T = np.array([Vi[i] * np.prod(np.delete(1 + Vi, i)) for i in range(len(G_A))]) / V
    return 1.0, V, Vi / V, T


def poly_model(x):
    """x0 + x1^2 + x0 x1 with x0 ~ U(0, 1), x1 ~ U(-1, 1).

    Hoeffding: x0 x1 = (x0 - 1/2) x1 + x1 / 2, so (in units of 1/180)
    V0 = 15, V1 = Var(x1^2 + x1/2) = 16 + 15 = 31, V01 = (1/12)(1/3) = 5, V = 51.
    """
    return x[0] + x[1] ** 2 + x[0] * x[1]


POLY_BOUNDS = [(0.0, 1.0), (-1.0, 1.0)]
POLY_MEAN = 0.5 + 1 / 3
POLY_VAR = 51 / 180
POLY_S = np.array([15, 31]) / 51
POLY_S01 = 5 / 51
POLY_T = np.array([20, 36]) / 51


def vector_model(x):
    """Two outputs: the polynomial model and its negative plus 3 (same indices)."""
    y = poly_model(x)
    return np.array([y, 3 - 2 * y])


def max_index_error(pce, S, T):
    return max(np.abs(pce.first_order() - S).max(), np.abs(pce.total() - T).max())


# --------------------------------------------------------------------------------------
# the expansion object
# --------------------------------------------------------------------------------------
def test_moments_and_indices_of_a_hand_built_expansion():
    # y = 1 + 2 L1(w0) + L1(w1) + 3 L1(w0) L1(w1) on an orthonormal basis
    basis = ChaosBasis(2, dim=2)  # (0,0) (1,0) (0,1) (2,0) (1,1) (0,2)
    pce = PolynomialChaosExpansion(basis, [1.0, 2.0, 1.0, 0.0, 3.0, 0.0])
    assert pce.mean == 1.0
    assert pce.variance == pytest.approx(14.0, rel=1e-15)
    np.testing.assert_allclose(pce.first_order(), [4 / 14, 1 / 14], rtol=1e-14)
    np.testing.assert_allclose(pce.total(), [13 / 14, 10 / 14], rtol=1e-14)
    assert pce.sobol([0, 1]) == pytest.approx(9 / 14, rel=1e-14)
    assert pce.sobol([1, 0], kind="closed") == pytest.approx(1.0, rel=1e-14)
    assert pce.sobol(1, kind="total") == pytest.approx(10 / 14, rel=1e-14)


def test_unnormalized_basis_gives_the_same_statistics():
    rng = np.random.default_rng(1)
    b1 = ChaosBasis(3, dim=3)
    b0 = ChaosBasis(3, dim=3, normalized=False)
    c1 = rng.normal(size=(b1.size, 2))
    # Psi_unnormalised = Psi_orthonormal * sqrt(norms2): same function, rescaled coefficients
    c0 = c1 / np.sqrt(b0.norms2)[:, None]
    p1, p0 = PolynomialChaosExpansion(b1, c1), PolynomialChaosExpansion(b0, c0)
    w = rng.random((7, 3))
    np.testing.assert_allclose(p0.evaluate(w), p1.evaluate(w), rtol=1e-12)
    np.testing.assert_allclose(p0.variance, p1.variance, rtol=1e-13)
    np.testing.assert_allclose(p0.total(), p1.total(), rtol=1e-13)
    np.testing.assert_allclose(p0.covariance, p1.covariance, rtol=1e-13)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), dim=st.integers(1, 4), order=st.integers(1, 4))
def test_sobol_identities(seed, dim, order):
    rng = np.random.default_rng(seed)
    basis = ChaosBasis(order, dim)
    c = rng.normal(size=basis.size)
    c[1:] += 0.1  # keep the variance away from zero
    pce = PolynomialChaosExpansion(basis, c)
    parts = pce.sobol_interactions()
    assert sum(float(v) for v in parts.values()) == pytest.approx(1.0, rel=1e-12)
    S, T = pce.first_order(), pce.total()
    assert S.sum() <= 1 + 1e-12 <= T.sum() + 2e-12
    assert np.all(S <= T + 1e-15)
    for i in range(dim):
        # total = sum of interactions containing i = 1 - closed index of the others
        assert T[i] == pytest.approx(sum(float(v) for u, v in parts.items() if i in u), abs=1e-12)
        others = [j for j in range(dim) if j != i]
        if others:
            assert T[i] == pytest.approx(1 - pce.sobol(others, kind="closed"), abs=1e-12)


def test_covariance_is_consistent_with_linear_maps_and_samples():
    rng = np.random.default_rng(2)
    basis = ChaosBasis(3, dim=2)
    pce = PolynomialChaosExpansion(basis, rng.normal(size=(basis.size, 3)))
    np.testing.assert_allclose(np.diag(pce.covariance), pce.variance, rtol=1e-14)
    A = rng.normal(size=(2, 3))
    mapped = pce.linear_map(A)
    np.testing.assert_allclose(mapped.covariance, A @ pce.covariance @ A.T, rtol=1e-12)
    np.testing.assert_allclose(mapped.mean, A @ pce.mean, rtol=1e-12)
    # exact moments against many surrogate samples (sampling error ~ 1/sqrt(n))
    y = pce.sample(200_000, seed=3)
    np.testing.assert_allclose(y.mean(axis=0), pce.mean, atol=5 * pce.std.max() / 400)
    np.testing.assert_allclose(np.cov(y.T), pce.covariance, atol=0.05 * pce.variance.max())


def test_field_output_shape_is_kept():
    basis = ChaosBasis(2, dim=2)
    c = np.random.default_rng(4).normal(size=(basis.size, 3, 4))
    pce = PolynomialChaosExpansion(basis, c)
    assert pce.output_shape == (3, 4)
    assert pce.evaluate(np.full((5, 2), 0.3)).shape == (5, 3, 4)
    assert pce.first_order().shape == (2, 3, 4)
    assert pce.covariance.shape == (3, 4, 3, 4)
    assert pce.quantile([0.1, 0.9], n_samples=1000).shape == (2, 3, 4)


def test_quantiles_and_density_of_a_uniform_output():
    # y = x ~ U(2, 5): quantile a + q (b - a), density 1/3 inside
    pce = PolynomialChaosExpansion(ChaosBasis(1), [3.5, 1.5 / np.sqrt(3)], inputs=[(2, 5)])
    q = np.array([0.1, 0.5, 0.9])
    np.testing.assert_allclose(pce.quantile(q, n_samples=200_000, seed=0), 2 + 3 * q, atol=0.01)
    kde = pce.density(n_samples=50_000, seed=0)
    assert kde(3.5)[0] == pytest.approx(1 / 3, rel=0.05)
    np.testing.assert_allclose(pce([[2.0], [5.0]]), [2.0, 5.0], atol=1e-13)


# --------------------------------------------------------------------------------------
# inputs and chaospy interop
# --------------------------------------------------------------------------------------
def test_uniform_inputs_map_affinely_and_from_chaospy():
    dist = chaospy.J(chaospy.Uniform(-1, 3), chaospy.Uniform(10, 11))
    inputs = UniformInputs.from_chaospy(dist)
    np.testing.assert_array_equal(inputs.bounds, [[-1, 3], [10, 11]])
    w = np.array([[0.0, 1.0], [0.25, 0.5]])
    np.testing.assert_allclose(inputs.from_germ(w), [[-1, 11], [0, 10.5]])
    np.testing.assert_allclose(inputs.to_germ(inputs.from_germ(w)), w, atol=1e-15)
    iid = UniformInputs.from_chaospy(chaospy.Iid(chaospy.Uniform(0, 2), 3))
    assert iid.dim == 3 and np.all(iid.upper == 2)
    assert UniformInputs.from_chaospy(inputs.to_chaospy()) == inputs


def test_chaospy_export_matches_chaospy_statistics_and_round_trips():
    rng = np.random.default_rng(5)
    basis = ChaosBasis(3, dim=3)
    pce = PolynomialChaosExpansion(
        basis, rng.normal(size=(basis.size, 2)), inputs=[(-1, 2), (0, 5), (3, 4)]
    )
    poly = pce.to_chaospy()
    dist = pce.inputs.to_chaospy()
    x = pce.inputs.from_germ(rng.random((9, 3)))
    np.testing.assert_allclose(poly(*x.T).T, pce(x), rtol=1e-10, atol=1e-10)
    # chaospy's own moment and Sobol implementations on the exported polynomial
    np.testing.assert_allclose(chaospy.E(poly, dist), pce.mean, rtol=1e-10)
    np.testing.assert_allclose(chaospy.Var(poly, dist), pce.variance, rtol=1e-8)
    np.testing.assert_allclose(chaospy.Sens_m(poly, dist), pce.first_order(), atol=1e-8)
    np.testing.assert_allclose(chaospy.Sens_t(poly, dist), pce.total(), atol=1e-8)
    back = PolynomialChaosExpansion.from_chaospy(poly, pce.inputs)
    np.testing.assert_allclose(back.coefficients, pce.coefficients, atol=1e-10)


def test_chaospy_fit_imports_into_our_expansion():
    # a chaospy user's expansion of the polynomial model, read off with our indices
    dist = chaospy.J(*[chaospy.Uniform(a, b) for a, b in POLY_BOUNDS])
    expansion = chaospy.generate_expansion(2, dist)
    nodes, weights = chaospy.generate_quadrature(3, dist, rule="gaussian")
    evals = [poly_model(n) for n in nodes.T]
    poly = chaospy.fit_quadrature(expansion, nodes, weights, evals)
    pce = PolynomialChaosExpansion.from_chaospy(poly, dist)
    assert pce.variance == pytest.approx(POLY_VAR, rel=1e-10)
    np.testing.assert_allclose(pce.first_order(), POLY_S, atol=1e-10)


# --------------------------------------------------------------------------------------
# non-intrusive fits against closed forms
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "method, kw",
    [
        ("quadrature", dict(order=2)),
        ("smolyak", dict(order=2)),
        ("smolyak", dict(order=2, rule="clenshaw-curtis")),
        ("lstsq", dict(order=2, n_samples=12, seed=0)),
        ("lstsq", dict(order=3, n_samples=40, design="sobol", seed=1)),
        ("lars", dict(n_samples=30, seed=0)),
        ("omp", dict(n_samples=30, design="halton", seed=0)),
    ],
)
def test_polynomial_model_is_recovered_exactly(method, kw):
    pce = fit_pce(poly_model, POLY_BOUNDS, method, **kw)
    assert pce.mean == pytest.approx(POLY_MEAN, rel=1e-12)
    assert pce.variance == pytest.approx(POLY_VAR, rel=1e-11)
    np.testing.assert_allclose(pce.first_order(), POLY_S, atol=1e-11)
    np.testing.assert_allclose(pce.total(), POLY_T, atol=1e-11)
    assert pce.sobol([0, 1]) == pytest.approx(POLY_S01, abs=1e-11)
    x = np.array([[0.3, -0.7], [1.0, 1.0]])
    np.testing.assert_allclose(pce(x), [poly_model(r) for r in x], atol=1e-11)
    assert pce.diagnostics["method"] == method


def test_linear_model_indices_are_weighted_input_variances():
    a = np.array([1.0, -2.0, 0.5])
    bounds = np.array([[0.0, 2.0], [1.0, 1.5], [-3.0, 3.0]])
    var = (bounds[:, 1] - bounds[:, 0]) ** 2 / 12
    pce = fit_pce(functools.partial(np.dot, a), bounds, "lstsq", order=1, n_samples=10, seed=0)
    S = a**2 * var / np.sum(a**2 * var)
    np.testing.assert_allclose(pce.first_order(), S, rtol=1e-12)
    np.testing.assert_allclose(pce.total(), S, rtol=1e-12)
    assert pce.mean == pytest.approx(a @ bounds.mean(axis=1), rel=1e-12)


def test_ishigami_by_tensor_quadrature():
    mean, V, S, T = ishigami_reference()
    pce = fit_pce(ishigami, [(-PI, PI)] * 3, "quadrature", order=16)
    assert pce.mean == pytest.approx(mean, rel=1e-10)
    assert pce.variance == pytest.approx(V, rel=1e-9)
    assert max_index_error(pce, S, T) < 1e-9


def test_ishigami_by_lars_reaches_peer_accuracy_with_500_runs():
    # OpenTURNS' LARS reaches 3.3e-7 with 500 LHS runs (SPEC); chaospy least squares 2.6e-4
    mean, V, S, T = ishigami_reference()
    pce = fit_pce(ishigami, [(-PI, PI)] * 3, "lars", n_samples=500, seed=0)
    assert max_index_error(pce, S, T) < 1e-6
    assert pce.mean == pytest.approx(mean, rel=1e-6)
    assert pce.diagnostics["corrected_loo_error"] < 1e-8
    assert pce.diagnostics["n_evaluations"] == 500


def test_ishigami_by_omp_with_100_runs():
    # OpenTURNS' LARS reaches 1.0e-3 with 100 LHS runs (SPEC); the Ishigami function is
    # sparse in the Legendre basis, which greedy selection finds from 100 points
    mean, V, S, T = ishigami_reference()
    pce = fit_pce(ishigami, [(-PI, PI)] * 3, "omp", n_samples=100, seed=0)
    assert max_index_error(pce, S, T) < 1e-5
    assert pce.variance == pytest.approx(V, rel=1e-5)


def test_ishigami_lstsq_loo_error_tracks_the_true_error():
    mean, V, S, T = ishigami_reference()
    pce = fit_pce(ishigami, [(-PI, PI)] * 3, "lstsq", order=6, n_samples=300, seed=0)
    rng = np.random.default_rng(0)
    x = rng.uniform(-PI, PI, (20_000, 3))
    y = np.array([ishigami(r) for r in x])
    true_rel = np.mean((pce(x) - y) ** 2) / np.var(y)
    loo = float(pce.diagnostics["loo_error"])
    assert 0.3 * true_rel < loo < 3 * true_rel
    assert float(pce.diagnostics["corrected_loo_error"]) > loo


def test_sobol_g_function_by_lars():
    # non-smooth (|4x - 2|): OpenTURNS reaches 1.0e-2 with 500 runs (SPEC)
    mean, V, S, T = sobol_g_reference()
    pce = fit_pce(sobol_g, [(0, 1)] * 6, "lars", n_samples=500, seed=2, q_norm=0.75)
    assert max_index_error(pce, S, T) < 2e-2
    assert pce.mean == pytest.approx(mean, abs=5e-3)


def test_smolyak_gauss_is_exact_for_total_degree_and_cc_is_nested():
    rng = np.random.default_rng(6)
    basis = ChaosBasis(4, dim=3)
    truth = PolynomialChaosExpansion(basis, rng.normal(size=basis.size))
    model = lambda x: truth.evaluate(x[None, :])[0]
    pce = fit_pce(model, [(0, 1)] * 3, "smolyak", order=4)
    assert pce.basis == basis
    np.testing.assert_allclose(pce.coefficients, truth.coefficients, atol=1e-11)
    # nested Clenshaw-Curtis: level 3 in 2-D has 29 distinct nodes; the tensor rules of
    # the formula hold more (the shared ones are evaluated once)
    nodes, parts = smolyak_rule(3, 2, "clenshaw-curtis")
    assert len(nodes) == 29
    assert sum(len(p[2]) for p in parts) > len(nodes)
    # the combination weights integrate constants exactly
    total = sum(coef * w.sum() for coef, _, _, w, _ in parts)
    assert total == pytest.approx(1.0, abs=1e-13)


def test_ols_leave_one_out_equals_brute_force_refits():
    rng = np.random.default_rng(7)
    basis = ChaosBasis(2, dim=2)
    w = rng.random((15, 2))
    X = basis.evaluate(w)
    y = np.sin(3 * w[:, 0]) + w[:, 1] ** 3
    Q, R = np.linalg.qr(X)
    loo, corrected = loo_nested(Q, R, y)
    for k in range(1, basis.size + 1):
        e = []
        for i in range(len(y)):
            keep = np.arange(len(y)) != i
            c = np.linalg.lstsq(X[keep, :k], y[keep], rcond=None)[0]
            e.append(y[i] - X[i, :k] @ c)
        assert loo[k - 1] == pytest.approx(np.mean(np.square(e)) / np.var(y), rel=1e-9)
        C = X[:, :k].T @ X[:, :k] / len(y)
        T = len(y) / (len(y) - k) * (1 + np.trace(np.linalg.inv(C)) / len(y))
        assert corrected[k - 1] == pytest.approx(loo[k - 1] * T, rel=1e-9)


def test_vector_outputs_and_given_evaluations():
    x = np.random.default_rng(8).uniform([0, -1], [1, 1], (25, 2))
    y = np.array([vector_model(r) for r in x])
    pce = fit_pce(None, POLY_BOUNDS, "lstsq", order=2, samples=x, evaluations=y)
    assert pce.output_shape == (2,)
    np.testing.assert_allclose(pce.first_order(), np.column_stack([POLY_S, POLY_S]), atol=1e-11)
    np.testing.assert_allclose(pce.mean, [POLY_MEAN, 3 - 2 * POLY_MEAN], rtol=1e-12)
    lars = fit_pce(vector_model, POLY_BOUNDS, "lars", n_samples=30, seed=1)
    np.testing.assert_allclose(lars.total(), np.column_stack([POLY_T, POLY_T]), atol=1e-10)


@pytest.mark.parametrize("method", ["lars", "omp", "lstsq"])
def test_constant_output_component_is_fitted_and_reported(method):
    model = lambda x: np.array([x[0] ** 2 + x[1], 2.0])
    pce = fit_pce(model, [(0, 1), (0, 1)], method, order=2, n_samples=20, seed=0)
    np.testing.assert_allclose(pce.mean, [1 / 3 + 1 / 2, 2.0], rtol=1e-12)
    np.testing.assert_allclose(pce.variance[1], 0.0, atol=1e-24)
    T = pce.total(zero_variance=0.0)
    np.testing.assert_allclose(T[:, 1], 0.0)
    # Var(x0^2) = 1/5 - 1/9 = 4/45, Var(x1) = 1/12
    np.testing.assert_allclose(T[:, 0], np.array([16, 15]) / 31, atol=1e-10)
    with pytest.raises(ValueError, match=r"component \(1,\)"):
        pce.first_order()


def test_thread_executor_gives_the_same_expansion():
    ref = fit_pce(ishigami, [(-PI, PI)] * 3, "lstsq", order=4, n_samples=80, seed=3)
    with ThreadPoolExecutor(2) as pool:
        par = fit_pce(
            ishigami, [(-PI, PI)] * 3, "lstsq", order=4, n_samples=80, seed=3, executor=pool
        )
    np.testing.assert_array_equal(par.coefficients, ref.coefficients)


def test_process_pool_gives_the_same_expansion_and_needs_a_picklable_model():
    ref = fit_pce(ishigami, [(-PI, PI)] * 3, "quadrature", order=3)
    par = fit_pce(ishigami, [(-PI, PI)] * 3, "quadrature", order=3, workers=2)
    np.testing.assert_array_equal(par.coefficients, ref.coefficients)
    with pytest.raises(TypeError, match="`model` must be picklable"):
        fit_pce(lambda x: x[0], [(0, 1)], "quadrature", order=2, workers=2)


def test_docstring_examples():
    import doctest

    import ecfm_uq.chaos.inputs
    import ecfm_uq.chaos.nonintrusive
    import ecfm_uq.chaos.pce

    for module in (ecfm_uq.chaos.pce, ecfm_uq.chaos.nonintrusive, ecfm_uq.chaos.inputs):
        result = doctest.testmod(module, extraglobs={"np": np, "ChaosBasis": ChaosBasis})
        assert result.attempted > 0 and result.failed == 0, module.__name__


class _Counter:
    def __init__(self):
        self.n = 0

    def update(self, k):
        self.n += k


def test_progress_bar_counts_the_model_runs(capsys):
    fit_pce(poly_model, POLY_BOUNDS, "lstsq", order=2, n_samples=12, seed=0, progress=True)
    assert "fit_pce (regression)" in capsys.readouterr().err
    bar = _Counter()
    with ThreadPoolExecutor(2) as pool:
        fit_pce(poly_model, POLY_BOUNDS, "quadrature", order=3, executor=pool, progress=bar)
    assert bar.n == 16


def test_chaospy_distribution_as_inputs():
    dist = chaospy.J(*[chaospy.Uniform(a, b) for a, b in POLY_BOUNDS])
    pce = fit_pce(poly_model, dist, "quadrature", order=2)
    np.testing.assert_allclose(pce.total(), POLY_T, atol=1e-12)


# --------------------------------------------------------------------------------------
# Galerkin solutions as expansions
# --------------------------------------------------------------------------------------
def test_beam_galerkin_sobol_and_variance_equal_pseudospectral_projection():
    from ecfm_uq.problems.beam import BeamModel

    model = BeamModel()
    sol = model.solve(1.0)
    gal = sol.pce(observe=model.M_obs)
    # Galerkin with an operator affine in one germ = collocation at the order + 1 Gauss nodes
    nip = fit_pce(model.response_function(1.0), [(0, 1)], "quadrature", order=model.chaos.order)
    np.testing.assert_allclose(gal.first_order(), nip.first_order(), atol=1e-8)
    np.testing.assert_allclose(gal.total(), nip.total(), atol=1e-8)
    np.testing.assert_allclose(gal.variance, nip.variance, rtol=1e-8)
    np.testing.assert_allclose(gal.coefficients, nip.coefficients, rtol=1e-8, atol=1e-10)
    mean, var = model.sensor_moments(sol.Theta)
    np.testing.assert_allclose(gal.mean, mean, rtol=1e-13)
    np.testing.assert_allclose(gal.variance, var, rtol=1e-13)


def _two_germ_response(x, K0, K1, K2, F):
    return np.linalg.solve(K0 + (x[0] - 0.5) * K1 + (x[1] - 0.5) * K2, F)


def test_two_variable_galerkin_sobol_equal_tensor_collocation():
    # K(w) = K0 + (w0 - 1/2) K1 + (w1 - 1/2) K2: on a tensor basis the Galerkin solution
    # equals tensor Gauss collocation, so all Sobol indices agree to round-off
    rng = np.random.default_rng(9)
    B = rng.normal(size=(4, 4))
    K0 = B @ B.T + 4 * np.eye(4)
    K1 = 0.8 * np.diag([1.0, 0.5, 0.2, 0.1])
    K2 = 0.6 * np.diag([0.1, 0.3, 1.0, 0.4])
    F = rng.normal(size=4)
    chaos = ChaosBasis(4, dim=2, index_set="tensor")
    G1 = weighted_gram(chaos, lambda w: w[:, 0] - 0.5)
    G2 = weighted_gram(chaos, lambda w: w[:, 1] - 0.5)
    system = GalerkinSystem(
        [LinearTerm(K0), LinearTerm(K1, G=G1), LinearTerm(K2, G=G2), LoadTerm.constant(F)],
        n_eps=0,
        basis=chaos,
    )
    sol = solve_steady(system, np.zeros(0))
    gal = sol.pce()
    model = functools.partial(_two_germ_response, K0=K0, K1=K1, K2=K2, F=F)
    nip = fit_pce(model, [(0, 1), (0, 1)], "quadrature", order=4)
    assert 0.05 < gal.first_order().min() and gal.sobol([0, 1]).max() > 1e-4
    np.testing.assert_allclose(gal.first_order(), nip.first_order(), atol=1e-8)
    np.testing.assert_allclose(gal.total(), nip.total(), atol=1e-8)
    np.testing.assert_allclose(gal.sobol([0, 1]), nip.sobol([0, 1]), atol=1e-8)


# --------------------------------------------------------------------------------------
# bad input: one test per documented error
# --------------------------------------------------------------------------------------
def _nan_in_corner(x):
    return np.nan if x[0] > 0.9 else x[0]


def _shape_changes(x):
    return np.zeros(2) if x[0] > 0.5 else np.zeros(3)


@pytest.mark.parametrize("bounds", [[(1.0, 1.0)], [(0, 1), (2.0, -2.0)], [(0, np.inf)]])
def test_bad_bounds(bounds):
    with pytest.raises(ValueError, match="bounds"):
        UniformInputs(bounds)
    with pytest.raises(ValueError, match="inputs"):
        fit_pce(poly_model, bounds, "quadrature")


def test_non_uniform_chaospy_distribution():
    dist = chaospy.J(chaospy.Uniform(0, 1), chaospy.Normal(0, 1))
    with pytest.raises(TypeError, match="dist.*Normal.*uniform"):
        UniformInputs.from_chaospy(dist)
    # issue 22: fit_pce takes it (Legendre x Hermite germs) instead of refusing it
    pce = fit_pce(poly_model, dist, "quadrature")
    assert [g.family for g in pce.basis.germs] == ["legendre", "hermite"]


def test_too_few_regression_samples():
    with pytest.raises(ValueError, match="n_samples.*P = 10"):
        fit_pce(poly_model, POLY_BOUNDS, "lstsq", order=3, n_samples=10)
    with pytest.raises(ValueError, match="samples"):
        fit_pce(poly_model, POLY_BOUNDS, "lstsq", order=3, samples=np.full((5, 2), 0.5))


def test_model_returning_nan_is_named():
    with pytest.raises(ValueError, match=r"`model` returned NaN or inf at Gauss point \d+ \(x="):
        fit_pce(_nan_in_corner, [(0, 1)], "quadrature", order=4)


def test_mismatched_output_shapes():
    with pytest.raises(ValueError, match="model.*different shapes"):
        fit_pce(_shape_changes, [(0, 1)], "quadrature", order=3)
    x = np.linspace(0, 1, 12)[:, None]
    with pytest.raises(ValueError, match="evaluations"):
        fit_pce(None, [(0, 1)], "lstsq", order=2, samples=x, evaluations=np.zeros(11))
    basis = ChaosBasis(2, dim=2)
    with pytest.raises(ValueError, match="coefficients"):
        PolynomialChaosExpansion(basis, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="theta"):
        PolynomialChaosExpansion.from_galerkin(basis, np.zeros((3, 5)))
    with pytest.raises(ValueError, match="inputs"):
        PolynomialChaosExpansion(basis, np.zeros(6), inputs=[(0, 1)])


def test_zero_variance_output():
    pce = PolynomialChaosExpansion(ChaosBasis(1, dim=2), [[1.0, 2.0], [0.0, 1.0], [0.0, 0.0]])
    with pytest.raises(ValueError, match=r"component \(0,\).*zero_variance"):
        pce.first_order()
    np.testing.assert_array_equal(pce.total(zero_variance=0.0), [[0.0, 1.0], [0.0, 0.0]])


def test_unknown_method_design_and_subset():
    with pytest.raises(ValueError, match="method"):
        fit_pce(poly_model, POLY_BOUNDS, "kriging")
    with pytest.raises(ValueError, match="design"):
        fit_pce(poly_model, POLY_BOUNDS, "lstsq", design="grid")
    pce = PolynomialChaosExpansion(ChaosBasis(1, dim=2), [0.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="subset"):
        pce.sobol([2])
    with pytest.raises(TypeError, match="model"):
        fit_pce("not a model", POLY_BOUNDS, "quadrature")
    with pytest.raises(ValueError, match="samples.*regression"):
        fit_pce(poly_model, POLY_BOUNDS, "quadrature", samples=np.full((9, 2), 0.5))
