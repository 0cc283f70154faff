"""Expectation tensors against closed forms, quadrature, chaospy and exact rationals."""

import itertools
import math
from fractions import Fraction

import numpy as np
import pytest
from numpy.polynomial import legendre as npleg

from ecfm_uq.chaos import (
    ChaosBasis,
    SparseTensor3,
    expectation_tensor,
    triple_product_1d,
    weighted_gram,
)

# --- exact references ------------------------------------------------------------------


def adams_neumann(i, j, k):
    """E[P_i P_j P_k] for Legendre polynomials and dx/2 on [-1, 1], as an exact Fraction."""
    if (i + j + k) % 2 or k > i + j or i > j + k or j > i + k:
        return Fraction(0)
    s = (i + j + k) // 2
    f = math.factorial
    first = Fraction(f(2 * s - 2 * i) * f(2 * s - 2 * j) * f(2 * s - 2 * k), f(2 * s + 1))
    second = Fraction(f(s), f(s - i) * f(s - j) * f(s - k))
    return first * second**2


def closed_form_table(p, normalized):
    t = np.zeros((p + 1,) * 3)
    for i, j, k in itertools.combinations_with_replacement(range(p + 1), 3):
        v = float(adams_neumann(i, j, k))
        if normalized:
            v *= math.sqrt((2 * i + 1) * (2 * j + 1) * (2 * k + 1))
        for perm in set(itertools.permutations((i, j, k))):
            t[perm] = v
    return t


def shifted_legendre_coefficients(n):
    """Integer monomial coefficients of P_n(2x - 1) (exact)."""
    return [(-1) ** (n + k) * math.comb(n, k) * math.comb(n + k, k) for k in range(n + 1)]


def exact_monomial_gram(p, m):
    """E[omega^m P_a(2 omega - 1) P_b(2 omega - 1)] for a, b <= p, as Fractions."""
    c = [shifted_legendre_coefficients(n) for n in range(p + 1)]
    return [
        [
            sum(
                Fraction(ca * cb, m + k + l + 1)
                for k, ca in enumerate(c[a])
                for l, cb in enumerate(c[b])
            )
            for b in range(p + 1)
        ]
        for a in range(p + 1)
    ]


def triple_by_tensor_quadrature(basis, n_points):
    nodes, weights = basis.quadrature(n_points)
    Psi = basis.evaluate(nodes)
    return np.einsum("q,qa,qb,qc->abc", weights, Psi, Psi, Psi)


# --- triple products -------------------------------------------------------------------


@pytest.mark.parametrize("order", [0, 1, 3, 8, 16, 24])
@pytest.mark.parametrize("normalized", [True, False])
def test_triple_product_matches_adams_neumann(order, normalized):
    T = expectation_tensor(ChaosBasis(order, normalized=normalized), 3)
    np.testing.assert_allclose(T, closed_form_table(order, normalized), rtol=0, atol=1e-12)


def test_triple_product_high_order_relative_accuracy():
    order = 40
    T = triple_product_1d(order)
    ref = closed_form_table(order, True)
    nz = ref != 0
    np.testing.assert_array_equal(T != 0, nz)
    np.testing.assert_allclose(T[nz], ref[nz], rtol=1e-13)


def test_triple_product_agrees_with_independent_quadrature():
    # numpy's Gauss rule and numpy's Legendre evaluation, nothing shared with the library.
    order = 20
    x, w = npleg.leggauss(40)
    V = np.stack(
        [npleg.legval(x, np.eye(order + 1)[n]) * math.sqrt(2 * n + 1) for n in range(order + 1)],
        axis=1,
    )
    ref = np.einsum("q,qi,qj,qk->ijk", w / 2, V, V, V)
    np.testing.assert_allclose(expectation_tensor(ChaosBasis(order), 3), ref, atol=1e-12)


@pytest.mark.parametrize(
    "order,dim,index_set", [(4, 2, "total"), (3, 3, "total"), (2, 2, "tensor"), (2, 3, "tensor")]
)
@pytest.mark.parametrize("normalized", [True, False])
def test_multivariate_triple_product_against_direct_quadrature(order, dim, index_set, normalized):
    basis = ChaosBasis(order, dim=dim, index_set=index_set, normalized=normalized)
    T = expectation_tensor(basis, 3)
    assert T.shape == (basis.size,) * 3
    np.testing.assert_allclose(T, triple_by_tensor_quadrature(basis, None), atol=1e-13)


def test_triple_product_is_symmetric_under_all_permutations():
    T = expectation_tensor(ChaosBasis(4, dim=2), 3)
    for perm in itertools.permutations(range(3)):
        np.testing.assert_array_equal(T, T.transpose(perm))


def test_rank_one_and_two():
    basis = ChaosBasis(3, dim=2, normalized=False)
    e = expectation_tensor(basis, 1)
    np.testing.assert_array_equal(e, np.eye(basis.size)[0])
    np.testing.assert_array_equal(expectation_tensor(basis, 2), np.diag(basis.norms2))
    np.testing.assert_array_equal(expectation_tensor(ChaosBasis(3), 2), np.eye(4))
    # Psi_0 = 1, so the rank-3 tensor contains the rank-2 one.
    np.testing.assert_allclose(expectation_tensor(basis, 3)[0], np.diag(basis.norms2), atol=1e-15)


@pytest.mark.parametrize("dim", [1, 3])
def test_order_zero_reduces_every_tensor_to_one(dim):
    basis = ChaosBasis(0, dim=dim)
    np.testing.assert_array_equal(expectation_tensor(basis, 1), [1.0])
    np.testing.assert_array_equal(expectation_tensor(basis, 2), [[1.0]])
    np.testing.assert_array_equal(expectation_tensor(basis, 3), [[[1.0]]])
    S = expectation_tensor(basis, 3, sparse=True)
    np.testing.assert_array_equal(S.todense(), [[[1.0]]])
    np.testing.assert_array_equal(S.contract([2.0], [3.0]), [6.0])
    np.testing.assert_array_equal(weighted_gram(basis, lambda w: np.full(len(w), 5.0)), [[5.0]])


# --- chaospy ---------------------------------------------------------------------------


def chaospy_route(order, dim):
    """chaospy's E[Psi_i Psi_j Psi_k] with its own term order mapped onto ours."""
    chaospy = pytest.importorskip("chaospy")
    dist = chaospy.J(*[chaospy.Uniform(0, 1) for _ in range(dim)])
    if dim == 1:
        dist = chaospy.Uniform(0, 1)
    expansion = chaospy.generate_expansion(order, dist, normed=True)
    P = len(expansion)
    # numpoly.outer takes two operands (a third would be its `out`), so nest it.
    T = chaospy.E(chaospy.outer(expansion, chaospy.outer(expansion, expansion)), dist)
    T = np.asarray(T).reshape(P, P, P)
    # Match chaospy's terms to ours by their values (order and signs are conventions).
    basis = ChaosBasis(order, dim=dim)
    omega = np.random.default_rng(0).random((4 * P, dim))
    ours = basis.evaluate(omega)
    theirs = np.atleast_2d(expansion(*omega.T)).reshape(P, -1).T
    perm = []
    for k in range(P):
        hits = [l for l in range(P) if np.allclose(ours[:, l], theirs[:, k], atol=1e-10)]
        assert len(hits) == 1, "chaospy term has no unique counterpart"
        perm.append(hits[0])
    return basis, T, np.array(perm)


@pytest.mark.parametrize("order,dim,tol", [(1, 1, 1e-12), (2, 1, 1e-12), (2, 2, 1e-12)])
def test_triple_product_matches_chaospy_at_low_order(order, dim, tol):
    basis, T_cp, perm = chaospy_route(order, dim)
    ours = expectation_tensor(basis, 3)[np.ix_(perm, perm, perm)]
    np.testing.assert_allclose(ours, T_cp, atol=tol)


def test_chaospy_raw_moment_route_degrades_while_ours_does_not():
    # chaospy computes E[.] from raw moments; its error grows by orders of magnitude per
    # degree (documented in docs/chaos.md). We only pin that it still agrees loosely at 3.
    basis, T_cp, perm = chaospy_route(3, 1)
    ours = expectation_tensor(basis, 3)[np.ix_(perm, perm, perm)]
    np.testing.assert_allclose(ours, T_cp, atol=1e-9)
    np.testing.assert_allclose(ours, closed_form_table(3, True), atol=1e-15)


# --- sparse form -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "order,dim,index_set", [(6, 1, "total"), (3, 2, "total"), (2, 3, "tensor")]
)
def test_sparse_equals_dense_and_follows_selection_rules(order, dim, index_set):
    basis = ChaosBasis(order, dim=dim, index_set=index_set)
    T = expectation_tensor(basis, 3)
    S = expectation_tensor(basis, 3, sparse=True)
    assert isinstance(S, SparseTensor3)
    assert S.shape == T.shape and S.indices.shape == (S.nnz, 3) and S.values.shape == (S.nnz,)
    np.testing.assert_array_equal(S.todense(), T)
    # Every stored entry is nonzero and every nonzero is stored: no thresholds involved.
    assert np.all(S.values != 0)
    assert S.nnz == np.count_nonzero(T)
    alpha = basis.indices
    a, b, c = (alpha[S.indices[:, n]] for n in range(3))
    assert np.all((a + b + c) % 2 == 0)
    assert np.all((np.abs(a - b) <= c) & (c <= a + b))


def test_sparse_contractions_match_einsum():
    basis = ChaosBasis(4, dim=2)
    T = expectation_tensor(basis, 3)
    S = expectation_tensor(basis, 3, sparse=True)
    rng = np.random.default_rng(1)
    x, y = rng.standard_normal((2, basis.size))
    np.testing.assert_allclose(S.contract(x, y), np.einsum("ijk,j,k->i", T, x, y), atol=1e-13)
    np.testing.assert_allclose(S.contract_matrix(x), np.einsum("ijk,j->ik", T, x), atol=1e-13)
    assert "nnz" in repr(S)


def test_sparse_contract_bad_input():
    S = expectation_tensor(ChaosBasis(2), 3, sparse=True)
    with pytest.raises(ValueError, match="`x`"):
        S.contract(np.ones(4), np.ones(3))
    with pytest.raises(ValueError, match="`y`"):
        S.contract(np.ones(3), [1.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="`x`"):
        S.contract_matrix(np.ones((3, 2)))


def test_sparse_constructor_validates():
    with pytest.raises(ValueError, match="indices"):
        SparseTensor3([[0, 0, 3]], [1.0], (3, 3, 3))
    with pytest.raises(ValueError, match="values"):
        SparseTensor3([[0, 0, 0]], [1.0, 2.0], (3, 3, 3))
    S = SparseTensor3([[0, 1, 2], [2, 1, 0]], [1.0, 2.0], (3, 3, 3))
    np.testing.assert_array_equal(S.contract([0, 1, 0], [1, 0, 1]), [1.0, 0.0, 2.0])


# --- weighted Gram ---------------------------------------------------------------------


@pytest.mark.parametrize("order", [0, 2, 5])
@pytest.mark.parametrize("normalized", [True, False])
def test_weighted_gram_monomial_is_exact(order, normalized):
    basis = ChaosBasis(order, normalized=normalized)
    c = np.array([math.sqrt(2 * n + 1) if normalized else 1.0 for n in range(order + 1)])
    for m in range(order + 3):  # the default rule is exact for deg g <= order + 2
        ref = np.array(exact_monomial_gram(order, m), dtype=float) * np.outer(c, c)
        G = weighted_gram(basis, lambda w, m=m: w**m)
        np.testing.assert_allclose(G, ref, atol=1e-13)
    # Higher powers need more points.
    m = 3 * order + 4
    ref = np.array(exact_monomial_gram(order, m), dtype=float) * np.outer(c, c)
    np.testing.assert_allclose(
        weighted_gram(basis, lambda w: w**m, n_points=3 * order + 4), ref, atol=1e-13
    )


def test_weighted_gram_multivariate_factorizes_for_product_weights():
    # g = omega_1^2 omega_2: E[g Psi_a Psi_b] = prod_d E[omega_d^m_d L_a_d L_b_d].
    basis = ChaosBasis(3, dim=2)
    G = weighted_gram(basis, lambda w: w[:, 0] ** 2 * w[:, 1])
    c = np.sqrt(2 * np.arange(4) + 1.0)
    g1 = [np.array(exact_monomial_gram(3, m), dtype=float) * np.outer(c, c) for m in (2, 1)]
    a = basis.indices
    ref = g1[0][np.ix_(a[:, 0], a[:, 0])] * g1[1][np.ix_(a[:, 1], a[:, 1])]
    np.testing.assert_allclose(G, ref, atol=1e-13)
    np.testing.assert_array_equal(G, G.T)


def test_weighted_gram_constant_weight_is_the_gram_matrix():
    basis = ChaosBasis(3, dim=2, normalized=False)
    G = weighted_gram(basis, lambda w: np.full(w.shape[0], 2.0))
    np.testing.assert_allclose(G, 2.0 * np.diag(basis.norms2), atol=1e-14)


def test_weighted_gram_accepts_samples_at_the_nodes():
    basis = ChaosBasis(4)
    nodes, _ = basis.quadrature(12)
    g = np.exp(nodes[:, 0])
    np.testing.assert_array_equal(
        weighted_gram(basis, g, n_points=12), weighted_gram(basis, np.exp, n_points=12)
    )
    np.testing.assert_array_equal(
        weighted_gram(basis, list(g), n_points=12), weighted_gram(basis, g, n_points=12)
    )


def test_weighted_gram_passes_omega_as_n_by_dim_for_every_dim():
    # issue 23: the germ reaches g as (n, dim) whatever dim, so w[:, 0] works for dim = 1
    seen = {}

    def g(w):
        seen["shape"] = w.shape
        return w[:, 0] - 0.5

    for dim in (1, 2):
        G = weighted_gram(ChaosBasis(2, dim=dim), g)
        assert len(seen["shape"]) == 2 and seen["shape"][1] == dim
        # E[(w0 - 1/2) Psi_0 Psi_1] = E[(w0 - 1/2) sqrt(3)(2 w0 - 1)] = sqrt(3) / 6
        assert G[0, 1] == pytest.approx(np.sqrt(3) / 6, abs=1e-15)
    # a g returning (n, 1), such as lambda w: w, is one value per node
    np.testing.assert_array_equal(
        weighted_gram(ChaosBasis(2), lambda w: w), weighted_gram(ChaosBasis(2), lambda w: w[:, 0])
    )


# --- bad input -------------------------------------------------------------------------


def test_expectation_tensor_bad_input():
    basis = ChaosBasis(2)
    with pytest.raises(TypeError, match="basis"):
        expectation_tensor(3, 3)
    with pytest.raises(ValueError, match="rank"):
        expectation_tensor(basis, 4)
    with pytest.raises(ValueError, match="rank"):
        expectation_tensor(basis, 0)
    with pytest.raises(TypeError, match="rank"):
        expectation_tensor(basis, "3")
    with pytest.raises(ValueError, match="sparse"):
        expectation_tensor(basis, 2, sparse=True)
    with pytest.raises(TypeError, match="sparse"):
        expectation_tensor(basis, 3, sparse="yes")
    with pytest.raises(TypeError, match="dense"):
        expectation_tensor(basis, 3, dense=True)


@pytest.mark.parametrize(
    "g,exc,match",
    [
        ("omega**2", TypeError, "`g`"),
        (3.0, TypeError, "`g`"),
        (None, TypeError, "`g`"),
        (lambda w: np.full_like(w, np.nan), ValueError, "`g`.*NaN"),
        (lambda w: np.log(w - 0.5), ValueError, "`g`"),
        (lambda w: w[:-1], ValueError, r"`g`.*shape"),
        (lambda w: 1.0, ValueError, r"`g`.*shape"),
        (lambda w: ["a"] * len(w), TypeError, "`g`"),
        (np.ones(3), ValueError, r"`g`.*shape"),
        (np.array([1.0, np.inf, 1.0, 1.0, 1.0]), ValueError, "`g`"),
    ],
)
def test_weighted_gram_bad_g(g, exc, match):
    with np.errstate(all="ignore"):
        with pytest.raises(exc, match=match):
            weighted_gram(ChaosBasis(2), g)  # default rule: 5 nodes


def test_weighted_gram_bad_other_arguments():
    with pytest.raises(TypeError, match="basis"):
        weighted_gram("basis", np.exp)
    with pytest.raises(ValueError, match="n_points"):
        weighted_gram(ChaosBasis(2), np.exp, n_points=0)
    with pytest.raises(TypeError, match="npoints"):
        weighted_gram(ChaosBasis(2), np.exp, npoints=4)
