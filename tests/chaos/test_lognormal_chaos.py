"""Chaos-layer hooks for a lognormal coefficient in Hermite chaos (Galerkin side).

a(xi) = exp(m + b . xi) has exact Hermite coefficients; its Galerkin coupling
E[a Psi Psi^T] = sum_a a_a T[a] with T = coupling_tensor(coef_basis, basis). Truths:
moments of the lognormal, Gauss-Hermite quadrature of the coupling at many points, and
the identity coupling_tensor(basis, basis) == expectation_tensor(basis, 3).
"""

import numpy as np
import pytest

from ecfm_uq.chaos import (
    ChaosBasis,
    Germ,
    coupling_tensor,
    expectation_tensor,
    lognormal_coefficients,
    weighted_gram,
)

B = np.array([0.4, -0.25])


def test_lognormal_coefficients_reproduce_the_lognormal_moments():
    coef = ChaosBasis(14, dim=2, germ="hermite")
    a = lognormal_coefficients(coef, B, mean=0.1)
    s2 = B @ B
    assert a[0] == pytest.approx(np.exp(0.1 + s2 / 2), rel=1e-15)  # E[a]
    # Var[a] = exp(2m + s^2)(exp(s^2) - 1): the truncated sum converges to it
    assert np.sum(a[1:] ** 2) == pytest.approx(np.exp(0.2 + s2) * np.expm1(s2), rel=1e-12)
    # against a Gauss-Hermite projection of exp(m + b xi)
    x, w = coef.quadrature(30)
    proj = (coef.evaluate(x) * w[:, None]).T @ np.exp(0.1 + x @ B)
    np.testing.assert_allclose(a, proj, atol=1e-14)


def test_lognormal_coefficients_at_many_points_broadcast():
    coef = ChaosBasis(3, dim=2, germ="hermite")
    b = np.stack([B, 2 * B, 0 * B])
    a = lognormal_coefficients(coef, b, mean=np.array([0.0, 0.5, -1.0]))
    assert a.shape == (3, coef.size)
    np.testing.assert_allclose(a[1], lognormal_coefficients(coef, 2 * B, 0.5))
    np.testing.assert_allclose(a[2], np.exp(-1.0) * np.eye(coef.size)[0])


def test_coupling_tensor_is_the_triple_product_tensor_on_one_basis():
    for germ in ("hermite", Germ("laguerre", shape=2.0), "legendre"):
        basis = ChaosBasis(3, dim=2, germ=germ)
        np.testing.assert_array_equal(coupling_tensor(basis, basis), expectation_tensor(basis, 3))


def test_lognormal_coupling_truncation_table():
    # E[exp(b xi) Psi Psi^T] from the coefficient's chaos of order q, against quadrature
    basis = ChaosBasis(3, dim=2, germ="hermite")
    exact = weighted_gram(basis, lambda w: np.exp(w @ B), n_points=40)
    errors = []
    for q in range(1, 11):
        coef = ChaosBasis(q, dim=2, germ="hermite")
        G = np.einsum("a,aij->ij", lognormal_coefficients(coef, B), coupling_tensor(coef, basis))
        errors.append(np.abs(G - exact).max() / np.abs(exact).max())
    errors = np.array(errors)
    assert np.all(np.diff(errors[:6]) < 0)  # monotone convergence up to q = 2p
    first = int(np.argmax(errors < 1e-3)) + 1
    assert first == 5  # order at which the coupling's truncation error falls below 1e-3
    # terms of order > 2p are orthogonal to every product of two order-p terms: exact
    assert np.all(errors[5:] < 1e-14)


def test_bad_coefficient_bases():
    with pytest.raises(ValueError, match="Hermite"):
        lognormal_coefficients(ChaosBasis(2, dim=2), B)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        lognormal_coefficients(ChaosBasis(2, dim=2, germ="hermite"), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="share dim and germs"):
        coupling_tensor(ChaosBasis(2, germ="hermite"), ChaosBasis(2))
