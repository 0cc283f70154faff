"""The kpp study at the paper's size (N = 100, M = 16, C = 225) for two noise seeds:
the paper's claims of Section 3.2, not a snapshot of our numbers."""

import argparse
import json

import pytest

from ecfm_uq.cli import main
from ecfm_uq.studies import kpp
from ecfm_uq.studies._common import QUIET

PAPER_INV, PAPER_ECFM = 3.2e-2, 1.1e-2


def _check_claims(r):
    inv, ecfm, b = r["inv"], r["ecfm"], r["bounds"]
    assert inv["success"] and ecfm["success"], (inv["message"], ecfm["message"])
    # errors against the noiseless true state: ECFM better, both of the paper's order
    assert ecfm["rel_error"] < inv["rel_error"]
    assert PAPER_INV / 2 < inv["rel_error"] < 2 * PAPER_INV
    assert PAPER_ECFM / 2 < ecfm["rel_error"] < 2 * PAPER_ECFM
    # the standard discrepancy is not noise-like: the variance test rejects
    assert inv["variance_test_rejects"] is True
    assert inv["var_discrepancy"] > b["p2"]
    # ECFM's discrepancy moments sit inside the bounds (up to SLSQP's feasibility, 1e-9)
    assert b["l1"] * (1 + 1e-9) <= ecfm["mean_discrepancy"] <= b["l2"] * (1 + 1e-9)
    assert b["p1"] * (1 - 1e-9) <= ecfm["var_discrepancy"] <= b["p2"] * (1 + 1e-9)
    # the forces are active (model misspecified) and fix the source
    assert ecfm["force_norm"] > 0.1
    assert r["source_rel_error"]["b_plus_forces"] < r["source_rel_error"]["b_only"]
    assert r["source_rel_error"]["l2"]["b_plus_forces"] < r["source_rel_error"]["l2"]["b_only"]
    # "only subtle differences" in the recovered parameters
    assert r["param_rel_diff"] < 0.1
    # the noise itself passes both tests, so the rejection is due to the model
    assert not r["data"]["noise_alone"]["variance_test_rejects"]


def test_cli_seed0_writes_spec_keys_and_claims_hold(tmp_path):
    assert main(["reproduce", "kpp", "--out", str(tmp_path), "--quiet"]) == 0
    out = tmp_path / "kpp"
    r = json.loads((out / "result.json").read_text())
    for key in ("rel_error", "eps", "variance_test_rejects"):
        assert key in r["inv"]
    for key in ("rel_error", "eps", "mean_discrepancy", "var_discrepancy", "force_norm"):
        assert key in r["ecfm"]
    assert len(r["inv"]["eps"]) == 16 and len(r["ecfm"]["eps"]) == 16
    assert set(r["bounds"]) >= {"l1", "l2", "p1", "p2"}
    assert {"b_only", "b_plus_forces"} <= set(r["source_rel_error"])
    assert isinstance(r["inv"]["variance_test_rejects"], bool)
    assert r["settings"]["seed"] == 0 and r["settings"]["rbf_width"] == 128.0
    for name in ("setup.png", "standard.png", "ecfm.png", "recovery.png"):
        assert (out / name).stat().st_size > 1000
    _check_claims(r)
    rows = kpp.summary_rows(r)
    assert rows[0]["holds"] is True  # -1.96, 184.44, 267.35


def test_other_seed_same_conclusions(tmp_path):
    parser = argparse.ArgumentParser()
    kpp.add_arguments(parser)
    args = parser.parse_args([])
    args.seed = 1
    r = kpp.run(kpp.settings_from_args(args), tmp_path, QUIET)
    _check_claims(r)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--sigma", "-1"], "--sigma must be positive"),
        (["--sigma", "0"], "--sigma must be positive"),
        (["--alpha", "1.5"], "--alpha must lie in"),
        (["--alpha", "0"], "--alpha must lie in"),
        (["--rbf-width", "-3"], "--rbf-width must be positive"),
        (["--n-state", "0"], "--n-state must be"),
        (["--n-state", "3", "--n-source", "4"], "--n-source"),
        (["--maxiter", "0"], "--maxiter must be"),
    ],
)
def test_settings_reject_bad_options(argv, match):
    parser = argparse.ArgumentParser()
    kpp.add_arguments(parser)
    args = parser.parse_args(argv)
    args.seed = None
    with pytest.raises(ValueError, match=match):
        kpp.settings_from_args(args)


def test_cli_reports_bad_sigma_on_one_line(tmp_path, capsys):
    assert main(["reproduce", "kpp", "--out", str(tmp_path), "--sigma", "-1"]) != 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("ecfm-uq: error: --sigma must be positive") and "\n" not in err
