"""The inner problem of the pseudo-likelihood forces: :math:`\\lambda^*(\\epsilon) =
\\arg\\min_\\lambda \\Lambda(\\epsilon, \\lambda)` (paper Eq. stochastic_model, read as
ECFM's inner-outer structure), and the curvature of :math:`\\Lambda` in :math:`\\epsilon`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import check_int, check_positive
from ...errors import ConvergenceError
from ..problems.moments import DegenerateVarianceError
from ..problems.pseudo_likelihood import LikelihoodPoint

__all__ = ["ForceSolution", "eps_curvature", "optimal_forces"]


@dataclass
class ForceSolution:
    """The likelihood-maximizing constraint forces at one :math:`\\epsilon`.

    Attributes
    ----------
    eps : (n_eps,) ndarray
    lam : (C,) ndarray
        :math:`\\lambda^*(\\epsilon)`.
    point : LikelihoodPoint
        :math:`\\Lambda` and its first and second derivatives at ``lam``.
    dlam_deps : (C, n_eps) ndarray or None
        :math:`-(\\partial^2_{\\lambda\\lambda}\\Lambda)^{-1}\\partial^2_{\\lambda\\epsilon}\\Lambda`
        (``None`` if the Hessian is not positive definite).
    min_hess_eig : float
        Smallest eigenvalue of :math:`\\partial^2\\Lambda/\\partial\\lambda^2`; positive at a
        strict local minimum.
    hess_cond : float
        Its condition number (large means weakly identified forces).
    success : bool
        Converged (Newton decrement below ``tol``) to a strict local minimum.
    message : str
    nit : int
    """

    eps: np.ndarray
    lam: np.ndarray
    point: LikelihoodPoint
    dlam_deps: np.ndarray | None
    min_hess_eig: float
    hess_cond: float
    success: bool
    message: str
    nit: int


def _newton_forces(like, eps, lam, tol, maxiter):
    """Globalized Newton on :math:`\\min_\\lambda \\Lambda(\\epsilon, \\lambda)`.

    Directions use the Hessian with its eigenvalues replaced by their absolute values
    (floored), so every step descends even where :math:`\\Lambda` is not convex; an
    Armijo backtracking search keeps every iterate inside the region where the forward
    solve and the variances exist. Near the minimum the steps are pure Newton steps
    (quadratic convergence). The stopping test is on the Newton decrement
    :math:`\\tfrac12 g^T|H|^{-1}g \\le \\mathrm{tol}\\,(1 + |\\Lambda|)`, which is
    invariant to the (badly) different scales of the forces. Returns
    ``(point, nit, converged, message)``.
    """
    p = like.evaluate(eps, lam, order=2)
    for it in range(maxiter + 1):
        g, H = p.grad_lam, p.hess_lam
        w, V = np.linalg.eigh(H)
        w_abs = np.maximum(np.abs(w), 1e-12 * max(np.abs(w).max(), 1e-300))
        step = -V @ ((V.T @ g) / w_abs)
        slope = float(g @ step)
        scale = 1.0 + abs(p.value)
        if -0.5 * slope <= tol * scale:
            return p, it, True, f"converged: Newton decrement below {tol:.0e} (1 + |Lambda|)"
        if it == maxiter:
            break
        # in the quadratic region Lambda differences drown in round-off; there the
        # full Newton step is accepted if it reduces the gradient
        quadratic = w[0] > 0 and -0.5 * slope <= 1e-8 * scale
        t = 1.0
        for _ in range(40):
            try:
                trial = like.evaluate(eps, p.lam + t * step, order=2)
            except (ConvergenceError, DegenerateVarianceError):
                t *= 0.5
                continue
            if trial.value <= p.value + 1e-4 * t * slope:
                break
            if quadratic and t == 1.0 and np.linalg.norm(trial.grad_lam) < np.linalg.norm(g):
                break
            t *= 0.5
        else:
            return (
                p,
                it,
                False,
                (f"line search failed to decrease Lambda (Newton decrement {-0.5 * slope:.3e})"),
            )
        p = trial
    return p, maxiter, False, f"no convergence in {maxiter} Newton iterations"


def optimal_forces(like, eps, lam0=None, *, tol=1e-15, maxiter=100):
    """The forces that maximize the pseudo-likelihood at fixed :math:`\\epsilon`.

    Solves :math:`\\partial\\Lambda/\\partial\\lambda = 0` (the constraint of Eq.
    stochastic_model) as :math:`\\min_\\lambda\\Lambda(\\epsilon,\\lambda)` with a
    globalized Newton method on the analytic gradient and Hessian (saddle-free directions,
    Armijo backtracking), then checks that the Hessian is positive definite.

    Parameters
    ----------
    like : PseudoLikelihood
    eps : (n_eps,) array_like
    lam0 : (C,) array_like, optional
        Start (zero forces by default).
    tol : float
        Stop when the Newton decrement :math:`\\tfrac12 g^T H^{-1} g` (the predicted
        decrease of :math:`\\Lambda`) is below ``tol * (1 + |Lambda|)``.
    maxiter : int

    Returns
    -------
    ForceSolution
    """
    if like.system.Gamma is None:
        raise ValueError("optimal_forces needs a system with constraint forces (Gamma)")
    eps = like.system.check_eps(eps)
    lam0 = like.forces(lam0)
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    point, nit, converged, msg = _newton_forces(like, eps, lam0, tol, maxiter)
    w = np.linalg.eigvalsh(point.hess_lam)
    min_eig = float(w[0])
    cond = float(w[-1] / w[0]) if w[0] > 0 else np.inf
    ok = converged and min_eig > 0
    dlam = None
    if min_eig > 0:
        dlam = -np.linalg.solve(point.hess_lam, point.hess_lam_eps)
    else:
        msg += f"; Hessian in lam is not positive definite (min eigenvalue {min_eig:.3e})"
    return ForceSolution(eps, point.lam, point, dlam, min_eig, cond, ok, msg, nit)


def eps_curvature(like, eps, *, profile=False, step=1e-4):
    """Curvature of :math:`\\Lambda` in :math:`\\epsilon` (the observed pseudo-information).

    ``profile=False``: :math:`\\partial^2\\Lambda(\\epsilon, 0)/\\partial\\epsilon^2`, the
    curvature the standard estimate sees. ``profile=True``: the curvature of the profile
    :math:`\\Lambda^*(\\epsilon) = \\min_\\lambda\\Lambda(\\epsilon, \\lambda)`, whose gradient
    is :math:`\\partial_\\epsilon\\Lambda(\\epsilon, \\lambda^*(\\epsilon))` (envelope theorem):
    how much information on :math:`\\epsilon` is left once the forces are free. Both by
    central differences of the analytic gradient (error O(step^2)).

    Parameters
    ----------
    like : PseudoLikelihood
    eps : (n_eps,) array_like
    profile : bool
    step : float
        Absolute step in :math:`\\epsilon`.

    Returns
    -------
    (n_eps, n_eps) ndarray
    """
    eps = like.system.check_eps(eps)
    step = check_positive("step", step)

    def grad(e):
        if not profile:
            return like.evaluate(e, None, order=1).grad_eps
        fs = optimal_forces(like, e)
        if not fs.success:
            raise ConvergenceError(f"inner solve at eps={e}: {fs.message}")
        return fs.point.grad_eps

    m = eps.size
    H = np.zeros((m, m))
    for r in range(m):
        e = np.zeros(m)
        e[r] = step
        H[:, r] = (grad(eps + e) - grad(eps - e)) / (2 * step)
    return 0.5 * (H + H.T)
