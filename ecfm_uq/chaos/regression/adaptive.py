"""The default sparse fit: degree- and q-norm-adaptive candidate sets (``q_norm=None``).

For p = 1, 2, ... and each q in (0.5, 0.75, 1) the hyperbolic candidate set
:math:`\\{\\alpha \\ne 0: \\|\\alpha\\|_q \\le p\\}` (Blatman & Sudret 2011) is selected
by the hybrid LAR path and scored by the corrected leave-one-out error, as UQLab's
degree- and q-norm-adaptive sparse PCE does; OpenTURNS' default is the q = 0.5 chain
alone. The candidate sets are nested, so the columns met so far, their Gram matrix and
their correlations with the outputs are grown in place (each column evaluated once), the
path runs in its Gram form (a few small products per step) and only as far as the
leave-one-out error can still improve. A set is tried only while affordable (work,
candidates per run, memory budget); the result keeps the selected terms only (a
``ChaosBasis`` with an explicit index set).
"""

from __future__ import annotations

import math
import mmap

import numpy as np

from ...memory import check_allocation, memory_budget
from ...threads import library_threads
from .paths import QR_BYTES, SELECTION_SHARE, grow_path, lar_order_gram, sparse_select

__all__ = ["affordable", "hyperbolic_indices", "select_adaptive"]

# The q-norms tried at each degree (UQLab's qNorm-adaptive truncation; OpenTURNS' default
# hyperbolic enumeration has q = 0.5): sparse candidate sets of high degree for few
# interactions, the full total-degree set where it is affordable.
_ADAPTIVE_Q = (0.5, 0.75, 1.0)
# A candidate set is affordable when its selection's work n P min(n, P) stays below
# _ADAPTIVE_WORK * max(1, n / _ADAPTIVE_WORK_RUNS) and it has at most _candidate_cap(n)
# columns; the degree loop stops when no q-norm is affordable. Up to 1 000 runs the
# limit is v0.4's fixed 1e9 (about a second of selection on one core). Beyond, it grows
# with n: v0.4 kept it fixed, so the affordable sets shrank as n grew (P <= sqrt(1e9 / n):
# 316 candidates at n = 10^4, 100 at 10^5) and more data gave a worse fit (issue 37, the
# 8-input borehole: Sobol errors 8e-5 at n = 10^4, 1e-3 at 10^5). Per run the work is
# now capped, P min(n, P) <= 10^6, so every set affordable at n is affordable at any
# larger n (P <= 1 000 candidates from n >= 1 000 on) and the time grows like n.
_ADAPTIVE_WORK = 1e9
_ADAPTIVE_WORK_RUNS = 1000
# At most max(_ADAPTIVE_PER_RUN * n, _ADAPTIVE_MIN_CAP) candidates in one set: beyond, the
# LAR path (n / 2 steps at most) rarely finds better sets and each selection's Gram block
# grows as P^2; small designs still see OpenTURNS' few hundred (q = 0.5, degree 10).
_ADAPTIVE_PER_RUN = 2
_ADAPTIVE_MIN_CAP = 500
# The polynomial tables of the inputs are computed this many degrees beyond the first one
# needed, and again when a candidate goes past them (a table per input, degree + 1 rows of n).
_TABLE_AHEAD = 4
# OMP is the method for exactly sparse models from few runs (P >> n, compressed sensing):
# it keeps v0.3's ten candidates per run.
_OMP_PER_RUN = 10


def _candidate_cap(n, solver="lars"):
    if solver == "omp":
        return _OMP_PER_RUN * n
    return max(_ADAPTIVE_PER_RUN * n, _ADAPTIVE_MIN_CAP)


def hyperbolic_indices(dim, p, q, cap=None):
    """Multi-indices :math:`\\alpha \\ne 0` with :math:`\\|\\alpha\\|_q \\le p`, graded.

    The hyperbolic truncation of Blatman & Sudret (2011),
    :math:`\\|\\alpha\\|_q = (\\sum_d \\alpha_d^q)^{1/q}`: ``q = 1`` is the total-degree
    set, smaller ``q`` keeps high degrees in few variables and drops most interactions.

    Parameters
    ----------
    dim, p : int
    q : float in (0, 1]
    cap : int, optional
        Return ``None`` as soon as the set is known to exceed ``cap`` members.

    Returns
    -------
    (P, dim) ndarray of int or None
        Graded by total degree, lexicographically descending within a degree (the order
        of :class:`~ecfm_uq.chaos.ChaosBasis`).
    """
    if q == 1.0 and cap is not None and math.comb(p + dim, dim) - 1 > cap:
        return None
    limit = float(p) ** q * (1.0 + 1e-12)
    cost = np.arange(p + 1, dtype=float) ** q
    rows = np.zeros((1, 0), dtype=np.int64)
    used = np.zeros(1)
    for _ in range(dim):
        ok = used[:, None] + cost[None, :] <= limit
        r, k = np.nonzero(ok)
        rows = np.column_stack([rows[r], k])
        used = used[r] + cost[k]
        # every prefix extends (by zeros) to a member: more prefixes than cap means too many
        if cap is not None and len(rows) > cap + 1:
            return None
    rows = rows[rows.sum(axis=1) > 0]
    keys = [-rows[:, d] for d in range(dim - 1, -1, -1)] + [rows.sum(axis=1)]
    return rows[np.lexsort(keys)]


def affordable(n, P, K=0, solver="lars"):
    """A candidate set of P columns, with K columns held already, within the limits."""
    held = K + P + 1  # at most: the design's columns, the Gram's rows
    return (
        P <= _candidate_cap(n, solver)
        and n * P * min(n, P) <= _ADAPTIVE_WORK * max(1.0, n / _ADAPTIVE_WORK_RUNS)
        and 8.0 * (2 * n * held + 3 * held * held) <= SELECTION_SHARE * memory_budget()
    )


def largest_affordable(n, solver="lars"):
    """The most candidates of an affordable set from n runs (the work and candidate caps).

    The candidate sets of one q-norm are nested, so a column-wise selection meets at most
    ``len(_ADAPTIVE_Q)`` times this many columns.
    """
    cap = _candidate_cap(n, solver)
    work = _ADAPTIVE_WORK * max(1.0, n / _ADAPTIVE_WORK_RUNS)
    if not work < cap * n * n:
        return cap
    # P <= n: n P^2 <= work; P > n: n^2 P <= work
    return min(max(math.isqrt(int(work // n)), int(work // (n * n))), cap)


def _untouched(rows, n):
    """An uninitialised (rows, n) array whose pages are only held once written.

    A private anonymous mapping of 4 KiB pages, not reserved against the swap, where the
    platform has one: NumPy asks for transparent huge pages for large arrays, whose first
    touch can cost several times the zeroing (compaction) when the design buffer is
    reserved for its most columns. Raises MemoryError when the mapping is refused.
    """
    flags = getattr(mmap, "MAP_PRIVATE", 0) | getattr(mmap, "MAP_ANONYMOUS", 0)
    if flags and rows * n:
        try:
            pages = mmap.mmap(-1, 8 * rows * n, flags=flags | getattr(mmap, "MAP_NORESERVE", 0))
        except OSError as err:
            raise MemoryError(f"no mapping of {8 * rows * n} bytes: {err}") from err
        return np.frombuffer(pages, dtype=float).reshape(rows, n)
    return np.empty((rows, n))


class _GrowingDesign:
    """The candidate columns met so far, their Gram matrix and correlations, grown in place.

    The adaptive candidate sets are nested (in the degree and in q), so each column is
    evaluated, and its Gram row computed, once: the selection of a set reads the blocks
    of :math:`G = \\Psi^T\\Psi` and :math:`\\Psi^T Y` it needs, centres and scales them
    (the constant column is column 0) and runs LAR in its Gram form; only the selected
    columns are refitted, by a QR of the design.

    ``capacity``: the most columns the selection may meet (:func:`largest_affordable` per
    q-chain and output); the buffer is reserved for them at once when the memory budget
    allows, untouched until written, and otherwise grown by half.
    """

    def __init__(self, germs, omega, Y, capacity=1):
        self.germs, self.omega, self.Y = germs, omega, Y
        self.n = len(omega)
        self.capacity = int(capacity)
        self.position = {}
        self.alpha = np.zeros((1, len(germs)), dtype=np.int64)
        # the columns are the rows of a C-ordered buffer (B is the column-major view of its
        # first rows) allocated for all the columns the selection may meet (``capacity``)
        # when that fits the memory budget: appending to a copied array cost a copy of all
        # columns per extension, and a buffer grown by half still a copy per growth
        self._rows = np.ones((1, self.n))
        self.B = self._rows.T
        self.G = np.array([[float(self.n)]])
        self.XtY = Y.sum(axis=0, keepdims=True)
        self.degree, self.tables, self.unit = -1, None, None

    def extend(self, alpha):
        """Add the multi-indices ``alpha`` (rows) not met yet; return their positions."""
        new = [a for a in map(tuple, alpha.tolist()) if a not in self.position]
        if new:
            new_alpha = np.array(new, dtype=np.int64)
            p = int(new_alpha.max())
            if p > self.degree:
                # transposed, (p + 1, n): a column's values per input are one row to gather;
                # _TABLE_AHEAD degrees ahead, as the degree grows one at a time (the values
                # of a degree do not depend on the highest one: the same three-term steps)
                p = max(p, self.degree + _TABLE_AHEAD)
                self.tables = [
                    np.ascontiguousarray(g.table(self.omega[:, d], p).T)
                    for d, g in enumerate(self.germs)
                ]
                self.degree = p
                self.unit = [bool(np.all(t[0] == 1.0)) for t in self.tables]
            k0, k1 = self.B.shape[1], self.B.shape[1] + len(new)
            check_allocation(
                8.0 * (self.n * k1 + 2 * k1 * k1),
                f"the adaptive sparse-regression design of {k1} candidates from n = {self.n} runs",
                "pass a smaller `order`, or a `q_norm` < 1",
            )
            if k1 > len(self._rows):
                self._grow(k1)
            # each new column evaluated in its row of the buffer: the product over the inputs
            # in their order, a zero degree of a unit table skipped (it multiplies by 1)
            BnT = self._rows[k0:k1]
            for row, a in zip(BnT, new_alpha.tolist(), strict=True):
                row[:] = self.tables[0][a[0]]
                for d in range(1, len(a)):
                    if a[d] or not self.unit[d]:
                        row *= self.tables[d][a[d]]
            Bn = BnT.T  # (n, new), column-major
            cross = self.B.T @ Bn
            G = np.empty((k1, k1))
            G[:k0, :k0] = self.G
            G[:k0, k0:] = cross
            G[k0:, :k0] = cross.T
            G[k0:, k0:] = Bn.T @ Bn
            self.G = G
            self.XtY = np.vstack([self.XtY, Bn.T @ self.Y])
            self.B = self._rows[:k1].T
            self.alpha = np.vstack([self.alpha, new_alpha])
            for k, a in enumerate(new):
                self.position[a] = k0 + k
        return np.array([self.position[a] for a in map(tuple, alpha.tolist())], dtype=np.int64)

    def _grow(self, k1):
        """Room for at least k1 columns: ``capacity`` at once, else the rows grown by half.

        The buffer is allocated, not written: its pages are only touched (and held) as
        columns are evaluated, so a buffer of ``capacity`` columns costs what its used
        columns cost, with no copy of the held columns as the design grows.
        """
        k0 = self.B.shape[1]
        half = max(k1, 3 * len(self._rows) // 2)
        # the widest within the budget (old and new columns held once while copied; at k1
        # none to spare, v0.4's peak) that the system maps: a system that reserves every
        # mapping against its memory may refuse the capacity
        widths = [w for w in (max(half, self.capacity), half) if w > k1]
        widths = [w for w in widths if 8.0 * self.n * (k0 + w) <= SELECTION_SHARE * memory_budget()]
        for width in widths:
            try:
                rows = _untouched(width, self.n)
                break
            except MemoryError:
                continue
        else:
            rows = np.empty((k1, self.n))
        rows[:k0] = self._rows[:k0]
        self._rows = rows
        self.B = self._rows[:k0].T

    def select(self, j, pos, first_steps):
        """Hybrid LAR on the columns at ``pos`` for output column j: (positions, coef, LOO)."""
        n, y = self.n, self.Y[:, j]
        ybar = float(np.mean(y))
        mu = self.G[0, pos] / n  # the column means (column 0 is the constant)
        Gc = self.G[np.ix_(pos, pos)] - n * np.outer(mu, mu)
        c = self.XtY[pos, j] - n * mu * ybar
        scale = np.sqrt(np.maximum(np.diag(Gc), 0.0))
        scale[scale == 0] = 1.0
        Gc /= scale[:, None]
        Gc /= scale[None, :]
        c = c / scale
        # beyond n / 2 terms the LOO correction factor exceeds 2: such fits never win
        max_steps = min(len(pos), max(n // 2, 2))
        steps = min(max_steps, max(int(first_steps), 8))
        return grow_path(
            lambda steps: lar_order_gram(Gc, c, steps),
            self.B,
            pos,
            y,
            steps,
            max_steps,
            gram=(self.G, self.XtY[:, j]),
        )


def _select_adaptive_column(design, j, solver, early_stop, max_degree):
    """Degree- and q-adaptive sparse selection of output column j.

    For p = 1, 2, ...: the candidate sets :math:`\\{\\alpha: \\|\\alpha\\|_q \\le p\\}` for
    q in ``_ADAPTIVE_Q`` that are affordable, each selected by the hybrid LAR path (run in
    pieces: the best set's size so far and 16 more, grown while the best set is among the last
    steps run) and scored by the corrected LOO error (Blatman & Sudret 2011). Each q is a
    chain of degrees with its own early stop (``early_stop`` degrees without improving
    that chain's error) and ends when its set is no longer affordable; the best set of
    all chains wins.

    Returns
    -------
    alpha : (k, dim) ndarray
        Selected multi-indices, the zero index first.
    coef : (k,) ndarray
    err : float
        Corrected LOO error.
    choice : tuple (p, q, P)
    trace : list of (p, q, P, err)
    """
    n, dim = design.n, len(design.germs)
    best, trace = None, []
    cap = _candidate_cap(n, solver)
    # one chain of degrees per q, each with its own early stop: the cheap q = 0.5 chain
    # may still improve at high degree after the dearer ones stopped (the LOO error of a
    # chain may stall for a degree or two, e.g. odd degrees of an even function)
    chain_best = dict.fromkeys(_ADAPTIVE_Q, np.inf)
    worse = dict.fromkeys(_ADAPTIVE_Q, 0)
    chain_terms = dict.fromkeys(_ADAPTIVE_Q, 0)  # terms of each chain's best set
    live = list(_ADAPTIVE_Q)
    for p in range(1, max_degree + 1):
        previous = None
        for q in list(live):
            alpha = hyperbolic_indices(dim, p, q, cap)
            if alpha is None or not affordable(n, len(alpha), design.B.shape[1], solver):
                # nested in q and p: every larger q, at every higher degree, is dearer
                live = [r for r in live if r < q]
                break
            if previous is not None and len(alpha) == previous[0]:
                err, terms = previous[1], previous[2]  # the same set as at the smaller q
            else:
                pos = design.extend(alpha)
                first = 32 if best is None else len(best[1]) + 16
                if chain_terms[q] and 8.0 * n * first > QR_BYTES:
                    # refits in Gram form score only a grown path's new columns: start
                    # from this chain's best size, not the best of all chains (a q = 0.5
                    # set rarely needs as many terms as the total-degree winner)
                    first = min(first, chain_terms[q] + 16)
                if solver == "lars":
                    cols, coef, err = design.select(j, pos, first)
                else:
                    y = design.Y[:, j]
                    cols, coef, err = sparse_select(design.B, y, pos, n, solver, first)
                trace.append((p, q, len(alpha), err))
                if best is None or err < best[2]:
                    best = (design.alpha[cols], coef, err, (p, q, len(alpha)))
                terms = len(cols)
            previous = (len(alpha), err, terms)
            if err < chain_best[q]:
                chain_best[q], worse[q], chain_terms[q] = err, 0, terms
            else:
                worse[q] += 1
                if worse[q] >= early_stop:
                    live.remove(q)
        if not live:
            break
    sel, coef, err, choice = best
    return sel, coef, err, choice, trace


@library_threads()  # many mid-sized products: a threaded BLAS only synchronizes (ecfm_uq.threads)
def select_adaptive(germs, omega, Y, early_stop, max_degree, solver):
    """:func:`_select_adaptive_column` for each column of Y (n, m), on one union basis.

    Returns
    -------
    alpha : (P, dim) ndarray
        The union of the selected multi-indices, graded, the zero index first.
    coeffs : (P, m) ndarray
    info : dict of per-column arrays (degree, q_norm, n_terms, corrected LOO error,
        candidates of the winning set) and the first column's ``trace``.
    """
    n, m = Y.shape
    dim = len(germs)
    design = _GrowingDesign(
        germs, omega, Y, 1 + len(_ADAPTIVE_Q) * m * largest_affordable(n, solver)
    )
    picked, info = [], dict(degree=[], q_norm=[], n_terms=[], errors=[], n_candidates=[])
    trace0 = None
    for j in range(m):
        y = Y[:, j]
        if np.all(y == y[0]):
            picked.append((np.zeros((1, dim), dtype=np.int64), np.array([y[0]])))
            choice, err, trace = (0, 1.0, 0), 0.0, []
        else:
            sel, coef, err, choice, trace = _select_adaptive_column(
                design, j, solver, early_stop, max_degree
            )
            picked.append((sel, coef))
        if trace0 is None:
            trace0 = trace
        info["degree"].append(int(picked[-1][0].sum(axis=1).max()))
        info["q_norm"].append(choice[1])
        info["n_candidates"].append(choice[2])
        info["n_terms"].append(len(picked[-1][1]))
        info["errors"].append(err)
    union = np.unique(np.vstack([s for s, _ in picked]), axis=0)
    keys = [-union[:, d] for d in range(dim - 1, -1, -1)] + [union.sum(axis=1)]
    union = union[np.lexsort(keys)]
    where = {tuple(a): k for k, a in enumerate(union.tolist())}
    coeffs = np.zeros((len(union), m))
    for j, (sel, coef) in enumerate(picked):
        rows = [where[tuple(a)] for a in sel.tolist()]
        coeffs[rows, j] = coef
    info = {k: np.array(v) for k, v in info.items()}
    info["trace"] = trace0
    return union, coeffs, info
