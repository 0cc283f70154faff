"""Inverse formulations: standard least squares, ECFM (equality constraint forces),
noisy ECFM (z-score and chi-squared bounds), pseudo-likelihood constraint forces."""

from .result import InverseResult
from .steady import ecfm_objective, fit_steady, standard_objective

__all__ = ["InverseResult", "ecfm_objective", "fit_steady", "standard_objective"]
