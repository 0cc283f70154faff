"""Closed-form solutions of the heat problems' continuous BVPs (data without
discretization error), for :mod:`ecfm_uq.problems.heat` and its studies."""

from __future__ import annotations

from .._validation import as_finite_array, check_positive

__all__ = ["boundary_closed_form", "interval_closed_form"]


def boundary_closed_form(x, eps, s=1.0):
    """Exact solution of :math:`w'' + s = 0`, :math:`w(0) = \\epsilon_1`,
    :math:`w'(1) = \\epsilon_2` for a constant source :math:`s`:

    .. math:: w(x) = \\epsilon_1 + \\epsilon_2 x + s\\,(x - x^2/2).

    Parameters
    ----------
    x : (m,) array_like
    eps : (2,) array_like
    s : float

    Returns
    -------
    (m,) ndarray
    """
    x = as_finite_array("x", x, ndim=1)
    e = as_finite_array("eps", eps, shape=(2,))
    s = float(as_finite_array("s", s, ndim=0))
    return e[0] + e[1] * x + s * (x - 0.5 * x**2)


def interval_closed_form(x, L):
    """Exact solution of :math:`w'' + 1 + x = 0` on :math:`[0, L]`, :math:`w(0) = w(L) = 0`
    (the default source of :func:`interval_problem`):

    .. math:: w(x) = -\\frac{x^2}{2} - \\frac{x^3}{6} + \\Big(\\frac{L}{2} + \\frac{L^2}{6}\\Big) x .

    Parameters
    ----------
    x : (m,) array_like
        Physical coordinates in :math:`[0, L]`.
    L : float

    Returns
    -------
    (m,) ndarray
    """
    x = as_finite_array("x", x, ndim=1)
    L = check_positive("L", L)
    return -0.5 * x**2 - x**3 / 6.0 + (L / 2 + L**2 / 6) * x
