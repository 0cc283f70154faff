"""The exact-match ECFM of a user's ODE with its forces in a basis in time spanning the
data intervals: ``options={"force_basis": "linear"}`` (hat functions at the data times)
or ``{"rbf": width}`` (Gaussians centred there), :mod:`~ecfm_uq.inverse.problems.force_bases`.

The force on the forced components is :math:`f(t) = \\sum_j\\phi_j(t)\\lambda_j`, knots
:math:`t_0 < t_1 < \\dots < t_K` (the start and the data times). A hat couples two
intervals, so the forces are not found interval by interval (as the piecewise-constant
ones of :mod:`.ode_forces` are): for given :math:`\\epsilon`, Newton's method on all the
coefficients at once, the integrator (interval by interval, restarted at every knot)
carrying the sensitivities to the parameters and to every coefficient (the coefficients
enter as extra parameters of the right-hand side). With :math:`K + 1` functions for
:math:`K` data times the match does not fix them: the minimum-norm steps converge to the
forces of least :math:`L^2`, :math:`\\tfrac12\\lambda^T(G\\otimes I)\\lambda` with
:math:`G` the Gram matrix, the objective. The least-squares residual is
:math:`R\\lambda` (:math:`R^TR = G\\otimes I`), its Jacobian :math:`-RPH_\\epsilon`
(:math:`P` the match's minimum-norm right inverse): :math:`J^Tr` is the objective's exact
gradient (the multipliers' envelope derivative); :math:`J` itself drops the match's
curvature in the forces.

Not built for these bases: a datum at :math:`t_0` (the constant basis meets it by an
initial jump), the uncertainty and the verdict (reported as not computed), and the dense
forced state (``result.state`` is ``None``). ``result.forces`` holds the forces'
interval means (their integrals over each interval divided by its length).
"""

from __future__ import annotations

import copy

import numpy as np

from ...errors import ConvergenceError
from ..core.details import OdeEcfmDetails
from ..core.drivers import least_squares_scaled
from ..core.fitter import Outcome
from ..core.result import Uncertainty
from ..core.series import ForceSeries
from ..problems.force_bases import (
    basis_matrix,
    check_force_basis,
    checked_gram,
    interval_means,
    n_basis,
    right_inverse,
)
from ..problems.ode import solve_with_sensitivities
from ..statistics.loglik import no_likelihood, remember_last_point
from ..statistics.verdict import check_bounds, no_test

__all__ = ["MAX_NEWTON", "BasisForces", "fit_forces", "fit_ode_basis"]

#: Newton iterations before an exact match is declared failed (per data interval for
#: constant forces, on all the coefficients for a basis)
MAX_NEWTON = 25


class BasisForces:
    """The minimum-norm exact-match forces of an :class:`OdeProblem` in a basis in time.

    Parameters
    ----------
    problem : OdeProblem
        Checked, with no datum at ``t0``.
    forced : (m,) ints
        The forced state components, one per observed column.
    force_basis : {"linear"} or {"rbf": width}
        (``"constant"`` works too: one force per interval, the same forces as
        :class:`~.ode_forces.ExactForces` without a jump.)

    Raises
    ------
    ValueError
        A datum at ``t0``, naming ``force_basis``.
    """

    def __init__(self, problem, forced, force_basis):
        self.problem = problem
        self.F = np.asarray(forced, dtype=int)
        self.kind, self.width = check_force_basis(force_basis)
        if problem.t[0] <= problem.t0:
            raise ValueError(
                f"options['force_basis']={force_basis!r} with a datum at t0={problem.t0:g}: "
                "a force cannot meet it and the initial jump is built for the 'constant' "
                "basis only; drop that reading, or use 'constant'"
            )
        self.knots = np.r_[problem.t0, problem.t]
        self.K, self.m = problem.t.size, self.F.size
        self.B = n_basis(self.kind, self.knots.size)
        n = problem.n_state
        self.EF = np.zeros((n, self.m))
        self.EF[self.F, np.arange(self.m)] = 1.0
        self.W = np.kron(checked_gram(self.kind, self.width, self.knots), np.eye(self.m))
        self.root = np.linalg.cholesky(self.W).T
        self.means = interval_means(self.kind, self.width, self.knots)
        self.proxy = self._forced_problem()
        self.warm = np.zeros(self.B * self.m)

    def _phi(self, t):
        return basis_matrix(self.kind, self.width, self.knots, [t])[0]

    def _forced_problem(self):
        """The problem's ODE with the force :math:`E_F\\sum_j\\phi_j(t)\\lambda_j` added, its
        parameters :math:`(\\epsilon, \\lambda)`."""
        pb, EF, m = self.problem, self.EF, self.m
        proxy = copy.copy(pb)
        rhs = pb.rhs

        def forced_rhs(t, y, e):
            k = len(e) - self.B * m
            lam = np.asarray(e[k:], dtype=float).reshape(self.B, m)
            return np.asarray(rhs(t, y, e[:k]), dtype=float) + EF @ (self._phi(t) @ lam)

        proxy.rhs = forced_rhs
        proxy.vectorized = False
        if pb.jac is not None:
            jac_y, jac_eps = pb.jac

            def forced_jac_eps(t, y, e):
                k = len(e) - self.B * m
                base = np.asarray(jac_eps(t, y, e[:k]), dtype=float).reshape(-1, k)
                return np.hstack((base, np.kron(self._phi(t)[None, :], EF)))

            proxy.jac = (lambda t, y, e: jac_y(t, y, e[: len(e) - self.B * m]), forced_jac_eps)
        return proxy

    def _march(self, eps, lam):
        """The readings present after ``t0`` and their derivatives in ``(eps, lam)``."""
        pb = self.problem
        p, n = eps.size, pb.n_state
        e = np.r_[eps, lam]
        q = e.size
        y = pb.initial_state(eps).astype(float)
        S = np.hstack((pb.initial_sensitivity(eps), np.zeros((n, q - p))))
        T = np.eye(q)
        H = pb.H()
        G, D = [], []
        for k in range(self.K):
            span = (self.knots[k], self.knots[k + 1])
            _, Y, Sk = solve_with_sensitivities(self.proxy, e, span, y, S, T, t_eval=[span[1]])
            y, S = Y[-1], Sk[-1]
            present = pb.mask[k]
            G.append(H[present] @ y - pb.v[k, present])
            D.append(H[present] @ S)
        return np.concatenate(G), np.vstack(D)

    def solve(self, eps):
        """The minimum-norm forces at ``eps``: a dict with ``lam`` (B, m), ``r`` (the
        residual :math:`R\\lambda`), ``J`` (its Jacobian in ``eps``), ``means`` (K, m).

        Raises
        ------
        ConvergenceError
            An integration fails, or the match is not met in :data:`MAX_NEWTON` iterations.
        """
        pb, p = self.problem, eps.size
        lam = self.warm.copy()
        scale = max(1.0, float(np.max(np.abs(pb.v[pb.mask]))))
        accept = 10 * (pb.rtol * scale + float(np.max(pb.atol)))
        for it in range(MAX_NEWTON + 1):
            G, D = self._march(eps, lam)
            A = D[:, p:]
            try:
                P = right_inverse(A, self.W)
            except np.linalg.LinAlgError as e:
                raise ConvergenceError(
                    f"the forces do not move the observed components at eps={eps.tolist()} "
                    f"(singular match Jacobian): {e}"
                ) from e
            new = P @ (A @ lam - G)
            step = new - lam
            small = np.max(np.abs(step), initial=0.0) <= 1e-9 * max(1.0, np.max(np.abs(lam)))
            if np.max(np.abs(G), initial=0.0) <= accept and small:
                break
            if it == MAX_NEWTON:
                raise ConvergenceError(
                    f"Newton on the forces ({self.kind} basis) did not meet the data in "
                    f"{MAX_NEWTON} iterations at eps={eps.tolist()}"
                )
            lam = new
        dlam = -P @ D[:, :p]
        self.warm = lam.copy()
        L = lam.reshape(self.B, self.m)
        return {"lam": L, "r": self.root @ lam, "J": self.root @ dlam, "means": self.means @ L}


def fit_forces(problem, forces, eps0, settings, options):
    """The ECFM's least-squares fit of the residual of ``forces`` (an exact-match force
    model with ``solve(eps) -> {"r", "J", ...}``: :class:`BasisForces`,
    :class:`~.ode_forces.ExactForces`) by the trust region, and the
    :class:`~ecfm_uq.inverse.core.fitter.Outcome` fields every such fit shares.

    Returns
    -------
    out : drivers' Outcome
    common : dict
    """
    p = eps0.size
    if problem.n_data < p:
        raise ValueError(
            f"`data` has {problem.n_data} readings for {p} parameters: fewer data than "
            "parameters cannot determine eps"
        )
    bounds = check_bounds(settings.bounds, p)

    def residual(eps):
        out = forces.solve(eps)
        return out["r"], out["J"], out

    residual = remember_last_point(residual)
    maxiter = 2000 if settings.maxiter is None else settings.maxiter
    try:
        out = least_squares_scaled(residual, eps0, bounds, settings.tol, maxiter, options)
    except ConvergenceError as e:
        raise ConvergenceError(f"fit: {e}") from e
    common = dict(label="ecfm", method="least-squares", names=problem.names,
                  likelihood=no_likelihood("ecfm"), nit=out.nit, nfev=out.nfev,
                  eps_history=out.eps_history, loss_history=out.loss_history,
                  opt=out.opt, exhausted=out.exhausted, failure=out.final_error,
                  message=out.message)  # fmt: skip
    return out, common


def fit_ode_basis(problem, eps0, forced, force_basis, settings, options):
    """The ECFM fit of an :class:`OdeProblem` with ``options["force_basis"]`` a linear or
    RBF basis (:func:`~.ode_forces.fit_ode_ecfm` dispatches here): the least-squares fit
    of the residual :math:`R\\lambda(\\epsilon)`; the forces' interval means reported, the
    uncertainty and verdict not computed (module notes)."""
    forces = BasisForces(problem, forced, force_basis)
    out, common = fit_forces(problem, forces, eps0, settings, options)
    why = f"not computed for force_basis={force_basis!r} (built for 'constant')"
    common.update(uncertainty=Uncertainty.failed(f"uncertainty {why}"),
                  verdict=no_test(f"verdict {why}"))  # fmt: skip
    if out.payload is None:
        return Outcome(eps=out.x, loss=np.inf, extra=OdeEcfmDetails(n_missing=problem.n_missing),
                       **common)  # fmt: skip
    final = forces.solve(out.x)
    series = ForceSeries(
        times=forces.knots[:-1].copy(), intervals=np.column_stack((forces.knots[:-1],
        forces.knots[1:])), values=final["means"],
        names=[problem.state_names[j] for j in forces.F], jump=None,
    )  # fmt: skip
    return Outcome(
        eps=out.x, loss=out.loss, njev=out.nit, forces=series,
        extra=OdeEcfmDetails(n_missing=problem.n_missing, force_basis=force_basis,
                             force_coefficients=final["lam"]), **common,
    )  # fmt: skip
