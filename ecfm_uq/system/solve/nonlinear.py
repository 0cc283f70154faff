"""Newton's method on ``fun(z) -> (r, J)`` with the linear solves of :mod:`.linear`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import as_finite_array, as_operator
from ...errors import KrylovError, ModelEvaluationError
from ..model.operator import AugmentedOperator
from .linear import (
    DenseFactor,
    dense_lu,
)
from .plan import (
    NEWTON_ETA_FACTOR,
    SolveStatus,
    failure_message,
    newton_converged,
    residual_floor,
    scaled_tol,
)


@dataclass
class NewtonInfo:
    """Outcome of one Newton solve.

    ``solver`` names the linear solver used (e.g. ``"dense"``, ``"cg+mean"``),
    ``linear_iterations`` the Krylov iterations of each linear solve (empty for direct
    solvers) and ``status`` why the iteration stopped (:class:`.plan.SolveStatus`).
    """

    success: bool
    nit: int
    residual_norm: float
    message: str
    solver: str = "dense"
    linear_iterations: tuple = ()
    status: SolveStatus = SolveStatus.CONVERGED


def newton(fun, z0, tol=1e-10, maxiter=50, *, linear_solver=None, scale=None, first=None):
    """Newton's method on ``fun(z) -> (r, J)``.

    Parameters
    ----------
    fun : callable
        Returns the residual ``r`` (n,) and its Jacobian ``J``: a dense ``(n, n)`` array, or
        a :class:`~..model.operator.GalerkinOperator` / :class:`~..model.operator.AugmentedOperator`
        handled by ``linear_solver``.
    z0 : (n,) array_like
    tol : float
        Convergence when :math:`\\|r\\|_2 < \\mathrm{tol}`, or (with ``scale``) when
        :math:`\\|r\\|_2` is at the round-off floor of the model's scale, if that floor is
        above ``tol`` (:func:`.plan.newton_converged`). With ``scale``, ``tol`` is taken
        relative to the scale at ``z0`` where that scale is below 1
        (:func:`.plan.scaled_tol`), so equations multiplied by a small constant keep
        their digits.
    maxiter : int
    linear_solver : LinearSolver, optional
        How the Jacobians are factorized (dense LU when omitted). With a Krylov solver
        each step is an inexact Newton step (:meth:`LinearSolver.newton_rtol`).
    scale : callable, optional
        ``scale(z) -> float``, the magnitude of the terms the residual sums at ``z``
        (:meth:`GalerkinSystem.residual_scale`); evaluated only while
        :math:`\\|r\\| \\ge` ``tol``.
        A linear system -- a Jacobian operator whose ``is_linear`` is true, i.e. ``fun``
        affine in ``z`` -- costs one Krylov solve: the first solve aims at ``tol`` itself
        and, once the residual meets it, no further solve is made (more only where one
        falls short); the returned factors are those of the constant Jacobian. Direct
        solvers keep their one refinement step (a back-substitution with the same
        factors: it costs little and leaves the answer at round-off).
    first : (r, J), optional
        ``fun(z0)`` when the caller already has it (saves one evaluation).

    Returns
    -------
    z : (n,) ndarray
    factor : object with ``solve(rhs)``, or ``None``
        Factors of the Jacobian at the returned ``z`` (``None`` when the iteration failed);
        the Jacobian is evaluated at the converged point and used for one final
        correction, so ``factor`` is exact for sensitivities.
    info : NewtonInfo
    """
    z = np.array(z0, dtype=float)
    rnorm = np.inf
    label = "dense" if linear_solver is None else linear_solver.record.solver

    def info(status, k, message):
        its = () if linear_solver is None else tuple(linear_solver.record.iterations)
        ok = status == SolveStatus.CONVERGED
        return NewtonInfo(ok, k, rnorm, message, label, its, status)

    iterative = linear_solver is not None and linear_solver.iterative
    for k in range(maxiter + 1):
        try:
            r, J = first if (k == 0 and first is not None) else fun(z)
            # a residual too large to square (|R| > ~1e154, e.g. a rate 10^eps at an
            # extreme eps a profile tries) is a non-finite norm, reported as NON_FINITE
            # below: the expected answer, not a warning to print
            with np.errstate(over="ignore"):
                rnorm = float(np.linalg.norm(r))
            floor = 0.0
            if scale is not None and np.isfinite(rnorm) and (k == 0 or rnorm >= tol):
                sc = scale(z)  # once per iterate: the tolerance's scale and the floor's
                if k == 0:
                    tol = scaled_tol(tol, sc)
                if rnorm >= tol:
                    floor = residual_floor(sc, tol)
        except ModelEvaluationError as e:
            return z, None, info(SolveStatus.MODEL_FAILURE, k, f"model evaluation failed: {e}")
        if not np.isfinite(rnorm):
            return (
                z,
                None,
                info(SolveStatus.NON_FINITE, k, failure_message(SolveStatus.NON_FINITE, maxiter)),
            )
        if linear_solver is None:
            lu = dense_lu(J)
            factor = None if lu is None else DenseFactor(lu)
            rtol = None
        else:
            factor = linear_solver.factorize(J)
            rtol = linear_solver.newton_rtol(rnorm, tol, floor, linear=_is_linear(J))
        if factor is None:
            message = failure_message(SolveStatus.SINGULAR_JACOBIAN, maxiter)
            return z, None, info(SolveStatus.SINGULAR_JACOBIAN, k, message)
        # an affine residual: the Jacobian (and its factors) is the same everywhere, so
        # a correction step would only refine below tol; a start counts as solved only
        # if it is as good as a solve would make it (a warm start of a march step)
        if (
            iterative
            and _is_linear(J)
            and newton_converged(rnorm, tol if k else NEWTON_ETA_FACTOR * tol, floor)
        ):
            return z, factor, info(SolveStatus.CONVERGED, k, "converged")
        try:
            dz = factor.solve(r, rtol=rtol)
        except KrylovError as e:
            message = f"linear solve of Newton step {k} failed: {e}"
            return z, None, info(SolveStatus.KRYLOV_FAILED, k, message)
        z = z - dz
        if newton_converged(rnorm, tol, floor):
            return z, factor, info(SolveStatus.CONVERGED, k, "converged")
    message = failure_message(SolveStatus.MAX_ITERATIONS, maxiter)
    return z, None, info(SolveStatus.MAX_ITERATIONS, maxiter, message)


class Bordered:
    """The ECFM bordered operators of one constrained solve.

    ``Bordered(Jl, Cth)(J)`` wraps ``J`` with the constraint blocks; for a linear ``J``
    the same object comes back for the same ``J``, so the linear solver reuses its factors
    (Schur complement included) across steps. The cache lives here, with the solve.
    """

    def __init__(self, Jl, Cth):
        self.Jl, self.Cth = Jl, Cth
        self._last = None

    def __call__(self, J):
        if self._last is not None and self._last.J is J:
            return self._last
        op = AugmentedOperator(J, self.Jl, self.Cth)
        self._last = op if J.is_linear else None
        return op


def constraint_scale(Cth, theta, v):
    """The round-off scale of the data-constraint rows :math:`C\\theta - v`."""
    return float(np.linalg.norm(abs(Cth) @ np.abs(theta)) + np.linalg.norm(v))


def check_constraint(system, constraint, n_rows=None):
    if constraint is None:
        return None, None
    if system.Gamma is None:
        raise ValueError("a data `constraint` needs constraint forces: build the system with Gamma")
    try:
        M_obs, v = constraint
    except (TypeError, ValueError) as e:
        raise TypeError("`constraint` must be a pair (M_obs, v)") from e
    M_obs = as_operator("M_obs", M_obs, shape=(system.n_forces, system.N))
    v = as_finite_array("v", v)
    want = (system.n_forces,) if n_rows is None else (n_rows, system.n_forces)
    if v.shape != want:
        raise ValueError(f"`v` must have shape {want}, got {v.shape}")
    return M_obs, v


def _is_linear(J):
    """Whether a Jacobian operator says it does not depend on the state (a dense array
    does not say)."""
    return getattr(J, "is_linear", False) is True
