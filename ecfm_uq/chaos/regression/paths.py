"""Sparse-regression paths: the order in which candidate columns enter LAR or OMP.

Shared by the fixed-candidate selection (:mod:`.fit`) and the adaptive one
(:mod:`.adaptive`): the order in which candidate columns enter a least-angle regression
(Efron et al. 2004) or orthogonal matching pursuit path, in design or Gram form, and the
hybrid selection that refits every nested active set along it by OLS and scores it by the
corrected leave-one-out error (:mod:`.loo`, Blatman & Sudret 2011).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.linalg as sla

from .loo import CHOLESKY_RTOL, NestedLooRows, loo_nested

__all__ = [
    "CANDIDATES_PER_RUN",
    "QR_BYTES",
    "SELECTION_SHARE",
    "grow_path",
    "lar_order_gram",
    "path_order",
    "path_order_gram",
    "sparse_select",
]

# Largest candidate set per model run (both selections).
CANDIDATES_PER_RUN = 10
# Share of the memory budget a selection may hold.
SELECTION_SHARE = 0.5
# grow_path refits in its Gram form (Cholesky of the selected columns' Gram, leave-one-out
# in blocks of rows) when the selected columns of the design hold more than this; below,
# by a QR of those columns, as before.
QR_BYTES = 16 * 2**20


def path_order(X, y, max_steps, solver):
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


def sparse_select(Psi, y, candidates, n, solver, first_steps=None):
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
            return lar_order_gram(G, c, steps)
    else:

        def path(steps):
            return path_order(Xc, y - y.mean(), steps, solver)

    return grow_path(path, Psi, candidates, y, steps, max_steps)


def grow_path(path, design, positions, y, steps, max_steps, gram=None):
    """Run ``path`` in growing pieces and refit the best nested set: (columns, coef, LOO).

    ``path(steps)`` returns the entry order (indices into ``positions``) of its first
    ``steps`` columns; ``positions`` maps them to columns of ``design``, whose column 0 is
    the constant. Each piece's nested active sets are refitted by OLS (one QR) and scored
    by the corrected LOO error; the path grows, twice as many steps up to ``max_steps``,
    while the best set lies in the last quarter of the steps run. Shared by the
    fixed-candidate selection (:func:`sparse_select`) and the adaptive one
    (:mod:`ecfm_uq.chaos.regression.adaptive`).

    ``gram``: optional ``(G, b)``, the design's Gram matrix and :math:`\\Psi^T y`. When the
    selected columns hold more than ``QR_BYTES``, the refits use the Cholesky factor of
    their Gram block instead of a QR of the (n, s) columns and the leave-one-out errors
    are summed in blocks of rows (:class:`NestedLooRows`): the same errors for a
    Cholesky of (s, s) and products with (block, s) rows instead of an (n, s)
    Householder QR (most of the adaptive fit's time at n = 10^5 runs). The path then grows
    by a quarter of its steps, at least 16, and only the new columns are scored: doubling
    and rescoring all columns cost four times the piece for steps that rarely win.
    """
    n, nested = len(y), None
    while True:
        active = path(steps)
        cols = [0] + [int(positions[j]) for j in active]
        if gram is not None and 8.0 * n * len(cols) > QR_BYTES:
            if nested is None:
                nested = NestedLooRows(design, y, *gram)
            R, z, corrected = nested.errors(cols)
            s, Q = R.shape[0], None
        else:
            Q, R = sla.qr(design[:, cols], mode="economic")
            d = np.abs(np.diag(R))
            # stop at the first column that is numerically dependent on the earlier ones
            bad = np.flatnonzero(d < 1e-10 * d[0])
            s = int(bad[0]) if bad.size else len(cols)
            Q, R = Q[:, :s], R[:s, :s]
            _, corrected = loo_nested(Q, R, y)
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


def lar_order_gram(G, c, max_steps):
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
            if not d2 > CHOLESKY_RTOL**2 * G[j, j]:
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


def path_order_gram(Gs, Xys, n, max_steps, solver):
    """:func:`path_order` from the Gram matrix and correlations of the scaled columns."""
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.linear_model import orthogonal_mp_gram

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        warnings.simplefilter("ignore", RuntimeWarning)
        if solver == "lars":
            return lar_order_gram(Gs, Xys, max_steps)
        path = orthogonal_mp_gram(
            Gs, Xys, n_nonzero_coefs=max_steps, return_path=True, copy_Gram=False
        )
    path = path.reshape(Gs.shape[0], -1)
    nz = path != 0
    first = np.where(nz.any(axis=1), np.argmax(nz, axis=1), path.shape[1])
    entered = np.flatnonzero(first < path.shape[1])
    return entered[np.argsort(first[entered], kind="stable")].tolist()
