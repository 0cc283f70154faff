"""Expectation tensors of the stochastic Galerkin projection (paper Section 3.3, Eq. ``pce``).

Projecting a model onto the chaos basis needs

- :math:`\\mathbb{E}[\\Psi_k]` (the mean, Eq. for :math:`\\mu_i`),
- :math:`\\mathbb{E}[\\Psi_i \\Psi_j]` (the variance, and linear deterministic operators),
- :math:`\\mathbb{E}[\\Psi_i \\Psi_j \\Psi_k]` (quadratic nonlinearities such as
  :math:`\\mathbf{A} : \\theta \\otimes \\theta` with a random state),
- :math:`\\mathbb{E}[g(\\omega) \\Psi_k \\Psi_l]` (an operator that depends on the germ, e.g.
  the beam stiffness :math:`K^B(\\omega)` in Eq. ``pce``).

The triple product is computed exactly (to round-off, never from raw moments): the 1-D
table comes from the Adams-Neumann closed form, and the multivariate tensor is the product
of 1-D factors over the variables, :math:`T_{abc} = \\prod_d t_{\\alpha_d \\beta_d \\gamma_d}`.
"""

from __future__ import annotations

import math

import numpy as np

from .._validation import as_finite_array, check_choice, check_int
from ..memory import check_allocation
from ._kernels import (
    triple_1d,
    triple_cross,
    triple_dense_mixed,
    triple_sparse_mixed,
)
from .basis import ChaosBasis

__all__ = [
    "GaussNodes",
    "SparseTensor3",
    "common_eigenbasis",
    "coupling_tensor",
    "expectation_tensor",
    "lognormal_coefficients",
    "weighted_gram",
]


def _check_basis(basis):
    if not isinstance(basis, ChaosBasis):
        raise TypeError(
            f"`basis` must be a ChaosBasis, got {type(basis).__name__}; "
            "build one with ChaosBasis(order, dim)"
        )
    return basis


def triple_product_1d(order, normalized=True):
    """Exact 1-D table t[i, j, k] = E[L_i L_j L_k] for i, j, k <= ``order``.

    Parameters
    ----------
    order : int
        Maximal degree p >= 0.
    normalized : bool, optional
        Orthonormal (default) or unnormalised shifted Legendre polynomials.

    Returns
    -------
    t : (p + 1, p + 1, p + 1) ndarray
        Symmetric; exact zeros where i + j + k is odd or the triangle rule fails.

    Notes
    -----
    Adams-Neumann closed form: with :math:`s = (i + j + k)/2` and
    :math:`A(n) = \\prod_{m=1}^{n} \\frac{2m - 1}{2m} = \\frac{(2n)!}{4^n (n!)^2}`,

    .. math:: \\mathbb{E}[P_i P_j P_k] = \\frac{A(s - i)\\, A(s - j)\\, A(s - k)}
              {(2s + 1)\\, A(s)}

    for :math:`i + j + k` even and :math:`|i - j| \\le k \\le i + j`, and 0 otherwise; the
    orthonormal table multiplies by :math:`\\sqrt{(2i + 1)(2j + 1)(2k + 1)}`. :math:`A(n)` is a
    product of factors in [1/2, 1), free of cancellation, so the float result is accurate to
    a few ulps at any order (a
    Gauss-Legendre evaluation of the same integral is only good to ~1e-13 at order 20,
    limited by the accuracy of the nodes and weights).
    """
    order = check_int("order", order, minimum=0)
    if not isinstance(normalized, bool | np.bool_):
        raise TypeError(f"`normalized` must be True or False, got {normalized!r}")
    return triple_1d(order, bool(normalized))


class SparseTensor3:
    """Third-order tensor in coordinate form, built from structural (symbolic) zeros.

    Parameters
    ----------
    indices : (nnz, 3) array_like of int
        Coordinates (i, j, k) of the stored entries, each in ``range(P)``.
    values : (nnz,) array_like of float
        Entry values.
    shape : tuple of int
        ``(P, P, P)``.

    Attributes
    ----------
    indices : (nnz, 3) ndarray of int64
    values : (nnz,) ndarray
    shape : tuple of int
    nnz : int

    Notes
    -----
    All index permutations are stored explicitly, so :meth:`contract` needs no symmetry
    bookkeeping. Which entries are stored is decided by the Legendre selection rules
    (parity and triangle inequality per variable), never by thresholding values: an entry
    is stored if and only if it is nonzero in exact arithmetic.
    """

    def __init__(self, indices, values, shape):
        shape = tuple(check_int("shape", s, minimum=1) for s in shape)
        if len(shape) != 3:
            raise ValueError(f"`shape` must have 3 entries, got {shape}")
        idx = np.asarray(indices)
        if idx.ndim != 2 or idx.shape[1] != 3 or not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"`indices` must be an (nnz, 3) integer array, got {idx.shape}")
        val = as_finite_array("values", values, shape=(idx.shape[0],))
        if idx.size and (idx.min() < 0 or np.any(idx.max(axis=0) >= np.array(shape))):
            raise ValueError(f"`indices` out of range for shape {shape}")
        self.indices = idx.astype(np.int64, copy=False)
        self.values = val
        self.shape = shape
        i, j, k = self.indices.T
        # Flat (i, k) position used by contract_matrix.
        self._ik = i * shape[2] + k

    @property
    def nnz(self):
        """Number of stored entries."""
        return self.values.shape[0]

    def __repr__(self):
        return f"SparseTensor3(shape={self.shape}, nnz={self.nnz})"

    def todense(self):
        """Dense copy, shape ``self.shape``."""
        T = np.zeros(self.shape)
        i, j, k = self.indices.T
        T[i, j, k] = self.values
        return T

    def contract(self, x, y):
        """Contract the last two indices with vectors.

        .. math:: \\mathrm{out}_i = \\sum_{j,k} T_{ijk}\\, x_j\\, y_k

        Parameters
        ----------
        x : (P,) array_like
        y : (P,) array_like

        Returns
        -------
        out : (P,) ndarray
        """
        x = as_finite_array("x", x, shape=(self.shape[1],))
        y = as_finite_array("y", y, shape=(self.shape[2],))
        i, j, k = self.indices.T
        return np.bincount(i, weights=self.values * x[j] * y[k], minlength=self.shape[0])

    def contract_matrix(self, x):
        """Contract the middle index with a vector.

        .. math:: \\mathrm{out}_{ik} = \\sum_j T_{ijk}\\, x_j

        This is the Jacobian block of :math:`\\sum_{jk} T_{ijk} x_j x_k` up to a factor 2
        for a symmetric tensor.

        Parameters
        ----------
        x : (P,) array_like

        Returns
        -------
        out : (P, P) ndarray
        """
        x = as_finite_array("x", x, shape=(self.shape[1],))
        j = self.indices[:, 1]
        n0, n2 = self.shape[0], self.shape[2]
        flat = np.bincount(self._ik, weights=self.values * x[j], minlength=n0 * n2)
        return flat.reshape(n0, n2)


def expectation_tensor(basis, rank, *, sparse=False):
    """Expectation of products of 1, 2 or 3 basis terms.

    Parameters
    ----------
    basis : ChaosBasis
        The chaos basis, with P terms.
    rank : {1, 2, 3}
        Number of factors.
    sparse : bool, optional
        For ``rank=3`` only: return a :class:`SparseTensor3` holding the structurally
        nonzero entries. Default False (dense ndarray). The dense tensor has P**3 entries
        (187 MB at P = 286, i.e. 3 variables at order 10); prefer the sparse form there.

    Returns
    -------
    E : (P,) or (P, P) or (P, P, P) ndarray, or SparseTensor3
        - rank 1: :math:`\\mathbb{E}[\\Psi_k] = \\delta_{k0}`;
        - rank 2: :math:`\\mathbb{E}[\\Psi_i \\Psi_j] = \\delta_{ij}\\, \\mathbb{E}[\\Psi_i^2]`;
        - rank 3: :math:`\\mathbb{E}[\\Psi_a \\Psi_b \\Psi_c]`.

    Raises
    ------
    TypeError
        If ``basis`` is not a ChaosBasis, ``rank`` is not an int or ``sparse`` not a bool.
    ValueError
        If ``rank`` is not 1, 2 or 3, or ``sparse=True`` with ``rank != 3``.

    Notes
    -----
    For multi-indices :math:`\\alpha, \\beta, \\gamma` of the terms a, b, c,

    .. math:: \\mathbb{E}[\\Psi_a \\Psi_b \\Psi_c]
              = \\prod_{d=1}^{\\mathrm{dim}} t_{\\alpha_d \\beta_d \\gamma_d},
              \\qquad t_{ijk} = \\int_0^1 L_i L_j L_k \\, d\\omega,

    with the 1-D table :math:`t` in closed form (:func:`triple_product_1d`).
    :math:`t_{ijk} \\neq 0` exactly when :math:`i + j + k` is even and
    :math:`|i - j| \\le k \\le i + j`; both the dense zeros and the sparse pattern
    follow from this rule.

    Other germs (``basis.germs``) use their own exact 1-D tables
    (:meth:`~ecfm_uq.chaos.Germ.triple`: the Hermite closed form, the Jacobi-matrix
    linearisation for Laguerre and Jacobi); the sparse pattern keeps the triangle rule for
    every germ and the parity rule for symmetric ones (Legendre, Hermite, Jacobi a = b).

    Examples
    --------
    >>> T = expectation_tensor(ChaosBasis(3), 3)
    >>> round(float(T[1, 1, 2]), 12)  # 2 / sqrt(5)
    0.894427191
    """
    basis = _check_basis(basis)
    rank = check_int("rank", rank)
    check_choice("rank", rank, (1, 2, 3))
    if not isinstance(sparse, bool | np.bool_):
        raise TypeError(f"`sparse` must be True or False, got {sparse!r}")
    if sparse and rank != 3:
        raise ValueError(f"`sparse=True` is only available for rank 3, got rank={rank}")

    P = basis.size
    if rank == 1:
        e = np.zeros(P)
        e[0] = 1.0  # Psi_0 = 1 and every other term has zero mean.
        return e
    if rank == 2:
        check_allocation(
            8.0 * P * P,
            f"the (P, P) Gram matrix E[Psi_k Psi_l] at P={P}",
            "lower the chaos `order` or `dim`",
        )
        return np.diag(np.asarray(basis.norms2, dtype=float))

    alpha = np.ascontiguousarray(basis.indices)
    tables, parity = _stacked_tables(basis.germs, basis.order, basis.normalized)
    if sparse:
        idx, val = triple_sparse_mixed(alpha, tables, parity)
        return SparseTensor3(idx, val, (P, P, P))
    check_allocation(
        8.0 * P**3,
        f"the dense (P, P, P) tensor E[Psi_a Psi_b Psi_c] at P={P}",
        "pass sparse=True for a SparseTensor3, or lower the chaos `order` or `dim`",
    )
    return triple_dense_mixed(alpha, tables)


def _stacked_tables(germs, order, normalized=True):
    """Each germ's exact 1-D triple products to ``order``, stacked (dim, p+1, p+1, p+1),
    and which germs are symmetric (their parity rule holds)."""
    cache = {}
    for g in germs:
        if g not in cache:
            cache[g] = g.triple(order, normalized)
    return np.stack([cache[g] for g in germs]), np.array([g.symmetric for g in germs])


def coupling_tensor(coef_basis, basis):
    """:math:`\\mathbb E[\\phi_a \\Psi_i \\Psi_j]`: a coefficient's chaos terms against the basis.

    A random coefficient expanded on its own chaos, :math:`a(\\xi) = \\sum_a a_a
    \\phi_a(\\xi)` (e.g. a lognormal field in Hermite chaos, which needs about twice the
    order of the solution), enters the Galerkin system through
    :math:`\\mathbb E[a\\,\\Psi\\Psi^T] = \\sum_a a_a\\, T[a]`; each slice ``T[a]`` is the
    coupling ``G`` of one term :math:`K_a \\otimes G_a`.

    Parameters
    ----------
    coef_basis : ChaosBasis
        The coefficient's basis (same dim and germs as ``basis``, any order), Pa terms.
    basis : ChaosBasis
        The solution's basis, P terms.

    Returns
    -------
    T : (Pa, P, P) ndarray
        Exact (the germs' closed-form or Jacobi-matrix triple products), symmetric in the
        last two indices.
    """
    coef_basis = _check_basis(coef_basis)
    basis = _check_basis(basis)
    if coef_basis.germs != basis.germs or not (coef_basis.normalized and basis.normalized):
        raise ValueError(
            "`coef_basis` and `basis` must share dim and germs and be orthonormal; got "
            f"{coef_basis!r} and {basis!r}"
        )
    Pa, P = coef_basis.size, basis.size
    check_allocation(
        8.0 * Pa * P * P,
        f"the (Pa, P, P) coupling tensor at Pa={Pa}, P={P}",
        "lower the coefficient's or the solution's order",
    )
    tables, _ = _stacked_tables(basis.germs, max(coef_basis.order, basis.order))
    return triple_cross(
        np.ascontiguousarray(coef_basis.indices), np.ascontiguousarray(basis.indices), tables
    )


def lognormal_coefficients(coef_basis, b, mean=0.0):
    """Hermite chaos coefficients of :math:`\\exp(m + b\\cdot\\xi)`, exactly.

    Parameters
    ----------
    coef_basis : ChaosBasis
        With Hermite germs only (:math:`\\xi \\sim N(0, I)`), Pa terms.
    b : (..., dim) array_like
        Loadings, e.g. :math:`\\sqrt{\\lambda_k}\\,\\phi_k(x)` of a Karhunen-Loeve
        expansion at points x (leading axes).
    mean : float or (...) array_like
        :math:`m`, e.g. the Gaussian field's mean at those points.

    Returns
    -------
    (..., Pa) ndarray
        :math:`a_\\alpha = e^{m + |b|^2/2} \\prod_k b_k^{\\alpha_k} / \\sqrt{\\alpha_k!}`.

    Notes
    -----
    From the generating function :math:`e^{b\\xi - b^2/2} = \\sum_n b^n He_n(\\xi)/n!` and
    :math:`\\psi_n = He_n/\\sqrt{n!}`; the truncation at total order p leaves out
    :math:`e^{2m + |b|^2}\\sum_{|\\alpha| > p} \\prod_k b_k^{2\\alpha_k}/\\alpha_k!` of the
    second moment.
    """
    coef_basis = _check_basis(coef_basis)
    if any(g.family != "hermite" for g in coef_basis.germs) or not coef_basis.normalized:
        raise ValueError(
            f"`coef_basis` must be an orthonormal Hermite basis (germ='hermite'), got {coef_basis!r}"
        )
    b = as_finite_array("b", b)
    if b.ndim == 0 or b.shape[-1] != coef_basis.dim:
        raise ValueError(f"`b` must have shape (..., {coef_basis.dim}), got {b.shape}")
    mean = as_finite_array("mean", mean)
    alpha = np.asarray(coef_basis.indices)
    log_fact = np.array([math.lgamma(k + 1.0) for k in range(coef_basis.order + 1)])
    out = np.exp(mean + 0.5 * np.sum(b**2, axis=-1))[..., None] * np.ones(coef_basis.size)
    for d in range(coef_basis.dim):
        powers = b[..., d, None] ** alpha[:, d]  # 0 ** 0 = 1
        out = out * powers * np.exp(-0.5 * log_fact[alpha[:, d]])
    return out


def weighted_gram(basis, g, n_points=None):
    """Germ-weighted Gram matrix :math:`\\mathbb{E}[g(\\omega)\\, \\Psi_k \\Psi_l]`.

    Parameters
    ----------
    basis : ChaosBasis
        The chaos basis, with P terms.
    g : callable or (n,) array_like
        Either a function of the germ, called as ``g(omega)`` with ``omega`` of shape
        (n, dim) for every ``dim`` (so ``lambda w: w[:, 0]`` is the first germ whatever
        the dimension), returning n finite values (shape (n,), or (n, 1)); or the values
        of g at the nodes of ``basis.quadrature(n_points)``, in that order.
    n_points : int, optional
        Gauss-Legendre nodes per variable. Default as in :meth:`ChaosBasis.quadrature`,
        exact for polynomial g of degree <= order + 2 per variable; raise it for
        non-polynomial g.

    Returns
    -------
    G : (P, P) ndarray
        Symmetric matrix.

    Raises
    ------
    TypeError
        If ``g`` is neither callable nor array-like, or ``basis`` is not a ChaosBasis.
    ValueError
        If the values of ``g`` are non-finite or do not match the number of nodes.

    Notes
    -----
    .. math:: G_{kl} = \\mathbb{E}[g\\, \\Psi_k \\Psi_l]
              \\approx \\sum_q w_q\\, g(\\omega_q)\\, \\Psi_k(\\omega_q)\\, \\Psi_l(\\omega_q).

    This is the stochastic stiffness integral of paper Eq. ``pce`` for a coefficient
    affine in g, e.g. :math:`K^B(\\omega) = K_0 + g(\\omega) K_1`.
    """
    basis = _check_basis(basis)
    nodes, weights = basis.quadrature(n_points)
    n = weights.shape[0]
    check_allocation(
        8.0 * 2 * n * basis.size,
        f"weighted_gram's basis values on {n} quadrature nodes x P={basis.size} terms",
        "pass a smaller `n_points`, or lower the chaos `order` or `dim`",
    )
    if callable(g):
        arg = nodes
        out = g(arg.copy())
        try:
            vals = np.asarray(out, dtype=float)
        except (TypeError, ValueError) as e:
            raise TypeError(f"`g` must return real numbers, got {type(out).__name__}") from e
        if vals.shape == (n, 1):
            vals = vals[:, 0]  # e.g. ``lambda w: w`` for one germ
        if vals.shape != (n,):
            raise ValueError(
                f"`g` must return an array of shape ({n},) for omega of shape {arg.shape}, "
                f"got shape {vals.shape}"
            )
        if not np.all(np.isfinite(vals)):
            raise ValueError("`g` returned NaN or inf at some quadrature node; it must be finite")
    elif isinstance(g, np.ndarray | list | tuple):
        vals = as_finite_array("g", g)
        if vals.shape != (n,):
            raise ValueError(
                f"`g` as samples must have shape ({n},), one value per node of "
                f"basis.quadrature(n_points={n_points}), got {vals.shape}"
            )
    else:
        raise TypeError(
            f"`g` must be a callable g(omega) or an array of its values at the quadrature "
            f"nodes, got {type(g).__name__}"
        )
    Psi = basis.evaluate(nodes)
    G = Psi.T @ (Psi * (weights * vals)[:, None])
    return 0.5 * (G + G.T)


def common_eigenbasis(couplings, tol=1e-11):
    """An orthonormal basis diagonalizing every coupling matrix at once, if there is one.

    Couplings :math:`G_q = \\mathbb E[g_q\\Psi\\Psi^T]` are symmetric; when they commute
    (e.g. every coupling is affine in one germ: :math:`\\mathbb E[\\omega\\Psi\\Psi^T]` is
    the Jacobi matrix, whose eigenvectors sit at the Gauss nodes), :math:`G_q = Q D_q Q^T`
    with one orthogonal :math:`Q`. Block systems :math:`\\sum_q K_q\\otimes G_q` then split
    into ``P`` independent ``N x N`` systems.

    Parameters
    ----------
    couplings : sequence of (P, P) ndarray
    tol : float
        Off-diagonal entries of :math:`Q^T G_q Q` above ``tol * max|G_q|`` mean no common
        basis.

    Returns
    -------
    (Q (P, P), D (n, P)) or None
        ``D[q]`` the eigenvalues of ``couplings[q]`` in the columns of ``Q``.
    """
    Gs = [np.asarray(G, dtype=float) for G in couplings]
    if not Gs:
        return None
    # a generic combination has simple eigenvalues whenever a common eigenbasis exists
    combo = sum((1.0 + 0.618034 * q) * G / max(np.abs(G).max(), 1e-300) for q, G in enumerate(Gs))
    _, Q = np.linalg.eigh(0.5 * (combo + combo.T))
    D = []
    for G in Gs:
        H = Q.T @ G @ Q
        d = np.diag(H).copy()
        if np.abs(H - np.diag(d)).max() > tol * max(np.abs(G).max(), 1e-300):
            return None
        D.append(d)
    return Q, np.array(D)


class GaussNodes:
    """Chaos coefficients and values at the germ's ``P``-node Gauss rule (one germ).

    For a one-germ basis of ``P = p + 1`` terms, the ``P``-node Gauss-Legendre rule is
    exact for products of two basis terms, so :math:`\\Phi^T W \\Phi = D` with
    :math:`\\Phi_{kb} = \\Psi_b(\\omega_k)`, :math:`W = \\mathrm{diag}(w)`,
    :math:`D = \\mathrm{diag}(\\mathbb E[\\Psi_b^2])`, and :math:`\\Phi` is invertible:
    :math:`\\Phi^{-1} = D^{-1}\\Phi^T W`. A Galerkin operator
    :math:`\\mathbb E[g\\,\\Psi\\Psi^T]` evaluated with this rule instead of exactly is
    :math:`\\Phi^T W \\mathrm{diag}(g(\\omega_k))\\,\\Phi`: in node values it is diagonal
    (Galerkin with the quadrature's aliasing is collocation). The solver layer builds its
    node-wise preconditioner from this (:class:`ecfm_uq.system.solve.linear.NodalPreconditioner`).

    Parameters
    ----------
    basis : ChaosBasis
        With ``dim == 1``.

    Attributes
    ----------
    nodes, weights : (P,) ndarray
        Gauss nodes of the germ (Gauss-Legendre on [0, 1] for the uniform germ) and
        probability weights.
    Phi : (P, P) ndarray
        ``Phi[k, b]`` = :math:`\\Psi_b(\\omega_k)`; node values of a state ``Theta``
        (N, P) are ``Theta @ Phi.T``.
    to_nodes : (P, P) ndarray
        :math:`D^{-1}\\Phi^T`: a Galerkin residual's columns (N, P) times this are the
        node residuals divided by the weights, :math:`r_k` with
        :math:`R = \\sum_k w_k r_k \\Phi_{k,:}`.
    from_nodes : (P, P) ndarray
        :math:`W\\Phi D^{-1}`: node values (N, P) times this are chaos coefficients
        (the inverse of ``Phi.T``).
    """

    def __init__(self, basis):
        _check_basis(basis)
        if basis.dim != 1 or basis.size != basis.order + 1:
            raise ValueError(
                f"GaussNodes needs a one-germ basis (dim=1), got dim={basis.dim}; the "
                "node-wise form of a multi-germ basis has more nodes than terms"
            )
        P = basis.size
        self.nodes, self.weights = basis.germs[0].gauss(P)
        self.Phi = basis.evaluate(self.nodes)
        dinv = 1.0 / np.asarray(basis.norms2, dtype=float)
        self.to_nodes = np.ascontiguousarray(dinv[:, None] * self.Phi.T)
        self.from_nodes = np.ascontiguousarray(self.weights[:, None] * self.Phi * dinv[None, :])

    def coupling_values(self, G):
        """Node values of a coupling :math:`G = \\mathbb E[g\\Psi\\Psi^T]`.

        The diagonal of :math:`\\Phi^{-T} G\\,\\Phi^{-1}` over the weights, i.e.
        :math:`\\mathbb E[g L_k^2]/w_k` with :math:`L_k` the Lagrange polynomial of node
        :math:`k`: a local average of ``g`` around :math:`\\omega_k`, equal to
        :math:`g(\\omega_k)` when ``g`` is affine in the germ.
        """
        G = as_finite_array("G", G, ndim=2)
        P = self.Phi.shape[0]
        if G.shape != (P, P):
            raise ValueError(f"`G` must have shape {(P, P)}, got {G.shape}")
        A = self.to_nodes.T @ G @ self.to_nodes  # Phi D^-1 G D^-1 Phi^T
        return self.weights * np.diag(A)
