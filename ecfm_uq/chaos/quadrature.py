"""The package's quadrature rules, one function per family.

The expectations of the stochastic Galerkin projection (paper Eq. ``pce``) are integrals
against the germ's law; an n-point Gauss rule of that law computes them exactly for
polynomial integrands of degree <= 2n - 1 per variable. Every rule of the chaos layer is
here, and the germs (:meth:`Germ.gauss <ecfm_uq.chaos.Germ.gauss>`,
:meth:`OwnGerm.gauss <ecfm_uq.chaos.OwnGerm.gauss>`), the bases, the sparse grids and the
own-law measure (:mod:`ecfm_uq.chaos.ownlaw`) call them:

* :func:`gauss_legendre` -- uniform on [0, 1] (probability weights);
* :func:`gauss_hermite` -- standard normal;
* :func:`gauss_laguerre` -- gamma(shape, 1);
* :func:`gauss_jacobi` -- beta(a, b) on [0, 1];
* :func:`gauss_golub_welsch` -- any law, from its monic three-term recurrence;
* :func:`clenshaw_curtis` -- nested Clenshaw-Curtis, uniform on [0, 1];
* :func:`tensor_gauss_legendre`, :func:`tensor_rule` -- tensor products of 1-D rules.

One rule lives elsewhere: the composite Gauss-Legendre panels of the spectral operators
(:func:`ecfm_uq.spectral.composite_gauss`, integrals over the physical domain with
numpy's nodes): ``ecfm_uq.spectral`` does not import this package (importing it would
add the chaos kernels' ~3 s to every spectral model's import).
"""

from __future__ import annotations

import numpy as np
from scipy.special import roots_genlaguerre, roots_hermitenorm, roots_jacobi, roots_legendre

from .._validation import check_int
from ..memory import check_allocation
from ._kernels import legendre_table

__all__ = [
    "clenshaw_curtis",
    "gauss_golub_welsch",
    "gauss_hermite",
    "gauss_jacobi",
    "gauss_laguerre",
    "gauss_legendre",
    "tensor_gauss_legendre",
    "tensor_rule",
]

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


def gauss_hermite(n):
    """Gauss rule of the standard normal law: nodes and probability weights.

    ``scipy.special.roots_hermitenorm`` (probabilists' Hermite polynomials), the weights
    divided by their sum. Exact for polynomials of degree :math:`\\le 2n - 1`.

    Parameters
    ----------
    n : int

    Returns
    -------
    nodes, weights : (n,) ndarray
    """
    x, w = roots_hermitenorm(n)
    return x, w / w.sum()


def gauss_laguerre(n, shape):
    """Gauss rule of the gamma law of ``shape`` (scale 1): nodes and probability weights.

    ``scipy.special.roots_genlaguerre(n, shape - 1)``, the weights divided by their sum.

    Parameters
    ----------
    n : int
    shape : float
        The gamma law's shape, > 0.

    Returns
    -------
    nodes, weights : (n,) ndarray
    """
    x, w = roots_genlaguerre(n, shape - 1.0)
    return x, w / w.sum()


def gauss_jacobi(n, a, b):
    """Gauss rule of the beta(a, b) law on [0, 1]: nodes and probability weights.

    ``scipy.special.roots_jacobi(n, b - 1, a - 1)`` on [-1, 1], mapped by
    :math:`x = (t + 1)/2`, the weights divided by their sum.

    Parameters
    ----------
    n : int
    a, b : float
        The beta law's shapes, > 0.

    Returns
    -------
    nodes, weights : (n,) ndarray
    """
    t, w = roots_jacobi(n, b - 1.0, a - 1.0)
    x = 0.5 * (t + 1.0)
    return x, w / w.sum()


def gauss_golub_welsch(a, b):
    """Gauss rule of a law from its monic recurrence (Golub & Welsch 1969).

    For :math:`\\pi_{k+1}(x) = (x - a_k)\\pi_k(x) - b_k\\pi_{k-1}(x)`, the n nodes are
    the eigenvalues of the Jacobi matrix
    :math:`J = \\operatorname{tridiag}(\\sqrt{b_k}, a_k, \\sqrt{b_k})` and the weights the
    squared first components of its unit eigenvectors, divided by their sum.

    Parameters
    ----------
    a, b : (n,) ndarray
        Recurrence coefficients (``b[0]`` unused).

    Returns
    -------
    nodes, weights : (n,) ndarray
    """
    J = np.diag(a) + np.diag(np.sqrt(b[1:]), 1) + np.diag(np.sqrt(b[1:]), -1)
    t, V = np.linalg.eigh(J)
    w = V[0] ** 2
    return t, w / w.sum()


def clenshaw_curtis(n):
    """Clenshaw-Curtis nodes on [0, 1] and probability weights (exact to degree n - 1).

    The nodes :math:`(1 - \\cos(\\pi k/(n - 1)))/2`, nested from one level of a sparse grid
    to the next (:math:`2^{l-1} + 1` points); the weights solve the moment equations
    :math:`\\mathbb E[L_m] = \\delta_{m0}` in the orthonormal Legendre basis.

    Parameters
    ----------
    n : int

    Returns
    -------
    nodes, weights : (n,) ndarray
    """
    if n == 1:
        return np.array([0.5]), np.array([1.0])
    x = 0.5 * (1.0 - np.cos(np.pi * np.arange(n) / (n - 1)))
    # weights from the moment equations E[L_m] = delta_m0 in the orthonormal Legendre basis
    V = legendre_table(np.ascontiguousarray(x), n - 1)
    e0 = np.zeros(n)
    e0[0] = 1.0
    w = np.linalg.solve(V.T, e0)
    return x, w


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
