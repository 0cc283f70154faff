"""Newton solvers for steady and backward-Euler systems, with forward sensitivities.

Steady problems solve :math:`R(\\Theta;\\epsilon,\\lambda) = 0`, optionally augmented with
the data constraint :math:`\\mathcal M\\,\\mathbb E[\\theta] - v = 0` for the unknowns
:math:`(\\Theta, \\lambda)` (the ECFM inner problem, Eq. ecfm and ecfm_solve).
Dynamic problems march

.. math::

    \\frac{M}{\\Delta t}(\\Theta_{t+1} - \\Theta_t) + R(\\Theta_{t+1}; \\epsilon,
    \\lambda_{t+1}, t_{t+1}) = 0

(Eq. backward_euler), with the same optional constraint at every step. Forward
sensitivities (Eqs. discrete_sens, discrete_sens_ecfm, stochastic_sens) reuse the
factorized Jacobian at the converged state: after convergence the Jacobian is evaluated
and factorized once more, used for one last Newton correction and for all
sensitivity right-hand sides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .._validation import as_finite_array, as_operator, check_choice, check_int, check_positive
from ..errors import ConvergenceError, KrylovError, ModelEvaluationError
from .linear import (
    COMPILED_MARCH_MAX_N,
    DenseFactor,
    LinearSolver,
    dense_lu,
    nodal_march_eligible,
    solver_options,
)
from .operator import AugmentedOperator
from .terms import LinearTerm, LoadTerm, QuadraticTerm


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


# --------------------------------------------------------------------------------------
# steady
# --------------------------------------------------------------------------------------
@dataclass
class SteadySolution:
    """Result of :func:`solve_steady`.

    Attributes
    ----------
    Theta : (N, P) ndarray
    lam : (C,) ndarray
        Constraint forces (given, or solved for under a data constraint).
    success, nit, residual_norm, message
        Newton outcome; a failed solve keeps its last iterate for diagnosis only.
    solver : str
        The linear solver used (``"dense"``, ``"decoupled"``, ``"sparse-direct"``,
        ``"cg+mean"``, ``"gmres+mean-amg"``, ...).
    linear_iterations : list of int
        Krylov iterations of every linear solve so far (Newton steps, then sensitivities);
        empty for direct solvers.
    """

    system: object
    eps: np.ndarray
    Theta: np.ndarray
    lam: np.ndarray
    success: bool
    nit: int
    residual_norm: float
    message: str
    constrained: bool = False
    solver: str = "dense"
    _lu: object = field(default=None, repr=False)
    _M_obs: object = field(default=None, repr=False)
    _linear: object = field(default=None, repr=False)

    @property
    def linear_iterations(self):
        return [] if self._linear is None else list(self._linear.record.iterations)

    def pce(self, observe=None, inputs=None):
        """The solution as a :class:`~ecfm_uq.chaos.PolynomialChaosExpansion`.

        Parameters
        ----------
        observe : (C, N) array_like or scipy.sparse matrix, optional
            Observation operator (e.g. the sensor matrix :math:`\\mathcal M`): the PCE
            is then of the C observations instead of the N states.
        inputs : UniformInputs, bounds or chaospy distribution, optional
            What the germ stands for, for evaluation on the inputs' own ranges.

        Returns
        -------
        PolynomialChaosExpansion
            Coefficients ``Theta.T`` (P, N), or ``(observe @ Theta).T`` (P, C): mean,
            variance, Sobol indices and densities of the Galerkin solution.
        """
        from ..chaos import PolynomialChaosExpansion

        if not self.success:
            raise ConvergenceError(f"a PCE of a failed solve: {self.message}")
        return PolynomialChaosExpansion.from_galerkin(
            self.system, self.Theta, inputs=inputs, observe=observe
        )

    def _require(self):
        if not self.success:
            raise ConvergenceError(f"sensitivities of a failed solve: {self.message}")

    def _solve(self, rhs):
        return self._lu.solve(rhs)

    def jacobian_solve(self, rhs):
        """Solve :math:`(\\partial R/\\partial\\Theta)\\,X = B` with the stored factors.

        The factors (dense LU, or the decoupled blocks) of the converged solve are reused,
        so further sensitivity systems (e.g. second derivatives) cost one back-substitution.

        Parameters
        ----------
        rhs : (N * P,) or (N * P, m) array_like
            Right-hand side(s), flattened row-major like ``Theta``.

        Returns
        -------
        ndarray of the shape of ``rhs``
        """
        self._require()
        if self.constrained:
            raise ValueError("a constrained solve stores the augmented (Theta, lam) factors")
        n = self.system.N * self.system.P
        rhs = as_finite_array("rhs", rhs)
        if rhs.shape[0] != n or rhs.ndim > 2:
            raise ValueError(f"`rhs` must have shape ({n},) or ({n}, m), got {rhs.shape}")
        return self._solve(rhs)

    def adjoint_gradient(self, g_theta, g_lam=None):
        """Gradient in :math:`\\epsilon` of a scalar :math:`z(\\Theta, \\lambda)` by one adjoint solve.

        With :math:`J` the (augmented, under a data constraint) Jacobian at the solution,
        solve :math:`J^T\\mu = \\partial z/\\partial(\\Theta, \\lambda)` and return
        :math:`dz/d\\epsilon = -(\\partial R/\\partial\\epsilon)^T\\mu_\\Theta` (the constraint
        rows do not depend on :math:`\\epsilon`). One transposed solve with the stored
        factors, whatever ``n_eps``; equal to the forward-sensitivity gradient.

        Parameters
        ----------
        g_theta : (N, P) array_like
            :math:`\\partial z/\\partial\\Theta`.
        g_lam : (C,) array_like, optional
            :math:`\\partial z/\\partial\\lambda` (constrained solves only).

        Returns
        -------
        (n_eps,) ndarray
        """
        self._require()
        sysm = self.system
        n = sysm.N * sysm.P
        rhs = as_finite_array("g_theta", g_theta, shape=sysm.shape).ravel()
        if self.constrained:
            g_lam = np.zeros(sysm.n_forces) if g_lam is None else g_lam
            g_lam = as_finite_array("g_lam", g_lam, shape=(sysm.n_forces,))
            rhs = np.concatenate([rhs, g_lam])
        elif g_lam is not None:
            raise ValueError("`g_lam` is only defined for a solve under a data constraint")
        mu = self._lu.solve_transpose(rhs)
        return -sysm.eps_vjp(self.Theta, self.eps, mu[:n])

    def eps_sensitivity(self):
        """:math:`\\partial\\Theta/\\partial\\epsilon` (N, P, n_eps) and, under a data
        constraint, :math:`\\partial\\lambda/\\partial\\epsilon` (C, n_eps) (else ``None``)."""
        self._require()
        sysm = self.system
        n = sysm.N * sysm.P
        D = sysm.eps_jacobian(self.Theta, self.eps)
        if self.constrained:
            D = np.vstack([D, np.zeros((sysm.n_forces, sysm.n_eps))])
        S = -self._solve(D)
        dTheta = S[:n].reshape(sysm.N, sysm.P, sysm.n_eps)
        return dTheta, (S[n:] if self.constrained else None)

    def lam_sensitivity(self):
        """:math:`\\partial\\Theta/\\partial\\lambda` (N, P, C) for given forces (Eq. stochastic_sens)."""
        self._require()
        if self.constrained:
            raise ValueError("lam is an unknown of a constrained solve; it has no sensitivity")
        sysm = self.system
        S = -self._solve(sysm.lam_jacobian())
        return S.reshape(sysm.N, sysm.P, sysm.n_forces)


def solve_steady(
    system,
    eps,
    lam=None,
    *,
    constraint=None,
    Theta0=None,
    tol=1e-10,
    maxiter=50,
    strict=False,
    solver="auto",
    structure=None,
):
    """Solve the steady system :math:`R(\\Theta; \\epsilon, \\lambda) = 0` by Newton's method.

    Parameters
    ----------
    system : GalerkinSystem
    eps : (n_eps,) array_like
    lam : (C,) array_like, optional
        Given constraint forces (ignored with ``constraint``).
    constraint : (M_obs, v), optional
        Data constraint :math:`\\mathcal M\\,\\Theta\\,\\mathbb E[\\Psi] = v` with
        ``M_obs`` (C, N) (dense or sparse) and ``v`` (C,); :math:`\\lambda` becomes an
        unknown.
    Theta0 : (N, P) array_like, optional
        Initial guess (zero by default).
    tol : float
        Newton tolerance on :math:`\\|R\\|_2`.
    maxiter : int
    strict : bool
        Raise :class:`ConvergenceError` instead of returning ``success=False``.
    solver : str, SolverOptions or dict
        Linear solver: ``"auto"`` (default), ``"dense"``, ``"decoupled"``,
        ``"sparse-direct"``, ``"cg"`` or ``"gmres"`` (see :mod:`ecfm_uq.system.linear`);
        a :class:`~ecfm_uq.system.SolverOptions` or dict also sets the preconditioner,
        Krylov tolerance and iteration limits. A linear system is solved by Newton too:
        one step, plus refinement steps until ``tol`` is met.
    structure : {"auto", "dense"}, optional
        Older name for ``solver`` (``"auto"`` or ``"dense"`` only).

    Returns
    -------
    SteadySolution
        ``solver`` and ``linear_iterations`` report what the linear solves did; a Krylov
        solve that misses its tolerance makes ``success`` False.
    """
    eps = system.check_eps(eps)
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    if structure is not None:
        solver = check_choice("structure", structure, ("auto", "dense"))
    opts = solver_options(solver)
    M_obs, v = _check_constraint(system, constraint)
    N, P = system.shape
    n = N * P
    Theta0 = system.zeros() if Theta0 is None else as_finite_array("Theta0", Theta0, shape=(N, P))
    linear = LinearSolver(system, opts, constrained=M_obs is not None, steady=True)
    if M_obs is None:
        lam = system.check_lam(lam)

        def fun(z):
            Th = z.reshape(N, P)
            return system.residual(Th, eps, lam).ravel(), system.jacobian_operator(Th, eps)

        z, factor, info = newton(fun, Theta0.ravel(), tol, maxiter, linear_solver=linear)
        Theta, lam_out = z.reshape(N, P), lam
    else:
        Cth = system.constraint_jacobian(M_obs)
        Jl = system.lam_jacobian()

        def fun(z):
            Th, lm = z[:n].reshape(N, P), z[n:]
            r = np.concatenate([system.residual(Th, eps, lm).ravel(), Cth @ z[:n] - v])
            return r, _bordered(system.jacobian_operator(Th, eps), Jl, Cth)

        z0 = np.concatenate([Theta0.ravel(), np.zeros(system.n_forces)])
        z, factor, info = newton(fun, z0, tol, maxiter, linear_solver=linear)
        Theta, lam_out = z[:n].reshape(N, P), z[n:]
    message = info.message
    if info.success and linear.name == "decoupled":
        message = "converged (decoupled direct solve)"
    sol = SteadySolution(
        system,
        eps,
        Theta,
        lam_out,
        info.success,
        info.nit,
        info.residual_norm,
        message,
        constrained=M_obs is not None,
        solver=linear.record.solver,
        _lu=factor,
        _M_obs=M_obs,
        _linear=linear,
    )
    if strict and not sol.success:
        raise ConvergenceError(f"{system.name}: steady Newton failed at eps={eps}: {message}")
    return sol


def solve_continuation(
    system,
    eps_start,
    eps_end,
    *,
    Theta0=None,
    max_halvings=6,
    tol=1e-10,
    maxiter=50,
    strict=False,
    solver="auto",
):
    """Solve at ``eps_end`` by Newton continuation along the straight path from ``eps_start``.

    Newton first goes straight to ``eps_end``; if that fails, the path is taken in
    ``2, 4, 8, ...`` equal steps, each Newton solve started from the previous solution
    (``Theta0`` for the first), until one pass succeeds.

    Parameters
    ----------
    system : GalerkinSystem
    eps_start, eps_end : (n_eps,) array_like
        Path ends; ``Theta0`` should solve (or nearly solve) the system at ``eps_start``.
    Theta0 : (N, P) array_like, optional
        Start state (zero by default).
    max_halvings : int
        At most ``2**max_halvings`` steps.
    tol, maxiter : Newton settings per step.
    strict : bool
        Raise :class:`ConvergenceError` instead of returning ``success=False``.
    solver : str, SolverOptions or dict
        Linear solver, as for :func:`solve_steady`.

    Returns
    -------
    sol : SteadySolution
        At ``eps_end``; ``nit`` counts the Newton iterations of the successful pass.
    steps : int
        Number of continuation steps used.
    """
    e0, e1 = system.check_eps(eps_start), system.check_eps(eps_end)
    max_halvings = check_int("max_halvings", max_halvings, minimum=0)
    Theta0 = (
        system.zeros() if Theta0 is None else as_finite_array("Theta0", Theta0, shape=system.shape)
    )
    for h in range(max_halvings + 1):
        steps = 2**h
        Theta, nit = Theta0, 0
        for t in np.arange(1, steps + 1) / steps:
            sol = solve_steady(
                system, e0 + t * (e1 - e0), Theta0=Theta, tol=tol, maxiter=maxiter, solver=solver
            )
            nit += sol.nit
            if not sol.success:
                sol.message = f"continuation step t={t:.4g} of {steps}: {sol.message}"
                break
            Theta = sol.Theta
        else:
            sol.nit = nit
            return sol, steps
    if strict:
        raise ConvergenceError(f"{system.name}: continuation failed ({sol.message})")
    return sol, steps


# --------------------------------------------------------------------------------------
# backward Euler
# --------------------------------------------------------------------------------------
@dataclass
class Trajectory:
    """Result of :func:`march`.

    Attributes
    ----------
    times : (n_steps + 1,) ndarray
    Theta : (n_steps + 1, N, P) ndarray
        States. After a failure the arrays stop at the last converged step, so no
        unconverged state is ever returned.
    lam : (n_steps + 1, C) ndarray
        Constraint forces (zero at t = 0).
    dTheta : (n_steps + 1, N, P, n_eps) ndarray or None
        :math:`\\partial\\Theta_t/\\partial\\epsilon` (Eq. discrete_sens / discrete_sens_ecfm).
    dlam : (n_steps + 1, C, n_eps) ndarray or None
    success : bool
    message : str
    failed_step : int or None
        Index of the step whose Newton solve failed.
    nit : (n_steps,) ndarray
        Newton iterations per step.
    solver : str
        The linear solver used.
    linear_iterations : list of int
        Krylov iterations of every linear solve (empty for direct solvers).
    """

    times: np.ndarray
    Theta: np.ndarray
    lam: np.ndarray
    dTheta: np.ndarray | None
    dlam: np.ndarray | None
    success: bool
    message: str
    failed_step: int | None
    nit: np.ndarray
    solver: str = "dense"
    linear_iterations: list = field(default_factory=list)
    _adjoint: object = field(default=None, repr=False)

    def adjoint_gradient(self, g_theta, g_lam=None):
        """Gradient in :math:`\\epsilon` of :math:`z = \\sum_t z_t(\\Theta_t, \\lambda_t)` by the
        discrete adjoint of backward Euler (needs ``march(..., keep_factors=True)``).

        Backward in time, with :math:`A_t` the (augmented) step Jacobian,

        .. math::

            A_t^T\\mu_t = \\frac{\\partial z}{\\partial(\\Theta_t, \\lambda_t)}
                + \\begin{bmatrix}(M/\\Delta t)^T\\mu_{t+1,\\Theta}\\\\0\\end{bmatrix},
            \\qquad
            \\frac{dz}{d\\epsilon} = -\\sum_t
                \\Bigl(\\frac{\\partial R_t}{\\partial\\epsilon}\\Bigr)^T\\mu_{t,\\Theta},

        one transposed solve per step with the factors kept from the forward march,
        whatever the number of parameters (the forward sensitivities of Eq.
        discrete_sens need ``n_eps`` right-hand sides per step).

        Parameters
        ----------
        g_theta : (n_steps + 1, N, P) array_like
            :math:`\\partial z/\\partial\\Theta_t` (row 0 is ignored: the initial state
            does not depend on :math:`\\epsilon`).
        g_lam : (n_steps + 1, C) array_like, optional
            :math:`\\partial z/\\partial\\lambda_t` (constrained marches).

        Returns
        -------
        (n_eps,) ndarray
        """
        if self._adjoint is None:
            raise ValueError("march with keep_factors=True to compute adjoint gradients")
        if not self.success:
            raise ConvergenceError(f"adjoint of a failed march: {self.message}")
        n_t, N, P = self.Theta.shape
        g_theta = as_finite_array("g_theta", g_theta, shape=(n_t, N, P)).reshape(n_t, N * P)
        C = self.lam.shape[1]
        if C:
            g_lam = np.zeros((n_t, C)) if g_lam is None else g_lam
            g_lam = as_finite_array("g_lam", g_lam, shape=(n_t, C))
            g_theta = np.concatenate([g_theta, g_lam], axis=1)
        elif g_lam is not None:
            raise ValueError("`g_lam` is only defined for a march under a data constraint")
        return self._adjoint(g_theta)


def _generic_adjoint(system, eps, Theta, times, factors, mass_T):
    """The backward pass of :meth:`Trajectory.adjoint_gradient` with kept factors.

    Returns ``adjoint(g)``, ``g`` of shape (n_t, NP + C) holding
    :math:`\\partial z/\\partial(\\Theta_t, \\lambda_t)`.
    """
    n = Theta[0].size

    def adjoint(g):
        grad = np.zeros(system.n_eps)
        carry = np.zeros(n)
        for t in range(len(times) - 1, 0, -1):
            rhs = g[t].copy()
            rhs[:n] += carry
            mu = factors[t - 1].solve_transpose(rhs)[:n]
            grad -= system.eps_vjp(Theta[t], eps, mu, times[t])
            carry = mass_T(mu)
        return grad

    return adjoint


# the P > 1 march's chord iteration hands a step to Newton-Krylov when its residual falls
# by less than this factor per iteration (<= 0: Newton-Krylov throughout)
_CHORD_RATE = 0.25
_COMPILED = {"disabled": False}


def _compiled_kernels():
    """The compiled march's module, or ``None`` where it cannot work.

    The kernels reach LAPACK through numba's own binding (``numba.np.linalg``), which is
    numba-internal: if a numba release moves it, every march takes the generic Python
    path (same results, slower) instead of failing.
    """
    if _COMPILED["disabled"]:
        return None
    try:
        from . import _kernels
    except (ImportError, AttributeError):
        _COMPILED["disabled"] = True
        return None
    return _kernels


def _compiled_march(
    linear, system, eps, Theta0, dt, n_steps, t0, M_obs, V, sens, tol, maxiter, keep, guess
):
    """March with a compiled kernel when the system qualifies, else ``None``.

    ``P = 1`` with the dense solver, at most one quadratic term and ``N`` at most 128
    (its tensor kept as compressed rows of the nonzeros): :func:`_kernels.march_p1`.
    ``P > 1`` with the node-preconditioned Krylov solver that
    :func:`.linear.choose_solver` picks for such marches (no data constraint, no kept
    factors, :func:`.linear.nodal_march_eligible`): :func:`_kernels.march_sg`.
    """
    N, P = system.shape
    quads = [t for t in system.terms if isinstance(t, QuadraticTerm)]
    if len(quads) > 1 or N > COMPILED_MARCH_MAX_N:
        return None
    if P == 1 and linear.name != "dense":
        return None
    if P > 1 and not (
        linear.name == "gmres"
        and linear.preconditioner_kind() == "nodal"
        and M_obs is None
        and not keep
        and nodal_march_eligible(system)
    ):
        return None
    _kernels = _compiled_kernels()
    if _kernels is None:
        return None
    lin = [t for t in system.terms if isinstance(t, LinearTerm)]
    loads = [t for t in system.terms if isinstance(t, LoadTerm)]
    n_eps = system.n_eps
    times = t0 + dt * np.arange(n_steps + 1)
    if "_compiled_Ks" not in system.__dict__:  # fixed operators: stacked once per system
        dense = [t.K.toarray() if t.sparse else t.K for t in lin]
        system._compiled_Ks = np.array(dense).reshape(len(lin), N, N)
    Ks = system._compiled_Ks
    if quads:
        rows, ptr, idx, val = quads[0].linearization_table()
        cq, gq = quads[0].coef.value(eps), np.asarray(quads[0].coef.grad(eps), dtype=float)
    else:
        rows = idx = np.zeros(0, dtype=np.int64)
        ptr = np.zeros(1, dtype=np.int64)
        val, cq, gq = np.zeros(0), 0.0, np.zeros(n_eps)
    F = np.zeros((n_steps + 1, N, P))
    dF = np.zeros((n_steps + 1, N, P, n_eps))
    for term in loads:
        Ft, dFt = term.on_grid(eps, times, derivative=sens or keep)
        F += Ft
        if dFt is not None:
            dF += dFt
    Mdt = system.mass_matrix() / dt if P == 1 else system.M / dt
    quad = (rows, ptr, idx, val, float(cq), gq)
    args = (system, eps, Theta0, times, M_obs, V, sens, tol, maxiter, keep, guess)
    from numba.core.errors import NumbaError

    try:
        with np.errstate(all="ignore"):
            if P == 1:
                F1, dF1 = np.ascontiguousarray(F[:, :, 0]), np.ascontiguousarray(dF[:, :, 0])
                return _march_p1(_kernels, linear, *args, lin, Ks, quad, F1, dF1, Mdt)
            return _march_sg(_kernels, linear, *args, lin, Ks, quad, F, dF, Mdt)
    except NumbaError:  # the kernel does not compile with this numba: use the generic march
        _COMPILED["disabled"] = True
        return None


def _failed_trajectory(system, times, failed, rnorm, maxiter, Theta, lam, nits, label, its=()):
    """The trajectory up to a compiled march's failed step, with the reason."""
    k = failed + 1
    where = f"{system.name}: Newton failed at step {k} (t={times[k]:.6g})"
    if rnorm == -1.0:
        msg = f"{where}: the step Jacobian is singular"
    elif rnorm == -2.0:
        msg = f"{where}: GMRES did not reach its tolerance (see SolverOptions.maxiter)"
    else:
        msg = f"{where} with ||R||={rnorm:.3e}: no convergence in {maxiter} iterations"
    return Trajectory(
        times[:k], Theta[:k], lam[:k], None, None, False, msg, k, nits[:k], label, list(its[:k])
    )


def _march_sg(_kernels, linear, system, eps, Theta0, times, M_obs, V, sens, tol, maxiter, keep,
              guess, lin, Ks, quad, F, dF, Mdt):  # fmt: skip
    """The ``P > 1`` compiled march (:func:`_kernels.march_sg`)."""
    N, P = system.shape
    n_eps = system.n_eps
    nodes = system.gauss_nodes()
    if "_compiled_nodal" not in system.__dict__:  # node factors of the fixed couplings
        Gs = np.array([t.G for t in lin]).reshape(len(lin), P, P)
        gnode = np.array([nodes.coupling_values(G) for G in Gs]).reshape(len(lin), P)
        E3m = np.zeros((P, P * P))
        quads = [t for t in system.terms if isinstance(t, QuadraticTerm)]
        if quads:  # E3[b, c, l] as row c, column b P + l
            E3m = np.ascontiguousarray(quads[0]._E3.transpose(1, 0, 2).reshape(P, P * P))
        system._compiled_nodal = (Gs, gnode, nodes.coupling_values(system.E2), E3m)
    Gs, gnode, mnode, E3m = system._compiled_nodal
    cs = np.array([t.coef.value(eps) for t in lin], dtype=float).reshape(len(lin))
    gK = np.array([t.coef.grad(eps) for t in lin], dtype=float).reshape(len(lin), n_eps)
    rows, ptr, idx, val, cq, gq = quad
    start = np.zeros((1, N, P)) if guess is None else np.ascontiguousarray(guess.Theta)
    opts = linear.options
    Th, dTh, nits, kits, failed, rnorm = _kernels.march_sg(
        np.ascontiguousarray(Mdt), np.ascontiguousarray(system.E2), Ks, cs, Gs, gK,
        rows, ptr, idx, val, cq, gq, E3m, F, dF,
        np.ascontiguousarray(nodes.Phi.T), nodes.to_nodes, nodes.from_nodes, mnode, gnode,
        np.ascontiguousarray(Theta0), start, guess is not None, tol, maxiter, bool(sens),
        opts.rtol, opts.restart, opts.maxiter, _CHORD_RATE,
    )  # fmt: skip
    label = "gmres+nodal (compiled)"
    lam = np.zeros((len(times), 0))
    if failed != -1:
        return _failed_trajectory(system, times, failed, rnorm, maxiter, Th, lam, nits, label, kits)
    return Trajectory(
        times, Th, lam, dTh if sens else None, None, True, "converged at every step", None,
        nits, label, [int(k) for k in kits],
    )  # fmt: skip


def _march_p1(_kernels, linear, system, eps, Theta0, times, M_obs, V, sens, tol, maxiter, keep,
              guess, lin, Ks, quad, F, dF, Mdt):  # fmt: skip
    """The ``P = 1`` compiled march (:func:`_kernels.march_p1`) and its adjoint."""
    N = system.N
    n_eps = system.n_eps
    n_steps = len(times) - 1
    # with P = 1 the coupling G = E[g Psi_0 Psi_0] is a scalar factor of the term
    g00 = np.array([t.G[0, 0] for t in lin])
    cs = np.array([t.coef.value(eps) for t in lin]) * g00
    gK = np.array([t.coef.grad(eps) for t in lin], dtype=float).reshape(len(lin), n_eps)
    gK = gK * g00[:, None]
    Klin = np.einsum("q,qij->ij", cs, Ks) if lin else np.zeros((N, N))
    rows, ptr, idx, val, cq, gq = quad
    if M_obs is None:
        Cobs, Gam, Vd = np.zeros((0, N)), np.zeros((N, 0)), np.zeros((n_steps + 1, 0))
    else:
        Cobs = M_obs.toarray() if sp.issparse(M_obs) else np.asarray(M_obs)
        Gam = -system.lam_jacobian()
        Vd = np.asarray(V, dtype=float)
    C = Cobs.shape[0]
    if guess is None:
        start = np.zeros((n_steps + 1, N + C))
    else:
        start = np.concatenate([guess.Theta[:, :, 0], guess.lam.reshape(n_steps + 1, C)], 1)
    Th, lam, dTh, dlam, nits, failed, rnorm, LUs, pivs = _kernels.march_p1(
        Mdt, Klin, Ks, gK, rows, ptr, idx, val, cq, gq, F, dF, Cobs, Gam, Vd,
        np.ascontiguousarray(Theta0[:, 0]), start, guess is not None,
        tol, maxiter, bool(sens), bool(keep),
    )  # fmt: skip
    label = "dense (compiled)"
    if failed != -1:
        return _failed_trajectory(
            system, times, failed, rnorm, maxiter, Th[:, :, None], lam, nits, label
        )
    adjoint = None
    if keep:

        def adjoint(g):  # g: (n_t, N + C) = dz/d(Theta_t, lam_t)
            with np.errstate(all="ignore"):
                return _kernels.adjoint_p1(
                    LUs,
                    pivs,
                    Th,
                    Mdt,
                    Ks,
                    gK,
                    rows,
                    ptr,
                    idx,
                    val,
                    gq,
                    dF,
                    np.ascontiguousarray(g),
                )

    return Trajectory(
        times,
        Th[:, :, None],
        lam,
        dTh[:, :, None, :] if sens else None,
        dlam if sens and M_obs is not None else None,
        True,
        "converged at every step",
        None,
        nits,
        label,
        [],
        adjoint,
    )


def march(
    system,
    eps,
    Theta0,
    dt,
    n_steps,
    *,
    t0=0.0,
    constraint=None,
    sensitivities=False,
    tol=1e-10,
    maxiter=30,
    strict=False,
    solver="auto",
    keep_factors=False,
    guess=None,
):
    """Integrate :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, \\lambda, t) = 0` by backward Euler.

    Parameters
    ----------
    system : GalerkinSystem
        Must have a mass matrix ``M``.
    eps : (n_eps,) array_like
    Theta0 : (N, P) or (N,) array_like
        Initial state (independent of :math:`\\epsilon`).
    dt : float
    n_steps : int
    t0 : float
    constraint : (M_obs, V), optional
        Data constraint at every step, ``V`` of shape (n_steps + 1, C) with row ``t`` the
        data at time ``t0 + t dt`` (row 0 unused). :math:`\\lambda_t` become unknowns
        (Eq. ecfm_solve).
    sensitivities : bool
        Also integrate :math:`\\partial\\Theta/\\partial\\epsilon` (and
        :math:`\\partial\\lambda/\\partial\\epsilon`) with the factorized step Jacobian.
    tol, maxiter : Newton settings per step.
    strict : bool
        Raise :class:`ConvergenceError` on failure instead of returning ``success=False``.
    solver : str, SolverOptions or dict
        Linear solver for the step Jacobians :math:`M/\\Delta t + J`, as for
        :func:`solve_steady` (``"decoupled"`` is for steady solves only).
    keep_factors : bool
        Keep every step's factorized Jacobian for :meth:`Trajectory.adjoint_gradient`.
    guess : Trajectory, optional
        A trajectory on the same time grid (e.g. at the previous parameters of an
        optimizer) whose states start each step's Newton iteration instead of the
        previous step's state (a warm start: fewer Newton iterations, same solution to
        ``tol``).

    Notes
    -----
    Small deterministic systems (``P = 1``, dense solver, at most one quadratic term,
    ``N <= 128``) are marched by one compiled kernel (:mod:`._kernels`) with the same
    maths and no Python work per step; ``Trajectory.solver`` then reads
    ``"dense (compiled)"``.

    Returns
    -------
    Trajectory
    """
    eps = system.check_eps(eps)
    dt = check_positive("dt", dt)
    n_steps = check_int("n_steps", n_steps, minimum=1)
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    N, P = system.shape
    n = N * P
    Theta0 = as_finite_array("Theta0", Theta0)
    if Theta0.shape == (N,):
        Theta0 = np.outer(Theta0, np.eye(P)[0])
    if Theta0.shape != (N, P):
        raise ValueError(f"`Theta0` must have shape {(N, P)} or {(N,)}, got {Theta0.shape}")
    M_obs, V = _check_constraint(system, constraint, n_rows=n_steps + 1)
    constrained = M_obs is not None
    C = system.n_forces if constrained else 0
    if system.M is None:
        system.mass_matrix()  # raises the "no mass matrix" error
    linear = LinearSolver(
        system,
        solver_options(solver),
        constrained=constrained,
        steady=False,
        keep_factors=keep_factors,
    )
    if guess is not None:
        if not isinstance(guess, Trajectory) or guess.Theta.shape != (n_steps + 1, N, P):
            raise ValueError(
                f"`guess` must be a Trajectory of shape {(n_steps + 1, N, P)} (a previous "
                "march on the same grid)"
            )
        if constrained and guess.lam.shape != (n_steps + 1, C):
            raise ValueError("`guess` must come from a march under the same data constraint")
    args = (system, eps, Theta0, dt, n_steps, t0, M_obs, V, sensitivities, tol, maxiter)
    traj = _compiled_march(linear, *args, keep_factors, guess)
    if traj is not None:
        if strict and not traj.success:
            raise ConvergenceError(traj.message)
        return traj
    if linear.name == "dense":
        Mdt = system.mass_matrix() / dt

        def mass(X):  # (NP,) or (NP, m)
            return Mdt @ X

        def mass_T(x):
            return Mdt.T @ x
    else:

        def mass(X):
            Xr = X.reshape(N, P, -1)
            out = np.stack([system.apply_mass(Xr[:, :, j]) for j in range(Xr.shape[2])], -1)
            return out.reshape(X.shape) / dt

        def mass_T(x):
            return system.apply_mass(x.reshape(N, P), transpose=True).ravel() / dt

    if constrained:
        Cth = system.constraint_jacobian(M_obs)
        Jl = system.lam_jacobian()

    times = t0 + dt * np.arange(n_steps + 1)
    Th = np.zeros((n_steps + 1, N, P))
    Th[0] = Theta0
    lam = np.zeros((n_steps + 1, C))
    dTh = np.zeros((n_steps + 1, n, system.n_eps)) if sensitivities else None
    dlam = np.zeros((n_steps + 1, C, system.n_eps)) if sensitivities and constrained else None
    nits = np.zeros(n_steps, dtype=int)
    factors = [] if keep_factors else None

    for s in range(n_steps):
        t1 = times[s + 1]
        prev = Th[s].ravel()

        if constrained:
            v1 = V[s + 1]

            def fun(z, prev=prev, t1=t1, v1=v1):
                T1, l1 = z[:n].reshape(N, P), z[n:]
                r1 = mass(z[:n] - prev) + system.residual(T1, eps, l1, t1).ravel()
                J = _bordered(system.jacobian_operator(T1, eps, t1, dt=dt), Jl, Cth)
                return np.concatenate([r1, Cth @ z[:n] - v1]), J

            z0 = np.concatenate([prev, lam[s]])
            if guess is not None:
                z0 = np.concatenate([guess.Theta[s + 1].ravel(), guess.lam[s + 1]])
        else:

            def fun(z, prev=prev, t1=t1):
                T1 = z.reshape(N, P)
                r1 = mass(z - prev) + system.residual(T1, eps, None, t1).ravel()
                return r1, system.jacobian_operator(T1, eps, t1, dt=dt)

            z0 = prev if guess is None else guess.Theta[s + 1].ravel()
        z, lu, info = newton(fun, z0, tol, maxiter, linear_solver=linear)
        nits[s] = info.nit
        if not info.success:
            msg = (
                f"{system.name}: Newton failed at step {s + 1} (t={t1:.6g}) with "
                f"||R||={info.residual_norm:.3e}: {info.message}"
            )
            if strict:
                raise ConvergenceError(msg)
            k = s + 1
            return Trajectory(
                times[:k],
                Th[:k],
                lam[:k],
                None if dTh is None else dTh[:k].reshape(k, N, P, -1),
                None if dlam is None else dlam[:k],
                False,
                msg,
                s + 1,
                nits[: s + 1],
                linear.record.solver,
                list(linear.record.iterations),
            )
        Th[s + 1] = z[:n].reshape(N, P)
        if keep_factors:
            factors.append(lu)
        if constrained:
            lam[s + 1] = z[n:]
        if sensitivities:
            T1 = Th[s + 1]
            rhs = mass(dTh[s]) - system.eps_jacobian(T1, eps, t1)
            if constrained:
                rhs = np.vstack([rhs, np.zeros((C, system.n_eps))])
            S = lu.solve(rhs)
            dTh[s + 1] = S[:n]
            if constrained:
                dlam[s + 1] = S[n:]

    return Trajectory(
        times,
        Th,
        lam,
        None if dTh is None else dTh.reshape(n_steps + 1, N, P, system.n_eps),
        dlam,
        True,
        "converged at every step",
        None,
        nits,
        linear.record.solver,
        list(linear.record.iterations),
        _generic_adjoint(system, eps, Th, times, factors, mass_T) if keep_factors else None,
    )
