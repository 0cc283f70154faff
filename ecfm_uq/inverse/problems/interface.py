"""The one interface every inverse problem offers the pipeline of :func:`~ecfm_uq.inverse.fitting.fit`.

:class:`~ecfm_uq.inverse.problems.model.ModelProblem`,
:class:`~ecfm_uq.inverse.problems.galerkin.SteadyProblem`,
:class:`~ecfm_uq.inverse.problems.galerkin.ReplicatedProblem` and
:class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem` derive from
:class:`InverseProblem`: their data (``data``, ``n_data``), a copy with other data
(:meth:`~InverseProblem.with_data`: refits, simulations, coverage studies) and the
likelihood of a formulation (``log_likelihood(formulation, sigma)``: a
:class:`~ecfm_uq.inverse.statistics.loglik.LogLikelihood` or why there is none). How each
problem computes residuals and Jacobians stays with it.

What each problem kind offers its fitters (the :class:`~ecfm_uq.inverse.core.fitter.Fitter`
rows of :data:`ecfm_uq.inverse.fitting.FITTERS`; public attributes and methods only, no
fitter reads a private one):

=====================  =====================================================================
problem                used by its fitters
=====================  =====================================================================
every kind             ``data``, ``n_data``, ``with_data``, ``forget_solves``,
                       ``log_likelihood(formulation, sigma)``
ModelProblem           ``v``, ``shape``, ``names``, ``jac``, ``executor``, ``formulations``,
                       ``predict``, ``jacobian``, ``residual_function(noise)``,
                       ``check_derivatives``
OdeProblem             ``check``, ``t``, ``v``, ``H``, ``mask``, ``n_state``, ``state_names``,
                       ``names``, ``n_missing``, ``readings``, ``readings_model``,
                       ``noise(sigma)``, ``solve``, ``trajectory``, ``predict``,
                       ``predict_jacobian``, ``observe``, ``forced``
SteadyProblem          ``system``, ``M_obs``, ``v``, ``n_sensors``, ``solve_options``,
                       ``gradient``
DynamicInverseProblem  ``system``, ``V``, ``n_steps``, ``n_sensors``, ``residual``,
                       ``objective``, ``solve``, ``predictions``, ``uncertainty``,
                       ``adaptive``, ``steps``, ``freeze_steps``, ``check_steps``,
                       ``warm_starts_kept()`` (a check that leaves the warm starts alone)
ReplicatedProblem      ``system``, ``likelihood`` (a
                       :class:`~ecfm_uq.inverse.problems.pseudo_likelihood.PseudoLikelihood`:
                       ``solve``, ``forces``, ...)
=====================  =====================================================================
"""

from __future__ import annotations

import copy

import numpy as np

from ..._validation import as_finite_array

__all__ = ["InverseProblem"]


class InverseProblem:
    """Base of the problem classes: the data and a copy with other data.

    Subclasses name the attribute that holds the data (``data_attribute``, ``"v"`` by
    default) and implement ``log_likelihood(formulation, sigma)``.
    """

    #: the attribute holding the data, also its name in error messages
    data_attribute = "v"

    @property
    def data(self):
        """The observations, as stored (their shape is the problem's)."""
        return getattr(self, self.data_attribute)

    @property
    def n_data(self):
        """Number of observations."""
        return int(np.size(self.data))

    def with_data(self, data):
        """The same problem with other data of the same shape (for refits, simulations).

        Raises
        ------
        ValueError, TypeError
            Data of another size, or not finite.
        """
        old = self.data
        value = np.asarray(data, dtype=float)
        if value.size == old.size:
            value = value.reshape(old.shape)
        new = copy.copy(self)
        setattr(new, self.data_attribute, as_finite_array(self.data_attribute, value,
                                                          shape=old.shape))  # fmt: skip
        new.forget_solves()
        return new

    def forget_solves(self):
        """Drop what is cached from solves with the previous data (none by default)."""

    def log_likelihood(self, formulation, sigma):
        """The likelihood of a fit of ``formulation``, or why there is none."""
        raise NotImplementedError
