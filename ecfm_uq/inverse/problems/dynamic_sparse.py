"""Data at their own times for a :class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem`:
readings at some steps of the time grid, the integrator stepping between them.

The data times ``t`` are a subset of the step grid :math:`t_0 + k\\Delta t` (:func:`data_steps`
checks it); the step ``dt`` is the integrator's (as fine as its accuracy needs), the data
come when they come. With ``scheme="adaptive"`` they are any times (:func:`check_data_times`):
the grid between them is chosen to ``rtol``/``atol`` with every data time a node, then
frozen, and the ECFM below runs on it (the gradients exact for that grid).

The force may be held in another basis in time (``force_basis``,
:mod:`~ecfm_uq.inverse.problems.force_bases`: hat functions or Gaussians at the data
times): :math:`F = E\\lambda` with :math:`E` the basis at the step points, the objective
:math:`\\tfrac12\\lambda^T(G\\otimes I)\\lambda` (:math:`G` the Gram matrix), and with
more basis functions than data intervals the minimum-norm forces that match. What
follows is the default, one force per interval.

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
from .force_bases import basis_matrix, check_force_basis, checked_gram, right_inverse

__all__ = [
    "IntervalForces",
    "check_data_times",
    "data_derivatives",
    "data_steps",
    "interval_forces",
]

#: Newton iterations of the exact match before the forces are declared not found
MAX_NEWTON = 25


def check_data_times(t, t0, end):
    """Data times ``t``: strictly increasing, within ``[t0, end]`` (to a relative
    ``1e-9`` of the span).

    Raises
    ------
    ValueError
        Naming ``t``: empty, not increasing (unsorted, or a repeated time), or outside
        the march.
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
    slack = 1e-9 * (end - t0)
    if t[0] < t0 - slack or t[-1] > end + slack:
        bad = t[0] if t[0] < t0 else t[-1]
        raise ValueError(
            f"`t` must lie in the march [t0, t0 + n_steps dt] = [{t0:g}, {end:g}]; "
            f"t={bad:g} does not: raise n_steps, or drop the readings outside"
        )
    return t


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
        march, or a time between two steps (choose ``dt`` dividing the data's spacing,
        or ``scheme="adaptive"``, whose grid holds any data times).
    """
    t = check_data_times(t, t0, t0 + n_steps * dt)
    x = (t - t0) / dt
    k = np.rint(x).astype(int)
    off = np.abs(x - k) > 1e-9 * np.maximum(1.0, np.abs(x))
    if np.any(off):
        i = int(np.flatnonzero(off)[0])
        raise ValueError(
            f"`t` must be on the step grid t0 + k dt (t0={t0:g}, dt={dt:g}): t[{i}]={t[i]:g} "
            f"is {x[i]:.6g} steps after t0; choose dt dividing the data's spacing (e.g. "
            f"dt = {float(np.min(np.diff(np.r_[t0, t]))):g} / m for an integer m), or "
            "scheme='adaptive' (its grid holds any data times)"
        )
    return k


class IntervalForces:
    """The exact-match forces of a problem with data at some times, in a basis in time.

    Parameters
    ----------
    problem : DynamicInverseProblem
        With ``t`` (data times) or ``scheme="adaptive"`` (its grid frozen) or a
        ``force_basis`` other than ``"constant"``, and ``C`` constraint forces
        (``Gamma``) for its ``C`` sensors.

    Attributes
    ----------
    steps : (J,) int ndarray
        The step index of every fitted data time (``V[1:]``'s rows).
    grid : (n_steps + 1,) ndarray
        The step points (the fixed ``t0 + k dt``, or the frozen adaptive grid).
    widths : (J,) ndarray
        :math:`\\Delta t_j = t_j - t_{j-1}` (:math:`t_0` the initial time).
    E : (n_steps + 1, B) ndarray
        The basis at the step points (:func:`.force_bases.basis_matrix`; row 0, the
        initial state, zero): the per-step forces are ``E @ lam``.
    W : (B C, B C) ndarray
        :math:`G\\otimes I_C`, ``G`` the basis' Gram matrix: the objective is
        :math:`\\tfrac12\\lambda^TW\\lambda`; ``root`` its upper Cholesky factor ``R``
        (:math:`W = R^TR`), the residual ``R lam``.
    system : GalerkinSystem
        The problem's system with the force as a load :math:`\\Gamma F(t_s)` and ``B C``
        more parameters, :math:`(\\epsilon, \\lambda_1, \\dots, \\lambda_B)`, so that one
        march gives the state and its derivatives in both.

    Raises
    ------
    ValueError
        Fewer basis functions than data intervals (the exact match over-determined),
        naming ``force_basis``.
    """

    def __init__(self, problem):
        system = problem.system
        self.n_eps = system.n_eps
        self.steps = np.asarray(problem._rows[1:], dtype=int)
        self.J, self.C = self.steps.size, system.n_forces
        if problem.adaptive:
            self.grid = np.asarray(problem.steps.times, dtype=float)
        else:
            self.grid = problem.t0 + problem.dt * np.arange(problem.n_steps + 1)
        knots = self.grid[problem._rows]
        self.widths = np.diff(knots)
        self.kind, width = check_force_basis(problem.force_basis)
        if self.kind == "constant":  # by step index: exact on any grid
            k = np.arange(self.grid.size)
            interval = np.searchsorted(self.steps, k, side="left")
            self.E = np.zeros((self.grid.size, self.J))
            held = (interval < self.J) & (k > 0)
            self.E[k[held], interval[held]] = 1.0
        else:
            self.E = basis_matrix(self.kind, width, knots, self.grid)
            self.E[0] = 0.0  # the initial state: no step, no force
        self.B = self.E.shape[1]
        if self.B < self.J:
            raise ValueError(
                f"`force_basis` {problem.force_basis!r} has {self.B} functions for {self.J} "
                "data intervals: the exact match has more conditions than forces; use "
                "'constant', 'linear' or an RBF basis centred at the data times"
            )
        self.W = np.kron(checked_gram(self.kind, width, knots), np.eye(self.C))
        self.root = np.linalg.cholesky(self.W).T
        Gamma = system.Gamma.toarray() if sp.issparse(system.Gamma) else np.asarray(system.Gamma)
        load = _BasisLoad(self, Gamma)
        terms = (*(_first_parameters(term, self.n_eps) for term in system.terms), load)
        self.system = GalerkinSystem(
            terms, self.n_eps + self.B * self.C, basis=system.basis, Gamma=system.Gamma,
            M=system.M, name=f"{system.name} + interval forces",
        )  # fmt: skip

    def points(self, times):
        """The step point nearest each of ``times`` (the loads are read at step points)."""
        times = np.atleast_1d(np.asarray(times, dtype=float))
        i = np.clip(np.searchsorted(self.grid, times), 1, self.grid.size - 1)
        left = np.abs(times - self.grid[i - 1]) <= np.abs(self.grid[i] - times)
        return np.where(left, i - 1, i)

    def expand(self, lam):
        """Per-step forces ``(n_steps + 1, ...)`` from the coefficients ``(B, ...)``:
        :math:`E\\lambda` (row 0 zero)."""
        lam = np.asarray(lam)
        return np.tensordot(self.E, lam, axes=(1, 0))

    def _march(self, problem, params):
        grid = dict(dt=problem.dt, n_steps=problem.n_steps, t0=problem.t0)
        scheme = problem.scheme
        if problem.adaptive:
            grid, scheme = dict(times=self.grid), "bdf2"
        return march(
            self.system, params, problem.Theta0, **grid, sensitivities=True,
            tol=problem.solve_tol, maxiter=problem.solve_maxiter, strict=True,
            solver=problem.solver, scheme=scheme,
        )  # fmt: skip

    def solve(self, problem, eps, sensitivities=False, lam0=None):
        """The forces that match the data at ``eps``, by Newton's method on all intervals
        (with more basis functions than intervals: minimum-norm Newton steps, converging
        to the minimum-:math:`L^2` forces that match).

        Returns
        -------
        traj : Trajectory
            The march with the forces: ``lam`` (n_steps + 1, C) the per-step forces
            :math:`E\\lambda`; with ``sensitivities``, ``dTheta`` and ``dlam`` the total
            derivatives in :math:`\\epsilon` (through the forces).
        lam : (B, C) ndarray
            The force coefficients.
        dlam : (B, C, n_eps) ndarray or None
            :math:`d\\lambda/d\\epsilon = -PG_\\epsilon` (with ``sensitivities``), ``P`` the
            right inverse of the match's Jacobian (:func:`.force_bases.right_inverse`):
            exact with one force per interval; with more, the derivative along the match
            linearized (the constraint's curvature dropped) -- ``lam^T W dlam``, the
            objective's gradient, is exact either way (it is :math:`-\\mu^TG_\\epsilon`,
            the multipliers' envelope derivative).
        P : (B C, J C) ndarray
            That right inverse: :math:`d\\lambda/dv` for the data ``V[1:]``.

        Raises
        ------
        ConvergenceError
            A march fails, or the match is not met in :data:`MAX_NEWTON` iterations.
        """
        ne, J, C = self.n_eps, self.J, self.C
        square = self.B == J
        n_lam = self.B * C
        lam = np.zeros(n_lam) if lam0 is None else np.array(lam0, dtype=float).ravel()
        target = problem._in_data_units(problem.V)[1:]  # (J, C)
        scale = max(1.0, float(np.max(np.abs(target))))
        E1 = problem.system.E1
        small = False  # the last Newton step was at round-off: this march is the answer
        last_size = np.inf
        for it in range(MAX_NEWTON + 1):
            traj = self._march(problem, np.r_[eps, lam])
            mean = traj.Theta[self.steps] @ E1  # (J, N)
            G = (mean @ problem.M_obs.T - target).ravel()
            dmean = np.einsum("tikm,k->tim", traj.dTheta[self.steps], E1)
            D = np.einsum("cj,tjm->tcm", problem.M_obs, dmean).reshape(J * C, -1)
            G_lam = D[:, ne:]
            size = float(np.max(np.abs(G)))
            # with more forces than conditions the match alone does not fix them: their
            # Newton steps must have stopped too
            if small or (size <= 1e-12 * scale and (square or it > 0)):
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
                if square:
                    new = lam + np.linalg.solve(G_lam, -G)
                else:  # the minimum-norm forces of the linearized match
                    new = right_inverse(G_lam, self.W) @ (G_lam @ lam - G)
            except np.linalg.LinAlgError as e:
                raise ConvergenceError(
                    "the interval forces cannot move the readings (singular match "
                    f"Jacobian: {e}); each sensor needs a force that reaches it (Gamma)"
                ) from e
            if not np.all(np.isfinite(new)):
                raise ConvergenceError("the Newton step on the interval forces is not finite")
            step = new - lam
            lam = new
            small = np.max(np.abs(step)) <= 1e-12 * max(1.0, float(np.max(np.abs(lam))))
        lam_j = lam.reshape(self.B, C)
        try:
            P = right_inverse(G_lam, self.W)
        except np.linalg.LinAlgError as e:
            raise ConvergenceError(f"the match Jacobian in the forces is singular: {e}") from e
        dlam = None
        dTheta = None
        if sensitivities:
            dl = -P @ D[:, :ne]  # (B C, n_eps)
            dTheta = traj.dTheta[..., :ne] + traj.dTheta[..., ne:] @ dl
            dlam = dl.reshape(self.B, C, ne)
        out = dataclasses.replace(
            traj, lam=self.expand(lam_j), dTheta=dTheta,
            dlam=None if dlam is None else self.expand(dlam),
        )  # fmt: skip
        return out, lam_j, dlam, P


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


class _BasisLoad(LoadTerm):
    """The load :math:`\\Gamma F(t_s)`, :math:`F(t_s) = \\sum_j E_{sj}\\lambda_j` at the
    step point :math:`t_s`, its coefficients the trailing ``B C`` parameters;
    :meth:`on_grid` tabulates a march's grid at once (the compiled march's one call per
    march, not one per step)."""

    def __init__(self, forces, Gamma):
        self.forces, self.Gamma = forces, Gamma
        super().__init__(self._force, self._dforce, name="interval forces")
        self.size = Gamma.shape[0]

    def _lam(self, eps):
        f = self.forces
        return np.asarray(eps[f.n_eps :], dtype=float).reshape(f.B, f.C)

    def _force(self, eps, t):
        row = self.forces.E[self.forces.points([t])[0]]
        return self.Gamma @ (row @ self._lam(eps))

    def _dforce(self, eps, t):
        f = self.forces
        D = np.zeros((self.size, len(eps)))
        row = f.E[f.points([t])[0]]
        D[:, f.n_eps :] = np.kron(row[None, :], self.Gamma)
        return D

    def on_grid(self, eps, times, derivative=False):
        """``F`` (n_t, N, P) and ``dF`` (n_t, N, P, n_eps) or ``None``, as
        :meth:`LoadTerm.on_grid`, from the basis at the step points."""
        f = self.forces
        E = f.E[f.points(times)]  # (n_t, B)
        E1 = self._E1
        F = ((E @ self._lam(eps)) @ self.Gamma.T)[:, :, None] * E1
        if not derivative:
            return F, None
        dF = np.zeros(F.shape + (len(eps),))
        block = np.einsum("tj,nc,p->tnpjc", E, self.Gamma, E1)
        dF[..., f.n_eps :] = block.reshape(F.shape + (f.B * f.C,))
        return F, dF


def interval_forces(problem, eps, sensitivities=False):
    """The ECFM of a problem with data times (or an adaptive grid, or a force basis): the
    march whose force matches the data (:meth:`IntervalForces.solve`, built on first use
    and after every new frozen grid), warm started from the problem's last forces (a cold
    retry if Newton fails from there). With ``scheme="adaptive"`` and no frozen grid, the
    grid is chosen at ``eps`` for the unforced model first (:meth:`freeze_steps`).

    Returns
    -------
    ``(traj, lam (B, C), dlam (B, C, n_eps) or None, P (B C, J C))``
    """
    if problem.adaptive and problem.steps is None:
        problem.freeze_steps(eps)
    if problem._forces is None:
        problem._forces = IntervalForces(problem)
    lam0 = problem._last.get("ecfm-coef") if problem.warm_start else None
    try:
        out = problem._forces.solve(problem, eps, sensitivities, lam0)
    except ConvergenceError as e:
        if lam0 is not None:  # forces far from this eps can mislead Newton: retry cold
            del problem._last["ecfm-coef"]
            return interval_forces(problem, eps, sensitivities)
        raise ConvergenceError(
            f"ecfm forward solve at eps={np.array2string(eps)} failed: {e}"
        ) from e
    if problem.warm_start:
        problem._last["ecfm"] = out[0]
        problem._last["ecfm-coef"] = out[1]
    return out


def data_derivatives(problem, eps):
    """The ECFM residual :math:`r = R\\lambda` (:math:`R^TR = W`, the objective
    :math:`\\tfrac12|r|^2`; one force per interval: :math:`(\\sqrt{\\Delta t_j}\\lambda_j)_j`)
    of a problem with data times, its Jacobian in :math:`\\epsilon` and its derivative in
    the fitted data ``V[1:]`` (flattened time by time): the forces move with the data
    through the match, :math:`d\\lambda/dv = P` (:meth:`IntervalForces.solve`; times
    ``reading_sigma`` in a copy whitened per reading, whose constraint is in the data's
    units).

    Returns
    -------
    r : (B C,) ndarray
    J : (B C, n_eps) ndarray
    dr_dv : (B C, J C) ndarray
    """
    _, lam, dlam, P = problem._interval_forces(eps, True)
    R = problem._forces.root
    du = np.ones(P.shape[1])
    if problem.reading_sigma is not None:
        du = np.asarray(problem.reading_sigma[1:], dtype=float).ravel()
    dr_dv = R @ (P * du[None, :])
    return R @ lam.ravel(), R @ dlam.reshape(lam.size, -1), dr_dv
