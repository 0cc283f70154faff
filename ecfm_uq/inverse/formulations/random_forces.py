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

:math:`\\tau` is estimated by restricted likelihood (REML): the likelihood of the error contrasts
:math:`K^T r`, :math:`K` an orthonormal basis of the complement of
:math:`J = \\mathcal M\\,\\partial\\mathbb E[\\theta]/\\partial\\epsilon`, so that the
parameters fitted to the data do not read as a smaller variance. With
:math:`K^T A A^T K / a_0^2 = V\\,\\mathrm{diag}(\\xi)\\,V^T` and
:math:`q = (V^T K^T r)^2/\\sigma^2`,

.. math::

    2(\\ell_R(0) - \\ell_R(s)) = \\sum_k q_k \\frac{s\\xi_k}{1 + s\\xi_k} - \\log(1 + s\\xi_k),

a scalar function of the scaled variance :math:`s = \\tau^2 a_0^2/\\sigma^2`, maximized on a
log grid and refined by Brent at every :math:`\\epsilon`; :math:`\\epsilon` then minimizes
the marginal likelihood :math:`\\ell(\\epsilon, \\hat\\tau(\\epsilon))` from the standard
estimate with its exact gradient (:mod:`~ecfm_uq.inverse.formulations.random_force_gradient`:
:math:`\\partial A/\\partial\\epsilon` and :math:`\\partial J/\\partial\\epsilon` from one more
back-substitution, :math:`\\hat\\tau`'s dependence on :math:`\\epsilon` by the implicit
function theorem; the search: :mod:`~ecfm_uq.inverse.formulations.random_force_search`).

"Can this model explain these data?" is the restricted likelihood-ratio test of
:math:`\\tau = 0`, :math:`T = \\max_s 2(\\ell_R(0) - \\ell_R(s))`. The null value lies on the
boundary, and with few sensors the asymptotic :math:`\\tfrac12\\chi^2_0 + \\tfrac12\\chi^2_1`
(Self & Liang 1987) is far from the truth (conservative); under :math:`\\tau = 0` the
:math:`q_k` are independent :math:`\\chi^2_1`, so the exact finite-sample null distribution of
:math:`T` (for the model linearized at the estimate, :math:`\\sigma` known) is simulated
from them (after Crainiceanu & Ruppert 2004), with a fixed seed.

With ``options={"force_prior": "sparse"}`` each force has a variance of its own,
:math:`\\lambda_i \\sim N(0, g_i)`, and :math:`S = \\sigma^2 I +
A\\,\\mathrm{diag}(g)\\,A^T`: the variances maximize the marginal likelihood at every
:math:`\\epsilon` (:mod:`~ecfm_uq.inverse.formulations.sparse_forces`, started from the
shared REML estimate), many of them end at zero, and the forces that remain sit where the
model lacks physics. This is the prior of a localized discrepancy (a missing source): with
the shared prior, a discrepancy spread over the sensors costs as little as a localized one,
so a parameter inside the operator can take part of a localized source; with a variance per
force the forces explaining a localized source are cheap and the parameter is not traded for
it (Brynjarsdottir & O'Hagan 2014: what the discrepancy's prior says decides what the
parameters absorb). The profiled likelihood then has local minima (forces switching on and
off) along the valley where the discrepancy trades off against :math:`\\epsilon`: it is
searched from the standard estimate, from the shared prior's and from probes along that
valley, the lowest kept, all with the exact gradient
(:meth:`~ecfm_uq.inverse.formulations.random_force_search.Search.run_sparse`). The
verdict is the same test of :math:`\\tau = 0` at the estimate: one rule for both priors.
"""

from __future__ import annotations

import contextlib
import functools
from collections import OrderedDict
from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize, stats

from ...errors import ConvergenceError, ModelEvaluationError
from ...system import solve_steady
from ...system.solve.factors import cho_factor, cho_solve
from ..core.convergence import SCALED_GRADIENT_TOL, at_bound, scaled_gradient_optimality
from ..core.details import RandomForceDetails
from ..core.finite_differences import fd_gradient
from ..core.fitter import Outcome, holds
from ..core.result import Uncertainty
from ..core.settings import FitSettings
from ..statistics.diagnostics import fd_hessian
from ..statistics.loglik import LogLikelihood
from ..statistics.verdict import decide
from .random_force_gradient import profiled_gradient, second_sensitivities, unit_column_svd
from .random_force_scoring import expected_uncertainty
from .random_force_scoring import gauss_newton_information as _gauss_newton_information
from .random_force_scoring import singular as _singular
from .random_force_search import FAILURES as _FAILURES
from .random_force_search import Search
from .random_force_simulation import nuisance_at, simulated_likelihood
from .sparse_forces import sparse_force_variances
from .steady import fit_steady_problem

__all__ = ["RandomForceModel", "fit_random_force"]

# the scaled variance s = tau^2 * a0^2 / sigma^2 is searched on this log grid, then refined
_S_GRID = np.concatenate([[0.0], np.logspace(-6, 10, 97)])
_N_SIM = 4000  # simulations of the test's null distribution (p-value resolution 1/4001)
_SIM_SEED = 20_261_124  # fixed: the same data always give the same p-value
_MEMO = 256  # points whose linearization and force variances a model remembers


@dataclass(frozen=True)
class Linearization:
    """The model at :math:`\\epsilon` with zero forces: residual and force-to-sensor map."""

    eps: np.ndarray
    r: np.ndarray  # v - M E[theta]
    A: np.ndarray  # M dE[theta]/dlam, (C, n_forces)
    mu: np.ndarray  # eigenvalues of A A^T / a0^2
    w2: np.ndarray  # squared residual in the eigenbasis
    xi: np.ndarray  # eigenvalues of K^T A A^T K / a0^2, K the complement of J
    q: np.ndarray  # squared error contrasts in that eigenbasis, over sigma^2
    J: np.ndarray  # M dE[theta]/deps, (C, n_eps)
    dA: np.ndarray | None = None  # dA/deps, (C, n_forces, n_eps), when asked for
    dJ: np.ndarray | None = None  # dJ/deps, (C, n_eps, n_eps), dJ[:, k, j] = d J_k / d eps_j
    svd: tuple | None = None  # unit_column_svd(J): (norms, U, sv, Vt, rank)


class RandomForceModel:
    """The marginal likelihood :math:`\\ell(\\epsilon, \\tau)` of a steady problem.

    Parameters
    ----------
    problem : SteadyProblem
        With constraint forces (``system.Gamma``).
    sigma : float
        Known noise standard deviation of the data.
    prior : {"shared", "sparse"}
        ``"shared"``: one variance :math:`\\tau^2` for every force (REML);
        ``"sparse"``: a variance per force, by maximum marginal likelihood
        (:mod:`~ecfm_uq.inverse.formulations.sparse_forces`), for a discrepancy that is localized.
    sigma_label : str, optional
        How the likelihoods' descriptions name the noise (``"sigma=1 (whitened: ...)"``
        for a fit of whitened data); default ``"sigma=<sigma>"``.
    """

    def __init__(self, problem, sigma, prior="shared", sigma_label=None):
        system = problem.system
        if system.Gamma is None:
            raise ValueError("the random-force ECFM needs a system with constraint forces (Gamma)")
        self.problem, self.system, self.sigma = problem, system, float(sigma)
        self.sigma_label = sigma_label or f"sigma={self.sigma:g}"
        self.M = problem.M_obs
        self.v = problem.v
        self.a0 = None  # force-to-data scale, fixed at the first linearization
        self.prior = prior
        self.n_solves = 0
        # the last points evaluated, eps bytes -> [Linearization, (g, nll) or None, the
        # profiled nll's gradient or None]: the optimizers and the profiles come back to
        # points they have seen (a restart, the estimate, the finite-difference stencils
        # around it), and a point's value is a deterministic function of eps (a0 is fixed
        # by the first linearization)
        self._memo = OrderedDict()
        self._last = None  # (eps bytes, solution, dTheta/deps, dTheta/dlam) of the last solve
        self.solved = {}  # eps bytes -> a solve made before (the standard fit's), used once

    def linearize(self, eps, second=False):
        """:class:`Linearization` at ``eps`` (one solve and one multi-right-hand-side
        back-substitution; with ``second``, :math:`\\partial A/\\partial\\epsilon` and
        :math:`\\partial J/\\partial\\epsilon` too, one more back-substitution); raises the
        model's error where it cannot be solved."""
        sysm = self.system
        sol = self.solved.pop(np.asarray(eps, float).tobytes(), None)
        if sol is None:
            sol = solve_steady(sysm, eps, strict=True, **self.problem.solve_options)
            self.n_solves += 1
        r = self.v - self.M @ sysm.mean(sol.Theta)
        dTh_l, dTh_e = sol.lam_sensitivity(), sol.eps_sensitivity()[0]
        A = np.asarray(self.M @ np.einsum("nkc,k->nc", dTh_l, sysm.E1))
        J = np.asarray(self.M @ np.einsum("nkm,k->nm", dTh_e, sysm.E1))
        dA = dJ = None
        if second:
            dA, dJ = second_sensitivities(sysm, sol, dTh_e, dTh_l, self.M)
        # the last solve: its second derivatives when asked for next (tau-hat > 0 there)
        self._last = (np.asarray(eps, float).tobytes(), sol, dTh_e, dTh_l)
        AA = A @ A.T
        if self.a0 is None:
            self.a0 = float(np.sqrt(max(np.trace(AA) / AA.shape[0], 1e-300)))
        mu, U = np.linalg.eigh(AA / self.a0**2)
        mu = np.maximum(mu, 0.0)
        # error contrasts: the residual's components orthogonal to what eps can explain
        # (the span of J from its unit columns, by SVD: unit_column_svd)
        svd = unit_column_svd(J)
        U_J, rank = svd[1], svd[4]
        K = U_J[:, rank:]
        xi, V = np.linalg.eigh(K.T @ AA @ K / self.a0**2)
        q = (V.T @ (K.T @ r)) ** 2 / self.sigma**2
        return Linearization(
            np.asarray(eps, float), r, A, mu, (U.T @ r) ** 2, np.maximum(xi, 0.0), q, J, dA, dJ,
            svd,
        )  # fmt: skip

    def nll(self, lin, s):
        """:math:`\\ell` at scaled variance ``s`` (:math:`\\tau^2 = s\\sigma^2/a_0^2`), up to
        the constant :math:`\\tfrac C2 \\log 2\\pi`."""
        d = self.sigma**2 * (1.0 + s * lin.mu)
        return 0.5 * float(np.sum(lin.w2 / d) + np.sum(np.log(d)))

    @staticmethod
    def restricted_drop(q, xi, s):
        """:math:`2(\\ell_R(0) - \\ell_R(s))` of error contrasts ``q`` (squared, over
        sigma^2) with eigenvalues ``xi``; ``q`` (..., K), ``s`` (G,) -> (..., G)."""
        a = s[:, None] * xi[None, :]  # (G, K)
        return q @ (a / (1.0 + a)).T - np.sum(np.log1p(a), axis=1)

    def best_s(self, lin):
        """Restricted-likelihood (REML) estimate of ``s``: the likelihood of the error
        contrasts (the residual orthogonal to what eps explains, so the fitted parameters
        do not read as a smaller variance), on a log grid then Brent; returns
        ``(s, marginal nll at s)``."""
        drop = self.restricted_drop(lin.q, lin.xi, _S_GRID)
        k = int(np.argmax(drop))
        s_hat = 0.0
        if k > 0 and drop[k] > 0.0:
            lo, hi = _S_GRID[k - 1], _S_GRID[min(k + 1, _S_GRID.size - 1)]
            slope = self._restricted_slope(lin)
            if slope(lo) > 0.0 > slope(hi):
                # the stationary point to machine precision (a bounded minimizer: sqrt(eps),
                # too coarse for differences of p(eps)); the bounded maximum below where
                # rounding in the slope keeps Brent from it (eps run far off on a ridge)
                with contextlib.suppress(RuntimeError):
                    s = optimize.brentq(slope, lo, hi, xtol=1e-300, rtol=4 * np.finfo(float).eps)
                    return float(s), self.nll(lin, float(s))
            res = optimize.minimize_scalar(
                lambda x: -self.restricted_drop(lin.q, lin.xi, np.array([x]))[0],
                bounds=(lo, hi), method="bounded", options={"xatol": 1e-10 * hi},
            )  # fmt: skip
            s_hat = float(res.x) if -res.fun > drop[k] else float(_S_GRID[k])
        return s_hat, self.nll(lin, s_hat)

    def tau_strictly_zero(self, eps):
        """Whether tau-hat is 0 at ``eps`` with a strict margin: the restricted drop < 0 at
        every grid point :math:`s > 0` (so :meth:`best_s` returns 0) and its slope at 0,
        :math:`\\sum_k \\xi_k (q_k - 1)`, < 0; both continuous in ``eps`` while :math:`J`
        keeps its rank, so tau-hat is 0 in a neighbourhood (``False`` without contrasts)."""
        lin = self.linearization(eps)
        if lin.xi.size == 0 or not np.any(lin.xi > 0):
            return False
        slope = float(np.sum(lin.xi * (lin.q - 1.0)))
        drop = self.restricted_drop(lin.q, lin.xi, _S_GRID[1:])
        return bool(slope < 0.0 and np.all(drop < 0.0))

    @staticmethod
    def _restricted_slope(lin):
        """:math:`d/ds` of :meth:`restricted_drop`, a function of scalar ``s``: Python
        floats over the few error contrasts (Brent calls it ~20 times at every eps; a numpy
        call per term cost more than the arithmetic). The same operations in the same
        order as the array expression ``sum(q xi / a**2 - xi / a)``."""
        terms = list(zip((lin.q * lin.xi).tolist(), lin.xi.tolist(), strict=True))

        def slope(s):
            total = 0.0
            for qx, x in terms:
                a = 1.0 + s * x
                total += qx / (a * a) - x / a
            return total

        return slope

    def profiled_nll(self, eps):
        """:math:`\\ell(\\epsilon, \\hat\\tau(\\epsilon))`: the marginal likelihood with
        :math:`\\tau` re-estimated (REML) at ``eps`` -- the function the estimate minimizes
        (one solve); raises the model's error where it cannot be solved."""
        lin = self.linearization(eps)
        self._refuse_dead(lin)
        return self._variances(lin)[1]

    def profiled_gradient(self, eps):
        """``(nll, gradient)`` of :meth:`profiled` at ``eps``: the exact gradient
        (:func:`~ecfm_uq.inverse.formulations.random_force_gradient.profiled_gradient`,
        one solve and two back-substitutions), by central differences only where the
        REML estimate is not differentiable (a rank-deficient :math:`J`)."""
        lin = self.linearization(eps)
        g, val = self._variances(lin)
        hit = self._memo.get(lin.eps.tobytes())
        if hit is not None and hit[0] is lin and hit[2] is not None:
            return val, hit[2].copy()  # a point seen before: its gradient remembered
        s, m = None, lin.J.shape[1]
        dA, dJ = np.zeros((*lin.A.shape, m)), np.zeros((*lin.J.shape, m))
        if np.any(g):  # (with g = 0 the dA terms vanish: -J^T S^-1 r, the same bits)
            lin = self.linearization(eps, second=True)
            dA, dJ = lin.dA, lin.dJ
        if self.prior == "shared":
            s = float(g[0]) * self.a0**2 / self.sigma**2 if g.size else 0.0
        grad = profiled_gradient(lin, dA, dJ, self.sigma, g, s, self.a0)
        if grad is None:
            steps = 1e-6 * np.maximum(1.0, np.abs(lin.eps))
            grad = fd_gradient(lambda e: self.profiled(e)[0], lin.eps, steps)
        hit = self._memo.get(lin.eps.tobytes())
        if hit is not None and hit[0] is lin:
            hit[2] = np.array(grad, float)
        return val, grad

    def _checked_gradient(self, eps):
        # the profiles' evaluation: refused where a parameter has no effect (profiled_nll)
        self._refuse_dead(self.linearization(eps))
        return self.profiled_gradient(eps)

    @staticmethod
    def _refuse_dead(lin):
        dead = np.flatnonzero(~(np.linalg.norm(lin.J, axis=0) > 0.0))
        if dead.size:
            # e.g. a reaction rate 10^eps0 that underflowed to zero: the parameter has no
            # effect at all, its direction is lost and the error contrasts would jump to
            # one more dimension (tau-hat and the likelihood with them)
            raise ModelEvaluationError(
                f"eps{dead.tolist()} have no effect on the readings at eps="
                f"{lin.eps.tolist()} (underflow): the error contrasts of tau are "
                "undefined there"
            )

    def profiled(self, eps):
        """``(nll, g, lin)`` at ``eps``: :meth:`linearize` and :meth:`variances`,
        remembered for the last points evaluated."""
        lin = self.linearization(eps)
        g, val = self._variances(lin)
        return val, g, lin

    def linearization(self, eps, second=False):
        """The :class:`Linearization` at ``eps`` (remembered per point; with ``second``
        its second derivatives ``dA``, ``dJ`` too, from the last solve when it was
        there)."""
        key = np.asarray(eps, dtype=float).tobytes()
        hit = self._memo.get(key)
        if hit is not None and (hit[0].dA is not None or not second):
            self._memo.move_to_end(key)
            return hit[0]
        if hit is not None and self._last is not None and self._last[0] == key:
            _, sol, dTh_e, dTh_l = self._last  # the same solve: no new one
            dA, dJ = second_sensitivities(self.system, sol, dTh_e, dTh_l, self.M)
            lin = replace(hit[0], dA=dA, dJ=dJ)
        else:
            lin = self.linearize(eps, second)
        # (a point seen without its second derivatives keeps its variances: the same lin)
        self._memo[key] = [lin, None if hit is None else hit[1], None]
        self._memo.move_to_end(key)
        if len(self._memo) > _MEMO:
            self._memo.popitem(last=False)
        return lin

    def _variances(self, lin):
        hit = self._memo.get(lin.eps.tobytes())
        if hit is None or hit[0] is not lin:
            return self.variances(lin)
        if hit[1] is None:
            hit[1] = self.variances(lin)
        return hit[1]

    def variances(self, lin):
        """The force variances at ``lin`` and the marginal nll there: ``(g, nll)``, ``g``
        of shape (n_forces,): :math:`\\hat\\tau^2` for every force (shared prior), or each
        force's own (sparse prior, started from the shared estimate)."""
        s, val = self.best_s(lin)
        g = np.full(lin.A.shape[1], self.tau(s) ** 2)
        if self.prior == "shared":
            return g, val
        return sparse_force_variances(lin.A, lin.r, self.sigma**2, g)

    def covariance(self, lin, g):
        """The data covariance :math:`\\sigma^2 I + A\\,\\mathrm{diag}(g)\\,A^T`."""
        return self.sigma**2 * np.eye(lin.A.shape[0]) + (lin.A * g) @ lin.A.T

    def profiled_likelihood(self):
        """The :class:`LogLikelihood` :math:`\\ell(\\epsilon, \\hat\\tau(\\epsilon))` of the
        profile-likelihood intervals: :math:`\\tau` re-estimated at every :math:`\\epsilon`,
        so the intervals carry its uncertainty. Its gradient is :meth:`profiled_gradient`,
        exact; the value itself (eigen-decompositions, the REML root) is reproducible to
        ~1e-12 relative only, so the profiles' inner fits keep the looser tolerances of a
        gradient marked inexact (with the tight ones, line searches stalled on that noise
        in equations scaled by 1e9 and left intervals untrusted)."""
        return LogLikelihood(
            self._checked_gradient, self.system.n_eps, self.v.size, "random forces",
            f"marginal likelihood, Gaussian noise {self.sigma_label} and random forces, "
            "tau re-estimated (REML) at every eps",
            exact_gradient=False, nuisance=functools.partial(nuisance_at, self),
            simulate=functools.partial(simulated_likelihood, self),
        )  # fmt: skip

    def restricted_test(self, lin, n_sim=_N_SIM):
        """Restricted likelihood-ratio test of tau = 0: statistic and p-value.

        Under tau = 0 (and the model linearized at the estimate) the squared error
        contrasts over sigma^2 are independent chi2_1, so the statistic's finite-sample
        null distribution is simulated exactly from them (Crainiceanu & Ruppert 2004,
        sigma known) instead of taken from the asymptotic 1/2 chi2_0 + 1/2 chi2_1 mixture,
        which is conservative with few sensors. The grid maximization is the same for the
        data and the simulations."""
        if lin.xi.size == 0 or not np.any(lin.xi > 0):
            return 0.0, 1.0
        T = max(float(self.restricted_drop(lin.q, lin.xi, _S_GRID).max()), 0.0)
        if T == 0.0:
            return T, 1.0  # every simulation reaches 0: nothing to simulate
        # the draws depend on (n_sim, K) only (a fixed seed): drawn once, remembered
        q = _null_contrasts(n_sim, lin.xi.size)
        threshold = T - 1e-12 * max(T, 1.0)
        # a simulation's statistic is at most sum_k q_k (the drop is sum_k q_k c_k(s) -
        # sum_k log(1 + a_k) with 0 <= c_k < 1 and the logs >= 0; rounding is monotone),
        # so only those whose sum reaches the threshold (less a margin for the order of
        # the summation's rounding) can exceed it: the count is that of all of them
        total = q.sum(axis=1)
        candidates = q[total >= threshold - 1e-9 * max(abs(threshold), 1.0)]
        exceed = 0
        for start in range(0, candidates.shape[0], 500):
            chunk = candidates[start : start + 500]  # chunks: the (m, G) array stays in cache
            sims = np.maximum(self.restricted_drop(chunk, lin.xi, _S_GRID).max(axis=1), 0.0)
            exceed += int(np.sum(sims >= threshold))
        return T, (1 + exceed) / (1 + n_sim)

    def conditional_likelihood(self, lin, g):
        """:math:`\\tfrac12 r(\\epsilon)^T S_0^{-1} r(\\epsilon)` with the data covariance
        :math:`S_0 = \\sigma^2 I + A\\,\\mathrm{diag}(g)\\,A^T` held at the estimate: the likelihood
        of :math:`\\epsilon` conditional on the estimated discrepancy (generalized least
        squares), exact gradient :math:`-J^T S_0^{-1} r`. With :math:`\\hat\\tau = 0` it is
        the standard likelihood with ``sigma`` known."""
        chol = cho_factor(self.covariance(lin, g))
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

        none = not np.any(g)
        what = "Gaussian, sigma" if none else "GLS with the estimated discrepancy"
        return LogLikelihood(
            evaluate, sysm.n_eps, self.v.size, "known sigma" if none else "random forces",
            f"{what} covariance held at the estimate ({self.sigma_label}, tau={rms(g):.3g})",
            value_only=value,
        )  # fmt: skip

    def tau(self, s):
        return float(np.sqrt(s) * self.sigma / self.a0)

    def forces(self, lin, g):
        """Posterior mean of the forces (variances ``g``) and their standard deviations."""
        n_f = lin.A.shape[1]
        if not np.any(g):
            return np.zeros(n_f), np.zeros(n_f)
        GAt = g[:, None] * lin.A.T
        SiAG = np.linalg.solve(self.covariance(lin, g), GAt.T)
        lam = SiAG.T @ lin.r
        var = g - np.einsum("ij,ji->i", GAt, SiAG)
        return lam, np.sqrt(np.maximum(var, 0.0))


@functools.lru_cache(maxsize=8)
def _null_contrasts(n_sim, K):
    """The restricted test's null contrasts, ``(n_sim, K)`` chi2_1 draws from the fixed
    seed (read-only, shared by every test with ``K`` contrasts)."""
    q = np.random.default_rng(_SIM_SEED).chisquare(1.0, size=(n_sim, K))
    q.flags.writeable = False
    return q


def rms(g):
    """The root-mean-square force standard deviation: tau of the shared prior."""
    return float(np.sqrt(np.mean(g))) if np.size(g) else 0.0


def fit_random_force(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` of ``formulation="ecfm-random"`` (settings ``s``).

    Starts from the standard estimate (``tau = 0``) and minimizes the marginal likelihood
    with ``tau`` profiled out.

    Returns
    -------
    Outcome
        What was measured (no status); ``extra["standard"]`` is the standard fit's own
        :class:`~ecfm_uq.inverse.core.fitter.Outcome` (what it measured, as
        :func:`~ecfm_uq.inverse.formulations.ode_random.fit_ode_random` keeps its
        standard fit).
    """
    system = problem.system
    opts = s.take({"tau_in_intervals": "profiled", "force_prior": "shared"})  # refuses unknown
    if opts["tau_in_intervals"] not in ("profiled", "held"):
        raise ValueError(
            "`options['tau_in_intervals']` must be 'profiled' (tau re-estimated at every eps "
            "along the profiles, the default) or 'held' (the data covariance held at "
            f"tau-hat), got {opts['tau_in_intervals']!r}"
        )
    if opts["force_prior"] not in ("shared", "sparse"):
        raise ValueError(
            "`options['force_prior']` must be 'shared' (one variance tau^2 for every force, "
            "the default) or 'sparse' (a variance per force: for a localized discrepancy), "
            f"got {opts['force_prior']!r}"
        )
    standard = fit_steady_problem(
        problem, eps0,
        FitSettings("standard", "auto", s.sigma, s.bounds, None, s.maxiter, {}, True, s.alpha),
    )  # fmt: skip
    eps_std = np.asarray(standard.eps, float)
    se = standard.uncertainty.stderr
    magnitude = np.maximum(1.0, np.abs(eps_std))
    scale = 0.1 * magnitude
    if se is not None:
        # the standard errors, capped at the parameter's magnitude (a flat direction has
        # a huge one, and steps of that size leave the range where the model solves)
        scale = np.where(np.isfinite(se) & (se > 0), np.minimum(se, magnitude), scale)
    bnds = None
    if s.bounds is not None:
        bnds = [
            (None if lo is None else (lo - e) / c, None if hi is None else (hi - e) / c)
            for (lo, hi), e, c in zip(s.bounds, eps_std, scale, strict=True)
        ]
    search = Search(
        eps_std, scale, bnds, 200 if s.maxiter is None else s.maxiter,
        SCALED_GRADIENT_TOL if s.tol is None else s.tol,
    )  # fmt: skip
    model = RandomForceModel(problem, s.sigma, "shared", s.sigma_label)
    # the standard fit's solve at its estimate, where the search starts (the same call: the
    # same bits), kept off the result (it holds the factors)
    solved, standard = standard.solution, replace(standard, solution=None)
    seed = {} if solved is None else {np.asarray(solved.eps, float).tobytes(): solved}
    model.solved = dict(seed)
    x, res = search.run(model, np.zeros(system.n_eps), holds(standard.opt, standard.failure),
                        also=(np.asarray(eps0, float) - eps_std) / scale)  # fmt: skip
    if opts["force_prior"] == "sparse":
        # the sparse prior's profiled likelihood has local minima (forces switching on and
        # off): searched from the standard estimate, from the shared prior's and along the
        # valley between them, the lowest kept
        shared = model
        model = RandomForceModel(problem, s.sigma, "sparse", s.sigma_label)
        model.solved = dict(seed)
        starts = [np.zeros(system.n_eps)] + ([x] if np.any(x) else [])
        x, res = search.run_sparse(model, starts)
        model.n_solves += shared.n_solves
    eps = eps_std + scale * x
    val, g_hat, lin = model.profiled(eps)
    try:
        grad = search.gradient(model)(x)
    except _FAILURES:  # e.g. an estimate run off to where a parameter has no effect
        grad = np.full(x.size, np.nan)
    # the one status decision (the optimizer's own success is not asked), from what is
    # measured: the gradient of the profiled marginal likelihood in standard-error units,
    # bounds projected, and the facts below
    opt = scaled_gradient_optimality(grad, x, search.bnds, tol=search.tol)
    hits = at_bound(eps, s.bounds)
    exhausted, failure = res.nit >= search.maxiter, None
    lam, lam_sd = model.forces(lin, g_hat)
    unc = _uncertainty(search.gradient(model), x, scale, standard, g_hat, model, lin,
                       res.get("information"))  # fmt: skip
    message = f"{res.message} [{opt.message}]"
    if opt.converged:
        # a small gradient is not an optimum where the data no longer determine eps (an
        # estimate run off towards infinity, e.g. a reaction rate 10^eps0 -> 0): the same
        # refusal as the standard fit's
        standard_holds = holds(standard.opt, standard.failure)
        if not np.any(g_hat) and not standard_holds and np.allclose(eps, standard.eps):
            # tau = 0: this is the standard fit, and what was measured there is this
            # fit's: its conditions did not hold, its budget, its model failure (where
            # nothing was measured, the model failed there)
            opt = replace(opt, converged=False)
            exhausted = standard.exhausted
            failure = standard.failure
            if failure is None and standard.opt is None:
                failure = standard.message
            message = f"tau = 0, the standard fit: {standard.message}"
        elif _singular(_gauss_newton_information(model, lin, g_hat)):
            # (with tau = 0 too: the search can walk on along the flat direction past
            # where the standard fit stopped, 1e7 further on one machine's last bits)
            # an optimum at infinity: no budget would reach it
            opt = replace(opt, converged=False)
            exhausted = False
            message = (
                f"{message} [NOT converged: the Gauss-Newton information J^T S^-1 J is "
                "singular at the estimate (the readings no longer depend on some parameter "
                "combination): the minimum may lie at infinity]"
            )
    T, p_value = model.restricted_test(lin)
    verdict = _verdict(T, p_value, g_hat, lam, lam_sd, s.alpha, hits)
    # the density of the data given eps (sample_posterior) holds the covariance at tau-hat;
    # the intervals and likelihood-ratio tests profile tau out: re-estimated at every eps
    like = model.conditional_likelihood(lin, g_hat)
    extra = RandomForceDetails(
        force_stderr=lam_sd, tau=rms(g_hat), force_prior=model.prior,
        force_tau=np.sqrt(g_hat), standard=standard, n_solves=model.n_solves,
    )  # fmt: skip
    interval_likelihood = None
    if opts["tau_in_intervals"] == "profiled":
        try:
            model.profiled_nll(eps)
            interval_likelihood = model.profiled_likelihood()
        except _FAILURES as e:
            # an estimate run off to where a parameter has no effect (not converged): its
            # intervals fall back to the held covariance, and say so
            interval_likelihood = (
                f"tau cannot be re-estimated at the estimate ({e}); the intervals hold the "
                "data covariance at tau-hat"
            )
    # the measurement (``fit`` decides the status from it: optimality is opt.value)
    return Outcome(
        eps=eps, loss=val, opt=opt, exhausted=exhausted, failure=failure, message=message,
        nit=standard.nit + res.nit, nfev=standard.nfev + search.nfev,
        njev=standard.njev + res.njev, label="ecfm-random",
        method="L-BFGS-B", forces=lam, uncertainty=unc, verdict=verdict,
        likelihood=like, interval_likelihood=interval_likelihood, extra=extra,
    )  # fmt: skip


def _uncertainty(grad, x, scale, standard, g_hat, model, lin, information=None):
    """Delta method of the random-force ECFM; the standard fit's where tau = 0.

    With tau > 0, where the search ended by Fisher scoring: its expected information
    of the profiled marginal likelihood at the estimate (``information``; evidence:
    :mod:`~ecfm_uq.inverse.formulations.random_force_scoring`). Otherwise, or where that
    is not positive definite, the observed information: central differences of ``grad`` of
    :math:`\\ell(\\epsilon, \\hat\\tau(\\epsilon))` in the scaled parameters. Both carry
    tau's uncertainty. Where the observed one is not positive definite (a flat valley, or
    the kink where :math:`\\hat\\tau(\\epsilon)` leaves zero), :math:`J^T S^{-1} J` with
    :math:`S = \\sigma^2 I + \\hat\\tau^2 AA^T` held at the estimate (the standard fit's
    Gauss-Newton convention with the discrepancy added to the noise; it does not carry
    tau's uncertainty, and the message says so and why)."""
    if not np.any(g_hat):
        u = standard.uncertainty
        return Uncertainty(
            u.success, "tau = 0: the standard estimate and its uncertainty", u.cov, u.stderr,
            u.intervals, u.level, u.method, u.noise_model, u.dof, u.jacobian,
        )  # fmt: skip
    eps = np.asarray(standard.eps, float) + scale * x
    expected = None if information is None else expected_uncertainty(information, eps, scale)
    if expected is not None:
        return expected
    z = stats.norm.ppf(0.975)
    why = None
    try:
        try:
            H = fd_hessian(grad, x, 1e-3)
            w = np.linalg.eigvalsh(H)
        except (ConvergenceError, ModelEvaluationError, ValueError):  # not solvable nearby
            w = np.array([np.nan])
        if w[0] > 1e-10 * w[-1]:
            cov = np.linalg.inv(H) * np.outer(scale, scale)
            se = np.sqrt(np.diag(cov))
            return Uncertainty(
                True, "observed information of the marginal likelihood (tau profiled out)",
                cov, se, np.column_stack([eps - z * se, eps + z * se]), 0.95,
                "marginal-likelihood", "known",
            )  # fmt: skip
        why = (
            "the observed information of the profiled marginal likelihood is not positive "
            f"definite (eigenvalues {np.round(w, 6).tolist()} in standard-error units)"
        )
    except np.linalg.LinAlgError as e:
        why = f"the observed information of the profiled marginal likelihood failed ({e})"
    # the expected information with the covariance held at tau-hat
    F = _gauss_newton_information(model, lin, g_hat)
    if _singular(F):
        return Uncertainty.failed(
            f"no delta-method uncertainty: {why}, and the Gauss-Newton information J^T S^-1 J "
            "is singular (a parameter combination the data do not determine)"
        )
    cov = np.linalg.inv(F)
    se = np.sqrt(np.diag(cov))
    return Uncertainty(
        True,
        f"{why}: Gauss-Newton information J^T S^-1 J with S = sigma^2 I + tau^2 A A^T held at "
        "tau-hat instead (does not carry tau's uncertainty; the profile intervals do)",
        cov, se, np.column_stack([eps - z * se, eps + z * se]), 0.95,
        "gauss-newton-held-tau", "known",
    )  # fmt: skip


def _verdict(T, p, g_hat, lam, lam_sd, alpha, at_bound):
    """The verdict of the restricted likelihood-ratio test of tau = 0."""
    zs = np.divide(lam, lam_sd, out=np.zeros_like(lam), where=lam_sd > 0)
    peak = int(np.argmax(np.abs(lam))) if lam.size else None
    parts = [f"restricted likelihood ratio of tau = 0: T = {T:.3g}, p = {p:.3g} (exact null)"]
    details = {"tau": rms(g_hat), "lr_statistic": T, "peak_force_index": peak, "force_z": zs}
    return decide(
        "likelihood-ratio tau=0", p, alpha, parts, statistic=T, at_bound=at_bound,
        details=details,
    )  # fmt: skip
