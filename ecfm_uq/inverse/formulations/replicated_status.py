"""Is the pseudo-likelihood fit's :math:`\\epsilon` a minimizer? The one status test of
the replicated fits (:func:`eps_optimality`: the relative Newton decrement in eps, the
Hessian differenced from the analytic gradient) and the Newton steps that finish an
estimate the optimizer left a hair short of it (:func:`penalty_eps_newton`) or certify it
at the inner solves' resolution (:func:`at_inner_resolution`). Used by
:mod:`~ecfm_uq.inverse.formulations.replicated`."""

from __future__ import annotations

import dataclasses

import numpy as np

from ...errors import ConvergenceError
from ..core.convergence import Optimality, bounds_arrays, gradient_optimality
from ..core.finite_differences import fd_jacobian
from ..problems.moments import DegenerateVarianceError
from .forces import optimal_forces

__all__ = ["FAILURES", "at_inner_resolution", "eps_hessian", "eps_optimality", "penalty_eps_newton"]

#: where a forward or inner solve cannot be done: a failed evaluation, not an error
FAILURES = (ConvergenceError, DegenerateVarianceError)


def eps_optimality(stationarity, eps, bounds, tol):
    """The one status test of every pseudo-likelihood fit: is ``eps`` a minimizer of the
    fit's objective in :math:`\\epsilon`?

    ``stationarity = (z, g, gradient)``: the objective at ``eps``, its analytic gradient
    there, and the gradient as a function of :math:`\\epsilon` (``"standard"``:
    :math:`\\Lambda(\\cdot, 0)`; ``"inner-outer"``: :math:`\\tfrac12\\|\\lambda^*\\|^2`
    along the branch of forces through the estimate's; ``"penalty"``:
    :math:`\\alpha\\Lambda(\\cdot, \\lambda)` at the returned forces, which have no
    minimizer to test). The Hessian is differenced from the analytic gradient (steps
    :math:`10^{-5}\\max(|\\epsilon_k|, 1)`, central inside the bounds, one-sided inward at
    them; :func:`~ecfm_uq.inverse.core.finite_differences.fd_jacobian`) and the test is the
    relative Newton decrement of
    :func:`~ecfm_uq.inverse.core.convergence.gradient_optimality`, parameters held at a
    bound dropped. The gradient's size alone says nothing: on the beam the inner-outer
    objective changes curvature by :math:`10^8` per unit load, so a gradient of 0.1 there is
    a
    Newton step of :math:`10^{-10}`.
    """
    z, g, gradient = stationarity
    if g is None:
        return Optimality(False, np.inf, "newton decrement", tol,
                          "in eps: the forces' Hessian is not positive definite at the "
                          "estimate (no smooth branch of optimal forces)")  # fmt: skip
    eps = np.asarray(eps, dtype=float)
    try:
        H = eps_hessian(gradient, eps, g, bounds)
    except FAILURES as e:
        return Optimality(False, np.inf, "newton decrement", tol, f"in eps: Hessian: {e}")
    opt = gradient_optimality(z, g, H, x=eps, bounds=bounds, tol=tol)
    return dataclasses.replace(opt, message=f"in eps: {opt.message}")


def eps_hessian(gradient, eps, g, bounds):
    """The Hessian in eps differenced from the analytic ``gradient`` (``g`` at ``eps``):
    the steps of :func:`eps_optimality`."""
    cols = []
    for k in range(eps.size):
        h = 1e-5 * max(abs(eps[k]), 1.0)
        lo, hi = (None, None) if bounds is None else bounds[k]
        up, down = hi is None or eps[k] + h <= hi, lo is None or eps[k] - h >= lo
        method, step = ("3-point", h) if up and down else ("2-point", h if up else -h)
        cols.append(fd_jacobian(gradient, eps, method=method, steps=step, f0=g, columns=[k]))
    return np.hstack(cols)


def penalty_eps_newton(like, eps, lam, alpha, bounds, tol, maxiter=20):
    """Newton steps in eps on the penalty objective at fixed forces ``lam``,
    :math:`\\alpha\\Lambda(\\epsilon, \\lambda)` (the log term does not depend on eps),
    until :func:`eps_optimality` holds or a step no longer lowers it.

    SLSQP down the :math:`\\lambda \\to 0` valley spends its iterations shrinking the
    forces (the log term falls without bound) and may stop with eps still moving, where
    it stopped depending on the machine's last bits (3.7e-4 off on one CPU, 1e-7 on
    another); at fixed forces the problem in eps is smooth and bounded, and its
    minimizer is what the status's "eps" test certifies.

    Returns
    -------
    eps, p
        The point and the pseudo-likelihood evaluation there.
    """
    lo, hi = bounds_arrays(bounds, eps.size)
    eps = np.asarray(eps, dtype=float)

    def gradient(e):
        return alpha * like.evaluate(e, lam, order=1).grad_eps

    p = like.evaluate(eps, lam, order=1)
    for _ in range(maxiter):
        z, g = alpha * p.value, alpha * p.grad_eps
        if eps_optimality((z, g, gradient), eps, bounds, tol).converged:
            break
        try:
            H = eps_hessian(gradient, eps, g, bounds)
            step = -np.linalg.solve(0.5 * (H + H.T), g)
        except (*FAILURES, np.linalg.LinAlgError):
            break
        for t in 0.5 ** np.arange(8):
            trial = np.clip(eps + t * step, lo, hi)
            try:
                pt = like.evaluate(trial, lam, order=1)
            except FAILURES:
                continue
            if alpha * pt.value < z:
                eps, p = trial, pt
                break
        else:
            break
    return eps, p


def at_inner_resolution(like, opt, stationarity, eps, lam, bounds, inner_tol):
    """The inner-outer status where the Newton decrement misses the test by little: the
    Newton step in eps, taken along the branch of forces, raises the objective instead of
    lowering it when the decrease it predicts is below the inner solves' resolution (the
    forces are solved to round-off of a Hessian of condition ~1e8 on the beam: a step of
    3e-8 moved 1/2|lambda*|^2 by 7e-4 up, where it predicted 1e-7 down). Then no descent
    is left that the objective can resolve: converged, at that resolution, said so.
    Otherwise ``opt`` as it was."""
    z, g, gradient = stationarity
    try:
        H = eps_hessian(gradient, eps, g, bounds)
        step = -np.linalg.solve(0.5 * (H + H.T), g)
        lo, hi = bounds_arrays(bounds, eps.size)
        f = optimal_forces(like, np.clip(eps + step, lo, hi), lam, tol=inner_tol)
    except (*FAILURES, np.linalg.LinAlgError):
        return opt
    if not f.success:
        return opt
    rise = 0.5 * float(f.lam @ f.lam) - z
    predicted = float(g @ step + 0.5 * step @ H @ step)
    if rise <= 0 or predicted >= 0:
        return opt
    return dataclasses.replace(
        opt, converged=True,
        message=f"{opt.message}; but the Newton step raises the objective by {rise:.2g} "
        f"where it predicts {predicted:.2g}: no descent the inner solves resolve "
        "(converged to their resolution)",
    )  # fmt: skip
