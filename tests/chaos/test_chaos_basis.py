"""ChaosBasis and Gauss-Legendre quadrature: identities, independent references, bad input."""

import math

import numpy as np
import pytest
from numpy.polynomial import legendre as npleg

from ecfm_uq.chaos import ChaosBasis, gauss_legendre


def gram_by_quadrature(basis, n_points=None):
    nodes, weights = basis.quadrature(n_points)
    Psi = basis.evaluate(nodes)
    return Psi.T @ (Psi * weights[:, None])


# --- quadrature ------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 5, 16, 40])
def test_gauss_legendre_integrates_monomials_exactly(n):
    x, w = gauss_legendre(n)
    assert x.shape == w.shape == (n,)
    assert np.all((x > 0) & (x < 1)) and np.all(np.diff(x) > 0) and np.all(w > 0)
    assert w.sum() == pytest.approx(1.0, abs=1e-15)
    for m in range(2 * n):  # exact up to degree 2n - 1
        assert w @ x**m == pytest.approx(1.0 / (m + 1), rel=1e-13, abs=1e-15)


def test_gauss_legendre_is_not_exact_beyond_its_degree():
    x, w = gauss_legendre(3)
    assert abs(w @ x**6 - 1.0 / 7.0) > 1e-6


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_basis_quadrature_is_a_tensor_rule(dim):
    basis = ChaosBasis(4, dim=dim)
    nodes, weights = basis.quadrature()
    n1 = math.ceil((3 * 4 + 1) / 2) + 1
    assert nodes.shape == (n1**dim, dim) and weights.shape == (n1**dim,)
    assert weights.sum() == pytest.approx(1.0, abs=1e-14)
    # E[omega_1^2 omega_dim^3] = 1/3 * 1/4 (or 1/6 in one variable).
    g = nodes[:, 0] ** 2 * nodes[:, -1] ** 3
    want = 1 / 6 if dim == 1 else 1 / 12
    assert weights @ g == pytest.approx(want, rel=1e-14)
    nodes5, weights5 = basis.quadrature(n_points=5)
    assert nodes5.shape == (5**dim, dim)


# --- multi-indices ---------------------------------------------------------------------


@pytest.mark.parametrize("order,dim", [(0, 1), (5, 1), (3, 2), (4, 3), (2, 5)])
def test_total_degree_indices(order, dim):
    basis = ChaosBasis(order, dim=dim)
    alpha = basis.indices
    assert basis.size == len(basis) == math.comb(order + dim, dim) == alpha.shape[0]
    assert alpha.shape == (basis.size, dim) and alpha.dtype.kind == "i"
    assert np.all(alpha[0] == 0)
    assert np.all(alpha.sum(axis=1) <= order) and np.all(alpha >= 0)
    assert len({tuple(a) for a in alpha}) == basis.size
    assert np.all(np.diff(alpha.sum(axis=1)) >= 0)  # graded


@pytest.mark.parametrize("order,dim", [(0, 2), (3, 1), (2, 2), (3, 3)])
def test_tensor_indices(order, dim):
    basis = ChaosBasis(order, dim=dim, index_set="tensor")
    alpha = basis.indices
    assert basis.size == (order + 1) ** dim
    assert np.all(alpha.max(axis=1) <= order)
    assert len({tuple(a) for a in alpha}) == basis.size
    assert np.all(alpha[0] == 0) and np.all(np.diff(alpha.sum(axis=1)) >= 0)


def test_indices_documented_order_and_read_only():
    basis = ChaosBasis(2, dim=2)
    assert basis.indices.tolist() == [[0, 0], [1, 0], [0, 1], [2, 0], [1, 1], [0, 2]]
    with pytest.raises(ValueError):
        basis.indices[0, 0] = 3


def test_one_dimensional_indices_are_the_degrees():
    assert ChaosBasis(7).indices.ravel().tolist() == list(range(8))


# --- evaluation ------------------------------------------------------------------------


@pytest.mark.parametrize("normalized", [True, False])
def test_evaluate_matches_numpy_legendre(normalized):
    order = 25
    omega = np.linspace(0.0, 1.0, 41)
    Psi = ChaosBasis(order, normalized=normalized).evaluate(omega)
    for n in range(order + 1):
        c = np.zeros(n + 1)
        c[n] = 1.0
        ref = npleg.legval(2 * omega - 1, c)
        if normalized:
            ref *= math.sqrt(2 * n + 1)
        np.testing.assert_allclose(Psi[:, n], ref, rtol=1e-12, atol=1e-12)


def test_evaluate_multivariate_is_product_of_univariate():
    rng = np.random.default_rng(3)
    omega = rng.random((20, 3))
    basis = ChaosBasis(3, dim=3)
    one = ChaosBasis(3).evaluate
    Psi = basis.evaluate(omega)
    for k, a in enumerate(basis.indices):
        ref = np.prod([one(omega[:, d])[:, a[d]] for d in range(3)], axis=0)
        np.testing.assert_allclose(Psi[:, k], ref, rtol=1e-14, atol=1e-14)


def test_evaluate_shapes_and_psi0():
    b1 = ChaosBasis(3)
    assert b1.evaluate([0.1, 0.5]).shape == (2, 4)
    np.testing.assert_array_equal(b1.evaluate([[0.1], [0.5]]), b1.evaluate([0.1, 0.5]))
    np.testing.assert_array_equal(b1(np.array([0.3])), b1.evaluate([0.3]))
    b2 = ChaosBasis(2, dim=2)
    Psi = b2.evaluate(np.full((5, 2), 0.25))
    assert Psi.shape == (5, 6)
    np.testing.assert_array_equal(Psi[:, 0], 1.0)
    assert b2.evaluate(np.empty((0, 2))).shape == (0, 6)


def test_order_zero_is_the_deterministic_case():
    basis = ChaosBasis(0)
    assert basis.size == 1
    np.testing.assert_array_equal(basis.evaluate([0.0, 0.3, 1.0]), np.ones((3, 1)))
    np.testing.assert_array_equal(basis.norms2, [1.0])


# --- orthonormality --------------------------------------------------------------------


@pytest.mark.parametrize("order", [0, 1, 2, 5, 10, 20, 30])
def test_orthonormality_1d(order):
    G = gram_by_quadrature(ChaosBasis(order))
    np.testing.assert_allclose(G, np.eye(order + 1), atol=1e-12)


@pytest.mark.parametrize(
    "order,dim,index_set", [(4, 2, "total"), (3, 3, "total"), (3, 2, "tensor"), (2, 3, "tensor")]
)
@pytest.mark.parametrize("normalized", [True, False])
def test_orthogonality_multivariate(order, dim, index_set, normalized):
    basis = ChaosBasis(order, dim=dim, index_set=index_set, normalized=normalized)
    G = gram_by_quadrature(basis)
    np.testing.assert_allclose(G, np.diag(basis.norms2), atol=1e-12)
    if normalized:
        np.testing.assert_array_equal(basis.norms2, 1.0)
    else:
        ref = [np.prod([1.0 / (2 * a + 1) for a in alpha]) for alpha in basis.indices]
        np.testing.assert_allclose(basis.norms2, ref, rtol=1e-15)


def test_equality_and_repr():
    assert ChaosBasis(2, dim=2) == ChaosBasis(2, 2, "total", True)
    assert ChaosBasis(2) != ChaosBasis(2, normalized=False)
    assert len({ChaosBasis(2), ChaosBasis(2)}) == 1
    assert "P = 6" in repr(ChaosBasis(2, dim=2))


# --- bad input -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs,exc,match",
    [
        ({"order": -1}, ValueError, "order"),
        ({"order": 2.0}, TypeError, "order"),
        ({"order": "3"}, TypeError, "order"),
        ({"order": True}, TypeError, "order"),
        ({"order": 2, "dim": 0}, ValueError, "dim"),
        ({"order": 2, "dim": 1.5}, TypeError, "dim"),
        ({"order": 2, "index_set": "hyperbolic"}, ValueError, "index_set"),
        ({"order": 2, "index_set": None}, TypeError, "index_set"),
        ({"order": 2, "normalized": "yes"}, TypeError, "normalized"),
        ({"order": 2, "degree": 3}, TypeError, "degree"),
        ({"order": 200, "dim": 6}, ValueError, "order"),
    ],
)
def test_basis_bad_input(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        ChaosBasis(**kwargs)


@pytest.mark.parametrize(
    "omega,match",
    [
        ([0.1, np.nan], "omega"),
        ([0.1, np.inf], "omega"),
        ([-0.5, 0.5], r"omega.*\[0, 1\]"),
        ([0.5, 1.5], r"omega.*\[0, 1\]"),
        (np.zeros((3, 2)), r"omega.*shape"),
        (np.zeros((2, 2, 1)), r"omega.*shape"),
    ],
)
def test_evaluate_bad_omega(omega, match):
    with pytest.raises(ValueError, match=match):
        ChaosBasis(3).evaluate(omega)


def test_evaluate_bad_omega_multivariate():
    basis = ChaosBasis(2, dim=2)
    with pytest.raises(ValueError, match=r"omega.*\(n, 2\)"):
        basis.evaluate([0.1, 0.2])
    with pytest.raises(TypeError, match="omega"):
        basis.evaluate("abc")


@pytest.mark.parametrize(
    "n,exc", [(0, ValueError), (-3, ValueError), (2.5, TypeError), (None, TypeError)]
)
def test_gauss_legendre_bad_n(n, exc):
    with pytest.raises(exc, match="`n`"):
        gauss_legendre(n)


def test_quadrature_bad_n_points():
    basis = ChaosBasis(2, dim=2)
    with pytest.raises(ValueError, match="n_points"):
        basis.quadrature(0)
    with pytest.raises(TypeError, match="n_points"):
        basis.quadrature(3.0)
    with pytest.raises(ValueError, match="n_points"):
        ChaosBasis(1, dim=8).quadrature(100)
    with pytest.raises(TypeError):
        basis.quadrature(n=3)
