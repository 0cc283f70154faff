"""Time integration as one family (the shape of ``scipy.integrate.solve_ivp``'s table of
``OdeSolver`` classes, one file per method).

Every method is a :class:`~.base.Stepper` in the table :data:`~.methods.METHODS`
(``{name: Stepper}``): backward Euler (:mod:`.euler`), BDF2 (:mod:`.bdf2`) and the
variable-order BDF (:mod:`.bdf`). One vocabulary serves the entry points: ``method=``
names the method, and the grid is fixed (``dt``, ``n_steps``), given (``times``) or chosen
to a tolerance (:func:`~.grids.choose_steps` for a frozen calibration grid,
``integrate(..., rtol=)`` as it goes).

* :func:`~.marching.march` — a fixed or given grid, the ECFM data constraint, forward
  sensitivities and the exact discrete adjoint;
* :func:`~.integration.integrate` — steps chosen to a tolerance, dense output at
  ``t_eval``, forward sensitivities (``sensitivities=True``);
* :func:`~.grids.choose_steps` — a grid through the data times that meets a tolerance.
"""

from .base import Stepper, check_times, time_grid
from .bdf import VariableBDF
from .bdf2 import BDF2
from .euler import BackwardEuler
from .grids import StepSequence, check_steps, choose_steps, step_errors
from .integration import integrate
from .marching import march
from .methods import ADAPTIVE, FIXED, METHODS, check_method

__all__ = [
    "ADAPTIVE",
    "BDF2",
    "FIXED",
    "METHODS",
    "BackwardEuler",
    "StepSequence",
    "Stepper",
    "VariableBDF",
    "check_method",
    "check_steps",
    "check_times",
    "choose_steps",
    "integrate",
    "march",
    "step_errors",
    "time_grid",
]
