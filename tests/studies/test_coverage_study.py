"""The `coverage` study (issue 13) with R = 40 data sets (20 for the blocks whose fits cost
seconds each): are the reported intervals honest? Checked against the binomial law of
honest intervals at each block's own size, not a snapshot.

Marked slow (the study runs a few minutes even at this size): CI runs it in its own step."""

import json

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.cli import main
from ecfm_uq.studies import coverage as study

pytestmark = pytest.mark.slow

R, R_SLOW = 40, 20  # data sets of the fast blocks and of the slow ones (beam, operator ECFM)


def honest_range(n, p=0.95):
    """A 99.9 % range of the share of hits of ``n`` honest ``p`` intervals (Binomial)."""
    return stats.binom.ppf([0.0005, 0.9995], n, p) / n


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("coverage")
    args = ["--n-datasets", str(R), "--n-datasets-slow", str(R_SLOW)]
    assert main(["reproduce", "coverage", "--out", str(out), "--quiet", *args]) == 0
    with open(out / "coverage" / "result.json") as fh:
        res = json.load(fh)
    res["_dir"] = out / "coverage"
    return res


def test_result_keys_of_the_contract(result):
    assert result["n_datasets"] == R and result["n_datasets_slow"] == R_SLOW
    for model in ("steady", "beam"):
        for form in ("standard", "ecfm"):
            blk = result[model][form]
            assert 0.0 <= blk["coverage"] <= 1.0
            assert blk["mean_width"] > 0
            assert blk["n_failed"] == 0
    assert (result["_dir"] / "coverage.png").stat().st_size > 0
    rows = study.summary_rows(result)
    assert all(set(r) == {"quantity", "paper", "ours", "holds"} for r in rows)


@pytest.mark.parametrize("model", ["steady", "beam"])
@pytest.mark.parametrize("form", ["standard", "ecfm"])
def test_coverage_is_what_honest_intervals_give(result, model, form):
    blk = result[model][form]
    n = blk["n_intervals"]
    # honest 95 % intervals: the number of hits is (for one parameter exactly)
    # Binomial(n, 0.95)
    lo, hi = honest_range(n)
    assert lo <= blk["coverage"] <= hi, blk


@pytest.mark.parametrize("form", ["standard", "ecfm"])
def test_beam_standard_errors_match_the_spread_of_the_estimates(result, form):
    blk = result["beam"][form]
    # sd of 20 estimates is known to ~ +-16 % (1/sqrt(2 * 19)); allow about 3 of those
    assert 0.67 < blk["mean_stderr"] / blk["estimate_std"] < 1.5, blk


def test_ecfm_intervals_say_the_ecfm_load_is_less_certain(result):
    # the beam seed study: the ECFM load scatters ~10x more than the standard one; the
    # single-fit intervals must say so
    b = result["beam"]
    assert b["ecfm"]["mean_width"] > 4 * b["standard"]["mean_width"]
    assert b["ecfm"]["estimate_std"] > 4 * b["standard"]["estimate_std"]


def test_bad_options_are_refused(tmp_path, capsys):
    for opt, val in (("--n-datasets", "0"), ("--sigma", "0"), ("--replicates", "2")):
        assert main(["reproduce", "coverage", "--out", str(tmp_path), opt, val]) != 0
        assert opt in capsys.readouterr().err


def test_binomial_band_against_scipy():
    from ecfm_uq.inverse.coverage import binomial_band

    lo, hi = binomial_band(200)
    k = np.arange(201)
    p = stats.binom.pmf(k, 200, 0.95)
    assert p[(k >= lo * 200) & (k <= hi * 200)].sum() >= 0.95


@pytest.mark.parametrize("form", ["standard", "ecfm", "ecfm_sparse"])
def test_profile_intervals_are_honest_with_a_parameter_in_the_operator(result, form):
    blk = result["operator"][form]
    assert blk["n_failed"] <= 8, blk  # estimates that run to infinity are refused
    lo, hi = honest_range(blk["n_datasets"])
    for cov in blk["profile"]["coverage_per_parameter"]:
        assert lo <= cov <= hi, blk
    if form != "standard":
        ratio = result["operator"][f"{form}_over_standard_profile_width"]
        assert all(r is None or r <= 1.5 for r in ratio)
    assert (result["_dir"] / "operator.png").stat().st_size > 0


@pytest.mark.parametrize("key", ["rows", "rows_sparse"])
def test_discrepancy_test_grows_from_its_size_to_full_power(result, key):
    rows = result["discrepancy"][key]
    rejects = [r["tau_test_rejects"] for r in rows]
    # false alarms of a size-0.05 test on R_SLOW data sets: at most its 99.9 % quantile
    top = stats.binom.ppf(0.999, R_SLOW, 0.05) / R_SLOW
    assert rows[0]["amplitude"] == 0.0 and rejects[0] <= top
    assert rejects == sorted(rejects) and rejects[-1] >= 0.8
    rms = [r["residual_rms_over_sigma"] for r in rows]
    assert rms == sorted(rms)


def test_function_models_intervals_and_verdicts(result):
    """Issue 28's rows at R = 40: profile-t and region coverage within the binomial law of
    honest 95 % intervals; no "inconsistent" without sigma; the chi-squared test's false
    alarms within the binomial law of its size, with and without a bound reached; the
    missing offset flagged every time."""
    fn = result["function"]
    lo, hi = honest_range(R)
    for key in ("small_sample", "two_basins"):
        for cov in fn[key]["regions"]["coverage_per_parameter"]:
            assert lo <= cov <= hi, (key, fn[key])
    assert fn["no_sigma"]["n_not_consistent"] == 0 and fn["no_sigma"]["n_no_test"] == R
    top = stats.binom.ppf(0.9995, R, 0.05)
    assert fn["sigma"]["n_not_consistent"] <= top
    assert fn["sigma_bounded"]["n_not_consistent"] <= top
    assert fn["sigma_bounded"]["n_at_bound"] >= 10  # the truth sits on the bound
    assert fn["missing_offset"]["n_not_consistent"] == R
    quantities = [r["quantity"] for r in study.summary_rows(result)]
    assert any("two basins" in q for q in quantities)
