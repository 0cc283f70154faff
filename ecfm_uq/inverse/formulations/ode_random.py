"""The random-force ECFM of a user's ODE: forces :math:`N(0, \\tau^2/\\Delta t_k)` per knot.

The forces are those of :mod:`ecfm_uq.inverse.formulations.ode_forces` (piecewise
constant between data times on the forced components), now random: independent, each
:math:`f_{kj} \\sim N(0, \\tau^2/\\Delta t_k)`, a white noise of intensity :math:`\\tau^2`
(so that :math:`\\tau` does not depend on the sampling density). Linearized in the forces
at :math:`f = 0` (the unforced model at the standard estimate), the readings are

.. math::

    d = h(\\epsilon) + A f + e,\\qquad d \\sim N\\big(h(\\epsilon),\\;
    V(\\tau) = \\Sigma + \\tau^2 A W A^T\\big),\\quad W = \\mathrm{diag}(1/\\Delta t_k),

with :math:`A = \\partial h/\\partial f` from the forward sensitivities of each interval
(chained through the intervals). For each :math:`\\tau` the parameters are the
generalized least-squares estimate :math:`\\hat\\epsilon(\\tau)` (the whitened residual
:math:`L_V^{-1}(h(\\epsilon) - d)`, trust-region, status from its measured optimality);
:math:`\\hat\\tau` maximizes the restricted (REML) likelihood

.. math::

    -2\\ell_R(\\tau) = \\log|V| + \\log|X^TV^{-1}X| + r^TV^{-1}r,\\qquad X = \\partial
    h/\\partial\\epsilon,

by bounded Brent in :math:`\\log\\tau`. The verdict is the restricted likelihood-ratio test
of :math:`\\tau = 0` (no forces needed), whose null distribution on the boundary is the
50:50 mixture of :math:`\\chi^2_0` and :math:`\\chi^2_1` (Self & Liang 1987). The forces
reported are their posterior mean :math:`\\tau^2WA^TV^{-1}r` with posterior standard
deviations; ``result.state`` is the solution forced by that mean.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg
from scipy import optimize, stats

from ..._validation import as_finite_array
from ...errors import ConvergenceError
from ..core.details import OdeRandomDetails
from ..core.drivers import least_squares_scaled
from ..core.fitter import Outcome
from ..core.series import ForceSeries, OdeTrajectory
from ..problems.ode import fit_ode_standard, solve_with_sensitivities
from ..statistics.loglik import no_likelihood
from ..statistics.uncertainty import estimate_uncertainty
from ..statistics.verdict import check_bounds, decide
from .ode_forces import ExactForces, _covariance, _StateOnly, forced_components

__all__ = ["force_response", "forced_solution", "fit_ode_random"]

#: Gauss-Newton steps of the tau search's GLS estimate before the trust-region fit
_GN_STEPS = 12
#: the GLS estimate is settled when the Gauss-Newton step is below this many standard
#: errors (the criterion then within ~settled^2 of its minimum in eps)
_GN_SETTLED = 1e-3


def force_response(problem, ef, eps):
    """:math:`A = \\partial h/\\partial f` at :math:`f = 0`: (n_data, K m), the readings
    present against the forces (interval-major, component-minor)."""
    pb = problem
    n, p, m = pb.n_state, eps.size, ef.m
    H = pb.H()
    y = pb.initial_state(eps).astype(float)
    Y_f = np.zeros((n, ef.K * m))
    rows = np.zeros((pb.v.shape[0], pb.v.shape[1], ef.K * m))
    EF = np.zeros((n, m))
    EF[ef.F, np.arange(m)] = 1.0
    S0 = np.hstack((np.eye(n), np.zeros((n, m))))
    T_eps = np.zeros((p, n + m))
    G = np.hstack((np.zeros((n, n)), EF))
    for k in range(ef.K):
        i = ef.ends[k]
        _, Yb, Sb = solve_with_sensitivities(pb, eps, (ef.starts[k], pb.t[i]), y, S0, T_eps,
                                             G, t_eval=[pb.t[i]])  # fmt: skip
        y, Phi_y, Phi_f = Yb[-1], Sb[-1][:, :n], Sb[-1][:, n:]
        Y_f = Phi_y @ Y_f
        Y_f[:, k * m : (k + 1) * m] += Phi_f
        rows[i] = H @ Y_f
    return rows[pb.mask]


def forced_solution(problem, ef, eps, forces, jump=None):
    """The solution forced by ``forces`` (K, m) (after an initial ``jump`` (m,) of the
    forced components, if given): its readings at the data times (n_t, n_obs) and its
    trajectory."""
    pb = problem
    n = pb.n_state
    y = pb.initial_state(eps).astype(float)
    if jump is not None:
        y[ef.F] += jump
    out = np.full(pb.v.shape, np.nan)
    H = pb.H()
    if ef.jump:
        out[0] = H @ y
    segments = []
    for k in range(ef.K):
        i = ef.ends[k]
        phi = np.zeros(n)
        phi[ef.F] = forces[k]
        sol, Yb, _ = solve_with_sensitivities(pb, eps, (ef.starts[k], pb.t[i]), y,
                                              np.zeros((n, 0)), np.zeros((eps.size, 0)),
                                              force=phi, t_eval=[pb.t[i]], dense=True)  # fmt: skip
        y = Yb[-1]
        out[i] = H @ y
        segments.append((ef.starts[k], _StateOnly(sol.sol, n)))
    ts = np.unique(np.concatenate([s[1].sol.ts for s in segments]))
    traj = OdeTrajectory(ts, np.zeros((ts.size, n)), pb.state_names, tuple(segments))
    return out, OdeTrajectory(ts, traj(ts), pb.state_names, tuple(segments))


def fit_ode_random(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` of an :class:`OdeProblem`,
    ``formulation="ecfm-random"`` (``sigma`` required)."""
    if s.method not in ("auto", "least-squares", "trf"):
        raise ValueError(
            f"unknown `method` {s.method!r} for the random-force ECFM of an OdeProblem; "
            "choose 'least-squares' (the default)"
        )
    eps0 = problem.check(as_finite_array("eps0", eps0, ndim=1))
    p = eps0.size
    bounds = check_bounds(s.bounds, p)
    ls = fit_ode_standard(problem, eps0, dataclasses.replace(s, formulation="standard"))
    ef = ExactForces(problem, forced_components(problem))
    Sigma = _covariance(s.sigma, problem.n_data)
    d = problem.readings
    A = force_response(problem, ef, ls.eps)
    w = np.repeat(1.0 / ef.dt, ef.m)
    AWA = (A * w) @ A.T
    ref = float(np.sqrt(np.median(np.diag(Sigma)) / np.median(np.diag(AWA))))
    state = {"eps": ls.eps.copy()}

    def gls(tau):
        L = np.linalg.cholesky(Sigma + tau**2 * AWA)

        def residual(eps):
            r = problem.predict(eps) - d

            def J():
                return scipy.linalg.solve_triangular(L, problem.predict_jacobian(eps),
                                                     lower=True)  # fmt: skip

            return scipy.linalg.solve_triangular(L, r, lower=True), J, None

        out = least_squares_scaled(residual, state["eps"], bounds, s.tol, 500,
                                   {"x_scale": "jac", "ftol": 1e-12, "xtol": 1e-12,
                                    "gtol": 1e-12})  # fmt: skip
        state["eps"] = out.x
        X = scipy.linalg.solve_triangular(L, problem.predict_jacobian(out.x), lower=True)
        rw = scipy.linalg.solve_triangular(L, problem.predict(out.x) - d, lower=True)
        logdet = 2 * np.sum(np.log(np.diag(L)))
        _, logdet_x = np.linalg.slogdet(X.T @ X)
        crit = logdet + logdet_x + float(rw @ rw)
        return crit, out, L, X, rw

    def criterion(tau):
        """The REML criterion at ``tau`` for the search: the GLS estimate by Gauss-Newton
        from the last one (each step one solve); the trust-region fit of :func:`gls`
        where it does not settle or leaves the bounds."""
        L = np.linalg.cholesky(Sigma + tau**2 * AWA)
        eps = state["eps"].copy()
        for _ in range(_GN_STEPS):
            X = scipy.linalg.solve_triangular(L, problem.predict_jacobian(eps), lower=True)
            rw = scipy.linalg.solve_triangular(L, problem.predict(eps) - d, lower=True)
            step, *_ = np.linalg.lstsq(X, -rw, rcond=None)
            se = np.sqrt(np.diag(np.linalg.pinv(X.T @ X)))
            if np.all(np.abs(step) <= _GN_SETTLED * se):
                break  # the criterion is at its minimum in eps to O(settled^2)
            trial = eps + step
            if bounds is not None and not all(
                (lo is None or v >= lo) and (hi is None or v <= hi)
                for v, (lo, hi) in zip(trial, bounds, strict=True)
            ):
                return gls(tau)[0]
            eps = trial
        else:
            state["eps"] = eps
            return gls(tau)[0]
        state["eps"] = eps
        _, logdet_x = np.linalg.slogdet(X.T @ X)
        return 2 * np.sum(np.log(np.diag(L))) + logdet_x + float(rw @ rw)

    try:
        c0 = gls(0.0)[0]
        search = optimize.minimize_scalar(lambda lt: criterion(ref * 10.0**lt), bounds=(-4, 3),
                                          method="bounded", options={"xatol": 1e-3})  # fmt: skip
    except ConvergenceError as e:
        raise ConvergenceError(f"fit: {e}") from e
    tau = ref * 10.0**search.x if search.fun < c0 else 0.0
    crit, out, L, X, rw = gls(tau)
    lrt = max(c0 - crit, 0.0)
    p_value = 1.0 if lrt == 0 else float(0.5 * stats.chi2.sf(lrt, 1))
    # posterior of the forces given the data, at the estimate
    Vinv_r = scipy.linalg.solve_triangular(L, rw, lower=True, trans="T")
    mean = tau**2 * w * (A.T @ Vinv_r)
    B = scipy.linalg.solve_triangular(L, A * w, lower=True)
    var = tau**2 * w - tau**4 * np.sum(B**2, axis=0)
    sd = np.sqrt(np.maximum(var, 0.0))
    K, m = ef.K, ef.m
    names = [problem.state_names[j] for j in ef.F]
    series = ForceSeries(times=ef.starts.copy(),
                         intervals=np.column_stack((ef.starts, problem.t[ef.ends])),
                         values=mean.reshape(K, m), stderr=sd.reshape(K, m), names=names)  # fmt: skip
    try:
        _, traj = forced_solution(problem, ef, out.x, series.values)
    except ConvergenceError:
        traj = None
    Dw = np.linalg.solve(X.T @ X, X.T)  # d eps / d (whitened data), GLS
    Dd = scipy.linalg.solve_triangular(L, Dw.T, lower=True, trans="T").T  # d eps / d data
    unc = estimate_uncertainty(None, out.x, None, L @ L.T, "known", deps_dv=Dd)
    parts = [
        f"restricted likelihood-ratio test of tau = 0: statistic {lrt:.3g}, p = {p_value:.3g} "
        f"{'>=' if p_value >= s.alpha else '<'} alpha = {s.alpha:g} (50:50 chi2_0:chi2_1); "
        f"tau = {tau:.3g}"
    ]
    verdict = decide("REML LRT tau=0", p_value, s.alpha, parts, statistic=lrt,
                     details={"tau": tau, "lrt": lrt})  # fmt: skip
    return Outcome(
        eps=out.x, loss=out.loss, opt=out.opt, exhausted=out.exhausted,
        failure=out.final_error, message=out.message, nit=out.nit,
        nfev=out.nfev, njev=out.nit, label="ecfm-random",
        method="least-squares", eps_history=out.eps_history,
        loss_history=out.loss_history, state=traj, forces=series, uncertainty=unc,
        verdict=verdict, likelihood=no_likelihood("ecfm-random"),
        names=problem.names,
        # "standard": the standard fit's Outcome (what it measured; no status)
        extra=OdeRandomDetails(tau=tau, standard=ls, n_missing=problem.n_missing),
    )  # fmt: skip
