"""From physical inputs to Galerkin coefficients: a coefficient or a state as a function of
the inputs, projected on the chaos basis of those inputs.

An intrusive (stochastic Galerkin) model needs, for a random coefficient :math:`a(x)` of
the physical inputs :math:`x = T(\\omega)` (:class:`~ecfm_uq.chaos.Inputs`, any
marginals), the weighted Gram matrix :math:`\\mathbb E[a(x)\\,\\Psi_k\\Psi_\\ell]` of a
linear term, and for a random initial state or load :math:`f(x)` its chaos coefficients
:math:`c_k = \\mathbb E[f(x)\\Psi_k]/\\mathbb E[\\Psi_k^2]` (paper Eq. pce). Both are
integrals over the germ, computed here by the basis' Gauss rule with
:math:`x = T(\\omega)` at its nodes, so no germ coordinate is written by hand.

Example: chaospy's intrusive Galerkin tutorial, :math:`\\dot u = -\\beta u`,
:math:`u(0) = \\alpha`, :math:`\\alpha \\sim N(1.5, 0.2^2)`, :math:`\\beta \\sim U(0.1, 0.2)`
(docs/time.md)::

    inputs = Inputs([stats.norm(1.5, 0.2), stats.uniform(0.1, 0.1)], names=["alpha", "beta"])
    basis = input_basis(inputs, 5)
    G = input_gram(basis, inputs, lambda x: x[:, 1])          # E[beta Psi Psi^T]
    u0 = input_coefficients(basis, inputs, lambda x: x[:, 0])  # chaos of alpha
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array
from .basis import ChaosBasis
from .inputs import Inputs
from .projection import project
from .tensors import weighted_gram

__all__ = ["input_basis", "input_coefficients", "input_gram"]


def _check(basis, inputs):
    if not isinstance(basis, ChaosBasis):
        raise TypeError(f"`basis` must be a ChaosBasis, got {type(basis).__name__}")
    if not isinstance(inputs, Inputs):
        raise TypeError(
            f"`inputs` must be an Inputs (e.g. Inputs([stats.norm(1, 0.1), ...])), got "
            f"{type(inputs).__name__}"
        )
    if basis.dim != inputs.dim or tuple(basis.germs) != tuple(inputs.germs):
        raise ValueError(
            f"`basis` has germs {basis.germs} but `inputs` needs {inputs.germs}; build the "
            "basis with input_basis(inputs, order)"
        )


def _values(name, f, x, n):
    """``f(x)`` for the (n, dim) input points, checked: (n, *shape) finite values."""
    if not callable(f):
        raise TypeError(f"`{name}` must be callable {name}(x) with x of shape (n, dim)")
    y = as_finite_array(f"{name}(x)", f(x))
    if y.ndim == 0 or y.shape[0] != n:
        raise ValueError(
            f"`{name}(x)` must return one value (or array) per input point, shape "
            f"({n}, ...), got {y.shape}; write it with x[:, k] for the k-th input"
        )
    return y


def input_basis(inputs, order, index_set="total"):
    """The orthonormal chaos basis of ``inputs``: one germ per input, of its Askey family
    (Hermite for normal, Legendre for uniform, ...; Hermite for every variable of
    correlated inputs).

    Parameters
    ----------
    inputs : Inputs
    order : int
    index_set : {"total", "tensor"}

    Returns
    -------
    ChaosBasis
    """
    if not isinstance(inputs, Inputs):
        raise TypeError(f"`inputs` must be an Inputs, got {type(inputs).__name__}")
    return ChaosBasis(order, inputs.dim, index_set=index_set, germ=inputs.germs)


def input_coefficients(basis, inputs, f, n_points=None):
    """Chaos coefficients :math:`c_k = \\mathbb E[f(x)\\Psi_k]/\\mathbb E[\\Psi_k^2]` of a
    function of the physical inputs.

    Parameters
    ----------
    basis : ChaosBasis
        Of ``inputs`` (:func:`input_basis`).
    inputs : Inputs
    f : callable
        ``f(x)`` with ``x`` of shape (n, dim), one row per input point, returning (n,) or
        (n, *shape) values (e.g. an initial field of N nodes: (n, N)).
    n_points : int, optional
        Gauss points per germ (default of :meth:`ChaosBasis.quadrature`; exact for ``f``
        polynomial of degree up to the order in affine inputs). Raise it for
        non-polynomial ``f`` until the coefficients stop changing.

    Returns
    -------
    (P, *shape) ndarray
        For a state ``Theta`` of shape (N, P), take ``c.T`` of an (n, N)-valued ``f``.
    """
    _check(basis, inputs)
    nodes, weights = basis.quadrature(n_points)
    x = inputs.from_germ(nodes)
    return project(basis, nodes, weights, _values("f", f, x, len(weights)))


def input_gram(basis, inputs, g, n_points=None):
    """The weighted Gram matrix :math:`\\mathbb E[g(x)\\,\\Psi_k\\Psi_\\ell]` of a scalar
    coefficient of the physical inputs: ``G`` of a :class:`~ecfm_uq.system.LinearTerm`
    whose operator is scaled by :math:`g(x)`.

    Parameters
    ----------
    basis : ChaosBasis
        Of ``inputs`` (:func:`input_basis`).
    inputs : Inputs
    g : callable
        ``g(x)`` with ``x`` of shape (n, dim) returning (n,) values.
    n_points : int, optional
        As for :func:`input_coefficients`.

    Returns
    -------
    (P, P) ndarray
    """
    _check(basis, inputs)

    def on_germ(omega):
        omega = np.atleast_2d(omega)
        y = _values("g", g, inputs.from_germ(omega), len(omega))
        if y.ndim != 1:
            raise ValueError(f"`g(x)` must return one scalar per point, shape (n,), got {y.shape}")
        return y

    return weighted_gram(basis, on_germ, n_points)
