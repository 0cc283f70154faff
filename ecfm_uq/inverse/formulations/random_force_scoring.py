"""Fisher scoring for the random-force ECFM's eps search (shared force prior).

The data are Gaussian, :math:`v \\sim N(f(\\epsilon), S)` with
:math:`S = \\sigma^2 I + t\\,AA^T`, :math:`t = \\tau^2`
(:mod:`~ecfm_uq.inverse.formulations.random_forces`), so the expected (Fisher) information
of :math:`\\theta = (\\epsilon, t)` is known in closed form from what every evaluation of the
exact gradient already has (:math:`J`, :math:`A` and :math:`\\partial A/\\partial\\epsilon`,
:mod:`~ecfm_uq.inverse.formulations.random_force_gradient`):

.. math::

    I_{\\epsilon_i\\epsilon_j} = J_i^T S^{-1} J_j
    + \\tfrac12\\mathrm{tr}(S^{-1}\\partial_i S\\,S^{-1}\\partial_j S),\\quad
    I_{\\epsilon_i t} = \\tfrac12\\mathrm{tr}(S^{-1}\\partial_i S\\,S^{-1}AA^T),\\quad
    I_{tt} = \\tfrac12\\mathrm{tr}(S^{-1}AA^T S^{-1}AA^T),

:math:`\\partial_i S = t(\\partial_i A\\,A^T + A\\,\\partial_i A^T)`. With :math:`t` profiled
out the information of :math:`\\epsilon` is the Schur complement
:math:`F = I_{\\epsilon\\epsilon} - I_{\\epsilon t} I_{tt}^{-1} I_{t\\epsilon}`
(:func:`profiled_information`): the flat valley where the discrepancy trades off against
:math:`\\epsilon` is flat in :math:`F` too (at the optimum of the reaction rods of
``benchmarks/random_forces.py``, :math:`F^{-1}H` has eigenvalues 0.97-1.04 for the observed
information :math:`H`, whose own are 0.1-0.5 and 9-400 in standard-error units).
:func:`score` minimizes the profiled likelihood :math:`p(\\epsilon)` by scoring steps
:math:`-F^{-1}\\nabla p`, :math:`F` recomputed at every point (no Hessian by differences of
the gradient: no solve), with Armijo backtracking on the exact value of :math:`p`, until the
gradient meets the status tolerance and the next step would be below ``_SCORE_STEP``
standard errors (3-7 steps from the standard estimate there); where scoring does not
descend the previous path runs.

Where scoring ends at its tolerance the estimate's delta-method covariance is
:math:`F^{-1}` at the estimate (:func:`expected_uncertainty`: no solve), not the inverse
of the observed information :math:`H` by central differences of the exact gradient
(:math:`2p` solves, which the Newton finish of
:class:`~ecfm_uq.inverse.formulations.random_force_search.Search` computed to check the
point). Both are asymptotic covariances; over 200 seeded data sets per row (the coverage
study's random-force rows, a rod with 8 sensors and 1 % noise, and data drawn from the
random-force model itself) their standard errors differed by at most 6 % (median 0.3-1 %)
where :math:`\\hat\\tau > 0`, the 95 % intervals covered the truth in the same data sets,
and both standard errors stood in the same ratio to the empirical spread of the estimates
(``docs/calibration.md``). Elsewhere (the scalar search, the sparse prior, :math:`F` not
positive definite) the observed information is kept.
"""

from __future__ import annotations

import numpy as np
from scipy import optimize

from ...errors import ConvergenceError, ModelEvaluationError
from ...system.solve.factors import cho_factor, cho_solve
from ..core.result import Uncertainty
from ..statistics.uncertainty import confidence_intervals

__all__ = [
    "FAILURES",
    "expected_uncertainty",
    "gauss_newton_information",
    "profiled_information",
    "score",
    "singular",
]

# the model cannot be solved there (ValueError: non-finite parameters after an overflow)
FAILURES = (ConvergenceError, ModelEvaluationError, np.linalg.LinAlgError, ValueError)

_SCORE_STEP = 1e-6  # scoring ends where its next step would be below this (standard errors)
_CONDITION = 1e12  # a metric worse conditioned than this is refused (the previous path)


def _usable(w):
    """Whether a metric with eigenvalues ``w`` (ascending) is positive definite and
    conditioned better than ``_CONDITION``: scoring steps in it, the delta method inverts it."""
    return bool(np.all(np.isfinite(w)) and w[0] > 0 and w[-1] < _CONDITION * w[0])


def profiled_information(lin, sigma, t):
    """The expected information of :math:`\\epsilon` with :math:`t = \\tau^2` profiled out.

    Parameters
    ----------
    lin : Linearization
        At the point, with ``dA`` (``second=True``) where ``t > 0``.
    sigma : float
        The noise standard deviation.
    t : float
        The shared force variance :math:`\\hat\\tau^2` at the point.

    Returns
    -------
    (n_eps, n_eps) ndarray
        :math:`F = I_{\\epsilon\\epsilon} - I_{\\epsilon t} I_{tt}^{-1} I_{t\\epsilon}`
        (module docstring), symmetric; :math:`J^T J/\\sigma^2` where ``t`` is 0.
    """
    A, J = lin.A, lin.J
    S = sigma**2 * np.eye(A.shape[0]) + t * (A @ A.T)
    chol = cho_factor(S)
    F = J.T @ cho_solve(chol, J)
    if t > 0.0 and lin.dA is not None:
        m = J.shape[1]
        SiAA = cho_solve(chol, A @ A.T)
        SidS = []
        for i in range(m):
            dAi = lin.dA[:, :, i]
            SidS.append(cho_solve(chol, t * (dAi @ A.T + A @ dAi.T)))
        I_et = np.array([0.5 * np.sum(SidS[i] * SiAA.T) for i in range(m)])
        I_tt = 0.5 * np.sum(SiAA * SiAA.T)
        for i in range(m):
            for j in range(m):
                F[i, j] += 0.5 * np.sum(SidS[i] * SidS[j].T)
        if I_tt > 0.0:
            F = F - np.outer(I_et, I_et) / I_tt
    return 0.5 * (F + F.T)


def expected_uncertainty(F, eps, scale, level=0.95):
    """The delta method from the profiled expected information at the estimate.

    Parameters
    ----------
    F : (n_eps, n_eps) ndarray
        :func:`profiled_information` at ``eps``: the one Fisher scoring computed at the
        point it returned (``res.information`` of :func:`score`; no solve).
    eps : (n_eps,) ndarray
        The estimate.
    scale : (n_eps,) ndarray
        The search's coordinates (standard errors of the standard fit): ``F`` is checked
        and inverted in them.
    level : float
        Of the normal intervals.

    Returns
    -------
    Uncertainty or None
        :math:`F^{-1}`, ``method`` ``"marginal-likelihood-expected"``; ``None`` where
        ``F`` in the scaled coordinates is not positive definite or is conditioned worse
        than ``_CONDITION`` (the caller keeps the observed information).
    """
    Fs = F * np.outer(scale, scale)
    w = np.linalg.eigvalsh(Fs)
    if not _usable(w):
        return None
    cov = np.linalg.inv(Fs) * np.outer(scale, scale)
    cov = 0.5 * (cov + cov.T)
    se, intervals = confidence_intervals(eps, cov, level)
    return Uncertainty(
        True, "expected information of the marginal likelihood (tau profiled out)", cov, se,
        intervals, level, "marginal-likelihood-expected", "known",
    )  # fmt: skip


def gauss_newton_information(model, lin, g_hat):
    """:math:`J^T S^{-1} J` with :math:`S = \\sigma^2 I + A\\,\\mathrm{diag}(\\hat g)\\,A^T`,
    symmetrized."""
    F = lin.J.T @ np.linalg.solve(model.covariance(lin, g_hat), lin.J)
    return 0.5 * (F + F.T)


def singular(F):
    """Whether the information ``F`` is singular (smallest eigenvalue at most 1e-12 of
    the largest): a parameter combination the readings do not depend on."""
    w = np.linalg.eigvalsh(F)
    return not w[0] > 1e-12 * max(w[-1], 0.0)


def score(search, model, x0, armijo):
    """Fisher scoring: descent of the profiled likelihood in its expected information.

    Parameters
    ----------
    search : Search
        Its coordinates (``eps_std``, ``scale``: standard errors), budget, tolerance and
        evaluation count (``nfev``).
    model : RandomForceModel
        Shared prior, with :math:`\\hat\\tau > 0` at ``x0`` (else ``None`` is returned).
    x0 : (n_eps,) ndarray
        The start, scaled coordinates.
    armijo : callable
        The backtracking line search ``armijo(p, x, step, val, slope)`` of the search.

    Returns
    -------
    tuple or None
        ``(x, res, size)``: the point, an ``OptimizeResult`` (``fun`` the profiled nll
        there) and the length of the scoring step at ``x`` (standard errors, below
        ``_SCORE_STEP``: not taken); ``None`` where
        :math:`\\hat\\tau` is 0 at a point, the metric is not positive definite or a line
        search fails (the previous path runs).
    """
    x = np.array(x0, float)
    grad = search.gradient(model)
    # trial points by value only: an accepted one gets its second derivatives from the
    # same solve (the model keeps its last), a rejected one costs no back-substitution
    p = search.objective(model)
    val = p(x)
    for k in range(search.maxiter):
        try:
            eps = search.eps_std + search.scale * x
            g_hat = model.profiled(eps)[1]
            if not (np.isfinite(val) and np.any(g_hat)):
                return None
            g = grad(x)  # with its second derivatives: dA, no solve
            lin = model.linearization(eps, second=True)
            F = profiled_information(lin, model.sigma, float(g_hat[0]))
        except FAILURES:
            return None
        Fs = F * np.outer(search.scale, search.scale)
        w, V = np.linalg.eigh(Fs)
        if not _usable(w):
            return None
        step = -V @ ((V.T @ g) / w)
        size = float(np.max(np.abs(step)))
        if search.optimal(g, x) and size < _SCORE_STEP:
            # F travels with the point: the delta method's expected information there
            return x, optimize.OptimizeResult(
                x=x, fun=val, nit=k, njev=k + 1, success=True, information=F,
                message=f"Fisher scoring from the standard estimate ({k} steps)",
            ), size  # fmt: skip
        found = armijo(p, x, step, val, float(g @ step))
        if found is None:
            return None
        t, val = found
        x = x + t * step
    return None
