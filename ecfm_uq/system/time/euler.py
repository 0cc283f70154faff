"""Backward Euler (paper Eq. backward_euler): the family's first-order method.

:math:`h_s = t_{s+1} - t_s` and :math:`\\psi_s = \\Theta_s`: first order, L-stable, the
default of ``march`` and the paper's method (every number of its studies).
"""

from __future__ import annotations

from .base import Stepper

__all__ = ["BackwardEuler"]


class BackwardEuler(Stepper):
    """Backward Euler on a fixed or given grid (``method="euler"``)."""

    name = "euler"
    order = 1

    def rule(self, s, dt):
        return dt, (1.0,)

    def grid_rule(self, s, steps):
        return float(steps[s]), (1.0,)
