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

from ..errors import ConvergenceError

__all__ = ["sparse_force_variances"]

_MAX_SWEEPS = 5000
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
            f"`A` (C, n), `r` (C,) and `g0` (n,) must agree, got {A.shape}, {r.shape}, "
            f"{g.shape}"
        )
    val, change, settled = _sweeps(A, r, float(sigma2), g, float(rtol), _MAX_SWEEPS, _CANCELLATION)
    if not settled:
        raise ConvergenceError(
            f"the force variances did not settle in {_MAX_SWEEPS} sweeps (largest change "
            f"{change:.3g} of {g.max():.3g}); the forces may be nearly collinear at the "
            "sensors: use fewer forces or the shared prior (options={'force_prior': 'shared'})"
        )
    return g, val


@numba.njit(cache=True)
def _sweeps(A, r, sigma2, g, rtol, max_sweeps, cancellation):
    """The coordinate-ascent sweeps on ``g`` (in place): ``(nll, last change, settled)``.

    Each sweep starts from :math:`S^{-1}` afresh (rank-one updates within it, so round-off
    cannot build up); where ``1 - g_i s_i`` or ``1 + delta s_i`` would cancel (force
    ``i`` dominates S) the quantities are solved afresh instead of updated.
    """
    C, n = A.shape
    prev = _nll(A, r, sigma2, g)
    change = 0.0
    for _ in range(max_sweeps):
        Si = np.linalg.inv(_covariance(A, sigma2, g))
        Si = 0.5 * (Si + Si.T)
        change = 0.0
        for i in range(n):
            a = np.ascontiguousarray(A[:, i])
            Sa = Si @ a
            s = 0.0
            q = 0.0
            for k in range(C):
                s += a[k] * Sa[k]
                q += Sa[k] * r[k]
            den = 1.0 - g[i] * s  # S_{-i}^-1 from S^-1 (Sherman-Morrison, force i removed)
            exact = not den > cancellation  # force i dominates S: 1 - g s cancels
            if exact:
                g_i = g[i]
                g[i] = 0.0
                S_m = _covariance(A, sigma2, g)
                g[i] = g_i
                w = np.linalg.solve(S_m, np.column_stack((a, r)))
                s_m = 0.0
                q_m = 0.0
                for k in range(C):
                    s_m += a[k] * w[k, 0]
                    q_m += a[k] * w[k, 1]
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
                Si = np.linalg.inv(_covariance(A, sigma2, g))
            else:
                f = delta / den
                for k in range(C):
                    for m in range(C):
                        Si[k, m] -= f * (Sa[k] * Sa[m])
        val = _nll(A, r, sigma2, g)
        largest = 0.0
        for j in range(n):
            largest = max(largest, g[j])
        if change <= rtol * max(largest, 1e-300) or abs(prev - val) <= rtol * max(1.0, abs(val)):
            return val, change, True
        prev = val
    return prev, change, False


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
def _nll(A, r, sigma2, g):
    c = np.linalg.cholesky(_covariance(A, sigma2, g))
    C = r.shape[0]
    w = np.empty(C)  # c^-1 r by forward substitution
    ww = 0.0
    logdet = 0.0
    for k in range(C):
        acc = r[k]
        for m in range(k):
            acc -= c[k, m] * w[m]
        w[k] = acc / c[k, k]
        ww += w[k] * w[k]
        logdet += np.log(c[k, k])
    return 0.5 * ww + logdet
