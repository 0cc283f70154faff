"""Askey germs: Hermite (normal), Laguerre (gamma) and Jacobi (beta) bases and tensors.

Independent truths: exact rational arithmetic (Gram-Schmidt on the germ's exact moments
with ``fractions.Fraction``), chaospy's orthonormal expansions, and scipy's Gauss rules.
"""

import itertools
import math
from fractions import Fraction

import chaospy
import numpy as np
import pytest

from ecfm_uq.chaos import ChaosBasis, Germ, expectation_tensor, weighted_gram
from ecfm_uq.chaos.tensors import GaussNodes

GERMS = [
    (Germ("hermite"), lambda: chaospy.Normal(0, 1)),
    (Germ("laguerre", shape=2.5), lambda: chaospy.Gamma(2.5)),
    (Germ("laguerre", shape=1.0), lambda: chaospy.Exponential(1)),
    (Germ("jacobi", a=2, b=3), lambda: chaospy.Beta(2, 3)),
    (Germ("jacobi", a=1.5, b=1.5), lambda: chaospy.Beta(1.5, 1.5)),
]
IDS = [repr(g) for g, _ in GERMS]


def exact_moments(germ, n):
    """E[x^m], m < n, as Fractions (parameters are given as exact binary fractions)."""
    if germ.family == "hermite":
        return [Fraction(0) if m % 2 else Fraction(math.prod(range(1, m, 2))) for m in range(n)]
    if germ.family == "laguerre":
        k = Fraction(germ.params[0])
        return [math.prod((k + r for r in range(m)), start=Fraction(1)) for m in range(n)]
    a, b = (Fraction(v) for v in germ.params)
    return [
        math.prod(((a + r) / (a + b + r) for r in range(m)), start=Fraction(1)) for m in range(n)
    ]


def exact_monic(germ, p):
    """Monic orthogonal polynomials (coefficient lists) and their squared norms, exactly."""
    mom = exact_moments(germ, 3 * p + 1)

    def inner(f, g):
        out = Fraction(0)
        for i, fi in enumerate(f):
            for j, gj in enumerate(g):
                out += fi * gj * mom[i + j]
        return out

    polys, norms = [], []
    for n in range(p + 1):
        f = [Fraction(0)] * n + [Fraction(1)]
        for q, h in zip(polys, norms, strict=True):
            c = inner(f, q) / h
            f = [fi - c * (q[i] if i < len(q) else 0) for i, fi in enumerate(f)]
        polys.append(f)
        norms.append(inner(f, f))
    return polys, norms, mom


def exact_triple(germ, p):
    polys, norms, mom = exact_monic(germ, p)

    def mul(f, g):
        out = [Fraction(0)] * (len(f) + len(g) - 1)
        for i, fi in enumerate(f):
            for j, gj in enumerate(g):
                out[i + j] += fi * gj
        return out

    t = np.zeros((p + 1,) * 3)
    for i, j, k in itertools.combinations_with_replacement(range(p + 1), 3):
        e = sum(c * mom[m] for m, c in enumerate(mul(mul(polys[i], polys[j]), polys[k])))
        v = float(e) / math.sqrt(float(norms[i] * norms[j] * norms[k]))
        for perm in set(itertools.permutations((i, j, k))):
            t[perm] = v
    return t


@pytest.mark.parametrize("germ,dist", GERMS, ids=IDS)
def test_values_match_chaospy_orthonormal_expansion(germ, dist):
    p = 6
    basis = ChaosBasis(p, germ=germ)
    x = germ.ppf(np.linspace(0.02, 0.98, 9))
    ours = basis.evaluate(x)
    theirs = np.asarray(chaospy.generate_expansion(p, dist(), normed=True)(x)).T
    np.testing.assert_allclose(ours, theirs, rtol=1e-10, atol=1e-11)


@pytest.mark.parametrize("germ,dist", GERMS, ids=IDS)
def test_gauss_rule_is_a_probability_rule_exact_to_degree_2n_minus_1(germ, dist):
    n = 6
    x, w = germ.gauss(n)
    mom = [float(m) for m in exact_moments(germ, 2 * n + 1)]
    for m in range(2 * n):
        # odd Hermite moments are 0: compare them on the scale of E[x^(m+1)]
        scale = mom[m + 1] if mom[m] == 0 else mom[m]
        assert abs(w @ x**m - mom[m]) <= 1e-12 * scale
    assert abs(w @ x ** (2 * n) - mom[2 * n]) > 1e-8 * mom[2 * n]


@pytest.mark.parametrize("germ,dist", GERMS, ids=IDS)
def test_basis_is_orthonormal(germ, dist):
    basis = ChaosBasis(8, germ=germ)
    x, w = basis.quadrature(12)
    Psi = basis.evaluate(x)
    np.testing.assert_allclose(Psi.T @ (Psi * w[:, None]), np.eye(9), atol=1e-12)
    np.testing.assert_array_equal(expectation_tensor(basis, 2), np.eye(9))
    np.testing.assert_array_equal(expectation_tensor(basis, 1), np.eye(9)[0])


@pytest.mark.parametrize("germ,dist", GERMS, ids=IDS)
def test_triple_products_are_exact(germ, dist):
    p = 7
    T = expectation_tensor(ChaosBasis(p, germ=germ), 3)
    ref = exact_triple(germ, p)
    np.testing.assert_allclose(T, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_hermite_triple_products_closed_form_at_high_order():
    # E[He_i He_j He_k] = i! j! k! / ((s-i)! (s-j)! (s-k)!) in integers, then normalised
    p = 20
    T = Germ("hermite").triple(p)
    f = math.factorial
    for i, j, k in [(20, 20, 20), (10, 12, 14), (1, 19, 20), (5, 7, 10)]:
        s = (i + j + k) // 2
        ref = Fraction(f(i) * f(j) * f(k), f(s - i) * f(s - j) * f(s - k)) ** 2
        ref = math.sqrt(ref / (f(i) * f(j) * f(k)))
        assert T[i, j, k] == pytest.approx(ref, rel=4e-16 * 3)
    assert T[1, 2, 4] == 0.0 and T[1, 1, 1] == 0.0 and T[5, 7, 9] == 0.0


@pytest.mark.parametrize("germ,dist", GERMS[:4], ids=IDS[:4])
def test_triple_products_match_chaospy_at_low_order(germ, dist):
    p = 3
    basis = ChaosBasis(p, germ=germ)
    d = dist()
    P = chaospy.generate_expansion(p, d, normed=True)
    Tc = np.stack([chaospy.E(P[i] * chaospy.outer(P, P), d) for i in range(p + 1)])
    # chaospy works from raw moments: agreement to its own round-off level
    np.testing.assert_allclose(expectation_tensor(basis, 3), Tc, atol=1e-9)


def test_mixed_germs_tensor_is_the_product_of_tables_and_sparse_equals_dense():
    germs = [Germ("hermite"), Germ("laguerre", shape=2.0), "legendre"]
    basis = ChaosBasis(3, dim=3, germ=germs)
    T = expectation_tensor(basis, 3)
    x, w = basis.quadrature(7)
    Psi = basis.evaluate(x)
    np.testing.assert_allclose(
        T, np.einsum("q,qa,qb,qc->abc", w, Psi, Psi, Psi), atol=1e-12 * np.abs(T).max()
    )
    S = expectation_tensor(basis, 3, sparse=True)
    np.testing.assert_array_equal(S.todense(), T)
    # parity holds for Hermite and Legendre variables, not for Laguerre: more stored entries
    lag = ChaosBasis(3, dim=3, germ=germs[1])
    S_lag = expectation_tensor(lag, 3, sparse=True)
    np.testing.assert_array_equal(S_lag.todense(), expectation_tensor(lag, 3))
    assert S_lag.nnz > expectation_tensor(ChaosBasis(3, dim=3, germ="hermite"), 3, sparse=True).nnz


def test_weighted_gram_with_hermite_germ_is_exact_for_lognormal_coefficient():
    # E[exp(s xi) He_k He_l]/sqrt(k! l!) = exp(s^2/2) sum_m ... ; for k = l = 1: exp(s^2/2)(1 + s^2)
    s = 0.4
    G = weighted_gram(ChaosBasis(4, germ="hermite"), lambda w: np.exp(s * w[:, 0]), n_points=30)
    assert G[0, 0] == pytest.approx(np.exp(s**2 / 2), rel=1e-14)
    assert G[0, 1] == pytest.approx(s * np.exp(s**2 / 2), rel=1e-14)
    assert G[1, 1] == pytest.approx((1 + s**2) * np.exp(s**2 / 2), rel=1e-14)


def test_gauss_nodes_use_the_germ_rule():
    basis = ChaosBasis(4, germ="hermite")
    gn = GaussNodes(basis)
    np.testing.assert_allclose(gn.Phi @ (gn.from_nodes.T), np.eye(5), atol=1e-12)
    np.testing.assert_allclose(np.sort(gn.nodes), np.sort(Germ("hermite").gauss(5)[0]))


def test_bad_germs_are_refused_by_name():
    with pytest.raises(ValueError, match="germ.*'legendre'"):
        ChaosBasis(2, germ="poisson")
    with pytest.raises(ValueError, match="`shape`"):
        Germ("laguerre", shape=-1.0)
    with pytest.raises(TypeError, match="jacobi.*a=, b="):
        Germ("jacobi")
    with pytest.raises(ValueError, match="one germ per variable"):
        ChaosBasis(2, dim=2, germ=["hermite"])
    with pytest.raises(ValueError, match="normalized"):
        ChaosBasis(2, germ="hermite", normalized=False)
    with pytest.raises(ValueError, match=r"column 0.*support \[0, inf\]"):
        ChaosBasis(2, germ=Germ("laguerre", shape=2.0)).evaluate([-1.0])


def test_legendre_germ_by_name_is_the_default_basis():
    assert ChaosBasis(3, dim=2, germ="legendre") == ChaosBasis(3, dim=2)
    assert ChaosBasis(3, germ="hermite") != ChaosBasis(3)
