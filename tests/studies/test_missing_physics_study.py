"""The `missing-physics` study (issue 20 item 6): a 2-D finite-element model calibrated
while a localized source is missing from it."""

import json

import pytest

pytest.importorskip("skfem")

from ecfm_uq.cli import main  # noqa: E402
from ecfm_uq.studies import missing_physics as study  # noqa: E402

pytestmark = pytest.mark.slow  # runs the study: CI runs these in their own step


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("mp")
    assert main(["reproduce", "missing-physics", "--out", str(out), "--quiet",
                 "--noise-seeds", "4"]) == 0  # fmt: skip
    res = json.loads((out / "missing-physics" / "result.json").read_text())
    res["_dir"] = out / "missing-physics"
    return res


def test_random_force_ecfm_maps_the_missing_source_and_flags_the_model(result):
    rf, std, paper = result["random_force_ecfm"], result["standard"], result["paper_ecfm"]
    assert rf["success"] and std["success"] and paper["success"]
    assert rf["peak_sensor"] == result["nearest_sensor"]
    assert rf["peak_over_median_force"] > paper["peak_over_median_force"]
    assert not rf["consistent"] and rf["p_value"] < 1e-3  # Monte Carlo p, resolution 1/4001
    # the discrepancy takes the source, not the conductivity
    assert rf["error"] < std["error"] and rf["error"] < paper["error"]
    assert (result["_dir"] / "force_maps.png").stat().st_size > 0
    rows = study.summary_rows(result)
    assert all(set(r) == {"quantity", "paper", "ours", "holds"} for r in rows)


def test_without_the_source_the_model_is_consistent(tmp_path):
    assert main(["reproduce", "missing-physics", "--out", str(tmp_path), "--quiet",
                 "--source-amplitude", "0", "--noise-seeds", "0"]) == 0  # fmt: skip
    res = json.loads((tmp_path / "missing-physics" / "result.json").read_text())
    rf = res["random_force_ecfm"]
    assert rf["consistent"] and rf["tau"] == 0.0 and abs(rf["eps"] - 0.2) < 0.01


def test_a_variance_per_force_puts_the_source_in_the_forces_and_recovers_eps(result):
    sp, std, rf = result["sparse_force_ecfm"], result["standard"], result["random_force_ecfm"]
    assert sp["success"] and not sp["consistent"]
    assert sp["peak_sensor"] == result["nearest_sensor"]
    assert sp["peak_over_median_force"] >= 10.0  # issue 20's must-show for the force map
    assert 0 < sp["n_forces_used"] < 25  # forces the data do not need are switched off
    # the conductivity is not traded for the source: far closer than the other fits
    assert sp["error"] < 0.25 * min(std["error"], rf["error"])


def test_over_noise_draws_the_sparse_map_stays_at_the_source(result):
    seeds = result["noise_seeds"]
    assert seeds["n"] == 4
    sp, rf = seeds["sparse_force_ecfm"], seeds["random_force_ecfm"]
    for r in (sp, rf):
        assert len(r["eps"]) == 4 and r["fraction_peak_at_nearest"] == 1.0
        assert r["fraction_inconsistent"] == 1.0
    assert sp["fraction_ratio_at_least_claim"] == 1.0
    assert max(abs(e - 0.2) for e in sp["eps"]) < 0.01  # the conductivity is not traded
    assert min(sp["ratio_min_median_max"]) >= 10.0


def test_bad_noise_seeds_are_refused(tmp_path, capsys):
    assert main(["reproduce", "missing-physics", "--out", str(tmp_path), "--quiet",
                 "--noise-seeds", "-1"]) != 0  # fmt: skip
    assert "--noise-seeds must be non-negative" in capsys.readouterr().err
    assert not (tmp_path / "missing-physics" / "result.json").exists()
