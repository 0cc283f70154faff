"""Force variances of their own: the sparse (ARD) prior of the random-force ECFM.

With the forces :math:`\\lambda_i \\sim N(0, g_i)` independent, each with its own variance,
the data covariance is :math:`S = \\sigma^2 I + A\\,\\mathrm{diag}(g)\\,A^T` and the marginal
likelihood :math:`\\ell = \\tfrac12 r^T S^{-1} r + \\tfrac12\\log\\det S` is maximized over
:math:`g \\ge 0` one force at a time: with :math:`S_{-i}` the covariance without force
:math:`i`, :math:`s_i = a_i^T S_{-i}^{-1} a_i` and :math:`q_i = a_i^T S_{-i}^{-1} r`, the
likelihood in :math:`g_i` alone has the single maximum

.. math::

    g_i = \\max\\Bigl(\\frac{q_i^2 - s_i}{s_i^2},\\ 0\\Bigr)

(automatic relevance determination; Tipping 2001, Tipping & Faul 2003). Every update
raises the likelihood, so the sweeps converge to a point where no single force can do
better; at that point most variances are exactly zero: the forces concentrate where the
data need them, the prior of a discrepancy that is localized (a missing source, a missing
contact) rather than spread evenly.
"""

from __future__ import annotations

import numba
import numpy as np

from ...errors import ConvergenceError

__all__ = ["sparse_force_variances"]

_MAX_SWEEPS = 5000
_SETTLED, _UNSETTLED, _NOT_POSITIVE = 0, 1, 2  # the kernel's outcome
_CANCELLATION = 1e-6  # below this 1 - g s (or 1 + delta s) loses digits: solve afresh


def sparse_force_variances(A, r, sigma2, g0, rtol=1e-12):
    """Maximize the marginal likelihood over independent force variances.

    Parameters
    ----------
    A : (C, n) array
        Force-to-reading map.
    r : (C,) array
        Residual of the model without forces.
    sigma2 : float
        Noise variance.
    g0 : (n,) array
        Starting variances (non-negative).
    rtol : float
        A sweep that changes no variance by more than ``rtol`` times the largest (and the
        likelihood by less than ``rtol``) ends the search.

    Returns
    -------
    g : (n,) array
        The variances; ``g[i] == 0`` for the forces the data do not need.
    nll : float
        :math:`\\tfrac12 r^T S^{-1} r + \\tfrac12\\log\\det S` at ``g``.

    Raises
    ------
    ConvergenceError
        If the sweeps do not settle.
    """
    A = np.ascontiguousarray(A, dtype=float)
    r = np.ascontiguousarray(r, dtype=float)
    g = np.array(g0, dtype=float)
    if A.ndim != 2 or r.shape != (A.shape[0],) or g.shape != (A.shape[1],):
        raise ValueError(
            f"`A` (C, n), `r` (C,) and `g0` (n,) must agree, got {A.shape}, {r.shape}, {g.shape}"
        )
    val, change, status = _sweeps(A, r, float(sigma2), g, float(rtol), _MAX_SWEEPS, _CANCELLATION)
    if status == _NOT_POSITIVE:
        raise np.linalg.LinAlgError(
            "sigma^2 I + A diag(g) A^T is not positive definite (a negative variance or "
            "sigma2 <= 0?)"
        )
    if status == _UNSETTLED:
        raise ConvergenceError(
            f"the force variances did not settle in {_MAX_SWEEPS} sweeps (largest change "
            f"{change:.3g} of {g.max():.3g}); the forces may be nearly collinear at the "
            "sensors: use fewer forces or the shared prior (options={'force_prior': 'shared'})"
        )
    return g, val


@numba.njit(cache=True)
def _sweeps(A, r, sigma2, g, rtol, max_sweeps, cancellation):
    """The coordinate-ascent sweeps on ``g`` (in place): ``(nll, last change, status)``.

    Each sweep starts from :math:`S^{-1}` afresh (rank-one updates within it, so round-off
    cannot build up); where ``1 - g_i s_i`` or ``1 + delta s_i`` would cancel (force
    ``i`` dominates S) the quantities are solved afresh instead of updated. Plain loops
    and a Cholesky factorization of their own (S is symmetric positive definite), so
    the kernel compiles in seconds.
    """
    C, n = A.shape
    prev, ok = _nll(A, r, sigma2, g)
    if not ok:
        return prev, 0.0, _NOT_POSITIVE
    change = 0.0
    Sa = np.empty(C)
    for _ in range(max_sweeps):
        Si, ok = _inverse(_covariance(A, sigma2, g))
        if not ok:
            return prev, change, _NOT_POSITIVE
        Si = 0.5 * (Si + Si.T)
        change = 0.0
        for i in range(n):
            s = 0.0
            q = 0.0
            for k in range(C):
                acc = 0.0
                for m in range(C):
                    acc += Si[k, m] * A[m, i]
                Sa[k] = acc
                s += A[k, i] * acc
                q += acc * r[k]
            den = 1.0 - g[i] * s  # S_{-i}^-1 from S^-1 (Sherman-Morrison, force i removed)
            exact = not den > cancellation  # force i dominates S: 1 - g s cancels
            if exact:
                g_i = g[i]
                g[i] = 0.0
                L, ok = _cholesky(_covariance(A, sigma2, g))
                g[i] = g_i
                if not ok:
                    return prev, change, _NOT_POSITIVE
                wa = _cho_solve(L, np.ascontiguousarray(A[:, i]))
                wr = _cho_solve(L, r)
                s_m = 0.0
                q_m = 0.0
                for k in range(C):
                    s_m += A[k, i] * wa[k]
                    q_m += A[k, i] * wr[k]
            else:
                s_m, q_m = s / den, q / den
            new = _best_variance(s_m, q_m)
            delta = new - g[i]
            if delta == 0.0:
                continue
            change = max(change, abs(delta))
            g[i] = new
            den = 1.0 + delta * s
            if exact or not den > cancellation:
                Si, ok = _inverse(_covariance(A, sigma2, g))
                if not ok:
                    return prev, change, _NOT_POSITIVE
            else:
                f = delta / den
                for k in range(C):
                    for m in range(C):
                        Si[k, m] -= f * (Sa[k] * Sa[m])
        val, ok = _nll(A, r, sigma2, g)
        if not ok:
            return prev, change, _NOT_POSITIVE
        largest = 0.0
        for j in range(n):
            largest = max(largest, g[j])
        if change <= rtol * max(largest, 1e-300) or abs(prev - val) <= rtol * max(1.0, abs(val)):
            return val, change, _SETTLED
        prev = val
    return prev, change, _UNSETTLED


@numba.njit(cache=True)
def _best_variance(s, q):
    """The maximizer :math:`(q^2 - s)/s^2` of one force's variance, or 0; written as
    :math:`(q/s)^2 - 1/s` so that a force of small effect (tiny ``s``) does not underflow
    :math:`s^2`."""
    if not (s > 0.0 and np.isfinite(s) and np.isfinite(q)) or q * q <= s:
        return 0.0
    ratio = q / s
    new = ratio * ratio - 1.0 / s
    return new if np.isfinite(new) and new > 0.0 else 0.0


@numba.njit(cache=True)
def _covariance(A, sigma2, g):
    """:math:`\\sigma^2 I + A\\,\\mathrm{diag}(g)\\,A^T`."""
    C, n = A.shape
    S = np.zeros((C, C))
    for k in range(C):
        S[k, k] = sigma2
        for m in range(C):
            acc = 0.0
            for j in range(n):
                acc += A[k, j] * g[j] * A[m, j]
            S[k, m] += acc
    return S


@numba.njit(cache=True)
def _cholesky(S):
    """Lower Cholesky factor of ``S`` and whether ``S`` was positive definite."""
    C = S.shape[0]
    L = np.zeros((C, C))
    for j in range(C):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return L, False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, C):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    return L, True


@numba.njit(cache=True)
def _forward(L, b):
    """:math:`L^{-1} b`, ``L`` lower triangular."""
    C = b.shape[0]
    w = np.empty(C)
    for k in range(C):
        acc = b[k]
        for m in range(k):
            acc -= L[k, m] * w[m]
        w[k] = acc / L[k, k]
    return w


@numba.njit(cache=True)
def _cho_solve(L, b):
    """:math:`(L L^T)^{-1} b`."""
    w = _forward(L, b)
    C = b.shape[0]
    x = np.empty(C)
    for k in range(C - 1, -1, -1):
        acc = w[k]
        for m in range(k + 1, C):
            acc -= L[m, k] * x[m]
        x[k] = acc / L[k, k]
    return x


@numba.njit(cache=True)
def _inverse(S):
    """:math:`S^{-1}` of a symmetric positive definite ``S`` (and whether it was)."""
    C = S.shape[0]
    L, ok = _cholesky(S)
    Si = np.zeros((C, C))
    if not ok:
        return Si, False
    e = np.zeros(C)
    for j in range(C):
        e[j] = 1.0
        Si[:, j] = _cho_solve(L, e)
        e[j] = 0.0
    return Si, True


@numba.njit(cache=True)
def _nll(A, r, sigma2, g):
    """:math:`\\tfrac12 r^T S^{-1} r + \\tfrac12\\log\\det S` and whether S was positive
    definite."""
    L, ok = _cholesky(_covariance(A, sigma2, g))
    if not ok:
        return np.inf, False
    w = _forward(L, r)
    val = 0.0
    for k in range(r.shape[0]):
        val += 0.5 * w[k] * w[k] + np.log(L[k, k])
    return val, True
