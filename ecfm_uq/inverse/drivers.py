"""Optimizer drivers shared by the reduced formulations (objective and gradient in eps).

A driver takes ``evaluate(eps) -> (z, grad, payload)`` (the payload is whatever the
formulation keeps at the final point: a steady solution, a trajectory), runs one
optimizer, records the path and the inner-solve failures, and returns an
:class:`Outcome`; the formulation turns it into an
:class:`~ecfm_uq.inverse.InverseResult`. An inner solve that fails at a trial point
(:class:`~ecfm_uq.errors.ConvergenceError`) counts as ``z = inf`` there and is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.optimize as sopt

from ..errors import ConvergenceError
from .status import FitStatus

__all__ = ["MINIMIZE_METHODS", "Outcome", "check_minimize_method", "minimize_scaled"]

#: gradient methods of scipy.optimize.minimize the reduced fits accept by name
MINIMIZE_METHODS = ("BFGS", "CG", "L-BFGS-B", "TNC", "SLSQP", "Newton-CG", "trust-constr")


def check_minimize_method(method):
    """``method`` must be a gradient method of ``scipy.optimize.minimize``."""
    if method.upper() not in {m.upper() for m in MINIMIZE_METHODS}:
        raise ValueError(
            f"unknown `method` {method!r}; choose a gradient method of {MINIMIZE_METHODS}"
        )


@dataclass
class Outcome:
    """What a driver did: the final point, how it stopped, the path and the failures."""

    x: np.ndarray
    loss: float
    grad: np.ndarray | None
    payload: object
    status: FitStatus
    message: str
    nit: int
    nfev: int
    eps_history: np.ndarray
    loss_history: np.ndarray
    failures: list = field(default_factory=list)
    final_error: Exception | None = None

    @property
    def success(self):
        return self.status.success


def minimize_scaled(evaluate, eps0, method, bounds, gtol, maxiter, options):
    """``scipy.optimize.minimize`` on the objective divided by its value at ``eps0``.

    Dividing by :math:`z(\\epsilon_0)` makes ``gtol`` relative (the tolerance does not
    depend on the data's units). A stop on "precision loss" (status 2) counts as
    converged when the objective is at round-off zero (a global minimum of a
    non-negative objective) or when a relative change of ``eps`` would change ``z`` by
    less than 1e-6 relative.

    Parameters
    ----------
    evaluate : callable
        ``eps -> (z, grad (n,), payload)``; may raise ConvergenceError.
    eps0 : (n,) ndarray
    method : str
    bounds : list of (lo, hi) or None
    gtol : float
    maxiter : int
    options : dict
        Extra ``scipy.optimize.minimize`` options (override the defaults).

    Returns
    -------
    Outcome

    Raises
    ------
    ConvergenceError
        When the objective cannot be evaluated at ``eps0``.
    """
    hist_eps, hist_loss, failures = [], [], []
    counts = {"nfev": 0}
    last = {}

    def fun(eps):
        counts["nfev"] += 1
        try:
            z, g, _ = evaluate(eps)
        except ConvergenceError as e:
            failures.append(str(e))
            z, g = np.inf, np.zeros_like(eps)
        last["eps"], last["z"] = np.array(eps), z
        return z / scale, g / scale

    def callback(xk, *args):
        # the optimizer evaluated fun at xk last (no second solve); fall back otherwise
        z = last["z"] if "eps" in last and np.array_equal(last["eps"], xk) else fun(xk)[0] * scale
        hist_eps.append(np.array(xk))
        hist_loss.append(z)

    scale = 1.0
    z0 = fun(eps0)[0]
    if not np.isfinite(z0):
        raise ConvergenceError(f"the model cannot be solved at eps0={eps0}: {failures[0]}")
    scale = z0 if z0 > 0 else 1.0
    last["z"] = z0  # z0 was computed with scale 1
    callback(eps0)
    opts = {"maxiter": maxiter}
    if method.upper() in {"BFGS", "CG", "L-BFGS-B", "TNC"}:
        opts["gtol"] = gtol
    if method.upper() == "L-BFGS-B":
        opts["ftol"] = 1e-15  # stop on the (relative) gradient, not on a stalled decrease
    opts.update(options)
    res = sopt.minimize(
        fun, eps0, jac=True, method=method, bounds=bounds, options=opts, callback=callback
    )
    counts["nfev"] += 1
    path = (np.array(hist_eps), np.array(hist_loss))
    x = np.asarray(res.x)
    nit = int(res.get("nit", 0))
    try:
        z, g, payload = evaluate(res.x)
    except ConvergenceError as e:  # the optimizer stopped where the model fails
        msg = f"{res.message} (the model cannot be solved at the final eps: {e})"
        return Outcome(x, np.inf, None, None, FitStatus.MODEL_FAILURE, msg, nit,
                       counts["nfev"], *path, failures, e)  # fmt: skip
    msg = str(res.message)
    success = bool(res.success)
    if not success and res.get("status") == 2 and not failures:
        # the line search could not decrease z at machine precision. That is convergence
        # when z is at round-off zero (both objectives are >= 0: a global minimum) or
        # when first-order optimality holds relative to z itself: a relative change of
        # eps would change z by less than 1e-6 relative (misspecified data: z* > 0)
        rel_opt = float(np.linalg.norm(g) * max(np.linalg.norm(res.x), 1.0) / max(z, 1e-300))
        if z <= 1e-20 * scale:
            success = True
            msg += " (objective at round-off zero: global minimum)"
        elif rel_opt <= 1e-6:
            success = True
            msg += f" (stopped at the round-off limit; relative optimality {rel_opt:.1e})"
    if failures:
        msg += f" ({len(failures)} inner solves failed; first: {failures[0]})"
    if success:
        status = FitStatus.CONVERGED
    elif nit >= maxiter:
        status = FitStatus.MAX_ITERATIONS
    else:
        status = FitStatus.STALLED
    return Outcome(x, z, g, payload, status, msg, nit, counts["nfev"], *path, failures)
