"""Principal components of field evaluations: the exact SVD, or a randomized SVD in blocks.

The compression of a field output before the sparse selection (PCA-PCE, Blatman &
Sudret 2013; :mod:`ecfm_uq.chaos.regression`): the centred evaluations
:math:`Y - \\bar y = USV^T` keep the leading principal components until every
component's discarded variance is below ``tol`` of its own variance. The exact thin SVD
holds about seven (n, m) arrays' worth of memory at its peak (the evaluations, their
centred copy, LAPACK's copy, the factors and the per-component energies); when that is
over the memory budget (:mod:`ecfm_uq.memory`), or on request, a randomized SVD
(Halko, Martinsson & Tropp 2011, randomized subspace iteration) works on the
evaluations in blocks of rows, centring each block on the fly, so the (n, m) matrix is
held once, and measures each component's discarded share on the data afterwards.
When even one copy of the evaluations is over the budget, :class:`StreamingSketch`
compresses them as they arrive from the model runner (one pass, nothing stored; Tropp,
Yurtsever, Udell & Cevher 2017), the discarded shares then estimated from an
independent Gaussian sketch.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg as sla

from ..._validation import check_choice, check_int
from ...executor import STREAM_CHUNK_BYTES
from ...memory import check_allocation, memory_budget

__all__ = ["StreamingSketch", "compress_outputs"]

# Rows per block (Gram path of the sparse selection, randomized compression): a block of
# this many bytes per array (or 1/64 of the budget if that is smaller).
_BLOCK_BYTES = 16 * 2**20


def row_blocks(n, width):
    """Row ranges [a, b) holding about _BLOCK_BYTES of ``width`` floats each."""
    block = min(_BLOCK_BYTES, memory_budget() / 64)
    step = max(1, int(block // (8 * max(width, 1))))
    return [(a, min(a + step, n)) for a in range(0, n, step)]


def _constant(total, ybar, n):
    """The components that do not vary (their spread below 1e-13 of their size): their
    discarded share is 0 whatever the rank."""
    scale = np.maximum(np.abs(ybar), np.sqrt(total / n))
    return total <= (1e-13 * scale) ** 2 * n


def exact_pca_bytes(n, m):
    """Peak of the exact compression: Y, its centred copy, LAPACK's copy, U, V^T, energies."""
    r = min(n, m)
    return 8.0 * (3 * n * m + n * r + 4 * r * m)


def randomized_pca_bytes(n, m, ell):
    """Peak of the randomized compression with a sketch of ``ell`` columns (Y held once).

    Y, the (n, l) sketches and QR factors, about eight (l, m) or (m, l) arrays (test
    matrix, products, the small SVD's factors and energies) and three row blocks.
    """
    rows = row_blocks(n, m)[0]
    block = rows[1] - rows[0]
    return 8.0 * (n * m + 3 * n * ell + 8 * m * ell + ell * ell + 3 * block * m)


def _rank_by_energy(energy, total, const, tol):
    """Smallest K whose discarded share is <= tol in every component, and the shares.

    ``energy[j, m]`` is component m's variance along direction j (decreasing j order),
    ``total[m]`` its variance; the discarded share when keeping K directions is
    ``(total - sum_{j<K} energy[j]) / total`` (0 for a constant component).
    """
    kept = np.vstack([np.zeros((1, energy.shape[1])), np.cumsum(energy, axis=0)])
    rel = np.where(const, 0.0, np.maximum(total - kept, 0.0) / np.where(const, 1.0, total))
    ok = np.flatnonzero(rel.max(axis=1) <= tol)
    return (int(ok[0]) if ok.size else None), rel


def _randomized_pca(Y, ybar, total, const, tol, oversample, power_iterations, seed):
    """Randomized range finder on the centred evaluations, in blocks of rows.

    Halko, Martinsson & Tropp (2011), Algorithm 4.4 (randomized subspace iteration):
    :math:`X = (Y - \\bar y)\\Omega` with a Gaussian :math:`\\Omega` of
    :math:`\\ell = K + p` columns, ``power_iterations`` passes
    :math:`X \\leftarrow (Y - \\bar y)\\,\\mathrm{orth}((Y - \\bar y)^T \\mathrm{orth}(X))`,
    then :math:`B = Q^T (Y - \\bar y) = \\tilde U S V^T`. The centring is applied block by
    block, so the centred (n, m) matrix never exists. The sketch starts at
    :math:`\\ell = 32` columns and doubles until some :math:`K \\le \\ell - p` meets the
    energy criterion, measured on the data: :math:`\\|(I - U_KU_K^T)(y_m - \\bar y_m)\\|^2
    = \\|y_m - \\bar y_m\\|^2 - \\sum_{j<K} S_j^2 V_{jm}^2` is exact for the computed
    orthonormal :math:`U_K = Q\\tilde U_K`, whatever the sketch's quality.

    Returns
    -------
    Z, V, K, ell, passes
    """
    n, m = Y.shape
    r = min(n, m)
    rng = np.random.default_rng(seed)
    blocks = row_blocks(n, m)

    # each block is centred before the product: subtracting ybar @ M afterwards would
    # cancel catastrophically when the mean dominates the fluctuations
    def times(M):  # (Y - ybar) @ M, (n, k)
        out = np.empty((n, M.shape[1]))
        for a, b in blocks:
            out[a:b] = (Y[a:b] - ybar) @ M
        return out

    def t_times(M):  # (Y - ybar)^T @ M, (m, k)
        out = np.zeros((m, M.shape[1]))
        for a, b in blocks:
            out += (Y[a:b] - ybar).T @ M[a:b]
        return out

    ell = min(32, r)
    passes = 0
    while True:
        check_allocation(
            randomized_pca_bytes(n, m, ell),
            f"the randomized principal components (sketch of {ell} columns) of {n} runs of "
            f"a {m}-component output",
            "pass a larger `compress_tol` (fewer components), fewer `n_samples`, or let "
            "the model return fewer output values",
        )
        Q = sla.qr(times(rng.standard_normal((m, ell))), mode="economic")[0]
        passes += 1
        for _ in range(power_iterations):
            W = sla.qr(t_times(Q), mode="economic")[0]
            Q = sla.qr(times(W), mode="economic")[0]
            passes += 2
        B = t_times(Q).T  # (ell, m) = Q^T (Y - ybar)
        passes += 1
        Ub, S, Vt = sla.svd(B, full_matrices=False)
        del B
        energy = S[:, None] ** 2 * Vt**2
        K, _ = _rank_by_energy(energy, total, const, tol)
        if ell >= r and K is None:
            K = r  # a full sketch: the tolerance is below round-off (e.g. tol = 0)
        if K is not None and (K <= ell - oversample or ell >= r):
            K = max(K, 1)
            Z = Q @ (Ub[:, :K] * S[:K])
            return Z, Vt[:K], K, ell, passes
        ell = min(2 * ell, r)


def compress_outputs(
    Y,
    tol,
    method="auto",
    *,
    oversample=10,
    power_iterations=2,
    seed=0,
    return_info=False,
):
    """Principal components of the evaluations, enough for every component to ``tol``.

    Parameters
    ----------
    Y : (n, m) ndarray
        Evaluations, one row per run.
    tol : float
        Largest discarded share of any component's own variance.
    method : {"auto", "exact", "randomized"}
        ``"exact"``: the thin SVD of the centred evaluations (LAPACK); ``"randomized"``:
        a randomized range finder in blocks of rows (Halko, Martinsson & Tropp 2011),
        which holds ``Y`` once plus a few (n, l) and (m, l) sketches; ``"auto"``: exact
        when its memory (``Y``, its centred copy, LAPACK's copy and the factors) fits the
        budget, randomized otherwise.
    oversample : int
        Randomized: sketch columns beyond the kept rank (p of Halko et al.).
    power_iterations : int
        Randomized: subspace iterations (each one more pass over ``Y`` each way).
    seed : int
        Randomized: seed of the Gaussian test matrix (the result is reproducible).
    return_info : bool
        Also return a dict: ``method``, ``rank``, and for the randomized path
        ``sketch_columns``, ``passes`` (over ``Y``), ``power_iterations``.

    Returns
    -------
    Z : (n, K) ndarray
        Scores :math:`U_K S_K` (centred columns).
    V : (K, m) ndarray
        Principal directions (orthonormal rows), :math:`Y \\approx \\bar y + Z V`.
    ybar : (m,) ndarray
    error : (m,) ndarray
        Discarded variance of each component over its variance (0 for a constant one).
        Exact path: read off the SVD. Randomized path: measured a posteriori, the
        residual :math:`\\|y_m - \\bar y_m - Z V_m\\|^2` over the component's variance,
        in one more pass over ``Y``.

    Raises
    ------
    MemoryBudgetError
        ``method="exact"`` over the budget (names ``compress='randomized'``), or even
        the randomized sketch over it (names ``compress_tol``, ``n_samples``).

    Notes
    -----
    With :math:`Y - \\bar y = USV^T`, component m's variance is
    :math:`\\sum_j S_j^2 V_{jm}^2`; keeping K directions discards
    :math:`\\sum_{j \\ge K} S_j^2 V_{jm}^2` of it, exactly. Both paths keep the smallest
    K for which every component's discarded share is at most ``tol``; the randomized
    subspace is near-optimal (not optimal), so its K may exceed the exact one by a few.
    """
    method = check_choice("compress", method, ("auto", "exact", "randomized"))
    n, m = Y.shape
    exact_bytes = exact_pca_bytes(n, m)
    if method == "auto":
        method = "exact" if exact_bytes <= memory_budget() else "randomized"
    if method == "exact":
        check_allocation(
            exact_bytes,
            f"the principal components (exact SVD) of {n} runs of a {m}-component output",
            "pass compress='randomized' (a randomized SVD holding the evaluations once), "
            "compress=False (one selection per component) or fit fewer components",
        )
        ybar = Y.mean(axis=0)
        Yc = Y - ybar
        U, S, Vt = np.linalg.svd(Yc, full_matrices=False)
        energy = S[:, None] ** 2 * Vt**2  # (r, m): component m's variance along direction j
        total = energy.sum(axis=0)
        const = _constant(total, ybar, len(Y))
        tail = np.cumsum(energy[::-1], axis=0)[::-1]  # tail[k] = discarded when keeping k
        rel = np.where(const, 0.0, tail / np.where(const, 1.0, total))
        rel = np.vstack([rel, np.zeros((1, rel.shape[1]))])
        ok = np.flatnonzero(rel.max(axis=1) <= tol)
        K = max(int(ok[0]) if ok.size else len(S), 1)
        out = (U[:, :K] * S[:K], Vt[:K], ybar, rel[K])
        # the column variances (np.var's arithmetic, on the centred copy already here)
        info = dict(method="exact", rank=K, variance=(Yc * Yc).mean(axis=0))
        return (*out, info) if return_info else out
    oversample = check_int("oversample", oversample, minimum=0)
    power_iterations = check_int("power_iterations", power_iterations, minimum=0)
    blocks = row_blocks(n, m)
    ybar = Y.mean(axis=0)
    total = np.zeros(m)
    for a, b in blocks:
        total += ((Y[a:b] - ybar) ** 2).sum(axis=0)
    const = _constant(total, ybar, n)
    Z, V, K, ell, passes = _randomized_pca(
        Y, ybar, total, const, tol, oversample, power_iterations, seed
    )
    resid = np.zeros(m)
    for a, b in blocks:
        resid += ((Y[a:b] - ybar - Z[a:b] @ V) ** 2).sum(axis=0)
    error = np.where(const, 0.0, resid / np.where(const, 1.0, total))
    info = dict(
        method="randomized",
        rank=K,
        sketch_columns=ell,
        passes=passes + 3,  # and the mean, the variances and the measured residual
        power_iterations=power_iterations,
        variance=total / n,
    )
    out = (Z, V, ybar, error)
    return (*out, info) if return_info else out


def streaming_bytes(n, m, k):
    """Peak memory of :class:`StreamingSketch` with a range sketch of ``k`` columns.

    Per output value: the test matrix (k), the co-range and error sketches (2k + 1 and
    32), the small SVD's input, copy and factor (3k) and a few (m,) sums; per run the
    range sketch and its QR factor (3k); plus the chunks in flight
    (:data:`ecfm_uq.executor.STREAM_CHUNK_BYTES`, twice) and the column slices.
    """
    per_value = k + (2 * k + 1) + _ERROR_SKETCH + 3 * k + 6
    return 8.0 * (per_value * m + 3 * n * k) + 2 * STREAM_CHUNK_BYTES + 4 * _SLICE_BYTES


# Rows of the Gaussian sketch that estimates the streamed compression's error (its
# relative standard deviation is sqrt(2 / _ERROR_SKETCH), 25 %).
_ERROR_SKETCH = 32
# Column slices of a streamed block: temporaries of at most this many bytes.
_SLICE_BYTES = 2**18


class StreamingSketch:
    """Principal components of evaluations that are never stored: a one-pass sketch.

    For evaluations :math:`Y` (n, m) arriving in blocks of rows (Tropp, Yurtsever, Udell
    & Cevher 2017, "Practical sketching algorithms for low-rank matrix approximation",
    Algorithm 7 with Gaussian test matrices): the range sketch :math:`X = Y\\Omega`
    (n, k), the co-range sketch :math:`W = \\Psi Y` (l, m), :math:`l = 2k + 1`, and an
    error sketch :math:`E = \\Theta Y` (s, m), all linear, so centring is applied at the
    end (:math:`X - 1(\\bar y\\Omega)`, ...). Then :math:`Q = \\mathrm{orth}(X)`,
    :math:`B = (\\Psi Q)^+ W`, :math:`B = \\tilde U S V^T` and :math:`Z = Q\\tilde U S`.

    Each component's discarded variance share cannot be measured without the data; it
    is estimated from the independent error sketch,
    :math:`\\|y_m - \\bar y_m - Z V_m\\|^2 \\approx \\|E_m - \\Theta Z V_m\\|^2 / s`
    (unbiased; relative standard deviation :math:`\\sqrt{2/s}` = 25 % for s = 32), and
    the rank is the smallest K whose estimate meets the tolerance in every component.
    """

    def __init__(self, n, m, k, seed=0):
        self.n, self.m, self.k = n, m, k
        rng = np.random.default_rng(seed)
        self.Omega = rng.standard_normal((m, k))
        self.Psi = rng.standard_normal((2 * k + 1, n))
        self.Theta = rng.standard_normal((_ERROR_SKETCH, n))
        self.X = np.zeros((n, k))
        self.W = np.zeros((2 * k + 1, m))
        self.E = np.zeros((_ERROR_SKETCH, m))
        self.shift = None
        self.s1 = np.zeros(m)  # sums of (y - shift) and of its squares: the variances
        self.s2 = np.zeros(m)
        self.rows = 0

    def __call__(self, start, block):
        """Add the rows ``start .. start + len(block) - 1`` (in order)."""
        block = block.reshape(len(block), -1)
        if self.shift is None:
            self.shift = block[0].copy()
        b = slice(start, start + len(block))
        self.X[b] = block @ self.Omega
        Psi, Theta = self.Psi[:, b], self.Theta[:, b]
        # column slices keep every temporary small (the sketches are updated in place)
        width = max(1, _SLICE_BYTES // (8 * max(len(Psi), len(block))))
        for j in range(0, self.m, width):
            cols = slice(j, j + width)
            Yb = block[:, cols]
            self.W[:, cols] += Psi @ Yb
            self.E[:, cols] += Theta @ Yb
            d = Yb - self.shift[cols]
            self.s1[cols] += d.sum(axis=0)
            self.s2[cols] += (d * d).sum(axis=0)
        self.rows += len(block)

    def _total(self):
        """(m,) sums of squared deviations from the mean."""
        return np.maximum(self.s2 - self.s1**2 / self.n, 0.0)

    def variance(self):
        """(m,) variances of the streamed components (population, ddof = 0)."""
        return self._total() / self.n

    def compress(self, tol):
        """``Z, V, ybar, error, info`` as :func:`compress_outputs` (error estimated)."""
        if self.rows != self.n:
            raise RuntimeError(f"the sketch holds {self.rows} of {self.n} rows")
        n = self.n
        ybar = self.shift + self.s1 / n
        total = self._total()
        const = _constant(total, ybar, n)
        # centred in place (the sketches are linear in Y); each big array is dropped as
        # soon as it is used, so the peak is the sketches plus the small SVD
        X = self.X - ybar @ self.Omega
        self.Omega = None
        Q = sla.qr(X, mode="economic")[0]
        del X
        self.W -= np.outer(self.Psi.sum(axis=1), ybar)
        E = self.E
        E -= np.outer(self.Theta.sum(axis=1), ybar)
        # B = (Psi Q)^+ W through the QR factors of the small (2k + 1, k) matrix
        Q2, R2 = sla.qr(self.Psi @ Q, mode="economic")
        B = Q2.T @ self.W
        self.W = None
        B = sla.solve_triangular(R2, B, overwrite_b=True)
        Ub, S, Vt = sla.svd(B, full_matrices=False, overwrite_a=True)
        del B
        TZ = (self.Theta @ Q) @ (Ub * S)  # Theta Z, (s, k)
        resid = E
        self.E = None
        K = None
        for j in range(len(S) + 1):
            if j:
                resid -= np.outer(TZ[:, j - 1], Vt[j - 1])
            est = np.where(
                const, 0.0, (resid**2).sum(axis=0) / _ERROR_SKETCH / np.where(const, 1.0, total)
            )
            if est.max() <= tol and j >= 1:
                K = j
                break
        if K is None:
            K = len(S)
        Z = Q @ (Ub[:, :K] * S[:K])
        info = dict(method="streaming", rank=K, sketch_columns=self.k, passes=1)
        info["variance"] = total / n
        info["tolerance_met"] = bool(est.max() <= tol)
        if not info["tolerance_met"]:
            warnings.warn(
                f"streamed compression: the {self.k}-column sketch keeps {K} components with "
                f"an estimated discarded share up to {est.max():.1e} > compress_tol={tol:.1e}; "
                "raise the memory budget (ECFM_UQ_MEMORY_BUDGET) so the evaluations can be "
                "stored and compressed exactly or by the randomized SVD, or return fewer "
                "output values",
                RuntimeWarning,
                stacklevel=2,
            )
        return Z, Vt[:K], ybar, est, info
