"""Inverse problems as objects: a model, its sensors, the data, and how to solve the model.

A problem is what :func:`ecfm_uq.inverse.fit` fits (as a function is what
:func:`scipy.optimize.minimize` minimizes). Three kinds, by what the data are:

==========================  =======================================  ======================
problem                     data                                     paper
==========================  =======================================  ======================
:class:`SteadyProblem`      one data set ``v`` (C,) of a steady      Eqs. traditional,
                            model                                    ecfm, kpp_inv,
                                                                     ecfm_noise; Sec. 4
:class:`~ecfm_uq.inverse.   a time series ``V`` (n_steps + 1, C) of  Eqs. inv_obj, ecfm_obj
dynamic.Dynamic\\           a backward-Euler model
InverseProblem`
:class:`ReplicatedProblem`  replicates ``v`` (C, D) of a stochastic  Eq. stochastic_model
                            (chaos) model
==========================  =======================================  ======================

Each validates its data once, here, and holds the settings of the model's solves
(Newton ``solve_tol``/``solve_maxiter``, linear ``solver``, forward or adjoint ``gradient``): the
one place those are given. The optimizer's settings are arguments of ``fit``.
"""

from __future__ import annotations

import numpy as np

from ..._validation import as_finite_array, as_operator
from ...system import solve_steady
from ..core.gradients import choose_gradient
from ..statistics.loglik import LogLikelihood, gaussian_likelihood, no_likelihood
from .interface import InverseProblem
from .noise_model import noise_model
from .pseudo_likelihood import PseudoLikelihood

__all__ = ["ReplicatedProblem", "SteadyProblem"]


def _solve_options(tol, maxiter, solver):
    """The given Newton/linear-solver settings (omitted ones keep the solver's defaults)."""
    out = {"solver": solver}
    if tol is not None:
        out["tol"] = tol
    if maxiter is not None:
        out["maxiter"] = maxiter
    return out


class SteadyProblem(InverseProblem):
    """A steady model and one data set: :math:`v \\approx \\mathcal M\\,\\mathbb E[\\theta(\\epsilon)]`.

    Parameters
    ----------
    system : GalerkinSystem
        With ``Gamma`` (N, C) for the ECFM formulations.
    M_obs : (C, N) array_like or scipy.sparse matrix
        Measurement operator :math:`\\mathcal M`.
    v : (C,) array_like
        Observations.
    solve_tol, solve_maxiter : optional
        Newton settings of every model solve (the solver's defaults when omitted).
    solver : str, SolverOptions or dict
        Linear solver of every model solve (:func:`ecfm_uq.system.solve_steady`).
    gradient : {"auto", "forward", "adjoint"}
        Gradients by forward sensitivities or one adjoint solve
        (:func:`~ecfm_uq.inverse.core.gradients.choose_gradient`).

    Raises
    ------
    ValueError, TypeError
        On a misshaped or non-finite ``M_obs``/``v``.

    Notes
    -----
    The noise of ``v`` is an argument of :func:`~ecfm_uq.inverse.fit`: ``sigma`` one
    number, one standard deviation per sensor ``(C,)`` or a covariance ``(C, C)``
    (whitened once, :mod:`~ecfm_uq.inverse.problems.whitening`).
    """

    def __init__(self, system, M_obs, v, *, solve_tol=None, solve_maxiter=None, solver="auto",
                 gradient="auto"):  # fmt: skip
        self.system = system
        M_obs = as_operator("M_obs", M_obs)
        if M_obs.shape[1] != system.N:
            raise ValueError(f"`M_obs` must have {system.N} columns (N), got {M_obs.shape}")
        self.M_obs = M_obs
        self.v = as_finite_array("v", v, shape=(M_obs.shape[0],))
        self.gradient = choose_gradient(gradient, system.n_eps)
        self.solve_options = _solve_options(solve_tol, solve_maxiter, solver)

    @property
    def n_sensors(self):
        """Number of measurements C."""
        return self.v.size

    def log_likelihood(self, formulation, sigma):
        """The :class:`~ecfm_uq.inverse.statistics.loglik.LogLikelihood` of a fit of ``formulation`` (the standard
        one: Gaussian least squares of the sensors' residual), or why there is none."""
        if formulation != "standard":
            return no_likelihood(formulation)
        noise = noise_model(sigma, self.v.size)

        def residual(eps):
            r, J, sol = lazy_standard_residual(
                self.system, self.M_obs, self.v, eps, **self.solve_options
            )
            return noise.whiten(r), lambda: noise.whiten(J()), sol

        return gaussian_likelihood(
            residual, self.v.size, self.system.n_eps, noise, "steady least squares"
        )


class ReplicatedProblem(InverseProblem):
    """A stochastic (chaos) model and replicated data, for the pseudo-likelihood fits.

    Parameters
    ----------
    system : GalerkinSystem
        Stochastic (``P >= 2``); with ``Gamma`` (N, C) for the force formulations.
    M_obs : (C, N) array_like
    v : (C, D) array_like
        ``D >= 2`` replicates per sensor.
    solve_tol, solve_maxiter, solver : optional
        Settings of every model solve (see :class:`SteadyProblem`).
    var_rtol, hessian, fd_step
        Of the pseudo-likelihood
        (:class:`~ecfm_uq.inverse.problems.pseudo_likelihood.PseudoLikelihood`).
    """

    def __init__(self, system, M_obs, v, *, solve_tol=None, solve_maxiter=None, solver="auto",
                 var_rtol=1e-12, hessian="auto", fd_step=1e-5):  # fmt: skip

        opts = _solve_options(solve_tol, solve_maxiter, solver)
        if opts == {"solver": "auto"}:
            opts = {}  # the pseudo-likelihood's own default: no override at all
        self.likelihood = PseudoLikelihood(
            system, M_obs, v, var_rtol=var_rtol, hessian=hessian, fd_step=fd_step,
            solve_options=opts,
        )  # fmt: skip
        self.system = system
        self.M_obs = self.likelihood.M_obs
        self.v = self.likelihood.v

    @property
    def n_sensors(self):
        """Number of sensors C."""
        return self.v.shape[0]

    @property
    def n_replicates(self):
        """Replicates per sensor D."""
        return self.v.shape[1]

    def log_likelihood(self, formulation, sigma):
        """The pseudo-likelihood :math:`\\Lambda(\\epsilon, 0)` (Eq. Lam) for the standard
        formulation, or why the force formulations have none."""
        if formulation != "standard":
            return (
                f"formulation={formulation!r} of the pseudo-likelihood optimizes constraint "
                "forces, not the likelihood of eps; refit with formulation='standard' for "
                "likelihood intervals"
            )
        like = self.likelihood

        def evaluate(eps):
            p = like.evaluate(eps, None, order=1)
            return p.value, p.grad_eps

        return LogLikelihood(
            evaluate, self.system.n_eps, like.C * like.D, "replicated",
            "pseudo-likelihood of replicated data",
        )  # fmt: skip


def data_size(problem):
    """Number of scalar data a problem's estimate is fitted to (for degrees of freedom)."""
    return int(np.size(problem.v)) if hasattr(problem, "v") else int(np.size(problem.V[1:]))


def lazy_standard_residual(system, M_obs, v, eps, **solve_kw):
    """:func:`standard_residual` with the Jacobian as a callable: the sensitivity solves
    run only when it is called (a trial point an optimizer rejects needs none)."""
    sol = solve_steady(system, eps, strict=True, **solve_kw)

    def jacobian():
        dTheta, _ = sol.eps_sensitivity()
        return np.asarray(M_obs @ np.einsum("ikm,k->im", dTheta, system.E1))

    return M_obs @ system.mean(sol.Theta) - v, jacobian, sol
