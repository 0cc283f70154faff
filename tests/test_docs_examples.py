"""The tutorial in docs/getting-started.md runs and does what it says."""

import re
from pathlib import Path

import numpy as np
import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_getting_started_tutorial_recovers_parameters():
    text = (DOCS / "getting-started.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[1]
    code = code.replace("    print(res)", "    results[formulation] = res")
    ns = {"results": {}}
    exec(compile(code, "getting-started.md", "exec"), ns)
    for res in ns["results"].values():
        assert res.success, res.message
        np.testing.assert_allclose(res.eps, [0.3, 2.0], rtol=1e-6)


def test_getting_started_function_model_matches_r_nls():
    """The Michaelis-Menten example is Bates & Watts' Puromycin (treated) data: R's
    ``nls`` gives V_max = 212.7 (se 6.947), K_m = 0.06412 (se 0.008281), and MASS's
    ``confint`` (profile-t) V_max in [197.3, 229.3], K_m in [0.04693, 0.08616]."""
    text = (DOCS / "getting-started.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code.replace("print(res.summary())", ""), "getting-started.md", "exec"), ns)
    res = ns["res"]
    assert res.success and res.verdict.consistent is None
    np.testing.assert_allclose(res.eps, [212.7, 0.06412], rtol=5e-4)
    np.testing.assert_allclose(res.uncertainty.stderr, [6.947, 0.008281], rtol=5e-4)
    iv = ns["prof"].intervals
    r = np.array([[197.3, 229.3], [0.04693, 0.08616]])
    assert np.all(np.abs(iv - r) <= 2e-3 * (r[:, 1:] - r[:, :1])), iv


def test_fem_tutorial_runs_and_recovers_parameters():
    import pytest

    pytest.importorskip("skfem")
    text = (DOCS / "fem.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    code = code.replace(
        "    print(formulation, res.eps, res.success)", "    results[formulation] = res"
    )
    ns = {"results": {}}
    exec(compile(code, "fem.md", "exec"), ns)
    assert ns["sol"].solver == "cg+mean"
    for res in ns["results"].values():
        assert res.success, res.message
        np.testing.assert_allclose(res.eps, [0.1, 0.5], atol=1e-6)


def test_pce_page_examples_run_and_match_closed_forms():
    text = (DOCS / "pce.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 3
    ns = {}
    exec(compile("\n".join(blocks), "pce.md", "exec"), ns)
    # the ten-line example: Ishigami, a = 7, b = 0.1, against its analytic indices
    pce, pi = ns["pce"], np.pi
    V = 49 / 8 + 0.1 * pi**4 / 5 + 0.01 * pi**8 / 18 + 0.5
    V1, V2, V13 = (1 + 0.1 * pi**4 / 5) ** 2 / 2, 49 / 8, 0.01 * pi**8 * (1 / 18 - 1 / 50)
    np.testing.assert_allclose(pce.mean, 3.5, rtol=1e-8)
    np.testing.assert_allclose(pce.variance, V, rtol=1e-8)
    np.testing.assert_allclose(pce.first_order(), [V1 / V, V2 / V, 0], atol=1e-8)
    np.testing.assert_allclose(pce.total(), [(V1 + V13) / V, V2 / V, V13 / V], atol=1e-8)
    # the Galerkin beam: one germ, so every first-order index is 1
    np.testing.assert_allclose(ns["beam"].first_order(), 1.0, rtol=1e-12)
    # chaospy interop: x0 + x1^2 + x0 x1 has T = (20, 36) / 51 (see tests/chaos/test_pce.py)
    np.testing.assert_allclose(ns["chaospy"].Sens_t(ns["poly"], ns["dist"]), [20 / 51, 36 / 51])


def test_uncertainty_page_example_runs_and_reports_intervals():
    text = (DOCS / "uncertainty.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 1
    ns = {}
    exec(compile(blocks[0], "uncertainty.md", "exec"), ns)
    res = ns["res"]  # the ECFM fit, last in the loop
    assert res.success and res.uncertainty.noise_model == "known" and res.formulation == "ecfm"
    np.testing.assert_allclose(
        res.uncertainty.stderr, np.sqrt(np.diag(res.uncertainty.cov)), rtol=1e-12
    )
    half = 1.959963984540054 * res.uncertainty.stderr  # normal 97.5 % quantile (sigma known)
    np.testing.assert_allclose(res.uncertainty.intervals[:, 1] - res.eps, half, rtol=1e-12)
    np.testing.assert_allclose(res.eps - res.uncertainty.intervals[:, 0], half, rtol=1e-12)


def test_calibration_page_example_runs_and_says_the_lower_end_is_open():
    text = (DOCS / "calibration.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code, "calibration.md", "exec"), ns)
    summary = ns["summary"]
    lo, hi = summary.intervals[0]
    assert lo == -np.inf and hi > 0.0 and "not identifiable" in summary.message
    assert summary.intervals[1, 0] < 20.0 < summary.intervals[1, 1]


def test_nonlinear_page_example_matches_collocation():
    import pytest

    pytest.importorskip("skfem")
    text = (DOCS / "nonlinear.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code, "nonlinear.md", "exec"), ns)
    assert ns["sol"].success
    # the table's order-3 row: chaos truncation error against 10 x 10 collocation
    assert ns["err_mean"] < 1e-7 and ns["err_var"] < 5e-5
    # the sensitivity against a central difference of two solves
    system, h = ns["system"], 1e-3
    plus = ns["solve_steady"](system, [50.0 + h], tol=1e-12).Theta
    minus = ns["solve_steady"](system, [50.0 - h], tol=1e-12).Theta
    fd = (plus - minus) / (2 * h)
    assert np.abs(ns["dTheta"][:, :, 0] - fd).max() <= 1e-5 * np.abs(fd).max()


def test_ode_page_example_gives_the_numbers_it_shows():
    """docs/ode.md: Lotka-Volterra on the lynx-hare pelts; the least-squares estimates
    and standard errors printed on the page."""
    text = (DOCS / "ode.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code.replace("print(res.summary())", ""), "ode.md", "exec"), ns)
    res = ns["res"]
    assert res.success, res.message
    np.testing.assert_allclose(res.eps, [0.481199, 0.0248318, 0.027533, 0.926018, 34.9143,
                                         3.86187], rtol=2e-5)  # fmt: skip
    np.testing.assert_allclose(res.uncertainty.stderr[:2], [0.035088, 0.001638], rtol=1e-4)


def test_time_page_sparse_data_example_prints_what_it_says():
    """docs/time.md, data at their own times: backward Euler at the data's spacing is 45 %
    off, 120 steps a year between the readings 0.3 %; the missing source is the 4th
    year's force (0.2)."""
    text = (DOCS / "time.md").read_text()
    code = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if ", t=t)" in b)
    ns = {}
    exec(compile(code, "time.md", "exec"), ns)
    est, yearly = ns["estimates"], ns["yearly"]
    for f in ("standard", "ecfm"):
        assert abs(est[1, f] / 0.7 - 1) > 0.4
        assert 0.002 < est[120, f] / 0.7 - 1 < 0.004
    assert abs(yearly[3] - 0.2) < 1e-3 and np.all(np.abs(np.delete(yearly, 3)) < 2e-3)
    np.testing.assert_allclose(yearly[:4], [-1.4086e-03, -6.9948e-04, -3.4735e-04, 2.0023e-01],
                               rtol=1e-4)  # fmt: skip


@pytest.mark.slow
def test_time_page_force_basis_example_prints_what_it_says():
    """docs/time.md, the adaptive ECFM and the force bases: the estimate nears 0.7 as rtol
    shrinks; a smooth source is met with a smaller L2 error by hats and Gaussians."""
    text = (DOCS / "time.md").read_text()
    code = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "force_basis=" in b)
    ns = {}
    exec(compile(code, "time.md", "exec"), ns)
    est, l2 = ns["adaptive"], ns["l2"]
    assert abs(est[1e-6] - 0.7) < abs(est[1e-4] - 0.7) / 5
    np.testing.assert_allclose([est[1e-4], est[1e-6]], [0.699263, 0.699935], atol=2e-6)
    np.testing.assert_allclose(
        [l2["constant"], l2["linear"], l2["{'rbf': 1.0}"]], [0.0569, 0.0148, 0.0161], atol=1e-4
    )
