"""The thresholds and status codes that the Python solvers and the compiled kernels share.

They live apart from the solve plan (:mod:`..solve.plan`, which re-exports them and documents
each in its module docstring) so that the compiled kernels (:mod:`..solve._kernels`), the
trajectories and the plan itself all read them without importing one another.
"""

from __future__ import annotations

import enum

import numpy as np

# -- thresholds shared by the Python solvers and the compiled kernels ------------------
# (the kernels freeze them when numba compiles; its cache is keyed on _kernels.py, so
# after changing one, touch _kernels.py or clear its __pycache__)
SINGULAR_PIVOT = 1e-14
NEWTON_ETA_MAX = 1e-4
NEWTON_ETA_FACTOR = 0.05
NEWTON_ETA_MIN = 1e-13
KRYLOV_ACCEPT = 10.0
# round-off floors: ROUNDOFF_FACTOR unit round-offs of the magnitude of what is summed
UNIT_ROUNDOFF = float(np.finfo(float).eps)
ROUNDOFF_FACTOR = 10.0
CHORD_RATE = 0.25
# a linear march step's Krylov solve starts from the last state plus the best combination
# of the differences of this many previous states (time.marching.warm_start; on
# benchmarks/transient.py 2 states took 20 % more Krylov iterations, 4 or 5 no fewer)
WARM_START_STATES = 3
# a chaos block (mean block, decoupled mode) below this fraction of the operator's scale
# vanishes: the Galerkin operator is singular whatever the spatial operators are
VANISHING_BLOCK = 1e-12


class SolveStatus(enum.IntEnum):
    """Why a nonlinear solve (a steady solve or one march step) stopped."""

    CONVERGED = 0
    MAX_ITERATIONS = 1
    SINGULAR_JACOBIAN = 2
    KRYLOV_FAILED = 3
    NON_FINITE = 4
    MODEL_FAILURE = 5
    STEP_SIZE = 6  # an error-controlled integration's step fell below round-off of t


def failure_message(status, maxiter):
    """The reason a solve stopped with ``status`` (one wording for every path)."""
    status = SolveStatus(status)
    if status == SolveStatus.MAX_ITERATIONS:
        return f"no convergence in {maxiter} iterations"
    return {
        SolveStatus.CONVERGED: "converged",
        SolveStatus.SINGULAR_JACOBIAN: "Jacobian is singular or not finite",
        SolveStatus.KRYLOV_FAILED: (
            "GMRES did not reach its tolerance (see SolverOptions.maxiter)"
        ),
        SolveStatus.NON_FINITE: "residual became non-finite",
        SolveStatus.MODEL_FAILURE: "model evaluation failed",
        SolveStatus.STEP_SIZE: "the step size fell below round-off without meeting rtol",
    }[status]
