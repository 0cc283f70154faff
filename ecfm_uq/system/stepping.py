"""Fixed-step marches with forward sensitivities and kept factors for the adjoint.

Steady problems solve :math:`R(\\Theta;\\epsilon,\\lambda) = 0`, optionally augmented with
the data constraint :math:`\\mathcal M\\,\\mathbb E[\\theta] - v = 0` for the unknowns
:math:`(\\Theta, \\lambda)` (the ECFM inner problem, Eq. ecfm and ecfm_solve).
Dynamic problems march

.. math::

    \\frac{M}{\\Delta t}(\\Theta_{t+1} - \\Theta_t) + R(\\Theta_{t+1}; \\epsilon,
    \\lambda_{t+1}, t_{t+1}) = 0

(Eq. backward_euler), with the same optional constraint at every step, or by the
second-order BDF2 (``scheme="bdf2"``, :mod:`.schemes`: each step the same solve from a
combination of the last two states). Forward
sensitivities (Eqs. discrete_sens, discrete_sens_ecfm, stochastic_sens) reuse the
factorized Jacobian at the converged state: after convergence the Jacobian is evaluated
and factorized once more, used for one last Newton correction and for all
sensitivity right-hand sides.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array, check_int, check_positive
from ..errors import ConvergenceError
from ..threads import library_threads
from .compiled import compiled_march
from .linear import LinearSolver
from .nonlinear import Bordered, _check_constraint, _constraint_scale, newton
from .options import solver_options
from .plan import WARM_START_STATES, dense_unknowns
from .schemes import check_scheme, check_times, grid_rules, step_rule
from .trajectory import Trajectory, _generic_adjoint


def _warm_start(fun, states):
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


def _time_grid(times, dt, n_steps, t0):
    """``(times, dt, n_steps, t0)`` of a march: ``times`` ``None`` for fixed steps, ``dt``
    ``None`` for a given grid; a ``ValueError`` names what is missing or contradictory."""
    if times is None:
        if dt is None or n_steps is None:
            raise ValueError("pass `dt` and `n_steps` (fixed steps) or `times` (a time grid)")
        dt = check_positive("dt", dt)
        n_steps = check_int("n_steps", n_steps, minimum=1)
        t0 = 0.0 if t0 is None else float(as_finite_array("t0", t0, ndim=0))
        return None, dt, n_steps, t0
    if dt is not None or n_steps is not None or t0 is not None:
        raise ValueError(
            "pass either `times` (the grid; it starts at the time of Theta0) or `dt`, "
            "`n_steps` and `t0`, not both"
        )
    times = check_times(times)
    return times, None, times.size - 1, float(times[0])


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
    scheme="euler",
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
        ``times[s]`` to ``times[s + 1]`` by the variable-step form of ``scheme``
        (:func:`.schemes.grid_rules`). Keep the step ratios below :math:`1 + \\sqrt 2`
        for BDF2 (:func:`.step_control.choose_steps` makes such grids).
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
    scheme : {"euler", "bdf2"}
        The time scheme (:mod:`.schemes`): backward Euler (first order, the default and
        the paper's) or BDF2 (second order, L-stable, started by one backward-Euler
        step). Sensitivities, the data constraint and the adjoint
        (:meth:`Trajectory.adjoint_gradient`) are those of the scheme that ran.

    Notes
    -----
    Small systems are marched by a compiled kernel (:mod:`._kernels`) with the same
    maths and no Python work per step when the solve plan (:mod:`.plan`) says so:
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
    times, dt, n_steps, t0 = _time_grid(times, dt, n_steps, t0)
    uniform = dt is not None
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    scheme = check_scheme(scheme)
    N, P = system.shape
    n = N * P
    Theta0 = system.check_initial_state(Theta0)
    M_obs, V = _check_constraint(system, constraint, n_rows=n_steps + 1)
    constrained = M_obs is not None
    C = system.n_forces if constrained else 0
    if system.M is None:
        system.mass_matrix()  # raises the "no mass matrix" error
    opts = solver_options(solver)
    plan = dict(
        constrained=constrained, steady=False, keep_factors=keep_factors, scheme=scheme,
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
    args = (system, eps, Theta0, dt, n_steps, t0, M_obs, V, sensitivities, tol, maxiter)
    if linear.plan.path != "generic":
        traj = compiled_march(linear, *args, keep_factors, guess, scheme)
        if traj is not None:
            if strict and not traj.success:
                raise ConvergenceError(traj.message)
            return traj
        # the kernel did not compile with this numba: the same solve on the generic path
        linear = LinearSolver(system, solver_options(opts, compiled=False), **plan)
    # every step of every scheme is a backward-Euler-like solve of effective length h
    if uniform:
        rules = [step_rule(scheme, s, dt) for s in range(n_steps)]
    else:
        rules = grid_rules(scheme, times)
    if linear.name == "dense" and not uniform:
        M_full = system.mass_matrix()  # one matrix, not one per distinct step length

        def mass(X, h):
            return (M_full @ X) / h

        def mass_T(x, h):
            return (M_full.T @ x) / h
    elif linear.name == "dense":
        Mh = {h: system.mass_matrix() / h for h in {h for h, _ in rules}}

        def mass(X, h):  # (NP,) or (NP, m)
            return Mh[h] @ X

        def mass_T(x, h):
            return Mh[h].T @ x
    else:

        def mass(X, h):
            Xr = X.reshape(N, P, -1)
            out = np.stack([system.apply_mass(Xr[:, :, j]) for j in range(Xr.shape[2])], -1)
            return out.reshape(X.shape) / h

        def mass_T(x, h):
            return system.apply_mass(x.reshape(N, P), transpose=True).ravel() / h

    if constrained:
        Cth = system.constraint_jacobian(M_obs)
        Jl = system.lam_jacobian()
        bordered = Bordered(Jl, Cth)
    # a Krylov solve of a linear step starts from the best combination of the last states
    warm = system.is_linear and linear.iterative

    if uniform:
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
        h, w = rules[s]
        last = Th[s].ravel()
        # the combination of earlier states the step starts from (backward Euler: the last)
        prev = last if len(w) == 1 else sum(wj * Th[s - j].ravel() for j, wj in enumerate(w))
        first = None

        if constrained:
            v1 = V[s + 1]

            def fun(z, prev=prev, t1=t1, v1=v1, h=h):
                T1, l1 = z[:n].reshape(N, P), z[n:]
                r1 = mass(z[:n] - prev, h) + system.residual(T1, eps, l1, t1).ravel()
                J = bordered(system.jacobian_operator(T1, eps, t1, dt=h))
                return np.concatenate([r1, Cth @ z[:n] - v1]), J

            z0 = np.concatenate([last, lam[s]])
            if guess is not None:
                z0 = np.concatenate([guess.Theta[s + 1].ravel(), guess.lam[s + 1]])
        else:

            def fun(z, prev=prev, t1=t1, h=h):
                T1 = z.reshape(N, P)
                r1 = mass(z - prev, h) + system.residual(T1, eps, None, t1).ravel()
                return r1, system.jacobian_operator(T1, eps, t1, dt=h)

            z0 = last if guess is None else guess.Theta[s + 1].ravel()
            if warm and guess is None and s > 0:
                z0, first = _warm_start(fun, Th[max(0, s + 1 - WARM_START_STATES) : s + 1])

        def scale(z, prev=prev, t1=t1, v1=V[s + 1] if constrained else None, h=h):
            T1 = z[:n].reshape(N, P)
            mag = np.abs(T1) + np.abs(prev.reshape(N, P))
            sc = system.residual_scale(T1, eps, z[n:] if constrained else None, t1)
            sc += system.mass_scale(mag) / h
            return sc + (_constraint_scale(Cth, z[:n], v1) if constrained else 0.0)

        z, lu, info = newton(
            fun,
            z0,
            tol,
            maxiter,
            linear_solver=linear,
            scale=scale,
            first=first,
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
                status=info.status,
                plan=linear.plan,
                scheme=scheme,
            )
        Th[s + 1] = z[:n].reshape(N, P)
        if keep_factors:
            factors.append(lu)
        if constrained:
            lam[s + 1] = z[n:]
        if sensitivities:
            T1 = Th[s + 1]
            dprev = dTh[s] if len(w) == 1 else sum(wj * dTh[s - j] for j, wj in enumerate(w))
            rhs = mass(dprev, h) - system.eps_jacobian(T1, eps, t1)
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
        _generic_adjoint(system, eps, Th, times, factors, mass_T, rules) if keep_factors else None,
        plan=linear.plan,
        scheme=scheme,
    )
