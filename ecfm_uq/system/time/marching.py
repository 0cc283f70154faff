"""``march``: the family's marches on a fixed or given grid, with forward sensitivities
and kept factors for the adjoint.

Steady problems solve :math:`R(\\Theta;\\epsilon,\\lambda) = 0`, optionally augmented with
the data constraint :math:`\\mathcal M\\,\\mathbb E[\\theta] - v = 0` for the unknowns
:math:`(\\Theta, \\lambda)` (the ECFM inner problem, Eq. ecfm and ecfm_solve).
Dynamic problems march

.. math::

    \\frac{M}{\\Delta t}(\\Theta_{t+1} - \\Theta_t) + R(\\Theta_{t+1}; \\epsilon,
    \\lambda_{t+1}, t_{t+1}) = 0

(Eq. backward_euler), with the same optional constraint at every step, or by the
second-order BDF2 (``method="bdf2"``, :mod:`.bdf2`: each step the same solve from a
combination of the last two states, :mod:`.base`). Forward
sensitivities (Eqs. discrete_sens, discrete_sens_ecfm, stochastic_sens) reuse the
factorized Jacobian at the converged state: after convergence the Jacobian is evaluated
and factorized once more, used for one last Newton correction and for all
sensitivity right-hand sides.

The march is three parts: the setup of a march (:class:`MarchSetup`: the mass products
:class:`MassProducts`, the linear solver, the constraint's border), the solve of one
step (:class:`StepProblem`, the residual and scale handed to Newton) and the
sensitivity bookkeeping (:class:`Sensitivities`); :func:`march` validates, dispatches to
the compiled kernels (:mod:`..solve.compiled`) or loops over the steps.
"""

from __future__ import annotations

import numpy as np

from ..._validation import check_int, check_positive
from ...errors import ConvergenceError
from ...threads import library_threads
from ..model.trajectory import Trajectory, generic_adjoint
from ..solve.compiled import compiled_march
from ..solve.linear import LinearSolver
from ..solve.nonlinear import Bordered, check_constraint, constraint_scale, newton
from ..solve.options import solver_options
from ..solve.plan import WARM_START_STATES, dense_unknowns
from .base import Stepper, time_grid
from .methods import METHODS, check_method

__all__ = ["MarchSetup", "MassProducts", "Sensitivities", "StepProblem", "march", "warm_start"]


def warm_start(fun, states):
    """The start of a linear step's solve: the last state plus the combination of the
    last state differences that minimizes the step's residual; returns it with its
    residual and the Jacobian, ``(z0, (r0, J))``.

    For an affine residual ``r(z0 + D c) = r(z0) + J D c``, so the least-squares ``c``
    costs one matrix product per difference: it contains keeping the last state
    (``c = 0``) and linear extrapolation (``c = e_1``), and is never worse than either.
    Later states of a smooth transient are predicted to a small fraction of a step's
    change, which the Krylov solve then no longer has to remove (Fischer 1998 projects
    onto previous solutions the same way).
    """
    last = states[-1].ravel()
    r, J = fun(last)
    D = np.column_stack([(states[j + 1] - states[j]).ravel() for j in range(len(states) - 1)])
    JD = np.column_stack([J.matvec(D[:, j]) for j in range(D.shape[1])])
    # least squares on the few columns themselves (the normal equations would square
    # their condition number, and the differences of a smooth march are nearly parallel)
    c = np.linalg.lstsq(JD, -r, rcond=None)[0]
    # the residual there is known without another evaluation (the residual is affine)
    return last + D @ c, (r + JD @ c, J)


@library_threads(size=dense_unknowns)
def march(
    system,
    eps,
    Theta0,
    dt=None,
    n_steps=None,
    *,
    times=None,
    t0=None,
    constraint=None,
    sensitivities=False,
    tol=1e-10,
    maxiter=30,
    strict=False,
    solver="auto",
    keep_factors=False,
    guess=None,
    scheme=None,
    method=None,
):
    """Integrate :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, \\lambda, t) = 0` with fixed steps
    (``dt``, ``n_steps``) or on a given grid (``times``).

    Parameters
    ----------
    system : GalerkinSystem
        Must have a mass matrix ``M``.
    eps : (n_eps,) array_like
    Theta0 : (N, P) or (N,) array_like
        Initial state (independent of :math:`\\epsilon`).
    dt : float
    n_steps : int
    times : (n_steps + 1,) array_like, optional
        Instead of ``dt`` and ``n_steps``: the step points :math:`t_0 < t_1 < \\dots`, any
        spacing; ``Theta0`` is the state at ``times[0]`` and step ``s`` goes from
        ``times[s]`` to ``times[s + 1]`` by the variable-step form of ``method``
        (:meth:`.base.Stepper.grid_rule`). Keep the step ratios below :math:`1 + \\sqrt 2`
        for BDF2 (:func:`.grids.choose_steps` makes such grids).
    t0 : float
        Time of ``Theta0`` (default 0; with ``times``, ``times[0]``).
    constraint : (M_obs, V), optional
        Data constraint at every step, ``V`` of shape (n_steps + 1, C) with row ``t`` the
        data at time ``t0 + t dt`` (or ``times[t]``; row 0 unused). :math:`\\lambda_t` become unknowns
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
    scheme : {"euler", "bdf2"}, optional
        The older name of ``method`` (same values, same behaviour).
    method : {"euler", "bdf2"}, optional
        The method (:data:`.methods.METHODS`; default ``"euler"``): backward Euler
        (:mod:`.euler`, first order, the paper's) or BDF2 (:mod:`.bdf2`, second order,
        L-stable, started by one backward-Euler step). Sensitivities, the data
        constraint and the adjoint (:meth:`Trajectory.adjoint_gradient`) are those of
        the method that ran.

    Notes
    -----
    Small systems are marched by a compiled kernel (:mod:`..solve._kernels`) with the same
    maths and no Python work per step when the solve plan (:mod:`..solve.plan`) says so:
    ``P = 1`` with the dense solver (``Trajectory.solver`` then reads
    ``"dense (compiled)"``), or a nonlinear one-germ ``P > 1`` system with GMRES and the
    nodal preconditioner (``"gmres+nodal (compiled)"``). ``solver={"compiled": False}``
    takes the generic path, ``True`` demands a kernel. The kernels march backward Euler
    only; ``Trajectory.plan.reason`` says why a march took the generic path.

    Returns
    -------
    Trajectory
    """
    eps = system.check_eps(eps)
    times, dt, n_steps, t0 = time_grid(times, dt, n_steps, t0)
    uniform = dt is not None
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    method = check_method(method, scheme)
    N, P = system.shape
    Theta0 = system.check_initial_state(Theta0)
    M_obs, V = check_constraint(system, constraint, n_rows=n_steps + 1)
    constrained = M_obs is not None
    C = system.n_forces if constrained else 0
    if system.M is None:
        system.mass_matrix()  # raises the "no mass matrix" error
    opts = solver_options(solver)
    plan = dict(
        constrained=constrained, steady=False, keep_factors=keep_factors, scheme=method,
        uniform=uniform,
    )  # fmt: skip
    linear = LinearSolver(system, opts, **plan)
    if guess is not None:
        if not isinstance(guess, Trajectory) or guess.Theta.shape != (n_steps + 1, N, P):
            raise ValueError(
                f"`guess` must be a Trajectory of shape {(n_steps + 1, N, P)} (a previous "
                "march on the same grid)"
            )
        if constrained and guess.lam.shape != (n_steps + 1, C):
            raise ValueError("`guess` must come from a march under the same data constraint")
    stepper = METHODS[method]
    rules = stepper.rules(dt, n_steps) if uniform else stepper.rules(times=times)
    args = (system, eps, Theta0, dt, n_steps, t0, M_obs, V, sensitivities, tol, maxiter)
    if linear.plan.path != "generic":
        traj = compiled_march(linear, *args, keep_factors, guess, method, rules)
        if traj is not None:
            if strict and not traj.success:
                raise ConvergenceError(traj.message)
            return traj
        # the kernel did not compile with this numba: the same solve on the generic path
        linear = LinearSolver(system, solver_options(opts, compiled=False), **plan)
    if uniform:
        times = t0 + dt * np.arange(n_steps + 1)
    setup = MarchSetup(system, eps, linear, rules, uniform, M_obs)
    return setup.run(Theta0, times, V, sensitivities, tol, maxiter, strict, keep_factors,
                     guess, method)  # fmt: skip


class MassProducts:
    """:math:`(M\\otimes\\mathbb E[\\Psi\\Psi^T])X/h` and its transpose, chosen once per
    march: one dense matrix (a given grid), one dense matrix per distinct step length
    (a fixed grid), or matrix-free products (the iterative and structured solvers)."""

    def __init__(self, system, dense, uniform, rules):
        self.system = system
        self.N, self.P = system.shape
        self.kind = "matrix-free"
        if dense and not uniform:
            self.kind = "full"  # one matrix, not one per distinct step length
            self.M = system.mass_matrix()
        elif dense:
            self.kind = "scaled"
            self.Mh = {h: system.mass_matrix() / h for h in {h for h, _ in rules}}

    def __call__(self, X, h):
        """:math:`(M/h)X` for ``X`` of shape (NP,) or (NP, m)."""
        if self.kind == "full":
            return (self.M @ X) / h
        if self.kind == "scaled":
            return self.Mh[h] @ X
        Xr = X.reshape(self.N, self.P, -1)
        apply = self.system.apply_mass
        out = np.stack([apply(Xr[:, :, j]) for j in range(Xr.shape[2])], -1)
        return out.reshape(X.shape) / h

    def transpose(self, x, h):
        """:math:`(M/h)^T x` for ``x`` of shape (NP,) (the adjoint's carry)."""
        if self.kind == "full":
            return (self.M.T @ x) / h
        if self.kind == "scaled":
            return self.Mh[h].T @ x
        return self.system.apply_mass(x.reshape(self.N, self.P), transpose=True).ravel() / h


class StepProblem:
    """The nonlinear system of one step, :math:`(M/h)(\\Theta_{s+1} - \\psi_s) +
    R(\\Theta_{s+1}, \\lambda_{s+1}, t_{s+1}) = 0` (and, under a data constraint,
    :math:`\\mathcal M\\Theta_{s+1} - v_{s+1} = 0`): called with the unknowns ``z`` it
    returns the residual and the Jacobian operator, :meth:`scale` is Newton's residual
    scale."""

    def __init__(self, setup, prev, t1, h, v1=None):
        self.setup, self.prev, self.t1, self.h, self.v1 = setup, prev, t1, h, v1

    def __call__(self, z):
        st = self.setup
        system, eps, n, t1, h = st.system, st.eps, st.n, self.t1, self.h
        if st.constrained:
            T1, l1 = z[:n].reshape(st.N, st.P), z[n:]
            r1 = st.mass(z[:n] - self.prev, h) + system.residual(T1, eps, l1, t1).ravel()
            J = st.bordered(system.jacobian_operator(T1, eps, t1, dt=h))
            return np.concatenate([r1, st.Cth @ z[:n] - self.v1]), J
        T1 = z.reshape(st.N, st.P)
        r1 = st.mass(z - self.prev, h) + system.residual(T1, eps, None, t1).ravel()
        return r1, system.jacobian_operator(T1, eps, t1, dt=h)

    def scale(self, z):
        st = self.setup
        system, n, constrained = st.system, st.n, st.constrained
        T1 = z[:n].reshape(st.N, st.P)
        mag = np.abs(T1) + np.abs(self.prev.reshape(st.N, st.P))
        sc = system.residual_scale(T1, st.eps, z[n:] if constrained else None, self.t1)
        sc += system.mass_scale(mag) / self.h
        return sc + (constraint_scale(st.Cth, z[:n], self.v1) if constrained else 0.0)


class Sensitivities:
    """:math:`\\partial\\Theta_s/\\partial\\epsilon` (and :math:`\\partial\\lambda_s/
    \\partial\\epsilon`) of a march: each step one solve with the step's factorized
    Jacobian, :math:`(M/h_s + J)S_{s+1} = (M/h_s)\\,\\partial\\psi_s/\\partial\\epsilon -
    R_\\epsilon` (Eqs. discrete_sens, discrete_sens_ecfm)."""

    def __init__(self, setup, n_steps):
        self.setup = setup
        n_eps, C = setup.system.n_eps, setup.C
        self.dTh = np.zeros((n_steps + 1, setup.n, n_eps))
        self.dlam = np.zeros((n_steps + 1, C, n_eps)) if setup.constrained else None

    def advance(self, s, rule, T1, t1, lu):
        """Step ``s`` by the rule ``(h, w)``, from the converged state ``T1`` at ``t1``
        with the step's factor ``lu``."""
        st = self.setup
        h, w = rule
        dprev = Stepper.combine(w, self.dTh, s)
        rhs = st.mass(dprev, h) - st.system.eps_jacobian(T1, st.eps, t1)
        if st.constrained:
            rhs = np.vstack([rhs, np.zeros((st.C, st.system.n_eps))])
        S = lu.solve(rhs)
        self.dTh[s + 1] = S[: st.n]
        if st.constrained:
            self.dlam[s + 1] = S[st.n :]

    def arrays(self, k):
        """``(dTheta, dlam)`` of the first ``k`` states, ``dTheta`` (k, N, P, n_eps)."""
        st = self.setup
        dTh = self.dTh[:k].reshape(k, st.N, st.P, st.system.n_eps)
        return dTh, None if self.dlam is None else self.dlam[:k]


class MarchSetup:
    """What a march fixes before its first step: the mass products, the linear solver,
    the step rules and the border of the data constraint; :meth:`run` marches."""

    def __init__(self, system, eps, linear, rules, uniform, M_obs):
        self.system, self.eps, self.linear, self.rules = system, eps, linear, rules
        self.N, self.P = system.shape
        self.n = self.N * self.P
        self.mass = MassProducts(system, linear.name == "dense", uniform, rules)
        self.constrained = M_obs is not None
        self.C = system.n_forces if self.constrained else 0
        self.Cth = self.bordered = None
        if self.constrained:
            self.Cth = system.constraint_jacobian(M_obs)
            self.bordered = Bordered(system.lam_jacobian(), self.Cth)
        # a Krylov solve of a linear step starts from the best combination of the last states
        self.warm = system.is_linear and linear.iterative

    def start(self, s, problem, Th, lam, guess):
        """Newton's start of step ``s``: ``(z0, first)`` (``first`` the residual and
        Jacobian at ``z0`` when a warm start evaluated them)."""
        if self.constrained:
            if guess is not None:
                return np.concatenate([guess.Theta[s + 1].ravel(), guess.lam[s + 1]]), None
            return np.concatenate([Th[s].ravel(), lam[s]]), None
        if guess is not None:
            return guess.Theta[s + 1].ravel(), None
        if self.warm and s > 0:
            return warm_start(problem, Th[max(0, s + 1 - WARM_START_STATES) : s + 1])
        return Th[s].ravel(), None

    def run(self, Theta0, times, V, sensitivities, tol, maxiter, strict, keep_factors, guess,
            method):  # fmt: skip
        """March from ``Theta0`` over ``times``; a :class:`Trajectory`."""
        system, linear, n, rules = self.system, self.linear, self.n, self.rules
        n_steps = len(rules)
        Th = np.zeros((n_steps + 1, self.N, self.P))
        Th[0] = Theta0
        flat = Th.reshape(n_steps + 1, n)  # a view: the states as vectors
        lam = np.zeros((n_steps + 1, self.C))
        sens = Sensitivities(self, n_steps) if sensitivities else None
        nits = np.zeros(n_steps, dtype=int)
        factors = [] if keep_factors else None
        for s in range(n_steps):
            t1 = times[s + 1]
            h, w = rules[s]
            # the combination of earlier states the step starts from (backward Euler: the last)
            prev = Stepper.combine(w, flat, s)
            problem = StepProblem(self, prev, t1, h, V[s + 1] if self.constrained else None)
            z0, first = self.start(s, problem, Th, lam, guess)
            z, lu, info = newton(
                problem, z0, tol, maxiter, linear_solver=linear, scale=problem.scale, first=first
            )
            nits[s] = info.nit
            if not info.success:
                msg = (
                    f"{system.name}: Newton failed at step {s + 1} (t={t1:.6g}) with "
                    f"||R||={info.residual_norm:.3e}: {info.message}"
                )
                if strict:
                    raise ConvergenceError(msg)
                k = s + 1
                dTh, dlam = (None, None) if sens is None else sens.arrays(k)
                return Trajectory(times[:k], Th[:k], lam[:k], dTh, dlam, False, msg, s + 1,
                                  nits[: s + 1], linear.record.solver,
                                  list(linear.record.iterations), status=info.status,
                                  plan=linear.plan, scheme=method)  # fmt: skip
            Th[s + 1] = z[:n].reshape(self.N, self.P)
            if keep_factors:
                factors.append(lu)
            if self.constrained:
                lam[s + 1] = z[n:]
            if sens is not None:
                sens.advance(s, rules[s], Th[s + 1], t1, lu)
        dTh, dlam = (None, None) if sens is None else sens.arrays(n_steps + 1)
        adjoint = None
        if keep_factors:
            eps = self.eps
            adjoint = generic_adjoint(system, eps, Th, times, factors, self.mass.transpose, rules)
        return Trajectory(times, Th, lam, dTh, dlam, True, "converged at every step", None, nits,
                          linear.record.solver, list(linear.record.iterations), adjoint,
                          plan=linear.plan, scheme=method)  # fmt: skip
