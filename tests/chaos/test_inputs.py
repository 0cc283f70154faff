"""Inputs as distributions: Askey germs, isoprobabilistic transforms, a Gaussian copula.

Truths: scipy.stats quantiles and moments, closed-form moments and Sobol indices of
product-sum models of independent inputs, Monte Carlo, and chaospy's expectation
operator on the exported polynomial.
"""

import itertools
import math

import chaospy
import numpy as np
import pytest
from scipy import stats

from ecfm_uq.chaos import ChaosBasis, Inputs, PolynomialChaosExpansion, UniformInputs, fit_pce


# --------------------------------------------------------------------------------------
# closed-form Sobol indices of y = c0 + sum_t c_t prod_v x_v^k (independent inputs)
# --------------------------------------------------------------------------------------
def closed_form(c0, terms, moment, dim):
    """Mean, variance, first-order and total indices from the inputs' raw moments.

    ``terms``: [(c_t, {v: k})]; ``moment(v, k)`` = E[x_v^k]. Var(E[y | x_S]) follows from
    independence: factors outside S are replaced by their means.
    """

    def cond_var(S):
        mean = c0 + sum(c * math.prod(moment(v, k) for v, k in pw.items()) for c, pw in terms)
        second = 0.0
        for (ci, pi), (cj, pj) in itertools.product(terms, repeat=2):
            val = ci * cj
            for v in set(pi) | set(pj):
                ki, kj = pi.get(v, 0), pj.get(v, 0)
                val *= moment(v, ki + kj) if v in S else moment(v, ki) * moment(v, kj)
            second += val
        return second - (mean - c0) ** 2, mean

    full = set(range(dim))
    V, mean = cond_var(full)
    S = np.array([cond_var({i})[0] for i in range(dim)]) / V
    T = np.array([1.0 - cond_var(full - {i})[0] / V for i in range(dim)])
    return mean, V, S, T


# --------------------------------------------------------------------------------------
# marginals and germs
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "law,family",
    [
        (stats.uniform(-1, 3), "legendre"),
        (stats.norm(2.0, 0.5), "hermite"),
        (stats.gamma(2.5, loc=1.0, scale=0.5), "laguerre"),
        (stats.expon(scale=2.0), "laguerre"),
        (stats.beta(2.0, 3.0, loc=1.0, scale=2.0), "jacobi"),
        (stats.lognorm(0.3, scale=2.0), "hermite"),
        (stats.weibull_min(1.5, scale=2.0), "hermite"),
        (stats.truncnorm(-1.0, 2.0, loc=1.0), "own"),  # bounded: its own polynomials
        (chaospy.Normal(2.0, 0.5), "hermite"),
        (chaospy.Gamma(2.5, 0.5, 1.0), "laguerre"),
        (chaospy.Beta(2.0, 3.0, 1.0, 3.0), "jacobi"),
        (chaospy.LogNormal(0.1, 0.3), "hermite"),
    ],
)
def test_each_marginal_is_its_germ_pushed_through_the_right_map(law, family):
    inputs = Inputs([law])
    germ = inputs.germs[0]
    assert germ.family == family
    u = np.linspace(0.01, 0.99, 13)
    x = inputs.from_germ(germ.ppf(u)[:, None])[:, 0]
    ref = law.ppf(u) if hasattr(law, "ppf") else law.inv(u)
    np.testing.assert_allclose(x, np.ravel(ref), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(inputs.to_germ(x[:, None])[:, 0], germ.ppf(u), rtol=1e-8, atol=1e-9)


def test_transform_keeps_precision_in_the_upper_tail():
    inputs = Inputs([stats.weibull_min(1.5)])
    xi = np.array([[6.0], [8.0]])  # Phi(xi) rounds to 1: the survival function is used
    np.testing.assert_allclose(
        inputs.from_germ(xi)[:, 0], stats.weibull_min(1.5).isf(stats.norm.sf(xi[:, 0])), rtol=1e-12
    )
    assert np.all(np.isfinite(inputs.from_germ(xi)))


def test_gaussian_copula_reproduces_the_correlation_of_normal_inputs():
    mu, sd = np.array([1.0, -2.0, 0.5]), np.array([0.5, 2.0, 1.0])
    R = np.array([[1.0, 0.6, -0.3], [0.6, 1.0, 0.2], [-0.3, 0.2, 1.0]])
    inputs = Inputs([stats.norm(m, s) for m, s in zip(mu, sd, strict=True)], correlation=R)
    assert inputs.dependent and all(g.family == "hermite" for g in inputs.germs)
    x = inputs.sample(200_000, seed=0)
    C = np.cov(x.T)
    # the sample covariance's standard error is about sd_i sd_j sqrt(2 / n) < 0.013
    np.testing.assert_allclose(C, R * np.outer(sd, sd), atol=0.03)
    xi = np.random.default_rng(1).standard_normal((20, 3))
    np.testing.assert_allclose(inputs.to_germ(inputs.from_germ(xi)), xi, atol=1e-12)


def test_chaospy_mvnormal_and_scipy_multivariate_normal_are_the_same_inputs():
    mu, S = [1.0, 2.0], [[1.0, 0.5], [0.5, 2.0]]
    xi = np.random.default_rng(2).standard_normal((5, 2))
    a = PolynomialChaosExpansion(
        ChaosBasis(1, 2, germ="hermite"), np.zeros(3), chaospy.MvNormal(mu, S)
    )
    b = PolynomialChaosExpansion(
        ChaosBasis(1, 2, germ="hermite"), np.zeros(3), stats.multivariate_normal(mu, S)
    )
    np.testing.assert_allclose(a.inputs.from_germ(xi), b.inputs.from_germ(xi), rtol=1e-14)
    np.testing.assert_allclose(a.inputs.correlation, [[1, 0.5 / np.sqrt(2)], [0.5 / np.sqrt(2), 1]])


# --------------------------------------------------------------------------------------
# must-show: dependent Gaussian inputs, gamma / beta / lognormal inputs
# --------------------------------------------------------------------------------------
MU = np.array([1.0, -0.5])
SIGMA = np.array([[0.5, 0.3], [0.3, 0.8]])
A_Q = np.array([[1.0, 1.0], [1.0, 0.0]])
B_Q = np.array([0.0, 1.0])


def quadratic(x):
    return x @ A_Q @ x + B_Q @ x + 3.0


@pytest.mark.parametrize(
    "method,kw",
    [
        ("lstsq", dict(order=2, n_samples=100, seed=0)),
        ("lars", dict(n_samples=100, seed=0)),
        ("omp", dict(n_samples=100, seed=1)),
        ("quadrature", dict(order=2)),
        ("smolyak", dict(order=2)),
    ],
)
def test_polynomial_of_dependent_gaussian_inputs_mean_and_variance(method, kw):
    # y = x^T A x + b^T x + c, x ~ N(mu, Sigma): closed-form Gaussian moments
    mean = np.trace(A_Q @ SIGMA) + MU @ A_Q @ MU + B_Q @ MU + 3.0
    var = (
        2 * np.trace(A_Q @ SIGMA @ A_Q @ SIGMA)
        + 4 * MU @ A_Q @ SIGMA @ A_Q @ MU
        + B_Q @ SIGMA @ B_Q
        + 4 * B_Q @ SIGMA @ A_Q @ MU
    )
    pce = fit_pce(quadratic, chaospy.MvNormal(MU, SIGMA), method, **kw)
    assert pce.diagnostics["n_evaluations"] <= 100
    assert abs(pce.mean - mean) <= 1e-6 * abs(mean)
    assert abs(pce.variance - var) <= 1e-6 * var
    x = pce.inputs.sample(7, seed=3)
    np.testing.assert_allclose(pce(x), [quadratic(r) for r in x], rtol=1e-9)


def test_sobol_indices_of_dependent_inputs_are_refused_with_the_reason():
    pce = fit_pce(quadratic, chaospy.MvNormal(MU, SIGMA), "quadrature", order=2)
    for call in (pce.first_order, pce.total, lambda: pce.sobol([0])):
        with pytest.raises(ValueError, match="dependent `inputs`.*no unique split"):
            call()
    # the germ's indices are available under their own name and sum as they should
    S = pce.sobol_germ("first")
    T = pce.sobol_germ("total")
    assert np.all(S <= T + 1e-15) and 0.99 < T.sum()


GBL = [stats.gamma(2.0), stats.beta(2.0, 3.0), stats.lognorm(0.25)]


def gbl_model(x):
    return x[0] + x[1] ** 2 + x[0] * x[2]


def gbl_reference():
    def moment(v, k):
        return float(GBL[v].moment(k)) if k else 1.0

    return closed_form(0.0, [(1.0, {0: 1}), (1.0, {1: 2}), (1.0, {0: 1, 2: 1})], moment, 3)


@pytest.mark.parametrize("method", ["lars", "omp"])
def test_gamma_beta_lognormal_inputs_moments_and_first_order_indices_at_300_runs(method):
    mean, var, S, T = gbl_reference()
    pce = fit_pce(gbl_model, GBL, method, n_samples=300, seed=1)
    assert [g.family for g in pce.basis.germs] == ["laguerre", "jacobi", "hermite"]
    assert abs(pce.mean - mean) <= 1e-3 * abs(mean)
    assert abs(pce.variance - var) <= 1e-3 * var
    np.testing.assert_allclose(pce.first_order(), S, atol=1e-3)
    np.testing.assert_allclose(pce.total(), T, atol=1e-3)


def test_gamma_beta_lognormal_quadrature_converges_to_the_closed_form():
    mean, var, S, T = gbl_reference()
    pce = fit_pce(gbl_model, GBL, "quadrature", order=6)
    assert abs(pce.mean - mean) <= 1e-12 * mean
    assert abs(pce.variance - var) <= 1e-9 * var
    np.testing.assert_allclose(pce.first_order(), S, atol=1e-10)


def test_askey_inputs_export_to_chaospy_in_their_own_variables():
    laws = [
        stats.norm(1.0, 0.3),
        stats.gamma(2.0, scale=0.5),
        stats.beta(2.0, 3.0, loc=-1, scale=2),
    ]

    def f(x):
        return x[0] ** 2 + x[1] * x[2] + x[2] ** 3

    pce = fit_pce(f, laws, "quadrature", order=3)
    poly = pce.to_chaospy()
    dist = pce.inputs.to_chaospy()
    assert float(chaospy.E(poly, dist)) == pytest.approx(float(pce.mean), rel=1e-10)
    assert float(chaospy.Var(poly, dist)) == pytest.approx(float(pce.variance), rel=1e-8)
    x = pce.inputs.sample(5, seed=0)
    np.testing.assert_allclose(poly(*x.T), [f(r) for r in x], rtol=1e-9)
    with pytest.raises(ValueError, match="affine.*not a polynomial"):
        fit_pce(np.sum, [stats.lognorm(0.2)], "quadrature", order=2).to_chaospy()


def test_quantiles_and_density_are_in_the_inputs_variables():
    law = stats.lognorm(0.3, scale=2.0)
    pce = fit_pce(lambda x: x[0], [law], "quadrature", order=10)
    q = pce.quantile([0.1, 0.5, 0.9], n_samples=200_000, seed=0)
    np.testing.assert_allclose(q, law.ppf([0.1, 0.5, 0.9]), rtol=5e-3)
    kde = pce.density(n_samples=50_000)
    np.testing.assert_allclose(kde([1.5, 2.0, 3.0]), law.pdf([1.5, 2.0, 3.0]), rtol=0.05)
    assert pce.mean == pytest.approx(law.mean(), rel=1e-6)
    assert pce.variance == pytest.approx(law.var(), rel=1e-4)


def test_transformed_bounded_and_weibull_inputs_give_their_moments():
    laws = [stats.truncnorm(-1.0, 2.0, loc=1.0), stats.weibull_min(1.5, scale=2.0)]
    pce = fit_pce(lambda x: x[0] + 2 * x[1], laws, "quadrature", order=12)
    assert pce.mean == pytest.approx(laws[0].mean() + 2 * laws[1].mean(), rel=1e-6)
    assert pce.variance == pytest.approx(laws[0].var() + 4 * laws[1].var(), rel=1e-4)


def test_uniform_marginals_as_distributions_match_bounds():
    f = lambda x: np.sin(x[0]) + x[1] ** 2  # noqa: E731
    a = fit_pce(f, [(0.0, 2.0), (-1.0, 1.0)], "quadrature", order=5)
    b = fit_pce(f, [stats.uniform(0, 2), chaospy.Uniform(-1, 1)], "quadrature", order=5)
    np.testing.assert_allclose(b.coefficients, a.coefficients, rtol=1e-13, atol=1e-15)
    assert isinstance(
        fit_pce(f, chaospy.J(chaospy.Uniform(0, 2), chaospy.Uniform(-1, 1)), "quadrature").inputs,
        UniformInputs,
    )


# --------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------
def test_discrete_inputs_are_refused_by_name():
    with pytest.raises(TypeError, match="input 'n'.*discrete.*poisson"):
        Inputs([stats.norm(), stats.poisson(3.0)], names=["x", "n"])
    with pytest.raises(TypeError, match="`inputs`.*discrete.*DiscreteUniform"):
        fit_pce(np.sum, chaospy.J(chaospy.Normal(), chaospy.DiscreteUniform(0, 4)), "lstsq")


@pytest.mark.parametrize(
    "R,match",
    [
        ([[1.0, 0.9, 0.9], [0.9, 1.0, -0.9], [0.9, -0.9, 1.0]], "not positive definite"),
        ([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "not positive definite"),
        ([[1.0, 0.2, 0.0], [0.3, 1.0, 0.0], [0.0, 0.0, 1.0]], "symmetric"),
        ([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "unit diagonal"),
        (np.eye(2), r"shape \(3, 3\)"),
    ],
)
def test_bad_correlation_matrices_are_refused(R, match):
    with pytest.raises(ValueError, match=f"`correlation`.*{match}|{match}"):
        Inputs([stats.norm()] * 3, correlation=R)


def test_other_bad_inputs():
    with pytest.raises(TypeError, match="dependent chaospy.*from_chaospy"):
        Inputs(chaospy.MvNormal([0, 1], [[1, 0.5], [0.5, 1]]))
    with pytest.raises(TypeError, match="input 'x0'.*scipy.stats frozen"):
        Inputs(["normal"])
    with pytest.raises(ValueError, match="germs.*germ=inputs.germs"):
        PolynomialChaosExpansion(ChaosBasis(1), [0.0, 1.0], inputs=[stats.norm()])
    with pytest.raises(ValueError, match="clenshaw-curtis.*rule='gauss'"):
        fit_pce(np.sum, [stats.norm()], "smolyak", rule="clenshaw-curtis")
    with pytest.raises(ValueError, match="outside the support"):
        fit_pce(np.sum, [stats.lognorm(0.2)], "quadrature", order=2)(np.array([[-1.0]]))


# --------------------------------------------------------------------------------------
# must-show: normal and lognormal inputs against OpenTURNS LARS on the same design
# --------------------------------------------------------------------------------------
SC_B, SC_H = 5.0, 15.0
SC_SY = math.sqrt(math.log(1 + 0.1**2))
SC_MY = math.log(5.0) - SC_SY**2 / 2
SHORT_COLUMN = [
    stats.norm(2000.0, 400.0),
    stats.norm(500.0, 100.0),
    stats.lognorm(SC_SY, scale=math.exp(SC_MY)),
]


def short_column(X):
    """Short column limit state (Kuschel & Rackwitz 1997): moment M, load P, yield stress Y."""
    M, P, Y = X.T
    return 1 - 4 * M / (SC_B * SC_H**2 * Y) - P**2 / (SC_B**2 * SC_H**2 * Y**2)


def short_column_reference():
    # g = 1 - 4/(b h^2) M U - 1/(b^2 h^2) P^2 U^2 with U = 1/Y lognormal: E[U^k] closed form
    def moment(v, k):
        if k == 0:
            return 1.0
        if v == 2:
            return math.exp(-k * SC_MY + k * k * SC_SY**2 / 2)
        return float(SHORT_COLUMN[v].moment(k))

    terms = [(-4 / (SC_B * SC_H**2), {0: 1, 2: 1}), (-1 / (SC_B * SC_H) ** 2, {1: 2, 2: 2})]
    return closed_form(1.0, terms, moment, 3)


def test_short_column_reference_against_monte_carlo():
    mean, var, _, _ = short_column_reference()
    rng = np.random.default_rng(0)
    X = np.column_stack([law.rvs(400_000, random_state=rng) for law in SHORT_COLUMN])
    y = short_column(X)
    n = len(y)
    assert abs(y.mean() - mean) < 4 * y.std() / math.sqrt(n)
    m4 = np.mean((y - y.mean()) ** 4)
    assert abs(y.var() - var) < 4 * math.sqrt((m4 - y.var() ** 2) / n)


def test_normal_and_lognormal_inputs_sobol_error_no_worse_than_openturns_lars():
    ot = pytest.importorskip("openturns")
    from scipy.stats import qmc

    _, _, S0, T0 = short_column_reference()
    u = qmc.LatinHypercube(3, rng=np.random.default_rng(0)).random(500)
    X = np.column_stack([law.ppf(u[:, k]) for k, law in enumerate(SHORT_COLUMN)])
    Y = short_column(X)

    pce = fit_pce(None, SHORT_COLUMN, "lars", samples=X, evaluations=Y)
    ours = max(np.abs(pce.first_order() - S0).max(), np.abs(pce.total() - T0).max())

    # OpenTURNS as its users set it up: each marginal's own orthonormal family, LARS with
    # the corrected leave-one-out error, total degree 10
    dist = ot.JointDistribution(
        [ot.Normal(2000.0, 400.0), ot.Normal(500.0, 100.0), ot.LogNormal(SC_MY, SC_SY)]
    )
    factory = ot.OrthogonalProductPolynomialFactory(
        [ot.StandardDistributionPolynomialFactory(dist.getMarginal(i)) for i in range(3)]
    )
    size = factory.getEnumerateFunction().getBasisSizeFromTotalDegree(10)
    selection = ot.LeastSquaresMetaModelSelectionFactory(ot.LARS(), ot.CorrectedLeaveOneOut())
    algo = ot.FunctionalChaosAlgorithm(
        ot.Sample(X),
        ot.Sample(Y[:, None]),
        dist,
        ot.FixedStrategy(factory, size),
        ot.LeastSquaresStrategy(selection),
    )
    algo.run()
    sens = ot.FunctionalChaosSobolIndices(algo.getResult())
    S = np.array([sens.getSobolIndex(i) for i in range(3)])
    T = np.array([sens.getSobolTotalIndex(i) for i in range(3)])
    theirs = max(np.abs(S - S0).max(), np.abs(T - T0).max())
    assert ours <= theirs
    assert ours < 1e-4


def test_inputs_docs_page_example_runs_and_matches_closed_forms():
    import pathlib
    import re

    text = (pathlib.Path(__file__).parents[2] / "docs" / "inputs.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code, "inputs.md", "exec"), ns)
    mean, var, S, _ = short_column_reference()
    assert abs(ns["pce"].mean - mean) < 1e-5 * abs(mean)
    assert abs(ns["pce"].variance - var) < 1e-4 * var
    np.testing.assert_allclose(ns["pce"].first_order(), S, atol=1e-4)
    assert ns["pce2"].mean == pytest.approx(2.2, rel=1e-14)
    assert ns["pce3"].mean == pytest.approx(-0.7, rel=1e-12)


def test_sobol_indices_of_an_output_without_finite_variance_are_refused_naming_the_input():
    laws = [stats.norm(), stats.t(2.0)]  # Student t with 2 degrees of freedom: Var = inf
    pce = fit_pce(lambda x: x[0] + x[1], Inputs(laws, names=["a", "heavy"]), "quadrature", order=3)
    with pytest.raises(ValueError, match="input 'heavy'.*no finite variance"):
        pce.first_order()
    with pytest.raises(ValueError, match="input 'heavy'"):
        pce.total()
    # an output that does not depend on the heavy-tailed input keeps its indices
    pce2 = fit_pce(lambda x: x[0] ** 2, Inputs(laws), "quadrature", order=3)
    np.testing.assert_allclose(pce2.first_order(), [1.0, 0.0], atol=1e-12)


def test_variance_of_an_output_on_an_input_without_finite_variance_is_refused():
    """x0 + x1 with x1 ~ t(2) has no finite variance: the expansion's truncated variance
    (a finite number) is refused rather than reported (issue 39); an output that does not
    depend on the heavy-tailed input keeps its variance, Var[x0^2] = 2."""
    laws = [stats.norm(), stats.t(2.0)]
    pce = fit_pce(lambda x: x[0] + x[1], Inputs(laws, names=["a", "heavy"]), "quadrature", order=3)
    with pytest.raises(ValueError, match="input 'heavy'.*no finite variance"):
        _ = pce.variance
    with pytest.raises(ValueError, match="input 'heavy'"):
        _ = pce.std
    assert pce.mean == pytest.approx(0.0, abs=1e-12)
    pce2 = fit_pce(lambda x: x[0] ** 2, Inputs(laws), "quadrature", order=3)
    assert pce2.variance == pytest.approx(2.0, rel=1e-12)
