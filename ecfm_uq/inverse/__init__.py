"""Inverse formulations: standard least squares, ECFM (equality constraint forces),
noisy ECFM (z-score and chi-squared bounds), pseudo-likelihood constraint forces.

==========================  ==============================================  ===========
formulation                 entry point                                     paper
==========================  ==============================================  ===========
steady standard / ECFM      :func:`fit_steady`                              Eqs. traditional, ecfm; Sec. 4
dynamic standard / ECFM     :class:`DynamicInverseProblem`                  Eqs. inv_obj, ecfm_obj
noisy standard / ECFM       :func:`fit_standard_slsqp`, :func:`fit_noisy_ecfm`  Eqs. kpp_inv, ecfm_noise
pseudo-likelihood forces    :func:`fit_pseudo_likelihood`                   Eq. stochastic_model
==========================  ==============================================  ===========
"""

from .coverage import likelihood_coverage, steady_coverage
from .diagnostics import condition_number, fd_hessian, loss_surface, taylor_remainders
from .dynamic import DynamicInverseProblem
from .likelihood import (
    DegenerateVarianceError,
    PseudoLikelihood,
    expected_relative_error,
    fit_pseudo_likelihood,
    negative_log_pseudo_likelihood,
    optimal_forces,
    sensor_moments,
)
from .noise import ConsistencyTest, consistency_test, noise_bounds, sample_moments
from .noisy import ConstrainedInverse, fit_noisy_ecfm, fit_standard_slsqp
from .optimizers import adam
from .result import InverseResult
from .steady import ecfm_objective, fit_steady, standard_objective

__all__ = [
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
