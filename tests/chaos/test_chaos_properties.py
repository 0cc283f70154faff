"""Property tests (hypothesis): symmetry and selection rules hold for every index triple."""

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ecfm_uq.chaos import ChaosBasis, expectation_tensor, triple_product_1d

FAST = settings(max_examples=60, deadline=None)


def allowed_1d(i, j, k):
    return (i + j + k) % 2 == 0 and abs(i - j) <= k <= i + j


@st.composite
def triple_in_order(draw, max_order=30):
    p = draw(st.integers(0, max_order))
    ijk = draw(st.tuples(*[st.integers(0, p)] * 3))
    return p, ijk


@FAST
@given(triple_in_order(), st.booleans())
def test_1d_selection_rules_and_symmetry(case, normalized):
    p, (i, j, k) = case
    t = triple_product_1d(p, normalized)
    if allowed_1d(i, j, k):
        # In one variable every allowed entry is strictly positive (Adams-Neumann).
        assert t[i, j, k] > 0
    else:
        assert t[i, j, k] == 0.0
    for perm in itertools.permutations((i, j, k)):
        assert t[perm] == t[i, j, k]


@st.composite
def multivariate_case(draw):
    dim = draw(st.integers(1, 3))
    order = draw(st.integers(0, 4))
    index_set = draw(st.sampled_from(["total", "tensor"]))
    basis = ChaosBasis(order, dim=dim, index_set=index_set)
    abc = draw(st.tuples(*[st.integers(0, basis.size - 1)] * 3))
    return basis, abc


@FAST
@given(multivariate_case())
def test_multivariate_entries_vanish_exactly_when_a_variable_breaks_the_rules(case):
    basis, (a, b, c) = case
    T = expectation_tensor(basis, 3)
    alpha = basis.indices
    ok = all(allowed_1d(alpha[a, d], alpha[b, d], alpha[c, d]) for d in range(basis.dim))
    if ok:
        assert T[a, b, c] > 0
    else:
        assert T[a, b, c] == 0.0
    for perm in itertools.permutations((a, b, c)):
        assert T[perm] == T[a, b, c]


@FAST
@given(
    st.integers(1, 3),
    st.integers(0, 4),
    st.integers(0, 2**32 - 1),
)
def test_sparse_contraction_is_the_dense_one(dim, order, seed):
    basis = ChaosBasis(order, dim=dim)
    T = expectation_tensor(basis, 3)
    S = expectation_tensor(basis, 3, sparse=True)
    rng = np.random.default_rng(seed)
    x, y = rng.standard_normal((2, basis.size))
    np.testing.assert_allclose(S.contract(x, y), np.einsum("ijk,j,k->i", T, x, y), atol=1e-12)
    np.testing.assert_allclose(S.contract(x, y), S.contract(y, x), atol=1e-12)
    np.testing.assert_allclose(S.contract_matrix(x) @ y, S.contract(x, y), atol=1e-12)


@FAST
@given(
    st.integers(1, 3),
    st.integers(0, 5),
    st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8),
)
def test_psi0_is_one_and_mean_of_others_is_zero(dim, order, values):
    basis = ChaosBasis(order, dim=dim)
    omega = np.resize(np.array(values), (len(values), dim))
    Psi = basis.evaluate(omega)
    np.testing.assert_array_equal(Psi[:, 0], 1.0)
    nodes, weights = basis.quadrature()
    mean = weights @ basis.evaluate(nodes)
    np.testing.assert_allclose(mean, expectation_tensor(basis, 1), atol=1e-13)
