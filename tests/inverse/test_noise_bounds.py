"""Noise bounds of Eq. (ecfm_noise): the paper's quantiles, coverage by Monte Carlo,
scaling properties, and bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ecfm_uq.inverse.formulations.noise_bounds import consistency_test, noise_bounds, sample_moments


def test_paper_quantiles_for_225_sensors():
    # Section 3.2: z_0.025 = -1.96, chi2_{0.025,224} = 184.44, chi2_{0.975,224} = 267.35
    b = noise_bounds(0.05, 225, alpha=0.05)
    assert round(b["z"], 2) == -1.96
    assert round(b["chi2_lo"], 2) == 184.44
    assert round(b["chi2_hi"], 2) == 267.35


def test_bounds_follow_the_paper_formulas():
    sigma, C = 0.05, 225
    b = noise_bounds(sigma, C)
    assert b["l1"] == pytest.approx(-1.959963984540054 * sigma / 15.0, rel=1e-12)
    assert b["l2"] == -b["l1"]
    assert b["p1"] == pytest.approx(b["chi2_lo"] * sigma**2 / 224, rel=1e-14)
    assert b["p2"] == pytest.approx(b["chi2_hi"] * sigma**2 / 224, rel=1e-14)


def test_monte_carlo_coverage_is_one_minus_alpha():
    # pure noise: each moment falls inside its interval with probability 1 - alpha
    rng = np.random.default_rng(12345)
    sigma, C, alpha, n = 0.3, 40, 0.1, 40000
    e = sigma * rng.standard_normal((n, C))
    b = noise_bounds(sigma, C, alpha)
    mean = e.mean(axis=1)
    var = e.var(axis=1, ddof=1)
    cover_mean = np.mean((mean >= b["l1"]) & (mean <= b["l2"]))
    cover_var = np.mean((var >= b["p1"]) & (var <= b["p2"]))
    se = np.sqrt(alpha * (1 - alpha) / n)  # binomial standard error, 0.0015
    assert abs(cover_mean - (1 - alpha)) < 4 * se
    assert abs(cover_var - (1 - alpha)) < 4 * se


def test_sample_moments_match_numpy():
    e = np.random.default_rng(0).standard_normal(17) + 0.3
    m, v = sample_moments(e)
    assert m == pytest.approx(e.mean(), rel=1e-14)
    assert v == pytest.approx(e.var(ddof=1), rel=1e-13)


def test_consistency_test_detects_wrong_variance_and_offset():
    rng = np.random.default_rng(7)
    sigma, C = 0.05, 225
    noise = sigma * rng.standard_normal(C)
    ok = consistency_test(noise - noise.mean(), sigma)  # centred: mean exactly 0
    assert ok.mean_ok
    # variance 4 sigma^2 is far outside [p1, p2] = [0.82, 1.19] sigma^2
    wide = consistency_test(2.0 * noise, sigma)
    assert wide.var_rejects and not wide.consistent
    # an offset of 3 standard errors of the mean fails the mean test
    shifted = consistency_test(noise - noise.mean() + 3 * sigma / 15, sigma)
    assert shifted.mean_rejects and not shifted.consistent


def test_consistency_rtol_only_admits_values_on_the_bound():
    sigma, C = 1.0, 50
    b = noise_bounds(sigma, C)
    e = np.zeros(C)
    e[0], e[1] = 1.0, -1.0  # mean 0, variance 2/(C-1)
    scale = np.sqrt(b["p2"] / sample_moments(e)[1])
    on_bound = consistency_test(e * scale * (1 + 1e-12), sigma, rtol=1e-9)
    assert on_bound.var_ok
    outside = consistency_test(e * scale * 1.01, sigma, rtol=1e-9)
    assert outside.var_rejects


@settings(max_examples=60, deadline=None)
@given(
    sigma=st.floats(1e-6, 1e3),
    C=st.integers(2, 5000),
    alpha=st.floats(1e-6, 0.999),
)
def test_bounds_ordering_and_scaling(sigma, C, alpha):
    b = noise_bounds(sigma, C, alpha)
    assert b["l1"] < 0 < b["l2"]
    assert 0 < b["p1"] < b["p2"]
    unit = noise_bounds(1.0, C, alpha)
    assert b["l1"] == pytest.approx(sigma * unit["l1"], rel=1e-12)
    assert b["p2"] == pytest.approx(sigma**2 * unit["p2"], rel=1e-12)


@pytest.mark.parametrize("sigma", [0.0, -0.05, np.nan, np.inf])
def test_bad_sigma(sigma):
    with pytest.raises(ValueError, match="sigma"):
        noise_bounds(sigma, 225)


@pytest.mark.parametrize("alpha", [0.0, 1.0, -0.1, 1.5])
def test_bad_alpha(alpha):
    with pytest.raises(ValueError, match="alpha"):
        noise_bounds(0.05, 225, alpha)
    with pytest.raises(ValueError, match="alpha"):
        consistency_test(np.ones(5), 0.05, alpha)


def test_too_few_sensors():
    with pytest.raises(ValueError, match="n_sensors"):
        noise_bounds(0.05, 1)
    with pytest.raises(ValueError, match="at least 2"):
        consistency_test(np.ones(1), 0.05)


def test_non_finite_discrepancy():
    e = np.ones(10)
    e[3] = np.nan
    with pytest.raises(ValueError, match="`e`"):
        consistency_test(e, 0.05)


def test_wrong_types():
    with pytest.raises(TypeError, match="sigma"):
        noise_bounds("0.05", 225)
    with pytest.raises(TypeError, match="alpha"):
        noise_bounds(0.05, 225, alpha="0.05")
    with pytest.raises(TypeError, match="n_sensors"):
        noise_bounds(0.05, 225.0)


def test_sample_variance_has_no_cancellation_for_an_offset_discrepancy():
    # a biased model's discrepancy: large mean, small spread. The one-pass formula
    # (sum e^2 - (sum e)^2 / C) / (C - 1) loses every digit here (and can go negative)
    rng = np.random.default_rng(3)
    spread = 1e-3 * rng.standard_normal(225)
    e = 1e4 + spread
    two_pass = np.sum((e - e.mean()) ** 2) / 224  # exact up to round-off of the mean
    assert sample_moments(e)[1] == pytest.approx(two_pass, rel=1e-8)
    # a constant discrepancy has sample variance 0 up to the round-off of its mean
    # squared (~1e-34 here), not the one-pass formula's residue of ~1e-18
    assert 0.0 <= sample_moments(np.full(10, 0.1))[1] < 1e-30
    assert consistency_test(np.full(10, 0.1), 0.05).var_rejects
