"""Per-call shortcuts of the system layer give the same bits as what they replace: the
dense LU solves by LAPACK's ``getrs`` directly (against ``scipy.linalg.lu_solve``), and
``eps_jacobian`` without the terms that do not depend on eps (against the sum over every
term)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from ecfm_uq.problems.reaction import ReactionRod
from ecfm_uq.system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady
from ecfm_uq.system.solve.factors import DenseFactor, dense_lu


@pytest.mark.parametrize("shape", [(5,), (5, 3)])
def test_dense_factor_solves_give_scipys_bits(shape):
    rng = np.random.default_rng(0)
    J = rng.standard_normal((5, 5)) + 5.0 * np.eye(5)
    b = rng.standard_normal(shape)
    lu = dense_lu(J)
    f = DenseFactor(lu)
    np.testing.assert_array_equal(f.solve(b), sla.lu_solve(lu, b, check_finite=False))
    np.testing.assert_array_equal(
        f.solve_transpose(b), sla.lu_solve(lu, b, trans=1, check_finite=False)
    )
    np.testing.assert_allclose(J @ f.solve(b), b, atol=1e-12)
    np.testing.assert_allclose(J.T @ f.solve_transpose(b), b, atol=1e-12)
    # what the direct call does not take (complex) goes through scipy
    bc = b + 1j * b
    np.testing.assert_allclose(J @ f.solve(bc), bc, atol=1e-12)


def term_sum(system, Theta, eps, t=None):
    D = np.zeros((system.N * system.P, system.n_eps))
    for term in system.terms:
        D += term.eps_jacobian(Theta, eps, t)
    return D


def test_eps_jacobian_without_eps_free_terms_is_the_full_sums():
    rod = ReactionRod(6)
    K = rod.system.terms[0].K
    F = np.linspace(1.0, 2.0, K.shape[0])
    system = GalerkinSystem(
        [*rod.system.terms, LinearTerm(K, 3.0), LoadTerm.constant(-F)], 2, Gamma=rod.system.Gamma
    )
    assert system.terms[0].coef.is_constant and not system.terms[1].coef.is_constant
    eps = np.array([1.3, 18.0])
    Theta = solve_steady(system, eps).Theta
    for term in system.terms:  # the terms skipped add exact zeros
        if getattr(term, "coef", None) is not None and term.coef.is_constant:
            assert not np.any(term.eps_jacobian(Theta, eps))
    np.testing.assert_array_equal(system.eps_jacobian(Theta, eps), term_sum(system, Theta, eps))
    # against central differences of the residual
    h = 1e-6
    fd = np.column_stack([
        (system.residual(Theta, eps + h * e) - system.residual(Theta, eps - h * e)).ravel()
        / (2 * h)
        for e in np.eye(2)
    ])  # fmt: skip
    np.testing.assert_allclose(system.eps_jacobian(Theta, eps), fd, rtol=1e-6, atol=1e-6)
    assert not Coefficient(lambda e: 1.0, lambda e: np.zeros(2)).is_constant


def test_eps_jacobian_skips_a_quadratic_term_with_a_constant_coefficient():
    """Burgers' convection (coefficient 1) beside its eps-dependent diffusion: the sum
    without the convection's zero columns is the full sum, bit for bit."""
    from ecfm_uq.problems.burgers import BurgersModel

    system = BurgersModel(n_modes=12, n_steps=5).system
    kinds = {type(t).__name__: t for t in system.terms}
    assert kinds["QuadraticTerm"].coef.is_constant
    eps = np.array([0.2, 0.9])[: system.n_eps]
    Theta = np.random.default_rng(3).standard_normal((system.N, system.P))
    assert not np.any(kinds["QuadraticTerm"].eps_jacobian(Theta, eps, 0.5))
    np.testing.assert_array_equal(
        system.eps_jacobian(Theta, eps, 0.5), term_sum(system, Theta, eps, 0.5)
    )
