"""The random-force ECFM's profile intervals with the threshold calibrated by simulation
(issue 37 item 4): data simulated from the random-force model at the profiled point, each
refitted by the random-force likelihood with and without the profiled value."""

import numpy as np
import pytest
from _models import ridge_data, ridge_rod

from ecfm_uq.inverse import SteadyProblem, fit, likelihood_ratio_test, profile_likelihood
from ecfm_uq.inverse.formulations.random_force_simulation import (
    simulated_data,
    simulation_variances,
)
from ecfm_uq.inverse.formulations.random_forces import RandomForceModel
from ecfm_uq.inverse.statistics.profile import _scales
from ecfm_uq.inverse.statistics.profile_calibration import simulated_threshold_by_model
from ecfm_uq.system import solve_steady

TRUTH = np.array([-50.0, 10.0])
BOUNDS = [(-50.0, 2000.0), (0.01, 1e5)]


def _ridge(n):
    """Issue 37's ridge (``_models.ridge_rod``), data set n of default_rng(1)."""
    system, M = ridge_rod()
    return (system, M, *ridge_data(system, M, TRUTH, n))


def test_simulated_data_have_the_random_force_models_distribution():
    """Where the test of tau = 0 rejects (data set 54: tau-hat = 2277, p = 0.005), the
    simulated data are N(M E[theta], sigma^2 I + tau^2 A A^T): 4000 draws whitened by that
    covariance have mean 0 and covariance I within their Monte Carlo error."""
    system, M, y, sigma = _ridge(54)
    model = RandomForceModel(SteadyProblem(system, M, y), sigma)
    eps = np.array([-30.0, 390.0])
    _, g, lin = model.profiled(eps)
    assert np.sqrt(g[0]) > 1000 and model.restricted_test(lin)[1] < 0.01
    np.testing.assert_array_equal(simulation_variances(model, eps), g)
    mean = M @ solve_steady(system, eps, strict=True).Theta[:, 0]
    S = sigma**2 * np.eye(y.size) + g[0] * lin.A @ lin.A.T
    L = np.linalg.cholesky(S)
    rng = np.random.default_rng(7)
    W = np.array([np.linalg.solve(L, simulated_data(model, eps, rng) - mean) for _ in range(4000)])
    assert np.all(np.abs(W.mean(0)) < 4.5 / np.sqrt(4000))
    assert np.max(np.abs(np.cov(W.T) - np.eye(y.size))) < 0.1  # entries' SE ~ 0.016-0.022


def test_a_discrepancy_the_data_do_not_show_is_simulated_as_none():
    """Data set 5: tau-hat = 165 but the test of tau = 0 does not reject (p = 0.22): the
    data are simulated with tau = 0, the prediction plus sigma z exactly."""
    system, M, y, sigma = _ridge(5)
    model = RandomForceModel(SteadyProblem(system, M, y), sigma)
    eps = np.array([-30.0, 390.0])
    _, g, lin = model.profiled(eps)
    assert np.sqrt(g[0]) > 100 and model.restricted_test(lin)[1] > 0.05
    np.testing.assert_array_equal(simulation_variances(model, eps), 0.0)
    mean = M @ solve_steady(system, eps, strict=True).Theta[:, 0]
    z = np.random.default_rng(3).standard_normal(y.size)  # z is drawn first
    np.testing.assert_allclose(simulated_data(model, eps, np.random.default_rng(3)),
                               mean + sigma * z, rtol=1e-12, atol=1e-12 * np.abs(mean).max())  # fmt: skip


def test_simulated_threshold_is_the_quantile_of_random_force_likelihood_ratios():
    """The simulated threshold at eps[1] = its estimate, 5 data sets at level 0.8 (the
    ceil(0.8 * 6) = 5th smallest: the largest), against fit(..., "ecfm-random") of the
    same simulated data and its likelihood-ratio test of eps[1] (a separate path: the
    fit's search from the standard estimate, the profiles' re-optimization)."""
    system, M, y, sigma = _ridge(0)
    res = fit(SteadyProblem(system, M, y), TRUTH, formulation="ecfm-random", sigma=sigma,
              bounds=BOUNDS)  # fmt: skip
    assert res.extra["tau"] == 0.0
    like = res.interval_likelihood
    eps_t = np.asarray(res.eps, dtype=float)
    _, _, scale = _scales(res, like, eps_t)
    seeds = [[3, 1, k] for k in range(5)]
    c = simulated_threshold_by_model(like, 1, eps_t, seeds, 0.8, scale, BOUNDS)
    model = RandomForceModel(SteadyProblem(system, M, y), sigma)
    stats = []
    for sd in seeds:
        v = simulated_data(model, eps_t, np.random.default_rng(sd))
        r = fit(SteadyProblem(system, M, v), eps_t, formulation="ecfm-random", sigma=sigma,
                bounds=BOUNDS)  # fmt: skip
        stats.append(0.5 * likelihood_ratio_test(r, eps_t, free=[0]).statistic)
    assert c > 0
    np.testing.assert_allclose(c, max(stats), rtol=1e-3, atol=1e-4)


@pytest.mark.slow  # ~5-14 s: the whole calibrated profile of s
def test_the_random_force_ecfm_has_a_calibrated_option():
    """threshold='calibrated' is accepted for the random-force ECFM (refused before): the
    interval of s on data set 0 uses simulated thresholds, listed in the message."""
    system, M, y, sigma = _ridge(0)
    res = fit(SteadyProblem(system, M, y), TRUTH, formulation="ecfm-random", sigma=sigma,
              bounds=BOUNDS)  # fmt: skip
    prof = profile_likelihood(res, which=[1], threshold="calibrated", n_simulations=20)
    assert prof.threshold_used == (None, "calibrated")
    cal = prof.profiles[1].calibration
    assert cal.n_simulations == 20 and len(cal.points) >= 2
    assert "eps[1]: calibrated thresholds" in prof.message
    assert np.all(np.isfinite(prof.intervals[1]))
