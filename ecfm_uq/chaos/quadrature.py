"""Gauss-Legendre quadrature for the uniform germ omega ~ U(0, 1)^dim.

The expectations of the stochastic Galerkin projection (paper Eq. ``pce``) are integrals
over [0, 1] with unit density; an n-point Gauss-Legendre rule mapped to [0, 1] computes
them exactly for polynomial integrands of degree <= 2n - 1 per variable.
"""

from __future__ import annotations

import numpy as np
from scipy.special import roots_legendre

from .._validation import check_int
from ..memory import check_allocation

__all__ = ["gauss_legendre", "tensor_gauss_legendre", "tensor_rule"]

# A tensor rule larger than this is almost certainly a mistake (n_points ** dim nodes).
_MAX_TENSOR_NODES = 20_000_000


def gauss_legendre(n):
    """Gauss-Legendre nodes and probability weights on [0, 1].

    Parameters
    ----------
    n : int
        Number of nodes, ``n >= 1``.

    Returns
    -------
    nodes : (n,) ndarray
        Nodes in (0, 1), increasing.
    weights : (n,) ndarray
        Positive weights summing to 1, so that ``weights @ f(nodes)`` approximates
        :math:`\\mathbb{E}[f(\\omega)]` for :math:`\\omega \\sim \\mathcal{U}(0, 1)`.

    Notes
    -----
    The rule on [-1, 1] (``scipy.special.roots_legendre``) is mapped by
    :math:`\\omega = (x + 1)/2`, :math:`w = w_x / 2`. It is exact for polynomials of degree
    :math:`\\le 2n - 1`:

    .. math:: \\sum_{q=1}^{n} w_q\\, p(\\omega_q) = \\int_0^1 p(\\omega)\\, d\\omega.

    Examples
    --------
    >>> x, w = gauss_legendre(3)
    >>> round(float(w @ x**5), 15)  # exactly 1/6 up to round-off
    0.166666666666667
    """
    n = check_int("n", n, minimum=1)
    x, w = roots_legendre(n)
    return 0.5 * (x + 1.0), 0.5 * w


def _check_tensor_size(n, dim, family):
    """Refuse a tensor rule of ``n**dim`` nodes over the node limit or the memory budget."""
    if n**dim > _MAX_TENSOR_NODES:
        raise ValueError(
            f"a tensor rule with `n_points`={n} in dim={dim} has {n**dim} nodes "
            f"(limit {_MAX_TENSOR_NODES}); pass a smaller `n_points`"
        )
    # meshgrid copies, the stacked nodes and the weights: about (2 dim + 1) n^dim floats
    check_allocation(
        8.0 * (2 * dim + 1) * float(n) ** dim,
        f"a tensor {family} rule with {n}^{dim} nodes",
        "pass a smaller `n_points` or use fewer variables",
    )


def tensor_gauss_legendre(n, dim):
    """Tensor-product Gauss-Legendre rule on [0, 1]^dim.

    Parameters
    ----------
    n : int
        Nodes per variable, ``n >= 1``.
    dim : int
        Number of variables, ``dim >= 1``.

    Returns
    -------
    nodes : (n**dim, dim) ndarray
        Nodes; the last variable varies fastest.
    weights : (n**dim,) ndarray
        Products of the 1-D probability weights; they sum to 1.
    """
    n = check_int("n_points", n, minimum=1)
    dim = check_int("dim", dim, minimum=1)
    _check_tensor_size(n, dim, "Gauss-Legendre")
    x, w = gauss_legendre(n)
    grids = np.meshgrid(*([x] * dim), indexing="ij")
    nodes = np.stack([g.ravel() for g in grids], axis=1)
    weights = np.ones(1)
    for _ in range(dim):
        weights = np.outer(weights, w).ravel()
    return nodes, weights


def tensor_rule(rules, n):
    """Tensor product of 1-D rules, one per variable (e.g. ``Germ.gauss`` of each germ).

    Parameters
    ----------
    rules : sequence of callable
        ``rule(n) -> (nodes (n,), weights (n,))``, one per variable.
    n : int
        Nodes per variable.

    Returns
    -------
    nodes : (n**dim, dim) ndarray
        The last variable varies fastest.
    weights : (n**dim,) ndarray
        Products of the 1-D weights.
    """
    n = check_int("n_points", n, minimum=1)
    dim = len(rules)
    _check_tensor_size(n, dim, "Gauss")
    parts = [rule(n) for rule in rules]
    grids = np.meshgrid(*[x for x, _ in parts], indexing="ij")
    nodes = np.stack([g.ravel() for g in grids], axis=1)
    weights = np.ones(1)
    for _, w in parts:
        weights = np.outer(weights, w).ravel()
    return nodes, weights
