"""Polynomial chaos basis: shifted Legendre on the uniform germ, or any Askey germ.

The paper's stochastic basis (Section 3.3, expansion theta_i(omega) = Theta_ij Psi_j(omega))
is the Legendre family shifted to [0, 1], P_n(2 omega - 1), on omega ~ U(0, 1)^dim. This
module builds its multi-variate version by products over multi-indices, in orthonormal or
in the paper's unnormalised scaling; with ``germ=`` a variable may instead be a standard
normal (Hermite), gamma (Laguerre) or beta (Jacobi) germ (:mod:`ecfm_uq.chaos.germs`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .._validation import as_finite_array, check_choice, check_int
from ._kernels import legendre_table
from .germs import as_germs
from .quadrature import tensor_gauss_legendre, tensor_rule

__all__ = ["ChaosBasis", "default_n_points"]

_INDEX_SETS = ("total", "tensor")
# Round-off slack when checking that omega lies in the germ's support [0, 1].
_SUPPORT_TOL = 1e-12


def default_n_points(order):
    """Gauss points per variable that integrate degree ``3 * order`` exactly, plus one.

    An n-point rule is exact up to degree 2n - 1, so n = ceil((3 p + 1) / 2) covers the
    triple products; the extra point raises the exact degree to at least 3 p + 2, so
    :func:`~ecfm_uq.chaos.weighted_gram` is exact for a polynomial weight g of degree
    <= p + 2.
    """
    return (3 * order + 2) // 2 + 1


def _total_degree_indices(order, dim):
    """Multi-indices with |alpha|_1 <= order, graded, then lexicographically descending."""
    out = []

    def compositions(total, parts):
        # All tuples of `parts` non-negative ints summing to `total`, first entry descending.
        if parts == 1:
            yield (total,)
            return
        for first in range(total, -1, -1):
            for rest in compositions(total - first, parts - 1):
                yield (first, *rest)

    for deg in range(order + 1):
        out.extend(compositions(deg, dim))
    return out


def _tensor_indices(order, dim):
    """Multi-indices with max(alpha) <= order, in the same graded order as the total set."""
    idx = itertools.product(range(order + 1), repeat=dim)
    return sorted(idx, key=lambda a: (sum(a), tuple(-x for x in a)))


class ChaosBasis:
    """Shifted Legendre polynomial chaos basis for omega ~ U(0, 1)^dim.

    Parameters
    ----------
    order : int
        Polynomial order p >= 0 (total degree for ``index_set="total"``, maximal degree per
        variable for ``"tensor"``). ``order=0`` gives the single term Psi_0 = 1: the
        deterministic (zero-order chaos) case.
    dim : int, optional
        Number of independent uniform variables, ``dim >= 1``. Default 1.
    index_set : {"total", "tensor"} or (P, dim) array_like of int, optional
        ``"total"``: multi-indices with :math:`|\\alpha|_1 \\le p`;
        ``"tensor"``: :math:`\\max_d \\alpha_d \\le p`. Default ``"total"``.
        An array gives the multi-indices themselves (a sparse basis, as a sparse fit
        selects it): distinct, non-negative, of total degree at most ``order``, the
        first row all zeros; ``index_set`` is then ``"custom"``.
    normalized : bool, optional
        ``True`` (default): orthonormal, :math:`\\mathbb{E}[\\Psi_k \\Psi_l] = \\delta_{kl}`.
        ``False``: the paper's unnormalised :math:`P_n(2\\omega - 1)` products, with
        :math:`\\mathbb{E}[\\Psi_k^2] = \\prod_d 1/(2\\alpha_d + 1)` (Legendre germs only).
    germ : str, Germ or sequence of them, optional
        The law of each germ variable and so its polynomial family: ``"legendre"``
        (U(0, 1), the default), ``"hermite"`` (N(0, 1)), or a
        :class:`~ecfm_uq.chaos.Germ` such as ``Germ("laguerre", shape=2.5)`` (gamma) or
        ``Germ("jacobi", a=2, b=3)`` (beta on [0, 1]); one per variable or one for all.

    Attributes
    ----------
    order, dim : int
    index_set : str
    normalized : bool
    germs : tuple of Germ
        One per variable.
    size : int
        Number of terms P (``comb(p + dim, dim)`` for the total set, ``(p + 1)**dim`` for the
        tensor set).
    indices : (P, dim) ndarray of int
        Multi-indices :math:`\\alpha^{(k)}`, graded by total degree (lexicographically
        descending within a degree); ``indices[0]`` is all zeros.
    norms2 : (P,) ndarray
        :math:`\\mathbb{E}[\\Psi_k^2]`.

    Notes
    -----
    With :math:`t = 2\\omega - 1`, Legendre polynomials obey

    .. math:: (n + 1) P_{n+1}(t) = (2n + 1)\\, t\\, P_n(t) - n P_{n-1}(t),
              \\qquad P_0 = 1,\\; P_1 = t,

    and :math:`\\mathbb{E}[P_m(2\\omega - 1) P_n(2\\omega - 1)] = \\delta_{mn}/(2n + 1)`.
    The multivariate terms are
    :math:`\\Psi_k(\\omega) = \\prod_{d} c_{\\alpha_d} P_{\\alpha_d}(2\\omega_d - 1)` with
    :math:`c_n = \\sqrt{2n + 1}` (orthonormal) or :math:`c_n = 1` (unnormalised).
    Values are computed by the recurrence, never from monomial coefficients, which would
    cancel catastrophically at high order.

    Examples
    --------
    >>> basis = ChaosBasis(2, dim=2)
    >>> basis.size
    6
    >>> basis.indices.tolist()
    [[0, 0], [1, 0], [0, 1], [2, 0], [1, 1], [0, 2]]
    """

    def __init__(self, order, dim=1, index_set="total", normalized=True, germ=None):
        self.order = check_int("order", order, minimum=0)
        self.dim = check_int("dim", dim, minimum=1)
        custom = None
        if not isinstance(index_set, str):
            custom = self._check_indices(index_set)
            index_set = "custom"
        else:
            index_set = check_choice("index_set", index_set, _INDEX_SETS)
        self.index_set = index_set
        if not isinstance(normalized, bool | np.bool_):
            raise TypeError(f"`normalized` must be True or False, got {normalized!r}")
        self.normalized = bool(normalized)
        self.germs = as_germs(germ, self.dim)
        self.is_legendre = all(g.family == "legendre" for g in self.germs)
        if not self.normalized and not self.is_legendre:
            raise ValueError(
                "`normalized=False` (the paper's unnormalised Legendre scaling) needs "
                f"Legendre germs, got germ={self.germs}; use normalized=True"
            )

        if custom is not None:
            n_terms = len(custom)
        elif self.index_set == "total":
            n_terms = math.comb(self.order + self.dim, self.dim)
        else:
            n_terms = (self.order + 1) ** self.dim
        if n_terms > 1_000_000:
            raise ValueError(
                f"order={self.order}, dim={self.dim} ({self.index_set!r}) gives {n_terms} terms; "
                "reduce `order` or `dim`"
            )
        if custom is not None:
            self.indices = custom
        else:
            gen = _total_degree_indices if self.index_set == "total" else _tensor_indices
            self.indices = np.array(gen(self.order, self.dim), dtype=np.int64)
            self.indices = self.indices.reshape(-1, self.dim)
        self.indices.setflags(write=False)

        if self.normalized:
            norms2 = np.ones(len(self.indices))
        else:
            norms2 = np.prod(1.0 / (2.0 * self.indices + 1.0), axis=1)
        norms2.setflags(write=False)
        self.norms2 = norms2

    def _check_indices(self, index_set):
        alpha = None
        if isinstance(index_set, list | tuple | np.ndarray):
            try:
                alpha = np.array(index_set)
            except ValueError:  # ragged rows
                alpha = None
        if alpha is None or alpha.dtype == object:
            raise TypeError(
                f"`index_set` must be one of {list(_INDEX_SETS)} or a (P, dim) int array of "
                f"multi-indices, got {index_set!r}"
            )
        if alpha.ndim != 2 or alpha.shape[1] != self.dim or alpha.dtype.kind not in "iu":
            raise ValueError(
                f"an `index_set` array must be (P, {self.dim}) integers, got shape "
                f"{alpha.shape} of {alpha.dtype}"
            )
        alpha = alpha.astype(np.int64)
        if len(alpha) == 0 or np.any(alpha[0] != 0):
            raise ValueError("the first row of an `index_set` array must be all zeros (the mean)")
        if np.any(alpha < 0) or np.any(alpha.sum(axis=1) > self.order):
            raise ValueError(
                f"`index_set` rows must be non-negative with total degree <= order={self.order}"
            )
        if len(np.unique(alpha, axis=0)) != len(alpha):
            raise ValueError("`index_set` rows must be distinct multi-indices")
        return alpha

    @property
    def size(self):
        """Number of terms P."""
        return self.indices.shape[0]

    def __len__(self):
        return self.size

    def __repr__(self):
        germ = "" if self.is_legendre else f", germ={list(self.germs)}"
        return (
            f"ChaosBasis(order={self.order}, dim={self.dim}, index_set={self.index_set!r}, "
            f"normalized={self.normalized}{germ})  # P = {self.size}"
        )

    def __eq__(self, other):
        if not isinstance(other, ChaosBasis):
            return NotImplemented
        same = (self.order, self.dim, self.index_set, self.normalized, self.germs) == (
            other.order,
            other.dim,
            other.index_set,
            other.normalized,
            other.germs,
        )
        if same and self.index_set == "custom":
            return bool(np.array_equal(self.indices, other.indices))
        return same

    def __hash__(self):
        return hash((self.order, self.dim, self.index_set, self.normalized, self.germs))

    def _as_points(self, omega):
        """Validate ``omega`` and return it as a C-contiguous (n, dim) float array."""
        arr = as_finite_array("omega", omega)
        if arr.ndim == 1 and self.dim == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != self.dim:
            want = "(n,) or (n, 1)" if self.dim == 1 else f"(n, {self.dim})"
            raise ValueError(f"`omega` must have shape {want} for dim={self.dim}, got {arr.shape}")
        if self.is_legendre:
            if arr.size and (arr.min() < -_SUPPORT_TOL or arr.max() > 1.0 + _SUPPORT_TOL):
                raise ValueError(
                    "`omega` must lie in the germ's support [0, 1] (omega ~ U(0, 1)); "
                    f"got values in [{arr.min():.6g}, {arr.max():.6g}]. Map samples from "
                    "[-1, 1] with (x + 1) / 2"
                )
        elif arr.size:
            for d, g in enumerate(self.germs):
                lo, hi = g.support
                col = arr[:, d]
                if col.min() < lo - _SUPPORT_TOL or col.max() > hi + _SUPPORT_TOL:
                    raise ValueError(
                        f"`omega` column {d} must lie in the support [{lo:g}, {hi:g}] of its "
                        f"germ {g!r}; got values in [{col.min():.6g}, {col.max():.6g}]"
                    )
        return np.ascontiguousarray(arr)

    def univariate(self, omega):
        """Per-variable orthonormal tables, shape (dim, n, order + 1).

        ``out[d, q, m]`` is :math:`\\sqrt{2m + 1} P_m(2\\omega_{qd} - 1)` for a Legendre
        germ (unnormalised bases are rescaled in :meth:`evaluate`, not here) and the
        orthonormal polynomial of degree m of germ d otherwise.
        """
        pts = self._as_points(omega)
        if self.is_legendre:
            return np.stack(
                [
                    legendre_table(np.ascontiguousarray(pts[:, d]), self.order)
                    for d in range(self.dim)
                ]
            )
        return np.stack([g.table(pts[:, d], self.order) for d, g in enumerate(self.germs)])

    def evaluate(self, omega):
        """Values of every basis term at the points ``omega``.

        Parameters
        ----------
        omega : (n,) or (n, dim) array_like
            Points in [0, 1]^dim; a 1-D array is accepted when ``dim == 1``.

        Returns
        -------
        Psi : (n, P) ndarray
            ``Psi[q, k]`` = :math:`\\Psi_k(\\omega_q)`.

        Raises
        ------
        ValueError
            If ``omega`` is misshaped, non-finite or outside [0, 1].
        """
        tables = self.univariate(omega)
        n = tables.shape[1]
        Psi = np.ones((n, self.size))
        for d in range(self.dim):
            Psi *= tables[d][:, self.indices[:, d]]
        if not self.normalized:
            Psi *= np.sqrt(self.norms2)
        return Psi

    def __call__(self, omega):
        return self.evaluate(omega)

    def quadrature(self, n_points=None):
        """Tensor-product Gauss rule of the germs (Gauss-Legendre for U(0, 1)^dim).

        Parameters
        ----------
        n_points : int, optional
            Nodes per variable. Default :func:`default_n_points` ``(order)``, i.e.
            ``ceil((3 order + 1) / 2) + 1``, exact for polynomial integrands of degree
            ``3 * order + 2`` in each variable (all triple products of the basis).

        Returns
        -------
        nodes : (n_points**dim, dim) ndarray
        weights : (n_points**dim,) ndarray
            Probability weights, summing to 1.
        """
        if n_points is None:
            n_points = default_n_points(self.order)
        if self.is_legendre:
            return tensor_gauss_legendre(n_points, self.dim)
        return tensor_rule([g.gauss for g in self.germs], n_points)
