"""MINPACK's Levenberg-Marquardt as the driver of unbounded least-squares fits.

:func:`least_squares_lm` runs scipy's compiled lmdif (MINPACK differencing the residual,
one-sided, in compiled code) or lmder (the residual's own Jacobian) through
:mod:`.minpack`, then measures the least-squares optimality conditions at its final point
(:func:`~.drivers.verify_least_squares`): the unbounded fit of a
:class:`~ecfm_uq.inverse.problems.model.ModelProblem` at ``scipy.optimize.curve_fit``'s
cost, its status decided afterwards from what was measured, never from MINPACK's ``info``.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from ...errors import ConvergenceError
from . import minpack
from .convergence import OFFSET_TOL
from .drivers import Outcome, _blown_up, _counted, verify_least_squares

__all__ = ["LM_FTOL", "LM_KEYWORDS", "LM_STEP_TOL", "least_squares_lm"]

#: a float as the 8 bytes of a native float64 array element (``x.tobytes()``'s slots)
_pack_double = struct.Struct("=d").pack
#: MINPACK's relative difference step, sqrt(machine epsilon)
_ROOT_EPS = float(np.sqrt(np.finfo(float).eps))

#: options of the Levenberg-Marquardt driver (MINPACK's lmdif/lmder: :mod:`.minpack`)
LM_KEYWORDS = ("polish", "ftol", "xtol", "gtol", "x_scale")
_LM_OPTIONS = frozenset(LM_KEYWORDS)
#: MINPACK's default ``ftol`` here (the relative decrease of the sum of squares that ends
#: it): 1e-10, where the status test holds at its end on the calibration benchmark's
#: problems and on the NIST StRD fits; the estimate is then brought to :data:`LM_STEP_TOL`
#: by Gauss-Newton steps on the status test's Jacobian where it is not there yet. (At
#: 1e-14, the sum of squares' round-off, it cost one MINPACK iteration more, p + 1
#: evaluations, on every fit; at 1e-15 its last iterations hunted in rounding noise.)
LM_FTOL = 1e-10
#: the Gauss-Newton step, relative to each parameter, that the estimate of an LM fit is
#: brought below (:func:`~.drivers.verify_least_squares`' ``step_tol``): measured at
#: MINPACK's end on the status test's accurate Jacobian, it equals the distance to
#: NIST's certified values (1e-9 to 5e-6 at ``ftol`` = 1e-10, ENSO the farthest)
LM_STEP_TOL = 1e-7


def least_squares_lm(residual, eps0, tol, maxiter, options, check=None, differences=False):
    """MINPACK's Levenberg-Marquardt (:func:`~.minpack.lm`: scipy's compiled lmder with the
    Jacobian from ``residual``, or lmdif differencing it), then the status test of
    :func:`verify_least_squares`.

    The unbounded fit of :func:`least_squares_scaled` at the speed of
    ``scipy.optimize.curve_fit``: MINPACK scales the parameters by the column norms of
    the Jacobian (``x_scale="jac"``) and takes the same kind of step; its own
    stopping message is kept, and the status is decided after it, from the optimality
    measured at its final point (with ``check``'s Jacobian when given), never from
    MINPACK's ``info``.

    Parameters
    ----------
    residual : callable
        ``eps -> (r (n,), J (n, p) or a callable of no argument, payload)``; may raise
        ConvergenceError (the trial point is rejected: the damping grows).
    eps0 : (p,) ndarray
    tol : float or None
        Relative-offset tolerance of the status test.
    maxiter : int
        Residual evaluations allowed (MINPACK's ``maxfev``).
    options : dict
        ``polish`` (default True: also the steps to :data:`LM_STEP_TOL`), ``ftol``,
        ``xtol``, ``gtol`` (MINPACK's; defaults :data:`LM_FTOL`, 1e-15, 1e-15; the status
        test judges), ``x_scale`` (only ``"jac"``).
    check : callable, optional
        The residual of the status test and the polish (see :func:`least_squares_scaled`).
    differences : bool
        MINPACK differences the residual itself (lmdif: one-sided, step
        :math:`\\sqrt{\\varepsilon}\\,|\\epsilon_j|`, in compiled code) instead of
        asking ``residual`` for its Jacobian: the steering Jacobian of a one-sided
        difference mode, at ``curve_fit``'s cost. The status test's Jacobian is then
        ``check``'s (required).

    Returns
    -------
    Outcome

    Raises
    ------
    ConvergenceError
        When the model cannot be solved at ``eps0``.
    """
    options = dict(options)
    polish = bool(options.pop("polish", True))
    if options.pop("x_scale", "jac") != "jac":
        raise ValueError("least_squares_lm scales by the Jacobian only (x_scale='jac')")
    if not options.keys() <= _LM_OPTIONS:
        unknown = sorted(set(options) - _LM_OPTIONS)
        raise TypeError(f"`options` {unknown} are not options of Levenberg-Marquardt")
    tol = OFFSET_TOL if tol is None else tol
    eps0 = np.array(eps0, dtype=float)
    hist_eps, hist_loss, failures = [], [], []
    counts = {"nfev": 0}
    # model evaluations one lazy Jacobian costs (its stencil; counted into nfev)
    jacobian_cost = getattr(residual, "jacobian_evaluations", 0)
    # the last point evaluated (MINPACK asks again for the one it just had, e.g. the
    # Jacobian's base): plain closure cells, the cheapest state Python has per call
    last_key, last_ev = None, None

    def evaluate(x, key=None):
        nonlocal last_key, last_ev
        key = x.tobytes() if key is None else key
        if key != last_key:
            counts["nfev"] += 1
            try:
                ev = list(residual(x.copy()))
            except ConvergenceError as e:
                failures.append(str(e))
                ev = None
            last_key, last_ev = key, ev
        return last_ev

    first = evaluate(eps0)
    if first is None:
        raise ConvergenceError(f"the model cannot be solved at eps0={eps0}: {failures[0]}")
    m = np.size(first[0])
    p = eps0.size
    if m < p:
        raise ValueError(f"the residual has {m} entries for {p} parameters: at least {p} needed")

    # a rejected trial point: a residual far above any other (MINPACK then shrinks the
    # step; inf would turn its norms into nan), made when one is
    def rejected():
        return np.full(m, 1e150)

    # the best point so far (MINPACK returns it: it accepts only steps that lower the sum
    # of squares), kept with its evaluation: the final point costs no model call
    best_loss, best_key, best_ev = np.inf, None, None
    # MINPACK's differencing (lmdif's fdjac2): column j at base + h_j e_j, h_j =
    # sqrt(machine eps) |base_j| (sqrt(eps) at 0), right after each iterate, the p columns
    # in one run (fdjac2 loops over them without a break). Column 0 is recognized bit for
    # bit (its point's bytes spliced from the base's: Python floats are IEEE doubles, the
    # same sum as MINPACK's), the p - 1 after it counted down; they count as one Jacobian
    # per iterate and stay out of the path.
    root_eps = _ROOT_EPS
    fd_next, fd_left, fd_njev = None, 0, 0

    # the residual's values alone where MINPACK differences them (its `plain` when it has
    # one: (r, r @ r, y, fresh) with y possibly the model's own array, no Jacobian
    # closure; a failed point raises ConvergenceError)
    values = getattr(residual, "plain", None)
    if values is None:

        def values(e):
            r, _, y = residual(e)
            return r, r.dot(r), y, True

    first_key, nfev = eps0.tobytes(), 0

    def overflowed(r, key, x):
        """A point whose squares overflow: a failed point, rejected (the start: refused
        by name, MINPACK's first call)."""
        if key == first_key:
            raise _blown_up(r, eps0)
        failures.append(f"the sum of squares overflows at eps={x.tolist()}")
        return rejected()

    def fun(x):  # lmder: the residual with its (lazy) Jacobian
        nonlocal best_loss, best_key, best_ev
        key = x.tobytes()
        ev = evaluate(x, key)
        if ev is None:
            return rejected()
        r = ev[0]
        z = 0.5 * float(r.dot(r))
        if not math.isfinite(z):
            return overflowed(r, key, x)
        if z < best_loss:
            best_ev, best_loss, best_key = ev, z, key
            hist_eps.append(x.copy())
            hist_loss.append(z)
        return r

    def fun_differenced(x):  # lmdif: the residual alone, columns recognized
        nonlocal best_loss, best_key, best_ev, fd_next, fd_left, fd_njev, nfev
        if not fd_left:
            key = x.tobytes()
            if key == fd_next:  # column 0 of MINPACK's Jacobian: p columns to come
                fd_left, fd_next = p, None
        if fd_left:  # a column of MINPACK's Jacobian: out of the path
            fd_left -= 1
            if not fd_left:
                fd_njev += 1
            nfev += 1
            try:
                return values(x.copy())[0]
            except ConvergenceError as e:
                failures.append(str(e))
                return rejected()
        # an iterate or a trial point: the base of the columns that may follow
        bj = x.item(0)
        fd_next = _pack_double(bj + (root_eps * abs(bj) or root_eps)) + key[8:]
        if key == first_key:
            ev = first
            r = ev[0]
            ss = r.dot(r)
        else:
            nfev += 1
            try:
                r, ss, y, _ = values(x.copy())
            except ConvergenceError as e:
                failures.append(str(e))
                return rejected()
            ev = None
        z = 0.5 * float(ss)
        if not math.isfinite(z):
            return overflowed(r, key, x)
        if z < best_loss:
            # the best point's evaluation kept (its predictions copied: the model's array)
            best_ev = [r, None, y.copy()] if ev is None else ev
            best_loss, best_key = z, key
            hist_eps.append(x.copy())
            hist_loss.append(z)
        return r

    def jac(x):
        ev = evaluate(x)
        if ev is None:  # not reached: MINPACK asks for J only at accepted points
            return np.zeros((m, x.size))
        if callable(ev[1]):
            counts["nfev"] += jacobian_cost
            try:  # a lazy Jacobian (differenced by the problem): only where asked for
                ev[1] = ev[1]()
            except ConvergenceError as e:
                failures.append(str(e))
                return np.zeros((m, x.size))
        return ev[1]

    if differences and check is None:
        raise ValueError("differences=True needs `check`, the status test's Jacobian")
    kw = {"ftol": LM_FTOL, "xtol": 1e-15, "gtol": 1e-15}
    kw.update(options)
    # the budget counts residuals, not the p more of each differenced Jacobian
    maxfev = maxiter * (p + 1) if differences else maxiter
    with np.errstate(over="ignore"):  # an overflowing trial is a failed point (fun)
        x, ier, njev = minpack.lm(fun_differenced if differences else fun, eps0,
                                  None if differences else jac, maxfev=maxfev,
                                  **kw)  # fmt: skip
    nit = fd_njev if differences else njev
    msg = f"Levenberg-Marquardt (MINPACK): {minpack.minpack_message(ier, maxfev=maxfev, **kw)}"
    if failures:
        msg += f" ({len(failures)} model evaluations failed; first: {failures[0]})"
    counts["nfev"] += nfev
    key = x.tobytes()
    if key == best_key:  # MINPACK's point, the best one: evaluated
        last_key, last_ev = best_key, best_ev
    ev = evaluate(x, key)
    if ev is None:
        e = ConvergenceError(failures[-1])
        return Outcome(x, np.inf, None, None, msg, nit, counts["nfev"], np.array(hist_eps),
                       np.array(hist_loss), failures, e)  # fmt: skip
    r = ev[0]
    # verify_least_squares measures the optimality (the status is decided from it)
    out = Outcome(
        x,
        0.5 * float(r @ r),
        None,
        ev[2],
        msg,
        nit,
        counts["nfev"],
        None,
        None,
        failures,
        exhausted=ier == 5,
        claimed=ier in (1, 2, 3, 4),
    )  # fmt: skip

    def cached(e):
        ev = evaluate(np.array(e, dtype=float))
        if ev is None:
            raise ConvergenceError(failures[-1])
        if callable(ev[1]):
            counts["nfev"] += jacobian_cost
            ev[1] = ev[1]()
        return ev

    judge = cached if check is None else _counted(check, counts, (x, r, ev[2]))
    out = verify_least_squares(out, judge, None, out.exhausted, polish=polish, tol=tol,
                               step_tol=LM_STEP_TOL)  # fmt: skip
    out.grad = None if out.jacobian is None else out.jacobian.T @ out.residual
    out.nfev = counts["nfev"]
    if out.loss < best_loss:
        hist_eps.append(np.array(out.x))
        hist_loss.append(out.loss)
    out.eps_history, out.loss_history = np.array(hist_eps), np.array(hist_loss)
    return out
