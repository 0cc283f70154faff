"""Inputs.from_samples: empirical marginals joined by a Gaussian copula of normal scores."""

import numpy as np
import pytest

from ecfm_uq.chaos import Inputs, fit_pce


def test_samples_of_a_correlated_normal_are_reproduced_to_monte_carlo_error():
    mu = np.array([1.0, -2.0, 0.5])
    sd = np.array([0.5, 2.0, 1.0])
    R = np.array([[1.0, 0.6, -0.3], [0.6, 1.0, 0.2], [-0.3, 0.2, 1.0]])
    C = R * np.outer(sd, sd)
    n_s, n_d = 4000, 100_000
    X = np.random.default_rng(0).multivariate_normal(mu, C, size=n_s)
    inputs = Inputs.from_samples(X, names=["a", "b", "c"])
    assert inputs.names == ("a", "b", "c") and inputs.dependent
    Y = inputs.sample(n_d, seed=1)
    # errors of the samples and of the draws: se^2 (1/n_s + 1/n_d)
    w = np.sqrt(1 / n_s + 1 / n_d)
    assert np.all(np.abs(Y.mean(axis=0) - mu) < 4 * sd * w)
    assert np.all(np.abs(Y.std(axis=0) - sd) < 4 * sd * w / np.sqrt(2) + 1e-3 * sd)
    r = np.corrcoef(Y, rowvar=False)
    assert np.all(np.abs(r - R) < 4 * (1 - R**2) * w + 1e-12)
    # the draws stay inside the samples' range (an empirical law)
    assert np.all(Y.min(axis=0) >= X.min(axis=0)) and np.all(Y.max(axis=0) <= X.max(axis=0))
    x = inputs.sample(5, seed=2)
    np.testing.assert_allclose(inputs.from_germ(inputs.to_germ(x)), x, rtol=1e-10)


def test_one_input_from_samples_runs_in_a_pce():
    X = np.random.default_rng(3).gamma(3.0, size=3000)
    inputs = Inputs.from_samples(X)
    pce = fit_pce(lambda x: x[0] ** 2, inputs, method="quadrature", order=3)
    # E[x^2] of the law: the mean of squares between order statistics, near the samples'
    assert pce.mean == pytest.approx(np.mean(X**2), rel=0.02)


def test_bad_samples_are_refused():
    with pytest.raises(ValueError, match="samples"):
        Inputs.from_samples(np.ones((5, 2)))
    with pytest.raises(ValueError, match="constant"):
        Inputs.from_samples(np.column_stack([np.arange(20.0), np.ones(20)]))
    with pytest.raises(ValueError, match="samples"):
        Inputs.from_samples([[np.nan, 1.0]] * 20)
