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
the leave-one-out error, per output component. The compression itself (exact SVD, or a
randomized SVD in blocks when the exact one is over the memory budget) is
:mod:`ecfm_uq.chaos.regression.compression`; the evaluations' array, and what the fit adds per
output component, are checked after the first model run, before the others.

Sizes and memory. The default candidate degree is the largest whose total-degree basis
(P terms) satisfies all of: :math:`P \\le 10 n`; the selection's working set
:math:`4 \\cdot 8\\,P \\min(n, P)` bytes within half the memory budget
(:mod:`ecfm_uq.memory`); its work
:math:`W = 3\\,n P \\min(n, P) + 15\\,P \\min(P, n/2)^2 \\le 4 \\cdot 10^{12}`
(:func:`candidate_degree`); degree :math:`\\le 30`. Small or wide problems
(:math:`P \\ge n`, or the n x P design under 128 MiB) select on the design matrix
exactly as before; tall large ones select on the candidates' Gram matrix
:math:`\\Psi^T\\Psi` and :math:`\\Psi^T y`, accumulated in blocks of rows (LARS / OMP
in their Gram forms), and compute the corrected leave-one-out errors from the selected
columns only, again in blocks of rows: the n x P candidate matrix is never formed.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla

from ..._validation import check_int
from ...memory import check_allocation, memory_budget
from .adaptive import select_adaptive
from .compression import (
    StreamingSketch,
    compress_outputs,
    exact_pca_bytes,
    randomized_pca_bytes,
    row_blocks,
    streaming_bytes,
)
from .loo import cholesky_prefix, loo_nested_rows
from .paths import CANDIDATES_PER_RUN, SELECTION_SHARE, path_order_gram, sparse_select

__all__ = ["candidate_degree", "fit_sparse"]

# corrected LOO error stops improving); the candidates per run are in .paths.
_MAX_DEGREE = 30
# The default candidate set also fits the memory budget and a work limit: the selection
# holds about _SELECTION_COPIES arrays of P * min(n, P) floats (design or Gram form); its
# work is modelled by _selection_work and kept below _WORK_LIMIT (a few minutes of one core).
_SELECTION_COPIES = 4
_WORK_LIMIT = 4e12
# Below this design size (or when P >= n) the selection runs on the design matrix, exactly
# as in earlier releases; above it, on the Gram matrix built in blocks of rows.
_EXACT_DESIGN_BYTES = 128 * 2**20
# Field outputs whose evaluations do not fit in memory: range-sketch columns of the
# one-pass compression, the largest that fits (the largest rank it can keep).
_STREAM_COLUMNS = (64, 48, 32)
# Field outputs: above this many components the evaluations are compressed by default.
_COMPRESS_ABOVE = 64


# --------------------------------------------------------------------------------------
# sizes
# --------------------------------------------------------------------------------------
def _selection_bytes(n, P):
    """Working set of the selection on P candidates from n runs (design or Gram form)."""
    return 8.0 * _SELECTION_COPIES * P * min(n, P)


def _selection_work(n, P):
    """Work model of the selection (see :func:`candidate_degree`)."""
    return 3.0 * n * P * min(n, P) + 15.0 * P * min(P, n // 2) ** 2


def candidate_degree(n, dim, budget=None):
    """Default largest candidate degree of the sparse methods, and the limit that set it.

    The largest total degree p (at least 1) whose basis of
    :math:`P = \\binom{p + d}{d}` terms satisfies

    * :math:`P \\le 10\\,n` (no more candidates than ten per run);
    * :math:`4 \\cdot 8\\,P \\min(n, P)` bytes (the selection's working set in its design
      or Gram form) within half the memory budget;
    * its work :math:`W = 3\\,n P \\min(n, P) + 15\\,P \\min(P, n/2)^2 \\le 4 \\cdot 10^{12}`:
      the first term the Gram build and the blocked leave-one-out passes (or the LARS
      path on a wide design), the second the path's matrix-vector steps in Gram form
      (measured about 15 times slower per operation than the blocked products);
    * :math:`p \\le 30`.

    Parameters
    ----------
    n, dim : int
        Regression runs and inputs.
    budget : float, optional
        Memory budget in bytes (default :func:`ecfm_uq.memory.memory_budget`).

    Returns
    -------
    order : int
    limit : {"samples", "memory", "work", "max_degree"}
        Which rule stopped the degree from growing.
    """
    budget = memory_budget() if budget is None else float(budget)
    order = 1
    while True:
        if order >= _MAX_DEGREE:
            return order, "max_degree"
        P = math.comb(order + 1 + dim, dim)
        if P > CANDIDATES_PER_RUN * n:
            return order, "samples"
        if _selection_bytes(n, P) > SELECTION_SHARE * budget:
            return order, "memory"
        if _selection_work(n, P) > _WORK_LIMIT:
            return order, "work"
        order += 1


def _uses_gram(n, P, budget=None):
    """Select on the Gram matrix (True) or on the n x P design (False)?"""
    if P >= n:
        return False
    budget = memory_budget() if budget is None else float(budget)
    design = 8.0 * n * P
    return design > _EXACT_DESIGN_BYTES or _SELECTION_COPIES * design > SELECTION_SHARE * budget


# --------------------------------------------------------------------------------------
# Gram form: the candidates' Gram matrix built in blocks of rows, never the design
# --------------------------------------------------------------------------------------
class _GramDesign:
    """:math:`G = \\Psi_B^T \\Psi_B` and :math:`\\Psi_B^T Y` of the built columns B.

    The columns are added degree by degree (:meth:`extend`), each time in one pass over
    blocks of rows that evaluates only the columns needed, so only the degrees the
    selection reaches are paid for and no (n, P) array exists.
    """

    def __init__(self, basis, omega, Y):
        self.basis = basis
        self.omega = omega
        self.Y = Y
        self.n = len(omega)
        self.cols = np.zeros(0, dtype=np.int64)  # basis indices, in order of addition
        self.position = {}
        self.G = np.zeros((0, 0))
        self.XtY = np.zeros((0, Y.shape[1]))
        self.extend([0])

    def rows(self, a, b, cols):
        """:math:`\\Psi` at runs a..b-1, only the basis columns ``cols``: (b - a, len(cols))."""
        tables = self.basis.univariate(self.omega[a:b])
        alpha = self.basis.indices[np.asarray(cols, dtype=np.int64)]
        B = tables[0][:, alpha[:, 0]]
        for d in range(1, self.basis.dim):
            B *= tables[d][:, alpha[:, d]]
        return B

    def extend(self, candidates):
        """Add the columns of ``candidates`` (basis indices) not built yet."""
        new = [int(c) for c in candidates if int(c) not in self.position]
        if not new:
            return
        s0, s1 = len(self.cols), len(self.cols) + len(new)
        check_allocation(
            8.0 * _SELECTION_COPIES * s1 * s1,
            f"the Gram matrix of {s1} sparse-regression candidates",
            "leave `order` to its default (sized by n and the memory budget), or pass a "
            "smaller `order` or `q_norm` < 1",
        )
        cols = np.concatenate([self.cols, np.asarray(new, dtype=np.int64)])
        G_new = np.zeros((s1, s1 - s0))
        XtY_new = np.zeros((s1 - s0, self.Y.shape[1]))
        for a, b in row_blocks(self.n, s1):
            B = self.rows(a, b, cols)
            Bn = B[:, s0:]
            G_new += B.T @ Bn
            XtY_new += Bn.T @ self.Y[a:b]
        G = np.empty((s1, s1))
        G[:s0, :s0] = self.G
        G[:, s0:] = G_new
        G[s0:, :s0] = G_new[:s0].T
        self.G = G
        self.XtY = np.vstack([self.XtY, XtY_new])
        for k, c in enumerate(new):
            self.position[c] = s0 + k
        self.cols = cols

    def positions(self, cols):
        return np.array([self.position[int(c)] for c in cols], dtype=np.int64)


def _loo_nested_gram(gd, cols, R, z, j):
    """:func:`loo_nested` from the selected columns, in blocks of rows (Q = X R^{-1})."""
    return loo_nested_rows(lambda a, b: gd.rows(a, b, cols), gd.Y[:, j], R, z)


def _sparse_select_gram(gd, j, candidates, solver):
    """:func:`sparse_select` on the Gram matrix: (columns, coefficients, corrected LOO)."""
    n = gd.n
    gd.extend(candidates)
    G = gd.G
    b = gd.XtY[:, j]
    ybar = float(np.mean(gd.Y[:, j]))
    pc = gd.positions(candidates)
    # centring: Psi_0 = 1, so the column sums are the Gram's first row
    mu = G[0, pc] / n
    Gc = G[np.ix_(pc, pc)] - n * np.outer(mu, mu)
    Xyc = b[pc] - n * mu * ybar
    scale = np.sqrt(np.maximum(np.diag(Gc), 0.0))
    scale[scale == 0] = 1.0
    Gc /= scale[:, None]
    Gc /= scale[None, :]
    max_steps = min(len(candidates), max(n // 2, 2))
    active = path_order_gram(Gc, Xyc / scale, n, max_steps, solver)
    del Gc
    cols = [0] + [int(candidates[a]) for a in active]
    pos = gd.positions(cols)
    R = cholesky_prefix(G[np.ix_(pos, pos)])
    s = R.shape[0]
    cols, pos = cols[:s], pos[:s]
    z = sla.solve_triangular(R, b[pos], trans="T")
    corrected = _loo_nested_gram(gd, cols, R, z, j)
    k = int(np.argmin(corrected)) + 1
    coef = sla.solve_triangular(R[:k, :k], z[:k])
    return cols[:k], coef, float(corrected[k - 1])


def _select_columns(select, P, Y, qn, order, early_stop):
    """Degree-adaptive sparse selection for each column of Y (n, m) among P terms.

    ``select(j, candidates)`` runs the path and the LOO scoring on column j.
    """
    coeffs = np.zeros((P, Y.shape[1]))
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
            cols, coef, err = select(j, candidates)
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


def _compress_flag(compress, m):
    """``compress`` as given (True, False, 'exact', 'randomized'), None by the output size."""
    if compress is None:
        return m > _COMPRESS_ABOVE
    return compress


def fit_sparse(
    inputs, order, index_set, data, ev, q_norm, early_stop, solver, compress, tol, basis_type
):
    """The sparse fit of ``fit_pce(method="lars" | "omp")``: basis, coefficients, diagnostics.

    Parameters
    ----------
    inputs : Inputs
        The inputs (``dim`` and ``germs``).
    order : int or None
        Largest candidate degree (``None``: adaptive, or :func:`candidate_degree`).
    index_set : None or "total"
        The candidate sets are graded: only ``"total"`` is accepted.
    data : callable
        ``data(None) -> (omega, x, y, name)``: germ points, input points, evaluations
        (``None`` when the model is still to run) and the argument that gave them;
        ``data.design`` names the generated design.
    ev : callable
        ``ev(x, label, check) -> y``: the model runs (``check(n, out_shape)`` is called
        after the first, before the others).
    q_norm : float or None
        Fixed hyperbolic q-norm, or ``None`` for the adaptive candidate sets
        (:mod:`.adaptive`).
    early_stop : int
        Degrees without improvement before a chain stops.
    solver : {"lars", "omp"}
    compress : None, bool, "exact" or "randomized"
    tol : float
        Largest share of a component's variance the compression may discard.
    basis_type : type
        The chaos basis class, called as ``basis_type(order, dim, index_set=..., germ=...)``
        (:class:`~ecfm_uq.chaos.ChaosBasis`; passed in, so this package sits below
        :mod:`ecfm_uq.chaos`).

    Returns
    -------
    basis : basis_type
        The expansion's basis (the selected terms only when adaptive).
    coefficients : (P, *output_shape) ndarray
    diagnostics : dict
        What the selection chose (degree, terms, corrected LOO error, ...).
    n : int
        Regression runs.
    """
    dim = inputs.dim
    if index_set not in (None, "total"):
        raise ValueError(
            f"`index_set` must be 'total' for method={solver!r} (candidate sets are graded)"
        )
    omega, x, y, name = data(None)
    n = len(omega)
    if n < 4:
        raise ValueError(f"too few regression samples: `{name}` gives {n} points; pass at least 4")
    adaptive = q_norm is None
    if order is None and adaptive:
        # the degree grows while the corrected LOO error improves and a candidate set
        # of the next degree is affordable (_select_adaptive_column)
        order, limit = _MAX_DEGREE, "adaptive"
    elif order is None:
        # candidate degrees while the candidate set stays below CANDIDATES_PER_RUN * n,
        # the selection within the memory budget and its work within _WORK_LIMIT
        order, limit = candidate_degree(n, dim)
    else:
        limit = "order"
    order = check_int("order", order, minimum=1)
    if adaptive:
        # the largest candidate set an affordable selection holds (checked per set)
        P, gram = CANDIDATES_PER_RUN * n, False
    else:
        basis = basis_type(order, dim, germ=inputs.germs)
        P = basis.size
        alpha = np.asarray(basis.indices, dtype=float)
        qn = (np.sum(alpha**q_norm, axis=1)) ** (1.0 / q_norm)
        gram = _uses_gram(n, P)
        # checked before the model runs: the largest array the selection may need (the
        # design path evaluates all P terms, the Gram path only the candidates)
        P_sel = int(np.count_nonzero(qn <= order + 1e-12)) if gram else P
        check_allocation(
            _selection_bytes(n, P_sel),
            f"the sparse-regression {'Gram matrix' if gram else 'design'} of {P_sel} "
            f"candidates from n = {n} runs (order {order}, {dim} inputs)",
            "leave `order` to its default (sized by n and the memory budget), or pass a "
            f"smaller `order`{' or `q_norm` < 1' if gram else ''}",
        )

    def check_outputs(n_runs, out_shape):
        """Before the other runs: the evaluations and what the fit adds per component."""
        m_out = math.prod(out_shape)
        Y_bytes = 8.0 * n_runs * m_out
        if _compress_flag(compress, m_out) is False:
            # one selection per component: its coefficients and correlations, (P, m) each
            need, what = Y_bytes + 2 * 8.0 * P * m_out, "and one selection per component"
            cheaper = (
                "let `compress` compress the field (principal components), or let the model "
                "return fewer output values"
            )
        elif compress == "exact":
            need, what = exact_pca_bytes(n_runs, m_out), "and their exact principal components"
            cheaper = "pass compress='randomized' (holds the evaluations once)"
        else:
            need = randomized_pca_bytes(n_runs, m_out, min(32, n_runs, m_out))
            what = "and their randomized principal components"
            cheaper = (
                "pass fewer `n_samples`, or let the model return fewer output values (e.g. "
                "the sensors you need or a coarser field)"
            )
            if compress == "randomized":
                cheaper += ", or compress=True (streams the evaluations as they arrive)"
            elif need > memory_budget():
                # the evaluations do not fit even once: compress them as they arrive, with
                # the largest sketch that fits
                for k in _STREAM_COLUMNS:
                    k = min(k, n_runs, m_out)
                    if streaming_bytes(n_runs, m_out, k) <= memory_budget():
                        stream[:] = [StreamingSketch(n_runs, m_out, k), out_shape]
                        return stream[0]
        check_allocation(
            need,
            f"the evaluations of {n_runs} runs of a {m_out}-value output {what}",
            cheaper,
        )

    stream = []
    if y is None:
        y = ev(x, "regression", check_outputs)
    streamed = bool(stream)
    if streamed:
        yf, shape = None, tuple(stream[1])
        m = math.prod(shape)
    else:
        yf = y.reshape(n, -1)
        m = yf.shape[1]
        shape = y.shape[1:]
    extra = {}
    compress = _compress_flag(compress, m)

    def selector(Y):
        if gram:
            gd = _GramDesign(basis, omega, Y)
            return lambda j, candidates: _sparse_select_gram(gd, j, candidates, solver)
        Psi = basis.evaluate(omega)
        return lambda j, candidates: sparse_select(Psi, Y[:, j], candidates, n, solver)

    if compress:
        if streamed:
            sketch = stream.pop(0)  # dropped once compressed: only its results stay
            Z, V, ybar, comp_err, info = sketch.compress(tol)
            del sketch
        else:
            Z, V, ybar, comp_err, info = compress_outputs(
                yf, tol, "auto" if compress is True else compress, return_info=True
            )
        if adaptive:
            union, cz, ainfo = select_adaptive(inputs.germs, omega, Z, early_stop, order, solver)
            deg, err, nt = ainfo["degree"], ainfo["errors"], ainfo["n_terms"]
            P_top = len(union)
        else:
            cz, deg, err, nt = _select_columns(selector(Z), P, Z, qn, order, early_stop)
            # only the terms up to the highest selected degree are nonzero (graded order)
            P_top = basis_type(max(int(deg.max()), 1), dim).size
        check_allocation(
            8.0 * 2 * P_top * m,
            f"the expansion's coefficients ({P_top} terms by {m} output values)",
            "pass a smaller `order` (fewer terms), or let the model return fewer output values",
        )
        coeffs = cz[:P_top] @ V
        coeffs[0] += ybar
        chosen_deg = deg
        # component LOO error: the scores' (relative to their variances), mapped through
        # V onto each component's variance, plus what the compression discarded
        var_z = Z.var(axis=0)
        var_yf = info["variance"]  # each compression path's column variances
        var_y = np.maximum(var_yf, np.finfo(float).tiny)
        errors = (err * var_z) @ V**2 / var_y + comp_err
        errors = np.where(var_yf > 0, errors, 0.0)
        extra = dict(
            n_components=V.shape[0],
            compression_error=comp_err.reshape(shape),
            component_loo_error=err,
            component_degree=deg,
            component_n_terms=nt,
            compression=info["method"],
            compression_info=info,
        )
        n_terms = np.count_nonzero(coeffs, axis=0)
    elif adaptive:
        union, coeffs, ainfo = select_adaptive(inputs.germs, omega, yf, early_stop, order, solver)
        chosen_deg, errors, n_terms = ainfo["degree"], ainfo["errors"], ainfo["n_terms"]
    else:
        coeffs, chosen_deg, errors, n_terms = _select_columns(
            selector(yf), P, yf, qn, order, early_stop
        )
    top = max(max(chosen_deg), 1)
    if adaptive:
        # the selected terms only (a custom index set), not the total-degree basis
        basis_out = basis_type(top, dim, index_set=union, germ=inputs.germs)
    else:
        basis_out = basis_type(top, dim, germ=inputs.germs)
    c = coeffs[: basis_out.size].reshape((basis_out.size, *shape))
    if compress:
        # each component uses the union of the scores' terms
        degree = np.full(m, int(top))
    else:
        degree = np.array(chosen_deg)
    diagnostics = dict(
        design=None if name == "samples" else data.design,
        degree=degree.reshape(shape),
        n_terms=np.array(n_terms).reshape(shape),
        corrected_loo_error=np.array(errors).reshape(shape),
        q_norm=q_norm,
        compressed=bool(compress),
        candidate_degree=order,
        candidate_limit=limit,
        selection="gram" if gram else "design",
        **extra,
    )
    if adaptive:
        # what the adaptive truncation chose (per output component, or per principal
        # component when compressed) and the first one's path of (degree, q, P, LOO)
        key = "component_" if compress else ""
        diagnostics.update(
            selection="adaptive",
            q_norm=ainfo["q_norm"] if compress else ainfo["q_norm"].reshape(shape),
            candidate_degree=int(max(t[0] for t in ainfo["trace"]) if ainfo["trace"] else 1),
            adaptive_trace=ainfo["trace"],
        )
        diagnostics[f"{key}n_candidates"] = (
            ainfo["n_candidates"] if compress else ainfo["n_candidates"].reshape(shape)
        )
    return basis_out, c, diagnostics, n
