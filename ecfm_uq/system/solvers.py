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

import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from .._validation import as_finite_array, check_int, check_positive
from ..errors import ConvergenceError


@dataclass
class NewtonInfo:
    """Outcome of one Newton solve."""

    success: bool
    nit: int
    residual_norm: float
    message: str


def _factor(J):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sla.LinAlgWarning)
        lu = sla.lu_factor(J, check_finite=False)
    # lu_factor only warns on exact singularity; detect it ourselves
    d = np.abs(np.diag(lu[0]))
    if not np.all(np.isfinite(d)) or d.min() <= 1e-14 * max(d.max(), 1e-300):
        return None
    return lu


class _DenseFactor:
    """LU factors of a dense Jacobian."""

    def __init__(self, lu):
        self.lu = lu

    def solve(self, rhs):
        return sla.lu_solve(self.lu, rhs, check_finite=False)


class _BlockFactor:
    """Factors of a decoupled stochastic Galerkin system (see GalerkinSystem.decoupling).

    Solves :math:`\\sum_q c_q K_q X G_q = B` for ``X`` as ``P`` independent ``N x N``
    solves in the common eigenbasis ``Q`` of the couplings.
    """

    def __init__(self, Ks, coefs, Q, D):
        self.Q = Q
        self.N = Ks[0].shape[0]
        self.P = Q.shape[0]
        self.factors = []
        for p in range(self.P):
            Ap = sum(c * d * K for c, d, K in zip(coefs, D[:, p], Ks, strict=True))
            lu = _factor(Ap)
            if lu is None:
                raise np.linalg.LinAlgError(f"decoupled block {p} is singular")
            self.factors.append(lu)

    def solve(self, rhs):
        rhs = np.asarray(rhs, dtype=float)
        m = rhs.shape[1] if rhs.ndim == 2 else None
        B = rhs.reshape(self.N, self.P, -1)
        Bh = np.einsum("ikm,kp->ipm", B, self.Q)
        Xh = np.empty_like(Bh)
        for p, lu in enumerate(self.factors):
            Xh[:, p, :] = sla.lu_solve(lu, Bh[:, p, :], check_finite=False)
        X = np.einsum("ipm,kp->ikm", Xh, self.Q)
        return X.reshape(self.N * self.P, m) if m is not None else X.reshape(-1)


def _solve_decoupled(system, eps, lam, tol, maxiter):
    """Direct solve of a linear, decoupled system with iterative refinement.

    Returns ``(Theta, factor, NewtonInfo)``; refinement steps (the same factors applied
    to the residual, i.e. Newton on a linear system) count as iterations, so an
    ill-conditioned system near a singular point still reaches ``tol`` when it can.
    """
    from .terms import LinearTerm

    Q, D = system.decoupling()
    lin = [t for t in system.terms if isinstance(t, LinearTerm)]
    factor = _BlockFactor([t.K for t in lin], [t.coef.value(eps) for t in lin], Q, D)
    Theta = system.zeros()
    rnorm = np.inf
    for k in range(maxiter + 1):
        r = system.residual(Theta, eps, lam)
        rnorm = float(np.linalg.norm(r))
        if not np.isfinite(rnorm):
            return Theta, factor, NewtonInfo(False, k, rnorm, "residual became non-finite")
        if rnorm < tol:
            return Theta, factor, NewtonInfo(True, k, rnorm, "converged (decoupled direct solve)")
        Theta = Theta - factor.solve(r.ravel()).reshape(system.shape)
    msg = f"decoupled direct solve: ||R||={rnorm:.3e} >= tol after {maxiter} refinements"
    return Theta, factor, NewtonInfo(False, maxiter, rnorm, msg)


def newton(fun, z0, tol=1e-10, maxiter=50):
    """Newton's method on ``fun(z) -> (r, J)``.

    Returns ``(z, factor, info)`` where ``factor.solve(rhs)`` solves with the Jacobian
    at the returned ``z`` (``None`` when the iteration failed).

    Convergence is declared when :math:`\\|r\\|_2 < \\mathrm{tol}`; the Jacobian is then
    evaluated at the converged point, factorized, and used for one final correction
    (so the returned ``lu`` is exact for sensitivities).
    """
    z = np.array(z0, dtype=float)
    rnorm = np.inf
    for k in range(maxiter + 1):
        r, J = fun(z)
        rnorm = float(np.linalg.norm(r))
        if not np.isfinite(rnorm):
            return z, None, NewtonInfo(False, k, rnorm, "residual became non-finite")
        lu = _factor(J)
        if lu is None:
            return z, None, NewtonInfo(False, k, rnorm, "Jacobian is singular or not finite")
        dz = sla.lu_solve(lu, r, check_finite=False)
        z = z - dz
        if rnorm < tol:
            return z, _DenseFactor(lu), NewtonInfo(True, k, rnorm, "converged")
    return z, None, NewtonInfo(False, maxiter, rnorm, f"no convergence in {maxiter} iterations")


def _check_constraint(system, constraint, n_rows=None):
    if constraint is None:
        return None, None
    if system.Gamma is None:
        raise ValueError("a data `constraint` needs constraint forces: build the system with Gamma")
    try:
        M_obs, v = constraint
    except (TypeError, ValueError) as e:
        raise TypeError("`constraint` must be a pair (M_obs, v)") from e
    M_obs = as_finite_array("M_obs", M_obs, shape=(system.n_forces, system.N))
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
    _lu: object = field(default=None, repr=False)
    _M_obs: object = field(default=None, repr=False)

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
    structure="auto",
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
        ``M_obs`` (C, N) and ``v`` (C,); :math:`\\lambda` becomes an unknown.
    Theta0 : (N, P) array_like, optional
        Initial guess (zero by default).
    tol : float
        Newton tolerance on :math:`\\|R\\|_2`.
    maxiter : int
    strict : bool
        Raise :class:`ConvergenceError` instead of returning ``success=False``.
    structure : {"auto", "dense"}
        ``"auto"`` solves a linear system whose stochastic couplings share an eigenbasis
        as ``P`` decoupled ``N x N`` systems (no dense ``(NP)^2`` matrix; see
        :meth:`GalerkinSystem.decoupling`); ``"dense"`` always uses the dense Newton
        block solve.

    Returns
    -------
    SteadySolution
    """
    eps = system.check_eps(eps)
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    M_obs, v = _check_constraint(system, constraint)
    N, P = system.shape
    n = N * P
    Theta0 = system.zeros() if Theta0 is None else as_finite_array("Theta0", Theta0, shape=(N, P))
    if structure not in ("auto", "dense"):
        raise ValueError(f"unknown `structure` {structure!r}; choose 'auto' or 'dense'")
    if M_obs is None and structure == "auto" and system.decoupling() is not None:
        lam = system.check_lam(lam)
        try:
            Theta, factor, info = _solve_decoupled(system, eps, lam, tol, maxiter)
        except np.linalg.LinAlgError as e:
            Theta, factor, info = system.zeros(), None, NewtonInfo(False, 1, np.inf, str(e))
        sol = SteadySolution(
            system,
            eps,
            Theta,
            lam,
            info.success,
            info.nit,
            info.residual_norm,
            info.message,
            _lu=factor if info.success else None,
        )
        if strict and not sol.success:
            raise ConvergenceError(
                f"{system.name}: steady solve failed at eps={eps}: {info.message}"
            )
        return sol
    if M_obs is None:
        lam = system.check_lam(lam)

        def fun(z):
            Th = z.reshape(N, P)
            return system.residual(Th, eps, lam).ravel(), system.jacobian(Th, eps)

        z, lu, info = newton(fun, Theta0.ravel(), tol, maxiter)
        Theta, lam_out = z.reshape(N, P), lam
    else:
        Cth = np.kron(M_obs, system.E1[None, :])
        Jl = system.lam_jacobian()
        C = system.n_forces

        def fun(z):
            Th, lm = z[:n].reshape(N, P), z[n:]
            r = np.concatenate([system.residual(Th, eps, lm).ravel(), Cth @ z[:n] - v])
            J = np.block([[system.jacobian(Th, eps), Jl], [Cth, np.zeros((C, C))]])
            return r, J

        z0 = np.concatenate([Theta0.ravel(), np.zeros(C)])
        z, lu, info = newton(fun, z0, tol, maxiter)
        Theta, lam_out = z[:n].reshape(N, P), z[n:]
    sol = SteadySolution(
        system,
        eps,
        Theta,
        lam_out,
        info.success,
        info.nit,
        info.residual_norm,
        info.message,
        constrained=M_obs is not None,
        _lu=lu,
        _M_obs=M_obs,
    )
    if strict and not sol.success:
        raise ConvergenceError(f"{system.name}: steady Newton failed at eps={eps}: {info.message}")
    return sol


def solve_continuation(
    system, eps_start, eps_end, *, Theta0=None, max_halvings=6, tol=1e-10, maxiter=50, strict=False
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
            sol = solve_steady(system, e0 + t * (e1 - e0), Theta0=Theta, tol=tol, maxiter=maxiter)
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
    Mdt = system.mass_matrix() / dt
    if constrained:
        Cth = np.kron(M_obs, system.E1[None, :])
        Jl = system.lam_jacobian()

    times = t0 + dt * np.arange(n_steps + 1)
    Th = np.zeros((n_steps + 1, N, P))
    Th[0] = Theta0
    lam = np.zeros((n_steps + 1, C))
    dTh = np.zeros((n_steps + 1, n, system.n_eps)) if sensitivities else None
    dlam = np.zeros((n_steps + 1, C, system.n_eps)) if sensitivities and constrained else None
    nits = np.zeros(n_steps, dtype=int)

    for s in range(n_steps):
        t1 = times[s + 1]
        prev = Th[s].ravel()

        if constrained:
            v1 = V[s + 1]

            def fun(z, prev=prev, t1=t1, v1=v1):
                T1, l1 = z[:n].reshape(N, P), z[n:]
                r1 = Mdt @ (z[:n] - prev) + system.residual(T1, eps, l1, t1).ravel()
                J = np.block([[Mdt + system.jacobian(T1, eps, t1), Jl], [Cth, np.zeros((C, C))]])
                return np.concatenate([r1, Cth @ z[:n] - v1]), J

            z0 = np.concatenate([prev, lam[s]])
        else:

            def fun(z, prev=prev, t1=t1):
                T1 = z.reshape(N, P)
                r1 = Mdt @ (z - prev) + system.residual(T1, eps, None, t1).ravel()
                return r1, Mdt + system.jacobian(T1, eps, t1)

            z0 = prev
        z, lu, info = newton(fun, z0, tol, maxiter)
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
            )
        Th[s + 1] = z[:n].reshape(N, P)
        if constrained:
            lam[s + 1] = z[n:]
        if sensitivities:
            T1 = Th[s + 1]
            rhs = Mdt @ dTh[s] - system.eps_jacobian(T1, eps, t1)
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
    )
