"""``fit_pce(..., options=)``: method settings checked by name; the v0.4 keywords deprecated.

The options spelling must give the very numbers of the keyword spelling (bit for bit), a
name the method does not read must be refused before the model runs, and each old
keyword must warn with the spelling that replaces it.
"""

import warnings

import numpy as np
import pytest

from ecfm_uq.chaos import fit_pce
from ecfm_uq.chaos.pce_options import METHOD_OPTIONS

BOUNDS = [(0.0, 1.0), (-1.0, 1.0)]


def model(x):
    return np.exp(0.3 * x[0]) + x[0] * x[1] ** 2


def never(x):
    raise AssertionError("the model ran before the options were checked")


@pytest.mark.parametrize("method", sorted(METHOD_OPTIONS))
def test_unknown_option_is_refused_before_the_model_runs_naming_the_valid_ones(method):
    with pytest.raises(TypeError) as info:
        fit_pce(never, BOUNDS, method, options={"q_nrom": 0.5})
    msg = str(info.value)
    assert "q_nrom" in msg and f"method={method!r}" in msg
    for name in METHOD_OPTIONS[method]:
        assert repr(name) in msg
    # an option another method reads is refused too (quadrature reads no q_norm)
    if "q_norm" not in METHOD_OPTIONS[method]:
        with pytest.raises(TypeError, match="q_norm"):
            fit_pce(never, BOUNDS, method, options={"q_norm": 0.5})


def test_options_must_be_a_mapping():
    with pytest.raises(TypeError, match="options"):
        fit_pce(never, BOUNDS, "lars", options=[("q_norm", 0.5)])


@pytest.mark.parametrize(
    ("method", "name", "value", "kw"),
    [
        ("lars", "q_norm", 0.75, dict(n_samples=60, seed=1)),
        ("lars", "design", "sobol", dict(n_samples=64, seed=1)),
        ("omp", "q_norm", 1.0, dict(n_samples=60, seed=1)),
        ("lstsq", "design", "halton", dict(order=3, n_samples=30, seed=2)),
        ("quadrature", "n_points", 5, dict(order=3)),
        ("smolyak", "rule", "clenshaw-curtis", dict(order=3)),
    ],
)
def test_old_keyword_warns_and_gives_the_numbers_of_options(method, name, value, kw):
    new = fit_pce(model, BOUNDS, method, options={name: value}, **kw)
    with pytest.warns(DeprecationWarning, match=rf"options=\{{'{name}': {value!r}\}}"):
        old = fit_pce(model, BOUNDS, method, **{name: value}, **kw)
    np.testing.assert_array_equal(np.asarray(old.coefficients), np.asarray(new.coefficients))
    # and the option acts: the default gives other numbers
    default = fit_pce(model, BOUNDS, method, **kw)
    c_new, c_def = np.asarray(new.coefficients), np.asarray(default.coefficients)
    assert c_new.shape != c_def.shape or not np.array_equal(c_new, c_def)


def test_old_keyword_a_method_does_not_read_warns_and_changes_nothing():
    ref = fit_pce(model, BOUNDS, "quadrature", order=3)
    with pytest.warns(DeprecationWarning, match="no effect with method='quadrature'"):
        old = fit_pce(model, BOUNDS, "quadrature", order=3, q_norm=0.5)
    np.testing.assert_array_equal(np.asarray(old.coefficients), np.asarray(ref.coefficients))


def test_an_option_given_twice_is_refused():
    with pytest.raises(TypeError, match="given twice"):
        fit_pce(never, BOUNDS, "lars", q_norm=0.5, options={"q_norm": 0.75})


def test_option_values_are_checked_naming_the_option_before_the_model_runs():
    with pytest.raises(ValueError, match=r"options\['design'\]"):
        fit_pce(never, BOUNDS, "lstsq", options={"design": "grid"})
    with pytest.raises(ValueError, match=r"options\['q_norm'\]"):
        fit_pce(never, BOUNDS, "lars", options={"q_norm": 1.5})
    with pytest.raises(ValueError, match=r"options\['compress_tol'\]"):
        fit_pce(never, BOUNDS, "omp", options={"compress_tol": 2.0})


def test_the_options_spelling_does_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        fit_pce(model, BOUNDS, "lars", n_samples=40, seed=0, options={"q_norm": 1.0})
