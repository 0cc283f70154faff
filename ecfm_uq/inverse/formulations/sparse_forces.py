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

import numpy as np

from ...errors import ConvergenceError

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
    A = np.asarray(A, float)
    r = np.asarray(r, float)
    g = np.array(g0, float)
    C, n = A.shape
    prev = _nll(A, r, sigma2, g)
    for _ in range(_MAX_SWEEPS):
        # S^-1 afresh each sweep (rank-one updates within it), so round-off cannot build up
        Si = np.linalg.inv(sigma2 * np.eye(C) + (A * g) @ A.T)
        Si = 0.5 * (Si + Si.T)
        change = 0.0
        for i in range(n):
            a = A[:, i]
            Sa = Si @ a
            s, q = float(a @ Sa), float(Sa @ r)
            den = 1.0 - g[i] * s  # S_{-i}^-1 from S^-1 (Sherman-Morrison, force i removed)
            exact = not den > _CANCELLATION  # force i dominates S: 1 - g s cancels
            if exact:
                g_i, g[i] = g[i], 0.0
                S_m = sigma2 * np.eye(C) + (A * g) @ A.T
                g[i] = g_i
                w = np.linalg.solve(S_m, np.column_stack([a, r]))
                s_m, q_m = float(a @ w[:, 0]), float(a @ w[:, 1])
            else:
                s_m, q_m = s / den, q / den
            new = _best_variance(s_m, q_m)
            delta = new - g[i]
            if delta == 0.0:
                continue
            change = max(change, abs(delta))
            g[i] = new
            den = 1.0 + delta * s
            if exact or not den > _CANCELLATION:
                Si = np.linalg.inv(sigma2 * np.eye(C) + (A * g) @ A.T)
            else:
                Si -= (delta / den) * np.outer(Sa, Sa)
        val = _nll(A, r, sigma2, g)
        if change <= rtol * max(g.max(initial=0.0), 1e-300) or abs(prev - val) <= rtol * max(
            1.0, abs(val)
        ):
            return g, val
        prev = val
    raise ConvergenceError(
        f"the force variances did not settle in {_MAX_SWEEPS} sweeps (largest change "
        f"{change:.3g} of {g.max():.3g}); the forces may be nearly collinear at the sensors: "
        "use fewer forces or the shared prior (options={'force_prior': 'shared'})"
    )


def _best_variance(s, q):
    """The maximizer :math:`(q^2 - s)/s^2` of one force's variance, or 0; written as
    :math:`(q/s)^2 - 1/s` so that a force of small effect (tiny ``s``) does not underflow
    :math:`s^2`."""
    if not (s > 0.0 and np.isfinite(s) and np.isfinite(q)) or q * q <= s:
        return 0.0
    ratio = q / s
    new = ratio * ratio - 1.0 / s
    return new if np.isfinite(new) and new > 0.0 else 0.0


def _nll(A, r, sigma2, g):
    S = sigma2 * np.eye(A.shape[0]) + (A * g) @ A.T
    c = np.linalg.cholesky(S)
    w = np.linalg.solve(c, r)
    return 0.5 * float(w @ w) + float(np.sum(np.log(np.diag(c))))
