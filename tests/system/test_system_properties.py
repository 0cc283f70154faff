"""Property-based tests of the Galerkin engine (hypothesis): invariants that hold for
every admissible random system."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ecfm_uq.chaos import ChaosBasis, gauss_legendre, weighted_gram
from ecfm_uq.system import GalerkinSystem, LinearTerm, LoadTerm, QuadraticTerm, solve_steady

seeds = st.integers(min_value=0, max_value=2**32 - 1)


def _spd(rng, n, shift):
    X = rng.normal(size=(n, n))
    return X @ X.T + shift * np.eye(n)


@settings(max_examples=25, deadline=None)
@given(seed=seeds, n=st.integers(1, 5), order=st.integers(0, 4))
def test_affine_random_system_equals_collocation(seed, n, order):
    """Galerkin with K(w) = K0 + w K1 (K(w) SPD on [0, 1]) equals Gauss collocation at
    order + 1 nodes, and both the decoupled and the dense solve satisfy R = 0."""
    rng = np.random.default_rng(seed)
    K0, K1 = _spd(rng, n, 1.0), 0.5 * _spd(rng, n, 0.0)
    F = rng.normal(size=n)
    basis = ChaosBasis(order)
    system = GalerkinSystem(
        [LinearTerm(K0), LinearTerm(K1, G=weighted_gram(basis, lambda w: w)), LoadTerm.constant(F)],
        0,
        basis=basis,
    )
    sol = solve_steady(system, [])
    dense = solve_steady(system, [], structure="dense")
    assert sol.success and dense.success
    np.testing.assert_allclose(
        sol.Theta, dense.Theta, atol=1e-9 * max(1, np.abs(dense.Theta).max())
    )
    nodes, weights = gauss_legendre(order + 1)
    th = np.array([np.linalg.solve(K0 + w * K1, F) for w in nodes])
    coll = (th.T * weights) @ basis.evaluate(nodes)
    np.testing.assert_allclose(sol.Theta, coll, atol=1e-9 * max(1, np.abs(coll).max()))


@settings(max_examples=25, deadline=None)
@given(seed=seeds, n=st.integers(1, 4), order=st.integers(0, 3))
def test_quadratic_term_jacobian_is_the_derivative(seed, n, order):
    """For any tensor A and state Theta, the assembled Jacobian is the derivative of the
    residual (central differences are exact for a quadratic up to round-off)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n, n))
    basis = ChaosBasis(order)
    system = GalerkinSystem([LinearTerm(np.eye(n)), QuadraticTerm(A)], 0, basis=basis)
    Theta = rng.normal(size=system.shape)
    J = system.jacobian(Theta, [])
    h = 1e-3
    cols = []
    for m in range(Theta.size):
        E = np.zeros(Theta.size)
        E[m] = h
        rp = system.residual(Theta + E.reshape(Theta.shape), []).ravel()
        rm = system.residual(Theta - E.reshape(Theta.shape), []).ravel()
        cols.append((rp - rm) / (2 * h))
    np.testing.assert_allclose(J, np.array(cols).T, atol=1e-8 * max(1, np.abs(J).max()))
