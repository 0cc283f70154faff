"""The nonlinear solvers (compatibility module): see :mod:`.nonlinear`, :mod:`.steady`,
:mod:`.stepping`, :mod:`.trajectory` and :mod:`.compiled`."""

from .nonlinear import NewtonInfo, newton
from .steady import SteadySolution, solve_continuation, solve_steady
from .stepping import march
from .trajectory import Trajectory

__all__ = [
    "NewtonInfo",
    "SteadySolution",
    "Trajectory",
    "march",
    "newton",
    "solve_continuation",
    "solve_steady",
]
