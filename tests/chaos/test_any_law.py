"""Any continuous law as a chaos input: truncated, new-style and custom scipy laws.

Truth is independent of our code: scipy's own moments of each law, closed forms for
models linear in the inputs, and a law's variance computed once (its indices then cost
no integration).
"""

import time

import numpy as np
import pytest
from _laws import TRUNC_GUMBEL
from scipy import stats

from ecfm_uq.chaos import ChaosBasis, Inputs, fit_pce
from ecfm_uq.chaos.ownlaw import OwnGerm
from ecfm_uq.chaos.regression import hyperbolic_indices


def _raw_moments(law):
    if hasattr(law, "dist"):
        return law.moment(2), law.moment(4)
    return law.moment(2, kind="raw"), law.moment(4, kind="raw")


@pytest.mark.parametrize(
    "law",
    [
        stats.truncnorm(-4.0, np.inf, loc=30.0, scale=7.5),
        stats.truncate(stats.Normal(mu=30.0, sigma=7.5), lb=0.0),
        stats.truncnorm(-1.0, 2.0, loc=1.0, scale=0.5),
        stats.triang(0.3, loc=1.0, scale=2.0),
    ],
    ids=["truncnorm-below", "new-style-truncate", "truncnorm-both", "triangular"],
)
def test_square_of_a_truncated_input_has_exact_moments_from_an_order_2_fit(law):
    # y = x^2 is a degree-2 polynomial in the input: the law's own polynomials hold it
    pce = fit_pce(lambda x: x[0] ** 2, [law], "lstsq", order=2, n_samples=30, seed=0)
    m2, m4 = _raw_moments(law)
    assert float(pce.mean) == pytest.approx(m2, rel=1e-8)
    assert float(pce.variance) == pytest.approx(m4 - m2**2, rel=1e-8)


def test_truncnorm_with_an_infinite_bound_is_accepted_and_sampled_right():
    law = stats.truncnorm(-4.0, np.inf, loc=30.0, scale=7.5)
    inputs = Inputs([law])
    x = inputs.sample(20_000, seed=1)[:, 0]
    assert x.min() >= 0.0
    assert abs(x.mean() - law.mean()) < 4 * law.std() / np.sqrt(len(x))


def test_new_style_normal_keeps_the_hermite_germ():
    a = Inputs([stats.Normal(mu=1.0, sigma=2.0)])
    assert a.germs[0].family == "hermite" and a.affine
    np.testing.assert_allclose(a.from_germ([[1.0]]), [[3.0]])


def test_model_linear_in_a_lognormal_input_gets_exact_indices_with_own_polynomials():
    L, U = stats.lognorm(0.5, scale=2.0), stats.uniform(0.0, 1.0)
    inputs = Inputs([L, U], germ=["own", None])
    pce = fit_pce(lambda x: 3.0 * x[0] + 2.0 * x[1], inputs, "lstsq", order=2, n_samples=40, seed=0)
    v = np.array([9.0 * L.var(), 4.0 * U.var()])
    np.testing.assert_allclose(pce.first_order(), v / v.sum(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pce.total(), v / v.sum(), rtol=0, atol=1e-12)
    assert float(pce.mean) == pytest.approx(3.0 * L.mean() + 1.0, rel=1e-12)


def test_own_polynomials_are_orthonormal_and_their_gauss_rule_is_exact():
    for law in (stats.triang(0.3), TRUNC_GUMBEL(), stats.lognorm(0.25)):
        germ = OwnGerm(law, label="law")
        t, w = germ.gauss(12)
        V = germ.table(t, 6)
        np.testing.assert_allclose(V.T @ (w[:, None] * V), np.eye(7), atol=1e-10)
        # the Gauss nodes reproduce the law's moments (standardised: mean 0, variance 1)
        x = germ.mean + germ.std * t
        np.testing.assert_allclose(w @ x, law.mean(), rtol=1e-10)
        np.testing.assert_allclose(w @ x**3, law.moment(3), rtol=1e-9)


def test_quadrature_fit_on_own_gauss_rules_is_exact_for_a_cubic():
    laws = [stats.triang(0.3), stats.truncnorm(-1.0, np.inf)]
    f = lambda x: x[0] ** 3 + x[0] * x[1]  # noqa: E731
    pce = fit_pce(f, laws, "quadrature", order=3)
    m = [law.mean() for law in laws]
    assert float(pce.mean) == pytest.approx(laws[0].moment(3) + m[0] * m[1], rel=1e-10)


def test_indices_with_a_custom_law_cost_no_integration_after_the_fit():
    laws = [TRUNC_GUMBEL(), stats.weibull_min(1.5), stats.uniform()]
    pce = fit_pce(lambda x: x[0] + x[1] * x[2], laws, "lstsq", order=2, n_samples=40, seed=0)
    pce.first_order()
    t0 = time.perf_counter()
    for _ in range(5):
        pce.first_order(), pce.total()
    # scipy's numerical variance of a custom law takes ~0.3 s; five calls take far less
    assert time.perf_counter() - t0 < 0.5


REFUSED = [
    (stats.binom(3, 0.5), "input 'x0' is the discrete distribution binom"),
    (type("OnlyCdf", (), {"cdf": lambda self, x: x})(), "input 'x0'.*no ppf"),
    (stats.norm(0.0, -1.0), "input 'x0'.*parameters scipy rejects"),
]
if hasattr(stats, "Binomial"):  # scipy >= 1.16's new-style discrete laws (the floor is 1.15)
    REFUSED.append((stats.Binomial(n=3, p=0.5), "input 'x0' is the discrete distribution Binomial"))


@pytest.mark.parametrize("bad,match", REFUSED)
def test_refusals_name_the_input_and_what_is_missing(bad, match):
    with pytest.raises((TypeError, ValueError), match=match):
        Inputs([bad])


def test_hyperbolic_sets_are_the_total_degree_set_at_q_1_and_nested_in_q():
    for dim, p in ((3, 4), (5, 3)):
        full = hyperbolic_indices(dim, p, 1.0)
        ref = ChaosBasis(p, dim).indices[1:]
        np.testing.assert_array_equal(full, ref)
        half = hyperbolic_indices(dim, p, 0.5)
        assert {tuple(a) for a in half} <= {tuple(a) for a in full}
        q = np.sum(half.astype(float) ** 0.5, axis=1) ** 2
        assert np.all(q <= p + 1e-9)


def test_a_poor_fit_warns_and_points_at_the_sampling_estimator():
    # a discontinuous model from 40 runs: no expansion explains it
    def step(x):
        return float(x[0] > 0.3) + float(x[1] > 0.6)

    with pytest.warns(RuntimeWarning, match="sobol_indices"):
        pce = fit_pce(step, [(0, 1), (0, 1)], "lars", n_samples=40, seed=0)
    assert pce.diagnostics["poor_fit"]
    good = fit_pce(lambda x: x[0] + x[1] ** 2, [(0, 1), (0, 1)], "lars", n_samples=40, seed=0)
    assert not good.diagnostics["poor_fit"]


def test_adaptive_fit_reports_its_choice_and_keeps_only_the_selected_terms():
    laws = [stats.triang(0.3), stats.uniform(-1, 2), stats.uniform(0, 1)]
    pce = fit_pce(lambda x: np.exp(x[0]) * x[1] + x[2] ** 3, laws, n_samples=200, seed=1)
    d = pce.diagnostics
    assert d["selection"] == "adaptive" and pce.basis.index_set == "custom"
    assert pce.basis.size == d["n_terms"]
    assert d["q_norm"] in (0.5, 0.75, 1.0) and d["adaptive_trace"]
    p, q, P, err = min(d["adaptive_trace"], key=lambda t: t[3])
    assert err == pytest.approx(float(d["corrected_loo_error"]))


def test_inputs_page_own_law_example_runs_and_is_exact():
    import pathlib
    import re

    text = (pathlib.Path(__file__).parents[2] / "docs" / "inputs.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[1]
    ns = {}
    exec(compile(code, "inputs.md", "exec"), ns)
    L, U = ns["L"], ns["U"]
    v = np.array([9 * L.var(), 4 * U.var()])
    np.testing.assert_allclose(ns["pce"].first_order(), v / v.sum(), rtol=0, atol=1e-12)
    assert float(ns["pce2"].mean) == pytest.approx(ns["below"].moment(2), rel=1e-12)


def test_an_expansion_rebuilt_with_the_same_laws_keeps_its_own_germs():
    from ecfm_uq.chaos import PolynomialChaosExpansion

    laws = [stats.triang(0.3), stats.uniform()]
    pce = fit_pce(lambda x: x[0] ** 2 + x[1], laws, "lstsq", order=2, n_samples=20, seed=0)
    again = PolynomialChaosExpansion(pce.basis, pce.coefficients, inputs=laws)
    np.testing.assert_allclose(again.total(), pce.total(), rtol=1e-14)


def test_make_distribution_law_is_accepted_and_exact_on_its_own_polynomials():
    law = stats.make_distribution(stats.lognorm)(s=0.25)
    inputs = Inputs([law], germ="own")
    pce = fit_pce(lambda x: x[0] ** 2, inputs, "lstsq", order=2, n_samples=30, seed=0)
    m2, m4 = law.moment(2, kind="raw"), law.moment(4, kind="raw")
    assert float(pce.mean) == pytest.approx(m2, rel=1e-8)
    assert float(pce.variance) == pytest.approx(m4 - m2**2, rel=1e-8)


def test_a_custom_unbounded_law_has_its_variance_checked_once_during_the_fit():
    class _Logistic(stats.rv_continuous):  # no closed-form moments given: scipy integrates
        def _cdf(self, x):
            return 1.0 / (1.0 + np.exp(-x))

        def _ppf(self, u):
            return np.log(u / (1.0 - u))

    inputs = Inputs([_Logistic(name="mylogistic")(), stats.uniform()])
    m = inputs.marginals[0]
    assert "finite_variance" not in m.__dict__
    pce = fit_pce(lambda x: x[0] + x[1], inputs, "lstsq", order=1, n_samples=20, seed=0)
    assert "finite_variance" in m.__dict__  # cached: the indices integrate nothing
    assert np.all(np.isfinite(pce.total()))
