"""Bands of a fit (``InverseResult.predict``) and its uncertainty as inputs (issue 38).

Truths: statsmodels' OLS prediction frame, a delta-method band written out in numpy for
Michaelis-Menten (Puromycin, R's ``nls`` estimates), Monte Carlo of the normal pushed
through g, the closed-form Sobol indices of a linear function of correlated normals.
"""

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.chaos import Inputs, StudentInputs, fit_pce
from ecfm_uq.inverse import Band, ModelProblem, fit
from ecfm_uq.mc import monte_carlo, sobol_indices

# R datasets::Puromycin, state "treated"
CONC = np.array([0.02, 0.02, 0.06, 0.06, 0.11, 0.11, 0.22, 0.22, 0.56, 0.56, 1.10, 1.10])
RATE = np.array([76, 47, 97, 107, 123, 139, 159, 152, 191, 201, 207, 200], dtype=float)


def mm(e, x=CONC):
    return e[0] * x / (e[1] + x)


def mm_jac(e, x=CONC):
    return np.column_stack([x / (e[1] + x), -e[0] * x / (e[1] + x) ** 2])


@pytest.fixture(scope="module")
def linear():
    rng = np.random.default_rng(3)
    x = np.linspace(0.0, 2.0, 25)
    X = np.column_stack([np.ones_like(x), x, x**2])
    y = X @ [0.5, 1.5, -0.4] + 0.2 * rng.standard_normal(x.size)
    res = fit(ModelProblem(lambda e: X @ e, y, jac=lambda e: X, names=["a", "b", "c"]), np.zeros(3))
    return X, y, res


@pytest.fixture(scope="module")
def puromycin():
    return fit(ModelProblem(mm, RATE, jac=mm_jac, names=["Vm", "K"]), [200.0, 0.1])


def test_bands_equal_statsmodels_ols(linear):
    sm = pytest.importorskip("statsmodels.api")
    X, y, res = linear
    frame = sm.OLS(y, X).fit().get_prediction(X).summary_frame(alpha=0.05)
    conf, pred = res.predict(), res.predict(kind="prediction")
    assert isinstance(conf, Band) and conf.kind == "confidence" and conf.method == "delta"
    assert conf.dof == y.size - 3 and conf.level == 0.95
    np.testing.assert_allclose(conf.value, frame["mean"], rtol=1e-8)
    np.testing.assert_allclose(conf.std, frame["mean_se"], rtol=1e-8)
    np.testing.assert_allclose(conf.lower, frame["mean_ci_lower"], rtol=1e-8)
    np.testing.assert_allclose(conf.upper, frame["mean_ci_upper"], rtol=1e-8)
    np.testing.assert_allclose(pred.lower, frame["obs_ci_lower"], rtol=1e-8)
    np.testing.assert_allclose(pred.upper, frame["obs_ci_upper"], rtol=1e-8)


def test_sigma_is_the_residual_estimate_or_the_noise_as_given(linear):
    X, y, res = linear
    n, p = X.shape
    r = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    assert res.uncertainty.dof == n - p
    assert res.uncertainty.sigma == pytest.approx(np.sqrt(r @ r / (n - p)), rel=1e-10)
    np.testing.assert_array_equal(res.uncertainty.eps, res.eps)
    problem = ModelProblem(lambda e: X @ e, y, jac=lambda e: X)
    assert fit(problem, np.zeros(3), sigma=0.3).uncertainty.sigma == 0.3
    per = np.linspace(0.1, 0.3, n)
    np.testing.assert_array_equal(fit(problem, np.zeros(3), sigma=per).uncertainty.sigma, per)
    cov = np.diag(per**2) + 0.005 * np.ones((n, n))
    np.testing.assert_allclose(
        fit(problem, np.zeros(3), sigma=cov).uncertainty.sigma, np.sqrt(np.diag(cov)), rtol=1e-12
    )


def test_known_sigma_per_observation_gives_normal_bands_with_each_noise(linear):
    X, y, _ = linear
    per = np.linspace(0.1, 0.3, y.size)
    res = fit(ModelProblem(lambda e: X @ e, y, jac=lambda e: X), np.zeros(3), sigma=per)
    W = X / per[:, None]
    cov = np.linalg.inv(W.T @ W)
    se = np.sqrt(np.einsum("ij,jk,ik->i", X, cov, X))
    z = stats.norm.ppf(0.95)
    band = res.predict(level=0.9, kind="prediction")
    assert band.dof is None and band.quantile == pytest.approx(z, rel=1e-12)
    np.testing.assert_allclose(band.std, np.sqrt(se**2 + per**2), rtol=1e-8)
    np.testing.assert_allclose(band.upper, X @ res.eps + z * np.sqrt(se**2 + per**2), rtol=1e-8)
    with pytest.raises(ValueError, match="noise_std"):
        res.predict(lambda e: e[:2], kind="prediction")
    b = res.predict(lambda e: e[:2], kind="prediction", noise_std=0.5)
    np.testing.assert_allclose(b.std, np.sqrt(np.diag(cov)[:2] + 0.25), rtol=1e-6)


def test_puromycin_band_equals_a_numpy_delta_method_t_band(puromycin):
    res = puromycin
    # R: nls(rate ~ Vm * conc / (K + conc), Puromycin, subset = state == "treated")
    np.testing.assert_allclose(res.eps, [212.6837, 0.06412], rtol=2e-5)
    n, p = RATE.size, 2
    e = res.eps
    J = mm_jac(e)
    r = mm(e) - RATE
    s2 = r @ r / (n - p)
    cov = s2 * np.linalg.inv(J.T @ J)
    se = np.sqrt(np.einsum("ij,jk,ik->i", J, cov, J))
    t = stats.t.ppf(0.975, n - p)
    band = res.predict()
    np.testing.assert_allclose(band.lower, mm(e) - t * se, rtol=1e-8)
    np.testing.assert_allclose(band.upper, mm(e) + t * se, rtol=1e-8)
    pred = res.predict(kind="prediction", level=0.9)
    t90 = stats.t.ppf(0.95, n - p)
    np.testing.assert_allclose(pred.upper, mm(e) + t90 * np.sqrt(se**2 + s2), rtol=1e-8)
    # a user quantity on a grid: central differences of g, or its exact Jacobian
    grid = np.linspace(0.0, 1.2, 7)
    Jg = mm_jac(e, grid)
    se_g = np.sqrt(np.einsum("ij,jk,ik->i", Jg, cov, Jg))
    fd = res.predict(lambda e: mm(e, grid))
    np.testing.assert_allclose(fd.std, se_g, rtol=1e-6, atol=1e-12)
    exact = res.predict(lambda e: mm(e, grid), g_jac=lambda e: mm_jac(e, grid))
    np.testing.assert_allclose(exact.upper, mm(e, grid) + t * se_g, rtol=1e-8)


def test_pce_band_against_monte_carlo_of_the_normal(puromycin):
    res = puromycin
    x0 = np.array([0.01, 0.03])  # low concentrations: g curved in K

    def g(e):
        return mm(e, x0)

    band = res.predict(g, method="pce", order=4)
    assert band.method == "pce"
    rng = np.random.default_rng(7)
    n = 40_000
    Y = np.array([g(e) for e in rng.multivariate_normal(res.eps, res.uncertainty.cov, n)])
    m, s = Y.mean(axis=0), Y.std(axis=0, ddof=1)
    m4 = np.mean((Y - m) ** 4, axis=0)
    se_mean = s / np.sqrt(n)
    se_std = np.sqrt((m4 - s**4) / n) / (2 * s)
    assert np.all(np.abs(band.value - m) < 3 * se_mean)
    assert np.all(np.abs(band.std - s) < 3 * se_std)
    q = stats.t.ppf(0.975, RATE.size - 2)
    np.testing.assert_allclose(band.upper, band.value + q * band.std, rtol=1e-12)
    delta = res.predict(g)
    assert np.all(np.abs(band.value - delta.value) > 3 * se_mean)  # the curvature it keeps


def test_pce_band_of_a_linear_quantity_is_the_delta_band(linear):
    _, _, res = linear
    np.testing.assert_allclose(res.predict(method="pce").lower, res.predict().lower, rtol=1e-10)


def test_to_inputs_is_the_normal_of_the_fit_and_runs_in_pce_mc_and_sobol(puromycin):
    res = puromycin
    unc = res.uncertainty
    inputs = unc.to_inputs()
    assert isinstance(inputs, Inputs) and inputs.names == ("Vm", "K") and inputs.dependent
    se = np.sqrt(np.diag(unc.cov))
    assert [m.loc for m in inputs.marginals] == pytest.approx(res.eps, rel=1e-14)
    assert [m.scale for m in inputs.marginals] == pytest.approx(se, rel=1e-14)
    xi = np.random.default_rng(0).standard_normal((5, 2))
    L = np.linalg.cholesky(unc.cov)
    np.testing.assert_allclose(inputs.from_germ(xi), res.eps + xi @ L.T, rtol=1e-12)
    pce = fit_pce(lambda e: e[0] + e[1], inputs, method="quadrature", order=2)
    assert pce.mean == pytest.approx(res.eps.sum(), rel=1e-12)
    assert pce.variance == pytest.approx(unc.cov.sum(), rel=1e-10)
    out = monte_carlo(lambda e: e, inputs.sample(2000, seed=1), workers=1)
    assert out.shape == (2000, 2)
    # germ indices of a . x, x = eps + L xi: (a . L)_k^2 / sum
    a = np.array([1.0, 2000.0])
    w = (a @ L) ** 2
    with pytest.raises(ValueError, match="germ=True"):
        sobol_indices(lambda X: X @ a, inputs, 1024, seed=0, vectorized=True)
    sob = sobol_indices(lambda X: X @ a, inputs, 4096, seed=0, vectorized=True, germ=True)
    lo, hi = sob.first_order_interval
    assert np.all((lo <= w / w.sum()) & (w / w.sum() <= hi))


def test_to_inputs_t_is_the_multivariate_t_and_is_refused_with_sigma_known(puromycin):
    unc = puromycin.uncertainty
    t_in = unc.to_inputs("t")
    assert isinstance(t_in, StudentInputs) and t_in.dof == 10 and t_in.dim == 3
    n = 200_000
    x = t_in.sample(n, seed=3)
    nu = 10
    # each standardized coordinate is t_10: its quantiles, to Monte Carlo error
    z = (x - puromycin.eps) / np.sqrt(np.diag(unc.cov))
    for k in range(2):
        for q in (0.05, 0.5, 0.95):
            tq = stats.t.ppf(q, nu)
            se = np.sqrt(q * (1 - q) / n) / stats.t.pdf(tq, nu)
            assert abs(np.quantile(z[:, k], q) - tq) < 4 * se
    r_hat = np.corrcoef(x, rowvar=False)[0, 1]
    r = unc.cov[0, 1] / np.sqrt(unc.cov[0, 0] * unc.cov[1, 1])
    assert abs(r_hat - r) < 0.01
    # a PCE on its p + 1 germs: the mean exact, the variance nu/(nu - 2) S_00 approached
    # as the degree grows (x is not polynomial in the scale germ)
    errs = []
    for order in (2, 4, 6):
        pce = fit_pce(lambda e: e[0], t_in, method="quadrature", order=order)
        assert pce.mean == pytest.approx(puromycin.eps[0], rel=1e-12)
        errs.append(abs(pce.variance / (nu / (nu - 2) * unc.cov[0, 0]) - 1))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 5e-3
    known = fit(ModelProblem(mm, RATE, jac=mm_jac), [200.0, 0.1], sigma=10.0)
    with pytest.raises(ValueError, match="kind='normal'"):
        known.uncertainty.to_inputs("t")
    with pytest.raises(ValueError, match="to_germ"):
        t_in.to_germ(x[:2])


def test_bad_input_is_refused_naming_the_argument(puromycin):
    res = puromycin
    with pytest.raises(ValueError, match="`level`"):
        res.predict(level=1.0)
    with pytest.raises(ValueError, match="`level`"):
        res.predict(level=0)
    with pytest.raises(ValueError, match="`kind`"):
        res.predict(kind="credible")
    with pytest.raises(ValueError, match="`method`"):
        res.predict(method="bootstrap")
    with pytest.raises(TypeError, match="`g`"):
        res.predict(g=3.0)
    with pytest.raises(ValueError, match="`g` returned a non-finite"):
        res.predict(lambda e: np.array([np.nan, 1.0]))
    with pytest.raises(ValueError, match="`g` returned shape"):
        res.predict(lambda e: np.ones(2 if e[1] == res.eps[1] else 3))
    with pytest.raises(ValueError, match="`kind`"):
        res.uncertainty.to_inputs("cauchy")
    bare = fit(ModelProblem(mm, RATE, jac=mm_jac), [200.0, 0.1], uncertainty=False)
    with pytest.raises(ValueError, match="to_inputs.*uncertainty=True"):
        bare.uncertainty.to_inputs()
    with pytest.raises(ValueError, match="covariance"):
        bare.predict()


def test_a_galerkin_fit_needs_g_and_predicts_a_user_quantity():
    from ecfm_uq.inverse import SteadyProblem
    from ecfm_uq.problems.reaction import ReactionRod

    rod = ReactionRod(4)
    v = rod.data([1.5, 20.0])
    v = v + 0.01 * np.random.default_rng(0).standard_normal(v.size)
    res = fit(SteadyProblem(rod.system, rod.M_obs, v), [1.0, 10.0], sigma=0.01)
    with pytest.raises(ValueError, match="pass `g`"):
        res.predict()
    band = res.predict(lambda e: e[0] * e[1], kind="prediction", noise_std=0.0)
    grad = np.array([res.eps[1], res.eps[0]])
    se = np.sqrt(grad @ res.uncertainty.cov @ grad)
    assert float(band.std) == pytest.approx(se, rel=1e-6)
    assert band.quantile == pytest.approx(stats.norm.ppf(0.975), rel=1e-12)


def test_band_plot_returns_axes(linear):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    X, y, res = linear
    ax = res.predict(kind="prediction").plot(X[:, 1], data=y)
    assert ax.__class__.__name__ == "Axes"
    assert len(ax.collections) == 1 and len(ax.lines) == 2  # the band; value and data
    np.testing.assert_allclose(ax.lines[1].get_ydata(), y)
    plt.close(ax.figure)


def test_prediction_page_examples_run():
    import re
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    text = (Path(__file__).resolve().parents[2] / "docs" / "prediction.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 2
    ns = {}
    for code in blocks:
        exec(compile(code, "prediction.md", "exec"), ns)
    plt.close("all")
    res, pred, conf = ns["res"], ns["pred"], ns["conf"]
    np.testing.assert_allclose(res.eps, [212.68, 0.06412], rtol=5e-4)
    assert np.all(pred.upper - pred.lower > conf.upper - conf.lower)
    assert ns["t_inputs"].dof == 10 and ns["inputs"].names == ("Vm", "K")
    assert ns["draws"].shape == (1000, 1)
