"""ECFM consistent with noisy data: the constraint forces as a random discrepancy.

The paper's ECFM (Eq. ecfm) asks the forces :math:`\\lambda` to make the model match the
data exactly and minimizes :math:`\\tfrac12\\|\\lambda\\|^2`. With noisy data that objective is
smallest where the model is most compliant (the forces needed are smallest there), so a
parameter inside the operator runs to its most compliant corner. Here the forces are a
random discrepancy inside the model instead,

.. math::

    R(\\theta;\\epsilon) - \\Gamma\\lambda = 0,\\qquad \\lambda \\sim N(0, \\tau^2 I),\\qquad
    v = \\mathcal M\\,\\mathbb E[\\theta] + e,\\quad e \\sim N(0, \\sigma^2 I),

linearized in :math:`\\lambda` about :math:`\\lambda = 0` (exact for a model linear in
:math:`\\theta`): with :math:`r(\\epsilon) = v - \\mathcal M\\,\\mathbb E[\\theta(\\epsilon, 0)]`
and :math:`A(\\epsilon) = \\mathcal M\\,\\partial\\mathbb E[\\theta]/\\partial\\lambda`, the data
are Gaussian with covariance :math:`S = \\sigma^2 I + \\tau^2 A A^T`, and
:math:`(\\epsilon, \\tau)` maximize the marginal likelihood

.. math::

    \\ell(\\epsilon, \\tau) = \\tfrac12 r^T S^{-1} r + \\tfrac12 \\log\\det S .

The :math:`\\log\\det S` term is what the paper's objective lacks: a compliant model (large
:math:`A`) pays for the data variance it claims to explain, so no degenerate corner.
:math:`\\tau = 0` is the standard least-squares estimate, and :math:`\\sigma \\to 0` with
:math:`\\tau > 0` recovers the paper's ECFM. At the estimate the forces are the posterior
mean :math:`\\hat\\lambda = \\tau^2 A^T S^{-1} r` with covariance
:math:`\\tau^2 I - \\tau^4 A^T S^{-1} A`: a map of the missing physics with error bars.

"Can this model explain these data?" is the likelihood-ratio test of :math:`\\tau = 0`. The
null value lies on the boundary of the parameter space, so the statistic
:math:`2(\\ell(\\hat\\epsilon_0, 0) - \\ell(\\hat\\epsilon, \\hat\\tau))` follows the mixture
:math:`\\tfrac12\\chi^2_0 + \\tfrac12\\chi^2_1` (Self & Liang 1987):
:math:`p = \\tfrac12 P(\\chi^2_1 > T)` for :math:`T > 0`, else 1.

:math:`\\tau` is profiled out exactly at each :math:`\\epsilon` (one eigen-decomposition of
:math:`AA^T` makes :math:`\\ell(\\epsilon, \\cdot)` a cheap scalar function), and the profiled
:math:`\\ell(\\epsilon)` is minimized over :math:`\\epsilon` from the standard estimate. Its
gradient is taken by central differences (the exact one would need second sensitivities
:math:`\\partial A/\\partial\\epsilon`), in the parameters scaled by their standard errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize, stats

from ..errors import ConvergenceError, ModelEvaluationError
from ..system import solve_steady
from .loglik import LogLikelihood
from .result import InverseResult, Uncertainty
from .status import FitStatus
from .verdict import decide

__all__ = ["RandomForceModel", "fit_random_force"]

_FAILURES = (ConvergenceError, ModelEvaluationError, np.linalg.LinAlgError)
# the scaled variance s = tau^2 * a0^2 / sigma^2 is searched on this log grid, then refined
_S_GRID = np.concatenate([[0.0], np.logspace(-6, 10, 97)])


@dataclass(frozen=True)
class Linearization:
    """The model at :math:`\\epsilon` with zero forces: residual and force-to-sensor map."""

    eps: np.ndarray
    r: np.ndarray  # v - M E[theta]
    A: np.ndarray  # M dE[theta]/dlam, (C, n_forces)
    mu: np.ndarray  # eigenvalues of A A^T / a0^2
    w2: np.ndarray  # squared residual in the eigenbasis
    UJ: np.ndarray  # the sensitivity dE[M theta]/deps in the eigenbasis, (C, n_eps)


class RandomForceModel:
    """The marginal likelihood :math:`\\ell(\\epsilon, \\tau)` of a steady problem.

    Parameters
    ----------
    problem : SteadyProblem
        With constraint forces (``system.Gamma``).
    sigma : float
        Known noise standard deviation of the data.
    """

    def __init__(self, problem, sigma):
        system = problem.system
        if system.Gamma is None:
            raise ValueError("the random-force ECFM needs a system with constraint forces (Gamma)")
        self.problem, self.system, self.sigma = problem, system, float(sigma)
        self.M = problem.M_obs
        self.v = problem.v
        self.a0 = None  # force-to-data scale, fixed at the first linearization
        self.n_solves = 0

    def linearize(self, eps):
        """:class:`Linearization` at ``eps`` (one solve and one multi-right-hand-side
        back-substitution); raises the model's error where it cannot be solved."""
        sysm = self.system
        sol = solve_steady(sysm, eps, strict=True, **self.problem.solve_options)
        self.n_solves += 1
        r = self.v - self.M @ sysm.mean(sol.Theta)
        dmean = np.einsum("nkc,k->nc", sol.lam_sensitivity(), sysm.E1)
        A = np.asarray(self.M @ dmean)
        J = np.asarray(self.M @ np.einsum("nkm,k->nm", sol.eps_sensitivity()[0], sysm.E1))
        AA = A @ A.T
        if self.a0 is None:
            self.a0 = float(np.sqrt(max(np.trace(AA) / AA.shape[0], 1e-300)))
        mu, U = np.linalg.eigh(AA / self.a0**2)
        mu = np.maximum(mu, 0.0)
        return Linearization(np.asarray(eps, float), r, A, mu, (U.T @ r) ** 2, U.T @ J)

    def nll(self, lin, s, restricted=False):
        """:math:`\\ell` at scaled variance ``s`` (:math:`\\tau^2 = s\\sigma^2/a_0^2`), up to
        the constant :math:`\\tfrac C2 \\log 2\\pi`; ``restricted`` adds the REML term.
        ``s`` may be an array (one value per entry)."""
        s_arr = np.atleast_1d(np.asarray(s, dtype=float))
        d = self.sigma**2 * (1.0 + s_arr[:, None] * lin.mu[None, :])  # (G, C)
        val = 0.5 * (np.sum(lin.w2 / d, axis=1) + np.sum(np.log(d), axis=1))
        if restricted and lin.UJ.size:
            # the residual has lost n_eps degrees of freedom to the fitted parameters,
            # which the plain marginal likelihood reads as a smaller variance (a biased
            # tau and a conservative test of tau = 0): + 1/2 log det(J^T S^-1 J)
            info = np.einsum("cm,gc,cn->gmn", lin.UJ, 1.0 / d, lin.UJ)
            w = np.linalg.eigvalsh(info)
            floor = 1e-300 + 1e-14 * w[:, -1:]
            val = val + 0.5 * np.sum(np.log(np.maximum(w, floor)), axis=1)
        return float(val[0]) if np.ndim(s) == 0 else val

    def best_s(self, lin):
        """The restricted-likelihood :math:`\\arg\\min_{s \\ge 0}`: a log grid, then Brent;
        returns ``(s, marginal nll at s)``."""
        vals = self.nll(lin, _S_GRID, restricted=True)
        k = int(np.argmin(vals))
        s_hat = 0.0
        if k > 0:
            lo, hi = _S_GRID[k - 1], _S_GRID[min(k + 1, _S_GRID.size - 1)]
            res = optimize.minimize_scalar(
                lambda s: self.nll(lin, s, restricted=True), bounds=(lo, hi),
                method="bounded", options={"xatol": 1e-10 * hi},
            )  # fmt: skip
            s_hat = float(res.x) if res.fun < vals[k] else float(_S_GRID[k])
        return s_hat, self.nll(lin, s_hat)

    def conditional_likelihood(self, lin, s):
        """:math:`\\tfrac12 r(\\epsilon)^T S_0^{-1} r(\\epsilon)` with the data covariance
        :math:`S_0 = \\sigma^2 I + \\hat\\tau^2 A A^T` held at the estimate: the likelihood
        of :math:`\\epsilon` conditional on the estimated discrepancy (generalized least
        squares), exact gradient :math:`-J^T S_0^{-1} r`. With :math:`\\hat\\tau = 0` it is
        the standard likelihood with ``sigma`` known."""
        from scipy.linalg import cho_factor, cho_solve

        tau2 = self.tau(s) ** 2
        S0 = self.sigma**2 * np.eye(lin.A.shape[0]) + tau2 * lin.A @ lin.A.T
        chol = cho_factor(S0)
        sysm = self.system

        def evaluate(eps):
            sol = solve_steady(sysm, eps, strict=True, **self.problem.solve_options)
            r = self.v - self.M @ sysm.mean(sol.Theta)
            dmean = np.einsum("nkm,k->nm", sol.eps_sensitivity()[0], sysm.E1)
            w = cho_solve(chol, r)
            return 0.5 * float(r @ w), -np.asarray(self.M @ dmean).T @ w

        def value(eps):
            sol = solve_steady(sysm, eps, strict=True, **self.problem.solve_options)
            r = self.v - self.M @ sysm.mean(sol.Theta)
            return 0.5 * float(r @ cho_solve(chol, r))

        what = "Gaussian, sigma" if tau2 == 0.0 else "GLS with the estimated discrepancy"
        return LogLikelihood(
            evaluate, sysm.n_eps, self.v.size, "known sigma" if tau2 == 0.0 else "random forces",
            f"{what} covariance held at the estimate (sigma={self.sigma:g}, tau={self.tau(s):.3g})",
            value_only=value,
        )  # fmt: skip

    def tau(self, s):
        return float(np.sqrt(s) * self.sigma / self.a0)

    def forces(self, lin, s):
        """Posterior mean of the forces and their standard deviations."""
        tau2 = self.tau(s) ** 2
        n_f = lin.A.shape[1]
        if tau2 == 0.0:
            return np.zeros(n_f), np.zeros(n_f)
        S = self.sigma**2 * np.eye(lin.A.shape[0]) + tau2 * lin.A @ lin.A.T
        SiA = np.linalg.solve(S, lin.A)
        lam = tau2 * SiA.T @ lin.r
        cov = tau2 * np.eye(n_f) - tau2**2 * lin.A.T @ SiA
        return lam, np.sqrt(np.maximum(np.diag(cov), 0.0))


def _profiled(model, eps):
    lin = model.linearize(eps)
    s, val = model.best_s(lin)
    return val, s, lin


def _fd_gradient(f, x, h):
    g = np.empty(x.size)
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = h
        g[j] = (f(x + e) - f(x - e)) / (2 * h)
    return g


def fit_random_force(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` of ``formulation="ecfm"`` with ``sigma`` (settings ``s``).

    Starts from the standard estimate (``tau = 0``) and minimizes the marginal likelihood
    with ``tau`` profiled out.
    """
    from .fitting import FitSettings
    from .steady import fit_steady_problem

    system = problem.system
    s.take({})  # no options of its own: refuse unknown names
    standard = fit_steady_problem(
        problem, eps0,
        FitSettings("standard", "auto", s.sigma, s.bounds, None, s.maxiter, {}, True, s.alpha),
    )  # fmt: skip
    model = RandomForceModel(problem, s.sigma)
    eps_std = np.asarray(standard.eps, float)
    se = standard.uncertainty.stderr
    scale = np.where(
        np.isfinite(se) & (se > 0), se, 0.1 * np.maximum(1.0, np.abs(eps_std))
    ) if se is not None else 0.1 * np.maximum(1.0, np.abs(eps_std))  # fmt: skip
    nll0, _, _ = _profiled(model, eps_std)
    base = nll0
    nfev = [0]

    def p(x):
        nfev[0] += 1
        try:
            return _profiled(model, eps_std + scale * x)[0]
        except _FAILURES:
            return np.inf

    def fun(x):
        val = p(x)
        if not np.isfinite(val):
            return base + 1e12, np.zeros(x.size)
        return val, _fd_gradient(p, x, 1e-5)

    bnds = None
    if s.bounds is not None:
        bnds = [
            (None if lo is None else (lo - e) / c, None if hi is None else (hi - e) / c)
            for (lo, hi), e, c in zip(s.bounds, eps_std, scale, strict=True)
        ]
    maxiter = 200 if s.maxiter is None else s.maxiter
    tol = 1e-10 if s.tol is None else s.tol
    res = optimize.minimize(
        fun, np.zeros(system.n_eps), jac=True, method="L-BFGS-B", bounds=bnds,
        options={"maxiter": maxiter, "ftol": tol, "gtol": 1e-6},
    )  # fmt: skip
    x = res.x if res.fun <= nll0 else np.zeros(system.n_eps)
    eps = eps_std + scale * x
    val, s_hat, lin = _profiled(model, eps)
    grad = _fd_gradient(p, x, 1e-5)
    optimality = float(np.max(np.abs(grad))) if grad.size else 0.0
    at_bound = _at_bound(eps, s.bounds)
    if res.success or optimality < 1e-5:
        status = FitStatus.CONVERGED
    elif res.nit >= maxiter:
        status = FitStatus.MAX_ITERATIONS
    else:
        status = FitStatus.STALLED
    lam, lam_sd = model.forces(lin, s_hat)
    unc = _uncertainty(p, x, scale, standard, s_hat)
    T = 2.0 * (model.nll(lin, 0.0, restricted=True) - model.nll(lin, s_hat, restricted=True))
    verdict = _verdict(model, T, s_hat, lam, lam_sd, s.alpha, at_bound)
    like = model.conditional_likelihood(lin, s_hat)
    result = InverseResult(
        eps=eps, loss=val, status=status, message=str(res.message),
        nit=standard.nit + res.nit, nfev=standard.nfev + nfev[0],
        njev=standard.njev + res.njev, optimality=optimality, method="ecfm",
        optimizer="L-BFGS-B", uncertainty=unc, verdict=verdict,
        extra={
            "lam": lam, "lam_stderr": lam_sd, "tau": model.tau(s_hat),
            "standard": standard, "n_solves": model.n_solves,
        },
    )  # fmt: skip
    result.likelihood = like
    return result


def _at_bound(eps, bounds):
    if bounds is None:
        return []
    out = []
    for m, (lo, hi) in enumerate(bounds):
        for b in (lo, hi):
            if b is not None and abs(eps[m] - b) <= 1e-8 * max(1.0, abs(b)):
                out.append(m)
    return out


def _uncertainty(p, x, scale, standard, s_hat):
    """Delta method on the profiled marginal likelihood (observed information by central
    differences of ``p`` in the scaled parameters); the standard fit's where tau = 0."""
    if s_hat == 0.0:
        u = standard.uncertainty
        return Uncertainty(
            u.success, "tau = 0: the standard estimate and its uncertainty", u.cov, u.stderr,
            u.intervals, u.level, u.method, u.noise_model, u.dof, u.jacobian,
        )  # fmt: skip
    n, h = x.size, 1e-3
    H = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        H[:, j] = (_fd_gradient(p, x + e, 1e-5) - _fd_gradient(p, x - e, 1e-5)) / (2 * h)
    H = 0.5 * (H + H.T)
    try:
        w = np.linalg.eigvalsh(H)
        if not w[0] > 1e-10 * w[-1]:
            raise np.linalg.LinAlgError("observed information not positive definite")
        cov = np.linalg.inv(H) * np.outer(scale, scale)
    except np.linalg.LinAlgError as e:
        return Uncertainty.failed(f"no delta-method uncertainty: {e}")
    se = np.sqrt(np.diag(cov))
    z = stats.norm.ppf(0.975)
    eps = np.asarray(standard.eps, float) + scale * x
    return Uncertainty(
        True, "observed information of the marginal likelihood (tau profiled out)", cov, se,
        np.column_stack([eps - z * se, eps + z * se]), 0.95, "marginal-likelihood", "known",
    )  # fmt: skip


def _verdict(model, T, s_hat, lam, lam_sd, alpha, at_bound):
    """Restricted likelihood-ratio test of tau = 0 against the boundary mixture."""
    T = max(T, 0.0)
    p = 1.0 if T == 0.0 else 0.5 * float(stats.chi2.sf(T, 1))
    zs = np.divide(lam, lam_sd, out=np.zeros_like(lam), where=lam_sd > 0)
    peak = int(np.argmax(np.abs(lam))) if lam.size else None
    parts = [f"likelihood ratio of tau = 0: T = {T:.3g}, p = {p:.3g} (1/2 chi2_0 + 1/2 chi2_1)"]
    details = {
        "tau": model.tau(s_hat),
        "lr_statistic": T,
        "peak_force_index": peak,
        "force_z": zs,
    }
    return decide(
        "likelihood-ratio tau=0", p, alpha, parts, statistic=T, at_bound=at_bound,
        details=details,
    )  # fmt: skip
