"""docs/study.md: the end-to-end study script runs and says what the page says (issue 38
item 6): a calibration equal to R's nls, a PCE of the predictions whose moments a Monte
Carlo run confirms, and four figures."""

import re
from pathlib import Path

import numpy as np

PAGE = Path(__file__).resolve().parents[1] / "docs" / "study.md"


def test_study_page_script_runs_and_verifies(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    (code,) = re.findall(r"```python\n(.*?)```", PAGE.read_text(), re.S)
    assert len(code.strip().splitlines()) <= 40
    monkeypatch.chdir(tmp_path)
    ns = {}
    exec(compile(code, "study.md", "exec"), ns)
    res, pce, report, band = ns["res"], ns["pce"], ns["report"], ns["band"]
    np.testing.assert_allclose(res.eps, [212.7, 0.06412], rtol=5e-4)  # R's nls
    # the PCE's moments against numpy's own draws of N(eps, cov) pushed through the model
    rng = np.random.default_rng(7)
    draws = rng.multivariate_normal(res.eps, res.uncertainty.cov, 100_000)
    y = np.array([ns["qoi"](e) for e in draws])
    se = y.std(0) / np.sqrt(len(y))
    assert np.all(np.abs(pce.mean - y.mean(0)) < 4 * se), (pce.mean, y.mean(0), se)
    np.testing.assert_allclose(pce.std, y.std(0), rtol=0.02)
    assert np.all(np.abs(report.mean_z) < 4) and np.all(np.abs(report.variance_z) < 4)
    assert np.max(report.holdout_error) < 1e-3
    S = pce.sobol_germ("first")
    assert S[1, 0] > 0.5 and S[0, 2] > 0.9  # K_m at low, V_max at high concentration
    assert np.all(band.lower < band.value) and np.all(band.value < band.upper)
    assert (tmp_path / "study.png").exists() and len(ns["fig"].axes) == 4
