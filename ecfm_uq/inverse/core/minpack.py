"""MINPACK's Levenberg-Marquardt (lmdif, lmder) as scipy compiles it, called directly.

:func:`scipy.optimize.leastsq` wraps the compiled routines with a shape check that
evaluates the function once more, a message table built on every call and, with
``full_output``, a covariance from MINPACK's factors; :func:`lm` calls the same compiled
routines (``scipy.optimize._minpack._lmdif`` / ``_lmder``, their arguments as
``leastsq`` passes them) and keeps only what the driver reads: the point, MINPACK's
``info`` and its message, the Jacobians evaluated. Those routines are scipy's private
names: their call is checked once on a small problem against ``leastsq`` and, should a
scipy release change them, every call goes through ``leastsq`` instead (same numbers,
its overhead back).
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.optimize as sopt

try:  # scipy's compiled MINPACK, leastsq's own callees (private: checked before use)
    from scipy.optimize import _minpack
except ImportError:  # pragma: no cover - a scipy without the module: leastsq only
    _minpack = None

__all__ = ["lm", "minpack_message"]

#: machine epsilon: leastsq's default ``epsfcn`` (lmdif's relative step is its root)
_EPS = float(np.finfo(float).eps)


@functools.lru_cache(maxsize=64)
def minpack_message(info, ftol, xtol, gtol, maxfev):
    """MINPACK's sentence for its return code ``info`` (the text ``leastsq`` reports;
    remembered: a fit's settings repeat, and the formatting is a few microseconds)."""
    if info == 1:
        return f"Both actual and predicted relative reductions in the sum of squares\n  are at most {ftol:f}"
    if info == 2:
        return f"The relative error between two consecutive iterates is at most {xtol:f}"
    if info == 3:
        return (
            "Both actual and predicted relative reductions in the sum of squares\n  are at "
            f"most {ftol:f} and the relative error between two consecutive iterates is at "
            f"\n  most {xtol:f}"
        )
    if info == 4:
        return (
            "The cosine of the angle between func(x) and any column of the\n  Jacobian is at "
            f"most {gtol:f} in absolute value"
        )
    if info == 5:
        return f"Number of calls to function has reached maxfev = {maxfev}."
    if info == 6:
        return (
            f"ftol={ftol:f} is too small, no further reduction in the sum of squares\n  is "
            "possible."
        )
    if info == 7:
        return (
            f"xtol={xtol:f} is too small, no further improvement in the approximate\n  "
            "solution is possible."
        )
    if info == 8:
        return (
            f"gtol={gtol:f} is too small, func(x) is orthogonal to the columns of\n  the "
            "Jacobian to machine precision."
        )
    return "Improper input parameters."


def _via_leastsq(fun, x0, jac, ftol, xtol, gtol, maxfev):
    out = sopt.leastsq(fun, x0, Dfun=jac, full_output=True, ftol=ftol, xtol=xtol, gtol=gtol,
                       maxfev=maxfev)  # fmt: skip
    return np.asarray(out[0], dtype=float), int(out[-1]), out[2].get("njev")


def _direct(fun, x0, jac, ftol, xtol, gtol, maxfev):
    if jac is None:
        x, info = _minpack._lmdif(fun, x0, (), 0, ftol, xtol, gtol, maxfev, _EPS, 100.0, None)
        return np.asarray(x, dtype=float), int(info), None
    x, out, info = _minpack._lmder(fun, jac, x0, (), 1, 0, ftol, xtol, gtol, maxfev, 100.0,
                                   None)  # fmt: skip
    return np.asarray(x, dtype=float), int(info), out["njev"]


def _direct_works():
    """Whether the compiled routines take ``leastsq``'s arguments and give its answer (a
    straight line through three points, with and without the Jacobian)."""
    if _minpack is None:
        return False
    t = np.array([0.0, 1.0, 2.0])
    v = np.array([1.0, 3.0, 4.0])

    def f(e):
        return e[0] + e[1] * t - v

    def J(e):
        return np.column_stack([np.ones(3), t])

    try:
        for jac in (None, J):
            got = _direct(f, np.zeros(2), jac, 1e-12, 1e-12, 0.0, 400)
            want = _via_leastsq(f, np.zeros(2), jac, 1e-12, 1e-12, 0.0, 400)
            if got[1:] != want[1:] or got[0].tobytes() != want[0].tobytes():
                return False
    except Exception:  # a changed signature or return: leastsq it is
        return False
    return True


#: the routine that runs (decided at the first fit: the compiled one, if it checks out)
_run = [None]


def lm(fun, x0, jac=None, *, ftol, xtol, gtol, maxfev):
    """Levenberg-Marquardt from ``x0``: lmdif (``jac=None``: MINPACK differences ``fun``,
    one-sided, step :math:`\\sqrt{\\varepsilon}|x_j|`) or lmder (``jac(x)``, the
    ``(m, n)`` Jacobian), with ``leastsq``'s other defaults (``factor = 100``, MINPACK's
    own scaling, ``epsfcn`` the machine epsilon).

    Parameters
    ----------
    fun : callable
        ``x (n,) -> (m,)`` float array, ``m >= n`` (``n == x0.size``).
    x0 : (n,) float ndarray
    jac : callable, optional
    ftol, xtol, gtol : float
        MINPACK's stopping tolerances.
    maxfev : int
        Calls of ``fun`` allowed.

    Returns
    -------
    x : (n,) ndarray
        MINPACK's final point.
    info : int
        MINPACK's return code (1-4: its tests met, 5: ``maxfev`` reached, 6-8: a
        tolerance below round-off; :func:`minpack_message` says it in words).
    njev : int or None
        The Jacobians ``jac`` evaluated (``None`` for lmdif).
    """
    run = _run[0]
    if run is None:
        run = _run[0] = _direct if _direct_works() else _via_leastsq
    # a copy: the compiled routines write their iterates into the array they are given
    return run(fun, np.array(x0, dtype=float).ravel(), jac, ftol, xtol, gtol, maxfev)
