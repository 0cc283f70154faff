"""The v0.2 module of the pseudo-likelihood (paper Section 3.3), kept for its imports.

Its parts now live in modules of one job each: :mod:`.moments` (sensor moments and the
pseudo-likelihood of given moments), :mod:`.pseudo_likelihood` (:math:`\\Lambda(\\epsilon,
\\lambda)` through the system), :mod:`.forces` (the inner force solve), :mod:`.replicated`
(the three estimators, their uncertainty and verdict) and :mod:`.diagnostics` (the
expected relative error).
"""

from .diagnostics import expected_relative_error
from .forces import ForceSolution, eps_curvature, optimal_forces
from .moments import DegenerateVarianceError, negative_log_pseudo_likelihood, sensor_moments
from .pseudo_likelihood import LikelihoodPoint, PseudoLikelihood
from .replicated import (
    FORMULATIONS,
    fit_pseudo_likelihood,
    moment_verdict,
    replicate_statistics,
)

__all__ = [
    "FORMULATIONS",
    "DegenerateVarianceError",
    "ForceSolution",
    "LikelihoodPoint",
    "PseudoLikelihood",
    "eps_curvature",
    "expected_relative_error",
    "fit_pseudo_likelihood",
    "moment_verdict",
    "negative_log_pseudo_likelihood",
    "optimal_forces",
    "replicate_statistics",
    "sensor_moments",
]
