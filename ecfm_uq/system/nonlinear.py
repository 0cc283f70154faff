"""Newton's method on ``fun(z) -> (r, J)`` with the linear solves of :mod:`.linear`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_finite_array, as_operator
from ..errors import KrylovError, ModelEvaluationError
from .linear import (
    DenseFactor,
    dense_lu,
)
from .operator import AugmentedOperator


@dataclass
class NewtonInfo:
    """Outcome of one Newton solve.

    ``solver`` names the linear solver used (e.g. ``"dense"``, ``"cg+mean"``) and
    ``linear_iterations`` the Krylov iterations of each linear solve (empty for direct
    solvers).
    """

    success: bool
    nit: int
    residual_norm: float
    message: str
    solver: str = "dense"
    linear_iterations: tuple = ()


def newton(fun, z0, tol=1e-10, maxiter=50, *, linear_solver=None):
    """Newton's method on ``fun(z) -> (r, J)``.

    Parameters
    ----------
    fun : callable
        Returns the residual ``r`` (n,) and its Jacobian ``J``: a dense ``(n, n)`` array, or
        a :class:`~.operator.GalerkinOperator` / :class:`~.operator.AugmentedOperator`
        handled by ``linear_solver``.
    z0 : (n,) array_like
    tol : float
        Convergence when :math:`\\|r\\|_2 < \\mathrm{tol}`.
    maxiter : int
    linear_solver : LinearSolver, optional
        How the Jacobians are factorized (dense LU when omitted). With a Krylov solver
        each step is an inexact Newton step (:meth:`LinearSolver.newton_rtol`).

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

    def info(success, k, message):
        its = () if linear_solver is None else tuple(linear_solver.record.iterations)
        return NewtonInfo(success, k, rnorm, message, label, its)

    for k in range(maxiter + 1):
        try:
            r, J = fun(z)
        except ModelEvaluationError as e:
            return z, None, info(False, k, f"model evaluation failed: {e}")
        rnorm = float(np.linalg.norm(r))
        if not np.isfinite(rnorm):
            return z, None, info(False, k, "residual became non-finite")
        if linear_solver is None:
            lu = dense_lu(J)
            factor = None if lu is None else DenseFactor(lu)
            rtol = None
        else:
            factor = linear_solver.factorize(J)
            rtol = linear_solver.newton_rtol(rnorm, tol)
        if factor is None:
            return z, None, info(False, k, "Jacobian is singular or not finite")
        try:
            dz = factor.solve(r, rtol=rtol)
        except KrylovError as e:
            return z, None, info(False, k, f"linear solve of Newton step {k} failed: {e}")
        z = z - dz
        if rnorm < tol:
            return z, factor, info(True, k, "converged")
    return z, None, info(False, maxiter, f"no convergence in {maxiter} iterations")


def _bordered(J, Jl, Cth):
    """The ECFM bordered operator of ``J``; the same object for the same (linear) ``J``,
    so the linear solver reuses its factors (Schur complement included) across steps."""
    cached = getattr(J, "_bordered", None)
    if cached is None or cached.Jl is not Jl or cached.Cth is not Cth:
        cached = AugmentedOperator(J, Jl, Cth)
        if J.is_linear:
            J._bordered = cached
    return cached


def _check_constraint(system, constraint, n_rows=None):
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
