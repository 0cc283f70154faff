"""Data at their own times for a :class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem`:
readings at some steps of the time grid, the integrator stepping between them.

The data times ``t`` are a subset of the step grid :math:`t_0 + k\\Delta t` (:func:`data_steps`
checks it); the step ``dt`` is the integrator's (as fine as its accuracy needs), the data
come when they come.

* The standard fit fits the readings at the data times only (the other steps have no
  datum: their sensitivities and adjoint sources are zero).
* The ECFM force is a function of time on the data's time scale: one force vector
  :math:`\\lambda_j` per data interval :math:`(t_{j-1}, t_j]` (:math:`t_0` the initial
  time), held over every step in it, the per-step forces :math:`F = E\\lambda` with
  :math:`E` the 0/1 expansion matrix. The exact match :math:`\\mathcal M\\,\\mathbb
  E[\\theta(t_j)] = v_j` holds at the data times; for given :math:`\\epsilon` the forces
  are its solution by Newton's method (:class:`IntervalForces`), the force entering the
  march as a known load :math:`\\Gamma\\lambda_j` whose derivative in :math:`\\lambda` the
  march's forward sensitivities carry. The objective is the force function's
  :math:`L^2`, :math:`z = \\tfrac12\\sum_j \\Delta t_j |\\lambda_j|^2` (the same as
  :class:`~ecfm_uq.inverse.problems.ode.OdeProblem`'s ECFM), its gradient the implicit
  derivative :math:`d\\lambda/d\\epsilon = -G_\\lambda^{-1}G_\\epsilon` of the match
  conditions :math:`G(\\lambda, \\epsilon) = 0` (:math:`G_\\lambda` block lower triangular:
  a force acts on its own and later data times only).

With data at every step (``t=None``, the default) nothing here runs: the problem is the
paper's, one force per step solved inside each step's Newton iteration.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import scipy.sparse as sp

from ..._validation import as_finite_array
from ...errors import ConvergenceError
from ...system import Coefficient, GalerkinSystem, LoadTerm, NonlinearTerm, march

__all__ = ["IntervalForces", "data_derivatives", "data_steps", "interval_forces"]

#: Newton iterations of the exact match before the forces are declared not found
MAX_NEWTON = 25


def data_steps(t, t0, dt, n_steps):
    """The step indices ``k`` of data times ``t = t0 + k dt`` on the march's grid.

    Parameters
    ----------
    t : (n_t,) array_like
        Strictly increasing data times in ``[t0, t0 + n_steps dt]``, each on the grid to
        a relative ``1e-9`` of ``dt``.
    t0, dt : float
    n_steps : int

    Returns
    -------
    (n_t,) int ndarray

    Raises
    ------
    ValueError
        Naming ``t``: empty, not increasing (unsorted, or a repeated time), outside the
        march, or a time between two steps (choose ``dt`` dividing the data's spacing).
    """
    t = as_finite_array("t", t, ndim=1)
    if t.size == 0:
        raise ValueError("`t` (the data times) is empty: pass the times of the rows of V")
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.flatnonzero(d <= 0)[0])
        what = "repeated" if d[i] == 0 else "not increasing"
        raise ValueError(
            f"`t` must be strictly increasing: t[{i}]={t[i]:g} is followed by "
            f"t[{i + 1}]={t[i + 1]:g} ({what}); sort the data by time and merge repeated times"
        )
    end = t0 + n_steps * dt
    if t[0] < t0 - 1e-9 * dt or t[-1] > end + 1e-9 * dt:
        bad = t[0] if t[0] < t0 else t[-1]
        raise ValueError(
            f"`t` must lie in the march [t0, t0 + n_steps dt] = [{t0:g}, {end:g}]; "
            f"t={bad:g} does not: raise n_steps, or drop the readings outside"
        )
    x = (t - t0) / dt
    k = np.rint(x).astype(int)
    off = np.abs(x - k) > 1e-9 * np.maximum(1.0, np.abs(x))
    if np.any(off):
        i = int(np.flatnonzero(off)[0])
        raise ValueError(
            f"`t` must be on the step grid t0 + k dt (t0={t0:g}, dt={dt:g}): t[{i}]={t[i]:g} "
            f"is {x[i]:.6g} steps after t0; choose dt dividing the data's spacing (e.g. "
            f"dt = {float(np.min(np.diff(np.r_[t0, t]))):g} / m for an integer m)"
        )
    return k


class IntervalForces:
    """The exact-match forces of a problem with data at some steps, one per data interval.

    Parameters
    ----------
    problem : DynamicInverseProblem
        With ``t`` (data times), a fixed-step scheme, and ``C`` constraint forces
        (``Gamma``) for its ``C`` sensors.

    Attributes
    ----------
    steps : (J,) int ndarray
        The step index of every fitted data time (``V[1:]``'s rows).
    widths : (J,) ndarray
        :math:`\\Delta t_j = t_j - t_{j-1}` (:math:`t_0` the initial time).
    system : GalerkinSystem
        The problem's system with the forces as a load :math:`\\Gamma\\lambda_j` on the steps
        of interval ``j`` and ``J C`` more parameters, :math:`(\\epsilon, \\lambda_1, \\dots,
        \\lambda_J)`, so that one march gives the state and its derivatives in both.
    """

    def __init__(self, problem):
        system = problem.system
        self.n_eps = system.n_eps
        self.steps = np.asarray(problem._rows[1:], dtype=int)
        self.J, self.C = self.steps.size, system.n_forces
        self.widths = problem.dt * np.diff(np.r_[0, self.steps])
        # the interval of every step point k (step k - 1 -> k): j with steps[j-1] < k <= steps[j]
        k = np.arange(problem.n_steps + 1)
        self.interval = np.searchsorted(self.steps, k, side="left")
        self.interval[0] = self.J  # the initial state: no force
        Gamma = system.Gamma.toarray() if sp.issparse(system.Gamma) else np.asarray(system.Gamma)
        load = _IntervalLoad(self, Gamma, problem.t0, problem.dt)
        terms = (*(_first_parameters(term, self.n_eps) for term in system.terms), load)
        self.system = GalerkinSystem(
            terms, self.n_eps + self.J * self.C, basis=system.basis, Gamma=system.Gamma, M=system.M,
            name=f"{system.name} + interval forces",
        )  # fmt: skip

    def at_times(self, times, t0, dt):
        """The interval of the step point at each of ``times`` (``J``: no force)."""
        k = np.rint((np.asarray(times, dtype=float) - t0) / dt).astype(int)
        return self.interval[np.clip(k, 0, self.interval.size - 1)]

    def expand(self, lam):
        """Per-step forces ``(n_steps + 1, ...)`` from the interval forces ``(J, ...)``:
        :math:`E\\lambda` (row 0 and the steps after the last datum: zero)."""
        lam = np.asarray(lam)
        out = np.zeros((self.interval.size,) + lam.shape[1:])
        held = self.interval < self.J
        out[held] = lam[self.interval[held]]
        return out

    def solve(self, problem, eps, sensitivities=False, lam0=None):
        """The forces that match the data at ``eps``, by Newton's method on all intervals.

        Returns
        -------
        traj : Trajectory
            The march with the forces: ``lam`` (n_steps + 1, C) the per-step forces
            :math:`E\\lambda`; with ``sensitivities``, ``dTheta`` and ``dlam`` the total
            derivatives in :math:`\\epsilon` (through the forces).
        lam : (J, C) ndarray
            The force of every data interval.
        dlam : (J, C, n_eps) ndarray or None
            :math:`d\\lambda/d\\epsilon` (with ``sensitivities``).
        G_lam : (J C, J C) ndarray
            The match's derivative in the forces, :math:`\\partial(\\mathcal M\\,\\mathbb
            E[\\theta(t_i)])/\\partial\\lambda_j` (block lower triangular).

        Raises
        ------
        ConvergenceError
            A march fails, or the match is not met in :data:`MAX_NEWTON` iterations.
        """
        ne, J, C = self.n_eps, self.J, self.C
        lam = np.zeros(J * C) if lam0 is None else np.array(lam0, dtype=float).ravel()
        target = problem._in_data_units(problem.V)[1:]  # (J, C)
        scale = max(1.0, float(np.max(np.abs(target))))
        E1 = problem.system.E1
        small = False  # the last Newton step was at round-off: this march is the answer
        last_size = np.inf
        for it in range(MAX_NEWTON + 1):
            traj = march(
                self.system, np.r_[eps, lam], problem.Theta0, problem.dt, problem.n_steps,
                t0=problem.t0, sensitivities=True, tol=problem.solve_tol,
                maxiter=problem.solve_maxiter, strict=True, solver=problem.solver,
                scheme=problem.scheme,
            )  # fmt: skip
            mean = traj.Theta[self.steps] @ E1  # (J, N)
            G = (mean @ problem.M_obs.T - target).ravel()
            dmean = np.einsum("tikm,k->tim", traj.dTheta[self.steps], E1)
            D = np.einsum("cj,tjm->tcm", problem.M_obs, dmean).reshape(J * C, -1)
            G_lam = D[:, ne:]
            size = float(np.max(np.abs(G)))
            if small or size <= 1e-12 * scale:
                break
            if size <= 1e-8 * scale and size > 0.5 * last_size:
                break  # no more progress: the match at the march's own precision
            last_size = size
            if it == MAX_NEWTON:
                raise ConvergenceError(
                    f"the exact match at the data times is not met after {MAX_NEWTON} Newton "
                    f"iterations on the interval forces (largest mismatch "
                    f"{size:.3e}); a finer dt, or parameters nearer the data"
                )
            try:
                step = np.linalg.solve(G_lam, -G)
            except np.linalg.LinAlgError as e:
                raise ConvergenceError(
                    "the interval forces cannot move the readings (singular match "
                    f"Jacobian: {e}); each sensor needs a force that reaches it (Gamma)"
                ) from e
            if not np.all(np.isfinite(step)):
                raise ConvergenceError("the Newton step on the interval forces is not finite")
            lam = lam + step
            small = np.max(np.abs(step)) <= 1e-12 * max(1.0, float(np.max(np.abs(lam))))
        lam_j = lam.reshape(J, C)
        dlam = None
        dTheta = None
        if sensitivities:
            dl = -np.linalg.solve(G_lam, D[:, :ne])  # (J C, n_eps)
            dTheta = traj.dTheta[..., :ne] + traj.dTheta[..., ne:] @ dl
            dlam = dl.reshape(J, C, ne)
        out = dataclasses.replace(
            traj, lam=self.expand(lam_j), dTheta=dTheta,
            dlam=None if dlam is None else self.expand(dlam),
        )  # fmt: skip
        return out, lam_j, dlam, G_lam


def _pad(D, n):
    """``D`` (..., n_eps) with zero columns up to ``n`` (the forces move no model term)."""
    D = np.asarray(D, dtype=float)
    return np.concatenate([D, np.zeros(D.shape[:-1] + (n - D.shape[-1],))], axis=-1)


def _first_parameters(term, n_eps):
    """The system's term, reading only the first ``n_eps`` of the augmented parameters.

    Coefficient terms (``LinearTerm``, ``QuadraticTerm``, a scaled ``LoadTerm``) with the
    library's coefficients read their own indices and differentiate in any number of
    parameters: as they are. A user's callbacks (``NonlinearTerm``, a ``LoadTerm`` of
    ``F(eps, t)``, a ``Coefficient(value, grad)``) see the model's ``eps`` and their
    derivatives get zero columns for the forces.
    """
    if isinstance(term, NonlinearTerm):
        new = copy.copy(term)
        res, jac, deps = term.residual, term.jacobian, term.eps_jacobian_fn
        new.residual = lambda u, w, e: res(u, w, e[:n_eps])
        new.jacobian = lambda u, w, e: jac(u, w, e[:n_eps])
        if deps is not None:
            new.eps_jacobian_fn = lambda u, w, e: _pad(deps(u, w, e[:n_eps]), len(e))
        return new
    coef = getattr(term, "coef", None)
    if isinstance(coef, Coefficient) and coef.indices is None:  # a user's c(eps)
        wrapped = Coefficient(
            lambda e: coef.value(e[:n_eps]),
            lambda e: _pad(coef.grad(e[:n_eps]), len(e)),
            label=coef.label,
        )
        if isinstance(term, LoadTerm):  # its F and dF hold the coefficient: rebuild it
            new = LoadTerm.scaled(term._Ft, wrapped, name=term.name)
            new.size = term.size
            return new
        new = copy.copy(term)
        new.coef = wrapped
        return new
    if isinstance(term, LoadTerm) and term.coef is None:
        F, dF = term.F, term.dF
        new = LoadTerm(
            lambda e, t: F(e[:n_eps], t),
            None if dF is None else (lambda e, t: _pad(dF(e[:n_eps], t), len(e))),
            name=term.name,
        )
        new.size = term.size
        return new
    return term


class _IntervalLoad(LoadTerm):
    """The load :math:`\\Gamma\\lambda_j` on the steps of data interval ``j``, its force
    values the trailing ``J C`` parameters; :meth:`on_grid` tabulates a march's grid at
    once (the compiled march's one call per march, not one per step)."""

    def __init__(self, forces, Gamma, t0, dt):
        self.forces, self.Gamma, self.t0, self.dt = forces, Gamma, t0, dt
        super().__init__(self._force, self._dforce, name="interval forces")
        self.size = Gamma.shape[0]

    def _columns(self, j):
        ne, C = self.forces.n_eps, self.forces.C
        return slice(ne + j * C, ne + (j + 1) * C)

    def _force(self, eps, t):
        j = int(self.forces.at_times([t], self.t0, self.dt)[0])
        if j >= self.forces.J:
            return np.zeros(self.size)
        return self.Gamma @ np.asarray(eps[self._columns(j)], dtype=float)

    def _dforce(self, eps, t):
        D = np.zeros((self.size, len(eps)))
        j = int(self.forces.at_times([t], self.t0, self.dt)[0])
        if j < self.forces.J:
            D[:, self._columns(j)] = self.Gamma
        return D

    def on_grid(self, eps, times, derivative=False):
        """``F`` (n_t, N, P) and ``dF`` (n_t, N, P, n_eps) or ``None``, as
        :meth:`LoadTerm.on_grid`, by interval rather than by time."""
        E1 = self._E1
        J, C, ne = self.forces.J, self.forces.C, self.forces.n_eps
        j = self.forces.at_times(times, self.t0, self.dt)
        held = j < J
        lam = np.asarray(eps[ne:], dtype=float).reshape(J, C)
        per = np.zeros((j.size, C))
        per[held] = lam[j[held]]
        F = (per @ self.Gamma.T)[:, :, None] * E1
        if not derivative:
            return F, None
        dF = np.zeros(F.shape + (len(eps),))
        block = self.Gamma[:, None, :] * E1[None, :, None]  # (N, P, C)
        for i in np.unique(j[held]):
            dF[np.flatnonzero(j == i), :, :, self._columns(i)] = block
        return F, dF


def interval_forces(problem, eps, sensitivities=False):
    """The ECFM of a problem with data times: the march whose force, one per data
    interval, matches the data (:meth:`IntervalForces.solve`, built on first use), warm
    started from the problem's last forces (a cold retry if Newton fails from there).

    Returns
    -------
    ``(traj, lam (J, C), dlam (J, C, n_eps) or None, G_lam (J C, J C))``
    """
    if problem._forces is None:
        problem._forces = IntervalForces(problem)
    last = problem._last.get("ecfm") if problem.warm_start else None
    lam0 = None if last is None else last.lam[problem._rows[1:]]
    try:
        out = problem._forces.solve(problem, eps, sensitivities, lam0)
    except ConvergenceError as e:
        if lam0 is not None:  # forces far from this eps can mislead Newton: retry cold
            del problem._last["ecfm"]
            return interval_forces(problem, eps, sensitivities)
        raise ConvergenceError(
            f"ecfm forward solve at eps={np.array2string(eps)} failed: {e}"
        ) from e
    if problem.warm_start:
        problem._last["ecfm"] = out[0]
    return out


def data_derivatives(problem, eps):
    """The ECFM residual :math:`r = (\\sqrt{\\Delta t_j}\\lambda_j)_j` of a problem with
    data times, its Jacobian in :math:`\\epsilon` and its derivative in the fitted data
    ``V[1:]`` (flattened time by time): the forces move with the data through the match,
    :math:`d\\lambda/dv = G_\\lambda^{-1}` (times ``reading_sigma`` in a copy whitened per
    reading, whose constraint is in the data's units).

    Returns
    -------
    r : (J C,) ndarray
    J : (J C, n_eps) ndarray
    dr_dv : (J C, J C) ndarray
    """
    _, lam, dlam, G_lam = problem._interval_forces(eps, True)
    w = np.repeat(np.sqrt(problem._forces.widths), lam.shape[1])
    du = np.ones(w.size)
    if problem.reading_sigma is not None:
        du = np.asarray(problem.reading_sigma[1:], dtype=float).ravel()
    dr_dv = w[:, None] * np.linalg.solve(G_lam, np.diag(du))
    return w * lam.ravel(), w[:, None] * dlam.reshape(w.size, -1), dr_dv
