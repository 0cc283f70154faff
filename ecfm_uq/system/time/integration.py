"""``integrate``: the family's error-controlled entry point (steps chosen to a tolerance).

:func:`integrate` solves :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, t) = 0` from
``Theta0`` and returns the states at ``t_eval`` (dense output), by a method of
:data:`.methods.METHODS` that chooses its own steps (today ``"bdf"``, :mod:`.bdf`), and
with ``sensitivities=True`` their derivatives in :math:`\\epsilon`. For calibration, where
gradients must be the exact derivatives of what was computed, march a frozen grid
instead (:func:`.marching.march`, :func:`.grids.choose_steps`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..._validation import as_finite_array, check_int, check_positive
from ...threads import library_threads
from ..solve.linear import LinearSolver
from ..solve.options import solver_options
from ..solve.plan import dense_unknowns
from .bdf import BDFIntegration
from .methods import check_method

__all__ = ["integrate"]


def _check_t_eval(t_eval, t0):
    t_eval = np.atleast_1d(as_finite_array("t_eval", t_eval))
    if t_eval.ndim != 1 or t_eval.size < 1:
        raise ValueError(f"`t_eval` must be a 1-D array of times, got shape {t_eval.shape}")
    if np.any(np.diff(t_eval) <= 0):
        k = int(np.nonzero(np.diff(t_eval) <= 0)[0][0])
        raise ValueError(
            f"`t_eval` must be strictly increasing, but t_eval[{k + 1}] = {t_eval[k + 1]:g} "
            f"<= t_eval[{k}] = {t_eval[k]:g}; sort it (np.unique) before integrating"
        )
    t0 = float(t_eval[0]) if t0 is None else float(as_finite_array("t0", t0, ndim=0))
    if t_eval[0] < t0:
        raise ValueError(f"`t_eval` must start at or after t0 = {t0:g}, got {t_eval[0]:g}")
    if t_eval[-1] == t0:
        raise ValueError("`t_eval` must reach beyond t0 (the time of Theta0)")
    return t_eval, t0


class _MassSolve:
    """Solves with :math:`M\\otimes\\mathbb E[\\Psi\\Psi^T]` (for the initial slope only)."""

    def __init__(self, system):
        M = system.M
        try:
            self.lu = spla.splu(sp.csc_matrix(M)) if sp.issparse(M) else None
        except RuntimeError as e:  # splu: "Factor is exactly singular"
            raise _singular_mass(M) from e
        self.M = None if sp.issparse(M) else np.asarray(M)
        self.E2 = system.E2

    def __call__(self, B):  # B (N, P): X with M X E2 = B
        try:
            X = self.lu.solve(B) if self.lu is not None else np.linalg.solve(self.M, B)
        except np.linalg.LinAlgError as e:
            raise _singular_mass(self.M) from e
        return np.linalg.solve(self.E2.T, X.T).T


def _singular_mass(M):
    """The ValueError of a singular mass matrix, with its rank when it is dense."""
    rank = "" if sp.issparse(M) else f" (rank {np.linalg.matrix_rank(M)} < N = {M.shape[0]})"
    return ValueError(
        f"the mass matrix `M` of the system is singular{rank}: integrate() needs an "
        "invertible M (it starts from the slope M^-1 R); for algebraic rows (a DAE) march "
        "on a grid with march(system, eps, Theta0, dt, n_steps) or march(..., times=...), "
        "whose implicit steps allow a singular M, or give every equation a time derivative"
    )


@library_threads(size=dense_unknowns)
def integrate(
    system,
    eps,
    Theta0,
    t_eval,
    *,
    rtol=1e-6,
    atol=None,
    method="auto",
    t0=None,
    first_step=None,
    max_step=np.inf,
    max_steps=100_000,
    solver="auto",
    sensitivities=False,
):
    """Integrate :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, t) = 0` to a tolerance.

    Parameters
    ----------
    system : GalerkinSystem
        Must have a mass matrix ``M`` (and no data constraint: for calibration use the
        fixed-step :func:`march`, whose adjoint is exact).
    eps : (n_eps,) array_like
    Theta0 : (N, P) or (N,) array_like
        State at ``t0``.
    t_eval : (n_t,) array_like
        Strictly increasing times at which the state is returned.
    rtol : float
        Relative tolerance of the local error, per chaos coefficient; ``> 0``.
    atol : float or (N, P) array_like, optional
        Absolute tolerance; default ``rtol * max|Theta0|`` (``rtol`` when
        ``Theta0 = 0``), so the result does not depend on the model's units.
    method : {"auto", "bdf"}
        ``"bdf"`` (:data:`.methods.METHODS`): variable-order (1-5) NDF/BDF with error
        control (:mod:`.bdf`); ``"auto"`` is ``"bdf"``.
    t0 : float, optional
        Time of ``Theta0``; default ``t_eval[0]``.
    first_step, max_step : float, optional
        The first step (default: chosen from the slope) and the largest step.
    max_steps : int
        Give up (an unsuccessful result) after this many steps.
    solver : str, SolverOptions or dict
        Linear solver of the step Jacobians :math:`M/c + J`, as for :func:`march`.
    sensitivities : bool
        Also integrate :math:`S = \\partial\\Theta/\\partial\\epsilon` (the variational
        equations :math:`M\\dot S + R_\\Theta S + R_\\epsilon = 0`, :math:`S(t_0) = 0`)
        along the same steps, one linear solve per parameter and step with the step's
        iteration matrix (the staggered direct method, :mod:`.bdf`); returned as
        ``Trajectory.dTheta`` at ``t_eval``. The steps are chosen by the state's error
        alone.

    Returns
    -------
    Trajectory
        ``times = t_eval`` and ``Theta`` of shape ``(n_t, N, P)`` (with
        ``sensitivities``, ``dTheta`` of shape ``(n_t, N, P, n_eps)``), ``scheme="bdf"``,
        ``nit`` the Newton iterations of each accepted step and ``stats`` the counts of
        steps, rejected steps, Jacobians and factorizations. When a step cannot meet the
        tolerance (its size falls below round-off of ``t``, or ``max_steps`` is reached)
        ``success`` is ``False``, the message names the time reached and the reason, and
        ``times``/``Theta`` hold every ``t_eval`` reached before it.

    Raises
    ------
    ValueError
        Unknown ``method``, ``rtol <= 0``, ``atol < 0``, ``t_eval`` not increasing, a
        system without mass matrix.
    """
    eps = system.check_eps(eps)
    check_method(method, default="auto", adaptive=True)
    rtol = check_positive("rtol", rtol)
    if rtol < 100 * np.finfo(float).eps:
        raise ValueError(f"`rtol`={rtol:g} is below what double precision can meet; use >= 1e-14")
    t_eval, t0 = _check_t_eval(t_eval, t0)
    max_steps = check_int("max_steps", max_steps, minimum=1)
    if max_step != np.inf:
        max_step = check_positive("max_step", max_step)
    if first_step is not None:
        first_step = check_positive("first_step", first_step)
    if system.M is None:
        system.mass_matrix()  # raises the "no mass matrix" error
    N, P = system.shape
    Theta0 = system.check_initial_state(Theta0)
    if atol is None:
        big = float(np.abs(Theta0).max())
        atol = rtol * (big if big > 0 else 1.0)
    else:
        atol = as_finite_array("atol", atol)
        if atol.shape not in ((), (N, P)) or np.any(atol < 0):
            raise ValueError(f"`atol` must be a non-negative float or an {(N, P)} array")
        atol = atol if atol.shape == () else atol.copy()
    opts = solver_options(solver)
    linear = LinearSolver(system, opts, steady=False, scheme="bdf")
    run = BDFIntegration(system, eps, Theta0, t_eval, t0, rtol, atol, first_step, max_step,
                         max_steps, linear, _MassSolve(system), bool(sensitivities))  # fmt: skip
    return run.run()
