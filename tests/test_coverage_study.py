"""The coverage study (reduced to 12 data sets): keys, ranges, the figure, the summary
rows, and the CLI's refusal of bad options. The 200-set coverage itself is checked in
tests/test_uncertainty.py (steady, known sigma) and by ``reproduce coverage``."""

import json

import pytest

from ecfm_uq.cli import main
from ecfm_uq.studies import load_study


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("cov")
    assert main(["reproduce", "coverage", "--out", str(out), "--n-datasets", "12", "--quiet"]) == 0
    return json.loads((out / "coverage" / "result.json").read_text()), out


def test_result_has_the_contracted_keys(result):
    r, out = result
    assert r["n_datasets"] == 12
    for model in ("steady", "beam"):
        for form in ("standard", "ecfm"):
            entry = r[model][form]
            assert 0.0 <= entry["coverage"] <= 1.0
            assert entry["mean_width"] > 0 and entry["n_failed"] == 0
    # ECFM's intervals are the wider ones on both models (it fits the noise with forces)
    assert r["steady"]["ecfm"]["mean_width"] > r["steady"]["standard"]["mean_width"]
    assert r["beam"]["ecfm"]["mean_width"] > r["beam"]["standard"]["mean_width"]
    assert (out / "coverage" / "coverage.png").stat().st_size > 0


def test_summary_rows(result):
    rows = load_study("coverage").summary_rows(result[0])
    assert len(rows) == 6
    assert all(set(r) == {"quantity", "paper", "ours", "holds"} for r in rows)


@pytest.mark.parametrize("argv", [["--n-datasets", "1"], ["--sigma", "0"], ["--sigma", "nan"]])
def test_bad_options_are_refused(tmp_path, capsys, argv):
    assert main(["reproduce", "coverage", "--out", str(tmp_path), *argv]) != 0
    err = capsys.readouterr().err
    assert "--n-datasets" in err or "--sigma" in err
