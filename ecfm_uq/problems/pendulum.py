"""A damped pendulum with a random stiffness, through :class:`~ecfm_uq.system.NonlinearTerm`.

The state :math:`u = (\\varphi, \\omega)` (angle, angular velocity) obeys

.. math::

    \\dot\\varphi = \\omega, \\qquad
    \\dot\\omega = -c\\,\\omega - \\epsilon_0\\,\\bigl(1 + s\\,(\\xi - \\tfrac12)\\bigr)\\sin\\varphi,

with :math:`\\epsilon_0 = g/L`, the damping :math:`c` and a uniform germ :math:`\\xi \\sim
U(0, 1)` spreading the stiffness by :math:`\\pm s/2`. Written as :math:`M\\dot u + r(u) = 0`
with :math:`M = I`, :math:`r(u) = (-\\omega,\\; c\\,\\omega + a(\\xi)\\sin\\varphi)`: a
non-polynomial nonlinearity, so the Galerkin residual is integrated by the term's Gauss rule
(``degree`` sets its points). A small model of the time-integration tests and benchmarks
(not one of the paper's).
"""

from __future__ import annotations

import numpy as np

from ..chaos import ChaosBasis
from ..system import GalerkinSystem, NonlinearTerm

__all__ = ["build_pendulum"]


def build_pendulum(order=3, damping=0.3, spread=0.3, degree=11):
    """The Galerkin system of the random-stiffness pendulum and its initial state.

    Parameters
    ----------
    order : int
        Chaos order of the one-germ Legendre basis (``0``: deterministic, :math:`\\xi = 1/2`).
    damping : float
        :math:`c`.
    spread : float
        :math:`s`, the relative spread of the stiffness (``< 2`` keeps it positive).
    degree : int
        Degree of the Gauss rule of the nonlinear term (``sin`` is not polynomial).

    Returns
    -------
    system : GalerkinSystem
        ``N = 2``, ``n_eps = 1`` (:math:`\\epsilon_0 = g/L`), ``M = I``.
    Theta0 : (2, P) ndarray
        :math:`\\varphi(0) = 1`, :math:`\\omega(0) = 0` (deterministic).
    """

    def stiffness(omega):
        return 1.0 + spread * (omega[0] - 0.5) if len(omega) else 1.0

    def residual(u, omega, eps):
        a = eps[0] * stiffness(omega)
        return np.array([-u[1], damping * u[1] + a * np.sin(u[0])])

    def jacobian(u, omega, eps):
        a = eps[0] * stiffness(omega)
        return np.array([[0.0, -1.0], [a * np.cos(u[0]), damping]])

    def eps_jacobian(u, omega, eps):
        return np.array([[0.0], [stiffness(omega) * np.sin(u[0])]])

    term = NonlinearTerm(
        residual, jacobian, eps_jacobian=eps_jacobian, degree=degree, size=2, name="pendulum"
    )
    basis = ChaosBasis(order, 1) if order > 0 else None
    system = GalerkinSystem([term], 1, basis=basis, M=np.eye(2), name="pendulum")
    Theta0 = np.zeros(system.shape)
    Theta0[0, 0] = 1.0
    return system, Theta0
