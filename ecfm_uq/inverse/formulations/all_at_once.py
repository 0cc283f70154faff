"""All-at-once constrained inverse problems for steady models with noisy data
(paper Section 3.2, Eqs. kpp_inv and ecfm_noise).

Both problems are nonlinear programs in the stacked variables, solved with
``scipy.optimize.minimize(method="SLSQP")`` and analytic first derivatives of the
objective and of every constraint (no sensitivity solves: the variables are
independent, as the paper remarks after Eq. ecfm_noise):

* standard, Eq. (kpp_inv), variables :math:`z = (\\theta, \\epsilon)`:

  .. math::

      \\min \\tfrac12\\|\\mathcal M\\theta - v\\|^2 \\quad\\text{s.t.}\\quad
      R(\\theta;\\epsilon) = 0;

* noise-aware ECFM, Eq. (ecfm_noise), variables :math:`z = (\\theta, \\epsilon, \\lambda)`:

  .. math::

      \\min \\tfrac12\\|\\lambda\\|^2 \\quad\\text{s.t.}\\quad
      \\tilde R(\\lambda, \\theta;\\epsilon) = R(\\theta;\\epsilon) - \\Gamma\\lambda = 0,\\quad
      \\ell_1 \\le \\bar e \\le \\ell_2,\\quad p_1 \\le s^2_e \\le p_2,

  with :math:`e = \\mathcal M\\theta - v`, :math:`\\bar e` its sample mean, :math:`s^2_e`
  its sample variance and the bounds of :func:`ecfm_uq.inverse.formulations.noise_bounds.noise_bounds`.

Derivatives: :math:`\\partial R/\\partial(\\theta, \\epsilon, \\lambda) =
[J_\\theta, J_\\epsilon, -\\Gamma]` from the system, :math:`\\nabla_\\theta\\bar e =
\\mathcal M^T\\mathbf 1/C`, :math:`\\nabla_\\theta s^2_e = 2\\mathcal M^T(e - \\bar e)/(C-1)`.
The four inequalities are divided by their natural scales (:math:`\\sigma/\\sqrt C` for the
mean, :math:`\\sigma^2` for the variance); positive scaling leaves the feasible set
unchanged and keeps SLSQP's feasibility tolerance meaningful.

Any steady deterministic :class:`~ecfm_uq.system.GalerkinSystem` (``P = 1``) works; the
ECFM problem needs its ``Gamma``.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import scipy.optimize as sopt

from ..._validation import as_dense_rows, as_finite_array, check_positive
from ...system import solve_steady
from ..core.convergence import KKT_TOL, kkt_optimality
from ..core.details import AllAtOnceDetails
from ..core.fitter import Outcome, holds
from ..core.result import Uncertainty
from ..statistics.uncertainty import estimate_uncertainty
from ..statistics.verdict import moments_bounds_verdict
from .noise_bounds import consistency_test, noise_bounds, sample_moments
from .steady import _uncertainty

_GRADIENTS = ("analytic", "fd")


class ConstrainedInverse:
    """The nonlinear program of Eq. (kpp_inv) or Eq. (ecfm_noise) in stacked variables.

    Parameters
    ----------
    system : GalerkinSystem
        Steady, deterministic (``P = 1``); with ``Gamma`` for ``formulation="noisy-ecfm"``.
    M_obs : (C, N) array_like
        Measurement operator.
    v : (C,) array_like
        Data.
    formulation : {"standard", "noisy-ecfm"}
    sigma : float, optional
        Noise standard deviation (required for ``"noisy-ecfm"``).
    alpha : float
        Significance level of the moment bounds.

    Notes
    -----
    The stacked vector is ``z = [theta (N), eps (n_eps), lam (C)]`` (no ``lam`` for the
    standard problem). Every method takes ``z`` and returns plain arrays.
    """

    def __init__(self, system, M_obs, v, formulation="standard", sigma=None, alpha=0.05):
        if formulation not in ("standard", "noisy-ecfm"):
            raise ValueError(
                f"unknown `formulation` {formulation!r}; choose 'standard' or 'noisy-ecfm'"
            )
        if getattr(system, "P", None) != 1:
            raise ValueError(
                "`system` must be a deterministic GalerkinSystem (P = 1); the moment "
                "constraints act on one measured state"
            )
        self.system = system
        self.formulation = formulation
        self.M_obs = as_dense_rows("M_obs", M_obs)
        if self.M_obs.shape[1] != system.N:
            raise ValueError(
                f"`M_obs` must have {system.N} columns (N), got shape {self.M_obs.shape}"
            )
        self.C = self.M_obs.shape[0]
        self.v = as_finite_array("v", v, shape=(self.C,))
        self.N = system.N
        self.n_eps = system.n_eps
        if formulation == "noisy-ecfm":
            if system.Gamma is None:
                raise ValueError("formulation='noisy-ecfm' needs a system with `Gamma`")
            if system.n_forces != self.C:
                raise ValueError(
                    f"`Gamma` has {system.n_forces} columns but there are {self.C} "
                    "measurements; use one constraint force per sensor"
                )
            if sigma is None:
                raise ValueError("formulation='noisy-ecfm' needs the noise level `sigma`")
            self.bounds = noise_bounds(sigma, self.C, alpha)
            self.n_lam = self.C
            self._Jlam = system.lam_jacobian()
            self._mean_scale = self.bounds["sigma"] / np.sqrt(self.C)
            self._var_scale = self.bounds["sigma"] ** 2
        else:
            self.bounds = None
            self.n_lam = 0
        self.size = self.N + self.n_eps + self.n_lam
        self._mean_row = self.M_obs.sum(axis=0) / self.C

    # -- variables ---------------------------------------------------------------------
    def split(self, z):
        """``(theta (N,), eps (n_eps,), lam (n_lam,))`` views of ``z``."""
        z = np.asarray(z, dtype=float)
        if z.shape != (self.size,):
            raise ValueError(f"`z` must have shape ({self.size},), got {z.shape}")
        N, m = self.N, self.n_eps
        return z[:N], z[N : N + m], z[N + m :]

    def stack(self, theta, eps, lam=None):
        """Stack ``theta``, ``eps`` (and ``lam``) into ``z``."""
        parts = [np.ravel(theta), np.ravel(eps)]
        if self.n_lam:
            parts.append(np.zeros(self.n_lam) if lam is None else np.ravel(lam))
        z = np.concatenate(parts).astype(float)
        if z.shape != (self.size,):
            raise ValueError(f"stacked variables have {z.size} entries, expected {self.size}")
        return z

    def discrepancy(self, z):
        """:math:`e = \\mathcal M\\theta - v`, shape (C,)."""
        theta, _, _ = self.split(z)
        return self.M_obs @ theta - self.v

    # -- objective ---------------------------------------------------------------------
    def objective(self, z):
        """:math:`\\tfrac12\\|e\\|^2` (standard) or :math:`\\tfrac12\\|\\lambda\\|^2` (ECFM)."""
        if self.n_lam:
            lam = self.split(z)[2]
            return 0.5 * float(lam @ lam)
        e = self.discrepancy(z)
        return 0.5 * float(e @ e)

    def objective_grad(self, z):
        """Gradient of :meth:`objective`, shape (size,)."""
        g = np.zeros(self.size)
        if self.n_lam:
            g[self.N + self.n_eps :] = self.split(z)[2]
        else:
            g[: self.N] = self.M_obs.T @ self.discrepancy(z)
        return g

    # -- equality: the discretized model -----------------------------------------------
    def equality(self, z):
        """:math:`R(\\theta;\\epsilon) - \\Gamma\\lambda`, shape (N,)."""
        theta, eps, lam = self.split(z)
        Th = theta[:, None]
        return self.system.residual(Th, eps, lam if self.n_lam else None).ravel()

    def equality_jac(self, z):
        """:math:`[\\partial R/\\partial\\theta, \\partial R/\\partial\\epsilon, -\\Gamma]`,
        shape (N, size)."""
        theta, eps, _ = self.split(z)
        Th = theta[:, None]
        blocks = [self.system.jacobian(Th, eps), self.system.eps_jacobian(Th, eps)]
        if self.n_lam:
            blocks.append(self._Jlam)
        return np.hstack(blocks)

    # -- inequalities: moments of the discrepancy (ECFM only) --------------------------
    def moments(self, z):
        """Sample mean and variance of the discrepancy at ``z``."""
        return sample_moments(self.discrepancy(z))

    def inequality(self, z):
        """Scaled :math:`[\\bar e - \\ell_1, \\ell_2 - \\bar e, s^2 - p_1, p_2 - s^2] \\ge 0`.

        The mean rows are divided by :math:`\\sigma/\\sqrt C`, the variance rows by
        :math:`\\sigma^2`. Shape (4,) (empty for the standard problem).
        """
        if not self.n_lam:
            return np.zeros(0)
        b = self.bounds
        mean, var = self.moments(z)
        sm, sv = self._mean_scale, self._var_scale
        return np.array(
            [
                (mean - b["l1"]) / sm,
                (b["l2"] - mean) / sm,
                (var - b["p1"]) / sv,
                (b["p2"] - var) / sv,
            ]
        )

    def inequality_jac(self, z):
        """Jacobian of :meth:`inequality`, shape (4, size)."""
        if not self.n_lam:
            return np.zeros((0, self.size))
        e = self.discrepancy(z)
        dmean = self._mean_row
        dvar = 2.0 * self.M_obs.T @ (e - e.mean()) / (self.C - 1)
        J = np.zeros((4, self.size))
        sm, sv = self._mean_scale, self._var_scale
        J[0, : self.N] = dmean / sm
        J[1, : self.N] = -dmean / sm
        J[2, : self.N] = dvar / sv
        J[3, : self.N] = -dvar / sv
        return J

    def scipy_constraints(self, gradients="analytic"):
        """Constraint dicts for ``scipy.optimize.minimize(method="SLSQP")``.

        ``gradients="fd"`` omits every ``jac`` so SLSQP differences them itself.
        """
        analytic = gradients == "analytic"
        cons = [{"type": "eq", "fun": self.equality}]
        if analytic:
            cons[0]["jac"] = self.equality_jac
        if self.n_lam:
            cons.append({"type": "ineq", "fun": self.inequality})
            if analytic:
                cons[1]["jac"] = self.inequality_jac
        return cons


def _start(problem, eps0, theta0, lam0, solve_options):
    """Starting point: eps0 (default 0), theta0 = Newton solution at (eps0, lam0)."""
    sysm = problem.system
    eps0 = np.zeros(sysm.n_eps) if eps0 is None else sysm.check_eps(eps0)
    lam0 = (
        np.zeros(problem.n_lam)
        if lam0 is None
        else as_finite_array("lam0", lam0, shape=(problem.n_lam,))
    )
    note = "given theta0"
    if theta0 is None:
        sol = solve_steady(sysm, eps0, lam0 if problem.n_lam else None, **dict(solve_options or {}))
        if sol.success:
            theta0, note = sol.Theta[:, 0], f"theta0 = Newton solution at eps0 ({sol.nit} it.)"
        else:
            theta0, note = np.zeros(sysm.N), f"theta0 = 0 (Newton at eps0 failed: {sol.message})"
    else:
        theta0 = as_finite_array("theta0", theta0, shape=(sysm.N,))
    return problem.stack(theta0, eps0, lam0), note


def _solve(problem, z0, note, gradients, maxiter, ftol, tol, method_name):
    hist_eps, hist_loss = [], []

    def callback(xk, *args):
        hist_eps.append(problem.split(xk)[1].copy())
        hist_loss.append(problem.objective(xk))

    callback(z0)
    jac = problem.objective_grad if gradients == "analytic" else None
    t0 = time.perf_counter()
    res = sopt.minimize(
        problem.objective,
        z0,
        jac=jac,
        method="SLSQP",
        constraints=problem.scipy_constraints(gradients),
        options={"maxiter": maxiter, "ftol": ftol},
        callback=callback,
    )
    wall = time.perf_counter() - t0
    z = np.asarray(res.x, dtype=float)
    theta, eps, lam = problem.split(z)
    e = problem.discrepancy(z)
    mean, var = sample_moments(e) if e.size >= 2 else (float(e.mean()), 0.0)
    extra = AllAtOnceDetails(
        discrepancy=e,
        mean_discrepancy=mean,
        var_discrepancy=var,
        residual_norm=float(np.linalg.norm(problem.equality(z))),
        inequality=problem.inequality(z),
        moment_bounds=problem.bounds,
        slsqp_status=int(res.status),
        start=note,
        gradients=gradients,
        wall_time_s=wall,
        z=z,
    )
    # the status is read from the KKT conditions at z, not from SLSQP's own "success"
    with np.errstate(all="ignore"):
        opt = kkt_optimality(
            z, float(res.fun), problem.objective_grad(z), problem.equality(z),
            problem.equality_jac(z), problem.inequality(z), problem.inequality_jac(z),
            f_scale=max((abs(x) for x in hist_loss if np.isfinite(x)), default=0.0),
            f_lower=0.0, tol=tol,  # both objectives are 1/2 ||.||^2
        )  # fmt: skip
    message = f"SLSQP: {res.message} [{opt.message}]"
    if not np.isfinite(opt.value):  # measured, not a size: no optimality to report
        opt = replace(opt, value=None)
    return dict(
        eps=eps.copy(),
        loss=float(res.fun) if np.isfinite(res.fun) else float("inf"),
        opt=opt,
        exhausted=res.status == 9 or res.nit >= maxiter,
        method="SLSQP",
        message=message,
        nit=int(res.nit),
        nfev=int(res.nfev),
        njev=int(getattr(res, "njev", 0) or 0),
        label=method_name,
        eps_history=np.array(hist_eps),
        loss_history=np.array(hist_loss),
        state=theta.copy(),
        forces=lam.copy() if problem.n_lam else None,
        extra=extra,
    )


#: defaults of the all-at-once SLSQP fits: SLSQP's ``ftol`` (its precision goal on the
#: objective, also its feasibility tolerance; ``options={"ftol": ...}``)
_DEFAULT_FTOL = 1e-12
_DEFAULT_MAXITER = 500


def fit_all_at_once(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` of a steady problem in stacked variables with SLSQP.

    ``formulation="standard"`` with ``method="all-at-once"`` is Eq. (kpp_inv);
    ``formulation="noisy-ecfm"`` (``sigma`` required, bounds at level ``alpha``) is Eq.
    (ecfm_noise). ``options``: ``theta0`` (N,) and ``lam0`` (C,) starts (default: the
    Newton solution at ``eps0``, zero forces), ``jac`` (``"analytic"``, or ``"fd"`` to let
    SLSQP difference objective and constraints: benchmarks only).

    Returns an :class:`~ecfm_uq.inverse.core.fitter.Outcome`: the KKT conditions measured
    at SLSQP's point (the status is decided from them by the entry point).
    """
    if s.formulation not in ("standard", "noisy-ecfm"):
        raise ValueError(
            f"method='all-at-once' solves formulation 'standard' or 'noisy-ecfm', not "
            f"{s.formulation!r}"
        )
    if s.method not in ("auto", "all-at-once"):
        raise ValueError(
            f"formulation='noisy-ecfm' is solved all at once by SLSQP: pass method='auto' "
            f"or 'all-at-once', not {s.method!r}"
        )
    known = {"theta0": None, "jac": "analytic", "ftol": _DEFAULT_FTOL}
    if s.formulation == "noisy-ecfm":
        known["lam0"] = None
        if s.sigma is None:
            raise ValueError("formulation='noisy-ecfm' needs the noise level `sigma`")
    opts = s.take(known)
    if opts["jac"] not in _GRADIENTS:
        raise ValueError(f"unknown `options['jac']` {opts['jac']!r}; choose 'analytic' or 'fd'")
    ftol = check_positive("options['ftol']", opts["ftol"])
    tol = KKT_TOL if s.tol is None else s.tol
    maxiter = _DEFAULT_MAXITER if s.maxiter is None else s.maxiter
    system = problem.system
    if s.formulation == "standard":
        inverse = ConstrainedInverse(system, problem.M_obs, problem.v, "standard")
        label = "standard-slsqp"
    else:
        inverse = ConstrainedInverse(
            system, problem.M_obs, problem.v, "noisy-ecfm", sigma=s.sigma, alpha=s.alpha
        )
        label = "noisy-ecfm"
    z0, note = _start(inverse, eps0, opts["theta0"], opts.get("lam0"), problem.solve_options)
    res = _solve(inverse, z0, note, opts["jac"], maxiter, ftol, tol, label)
    if not holds(res["opt"]):
        unc = Uncertainty.failed("uncertainty not computed: the fit did not succeed")
    elif not s.uncertainty:
        unc = Uncertainty.failed("not computed (uncertainty=False)")
    elif s.formulation == "standard":
        # the all-at-once optimum is the reduced one: same optimality condition
        # grad z^INV(eps) = 0, hence the same covariance code path as the reduced fit

        unc = _uncertainty(
            system, inverse.M_obs, inverse.v, res["eps"], "standard",
            dict(problem.solve_options), s.sigma,
        )  # fmt: skip
    else:
        unc = _kkt_uncertainty(inverse, res["extra"].z, s.sigma)
    verdict = _verdict(res["extra"].discrepancy, s.sigma, s.alpha, s.sigma_label)
    return Outcome(**res, uncertainty=unc, verdict=verdict)


#: a scaled moment inequality within this of zero is active at the optimum
ACTIVE_TOL = 1e-6


def _verdict(discrepancy, sigma, alpha, sigma_label=None):
    """The paper's z / chi-squared test of the discrepancy (Eq. ecfm_noise) when the noise
    is modelled, as the fit's :class:`~ecfm_uq.inverse.core.result.Verdict` (``None``
    without sigma); ``sigma_label`` names the noise in its message."""
    if sigma is None:
        return None

    test = consistency_test(discrepancy, sigma, alpha)
    return moments_bounds_verdict(test, sigma, alpha, sigma_label=sigma_label)


def _kkt_uncertainty(problem, z, sigma):
    """Delta-method covariance of the noisy-ECFM estimate by implicit differentiation of
    its KKT conditions (the active moment bounds are the only place the data enter).

    With :math:`L = f - y^T h - \\mu^T c_A` the KKT map
    :math:`F = (\\nabla_z L, -h, -c_A)` is stationary in :math:`x = (z, y, \\mu)`;
    :math:`dx/dv = -(\\partial F/\\partial x)^{-1}\\partial F/\\partial v` and the eps
    block of the covariance is reported (Sigma_v = sigma^2 I).
    """
    n = problem.size
    active = np.flatnonzero(problem.inequality(z) <= ACTIVE_TOL)
    A = np.vstack([problem.equality_jac(z), problem.inequality_jac(z)[active]])
    mult = np.linalg.lstsq(A.T, problem.objective_grad(z), rcond=None)[0]
    x0 = np.concatenate([z, mult])
    kw = {"sigma": sigma, "alpha": problem.bounds["alpha"]}

    def kkt(x, w):
        p = ConstrainedInverse(problem.system, problem.M_obs, w, problem.formulation, **kw)
        zz, y, mu = x[:n], x[n : n + problem.N], x[n + problem.N :]
        Jh = p.equality_jac(zz)
        Jc = p.inequality_jac(zz)[active]
        return np.concatenate(
            [
                p.objective_grad(zz) - Jh.T @ y - Jc.T @ mu,
                -p.equality(zz),
                -p.inequality(zz)[active],
            ]
        )

    return estimate_uncertainty(
        kkt, x0, problem.v, float(sigma) ** 2, "known",
        block=slice(problem.N, problem.N + problem.n_eps),
        hint="the estimate is not determined by the data at this optimum, "
        f"{active.size} active moment bounds",
    )  # fmt: skip


__all__ = ["ConstrainedInverse"]
