"""Leave-one-out errors of least-squares fits, nested along a regression path.

The corrected leave-one-out error (Blatman & Sudret 2011) of every nested OLS refit
along a LAR/OMP path (:mod:`.paths`), all at once from one QR or one Cholesky factor:
in design form (:func:`loo_nested`), or in Gram form a block of rows at a time
(:func:`loo_nested_rows`, :class:`NestedLooRows`), so no (n, s) array is held.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.linalg as sla
from scipy.linalg.blas import dtrmm
from scipy.linalg.lapack import dpotrf

from .compression import row_blocks

__all__ = [
    "CHOLESKY_RTOL",
    "NestedLooRows",
    "cholesky_prefix",
    "loo_nested",
    "loo_nested_rows",
    "nested_loo_rows",
]

# Gram path: a selected column whose Cholesky pivot falls below this share of its norm is
# numerically dependent on the earlier ones (the Gram squares the conditioning).
CHOLESKY_RTOL = 1e-6


@numba.njit(cache=True, fastmath={"reassoc"})  # the sums over rows in SIMD lanes
def nested_loo_rows(QT, z, y, fitted, h, sums):
    """Add the squared LOO residuals of nested fits, over a block of rows, to ``sums``.

    ``QT`` (m, b) holds the next m columns of :math:`Q = X R^{-1}` at b rows (one column per
    row of QT), ``z`` their m coefficients :math:`Q^T y`, ``fitted`` and ``h`` the fitted
    values and hat diagonals of the b rows from the earlier columns (updated in place to
    include these). For column k the fit's residual :math:`r = y - f^{(k)}` and hat value
    :math:`h^{(k)}` continue cumulative sums; ``sums[k] += sum_i (r_i / (1 - h_i))^2``, or
    inf where :math:`1 - h_i \\le 10^{-10}`. One pass over QT instead of a dozen array
    passes; the sum over the rows may be reassociated (vectorised: three times faster),
    which changes the sums by rounding only (a few 1e-15 relative); infinities and NaNs
    propagate as in IEEE arithmetic.
    """
    m, b = QT.shape
    cf = np.zeros(b)
    ch = np.zeros(b)
    for k in range(m):
        zk = z[k]
        acc = 0.0
        for i in range(b):
            q = QT[k, i]
            cf[i] += q * zk
            ch[i] += q * q
            one_h = 1.0 - (ch[i] + h[i])
            if one_h <= 1e-10:
                acc += np.inf
            else:
                e = (y[i] - (cf[i] + fitted[i])) / one_h
                acc += e * e
        sums[k] += acc
    for i in range(b):
        fitted[i] += cf[i]
        h[i] += ch[i]


def loo_nested(Q, R, y):
    """Corrected LOO errors of the OLS fits on the first k = 1..s columns, all at once.

    With :math:`X = QR` (economic), the fit on the first k columns uses :math:`Q_k`, so the
    hat diagonals and residuals of all nested fits are cumulative sums:
    :math:`h^{(k)}_i = \\sum_{j<k} Q_{ij}^2`, :math:`r^{(k)} = y - \\sum_{j<k} Q_j (Q_j^T y)`.
    The LOO residual is :math:`r_i / (1 - h_i)` (no refits), normalised by the sample
    variance, and multiplied by Chapelle's correction (Blatman & Sudret 2011)

    .. math:: T(k, n) = \\frac{n}{n - k}\\Bigl(1 + \\operatorname{tr}(C^{-1})/n\\Bigr),
              \\qquad C = X_k^T X_k / n,\\quad \\operatorname{tr}(C^{-1})/n = \\|R_k^{-1}\\|_F^2.

    Returns
    -------
    loo, corrected : (s,) ndarray
    """
    n, s = Q.shape
    z = Q.T @ y
    fitted = np.cumsum(Q * z[None, :], axis=1)
    h = np.cumsum(Q**2, axis=1)
    resid = y[:, None] - fitted
    one_h = 1.0 - h
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(one_h > 1e-10, resid / one_h, np.inf)
    var = np.var(y) if np.var(y) > 0 else 1.0
    loo = np.mean(e**2, axis=0) / var
    Rinv = sla.solve_triangular(R, np.eye(s))
    trace = np.cumsum(np.sum(np.triu(Rinv) ** 2, axis=0))
    k = np.arange(1, s + 1)
    with np.errstate(divide="ignore"):
        T = np.where(k < n, n / np.maximum(n - k, 1) * (1.0 + trace), np.inf)
    return loo, loo * T


def cholesky_prefix(G):
    """Upper Cholesky factor of the longest leading block of G that is well conditioned.

    Returns R (s, s) with :math:`R^T R = G_{:s,:s}`, stopping before the first column whose
    pivot is below ``CHOLESKY_RTOL`` of its norm (dependent on the earlier columns).
    """
    s = G.shape[0]
    while s > 0:
        R, info = dpotrf(G[:s, :s], lower=0, clean=1)
        if info > 0:
            s = info - 1
            continue
        d = np.abs(np.diag(R))
        bad = np.flatnonzero(d < CHOLESKY_RTOL * np.sqrt(np.abs(np.diag(G)[:s])))
        if bad.size:
            s = int(bad[0])
            continue
        return R
    raise ValueError("the constant regression column is zero; check the samples")


def loo_nested_rows(rows, y, R, z):
    """Corrected LOO errors of :func:`loo_nested` from :math:`R^T R = X^T X`, in row blocks.

    ``rows(a, b)`` returns the rows a..b-1 of the selected columns X (n, s) and
    :math:`z = R^{-T} X^T y`; :math:`Q = X R^{-1}` is formed a block of rows at a time, so
    only (block, s) arrays are held. Returns the corrected errors (s,).
    """
    n, s = len(y), R.shape[0]
    sum_e2 = np.zeros(s)
    for a, b in row_blocks(n, 4 * s):
        Q = sla.solve_triangular(R, rows(a, b).T, trans="T", check_finite=False).T
        fitted = np.cumsum(Q * z[None, :], axis=1)
        h = np.cumsum(Q**2, axis=1)
        one_h = 1.0 - h
        with np.errstate(divide="ignore", invalid="ignore"):
            e = np.where(one_h > 1e-10, (y[a:b, None] - fitted) / one_h, np.inf)
        sum_e2 += np.sum(e**2, axis=0)
    var = np.var(y) if np.var(y) > 0 else 1.0
    loo = sum_e2 / n / var
    Rinv = sla.solve_triangular(R, np.eye(s))
    trace = np.cumsum(np.sum(np.triu(Rinv) ** 2, axis=0))
    k = np.arange(1, s + 1)
    with np.errstate(divide="ignore"):
        T = np.where(k < n, n / np.maximum(n - k, 1) * (1.0 + trace), np.inf)
    return loo * T


class NestedLooRows:
    """Corrected LOO errors of nested fits in Gram form, extended as a path grows.

    For the columns ``cols`` of ``design`` (column 0 the constant) with Gram matrix
    :math:`G` and :math:`b = \\Psi^T y`: :math:`R^T R = G_{cols, cols}` (Cholesky, up to the
    first dependent column), :math:`z = R^{-T} b_{cols}`, and the errors of
    :func:`loo_nested` with :math:`Q = X R^{-1}`. A later call with a longer ``cols``
    (the same prefix: a path run further) evaluates the new columns only,
    :math:`Q_{:, k_0:s} = X_{:, :s} (R^{-1})_{:s, k_0:s}`, continuing each run's hat
    diagonal and fitted value from the ones kept after the last call (two n-vectors), in
    blocks of rows: no (n, s) array is held.
    """

    def __init__(self, design, y, G, b):
        self.design, self.y, self.G, self.b = design, y, G, b
        self.columns = design.T  # C-ordered (no copy) for the column-major design
        n = len(y)
        self.h = np.zeros(n)
        self.fitted = np.zeros(n)
        self.sum_e2 = np.zeros(0)

    def errors(self, cols):
        """(R, z, corrected) of the nested fits on the leading columns of ``cols``."""
        y, n = self.y, len(self.y)
        R = cholesky_prefix(self.G[np.ix_(cols, cols)])
        s = R.shape[0]
        z = sla.solve_triangular(R, self.b[cols[:s]], trans="T")
        Rinv = sla.solve_triangular(R, np.eye(s))
        k0 = len(self.sum_e2)
        if s > k0:
            sel = cols[:s]
            W = Rinv[:, k0:]
            new = np.zeros(s - k0)
            for a, b in row_blocks(n, 4 * s):
                # the block's rows of the selected columns, one column per row (C order):
                # the nested sums then run along contiguous rows
                XT = self.columns[sel, a:b]
                if k0:
                    QT = W.T @ XT
                else:  # all columns: Q = X R^{-1} by a triangular product, half the flops
                    QT = dtrmm(1.0, Rinv, XT.T, side=1, overwrite_b=1).T
                nested_loo_rows(QT, z[k0:], y[a:b], self.fitted[a:b], self.h[a:b], new)
            self.sum_e2 = np.concatenate([self.sum_e2, new])
        var = np.var(y) if np.var(y) > 0 else 1.0
        loo = self.sum_e2[:s] / n / var
        trace = np.cumsum(np.sum(np.triu(Rinv) ** 2, axis=0))
        k = np.arange(1, s + 1)
        with np.errstate(divide="ignore"):
            T = np.where(k < n, n / np.maximum(n - k, 1) * (1.0 + trace), np.inf)
        return R, z, loo * T
