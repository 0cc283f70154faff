"""The ``boundary`` and ``geometry`` studies (paper Section 4 as working examples), run
with reduced sizes, checked against the claims: consistent data give back the true
parameters with (near-)zero constraint forces; misspecified data need forces at least ten
times larger, concentrated near the missing physics."""

import argparse
import json

import numpy as np
import pytest

from ecfm_uq.cli import main
from ecfm_uq.studies import boundary, geometry
from ecfm_uq.studies._common import QUIET, write_json


def _settings(study, argv):
    parser = argparse.ArgumentParser()
    parser.add_argument("--seed", type=int, default=None)
    study.add_arguments(parser)
    return study.settings_from_args(parser.parse_args(argv))


def _check_claims(res, true_eps):
    np.testing.assert_allclose(res["true_eps"], true_eps)
    # consistent data: both methods recover the truth to 1e-3 relative
    np.testing.assert_allclose(res["inv"]["eps"], true_eps, rtol=1e-3)
    np.testing.assert_allclose(res["ecfm"]["eps"], true_eps, rtol=1e-3)
    assert res["inv"]["success"] and res["ecfm"]["success"]
    # ECFM forces vanish up to the optimizer tolerance: far below their size at the start
    assert res["ecfm"]["force_norm"] < 1e-5 * res["ecfm"]["force_norm_start"]
    # misspecified data: the forces grow
    mis = res["misspecified"]
    assert mis["ecfm"]["force_norm"] >= 10 * res["ecfm"]["force_norm"]
    assert mis["ecfm"]["force_norm"] > 1e-2 * mis["ecfm"]["force_norm_start"]
    # ... and peak near the unmodelled source, to within the sensor resolution
    assert mis["peak_within_one_sensor_spacing"]
    for key in ("eps",):
        assert np.all(np.isfinite(mis["inv"][key])) and np.all(np.isfinite(mis["ecfm"][key]))


def test_boundary_study_recovers_boundary_data_and_flags_misspecification(tmp_path):
    settings = _settings(boundary, ["--n-basis", "20", "--true-eps", "0.5", "1.25"])
    res = boundary.run(settings, tmp_path, QUIET)
    _check_claims(res, [0.5, 1.25])
    assert abs(res["misspecified"]["force_peak_position"] - 0.6) <= 1 / 6
    for fig in ("fields.png", "forces.png", "parameters.png"):
        assert (tmp_path / fig).stat().st_size > 0
    write_json(tmp_path / "result.json", res)  # JSON-able, no NaN
    back = json.loads((tmp_path / "result.json").read_text())
    assert set(back) >= {"true_eps", "inv", "ecfm", "misspecified", "settings"}
    assert "force_norm" in back["misspecified"]["ecfm"] and "eps" in back["misspecified"]["inv"]
    rows = boundary.summary_rows(res)
    assert all(set(r) == {"quantity", "paper", "ours", "holds"} for r in rows)
    assert all(r["holds"] for r in rows)


def test_geometry_study_recovers_sizes_and_flags_misspecification(tmp_path):
    settings = _settings(
        geometry, ["--n-basis", "10", "--sensors", "4", "--true-eps", "1.2", "1.6", "0.9"]
    )
    res = geometry.run(settings, tmp_path, QUIET)
    assert res["main_case"] == "rectangle"
    _check_claims(res["cases"]["interval"], [1.2])
    _check_claims(res["cases"]["rectangle"], [1.6, 0.9])
    # top-level SPEC keys are the main case's
    assert res["ecfm"]["eps"] is res["cases"]["rectangle"]["ecfm"]["eps"]
    write_json(tmp_path / "result.json", res)
    rows = geometry.summary_rows(res)
    assert len(rows) == 11 and all(r["holds"] for r in rows)
    for fig in ("fields_rectangle.png", "forces_rectangle.png", "forces_interval.png"):
        assert (tmp_path / fig).stat().st_size > 0


def test_geometry_option_layout_and_errors():
    s = _settings(geometry, ["--case", "interval", "--true-eps", "2.0", "--start", "1.0"])
    assert s["cases"] == {
        "interval": {
            "true_eps": [2.0],
            "start": [1.0],
            "missing_sink": geometry.DEFAULTS["interval"]["missing_sink"],
        }
    }
    with pytest.raises(ValueError, match="--true-eps"):
        _settings(geometry, ["--case", "rectangle", "--true-eps", "1.0"])
    with pytest.raises(ValueError, match="--true-eps"):
        _settings(geometry, ["--case", "interval", "--true-eps", "-1.0"])
    with pytest.raises(ValueError, match="--sensors"):
        _settings(geometry, ["--sensors", "30"])


def test_boundary_option_errors():
    with pytest.raises(ValueError, match="--sensors"):
        _settings(boundary, ["--sensors", "1"])
    with pytest.raises(ValueError, match="--true-eps"):
        _settings(boundary, ["--true-eps", "nan", "1"])
    with pytest.raises(ValueError, match="--missing-center"):
        _settings(boundary, ["--missing-center", "1.5"])


def test_cli_reports_bad_options_on_one_line(tmp_path, capsys):
    code = main(["reproduce", "geometry", "--out", str(tmp_path), "--true-eps", "0", "1", "1"])
    assert code != 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("ecfm-uq: error:") and "--true-eps" in err and "\n" not in err
    assert not (tmp_path / "geometry" / "result.json").exists()
