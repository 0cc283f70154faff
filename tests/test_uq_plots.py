"""The plots UQ users expect (issue 38, item 4): PCE and sampled Sobol indices, profiles."""

import matplotlib
import numpy as np
import pytest
from matplotlib.axes import Axes
from scipy.interpolate import PchipInterpolator

from ecfm_uq.chaos import ChaosBasis, PolynomialChaosExpansion, UniformInputs, fit_pce
from ecfm_uq.inverse import ModelProblem, fit, profile_likelihood
from ecfm_uq.mc import sobol_indices

matplotlib.use("Agg")


def linear(X):
    X = np.atleast_2d(X)
    return X[:, 0] + 2.0 * X[:, 1]


def _bars(ax):
    return [p for p in ax.patches if isinstance(p, matplotlib.patches.Rectangle)]


def test_pce_plot_sobol_bars_are_the_indices_with_input_names():
    # y = 1 + 2 L1(w1) + L1(w2): S = T = (0.8, 0.2), no interactions
    inputs = UniformInputs([(0, 1), (0, 1)], names=["load", "stiffness"])
    pce = PolynomialChaosExpansion(ChaosBasis(1, dim=2), [1.0, 2.0, 1.0], inputs)
    ax = pce.plot_sobol()
    assert isinstance(ax, Axes)
    bars = _bars(ax)
    assert len(bars) == 4
    np.testing.assert_allclose([b.get_height() for b in bars], [0.8, 0.2, 0.8, 0.2])
    assert [t.get_text() for t in ax.get_xticklabels()] == ["load", "stiffness"]
    assert ax.get_ylabel() == "Sobol index"
    ax = PolynomialChaosExpansion(pce.basis, pce.coefficients).plot_sobol(names=["a", "b"])
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b"]
    with pytest.raises(ValueError, match="`names` must hold 2 names"):
        pce.plot_sobol(names=["a"])


def test_pce_plot_sobol_of_a_vector_output_needs_a_component():
    def f(x):
        return np.array([x[0] + x[1] ** 2, x[2]])

    pce = fit_pce(f, [(0, 1)] * 3, method="quadrature", order=2)
    fig, ax = matplotlib.pyplot.subplots()
    assert pce.plot_sobol(ax=ax, component=1) is ax
    np.testing.assert_allclose([b.get_height() for b in _bars(ax)], [0, 0, 1, 0, 0, 1], atol=1e-12)
    assert [t.get_text() for t in ax.get_xticklabels()] == ["x0", "x1", "x2"]
    with pytest.raises(ValueError, match="`component`"):
        pce.plot_sobol()


def test_sampled_sobol_plot_has_the_intervals_as_error_bars():
    res = sobol_indices(linear, [(0, 1), (0, 1)], 256, seed=0, vectorized=True)
    ax = res.plot(names=["a", "b"])
    assert isinstance(ax, Axes)
    bars = _bars(ax)
    assert len(bars) == 4
    np.testing.assert_allclose(
        [b.get_height() for b in bars], np.concatenate([res.first_order, res.total])
    )
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b"]
    # two error-bar containers whose segments span the intervals
    segs = [c.lines[2][0].get_segments() for c in ax.containers if hasattr(c, "has_yerr")]
    assert len(segs) == 2
    pairs = [(res.first_order_interval, res.first_order), (res.total_interval, res.total)]
    for seg, (iv, est) in zip(segs, pairs, strict=True):
        np.testing.assert_allclose([s[:, 1].min() for s in seg], np.minimum(iv[0], est))
        np.testing.assert_allclose([s[:, 1].max() for s in seg], np.maximum(iv[1], est))
        assert np.all(iv[1] - iv[0] > 0.005)  # visible bars, not zero-length ones
    assert "95 %" in ax.get_title()


X = np.linspace(0, 3, 12)


def _decay(e):
    return e[0] * np.exp(-e[1] * X)


@pytest.fixture(scope="module")
def named_fit():
    rng = np.random.default_rng(3)
    y = _decay([2.0, 0.7]) + 0.05 * rng.standard_normal(12)
    return fit(ModelProblem(_decay, y, names=["amplitude", "rate"]), [1.0, 1.0])


def test_profile_plot_names_the_axes_and_draws_a_smooth_curve_through_the_points(named_fit):
    summary = profile_likelihood(named_fit, 0.95)
    assert summary.names == ("amplitude", "rate")
    axes = summary.plot()
    assert len(axes) == 2 and all(isinstance(a, Axes) for a in axes)
    assert [a.get_xlabel() for a in axes] == ["amplitude", "rate"]
    for a, i in zip(axes, sorted(summary.profiles), strict=True):
        prof = summary.profiles[i]
        curve, points = a.lines[0], a.lines[1]
        np.testing.assert_array_equal(points.get_xdata(), prof.values)
        np.testing.assert_array_equal(points.get_ydata(), 2 * prof.delta)
        t, y = curve.get_xdata(), curve.get_ydata()
        assert len(t) > 5 * len(prof.values)  # smooth, not one segment per point
        np.testing.assert_allclose(y, PchipInterpolator(prof.values, 2 * prof.delta)(t))
        # through every computed point, and monotone between neighbours (no overshoot)
        np.testing.assert_allclose(np.interp(prof.values, t, y), 2 * prof.delta, atol=1e-12)
        k = np.searchsorted(prof.values, t, side="right").clip(1, len(prof.values) - 1)
        lo = np.minimum(2 * prof.delta[k - 1], 2 * prof.delta[k])
        hi = np.maximum(2 * prof.delta[k - 1], 2 * prof.delta[k])
        assert np.all((y >= lo - 1e-12) & (y <= hi + 1e-12))
    axes = summary.plot(names=["A", "k"])
    assert [a.get_xlabel() for a in axes] == ["A", "k"]
    fig, ax = matplotlib.pyplot.subplots(1, 2)
    assert list(summary.plot(ax=ax)) == list(ax)
    one = profile_likelihood(named_fit, 0.95, which=[1])
    (ax,) = one.plot()
    assert ax.get_xlabel() == "rate"
