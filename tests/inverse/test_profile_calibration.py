"""The simulation-calibrated likelihood-ratio threshold of profile intervals
(``profile_likelihood(..., threshold="calibrated")``, issue 37 item 4) and profiles that
walk into overflow without a RuntimeWarning."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from ecfm_uq.inverse import ModelProblem, fit, profile_likelihood
from ecfm_uq.inverse.coverage import binomial_band
from ecfm_uq.inverse.statistics.profile_calibration import check_calibratable

X = np.linspace(0.0, 1.0, 8)
SIGMA = 0.1


def line(e):
    return e[0] + e[1] * X


def _line_fit():
    y = line([1.0, 2.0]) + SIGMA * np.random.default_rng(4).standard_normal(X.size)
    return fit(ModelProblem(line, y, names=["a", "b"]), [0.0, 0.0], sigma=SIGMA)


def test_calibrated_threshold_of_a_linear_model_is_the_simulated_closed_form():
    """Linear and Gaussian: the simulated statistic at any t is (w.z)^2 / 2, w the unit
    vector of column i orthogonal to the others (whitened), with the same z at every t.
    The threshold is that sample's quantile, and the interval est -/+ se sqrt(2 c)."""
    res = _line_fit()
    n_sim, seed = 30, 7
    prof = profile_likelihood(res, threshold="calibrated", n_simulations=n_sim, seed=seed)
    A = np.column_stack([np.ones_like(X), X]) / SIGMA
    cov = np.linalg.inv(A.T @ A)
    for i in range(2):
        other = A[:, 1 - i]
        w = A[:, i] - other * (other @ A[:, i]) / (other @ other)
        w /= np.linalg.norm(w)
        Z = np.random.default_rng([seed, i]).standard_normal((n_sim, X.size))
        c = 0.5 * np.sort((Z @ w) ** 2)[int(np.ceil(0.95 * (n_sim + 1))) - 1]
        cal = prof.profiles[i].calibration
        assert prof.profiles[i].threshold_used == "calibrated"
        np.testing.assert_allclose(cal.thresholds, [c, c], rtol=1e-6)
        half = np.sqrt(2 * c * cov[i, i])
        np.testing.assert_allclose(prof.intervals[i], res.eps[i] + np.array([-half, half]),
                                   rtol=1e-6, atol=1e-6 * half)  # fmt: skip
        assert prof.trusted[i]
    assert "calibrated thresholds" in prof.message
    axes = prof.plot()
    (marks,) = [ln for ln in axes[0].lines if ln.get_label() == "calibrated threshold"]
    np.testing.assert_allclose(marks.get_ydata(), [2 * q[1] for q in prof.profiles[0]
                               .calibration.points])  # fmt: skip
    assert len(marks.get_ydata()) >= 2  # at least one threshold simulated per end
    assert prof.threshold_used == ("calibrated", "calibrated")
    assert profile_likelihood(res, which=[1]).threshold_used == (None, "chi2")


def test_calibrated_threshold_with_sigma_estimated_is_the_simulated_closed_form():
    """Sigma profiled out: the statistic is (n/2) log(1 + (w.z)^2 / |P z|^2), P the
    projection off the model's range (the noise scale cancels)."""
    y = line([1.0, 2.0]) + SIGMA * np.random.default_rng(4).standard_normal(X.size)
    res = fit(ModelProblem(line, y), [0.0, 0.0])
    n_sim, seed = 30, 3
    prof = profile_likelihood(res, which=[1], threshold="calibrated", n_simulations=n_sim,
                              seed=seed)  # fmt: skip
    A = np.column_stack([np.ones_like(X), X])
    Q = np.linalg.qr(A)[0]
    w = A[:, 1] - A[:, 0] * (A[:, 0] @ A[:, 1]) / (A[:, 0] @ A[:, 0])
    w /= np.linalg.norm(w)
    Z = np.random.default_rng([seed, 1]).standard_normal((n_sim, X.size))
    off = Z - (Z @ Q) @ Q.T
    stat = 0.5 * X.size * np.log1p((Z @ w) ** 2 / np.sum(off**2, axis=1))
    np.testing.assert_allclose(prof.profiles[1].calibration.thresholds,
                               [np.sort(stat)[int(np.ceil(0.95 * (n_sim + 1))) - 1]] * 2, rtol=1e-6)  # fmt: skip


def test_calibrated_threshold_refuses_bad_arguments():
    res = _line_fit()
    with pytest.raises(ValueError, match="threshold"):
        profile_likelihood(res, threshold="wilks")
    with pytest.raises(ValueError, match="n_simulations"):
        profile_likelihood(res, threshold="calibrated", n_simulations=5)
    with pytest.raises(ValueError, match="at least 99"):  # the 0.99 quantile of 50
        profile_likelihood(res, 0.99, threshold="calibrated", n_simulations=50)
    # a likelihood without a Gaussian residual (pseudo-likelihood, random forces)
    bare = replace(res.likelihood, residual=None)
    with pytest.raises(ValueError, match="threshold='chi2'"):
        check_calibratable(bare)


MODES = np.arange(1, 40, 2)
SHAPE = 4 / (MODES * np.pi) * np.sin(np.pi * np.outer(np.linspace(0.2, 0.8, 5), MODES))
RIDGE_TRUTH = np.array([-9.5, 10.0])
RIDGE_BOUNDS = [(-9.5, 500.0), (0.01, 1000.0)]


def ridge_rod(e):
    """-w'' + c w = s on (0, 1), read at five points; singular at c = -pi^2: near it the
    likelihood runs along a ridge (s / (pi^2 + c) nearly fixed) to the user's bound on c,
    where the truth sits."""
    c, s = e
    return s * (SHAPE / (MODES**2 * np.pi**2 + c)).sum(1)


def _ridge_fit(rng):
    y0 = ridge_rod(RIDGE_TRUTH)
    sigma = 0.02 * np.abs(y0).mean()
    y = y0 + sigma * rng.standard_normal(y0.size)
    return fit(ModelProblem(ridge_rod, y, names=["c", "s"]), RIDGE_TRUTH, sigma=sigma,
               bounds=RIDGE_BOUNDS)  # fmt: skip


def test_an_interval_shaped_by_a_bound_names_the_calibrated_option():
    prof = profile_likelihood(_ridge_fit(np.random.default_rng(3)), which=[1])
    assert not prof.trusted[1]
    assert any("eps[0] sits at its lower bound -9.5" in c for c in prof.profiles[1].concerns)
    assert "threshold='calibrated'" in prof.message


@pytest.mark.slow
def test_calibrated_intervals_cover_on_the_ridge_to_a_bound():
    """R data sets of the ridge model: the calibrated intervals of s cover the truth
    within the binomial band of R (R = 200 was run once: see docs/uncertainty.md)."""
    R = 30
    rng = np.random.default_rng(1)
    hits = []
    for r in range(R):
        res = _ridge_fit(rng)
        prof = profile_likelihood(res, which=[1], threshold="calibrated", n_simulations=100,
                                  seed=r)  # fmt: skip
        lo, hi = prof.intervals[1]
        hits.append(lo <= RIDGE_TRUTH[1] <= hi)
    lo, hi = binomial_band(R, 0.95)
    assert lo <= np.mean(hits) <= hi, np.mean(hits)


def test_a_profile_into_overflow_warns_nothing():
    """Past eps[0] = 2 the readings are ~1e160 and their squares overflow: failed points
    of the profile, not RuntimeWarnings (they were hundreds of lines in a study)."""
    x = np.linspace(0.1, 1.0, 6)

    def model(e):
        return e[1] * x + 1e160 * max(e[0] - 2.0, 0.0) * x

    y = 1.5 * x + 0.01 * np.random.default_rng(0).standard_normal(x.size)
    res = fit(ModelProblem(model, y), [0.0, 1.0], sigma=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        prof = profile_likelihood(res)
    np.testing.assert_allclose(prof.intervals[1], res.eps[1] + np.array([-1, 1]) * 1.96 * 0.01
                               / np.linalg.norm(x), rtol=1e-3)  # fmt: skip
