"""The `beam` study (paper Section 3.3): the paper's setting with a reduced seed study,
another true load, and a load at buckling. Checks the paper's claims, not a snapshot."""

import json

import numpy as np
import pytest

from ecfm_uq.cli import main
from ecfm_uq.studies import beam as study

pytestmark = pytest.mark.slow  # runs the study: CI runs these in their own step

PAPER_EPS, PAPER_E, PAPER_BETA = 0.987, 7e-3, 2.24


def _run(out, *extra):
    assert main(["reproduce", "beam", "--out", str(out), "--quiet", *extra]) == 0
    with open(out / "beam" / "result.json") as fh:
        res = json.load(fh)
    res["_dir"] = out / "beam"
    return res


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("beam"), "--seed-study", "8")


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("beam15"), "--true-eps", "1.5", "--seed-study", "6")


def test_spec_keys_settings_and_figures(paper):
    for key in ("eps", "expected_rel_error", "force_norm", "beta_crit"):
        assert isinstance(paper[key], float)
    assert isinstance(paper["pce_vs_reference_max_rel_error"], float)
    assert paper["settings"]["true_eps"] == 1.0
    assert paper["settings"]["replicates"] == 25 and paper["settings"]["penalty"] == 100.0
    assert isinstance(paper["standard"]["eps"], float)
    ss = paper["seed_study"]
    assert ss["n"] == 8
    for key in ("ecfm_eps_mean", "ecfm_eps_std", "standard_eps_mean", "standard_eps_std"):
        assert isinstance(ss[key], float)
    assert paper["eps"] == paper["inner_outer"]["eps"]  # the main method is inner-outer
    for key in ("eps", "force_norm", "success"):
        assert key in paper["penalty"]
    for name in ("bases_and_stiffness", "comparison", "recovery", "seed_study"):
        assert (paper["_dir"] / f"{name}.png").stat().st_size > 0
    rows = study.summary_rows(paper)
    assert all(set(r) == {"quantity", "paper", "ours", "holds"} for r in rows)


def test_sensor_pce_and_estimate_uncertainty_are_reported(paper):
    pce = paper["sensor_pce"]
    q = np.array(pce["quantiles"])  # (3 levels, 5 sensors)
    assert np.all(np.diff(q, axis=0) > 0) and np.allclose(pce["first_order_sobol"], 1.0)
    # the quantiles bracket the model mean reported with the data
    assert np.all((q[0] < paper["data"]["model_mean"]) & (paper["data"]["model_mean"] < q[2]))
    unc = paper["uncertainty"]
    for key in ("standard", "inner_outer"):
        assert unc[key]["noise_model"] == "replicates" and unc[key]["eps_stderr"][0] > 0
    # ECFM's interval is the wider one, as its scatter over data sets is (seed study)
    assert unc["inner_outer"]["eps_stderr"][0] > 3 * unc["standard"]["eps_stderr"][0]
    assert "no minimizer" in unc["penalty"]["message"]
    assert (paper["_dir"] / "sensor_densities.png").stat().st_size > 0


def test_forward_model_claims(paper):
    assert paper["beta_crit"] == pytest.approx(PAPER_BETA, abs=1e-3)
    assert paper["pce_vs_reference_max_rel_error"] < 1e-2  # "agrees satisfactorily"


def test_paper_load_is_within_the_sampling_spread(paper):
    ss = paper["seed_study"]
    # the paper's 0.987 and our estimate for the default seed are both draws of an
    # estimator whose spread over data sets the seed study measures
    assert abs(paper["eps"] - 1.0) < 3 * ss["ecfm_eps_std"]
    assert abs(PAPER_EPS - 1.0) < 3 * ss["ecfm_eps_std"]
    assert abs(paper["standard"]["eps"] - 1.0) < 3 * ss["standard_eps_std"]
    assert abs(PAPER_EPS - 1.0) < 3 * ss["standard_eps_std"]


def test_expected_error_is_of_the_papers_order(paper):
    assert PAPER_E / 3 < paper["expected_rel_error"] < 3 * PAPER_E
    med = paper["seed_study"]["inner_outer"]["expected_rel_error_median"]
    assert PAPER_E / 3 < med < 3 * PAPER_E


def test_standard_estimate_is_the_more_reliable_one(paper):
    ss = paper["seed_study"]
    assert ss["standard_eps_std"] < 0.5 * ss["ecfm_eps_std"]
    assert ss["standard"]["rmse"] < ss["inner_outer"]["rmse"]
    # unbiased to within its standard error
    assert abs(ss["standard_eps_mean"] - 1.0) < 3 * ss["standard_eps_std"] / np.sqrt(ss["n"])
    # and the pseudo-information explains it: free forces flatten Lambda in eps
    assert paper["identifiability"]["std_ratio_predicted"] > 3


def test_penalty_form_is_reported_honestly(paper):
    ss = paper["seed_study"]
    pen = ss["penalty"]
    # SLSQP either follows log|lam|^2 down to lam ~ 0, and then returns the standard
    # estimate, or stops at a local minimum next to the inner-outer estimate
    assert pen["collapsed_equal_standard"]
    assert pen["n_forces_collapsed"] + pen["n_local_minimum_near_inner_outer"] == ss["n"]
    assert pen["n_other"] == 0
    # and the result says which: the fits down the valley are not converged, the others are
    assert pen["n_failed"] == pen["n_forces_collapsed"]


def test_another_true_load_is_recovered(heavy):
    ss = heavy["seed_study"]
    assert heavy["settings"]["true_eps"] == 1.5
    assert abs(heavy["eps"] - 1.5) < 3 * ss["ecfm_eps_std"]
    assert abs(heavy["standard"]["eps"] - 1.5) < 3 * ss["standard_eps_std"]
    assert abs(ss["standard_eps_mean"] - 1.5) < 3 * ss["standard_eps_std"] / np.sqrt(ss["n"])


def test_load_at_buckling_is_refused_with_one_line(tmp_path, capsys):
    for opt, val in (("--true-eps", "2.3"), ("--true-eps", "2.24007")):
        assert main(["reproduce", "beam", "--out", str(tmp_path), "--quiet", opt, val]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert f"eps={val}" in err and "beta_crit=2.24" in err
    assert not (tmp_path / "beam" / "result.json").exists()


@pytest.mark.parametrize(
    "opt, val, match",
    [
        ("--replicates", "1", "--replicates"),
        ("--penalty", "-1", "--penalty"),
        ("--order", "0", "--order"),
        ("--seed-study", "-2", "--seed-study"),
        ("--eps0", "2.23", "--eps0"),
        ("--true-eps", "-1", "--true-eps"),
    ],
)
def test_bad_options(tmp_path, capsys, opt, val, match):
    assert main(["reproduce", "beam", "--out", str(tmp_path), "--quiet", opt, val]) == 1
    assert match in capsys.readouterr().err
