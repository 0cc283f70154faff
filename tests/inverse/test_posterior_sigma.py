"""Posterior samples of a fit whose sigma was estimated: sigma sampled too (Jeffreys prior).

Closed form for a linear model with a flat prior on eps and p(sigma) ~ 1/sigma: the
marginal posterior of eps is the multivariate t with n - p degrees of freedom, location
the least-squares estimate and scale s^2 (X^T X)^{-1}; sigma^2 ~ RSS / chi2_{n-p}.
"""

import numpy as np
import pytest
from scipy import stats

pytest.importorskip("emcee")

from ecfm_uq.inverse import ModelProblem, fit  # noqa: E402
from ecfm_uq.inverse.statistics.posterior import sample_posterior  # noqa: E402

N, P = 12, 2


@pytest.fixture(scope="module")
def runs():
    rng = np.random.default_rng(5)
    x = np.linspace(0.0, 1.0, N)
    X = np.column_stack([np.ones_like(x), x])
    y = X @ [1.0, -2.0] + 0.3 * rng.standard_normal(N)
    res = fit(ModelProblem(lambda e: X @ e, y, jac=lambda e: X), np.zeros(P))
    post = sample_posterior(res, bounds=[(-20, 20)] * 2, n_walkers=12, n_steps=2500, seed=2)
    return X, y, res, post


def _quantile_se(q, n_eff, density):
    return np.sqrt(q * (1 - q) / n_eff) / density


def test_eps_marginals_are_the_student_t_of_the_closed_form(runs):
    X, y, res, post = runs
    assert post.success and post.sigma_prior == "jeffreys"
    nu = N - P
    r = y - X @ res.eps
    s2 = r @ r / nu
    scale = s2 * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(res.uncertainty.cov, scale, rtol=1e-10)
    for k in range(P):
        z = (post.samples[:, k] - res.eps[k]) / np.sqrt(scale[k, k])
        for q in (0.05, 0.25, 0.5, 0.75, 0.95):
            tq = stats.t.ppf(q, nu)
            se = _quantile_se(q, post.ess[k], stats.t.pdf(tq, nu))
            assert abs(np.quantile(z, q) - tq) < 4 * se, (k, q)
    # the t's covariance nu/(nu - 2) scale, to the chain's Monte Carlo error
    np.testing.assert_allclose(post.cov, nu / (nu - 2) * scale, rtol=0.15)


def test_sigma_samples_follow_rss_over_chi2(runs):
    X, y, res, post = runs
    nu = N - P
    rss = float(np.sum((y - X @ res.eps) ** 2))
    assert post.sigma.shape == (post.samples.shape[0],) and np.all(post.sigma > 0)
    w = rss / post.sigma**2  # ~ chi2_{n-p} marginally
    n_eff = float(post.ess.min())
    for q in (0.05, 0.25, 0.5, 0.75, 0.95):
        cq = stats.chi2.ppf(q, nu)
        se = _quantile_se(q, n_eff, stats.chi2.pdf(cq, nu))
        assert abs(np.quantile(w, q) - cq) < 4 * se, q


def test_posterior_prediction_band_is_the_ols_prediction_interval(runs):
    X, y, res, post = runs
    band = res.predict(kind="prediction", method="posterior", posterior=post, n_draws=20000)
    delta = res.predict(kind="prediction")  # the exact Bayesian predictive here
    assert band.method == "posterior" and band.quantile is None
    q, nu = 0.975, N - P
    dens = stats.t.pdf(stats.t.ppf(q, nu), nu) / delta.std
    se = _quantile_se(q, float(post.ess.min()), dens)
    assert np.all(np.abs(band.upper - delta.upper) < 4 * se)
    assert np.all(np.abs(band.lower - delta.lower) < 4 * se)


def test_a_known_sigma_fit_samples_no_sigma(runs):
    X, y, res, _ = runs
    known = fit(ModelProblem(lambda e: X @ e, y, jac=lambda e: X), np.zeros(P), sigma=0.3)
    post = sample_posterior(known, bounds=[(-20, 20)] * 2, n_steps=200, seed=0)
    assert post.sigma is None and post.sigma_prior == ""
