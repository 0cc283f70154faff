"""The stochastic Galerkin system R(Theta; eps, lam) and its solvers (paper Eqs.
backward_euler, ecfm_solve, discrete_sens, discrete_sens_ecfm, pce, stochastic_sens).

Transients (the time family, :mod:`.time`): ``march`` (fixed steps or a given grid
``times=``, ``method="euler"`` or ``"bdf2"``, sensitivities and the exact discrete
adjoint), ``choose_steps`` (a grid through the data times meeting rtol/atol, to be frozen
for a calibration) and ``integrate`` (variable-order BDF with error control and forward
sensitivities); ``METHODS`` is the table of methods.

Layers, each importing only the ones below it: :mod:`.model` (terms, the system, its
operators, trajectories, status codes), :mod:`.solve` (the solve plan, linear and Newton
solvers, compiled marches), :mod:`.time` (the time family) and this package (steady solves
in :mod:`.steady`, the public names, the former module paths ``plan``, ``linear``,
``trajectory``, ``galerkin``, ``schemes``, ``step_control``, ``stepping``, ``adaptive``)."""

from .model.galerkin import GalerkinSystem
from .model.nonlinear_term import NonlinearTerm
from .model.operator import AugmentedOperator, GalerkinOperator
from .model.terms import Coefficient, DenseQuadraticForm, LinearTerm, LoadTerm, QuadraticTerm
from .model.trajectory import Trajectory
from .solve.linear import LinearSolver
from .solve.nonlinear import NewtonInfo, newton
from .solve.options import SOLVERS, SolverOptions, solver_options
from .steady import SteadySolution, solve_continuation, solve_steady
from .time import FIXED as SCHEMES
from .time import METHODS, StepSequence, choose_steps, integrate, march

__all__ = [
    "METHODS",
    "SCHEMES",
    "SOLVERS",
    "AugmentedOperator",
    "Coefficient",
    "DenseQuadraticForm",
    "GalerkinOperator",
    "GalerkinSystem",
    "LinearSolver",
    "LinearTerm",
    "LoadTerm",
    "NewtonInfo",
    "NonlinearTerm",
    "QuadraticTerm",
    "SolverOptions",
    "SteadySolution",
    "StepSequence",
    "Trajectory",
    "choose_steps",
    "integrate",
    "march",
    "newton",
    "solve_continuation",
    "solve_steady",
    "solver_options",
]
