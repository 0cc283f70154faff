"""Composite Gauss-Legendre quadrature on the unit interval.

Used once, when operators are assembled; breakpoints let integrands with kinks or jumps
(hat functions, the beam's :math:`|x - 1/2|` stiffness, a piecewise source) be
integrated to round-off by putting every kink on a panel edge.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array, check_int


def composite_gauss(breakpoints=(), n_per_panel=64, a=0.0, b=1.0):
    """Nodes and weights of a composite Gauss-Legendre rule on ``[a, b]``.

    Parameters
    ----------
    breakpoints : sequence of float
        Interior points where the integrand may be non-smooth; points outside
        ``(a, b)`` are ignored.
    n_per_panel : int
        Gauss points on each panel.
    a, b : float
        Interval ends.

    Returns
    -------
    x : (n,) ndarray
    w : (n,) ndarray
        Weights summing to ``b - a``.
    """
    n = check_int("n_per_panel", n_per_panel, minimum=1)
    bp = as_finite_array("breakpoints", list(breakpoints)).ravel()
    edges = np.unique(np.concatenate([[a, b], bp[(bp > a) & (bp < b)]]))
    t, wt = np.polynomial.legendre.leggauss(n)
    lo, hi = edges[:-1, None], edges[1:, None]
    x = 0.5 * (hi - lo) * t + 0.5 * (hi + lo)
    w = 0.5 * (hi - lo) * wt
    return x.ravel(), w.ravel()


def default_points(*bases, extra=1):
    """A per-panel Gauss size that resolves products of the given sinusoid bases.

    ``extra`` counts further smooth factors (a weight, a third basis function).
    """
    kmax = sum(bz.max_wavenumber() for bz in bases)
    return int(np.ceil(kmax / np.pi)) * 2 + 24 * extra + 16
