"""Galerkin coefficients from functions of the physical inputs (chaos.input_projection)."""

import numpy as np
import pytest
from scipy import stats

from ecfm_uq.chaos import ChaosBasis, Inputs, input_basis, input_coefficients, input_gram

INPUTS = Inputs([stats.norm(1.5, 0.2), stats.uniform(0.1, 0.1)], names=["alpha", "beta"])


def test_coefficients_of_a_product_of_inputs_give_its_exact_moments():
    basis = input_basis(INPUTS, 3)
    assert [g.family for g in basis.germs] == ["hermite", "legendre"]
    c = input_coefficients(basis, INPUTS, lambda x: x[:, 0] * x[:, 1])
    mean = 1.5 * 0.15
    var = (1.5**2 + 0.2**2) * (0.15**2 + 0.1**2 / 12) - mean**2
    assert c[0] == pytest.approx(mean, rel=1e-13)
    assert np.sum(c[1:] ** 2) == pytest.approx(var, rel=1e-12)


def test_field_valued_functions_and_the_gram_matrix_of_a_coefficient():
    basis = input_basis(INPUTS, 4)
    x_nodes = np.linspace(0.0, 1.0, 5)
    c = input_coefficients(basis, INPUTS, lambda x: np.outer(x[:, 0], np.sin(np.pi * x_nodes)))
    assert c.shape == (basis.size, 5)
    np.testing.assert_allclose(c[0], 1.5 * np.sin(np.pi * x_nodes), atol=1e-13)
    G = input_gram(basis, INPUTS, lambda x: x[:, 1])
    np.testing.assert_allclose(G, G.T, atol=1e-15)
    # E[beta Psi_k Psi_0] is the k-th chaos coefficient of beta itself
    np.testing.assert_allclose(G[:, 0], input_coefficients(basis, INPUTS, lambda x: x[:, 1]),
                               atol=1e-14)  # fmt: skip
    # beta in [0.1, 0.2]: the Gram matrix of a positive coefficient is positive definite
    assert np.linalg.eigvalsh(G).min() > 0.1 - 1e-12


def test_mistakes_are_named():
    basis = input_basis(INPUTS, 2)
    with pytest.raises(ValueError, match="build the basis with input_basis"):
        input_gram(ChaosBasis(2, 2), INPUTS, lambda x: x[:, 1])
    with pytest.raises(TypeError, match="`f` must be callable"):
        input_coefficients(basis, INPUTS, 1.0)
    with pytest.raises(ValueError, match="one value .* per input point"):
        input_coefficients(basis, INPUTS, lambda x: x[0])
    with pytest.raises(ValueError, match="one scalar per point"):
        input_gram(basis, INPUTS, lambda x: x)
    with pytest.raises(TypeError, match="`inputs` must be an Inputs"):
        input_basis([stats.norm()], 2)
