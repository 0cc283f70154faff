"""A 1-D reaction-diffusion rod with its reaction rate inside the operator.

.. math::

    -w'' + 10^{\\epsilon_0} w = \\epsilon_1 \\quad\\text{on } (0, 1), \\qquad w(0) = w(1) = 0,

observed at a few point sensors, with hat-shaped constraint forces at the sensors (paper
Eq. ecfm). The reading is nonlinear in :math:`\\epsilon_0` (a parameter in the operator)
and linear in :math:`\\epsilon_1` (the source): with few sensors the likelihood is curved
(a banana) and the delta-method intervals are not to be trusted, which makes it the test
model of the profile-likelihood intervals and of the random-force ECFM
(``ecfm-uq reproduce coverage``). :meth:`ReactionRod.data` can add a narrow source the
model does not have, the "missing physics" the discrepancy test must find.

This module only builds systems and data; fitting is :func:`ecfm_uq.inverse.fit`'s job.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array, check_int, check_positive
from ..spectral import SineBasis, hat_forces, load, mass, sensor_matrix, stiffness
from ..system import Coefficient, GalerkinSystem, LinearTerm, LoadTerm, solve_steady

__all__ = ["ReactionRod"]


class ReactionRod:
    """The rod, its sensors and its constraint forces.

    Parameters
    ----------
    sensors : int or (C,) array_like
        Number of equally spaced sensors in [0.15, 0.85], or their positions in (0, 1).
    n_basis : int
        Sine modes of the Galerkin discretization.
    force_width : float
        Half-width of the hat-shaped constraint forces.
    """

    def __init__(self, sensors=4, n_basis=16, force_width=0.05):
        n_basis = check_int("n_basis", n_basis, minimum=2)
        if np.ndim(sensors) == 0:
            sensors = np.linspace(0.15, 0.85, check_int("sensors", sensors, minimum=2))
        self.sensors = as_finite_array("sensors", sensors, ndim=1)
        if np.any((self.sensors <= 0) | (self.sensors >= 1)):
            raise ValueError("`sensors` must lie strictly inside (0, 1)")
        self.basis = SineBasis(n_basis)
        self.force_width = check_positive("force_width", force_width)
        self.M_obs = sensor_matrix(self.basis, self.sensors)
        self.system = GalerkinSystem(
            self._terms(), 2, Gamma=hat_forces(self.basis, self.sensors, self.force_width),
            name="reaction rod",
        )  # fmt: skip

    def _terms(self):
        B = self.basis
        return [
            LinearTerm(stiffness(B)),
            LinearTerm(mass(B), Coefficient.power10(0, sign=1.0)),
            LoadTerm.scaled(-load(B, np.ones_like), Coefficient.parameter(1)),
        ]

    def data(self, eps, source=0.0, at=0.62, width=0.02):
        """Noise-free readings at ``eps``, plus a Gaussian source of amplitude ``source``
        centred at ``at`` that the model does not have."""
        if source == 0.0:
            return self.M_obs @ solve_steady(self.system, eps, strict=True).Theta[:, 0]
        bump = load(self.basis, lambda x: np.exp(-0.5 * ((x - at) / width) ** 2))
        truth = GalerkinSystem(
            [*self._terms(), LoadTerm.scaled(-bump, Coefficient.parameter(2))], 3,
            name="reaction rod with the missing source",
        )  # fmt: skip
        return self.M_obs @ solve_steady(truth, [*eps, source], strict=True).Theta[:, 0]
