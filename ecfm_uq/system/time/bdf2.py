"""The two-step backward differentiation formula, fixed or variable steps.

On a fixed grid (Hairer & Wanner II, Sec. III.1 and V.1)

.. math::

    \\frac{M}{\\Delta t}\\Bigl(\\tfrac32\\Theta_{s+1} - 2\\Theta_s
        + \\tfrac12\\Theta_{s-1}\\Bigr) + R(\\Theta_{s+1}) = 0,

i.e. :math:`h_s = \\tfrac23\\Delta t`, :math:`\\psi_s = \\tfrac43\\Theta_s -
\\tfrac13\\Theta_{s-1}`: second order, A- and L-stable (stiffly accurate: the data
constraint of the ECFM holds exactly at every grid time). It starts with one
backward-Euler step, whose local error :math:`O(\\Delta t^2)` keeps the global error second
order.

On a given grid, the variable-step BDF2 (Hairer & Wanner II, Sec. III.5; :math:`p'(t_{s+1})
= f` for the quadratic :math:`p` through the last three states), with :math:`\\omega_s =
h_s/h_{s-1}`,

.. math::

    \\frac{1 + 2\\omega_s}{1 + \\omega_s}\\Theta_{s+1} - (1 + \\omega_s)\\Theta_s
        + \\frac{\\omega_s^2}{1 + \\omega_s}\\Theta_{s-1}
        = -h_s M^{-1}R(\\Theta_{s+1}),

i.e. an effective length :math:`h_s(1 + \\omega_s)/(1 + 2\\omega_s)` and
:math:`\\psi_s = ((1 + \\omega_s)^2\\Theta_s - \\omega_s^2\\Theta_{s-1})/(1 + 2\\omega_s)`.
It is zero-stable for step ratios :math:`\\omega_s < 1 + \\sqrt 2` (Grigorieff 1983); the
grids of :mod:`.grids` keep :math:`\\omega_s \\le 2`.
"""

from __future__ import annotations

from .base import Stepper

__all__ = ["BDF2"]


class BDF2(Stepper):
    """BDF2 on a fixed or given grid (``method="bdf2"``), started by backward Euler."""

    name = "bdf2"
    order = 2

    def rule(self, s, dt):
        if s == 0:
            return dt, (1.0,)
        return 2.0 * dt / 3.0, (4.0 / 3.0, -1.0 / 3.0)

    def grid_rule(self, s, steps):
        hs = steps[s]
        if s == 0:
            return float(hs), (1.0,)
        om = hs / steps[s - 1]
        return (
            float(hs * (1.0 + om) / (1.0 + 2.0 * om)),
            ((1.0 + om) ** 2 / (1.0 + 2.0 * om), -(om**2) / (1.0 + 2.0 * om)),
        )
