"""Steady solves :math:`R(\\Theta;\\epsilon,\\lambda) = 0`, alone or under the ECFM data
constraint (paper Eqs. ecfm, ecfm_solve), with forward and adjoint sensitivities."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from .._validation import as_finite_array, check_choice, check_int, check_positive
from ..errors import ConvergenceError
from ..threads import library_threads
from .solve.linear import (
    LinearSolver,
    solver_options,
)
from .solve.nonlinear import Bordered, check_constraint, constraint_scale, newton
from .solve.plan import SolveStatus, dense_unknowns


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
    status : SolveStatus
        Why Newton stopped (:class:`.solve.plan.SolveStatus`: ``CONVERGED``, ``MAX_ITERATIONS``,
        ``SINGULAR_JACOBIAN``, ``KRYLOV_FAILED``, ``NON_FINITE``, ``MODEL_FAILURE``).
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
    status: SolveStatus = SolveStatus.CONVERGED
    _lu: object = field(default=None, repr=False)
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


@library_threads(size=dense_unknowns)
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
        ``"sparse-direct"``, ``"cg"`` or ``"gmres"`` (see :mod:`ecfm_uq.system.solve.plan`);
        a :class:`~ecfm_uq.system.SolverOptions` or dict also sets the preconditioner,
        Krylov tolerance and iteration limits. A linear system is solved by Newton too:
        one Krylov solve aimed at ``tol`` (more only if it falls short), or a direct
        solve plus one refinement back-substitution.
    structure : {"auto", "dense"}, optional
        Deprecated older name for ``solver`` (``"auto"`` or ``"dense"`` only); warns.

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
        warnings.warn(
            "solve_steady(structure=) is deprecated; pass solver='auto' or 'dense'",
            DeprecationWarning,
            stacklevel=2,
        )
        solver = check_choice("structure", structure, ("auto", "dense"))
    opts = solver_options(solver)
    M_obs, v = check_constraint(system, constraint)
    N, P = system.shape
    n = N * P
    Theta0 = system.zeros() if Theta0 is None else as_finite_array("Theta0", Theta0, shape=(N, P))
    linear = LinearSolver(system, opts, constrained=M_obs is not None, steady=True)
    if M_obs is None:
        lam = system.check_lam(lam)

        def fun(z):
            Th = z.reshape(N, P)
            return system.residual(Th, eps, lam).ravel(), system.jacobian_operator(Th, eps)

        def scale(z):
            return system.residual_scale(z.reshape(N, P), eps, lam)

        z, factor, info = newton(
            fun, Theta0.ravel(), tol, maxiter, linear_solver=linear, scale=scale
        )
        Theta, lam_out = z.reshape(N, P), lam
    else:
        Cth = system.constraint_jacobian(M_obs)
        Jl = system.lam_jacobian()
        bordered = Bordered(Jl, Cth)

        def fun(z):
            Th, lm = z[:n].reshape(N, P), z[n:]
            r = np.concatenate([system.residual(Th, eps, lm).ravel(), Cth @ z[:n] - v])
            return r, bordered(system.jacobian_operator(Th, eps))

        def scale(z):
            s = system.residual_scale(z[:n].reshape(N, P), eps, z[n:])
            return s + constraint_scale(Cth, z[:n], v)

        z0 = np.concatenate([Theta0.ravel(), np.zeros(system.n_forces)])
        z, factor, info = newton(fun, z0, tol, maxiter, linear_solver=linear, scale=scale)
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
        status=info.status,
        _lu=factor,
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
