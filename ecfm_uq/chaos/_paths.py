"""Sparse-regression primitives: LAR/OMP paths and nested corrected leave-one-out errors.

Shared by the fixed-candidate selection (:mod:`ecfm_uq.chaos.sparse`) and the adaptive
one (:mod:`ecfm_uq.chaos.adaptive`): the order in which candidate columns enter a
least-angle regression (Efron et al. 2004) or orthogonal matching pursuit path, in design
or Gram form, and the corrected leave-one-out errors of all nested OLS refits along it
(Blatman & Sudret 2011).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.linalg as sla
from scipy.linalg.lapack import dpotrf

from .compression import _row_blocks

# Largest candidate set per model run (both selections).
_CANDIDATES_PER_RUN = 10
# Share of the memory budget a selection may hold.
_SELECTION_SHARE = 0.5
# Gram path: a selected column whose Cholesky pivot falls below this share of its norm is
# numerically dependent on the earlier ones (the Gram squares the conditioning).
_CHOLESKY_RTOL = 1e-6
# _grow_path refits in its Gram form (Cholesky of the selected columns' Gram, leave-one-out
# in blocks of rows) when the selected columns of the design hold more than this; below,
# by a QR of those columns, as before.
_QR_BYTES = 16 * 2**20


def _loo_nested(Q, R, y):
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


def _cholesky_prefix(G):
    """Upper Cholesky factor of the longest leading block of G that is well conditioned.

    Returns R (s, s) with :math:`R^T R = G_{:s,:s}`, stopping before the first column whose
    pivot is below ``_CHOLESKY_RTOL`` of its norm (dependent on the earlier columns).
    """
    s = G.shape[0]
    while s > 0:
        R, info = dpotrf(G[:s, :s], lower=0, clean=1)
        if info > 0:
            s = info - 1
            continue
        d = np.abs(np.diag(R))
        bad = np.flatnonzero(d < _CHOLESKY_RTOL * np.sqrt(np.abs(np.diag(G)[:s])))
        if bad.size:
            s = int(bad[0])
            continue
        return R
    raise ValueError("the constant regression column is zero; check the samples")


def _loo_nested_rows(rows, y, R, z):
    """Corrected LOO errors of :func:`_loo_nested` from :math:`R^T R = X^T X`, in row blocks.

    ``rows(a, b)`` returns the rows a..b-1 of the selected columns X (n, s) and
    :math:`z = R^{-T} X^T y`; :math:`Q = X R^{-1}` is formed a block of rows at a time, so
    only (block, s) arrays are held. Returns the corrected errors (s,).
    """
    n, s = len(y), R.shape[0]
    sum_e2 = np.zeros(s)
    for a, b in _row_blocks(n, 4 * s):
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


def _path_order(X, y, max_steps, solver):
    """Order in which the columns of ``X`` enter a LARS or OMP path (nested active sets)."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import lars_path, orthogonal_mp

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        warnings.simplefilter("ignore", RuntimeWarning)
        if solver == "lars":
            _, active, _ = lars_path(X, y, method="lar", max_iter=max_steps, return_path=False)
            return list(active)[:max_steps]
        path = orthogonal_mp(X, y, n_nonzero_coefs=max_steps, return_path=True)
    path = path.reshape(X.shape[1], -1)
    # OMP only adds: the first nonzero step of each column gives its entry order
    nz = path != 0
    first = np.where(nz.any(axis=1), np.argmax(nz, axis=1), path.shape[1])
    entered = np.flatnonzero(first < path.shape[1])
    return entered[np.argsort(first[entered], kind="stable")].tolist()


def _sparse_select(Psi, y, candidates, n, solver, first_steps=None):
    """Hybrid LARS/OMP on the candidate columns: (columns, coefficients, corrected LOO).

    The path is computed on centred, unit-norm candidate columns (the constant term is
    always kept); every nested active set along it is then refitted by OLS, and the one
    with the smallest corrected leave-one-out error wins (Blatman & Sudret 2011).

    ``first_steps``: run the path in growing pieces, ``first_steps`` steps first and
    twice as many while the best set lies in the last quarter of the steps run (the
    path's prefix does not depend on where it stops, so each piece repeats the last);
    the LOO error is then minimised over the steps run, not the whole path. ``None``:
    the whole path (up to n / 2 steps) at once.
    """
    # centred and scaled in place: one copy of the candidate columns, not three
    Xc = Psi[:, candidates]
    Xc -= Xc.mean(axis=0)
    scale = np.linalg.norm(Xc, axis=0)
    scale[scale == 0] = 1.0
    Xc /= scale
    # beyond n / 2 terms the LOO correction factor exceeds 2: such fits never win
    max_steps = min(len(candidates), max(n // 2, 2))
    steps = max_steps if first_steps is None else min(max_steps, max(int(first_steps), 8))
    if first_steps is not None and solver == "lars" and len(candidates) <= n:
        # tall: LAR in its Gram form, a few small matrix-vector products per step
        G, c = Xc.T @ Xc, Xc.T @ (y - y.mean())

        def path(steps):
            return _lar_order_gram(G, c, steps)
    else:

        def path(steps):
            return _path_order(Xc, y - y.mean(), steps, solver)

    return _grow_path(path, Psi, candidates, y, steps, max_steps)


class _NestedLooRows:
    """Corrected LOO errors of nested fits in Gram form, extended as a path grows.

    For the columns ``cols`` of ``design`` (column 0 the constant) with Gram matrix
    :math:`G` and :math:`b = \\Psi^T y`: :math:`R^T R = G_{cols, cols}` (Cholesky, up to the
    first dependent column), :math:`z = R^{-T} b_{cols}`, and the errors of
    :func:`_loo_nested` with :math:`Q = X R^{-1}`. A later call with a longer ``cols``
    (the same prefix: a path run further) evaluates the new columns only,
    :math:`Q_{:, k_0:s} = X_{:, :s} (R^{-1})_{:s, k_0:s}`, continuing each run's hat
    diagonal and fitted value from the ones kept after the last call (two n-vectors), in
    blocks of rows: no (n, s) array is held.
    """

    def __init__(self, design, y, G, b):
        self.design, self.y, self.G, self.b = design, y, G, b
        n = len(y)
        self.h = np.zeros(n)
        self.fitted = np.zeros(n)
        self.sum_e2 = np.zeros(0)

    def errors(self, cols):
        """(R, z, corrected) of the nested fits on the leading columns of ``cols``."""
        y, n = self.y, len(self.y)
        R = _cholesky_prefix(self.G[np.ix_(cols, cols)])
        s = R.shape[0]
        z = sla.solve_triangular(R, self.b[cols[:s]], trans="T")
        Rinv = sla.solve_triangular(R, np.eye(s))
        k0 = len(self.sum_e2)
        if s > k0:
            sel = cols[:s]
            W = Rinv[:, k0:]
            new = np.zeros(s - k0)
            for a, b in _row_blocks(n, 4 * s):
                X = self.design[a:b][:, sel]
                if k0:
                    Q = X @ W
                else:  # all columns: the triangular solve, half the products
                    Q = sla.solve_triangular(R, X.T, trans="T", check_finite=False).T
                # in place: r = y - fitted and 1 - h of the nested fits, then (r / (1 - h))^2
                r = Q * z[None, k0:]
                np.cumsum(r, axis=1, out=r)
                r += self.fitted[a:b, None]
                self.fitted[a:b] = r[:, -1]
                np.subtract(y[a:b, None], r, out=r)
                np.multiply(Q, Q, out=Q)
                np.cumsum(Q, axis=1, out=Q)
                Q += self.h[a:b, None]
                self.h[a:b] = Q[:, -1]
                np.subtract(1.0, Q, out=Q)
                with np.errstate(divide="ignore", invalid="ignore"):
                    np.divide(r, Q, out=r)
                r[Q <= 1e-10] = np.inf
                np.multiply(r, r, out=r)
                new += np.sum(r, axis=0)
            self.sum_e2 = np.concatenate([self.sum_e2, new])
        var = np.var(y) if np.var(y) > 0 else 1.0
        loo = self.sum_e2[:s] / n / var
        trace = np.cumsum(np.sum(np.triu(Rinv) ** 2, axis=0))
        k = np.arange(1, s + 1)
        with np.errstate(divide="ignore"):
            T = np.where(k < n, n / np.maximum(n - k, 1) * (1.0 + trace), np.inf)
        return R, z, loo * T


def _grow_path(path, design, positions, y, steps, max_steps, gram=None):
    """Run ``path`` in growing pieces and refit the best nested set: (columns, coef, LOO).

    ``path(steps)`` returns the entry order (indices into ``positions``) of its first
    ``steps`` columns; ``positions`` maps them to columns of ``design``, whose column 0 is
    the constant. Each piece's nested active sets are refitted by OLS (one QR) and scored
    by the corrected LOO error; the path grows, twice as many steps up to ``max_steps``,
    while the best set lies in the last quarter of the steps run. Shared by the
    fixed-candidate selection (:func:`_sparse_select`) and the adaptive one
    (:mod:`ecfm_uq.chaos.adaptive`).

    ``gram``: optional ``(G, b)``, the design's Gram matrix and :math:`\\Psi^T y`. When the
    selected columns hold more than ``_QR_BYTES``, the refits use the Cholesky factor of
    their Gram block instead of a QR of the (n, s) columns and the leave-one-out errors
    are summed in blocks of rows (:class:`_NestedLooRows`): the same errors for a
    Cholesky of (s, s) and products with (block, s) rows instead of an (n, s)
    Householder QR (most of the adaptive fit's time at n = 10^5 runs). The path then grows
    by a quarter of its steps, at least 16, and only the new columns are scored: doubling
    and rescoring all columns cost four times the piece for steps that rarely win.
    """
    n, nested = len(y), None
    while True:
        active = path(steps)
        cols = [0] + [int(positions[j]) for j in active]
        if gram is not None and 8.0 * n * len(cols) > _QR_BYTES:
            if nested is None:
                nested = _NestedLooRows(design, y, *gram)
            R, z, corrected = nested.errors(cols)
            s, Q = R.shape[0], None
        else:
            Q, R = sla.qr(design[:, cols], mode="economic")
            d = np.abs(np.diag(R))
            # stop at the first column that is numerically dependent on the earlier ones
            bad = np.flatnonzero(d < 1e-10 * d[0])
            s = int(bad[0]) if bad.size else len(cols)
            Q, R = Q[:, :s], R[:s, :s]
            _, corrected = _loo_nested(Q, R, y)
        cols = cols[:s] if s < len(cols) else cols
        k = int(np.argmin(corrected)) + 1
        # grow the path while the best set lies in the last quarter of the steps run
        if steps >= max_steps or len(active) < steps or s < len(active) + 1 or 4 * k <= 3 * s:
            break
        # in Gram form only the new columns are scored: grow by a quarter (at least 16),
        # as the path usually runs on, a few steps past its best set, by `first_steps`
        steps = min(2 * steps if nested is None else steps + max(16, steps // 4), max_steps)
    if Q is None:
        coef = sla.solve_triangular(R[:k, :k], z[:k])
    else:
        coef = sla.solve_triangular(R[:k, :k], Q[:, :k].T @ y)
    return cols[:k], coef, float(corrected[k - 1])


def _lar_order_gram(G, c, max_steps):
    """Entry order of least-angle regression (LAR) from the Gram matrix of unit-norm columns.

    The LAR of Efron et al. (2004) in Gram form: the correlations
    :math:`c = X^T r` are updated as :math:`c \\leftarrow c - \\gamma\\,G_{:,A} w` without
    the design. The inverse :math:`L^{-1}` of the Cholesky factor of :math:`G_{AA}` grows
    by one row per step and the rows :math:`G_{A,:}` are kept contiguous, so a step is a
    few matrix-vector products, O(k P). Stops at ``max_steps``, when the correlations
    vanish, or at a column numerically dependent on the active ones.
    """
    P = len(c)
    max_steps = min(max_steps, P)
    c = np.array(c, dtype=float)
    inactive = np.ones(P, dtype=bool)
    GA = np.empty((max_steps, P))
    Linv = np.zeros((max_steps, max_steps))
    z = np.empty(max_steps)  # L^{-1} s_A, s_A the signs of the active correlations
    v = np.empty(max_steps)  # L^{-T} z = G_AA^{-1} s_A (signs never change in LAR)
    active = []
    j = int(np.argmax(np.abs(c)))
    C = abs(c[j])
    floor = 1e3 * np.finfo(float).eps * max(C, np.finfo(float).tiny)
    with np.errstate(divide="ignore", invalid="ignore"):  # once: a step costs ~50 us
        for k in range(max_steps):
            if C <= floor:
                break
            GA[k] = G[j]
            l = Linv[:k, :k] @ GA[:k, j]
            d2 = G[j, j] - l @ l
            if not d2 > _CHOLESKY_RTOL**2 * G[j, j]:
                break  # dependent on the active columns
            d = math.sqrt(d2)
            Linv[k, :k] = -(l @ Linv[:k, :k]) / d
            Linv[k, k] = 1.0 / d
            z[k] = (math.copysign(1.0, c[j]) - l @ z[:k]) / d
            v[:k] += z[k] * Linv[k, :k]
            v[k] = z[k] / d
            active.append(j)
            inactive[j] = False
            if k + 1 == max_steps:
                break
            AA = 1.0 / math.sqrt(z[: k + 1] @ z[: k + 1])
            a = AA * (v[: k + 1] @ GA[: k + 1])
            # the step to the next column's entry: the smallest positive of the two
            # candidate steps of each inactive column
            g1 = (C - c) / (AA - a)
            g2 = (C + c) / (AA + a)
            g1[~(g1 > 1e-14 * C)] = np.inf
            g2[~(g2 > 1e-14 * C)] = np.inf
            g = np.minimum(g1, g2)
            g[~inactive] = np.inf
            m = int(np.argmin(g))
            gamma = min(g[m], C / AA)
            if not np.isfinite(gamma):
                break
            c -= gamma * a
            C -= gamma * AA
            j = m
    return active
