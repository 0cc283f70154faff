"""The stochastic Galerkin system R(Theta; eps, lam) and its solvers (paper Eqs.
backward_euler, ecfm_solve, discrete_sens, discrete_sens_ecfm, pce, stochastic_sens)."""

from .galerkin import GalerkinSystem
from .solvers import (
    NewtonInfo,
    SteadySolution,
    Trajectory,
    march,
    newton,
    solve_continuation,
    solve_steady,
)
from .terms import Coefficient, DenseQuadraticForm, LinearTerm, LoadTerm, QuadraticTerm

__all__ = [
    "Coefficient",
    "DenseQuadraticForm",
    "GalerkinSystem",
    "LinearTerm",
    "LoadTerm",
    "NewtonInfo",
    "QuadraticTerm",
    "SteadySolution",
    "Trajectory",
    "march",
    "newton",
    "solve_continuation",
    "solve_steady",
]
