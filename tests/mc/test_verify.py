"""Monte Carlo verification of a PCE surrogate (ecfm_uq.mc.verify, issue 38 item 3)."""

import re
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from ecfm_uq.chaos import PolynomialChaosExpansion, fit_pce
from ecfm_uq.mc import VerificationReport, mc_moments, verify

matplotlib.use("Agg")

BOUNDS = [(-1.0, 2.0), (0.0, 1.0)]
ISHIGAMI = [(-np.pi, np.pi)] * 3


def poly(x):
    """x0^2 + 2 x0 x1 + x1^3 on U(-1, 2) x U(0, 1)."""
    return x[0] ** 2 + 2.0 * x[0] * x[1] + x[1] ** 3


def poly_shifted(x):
    return poly(x) + x[0]


def poly_vector(x):
    return np.array([poly(x), x[0] - x[1], 3.0 * x[1] ** 2])


def ishigami(x, a=7.0, b=0.1):
    return np.sin(x[0]) + a * np.sin(x[1]) ** 2 + b * x[2] ** 4 * np.sin(x[0])


def ishigami_a6(x):
    return ishigami(x, a=6.0)


def fails_above(x):
    if x[0] > 1.5:
        raise ZeroDivisionError("solver broke down")
    return poly(x)


def poly_three_inputs(x):
    return poly(x) + x[2]


def poly_nan(x):
    return np.nan if x[1] > 0.8 else poly(x)


def _poly_moments():
    """Closed-form mean and variance of poly under U(-1, 2) x U(0, 1)."""
    # raw moments of U(-1, 2): E x^k = (2^{k+1} - (-1)^{k+1}) / (3 (k + 1)); of U(0, 1): 1/(k + 1)
    a = {k: (2.0 ** (k + 1) - (-1.0) ** (k + 1)) / (3.0 * (k + 1)) for k in range(5)}
    b = {k: 1.0 / (k + 1) for k in range(7)}
    mean = a[2] + 2 * a[1] * b[1] + b[3]
    second = a[4] + 4 * a[2] * b[2] + b[6] + 4 * a[3] * b[1] + 2 * a[2] * b[3] + 4 * a[1] * b[4]
    return mean, second - mean**2


@pytest.fixture(scope="module")
def poly_pce():
    return fit_pce(poly, BOUNDS, method="quadrature", order=3)


@pytest.fixture(scope="module")
def ishigami_pce():
    return fit_pce(ishigami, ISHIGAMI, method="quadrature", order=12)


def test_correct_polynomial_surrogate_has_small_z_and_zero_holdout(poly_pce):
    mean, var = _poly_moments()
    rep = verify(poly_pce, poly, 4000, seed=3)
    assert isinstance(rep, VerificationReport)
    np.testing.assert_allclose([rep.pce_mean, rep.pce_variance], [mean, var], rtol=1e-12)
    assert abs(rep.mean_z) < 4 and abs(rep.variance_z) < 4
    assert rep.holdout_error < 1e-10
    # the Monte Carlo side is the sample statistics of the model at fresh samples
    y = np.array([poly(x) for x in rep.samples])
    np.testing.assert_array_equal(rep.model_values, y)
    mom = mc_moments(y)
    assert rep.mean_z == pytest.approx((mean - y.mean()) / mom.se_mean, rel=1e-9)
    assert rep.variance_z == pytest.approx((var - y.var(ddof=1)) / mom.se_var, rel=1e-9)
    assert np.all((rep.samples[:, 0] >= -1) & (rep.samples[:, 0] <= 2))
    np.testing.assert_allclose(rep.pce_quantiles, np.quantile(y, [0.05, 0.5, 0.95]), rtol=1e-10)
    np.testing.assert_array_equal(rep.model_quantiles, np.quantile(y, [0.05, 0.5, 0.95]))


def test_correct_ishigami_surrogate_passes(ishigami_pce):
    a, b = 7.0, 0.1
    var = a**2 / 8 + b * np.pi**4 / 5 + b**2 * np.pi**8 / 18 + 0.5
    rep = verify(ishigami_pce, ishigami, 4000, seed=11)
    np.testing.assert_allclose([rep.pce_mean, rep.pce_variance], [3.5, var], rtol=1e-4)
    assert rep.max_abs_z < 4
    assert rep.holdout_error < 1e-3


def test_wrong_surrogate_is_flagged(poly_pce, ishigami_pce):
    rep = verify(poly_pce, poly_shifted, 8000, seed=3)  # bias 0.5, se about 0.03
    assert abs(rep.mean_z) > 10 and rep.holdout_error > 0.1
    rep = verify(ishigami_pce, ishigami_a6, 8000, seed=11)  # a = 6 against a PCE of a = 7
    assert rep.max_abs_z > 10 or rep.holdout_error > 0.1
    assert rep.holdout_error > 0.1


def test_convergence_falls_as_root_n_for_a_correct_surrogate_and_stalls_for_a_wrong_one(
    poly_pce,
):
    good = verify(poly_pce, poly, 20000, seed=5)
    bad = verify(poly_pce, poly_shifted, 20000, seed=5)
    assert list(good.sizes) == sorted(good.sizes) and good.sizes[0] == 10
    assert np.all(good.n_batches == 20000 // good.sizes)
    assert -0.75 < good.convergence_slope < -0.3
    assert bad.convergence_slope > -0.2
    # the error of the largest size is the bias |E g - E pce| / |E pce| = 0.5 / mean
    mean, _ = _poly_moments()
    assert bad.convergence_mean_error[-1] == pytest.approx(0.5 / mean, rel=0.1)
    assert good.convergence_mean_error[-1] < 0.15 * bad.convergence_mean_error[-1]
    # running error: the mean of the first k samples against the surrogate's
    k = int(good.sizes[2])
    assert good.running_mean_error[2] == pytest.approx(
        abs(good.model_values[:k].mean() - mean) / mean, rel=1e-9
    )


def test_vector_outputs_executor_and_given_sizes(poly_pce):
    pce = fit_pce(poly_vector, BOUNDS, method="quadrature", order=3)
    rep = verify(pce, poly_vector, 600, seed=2, sizes=[10, 50, 100])
    assert rep.mean_z.shape == rep.holdout_error.shape == rep.pce_mean.shape == (3,)
    assert rep.pce_quantiles.shape == rep.model_quantiles.shape == (3, 3)
    assert np.all(np.abs(rep.mean_z) < 4) and np.all(np.abs(rep.variance_z) < 4)
    assert rep.convergence_mean_error.shape == (3,)
    with ThreadPoolExecutor(2) as ex:
        threaded = verify(pce, poly_vector, 600, seed=2, sizes=[10, 50, 100], executor=ex)
    np.testing.assert_array_equal(threaded.model_values, rep.model_values)
    np.testing.assert_array_equal(threaded.mean_z, rep.mean_z)
    with pytest.raises(ValueError, match="`sizes`"):
        verify(pce, poly_vector, 100, seed=2, sizes=[1000])


def test_germ_surrogate_with_inputs(poly_pce):
    germ_pce = PolynomialChaosExpansion(poly_pce.basis, poly_pce.coefficients)
    rep = verify(germ_pce, poly, 2000, seed=4, inputs=BOUNDS)
    assert rep.holdout_error < 1e-10 and rep.max_abs_z < 4
    same = verify(poly_pce, poly, 2000, seed=4, inputs=BOUNDS)
    np.testing.assert_array_equal(same.model_values, rep.model_values)


def test_summary_and_plots(poly_pce):
    rep = verify(poly_pce, poly, 500, seed=1)
    text = rep.summary()
    assert "n = 500" in text and "max |z|" in text and "q95% model" in text
    ax = rep.plot_parity()
    assert ax.get_xlabel() == "model(x)" and ax.get_ylabel() == "PCE(x)"
    assert len(ax.lines[0].get_xdata()) == 500
    ax = rep.plot_convergence()
    assert ax.get_xlabel() == "samples n" and ax.get_xscale() == "log"
    axes = rep.plot()
    assert len(axes) == 2 and axes[0].figure is axes[1].figure
    assert axes[0].get_xlabel() == "model(x)" and axes[1].get_xlabel() == "samples n"
    vec = verify(fit_pce(poly_vector, BOUNDS, method="quadrature", order=3), poly_vector, 50)
    assert "y[2]" in vec.summary()
    short = vec.summary(max_rows=2)
    assert (
        "(the 2 components" in short
        and sum(ln.startswith("      y[") for ln in short.splitlines()) == 4
    )


# -- bad input -------------------------------------------------------------------------
def test_n_below_two_is_refused(poly_pce):
    with pytest.raises(ValueError, match="`n`"):
        verify(poly_pce, poly, 1)
    with pytest.raises(TypeError, match="`pce`"):
        verify(poly, poly, 10)
    with pytest.raises(TypeError, match="`model` must be picklable"):
        verify(poly_pce, lambda x: poly(x), 10, workers=2)


def test_inputs_other_than_the_surrogates_are_refused(poly_pce):
    with pytest.raises(ValueError, match="`inputs` has 3 inputs but the surrogate `pce` has 2"):
        verify(poly_pce, poly, 10, inputs=[(0, 1)] * 3)
    with pytest.raises(ValueError, match="`inputs` .* differ from the surrogate's own"):
        verify(poly_pce, poly, 10, inputs=[(0.0, 1.0), (0.0, 1.0)])


def test_model_of_other_dimension_is_refused(poly_pce):
    with pytest.raises(ValueError, match="sample 0 .*`pce` has 2 input") as info:
        verify(poly_pce, poly_three_inputs, 10, seed=0)
    assert isinstance(info.value.__cause__, IndexError)
    with pytest.raises(ValueError, match="`model` returns outputs of shape \\(3,\\)"):
        verify(poly_pce, poly_vector, 10, seed=0)


def test_model_raising_is_wrapped_with_its_sample(poly_pce):
    x0 = np.random.default_rng(7).random((50, 2))[:, 0] * 3.0 - 1.0
    first = int(np.argmax(x0 > 1.5))
    with pytest.raises(RuntimeError, match=f"ZeroDivisionError at sample {first} ") as info:
        verify(poly_pce, fails_above, 50, seed=7)
    assert isinstance(info.value.__cause__, ZeroDivisionError)
    with ProcessPoolExecutor(1) as ex, pytest.raises(RuntimeError, match=f"sample {first} "):
        verify(poly_pce, fails_above, 50, seed=7, executor=ex)
    with pytest.raises(ValueError, match="NaN or inf at sample"):
        verify(poly_pce, poly_nan, 50, seed=7)


@pytest.mark.slow  # the page's sparse fit (300 runs, adaptive degree) takes seconds
def test_docs_example_runs_and_prints_what_the_page_says():
    text = (Path(__file__).resolve().parents[2] / "docs" / "verify.md").read_text()
    code = re.findall(r"```python\n(.*?)```", text, re.S)[0]
    ns = {}
    exec(compile(code.replace("print(report.summary())", ""), "verify.md", "exec"), ns)
    rep = ns["report"]
    assert rep.max_abs_z < 4 and rep.holdout_error < 1e-6
    assert f"max |z| = {rep.max_abs_z:.2f}" in text
    assert f"MC error slope in n = {rep.convergence_slope:.2f}" in text
