"""Inverse formulations: standard least squares, ECFM (equality constraint forces),
noisy ECFM (z-score and chi-squared bounds), pseudo-likelihood constraint forces.

One entry point, :func:`fit`, takes a problem (the model and the data) and returns an
:class:`InverseResult` (``success``/``status``, the estimate, its :class:`Uncertainty` and
the :class:`Verdict` on whether the model explains the data):

==========================  =====================================================  ================
problem                     formulations (``fit(problem, eps0, formulation=...)``)  paper
==========================  =====================================================  ================
:class:`ModelProblem`       ``"standard"`` (a model that is a Python function)     --
:class:`SteadyProblem`      ``"standard"``, ``"ecfm"``, ``"noisy-ecfm"``            Eqs. traditional,
                                                                                   ecfm, kpp_inv,
                                                                                   ecfm_noise; Sec. 4
:class:`DynamicInverse\\    ``"standard"``, ``"ecfm"``                              Eqs. inv_obj,
Problem`                                                                           ecfm_obj
:class:`ReplicatedProblem`  ``"standard"``, ``"inner-outer"``, ``"penalty"``        Eq. stochastic_model
==========================  =====================================================  ================

``SteadyProblem`` also takes ``"ecfm-random"`` (the random-force ECFM, with ``sigma``).
From a result: :func:`profile_likelihood` / :func:`profile_intervals` (profile-likelihood
intervals and regions), :func:`likelihood_ratio_test`, ``result.summary()``.

A map of the modules, read from the top: each group imports only from its own group and
the groups below it (one exception: :mod:`.dynamic_fit` imports the problem it fits,
:mod:`.dynamic`), and nothing but :mod:`.coverage` imports :mod:`.fitting`:

=====================  ===================================================================
the entry              :mod:`.fitting` (``fit``: validate, whiten, dispatch);
                       :mod:`.coverage` (fits over synthetic data sets)
the problems           :mod:`.interface` (what every problem offers), :mod:`.model_problem`,
                       :mod:`.problems` (steady, replicated), :mod:`.dynamic`;
                       :mod:`.noise_model` and :mod:`.whitening` (``sigma`` as given)
the formulations       :mod:`.steady` (standard and exact ECFM, reduced), :mod:`.noisy` and
                       :mod:`.noise` (all-at-once, the paper's noise bounds),
                       :mod:`.discrepancy` and :mod:`.sparse_forces` (random-force ECFM),
                       :mod:`.dynamic_fit`, :mod:`.replicated` with :mod:`.forces`,
                       :mod:`.pseudo_likelihood` and :mod:`.moments` (pseudo-likelihood),
                       :mod:`.loglik` (each formulation's likelihood)
the statistics         :mod:`.uncertainty`, :mod:`.verdict`, :mod:`.profile` and
                       :mod:`.profiler`, :mod:`.posterior`, :mod:`.diagnostics`
shared                 :mod:`.convergence` (the one status decision), :mod:`.drivers` and
                       :mod:`.optimizers` (the optimizer calls), :mod:`.gradients`,
                       :mod:`.finite_differences`; the types handed around:
                       :mod:`.settings` (the validated arguments), :mod:`.result` (the one
                       frozen result), :mod:`.status`, :mod:`.summary_table`
=====================  ===================================================================
"""

from .coverage import likelihood_coverage, steady_coverage
from .diagnostics import (
    condition_number,
    expected_relative_error,
    fd_hessian,
    loss_surface,
    taylor_remainders,
)
from .dynamic import DynamicInverseProblem
from .fitting import fit
from .forces import optimal_forces
from .loglik import LogLikelihood
from .model_problem import ModelProblem
from .moments import DegenerateVarianceError, negative_log_pseudo_likelihood, sensor_moments
from .noise import ConsistencyTest, consistency_test, noise_bounds, sample_moments
from .noisy import ConstrainedInverse
from .optimizers import adam
from .problems import ReplicatedProblem, SteadyProblem
from .profile import likelihood_ratio_test, profile_intervals, profile_likelihood
from .pseudo_likelihood import PseudoLikelihood
from .result import InverseResult, Uncertainty, Verdict
from .status import FitStatus
from .steady import ecfm_objective, standard_objective

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
