"""Sparse polynomial chaos regression: hybrid LARS / OMP with corrected leave-one-out.

The sparse methods of :func:`~ecfm_uq.chaos.fit_pce` (Blatman & Sudret 2011): the path
(least-angle regression or orthogonal matching pursuit) orders the candidate columns,
every nested active set is refitted by OLS and scored by the corrected leave-one-out
error, and the candidate degree is raised until the score stops improving.

A field output (many components) is compressed first (Blatman & Sudret 2013; UQLab's
PCA-PCE): the centred evaluations :math:`Y - \\bar y = U S V^T` keep the leading
principal components until every component's discarded variance is below ``pca_tol``
of its own variance; the selection runs on those few score columns and the expansion of
every component is :math:`c = c_Z V_K^T`. The compression's own error is reported beside
the leave-one-out error, per output component.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.linalg as sla

from .._validation import check_int
from .basis import ChaosBasis
from .pce import PolynomialChaosExpansion

__all__ = ["compress_outputs"]

# Sparse regression: largest candidate basis per model run, and the highest degree tried
# (the degree loop stops earlier when the corrected LOO error stops improving).
_CANDIDATES_PER_RUN = 10
_MAX_DEGREE = 30
# Field outputs: above this many components the evaluations are compressed by default.
_COMPRESS_ABOVE = 64


# --------------------------------------------------------------------------------------
# leave-one-out errors
# --------------------------------------------------------------------------------------
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


def _sparse_select(Psi, y, candidates, n, solver):
    """Hybrid LARS/OMP on the candidate columns: (columns, coefficients, corrected LOO).

    The path is computed on centred, unit-norm candidate columns (the constant term is
    always kept); every nested active set along it is then refitted by OLS, and the one
    with the smallest corrected leave-one-out error wins (Blatman & Sudret 2011).
    """
    X = Psi[:, candidates]
    Xc = X - X.mean(axis=0)
    scale = np.linalg.norm(Xc, axis=0)
    scale[scale == 0] = 1.0
    # beyond n / 2 terms the LOO correction factor exceeds 2: such fits never win
    max_steps = min(len(candidates), max(n // 2, 2))
    active = _path_order(Xc / scale, y - y.mean(), max_steps, solver)
    cols = [0] + [int(candidates[j]) for j in active]
    Q, R = sla.qr(Psi[:, cols], mode="economic")
    d = np.abs(np.diag(R))
    # stop at the first column that is numerically dependent on the earlier ones
    bad = np.flatnonzero(d < 1e-10 * d[0])
    s = int(bad[0]) if bad.size else len(cols)
    Q, R, cols = Q[:, :s], R[:s, :s], cols[:s]
    _, corrected = _loo_nested(Q, R, y)
    k = int(np.argmin(corrected)) + 1
    coef = sla.solve_triangular(R[:k, :k], Q[:, :k].T @ y)
    return cols[:k], coef, float(corrected[k - 1])


def _select_columns(Psi, Y, qn, order, n, solver, early_stop):
    """Degree-adaptive sparse selection for each column of Y (n, m) on the candidates Psi."""
    coeffs = np.zeros((Psi.shape[1], Y.shape[1]))
    chosen_deg, errors, n_terms = [], [], []
    for j in range(Y.shape[1]):
        if np.all(Y[:, j] == Y[0, j]):
            # a constant output component: the mean term alone, exactly
            coeffs[0, j] = Y[0, j]
            chosen_deg.append(0)
            errors.append(0.0)
            n_terms.append(1)
            continue
        best = None
        worse = 0
        for p in range(1, order + 1):
            candidates = np.flatnonzero((qn <= p + 1e-12) & (qn > 0))
            cols, coef, err = _sparse_select(Psi, Y[:, j], candidates, n, solver)
            if best is None or err < best[2]:
                best = (cols, coef, err, p)
                worse = 0
            else:
                worse += 1
                if worse >= early_stop:
                    break
        cols, coef, err, p = best
        coeffs[cols, j] = coef
        chosen_deg.append(p)
        errors.append(err)
        n_terms.append(len(cols))
    return coeffs, np.array(chosen_deg), np.array(errors), np.array(n_terms)


def compress_outputs(Y, tol):
    """Principal components of the evaluations, enough for every component to ``tol``.

    Parameters
    ----------
    Y : (n, m) ndarray
        Evaluations, one row per run.
    tol : float
        Largest discarded share of any component's own variance.

    Returns
    -------
    Z : (n, K) ndarray
        Scores :math:`U_K S_K` (centred columns).
    V : (K, m) ndarray
        Principal directions, :math:`Y \\approx \\bar y + Z V`.
    ybar : (m,) ndarray
    error : (m,) ndarray
        Discarded variance of each component over its variance (0 for a constant one).

    Notes
    -----
    With :math:`Y - \\bar y = USV^T`, component m's variance is
    :math:`\\sum_j S_j^2 V_{jm}^2`; keeping K directions discards
    :math:`\\sum_{j \\ge K} S_j^2 V_{jm}^2` of it, exactly.
    """
    ybar = Y.mean(axis=0)
    Yc = Y - ybar
    U, S, Vt = np.linalg.svd(Yc, full_matrices=False)
    energy = S[:, None] ** 2 * Vt**2  # (r, m): component m's variance along direction j
    total = energy.sum(axis=0)
    scale = np.maximum(np.abs(ybar), np.sqrt(total / len(Y)))
    const = total <= (1e-13 * scale) ** 2 * len(Y)
    tail = np.cumsum(energy[::-1], axis=0)[::-1]  # tail[k] = discarded when keeping k
    rel = np.where(const, 0.0, tail / np.where(const, 1.0, total))
    rel = np.vstack([rel, np.zeros((1, rel.shape[1]))])
    ok = np.flatnonzero(rel.max(axis=1) <= tol)
    K = max(int(ok[0]) if ok.size else len(S), 1)
    return U[:, :K] * S[:K], Vt[:K], ybar, rel[K]


def _fit_sparse(
    model, inputs, order, index_set, data, ev, q_norm, early_stop, solver, compress, tol
):
    dim = inputs.dim
    if index_set not in (None, "total"):
        raise ValueError(
            f"`index_set` must be 'total' for method={solver!r} (candidate sets are graded)"
        )
    omega, x, y, name = data(None)
    n = len(omega)
    if n < 4:
        raise ValueError(f"too few regression samples: `{name}` gives {n} points; pass at least 4")
    if order is None:
        # candidate degrees while the candidate set stays below _CANDIDATES_PER_RUN * n
        order = 1
        while math.comb(order + 1 + dim, dim) <= _CANDIDATES_PER_RUN * n and order < _MAX_DEGREE:
            order += 1
    order = check_int("order", order, minimum=1)
    if y is None:
        y = ev(x, "regression")
    yf = y.reshape(n, -1)
    basis = ChaosBasis(order, dim, germ=inputs.germs)
    Psi = basis.evaluate(omega)
    alpha = np.asarray(basis.indices, dtype=float)
    qn = (np.sum(alpha**q_norm, axis=1)) ** (1.0 / q_norm)
    m = yf.shape[1]
    shape = y.shape[1:]
    extra = {}
    if compress is None:
        compress = m > _COMPRESS_ABOVE
    if compress:
        Z, V, ybar, comp_err = compress_outputs(yf, tol)
        cz, deg, err, nt = _select_columns(Psi, Z, qn, order, n, solver, early_stop)
        # only the terms up to the highest selected degree are nonzero (graded order)
        P_top = ChaosBasis(max(int(deg.max()), 1), dim).size
        coeffs = cz[:P_top] @ V
        coeffs[0] += ybar
        chosen_deg = deg
        # component LOO error: the scores' (relative to their variances), mapped through
        # V onto each component's variance, plus what the compression discarded
        var_z = Z.var(axis=0)
        var_y = np.maximum(yf.var(axis=0), np.finfo(float).tiny)
        errors = (err * var_z) @ V**2 / var_y + comp_err
        errors = np.where(yf.var(axis=0) > 0, errors, 0.0)
        extra = dict(
            n_components=V.shape[0],
            compression_error=comp_err.reshape(shape),
            component_loo_error=err,
            component_degree=deg,
            component_n_terms=nt,
        )
        n_terms = np.count_nonzero(coeffs, axis=0)
    else:
        coeffs, chosen_deg, errors, n_terms = _select_columns(
            Psi, yf, qn, order, n, solver, early_stop
        )
    top = max(max(chosen_deg), 1)
    basis_out = ChaosBasis(top, dim, germ=inputs.germs)
    c = coeffs[: basis_out.size].reshape((basis_out.size, *y.shape[1:]))
    pce = PolynomialChaosExpansion(basis_out, c, inputs)
    if compress:
        # each component uses the union of the scores' terms
        degree = np.full(m, int(top))
    else:
        degree = np.array(chosen_deg)
    pce.diagnostics.update(
        design=None if name == "samples" else data.design,
        degree=degree.reshape(shape),
        n_terms=np.array(n_terms).reshape(shape),
        corrected_loo_error=np.array(errors).reshape(shape),
        q_norm=q_norm,
        compressed=bool(compress),
        **extra,
    )
    return pce, n
