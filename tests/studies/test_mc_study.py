"""The `mc` study: PCE against Monte Carlo for the beam (paper Section 3.3), reduced size."""

import json

import numpy as np
import pytest

from ecfm_uq.cli import build_parser, main
from ecfm_uq.studies import mc as study


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("mc")
    argv = ["reproduce", "mc", "--out", str(out), "--quiet", "--samples", "4000", "--seed", "7"]
    assert main(argv + ["--max-order", "7"]) == 0
    with open(out / "mc" / "result.json") as fh:
        res = json.load(fh)
    res["_dir"] = out / "mc"
    return res


def test_result_keys_and_figures(result):
    for key in ("pce", "mc"):
        for sub in ("mean", "var"):
            assert len(result[key][sub]) == 5
    assert result["mc"]["samples"] == 4000
    for key in ("rel_error_mean", "rel_error_var", "pce_vs_reference_max_rel_error", "delta"):
        assert isinstance(result[key], float)
    assert result["settings"]["seed"] == 7
    for name in ("convergence.png", "moments.png", "pce_vs_reference.png"):
        assert (result["_dir"] / name).stat().st_size > 0


def test_buckling_calibration(result):
    # SPEC: worst-case buckling load 2.24 with delta ~ 0.18; undamaged beam pi^2/4
    assert result["beta_crit_reference"] == pytest.approx(2.24, abs=1e-9)
    assert result["beta_crit"] == pytest.approx(2.24, abs=1e-3)
    assert result["beta_crit_omega0"] == pytest.approx(np.pi**2 / 4, rel=1e-10)
    assert 0.17 < result["delta"] < 0.19


def test_pce_agrees_with_monte_carlo_within_its_error(result):
    mc = result["mc"]
    assert np.all(np.abs(mc["z_mean"]) < 3)
    assert np.all(np.abs(mc["z_var"]) < 3)
    # the PCE is far closer to the quadrature reference than Monte Carlo is
    assert result["pce"]["rel_error_mean_vs_reference"] < 1e-3 * mc["rel_error_mean_vs_reference"]
    assert result["pce"]["rel_error_var_vs_reference"] < 1e-3 * mc["rel_error_var_vs_reference"]


def test_mc_error_rate(result):
    cv = result["mc"]["convergence"]
    assert cv["slope_mean"] == pytest.approx(-0.5, abs=0.15)
    assert cv["slope_var"] == pytest.approx(-0.5, abs=0.15)


def test_pce_error_is_spectral(result):
    pc = result["pce"]["convergence"]
    ev = np.array(pc["err_var"])
    em = np.array(pc["err_mean"])
    # each order gains at least a factor 50 until round-off (checked on orders 1..4)
    assert np.all(ev[2:5] < ev[1:4] / 50)
    assert np.all(em[1:5] < em[0:4] / 50)
    assert ev[5] < 1e-10 and em[5] < 1e-12


def test_pce_matches_15_mode_reference(result):
    # paper Figure `comparison` (left): "agrees satisfactorily"
    assert result["pce_vs_reference_max_rel_error"] < 1e-2
    assert result["reference"]["rel_change_with_32_more_nodes"] < 1e-12


def test_summary_rows(result):
    rows = study.summary_rows(result)
    assert {"quantity", "paper", "ours", "holds"} <= set(rows[0])
    assert all(r["holds"] is True for r in rows)


@pytest.mark.parametrize(
    ("opt", "value"),
    [("--samples", "10"), ("--order", "-1"), ("--workers", "0"), ("--reference-points", "2")],
)
def test_bad_options(tmp_path, opt, value):
    args = build_parser().parse_args(["reproduce", "mc", "--out", str(tmp_path), opt, value])
    with pytest.raises(ValueError, match=opt):
        study.settings_from_args(args)


def test_cli_reports_buckling(tmp_path, capsys):
    argv = [
        "reproduce",
        "mc",
        "--out",
        str(tmp_path),
        "--quiet",
        "--samples",
        "200",
        "--eps",
        "2.5",
    ]
    assert main(argv) != 0
    err = capsys.readouterr().err
    assert "beta_crit" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "mc" / "result.json").exists()


def test_summary_rows_with_only_order_zero(result):
    # --max-order 0 is a valid setting: the spectral-decay row must say "not measured"
    # (holds None) rather than crash on the missing order-1 error
    pc = result["pce"]["convergence"]
    short = {**result, "pce": {**result["pce"], "convergence": {k: v[:1] for k, v in pc.items()}}}
    rows = study.summary_rows(short)
    (decay,) = [r for r in rows if r["quantity"].startswith("PCE variance error")]
    assert decay["holds"] is None


def test_sobol_verification_rows(result):
    sob = result["sobol"]
    # the sampling estimator against the closed form, and the PCE inside its intervals
    assert sob["max_sampling_error"] <= 0.02
    assert sob["max_pce_error"] <= 1e-2
    assert sob["pce_inside_intervals"] >= sob["n_intervals"] - 1
    assert sob["sampling_runs"] == 4096 * 5
