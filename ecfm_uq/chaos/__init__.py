"""Polynomial chaos: shifted Legendre basis (or any Askey germ), quadrature, tensors, PCE.

The germ is omega ~ U(0, 1)^dim with independent components (paper Section 3.3, where
dim = 1); a basis may instead take normal, gamma or beta germ variables (``germ=``), and
the inputs of a non-intrusive fit any continuous marginals and a Gaussian copula. A field
is expanded as theta_i(omega) = Theta_ij Psi_j(omega) and projected with the expectations
computed here (paper Eq. ``pce``). Deterministic problems are the P = 1
case, ``ChaosBasis(0)``, for which every tensor is the scalar 1.

Public API
----------
ChaosBasis           basis terms Psi_k, multi-indices, evaluation, quadrature
Germ                 one germ variable of the Askey scheme (uniform, normal, gamma, beta)
OwnGerm              any law's own orthonormal polynomials (arbitrary chaos; germ="own")
gauss_legendre       Gauss-Legendre nodes and probability weights on [0, 1]
expectation_tensor   E[Psi_k], E[Psi_i Psi_j], E[Psi_i Psi_j Psi_k] (dense or sparse)
weighted_gram        E[g(omega) Psi_k Psi_l]
coupling_tensor      E[phi_a Psi_i Psi_j]: a coefficient's own chaos against the basis
lognormal_coefficients  exact Hermite chaos of exp(m + b . xi) (lognormal fields)
GaussNodes           a one-germ basis at its P-node Gauss rule (node-wise solvers)
SparseTensor3        coordinate-form third-order tensor with contractions
PolynomialChaosExpansion  a PCE as an object: moments, Sobol indices, sampling, chaospy export
Inputs               any continuous marginals, independent or joined by a Gaussian copula
UniformInputs        independent uniform inputs on their own ranges, mapped to the germ
StudentInputs        a multivariate Student t (a normal scale mixture: p + 1 germs)
project              pseudo-spectral projection of node values onto the basis
input_basis, input_coefficients, input_gram
                     a Galerkin model's coefficients and states as functions of the inputs
fit_pce              non-intrusive PCE of a black-box model (quadrature, Smolyak, OLS, LARS)
"""

from .basis import ChaosBasis
from .germs import Germ
from .input_projection import input_basis, input_coefficients, input_gram
from .inputs import Inputs, UniformInputs
from .nonintrusive import fit_pce, sample_design, smolyak_rule
from .ownlaw import OwnGerm
from .pce import PolynomialChaosExpansion
from .projection import project
from .quadrature import gauss_legendre
from .student import StudentInputs
from .tensors import (
    GaussNodes,
    SparseTensor3,
    common_eigenbasis,
    coupling_tensor,
    expectation_tensor,
    lognormal_coefficients,
    triple_product_1d,
    weighted_gram,
)

__all__ = [
    "ChaosBasis",
    "Germ",
    "OwnGerm",
    "PolynomialChaosExpansion",
    "Inputs",
    "StudentInputs",
    "UniformInputs",
    "fit_pce",
    "input_basis",
    "input_coefficients",
    "input_gram",
    "project",
    "sample_design",
    "smolyak_rule",
    "GaussNodes",
    "SparseTensor3",
    "common_eigenbasis",
    "coupling_tensor",
    "lognormal_coefficients",
    "expectation_tensor",
    "gauss_legendre",
    "triple_product_1d",
    "weighted_gram",
]
