"""The rules of ``ecfm_uq.chaos.quadrature`` against the closed-form moments of their laws.

An n-point Gauss rule integrates every polynomial of degree <= 2n - 1 against its law
exactly; Clenshaw-Curtis with n points every one of degree <= n - 1. The moments are
the laws' closed forms (scipy.stats' numerical ``moment`` is off by 2e-11 at degree 12).
"""

import numpy as np
import pytest
from scipy import special, stats

from ecfm_uq.chaos import Germ, OwnGerm
from ecfm_uq.chaos.quadrature import (
    clenshaw_curtis,
    gauss_golub_welsch,
    gauss_hermite,
    gauss_jacobi,
    gauss_laguerre,
    gauss_legendre,
)


def uniform01(k):
    return 1.0 / (k + 1)


def uniform11(k):
    return 0.0 if k % 2 else 1.0 / (k + 1)


def normal(k):
    return 0.0 if k % 2 else float(special.factorial2(k - 1)) if k else 1.0


def gamma(s):
    return lambda k: float(np.exp(special.gammaln(s + k) - special.gammaln(s)))


def beta(a, b):
    return lambda k: float(np.prod([(a + r) / (a + b + r) for r in range(k)]))


def _check_moments(x, w, moment, degree, rtol=1e-11):
    assert np.all(w > 0)
    assert np.sum(w) == pytest.approx(1.0, rel=1e-14)
    for k in range(degree + 1):
        # round-off scale: the sum of the terms' magnitudes (odd moments vanish by cancellation)
        scale = w @ np.abs(x) ** k
        assert w @ x**k == pytest.approx(moment(k), rel=rtol, abs=1e-13 * scale), k


@pytest.mark.parametrize("n", [1, 2, 5, 9])
def test_gauss_rules_integrate_their_laws_moments_to_degree_2n_minus_1(n):
    _check_moments(*gauss_legendre(n), uniform01, 2 * n - 1)
    _check_moments(*gauss_hermite(n), normal, 2 * n - 1)
    _check_moments(*gauss_laguerre(n, 2.5), gamma(2.5), 2 * n - 1)
    _check_moments(*gauss_jacobi(n, 2.0, 3.5), beta(2.0, 3.5), 2 * n - 1)


@pytest.mark.parametrize("n", [1, 3, 7])
def test_golub_welsch_of_the_legendre_recurrence_is_the_gauss_legendre_rule(n):
    # monic Legendre on [-1, 1]: a_k = 0, b_k = k^2 / (4 k^2 - 1)
    k = np.arange(n, dtype=float)
    a, b = np.zeros(n), np.r_[1.0, k[1:] ** 2 / (4 * k[1:] ** 2 - 1)]
    x, w = gauss_golub_welsch(a, b)
    t, v = special.roots_legendre(n)
    np.testing.assert_allclose(x, t, atol=1e-14)
    np.testing.assert_allclose(w, v / 2, rtol=1e-13)
    _check_moments(x, w, uniform11, 2 * n - 1)


@pytest.mark.parametrize("n", [1, 2, 3, 5, 9, 17])
def test_clenshaw_curtis_is_nested_and_exact_to_degree_n_minus_1(n):
    x, w = clenshaw_curtis(n)
    _check_moments(x, w, uniform01, n - 1, rtol=1e-12)
    if n > 2:
        coarse, _ = clenshaw_curtis((n - 1) // 2 + 1)
        assert np.all(np.isin(np.round(coarse, 14), np.round(x, 14)))


def test_the_germs_rules_are_the_module_rules():
    for germ, rule in [
        (Germ("legendre"), gauss_legendre),
        (Germ("hermite"), gauss_hermite),
        (Germ("laguerre", shape=2.5), lambda n: gauss_laguerre(n, 2.5)),
        (Germ("jacobi", a=2.0, b=3.5), lambda n: gauss_jacobi(n, 2.0, 3.5)),
    ]:
        for got, want in zip(germ.gauss(6), rule(6), strict=True):
            np.testing.assert_array_equal(got, want)
    own = OwnGerm(stats.triang(0.3))
    x, w = own.gauss(5)
    # the own law's rule integrates the standardised law's moments (mean 0, variance 1)
    assert w @ x == pytest.approx(0.0, abs=1e-12)
    assert w @ x**2 == pytest.approx(1.0, rel=1e-12)
    skew = stats.triang(0.3).stats(moments="s")
    assert w @ x**3 == pytest.approx(float(skew), rel=1e-10, abs=1e-12)
