"""The ``burgers`` study (paper Section 3.1) checks the paper's claims, at reduced size.

Reduced size: N = 16 modes and 50 backward-Euler steps instead of 50 and 100, so the two
250-epoch Adam runs take seconds; Adam's learning rate, epochs and start are the
paper's/SPEC's. The claims checked: both methods recover the true parameters to three
decimals in 250 epochs from (1.5, 0.5); the ECFM objective's Hessian at the optimum is
better conditioned than the standard one; another true parameter is recovered too.
"""

import json

import numpy as np
import pytest

from ecfm_uq.cli import build_parser, main
from ecfm_uq.studies import burgers
from ecfm_uq.studies._common import QUIET

REDUCED = ["--n-modes", "16", "--n-steps", "50"]


def _settings(*argv):
    args = build_parser().parse_args(["reproduce", "burgers", "--out", "unused", *argv])
    return burgers.settings_from_args(args)


def test_cli_run_recovers_paper_parameters_and_conditioning(tmp_path):
    code = main(
        ["reproduce", "burgers", "--out", str(tmp_path), "--quiet", *REDUCED, "--surface-grid", "3"]
    )
    assert code == 0
    out = tmp_path / "burgers"
    r = json.loads((out / "result.json").read_text())
    # SPEC keys (dotted keys are nested objects)
    assert r["epochs"] == 250
    assert r["settings"]["true_eps"] == [1.75, 1.0]
    for key in ("inv", "ecfm"):
        assert len(r[key]["eps"]) == 2
        assert isinstance(r[key]["loss"], float) and isinstance(r[key]["hessian_cond"], float)
        # the paper: both end at (1.750, 1.000), matching the truth to three decimals
        assert np.all(np.abs(np.array(r[key]["eps"]) - [1.75, 1.0]) < 5e-4), r[key]["eps"]
        # 250 Adam epochs stop a few 1e-6 short of the optimum: the fit says so (issue 20)
        assert not r[key]["success"] and "NOT converged" in r[key]["message"]
        assert len(r[key]["loss_history"]) == 251
    # the paper: ECFM's loss surface is better conditioned (3.46 vs 8.11)
    assert r["ecfm"]["hessian_cond"] < r["inv"]["hessian_cond"]
    for name in ("setup.png", "true_field.png", "convergence.png", "loss_surfaces.png"):
        assert (out / name).stat().st_size > 0
    assert len(r["surface"]["inv"]) == 3 and len(r["surface"]["ecfm"][0]) == 3
    rows = burgers.summary_rows(r)
    assert [row["holds"] for row in rows if row["holds"] is not None] == [True, True, True]


def test_other_true_parameters_are_recovered(tmp_path):
    s = _settings(*REDUCED, "--surface-grid", "0", "--true-eps", "1.5", "0.8")
    r = burgers.run(s, tmp_path, QUIET)
    for key in ("inv", "ecfm"):
        np.testing.assert_allclose(r[key]["eps"], [1.5, 0.8], atol=5e-4)
        assert r[key]["recovered_3_decimals"]
    assert "loss_surfaces.png" not in r["figures"]


def test_defaults_are_the_papers():
    s = _settings()
    assert s["true_eps"] == [1.75, 1.0] and s["start"] == [1.5, 0.5]
    assert (s["epochs"], s["lr"], s["n_modes"], s["n_steps"], s["T"]) == (250, 1e-2, 50, 100, 2.0)
    assert s["newton_tol"] == 1e-6 and s["hat_width"] is None


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--hat-width", "-1"], "--hat-width must be positive"),
        (["--lr", "0"], "--lr must be positive"),
        (["--epochs", "0"], "--epochs must be >= 1"),
        (["--newton-tol=-1e-6"], "--newton-tol must be positive"),
        (["--surface-grid", "2"], "--surface-grid"),
        (["--fd-step", "0"], "--fd-step must be positive"),
        (["--true-eps", "nan", "1"], "--true-eps must be finite"),
        (["--n-modes", "1"], "--n-modes"),
    ],
)
def test_bad_options_raise_naming_the_option(argv, match):
    with pytest.raises(ValueError, match=match):
        _settings(*argv)


def test_bad_options_exit_with_one_line(tmp_path, capsys):
    assert main(["reproduce", "burgers", "--out", str(tmp_path), "--hat-width", "-1"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--hat-width must be positive" in err
    with pytest.raises(SystemExit) as info:
        main(["reproduce", "burgers", "--out", str(tmp_path), "--no-such-option", "1"])
    assert info.value.code == 2
    with pytest.raises(SystemExit):
        main(["reproduce", "burgers", "--out", str(tmp_path), "--initial-state", "exact"])


def test_surface_box_contains_start_and_truth():
    lo, hi = burgers.surface_box([1.75, 1.0], [1.5, 0.5])
    assert np.all(lo < [1.5, 0.5]) and np.all(hi > [1.75, 1.0])
    np.testing.assert_allclose((lo + hi) / 2, [1.75, 1.0])
