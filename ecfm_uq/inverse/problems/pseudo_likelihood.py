"""The pseudo-likelihood :math:`\\Lambda(\\epsilon, \\lambda)` of replicated data through a
stochastic system, with its first and second derivatives (paper Section 3.3, Eqs. Lam,
gradlam, sens_stats, stochastic_sens).

Second derivatives of :math:`\\Lambda` are analytic when the system is linear in
:math:`\\Theta` (only :class:`LinearTerm` and :class:`LoadTerm`, as for the beam): then
:math:`\\Theta` is affine in :math:`\\lambda` and
:math:`\\partial^2\\Theta/\\partial\\lambda\\partial\\epsilon` solves
:math:`J\\,\\Theta_{\\lambda\\epsilon} = -(\\partial J/\\partial\\epsilon)\\Theta_\\lambda`.
For nonlinear systems they are central differences of the analytic gradient.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import as_dense_rows, check_int, check_positive
from ...system import LinearTerm, LoadTerm, solve_steady
from .moments import (
    _centered_gram,
    _check_data,
    _check_variance,
    _nll_terms,
    _stats,
    _stats_derivative,
    sensor_moments,
)

__all__ = ["LikelihoodPoint", "PseudoLikelihood"]


@dataclass
class LikelihoodPoint:
    """:math:`\\Lambda` and its derivatives at one :math:`(\\epsilon, \\lambda)`.

    Attributes
    ----------
    eps : (n_eps,) ndarray
    lam : (C,) ndarray
    value : float
        :math:`\\Lambda(\\epsilon, \\lambda)` (Eq. Lam).
    mu, var : (C,) ndarray
        Sensor moments (Eq. stats).
    Theta : (N, P) ndarray
    grad_lam : (C,) ndarray or None
        :math:`\\partial\\Lambda/\\partial\\lambda` (Eq. gradlam).
    grad_eps : (n_eps,) ndarray or None
        :math:`\\partial\\Lambda/\\partial\\epsilon`.
    hess_lam : (C, C) ndarray or None
        :math:`\\partial^2\\Lambda/\\partial\\lambda^2`.
    hess_lam_eps : (C, n_eps) ndarray or None
        :math:`\\partial^2\\Lambda/\\partial\\lambda\\partial\\epsilon`.
    """

    eps: np.ndarray
    lam: np.ndarray
    value: float
    mu: np.ndarray
    var: np.ndarray
    Theta: np.ndarray
    grad_lam: np.ndarray | None = None
    grad_eps: np.ndarray | None = None
    hess_lam: np.ndarray | None = None
    hess_lam_eps: np.ndarray | None = None


class PseudoLikelihood:
    """:math:`\\Lambda(\\epsilon, \\lambda)` of replicated data for a stochastic system.

    Parameters
    ----------
    system : GalerkinSystem
        Stochastic (``P > 1``) system; needs ``Gamma`` (N, C) for derivatives in
        :math:`\\lambda`.
    M_obs : (C, N) array_like
        Sensor matrix, one row per data row.
    v : (C, D) array_like
        Replicated data, ``D >= 2``.
    var_rtol : float
        A sensor whose variance is at most ``var_rtol`` times its second moment is
        declared degenerate (:class:`DegenerateVarianceError`); nothing is floored.
    hessian : {"auto", "analytic", "fd"}
        Second derivatives: analytic (systems linear in Theta only), central differences
        of the analytic gradient, or ``"auto"`` (analytic where possible).
    fd_step : float
        Relative step of the finite-difference Hessian.
    solve_options : dict, optional
        Passed to :func:`solve_steady` (``tol``, ``maxiter``).
    """

    def __init__(
        self,
        system,
        M_obs,
        v,
        *,
        var_rtol=1e-12,
        hessian="auto",
        fd_step=1e-5,
        solve_options=None,
    ):
        if system.P < 2:
            raise ValueError(
                "the pseudo-likelihood needs a stochastic system (chaos basis with P >= 2); "
                f"got P={system.P}, whose variance is identically zero"
            )
        self.system = system
        self.M_obs = as_dense_rows("M_obs", M_obs)
        if self.M_obs.shape[1] != system.N:
            raise ValueError(f"`M_obs` must have {system.N} columns (N), got {self.M_obs.shape}")
        self.v = _check_data(v, self.M_obs.shape[0])
        self.C, self.D = self.v.shape
        if system.Gamma is not None and system.n_forces != self.C:
            raise ValueError(
                f"the system has {system.n_forces} constraint forces but `v` has {self.C} "
                "sensors; ECFM puts one force on each sensor"
            )
        self.vbar = self.v.mean(axis=1)
        self.ss = ((self.v - self.vbar[:, None]) ** 2).sum(axis=1)
        self.var_rtol = check_positive("var_rtol", var_rtol)
        if hessian not in ("auto", "analytic", "fd"):
            raise ValueError(f"unknown `hessian` {hessian!r}; choose 'auto', 'analytic' or 'fd'")
        self.linear = all(isinstance(t, LinearTerm | LoadTerm) for t in system.terms)
        if hessian == "analytic" and not self.linear:
            raise ValueError(
                "hessian='analytic' needs a system linear in Theta (LinearTerm/LoadTerm only); "
                "use hessian='fd'"
            )
        self.hessian = "analytic" if (hessian == "auto" and self.linear) else hessian
        if self.hessian == "auto":
            self.hessian = "fd"
        self.fd_step = check_positive("fd_step", fd_step)
        self.solve_options = dict(solve_options or {})
        self.Cpsi = _centered_gram(system.E1, system.E2)
        self.n_solves = 0

    # -- pieces -----------------------------------------------------------------------
    def forces(self, lam):
        """``lam`` checked as the system's constraint forces, zeros for ``None``."""
        if lam is None:
            return np.zeros(self.system.n_forces)
        return self.system.check_lam(lam)

    def solve(self, eps, lam=None):
        """The steady PCE state at (eps, lam); raises ConvergenceError on failure."""
        self.n_solves += 1
        return solve_steady(self.system, eps, self.forces(lam), strict=True, **self.solve_options)

    def moments(self, Theta):
        """Sensor mean and variance (Eq. stats), each (C,)."""
        return sensor_moments(self.system, self.M_obs, Theta)

    def value(self, eps, lam=None):
        """:math:`\\Lambda(\\epsilon, \\lambda)` (Eq. Lam)."""
        return self.evaluate(eps, lam, order=0).value

    def evaluate(self, eps, lam=None, order=1):
        """:math:`\\Lambda` with derivatives up to ``order`` (0, 1 or 2).

        ``order=1`` gives both gradients (:math:`\\lambda` only if the system has
        ``Gamma``); ``order=2`` adds :math:`\\partial^2\\Lambda/\\partial\\lambda^2` and
        :math:`\\partial^2\\Lambda/\\partial\\lambda\\partial\\epsilon`.

        Returns
        -------
        LikelihoodPoint

        Raises
        ------
        ConvergenceError
            If the forward solve fails (e.g. a singular, buckled system).
        DegenerateVarianceError
            If a sensor variance is numerically zero.
        """
        order = check_int("order", order, minimum=0)
        if order > 2:
            raise ValueError(f"`order` must be 0, 1 or 2, got {order}")
        sysm = self.system
        eps = sysm.check_eps(eps)
        lam = self.forces(lam)
        if order == 2 and sysm.Gamma is None:
            raise ValueError("second derivatives in lam need a system with Gamma")
        sol = self.solve(eps, lam)
        Theta = sol.Theta
        A = self.M_obs @ Theta
        mu, var = _stats(A, sysm.E1, self.Cpsi)
        _check_variance(var, mu, self.var_rtol)
        f, f_mu, f_s, f_mumu, f_mus, f_ss = _nll_terms(mu, var, self.vbar, self.ss, self.D)
        point = LikelihoodPoint(eps, lam, float(f.sum()), mu, var, Theta)
        if order == 0:
            return point

        dTh_e, _ = sol.eps_sensitivity()
        A_e = np.einsum("ij,jkm->ikm", self.M_obs, dTh_e)
        mu_e, s_e = _stats_derivative(A, A_e, sysm.E1, self.Cpsi)
        point.grad_eps = f_mu @ mu_e + f_s @ s_e
        if sysm.Gamma is not None:
            dTh_l = sol.lam_sensitivity()
            A_l = np.einsum("ij,jkm->ikm", self.M_obs, dTh_l)
            mu_l, s_l = _stats_derivative(A, A_l, sysm.E1, self.Cpsi)
            point.grad_lam = f_mu @ mu_l + f_s @ s_l
        if order == 1:
            return point

        if self.hessian == "fd":
            point.hess_lam, point.hess_lam_eps = self._fd_hessian(eps, lam)
            return point
        # analytic: Theta affine in lam (d2 Theta / d lam2 = 0); the mixed derivative
        # solves J Theta_le = -(dJ/d eps) Theta_l, and (dJ/d eps) X is the eps-derivative
        # of the linear terms evaluated at X (loads do not depend on Theta).
        n, C, m = sysm.N * sysm.P, self.C, sysm.n_eps
        rhs = np.zeros((n, C * m))
        for q in range(C):
            X = dTh_l[:, :, q]
            for term in sysm.terms:
                if isinstance(term, LinearTerm):
                    rhs[:, q * m : (q + 1) * m] += term.eps_jacobian(X, eps)
        # the converged solve's factors (dense or decoupled) serve the mixed derivative too
        dTh_le = -sol.jacobian_solve(rhs).reshape(sysm.N, sysm.P, C, m)
        A_le = np.einsum("ij,jkqm->ikqm", self.M_obs, dTh_le)
        mu_le = np.einsum("ikqm,k->iqm", A_le, sysm.E1)
        s_ll = 2.0 * np.einsum("ikq,kl,ilr->iqr", A_l, self.Cpsi, A_l)
        s_le = 2.0 * np.einsum("ikm,kl,ilq->iqm", A_e, self.Cpsi, A_l) + 2.0 * np.einsum(
            "ik,kl,ilqm->iqm", A, self.Cpsi, A_le
        )

        def gauss_newton(mu_a, s_a, mu_b, s_b):
            """The second derivatives of Lambda in the moments, contracted with the
            moments' first derivatives in a and in b."""

            def outer(a, b, w):
                return np.einsum("i,iq,ir->qr", w, a, b)

            return (
                outer(mu_a, mu_b, f_mumu)
                + outer(mu_a, s_b, f_mus)
                + outer(s_a, mu_b, f_mus)
                + outer(s_a, s_b, f_ss)
            )

        H_ll = gauss_newton(mu_l, s_l, mu_l, s_l) + np.einsum("i,iqr->qr", f_s, s_ll)
        H_le = (
            gauss_newton(mu_l, s_l, mu_e, s_e)
            + np.einsum("i,iqm->qm", f_mu, mu_le)
            + np.einsum("i,iqm->qm", f_s, s_le)
        )
        point.hess_lam = 0.5 * (H_ll + H_ll.T)
        point.hess_lam_eps = H_le
        return point

    def _fd_hessian(self, eps, lam):
        """Central differences of the analytic gradient in lam (error O(h^2))."""
        C, m = self.C, self.system.n_eps
        H_ll = np.zeros((C, C))
        H_le = np.zeros((C, m))
        for r in range(C):
            h = self.fd_step * max(1.0, abs(lam[r]))
            e = np.zeros(C)
            e[r] = h
            gp = self.evaluate(eps, lam + e, order=1).grad_lam
            gm = self.evaluate(eps, lam - e, order=1).grad_lam
            H_ll[:, r] = (gp - gm) / (2 * h)
        for r in range(m):
            h = self.fd_step * max(1.0, abs(eps[r]))
            e = np.zeros(m)
            e[r] = h
            gp = self.evaluate(eps + e, lam, order=1).grad_lam
            gm = self.evaluate(eps - e, lam, order=1).grad_lam
            H_le[:, r] = (gp - gm) / (2 * h)
        return 0.5 * (H_ll + H_ll.T), H_le
