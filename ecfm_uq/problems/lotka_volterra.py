"""Lotka-Volterra predator-prey equations as an ODE right-hand side with its derivatives.

.. math::

    \\dot u = a u - b u v,\\qquad \\dot v = c u v - d v,

with parameters :math:`\\epsilon = (a, b, c, d, u_0, v_0)`: the four rates and the initial
state, in :func:`scipy.integrate.solve_ivp`'s signature with the parameters third (what
:class:`~ecfm_uq.inverse.OdeProblem` takes). The lynx-hare pelts it is usually fitted to
are :func:`ecfm_uq.datasets.lynx_hare`. This module only writes the model down; fitting is
:func:`ecfm_uq.inverse.fit`'s job.
"""

from __future__ import annotations

import numpy as np

__all__ = ["initial_state", "jac_eps", "jac_y", "rhs"]


def rhs(t, y, e):
    """:math:`(\\dot u, \\dot v)`; ``y`` may hold columns of states (vectorized)."""
    u, v = y[0], y[1]
    return np.array([e[0] * u - e[1] * u * v, e[2] * u * v - e[3] * v])


def jac_y(t, y, e):
    """:math:`\\partial(\\dot u, \\dot v)/\\partial(u, v)`, (2, 2)."""
    u, v = y
    return np.array([[e[0] - e[1] * v, -e[1] * u], [e[2] * v, e[2] * u - e[3]]])


def jac_eps(t, y, e):
    """:math:`\\partial(\\dot u, \\dot v)/\\partial\\epsilon`, (2, 6): the initial state
    does not enter the right-hand side."""
    u, v = y
    z = np.zeros_like(u)
    return np.array([[u, -u * v, z, z, z, z], [z, z, u * v, -v, z, z]])


def initial_state(e):
    """:math:`(u_0, v_0) = (\\epsilon_4, \\epsilon_5)`."""
    return e[4:6]
