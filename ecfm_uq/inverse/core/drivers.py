"""Optimizer drivers shared by the reduced formulations (objective and gradient in eps).

A driver takes ``evaluate(eps) -> (z, grad, payload)`` (the payload is whatever the
formulation keeps at the final point: a steady solution, a trajectory), runs one
optimizer, records the path and the inner-solve failures, and returns an
:class:`Outcome` of what it measured (no status: the formulation hands ``opt``,
``exhausted`` and ``final_error`` to its fitter's
:class:`~ecfm_uq.inverse.core.fitter.Outcome`, and :func:`~ecfm_uq.inverse.fit` decides
the status from them). An inner solve that fails at a trial point
(:class:`~ecfm_uq.errors.ConvergenceError`) counts as ``z = inf`` there and is reported.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize as sopt

from ...errors import ConvergenceError
from .convergence import (
    OFFSET_TOL,
    bounds_arrays,
    least_squares_optimality,
    minimize_optimality,
    polish_least_squares,
)

__all__ = [
    "MINIMIZE_METHODS",
    "Outcome",
    "check_minimize_method",
    "least_squares_scaled",
    "minimize_scaled",
    "verify_least_squares",
]


#: gradient methods of scipy.optimize.minimize the reduced fits accept by name
MINIMIZE_METHODS = ("BFGS", "CG", "L-BFGS-B", "TNC", "SLSQP", "Newton-CG", "trust-constr")


#: the options the least-squares driver takes (scipy.optimize.least_squares' keywords)
LEAST_SQUARES_KEYWORDS = ("maxiter", "ftol", "xtol", "gtol", "x_scale", "loss", "f_scale",
                          "diff_step", "tr_solver", "tr_options", "verbose")  # fmt: skip


def check_minimize_options(method, options, n):
    """Refuse, by name and before any model evaluation, options ``scipy.optimize.minimize``'s
    ``method`` does not know (scipy itself only warns, after the first evaluations).

    scipy's own check decides: a throw-away minimization of a quadratic in ``n``
    variables with the same method and options, one iteration.
    """
    if not options:
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            sopt.minimize(lambda x: (0.5 * x @ x, x), np.ones(n), jac=True, method=method,
                          options={**options, "maxiter": 1})  # fmt: skip
        except Exception:  # a bad value, not a bad name: the real run reports it
            return
    for w in caught:
        text = str(w.message)
        if "Unknown solver options" in text:
            names = text.split(":", 1)[-1].strip()
            raise TypeError(
                f"`options` has unknown name(s) {names} for method={method!r}: each name is "
                f"an option of scipy.optimize.minimize(method={method!r}) "
                f"(scipy.optimize.show_options('minimize', {method!r}))"
            )


def check_minimize_method(method):
    """``method`` must be a gradient method of ``scipy.optimize.minimize``."""
    if method.upper() not in {m.upper() for m in MINIMIZE_METHODS}:
        raise ValueError(
            f"unknown `method` {method!r}; choose a gradient method of {MINIMIZE_METHODS}"
        )


@dataclass
class Outcome:
    """What a driver did: the final point, what was measured there, the path and the
    failures.

    A driver decides no status: ``opt`` is the optimality conditions measured at ``x``
    (an :class:`~ecfm_uq.inverse.core.convergence.Optimality`; ``None`` until
    :func:`verify_least_squares` measures them, or when the model fails at ``x``),
    ``exhausted`` whether the optimizer's budget ran out, ``final_error`` the model
    failure at ``x``; ``claimed`` is the optimizer's own stopping claim, kept only for
    the message (it never decides the status).
    """

    x: np.ndarray
    loss: float
    grad: np.ndarray | None
    payload: object
    message: str
    nit: int
    nfev: int
    eps_history: np.ndarray
    loss_history: np.ndarray
    failures: list = field(default_factory=list)
    final_error: Exception | None = None
    opt: object = None
    #: the residual and its Jacobian at ``x`` that the status test judged (reused by the
    #: caller for the standard errors: no second Jacobian)
    residual: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    exhausted: bool = False
    claimed: bool = False

    @property
    def optimality(self):
        """The measured optimality's unit-free size (``None`` when not measured)."""
        return None if self.opt is None else self.opt.value


def minimize_scaled(evaluate, eps0, method, bounds, gtol, maxiter, options):
    """``scipy.optimize.minimize`` on the objective divided by its value at ``eps0``.

    Dividing by :math:`z(\\epsilon_0)` makes ``gtol`` relative (the tolerance does not
    depend on the data's units). The status is decided from what is measured at the
    returned point (:func:`minimize_optimality`), not from scipy's ``success``.

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
    check_minimize_options(method, options, np.size(eps0))
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
        return Outcome(x, np.inf, None, None, msg, nit, counts["nfev"], *path, failures,
                       e)  # fmt: skip
    opt = minimize_optimality(g, x, z, scale, gtol, bounds, precise=not failures)
    msg = str(res.message)
    if opt.converged and opt.test != "relative gradient":
        msg += f" ({opt.message})"
    if failures:
        msg += f" ({len(failures)} inner solves failed; first: {failures[0]})"
    exhausted = nit >= maxiter and not opt.converged
    return Outcome(x, z, g, payload, msg, nit, counts["nfev"], *path, failures, opt=opt,
                   exhausted=exhausted, claimed=opt.converged)  # fmt: skip


def verify_least_squares(out, residual, bounds, exhausted, *, polish, tol=OFFSET_TOL,
                         step_tol=math.inf):  # fmt: skip
    """Measure the least-squares optimality conditions at ``out.x``
    (:mod:`~ecfm_uq.inverse.core.convergence`), whatever the optimizer said.

    ``residual(eps) -> (r, J, payload)``. When the conditions do not hold and ``polish``
    is set and the optimizer stopped on its own (not ``exhausted`` its budget), a few
    Levenberg-Marquardt steps are taken from ``out.x`` first; likewise where they hold
    but the Gauss-Newton step is larger than ``step_tol`` relative to the parameters (an
    optimizer stopped on a relative decrease of the sum of squares, the estimate then
    brought to that accuracy). The returned
    :class:`Outcome` carries the measured optimality; its message keeps the optimizer's
    and adds the test's sentence when the two disagree (or after a polish).
    """
    if out.final_error is not None:  # the model cannot be solved at the final point
        return out
    try:
        r, J, payload = residual(out.x)
    except ConvergenceError as e:
        # the model fails there: a failure whatever ``opt`` (an earlier optimizer's
        # measurement, kept for its size) says
        out.final_error, out.exhausted = e, exhausted
        out.message = f"{out.message} ({e})"
        return out
    out.nfev += 1
    opt = least_squares_optimality(r, J, out.x, bounds=bounds, tol=tol)
    msg = out.message
    stepped = False
    if (not opt.converged or opt.step > step_tol) and polish and not exhausted:
        # a point that is not an optimum, or one whose estimate is not yet as accurate as
        # asked (the test holds, the Gauss-Newton step is larger than step_tol)
        refine, step = opt.converged, opt.step
        x, (r, J, payload), opt2, n = polish_least_squares(
            residual, out.x, bounds=bounds, tol=tol, step_tol=step_tol, first=(r, J, payload)
        )
        out.nfev += n
        if float(r @ r) <= 2 * out.loss or opt2.converged:
            out.x, out.loss, out.payload, opt = np.asarray(x), 0.5 * float(r @ r), payload, opt2
            stepped = True
            if refine:
                msg += (f"; its Gauss-Newton step ({step:.1e} of a parameter) brought below "
                        f"{step_tol:.0e} by Levenberg-Marquardt steps ({n} trial points)")  # fmt: skip
            else:
                msg += f"; polished by Levenberg-Marquardt steps ({n} evaluations)"
    said = out.claimed
    out.exhausted = exhausted
    if opt.converged != said or not opt.converged or stepped:
        msg += f" [{'converged' if opt.converged else 'NOT converged'}: {opt.message}]"
    out.message, out.opt = msg, opt
    out.residual, out.jacobian = r, J
    return out


def _blown_up(r0, eps0):
    """The error for a start whose residual cannot be squared in floating point (a model
    whose predictions there are ~1e154 times the data's or more: a start where the
    solution blows up), naming ``eps0``; the drivers' later points of that kind are
    failed points, their overflow unwarned (``np.errstate``)."""
    return ValueError(
        f"`eps0` = {np.asarray(eps0).tolist()}: the residual there is too large to be "
        f"squared (largest |r| {float(np.abs(r0).max()):.1e}): the model blows up at this "
        "start; start where its predictions are of the data's size"
    )


def least_squares_scaled(residual, eps0, bounds, tol, maxiter, options, check=None):
    """``scipy.optimize.least_squares`` (trust-region reflective, ``x_scale="jac"``, the
    exact Jacobian) on the residuals divided by their norm at ``eps0``.

    Parameters
    ----------
    residual : callable
        ``eps -> (r (n,), J (n, p), payload)``; may raise ConvergenceError (the trial
        point is rejected: the trust region shrinks). ``J`` may be a callable of no
        argument (a Jacobian computed only where the optimizer asks for it: at accepted
        points, not at rejected trials).
    eps0 : (p,) ndarray
    bounds : list of (lo, hi) or None
    tol : float or None
        Relative-offset tolerance of the convergence test (default
        :data:`~ecfm_uq.inverse.core.convergence.OFFSET_TOL`).
    maxiter : int
        Residual evaluations allowed to ``least_squares`` (``max_nfev``).
    options : dict
        ``polish`` (default True: Levenberg-Marquardt steps when the test fails), and any
        keyword of ``scipy.optimize.least_squares`` (``ftol``, ``xtol``, ``gtol``,
        ``x_scale``, ``loss``...).
    check : callable, optional
        The residual the status test and the polish use, ``eps -> (r, J, payload)``
        (default ``residual``): the same residual with a more accurate Jacobian (central
        differences where the optimizer's are one-sided), so that a point the test calls
        an optimum is one to the test's tolerance, not to the one-sided differences'
        error (:func:`least_squares_lm`).

    Returns
    -------
    Outcome
        With the optimality measured by :func:`verify_least_squares`.

    Raises
    ------
    ConvergenceError
        When the model cannot be solved at ``eps0``.
    """
    options = dict(options)
    polish = bool(options.pop("polish", True))
    if "maxiter" in options:  # the v0.2 spelling of minimize's budget
        maxiter = options.pop("maxiter")
    tol = OFFSET_TOL if tol is None else tol
    hist_eps, hist_loss, failures = [], [], []
    cache = {}
    counts = {"nfev": 0, "njev": 0}
    # model evaluations one lazy Jacobian costs (its stencil; counted into nfev)
    jacobian_cost = getattr(residual, "jacobian_evaluations", 0)

    def evaluate(x, with_jacobian=False):
        key = np.asarray(x, dtype=float).tobytes()
        if key not in cache:
            counts["nfev"] += 1
            try:
                cache.clear()
                cache[key] = list(residual(np.array(x, dtype=float)))
            except ConvergenceError as e:
                failures.append(str(e))
                cache[key] = None
        ev = cache[key]
        if with_jacobian and ev is not None and callable(ev[1]):
            counts["nfev"] += jacobian_cost
            try:  # a lazy Jacobian (differenced by the problem): only where asked for
                ev[1] = ev[1]()
            except ConvergenceError as e:
                failures.append(str(e))
                cache[key] = ev = None
        return ev

    first = evaluate(eps0)
    if first is None:
        raise ConvergenceError(f"the model cannot be solved at eps0={eps0}: {failures[0]}")
    r0 = np.asarray(first[0], dtype=float)
    with np.errstate(over="ignore"):
        if not math.isfinite(float(r0 @ r0)):
            raise _blown_up(r0, eps0)
    scale = float(np.linalg.norm(r0)) or 1.0
    hist_eps.append(np.array(eps0, dtype=float))
    hist_loss.append(0.5 * float(r0 @ r0))

    def fun(x):
        ev = evaluate(x)
        if ev is None:
            return np.full(r0.size, np.inf)
        z = 0.5 * float(ev[0] @ ev[0])
        if not math.isfinite(z):  # squares that overflow: a failed point
            failures.append(f"the sum of squares overflows at eps={np.asarray(x).tolist()}")
            return np.full(r0.size, np.inf)
        if not hist_loss or z < hist_loss[-1]:
            hist_eps.append(np.array(x, dtype=float))
            hist_loss.append(z)
        return np.asarray(ev[0], dtype=float) / scale

    def jac(x):
        ev = evaluate(x, with_jacobian=True)
        counts["njev"] += 1
        if ev is None:  # not reached: TRF asks for J only at accepted points
            return np.zeros((r0.size, np.size(x)))
        return np.asarray(ev[1], dtype=float).reshape(r0.size, -1) / scale

    lb, ub = bounds_arrays(bounds, len(eps0))
    kw = {"method": "trf", "x_scale": "jac", "ftol": 1e-15, "xtol": 1e-15, "gtol": 1e-15}
    kw.update(options)
    with np.errstate(over="ignore"):  # an overflowing trial is a failed point (fun)
        res = sopt.least_squares(fun, eps0, jac=jac, bounds=(lb, ub), max_nfev=maxiter, **kw)
    x = np.asarray(res.x)
    ev = evaluate(x, with_jacobian=True)
    nit = int(res.njev or 0)
    msg = str(res.message)
    if failures:
        msg += f" ({len(failures)} inner solves failed; first: {failures[0]})"
    if ev is None:
        e = ConvergenceError(failures[-1])
        return Outcome(x, np.inf, None, None, msg, nit, counts["nfev"], np.array(hist_eps),
                       np.array(hist_loss), failures, e)  # fmt: skip
    r, J, payload = ev
    # verify_least_squares measures the optimality (the status is decided from it)
    out = Outcome(
        x, 0.5 * float(r @ r), J.T @ r, payload, msg, nit,
        counts["nfev"], np.array(hist_eps), np.array(hist_loss), failures,
        exhausted=res.status == 0, claimed=res.status > 0,
    )  # fmt: skip

    def cached(e):
        ev = evaluate(e, with_jacobian=True)
        if ev is None:
            raise ConvergenceError(failures[-1])
        return ev

    judge = cached if check is None else _counted(check, counts)
    out = verify_least_squares(out, judge, bounds, out.exhausted, polish=polish, tol=tol)
    out.nfev = counts["nfev"]
    if out.loss < hist_loss[-1]:
        hist_eps.append(np.array(out.x))
        hist_loss.append(out.loss)
    out.eps_history, out.loss_history = np.array(hist_eps), np.array(hist_loss)
    return out


def _counted(check, counts, known=None):
    """``check`` (a residual with an accurate Jacobian, evaluated at once) counting its
    model evaluations into ``counts["nfev"]``.

    ``known``: ``(x, r, payload)``, the residual already evaluated at the driver's last
    point ``x``; when ``check`` has ``jacobian_at(eps, payload)`` (the Jacobian alone),
    the status test there reuses ``r`` and ``payload`` (the same residual: one model
    evaluation fewer) and asks only for the accurate Jacobian.
    """
    jacobian_at = getattr(check, "jacobian_at", None)
    key = None if known is None or jacobian_at is None else known[0].tobytes()
    cost = getattr(check, "jacobian_evaluations", 0)  # the Jacobian's model evaluations

    def judge(eps):
        eps = np.array(eps, dtype=float)
        if key is not None and eps.tobytes() == key:
            counts["nfev"] += cost
            return known[1], jacobian_at(eps, known[2]), known[2]
        counts["nfev"] += 1 + cost
        r, J, payload = check(eps)
        return r, (J() if callable(J) else J), payload

    return judge
