"""Inverse formulations: standard least squares, ECFM (equality constraint forces),
noisy ECFM (z-score and chi-squared bounds), pseudo-likelihood constraint forces.

One entry point, :func:`fit`, takes a problem (the model, its sensors and the data) and
returns an :class:`InverseResult` (``success``/``status``, the estimate, its
:class:`Uncertainty` and the :class:`Verdict` on whether the model explains the data):

==========================  =====================================================  ================
problem                     formulations (``fit(problem, eps0, formulation=...)``)  paper
==========================  =====================================================  ================
:class:`SteadyProblem`      ``"standard"``, ``"ecfm"``, ``"noisy-ecfm"``            Eqs. traditional,
                                                                                   ecfm, kpp_inv,
                                                                                   ecfm_noise; Sec. 4
:class:`DynamicInverse\\    ``"standard"``, ``"ecfm"``                              Eqs. inv_obj,
Problem`                                                                           ecfm_obj
:class:`ReplicatedProblem`  ``"standard"``, ``"inner-outer"``, ``"penalty"``        Eq. stochastic_model
==========================  =====================================================  ================

The v0.2 entry points (:func:`fit_steady`, :func:`fit_standard_slsqp`,
:func:`fit_noisy_ecfm`, :func:`fit_pseudo_likelihood`, ``DynamicInverseProblem.fit``) are
thin deprecated aliases of :func:`fit`.
"""

from .coverage import likelihood_coverage, steady_coverage
from .diagnostics import condition_number, fd_hessian, loss_surface, taylor_remainders
from .dynamic import DynamicInverseProblem
from .fitting import fit
from .likelihood import (
    DegenerateVarianceError,
    PseudoLikelihood,
    expected_relative_error,
    fit_pseudo_likelihood,
    negative_log_pseudo_likelihood,
    optimal_forces,
    sensor_moments,
)
from .loglik import LogLikelihood
from .model_problem import ModelProblem
from .noise import ConsistencyTest, consistency_test, noise_bounds, sample_moments
from .noisy import ConstrainedInverse, fit_noisy_ecfm, fit_standard_slsqp
from .optimizers import adam
from .problems import ReplicatedProblem, SteadyProblem
from .profile import likelihood_ratio_test, profile_intervals, profile_likelihood
from .result import InverseResult, Uncertainty, Verdict
from .status import FitStatus
from .steady import ecfm_objective, fit_steady, standard_objective

__all__ = [
    "FitStatus",
    "ModelProblem",
    "ReplicatedProblem",
    "SteadyProblem",
    "Uncertainty",
    "Verdict",
    "fit",
    "LogLikelihood",
    "likelihood_ratio_test",
    "profile_intervals",
    "profile_likelihood",
    "ConsistencyTest",
    "ConstrainedInverse",
    "DegenerateVarianceError",
    "DynamicInverseProblem",
    "InverseResult",
    "PseudoLikelihood",
    "adam",
    "condition_number",
    "consistency_test",
    "ecfm_objective",
    "expected_relative_error",
    "fd_hessian",
    "fit_noisy_ecfm",
    "fit_pseudo_likelihood",
    "fit_standard_slsqp",
    "fit_steady",
    "loss_surface",
    "negative_log_pseudo_likelihood",
    "noise_bounds",
    "optimal_forces",
    "likelihood_coverage",
    "sample_moments",
    "sensor_moments",
    "standard_objective",
    "steady_coverage",
    "taylor_remainders",
]
