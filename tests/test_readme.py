"""The README's examples run as shown and print what they say (issue 38 item 7)."""

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.fixture(scope="module")
def readme():
    text = README.read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    ns = {}
    exec(compile("\n".join(blocks), "README.md", "exec"), ns)
    return text, ns


def test_readme_is_short_and_shows_code_first(readme):
    text, _ = readme
    lines = text.splitlines()
    assert len(lines) <= 100, len(lines)
    assert max(map(len, lines)) <= 100
    assert text.index("```python") < text.index("## Reproduce")


def test_readme_pce_matches_ishigami_closed_form(readme):
    pce, pi = readme[1]["pce"], np.pi
    V = 49 / 8 + 0.1 * pi**4 / 5 + 0.01 * pi**8 / 18 + 0.5
    V1, V2, V13 = (1 + 0.1 * pi**4 / 5) ** 2 / 2, 49 / 8, 0.01 * pi**8 * (1 / 18 - 1 / 50)
    np.testing.assert_allclose([pce.mean, pce.variance], [3.5, V], rtol=1e-8)
    np.testing.assert_allclose(pce.first_order(), [V1 / V, V2 / V, 0], atol=1e-8)
    np.testing.assert_allclose(pce.total(), [(V1 + V13) / V, V2 / V, V13 / V], atol=1e-8)


def test_readme_calibration_band_is_the_t_prediction_band(readme):
    """R's nls on Puromycin (treated): V_max 212.7, K_m 0.06412; the prediction band is
    y_hat -/+ t(0.975, n - p) sqrt(s^2 + g' C g), written here in numpy."""
    ns = readme[1]
    res, band, s = ns["res"], ns["band"], ns["s"]
    np.testing.assert_allclose(res.eps, [212.7, 0.06412], rtol=5e-4)
    V, K = res.eps
    G = np.column_stack([s / (K + s), -V * s / (K + s) ** 2])
    r = ns["rate"] - V * s / (K + s)
    n, p = s.size, 2
    s2 = r @ r / (n - p)
    C = s2 * np.linalg.inv(G.T @ G)
    half = stats.t.ppf(0.975, n - p) * np.sqrt(s2 + np.einsum("ij,jk,ik->i", G, C, G))
    yhat = V * s / (K + s)
    np.testing.assert_allclose(band.lower, yhat - half, rtol=1e-6)
    np.testing.assert_allclose(band.upper, yhat + half, rtol=1e-6)


def test_readme_ecfm_forces_make_lotka_volterra_meet_the_pelts(readme):
    """The README's ECFM: scipy's own integration of Lotka-Volterra plus the returned
    piecewise-constant forces passes through every one of the 21 counts (the exact match
    the forces are defined by), and the verdict says what the comment says."""
    from scipy.integrate import solve_ivp

    ns = readme[1]
    fit_, pelts = ns["lvfit"], ns["pelts"]
    forces = fit_.forces
    assert forces.values.shape == (20, 2) and list(forces.names) == ["u", "v"]
    y = np.array(fit_.eps[4:], dtype=float)
    for k, (t0, t1) in enumerate(forces.intervals):

        def forced(t, z, f=forces.values[k]):
            return np.add(ns["lotka_volterra"](t, z, fit_.eps), f)

        sol = solve_ivp(forced, (t0, t1), y, method="DOP853", rtol=1e-11, atol=1e-10)
        y = sol.y[:, -1]
        np.testing.assert_allclose(y, pelts[k + 1], rtol=1e-5, atol=1e-5)
    assert fit_.success and fit_.verdict.consistent
    assert abs(fit_.verdict.p_value - 0.087) < 0.0005
