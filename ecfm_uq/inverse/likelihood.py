"""Pseudo-likelihood constraint forces for stochastic models (paper Section 3.3).

A stochastic Galerkin system :math:`R(\\Theta; \\epsilon, \\lambda) = 0` (Eq. pce; the
forces :math:`\\Gamma\\lambda` are deterministic) predicts at the sensors the random
values :math:`v_i(\\omega) = \\mathcal M_{ij}\\Theta_{jk}\\Psi_k(\\omega)` with mean and
variance (Eq. stats)

.. math::

    \\mu_i = \\mathcal M_{ij}\\Theta_{jk}\\,\\mathbb E[\\Psi_k], \\qquad
    \\sigma_i^2 = \\mathcal M_{ij}\\Theta_{jk}\\mathcal M_{ip}\\Theta_{pq}
        \\mathbb E[\\Psi_k\\Psi_q] - \\mu_i^2 .

Replicated data ``v`` (C, D) are scored by the Gaussian negative log pseudo-likelihood
(Eq. Lam)

.. math::

    \\Lambda(\\epsilon, \\lambda) = \\sum_{i=1}^C\\sum_{j=1}^D \\tfrac12\\log 2\\pi\\sigma_i^2
        + \\frac{(v_{ij} - \\mu_i)^2}{2\\sigma_i^2},

whose gradients (Eq. gradlam) follow from the moment sensitivities (Eq. sens_stats)
through :math:`\\partial\\Theta/\\partial\\lambda` (Eq. stochastic_sens) and
:math:`\\partial\\Theta/\\partial\\epsilon`. The inverse problem (Eq. stochastic_model)

.. math::

    \\min_{\\epsilon,\\lambda} \\tfrac12\\|\\lambda\\|^2 \\quad \\text{s.t.}\\quad
    \\partial\\Lambda/\\partial\\lambda = 0

is solved three ways by :func:`fit_pseudo_likelihood`:

``"inner-outer"``
    the ECFM structure: for each :math:`\\epsilon` the forces
    :math:`\\lambda^*(\\epsilon) = \\arg\\min_\\lambda \\Lambda` (a globalized Newton
    solve, checked to be a minimum), then :math:`\\min_\\epsilon \\tfrac12
    \\|\\lambda^*(\\epsilon)\\|^2` with the gradient from the implicit function theorem
    :math:`d\\lambda^*/d\\epsilon = -(\\partial^2\\Lambda/\\partial\\lambda^2)^{-1}
    \\partial^2\\Lambda/\\partial\\lambda\\partial\\epsilon`;
``"penalty"``
    the paper's unconstrained surrogate :math:`\\min_{\\epsilon,\\lambda}
    \\log(\\tfrac12\\|\\lambda\\|^2) + \\alpha\\Lambda` with SLSQP. Its first term is
    unbounded below as :math:`\\lambda \\to 0`; see :func:`fit_pseudo_likelihood`;
``"standard"``
    maximum pseudo-likelihood over :math:`\\epsilon` with :math:`\\lambda = 0`.

Second derivatives of :math:`\\Lambda` are analytic when the system is linear in
:math:`\\Theta` (only :class:`LinearTerm` and :class:`LoadTerm`, as for the beam): then
:math:`\\Theta` is affine in :math:`\\lambda` and
:math:`\\partial^2\\Theta/\\partial\\lambda\\partial\\epsilon` solves
:math:`J\\,\\Theta_{\\lambda\\epsilon} = -(\\partial J/\\partial\\epsilon)\\Theta_\\lambda`.
For nonlinear systems they are central differences of the analytic gradient.
"""

from __future__ import annotations

import copy
import numbers
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.optimize as sopt

from .._validation import as_dense_rows, as_finite_array, check_int, check_positive
from ..errors import ConvergenceError
from ..system import LinearTerm, LoadTerm, solve_steady
from .result import InverseResult

__all__ = [
    "DegenerateVarianceError",
    "ForceSolution",
    "LikelihoodPoint",
    "PseudoLikelihood",
    "eps_curvature",
    "expected_relative_error",
    "fit_pseudo_likelihood",
    "negative_log_pseudo_likelihood",
    "optimal_forces",
    "replicate_statistics",
    "sensor_moments",
]

FORMULATIONS = ("inner-outer", "penalty", "standard")


class DegenerateVarianceError(ValueError):
    """The model predicts (numerically) zero variance at a sensor.

    The Gaussian pseudo-likelihood is then undefined (Eq. Lam divides by
    :math:`\\sigma_i^2`). No floor is applied silently: remove the sensor, or move it
    where the model output is random.
    """


# --------------------------------------------------------------------------------------
# moments and the pseudo-likelihood of given moments (Eqs. stats, sens_stats, Lam)
# --------------------------------------------------------------------------------------
def _centered_gram(E1, E2):
    """:math:`\\mathbb E[\\Psi\\Psi^T] - \\mathbb E[\\Psi]\\mathbb E[\\Psi]^T` (P, P).

    Computing :math:`\\sigma^2 = A\\,C_\\Psi A^T` with this matrix (exactly
    ``diag(0, 1, ..., 1)`` for the orthonormal basis) avoids the cancellation of
    :math:`\\mathbb E[v^2] - \\mu^2` in Eq. stats; the two are equal in exact arithmetic.
    """
    C = E2 - np.outer(E1, E1)
    return 0.5 * (C + C.T)


def sensor_moments(system, M_obs, Theta, dTheta=None):
    """Mean and variance of the sensor outputs and their derivatives (Eqs. stats, sens_stats).

    Parameters
    ----------
    system : GalerkinSystem
        Supplies the chaos moments ``E1`` (P,) and ``E2`` (P, P).
    M_obs : (C, N) array_like
        Sensor matrix :math:`\\mathcal M`.
    Theta : (N, P) array_like
        PCE coefficients.
    dTheta : (N, P, m) array_like, optional
        Derivatives of ``Theta`` in m parameters (forces or model parameters).

    Returns
    -------
    mu : (C,) ndarray
    var : (C,) ndarray
    dmu : (C, m) ndarray
        Only if ``dTheta`` is given: :math:`\\mathcal M\\,\\partial\\Theta\\,\\mathbb E[\\Psi]`.
    dvar : (C, m) ndarray
        Only if ``dTheta`` is given:
        :math:`2\\mathcal M_{ij}\\Theta_{jk}\\mathcal M_{ip}\\partial\\Theta_{pq}
        \\mathbb E[\\Psi_k\\Psi_q] - 2\\mu_i\\partial\\mu_i`.
    """
    M_obs = as_dense_rows("M_obs", M_obs, n_cols=system.N)
    Theta = as_finite_array("Theta", Theta, shape=system.shape)
    Cpsi = _centered_gram(system.E1, system.E2)
    A = M_obs @ Theta
    mu, var = _stats(A, system.E1, Cpsi)
    if dTheta is None:
        return mu, var
    dTheta = as_finite_array("dTheta", dTheta, shape=(system.N, system.P, None))
    dA = np.einsum("ij,jkm->ikm", M_obs, dTheta)
    return (mu, var, *_stats_derivative(A, dA, system.E1, Cpsi))


def _stats(A, E1, Cpsi):
    """Sensor mean and variance from the observed coefficients ``A = M_obs Theta`` (C, P)."""
    return A @ E1, np.einsum("ik,kq,iq->i", A, Cpsi, A)


def _stats_derivative(A, dA, E1, Cpsi):
    """Derivatives (C, m) of the sensor mean and variance for ``dA = M_obs dTheta`` (C, P, m)."""
    return np.einsum("ikm,k->im", dA, E1), 2.0 * np.einsum("ik,kq,iqm->im", A, Cpsi, dA)


def _check_data(v, C):
    v = as_finite_array("v", v, ndim=2)
    if v.shape[0] != C:
        raise ValueError(
            f"`v` must have shape (C, D) = ({C}, D), one row of replicates per sensor; "
            f"got {v.shape}"
        )
    if v.shape[1] < 2:
        raise ValueError(
            f"`v` needs at least 2 replicates per sensor to inform a variance, got D={v.shape[1]}"
        )
    return v


def _check_variance(var, mu, rtol):
    """Raise :class:`DegenerateVarianceError` where :math:`\\sigma_i^2` is lost in round-off."""
    second = var + mu**2
    bad = np.flatnonzero(~(var > rtol * second) | ~(var > 0))
    if bad.size:
        i = int(bad[0])
        raise DegenerateVarianceError(
            f"the model variance at sensor {i} is {var[i]:.3e} (mean {mu[i]:.3e}), numerically "
            "zero: the pseudo-likelihood (Eq. Lam) is undefined there. Remove that sensor or "
            "place it where the model output is random"
        )


def _nll_terms(mu, var, vbar, ss, D):
    """:math:`\\Lambda` and its first and second partials in (mu_i, var_i), per sensor.

    With :math:`S_i = \\sum_j (v_{ij} - \\mu_i)^2 = ss_i + D(\\bar v_i - \\mu_i)^2`,
    :math:`f = \\tfrac D2 \\log 2\\pi s + S/(2s)`.
    """
    r = vbar - mu
    S = ss + D * r**2
    f = 0.5 * D * np.log(2.0 * np.pi * var) + 0.5 * S / var
    f_mu = -D * r / var
    f_s = 0.5 * D / var - 0.5 * S / var**2
    f_mumu = D / var
    f_mus = D * r / var**2
    f_ss = -0.5 * D / var**2 + S / var**3
    return f, f_mu, f_s, f_mumu, f_mus, f_ss


def negative_log_pseudo_likelihood(mu, var, v, dmu=None, dvar=None):
    """The Gaussian negative log pseudo-likelihood of replicated data (Eqs. Lam, gradlam).

    Parameters
    ----------
    mu, var : (C,) array_like
        Model mean and (positive) variance at the sensors.
    v : (C, D) array_like
        ``D >= 2`` replicates per sensor.
    dmu, dvar : (C, m) array_like, optional
        Derivatives of the moments in m parameters.

    Returns
    -------
    value : float
    grad : (m,) ndarray
        Only if ``dmu`` and ``dvar`` are given (Eq. gradlam):
        :math:`\\sum_{ij} \\frac{\\partial_m\\sigma_i^2}{2\\sigma_i^2}
        - \\frac{(v_{ij}-\\mu_i)^2}{2\\sigma_i^4}\\partial_m\\sigma_i^2
        - \\frac{v_{ij}-\\mu_i}{\\sigma_i^2}\\partial_m\\mu_i`.

    Raises
    ------
    DegenerateVarianceError
        If a variance is not positive.
    """
    mu = as_finite_array("mu", mu, ndim=1)
    var = as_finite_array("var", var, shape=mu.shape)
    v = _check_data(v, mu.size)
    if np.any(var <= 0):
        i = int(np.flatnonzero(var <= 0)[0])
        raise DegenerateVarianceError(
            f"`var` must be positive; sensor {i} has variance {var[i]:.3e}. The "
            "pseudo-likelihood (Eq. Lam) is undefined for a deterministic output"
        )
    D = v.shape[1]
    vbar = v.mean(axis=1)
    ss = ((v - vbar[:, None]) ** 2).sum(axis=1)
    f, f_mu, f_s, *_ = _nll_terms(mu, var, vbar, ss, D)
    if dmu is None and dvar is None:
        return float(f.sum())
    if dmu is None or dvar is None:
        raise ValueError("pass both `dmu` and `dvar` for the gradient, or neither")
    dmu = as_finite_array("dmu", dmu, shape=(mu.size, None))
    dvar = as_finite_array("dvar", dvar, shape=dmu.shape)
    return float(f.sum()), f_mu @ dmu + f_s @ dvar


# --------------------------------------------------------------------------------------
# Lambda(eps, lam) through the system
# --------------------------------------------------------------------------------------
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
    def _lam(self, lam):
        if lam is None:
            return np.zeros(self.system.n_forces)
        return self.system.check_lam(lam)

    def solve(self, eps, lam=None):
        """The steady PCE state at (eps, lam); raises ConvergenceError on failure."""
        self.n_solves += 1
        return solve_steady(self.system, eps, self._lam(lam), strict=True, **self.solve_options)

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
        lam = self._lam(lam)
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

        def outer(a, b, w):
            return np.einsum("i,iq,ir->qr", w, a, b)

        H_ll = (
            outer(mu_l, mu_l, f_mumu)
            + outer(mu_l, s_l, f_mus)
            + outer(s_l, mu_l, f_mus)
            + outer(s_l, s_l, f_ss)
            + np.einsum("i,iqr->qr", f_s, s_ll)
        )
        H_le = (
            outer(mu_l, mu_e, f_mumu)
            + outer(mu_l, s_e, f_mus)
            + outer(s_l, mu_e, f_mus)
            + outer(s_l, s_e, f_ss)
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


# --------------------------------------------------------------------------------------
# the inner problem: lam*(eps) = argmin_lam Lambda(eps, lam)
# --------------------------------------------------------------------------------------
@dataclass
class ForceSolution:
    """The likelihood-maximizing constraint forces at one :math:`\\epsilon`.

    Attributes
    ----------
    eps : (n_eps,) ndarray
    lam : (C,) ndarray
        :math:`\\lambda^*(\\epsilon)`.
    point : LikelihoodPoint
        :math:`\\Lambda` and its first and second derivatives at ``lam``.
    dlam_deps : (C, n_eps) ndarray or None
        :math:`-(\\partial^2_{\\lambda\\lambda}\\Lambda)^{-1}\\partial^2_{\\lambda\\epsilon}\\Lambda`
        (``None`` if the Hessian is not positive definite).
    min_hess_eig : float
        Smallest eigenvalue of :math:`\\partial^2\\Lambda/\\partial\\lambda^2`; positive at a
        strict local minimum.
    hess_cond : float
        Its condition number (large means weakly identified forces).
    success : bool
        Converged (Newton decrement below ``tol``) to a strict local minimum.
    message : str
    nit : int
    """

    eps: np.ndarray
    lam: np.ndarray
    point: LikelihoodPoint
    dlam_deps: np.ndarray | None
    min_hess_eig: float
    hess_cond: float
    success: bool
    message: str
    nit: int


def _newton_forces(like, eps, lam, tol, maxiter):
    """Globalized Newton on :math:`\\min_\\lambda \\Lambda(\\epsilon, \\lambda)`.

    Directions use the Hessian with its eigenvalues replaced by their absolute values
    (floored), so every step descends even where :math:`\\Lambda` is not convex; an
    Armijo backtracking search keeps every iterate inside the region where the forward
    solve and the variances exist. Near the minimum the steps are pure Newton steps
    (quadratic convergence). The stopping test is on the Newton decrement
    :math:`\\tfrac12 g^T|H|^{-1}g \\le \\mathrm{tol}\\,(1 + |\\Lambda|)`, which is
    invariant to the (badly) different scales of the forces. Returns
    ``(point, nit, converged, message)``.
    """
    p = like.evaluate(eps, lam, order=2)
    for it in range(maxiter + 1):
        g, H = p.grad_lam, p.hess_lam
        w, V = np.linalg.eigh(H)
        w_abs = np.maximum(np.abs(w), 1e-12 * max(np.abs(w).max(), 1e-300))
        step = -V @ ((V.T @ g) / w_abs)
        slope = float(g @ step)
        scale = 1.0 + abs(p.value)
        if -0.5 * slope <= tol * scale:
            return p, it, True, f"converged: Newton decrement below {tol:.0e} (1 + |Lambda|)"
        if it == maxiter:
            break
        # in the quadratic region Lambda differences drown in round-off; there the
        # full Newton step is accepted if it reduces the gradient
        quadratic = w[0] > 0 and -0.5 * slope <= 1e-8 * scale
        t = 1.0
        for _ in range(40):
            try:
                trial = like.evaluate(eps, p.lam + t * step, order=2)
            except (ConvergenceError, DegenerateVarianceError):
                t *= 0.5
                continue
            if trial.value <= p.value + 1e-4 * t * slope:
                break
            if quadratic and t == 1.0 and np.linalg.norm(trial.grad_lam) < np.linalg.norm(g):
                break
            t *= 0.5
        else:
            return (
                p,
                it,
                False,
                (f"line search failed to decrease Lambda (Newton decrement {-0.5 * slope:.3e})"),
            )
        p = trial
    return p, maxiter, False, f"no convergence in {maxiter} Newton iterations"


def optimal_forces(like, eps, lam0=None, *, tol=1e-15, maxiter=100):
    """The forces that maximize the pseudo-likelihood at fixed :math:`\\epsilon`.

    Solves :math:`\\partial\\Lambda/\\partial\\lambda = 0` (the constraint of Eq.
    stochastic_model) as :math:`\\min_\\lambda\\Lambda(\\epsilon,\\lambda)` with a
    globalized Newton method on the analytic gradient and Hessian (saddle-free directions,
    Armijo backtracking), then checks that the Hessian is positive definite.

    Parameters
    ----------
    like : PseudoLikelihood
    eps : (n_eps,) array_like
    lam0 : (C,) array_like, optional
        Start (zero forces by default).
    tol : float
        Stop when the Newton decrement :math:`\\tfrac12 g^T H^{-1} g` (the predicted
        decrease of :math:`\\Lambda`) is below ``tol * (1 + |Lambda|)``.
    maxiter : int

    Returns
    -------
    ForceSolution
    """
    if like.system.Gamma is None:
        raise ValueError("optimal_forces needs a system with constraint forces (Gamma)")
    eps = like.system.check_eps(eps)
    lam0 = like._lam(lam0)
    tol = check_positive("tol", tol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    point, nit, converged, msg = _newton_forces(like, eps, lam0, tol, maxiter)
    w = np.linalg.eigvalsh(point.hess_lam)
    min_eig = float(w[0])
    cond = float(w[-1] / w[0]) if w[0] > 0 else np.inf
    ok = converged and min_eig > 0
    dlam = None
    if min_eig > 0:
        dlam = -np.linalg.solve(point.hess_lam, point.hess_lam_eps)
    else:
        msg += f"; Hessian in lam is not positive definite (min eigenvalue {min_eig:.3e})"
    return ForceSolution(eps, point.lam, point, dlam, min_eig, cond, ok, msg, nit)


def eps_curvature(like, eps, *, profile=False, step=1e-4):
    """Curvature of :math:`\\Lambda` in :math:`\\epsilon` (the observed pseudo-information).

    ``profile=False``: :math:`\\partial^2\\Lambda(\\epsilon, 0)/\\partial\\epsilon^2`, the
    curvature the standard estimate sees. ``profile=True``: the curvature of the profile
    :math:`\\Lambda^*(\\epsilon) = \\min_\\lambda\\Lambda(\\epsilon, \\lambda)`, whose gradient
    is :math:`\\partial_\\epsilon\\Lambda(\\epsilon, \\lambda^*(\\epsilon))` (envelope theorem):
    how much information on :math:`\\epsilon` is left once the forces are free. Both by
    central differences of the analytic gradient (error O(step^2)).

    Parameters
    ----------
    like : PseudoLikelihood
    eps : (n_eps,) array_like
    profile : bool
    step : float
        Absolute step in :math:`\\epsilon`.

    Returns
    -------
    (n_eps, n_eps) ndarray
    """
    eps = like.system.check_eps(eps)
    step = check_positive("step", step)

    def grad(e):
        if not profile:
            return like.evaluate(e, None, order=1).grad_eps
        fs = optimal_forces(like, e)
        if not fs.success:
            raise ConvergenceError(f"inner solve at eps={e}: {fs.message}")
        return fs.point.grad_eps

    m = eps.size
    H = np.zeros((m, m))
    for r in range(m):
        e = np.zeros(m)
        e[r] = step
        H[:, r] = (grad(eps + e) - grad(eps - e)) / (2 * step)
    return 0.5 * (H + H.T)


# --------------------------------------------------------------------------------------
# the three estimators
# --------------------------------------------------------------------------------------
def _bounds(bounds, n):
    if bounds is None:
        return None
    try:
        b = [
            (None if lo is None else float(lo), None if hi is None else float(hi))
            for lo, hi in bounds
        ]
    except (TypeError, ValueError) as e:
        raise TypeError("`bounds` must be a sequence of (lo, hi) pairs, one per eps") from e
    if len(b) != n:
        raise ValueError(f"`bounds` must have {n} (lo, hi) pairs (one per eps), got {len(b)}")
    return b


_FAILURES = (ConvergenceError, DegenerateVarianceError)


class _Tracker:
    """History of successful evaluations and the failures met by an optimizer."""

    def __init__(self):
        self.eps, self.loss, self.failures = [], [], []
        self.best = None  # (loss, x, payload) with the lowest loss

    def record(self, x, eps, loss, payload):
        self.eps.append(np.array(eps, dtype=float))
        self.loss.append(float(loss))
        if self.best is None or loss < self.best[0]:
            self.best = (float(loss), np.array(x, dtype=float), payload)

    def final(self, x, evaluate):
        """``evaluate(x) -> (loss, payload)`` at the optimizer's answer; if that fails,
        fall back to the best successful evaluation and report it (``ok=False``)."""
        try:
            loss, payload = evaluate(x)
            return np.array(x, dtype=float), loss, payload, True
        except _FAILURES as e:
            self.failures.append(f"final point: {e}")
            if self.best is None:
                raise ConvergenceError(f"no successful evaluation; last failure: {e}") from e
            loss, xb, payload = self.best
            return xb, loss, payload, False


def _trust_region(fun, eps0, bounds, gtol, maxiter, trust_radius):
    """``scipy.optimize.minimize(method="trust-constr")`` with a first step of at most
    ``trust_radius``.

    A bounded first step matters: :math:`\\Lambda(\\epsilon, 0)` is not convex (for the
    beam it falls again as the load nears buckling, where the predicted variance blows
    up), and line-search methods such as L-BFGS-B take a first step of unit length along
    the gradient, which can jump over the physically relevant minimum (for the beam
    from eps0 = 0.5 straight to the upper bound). ``gtol`` is relative to the gradient
    at the start.

    trust-constr also stops, with ``success=True``, when the trust radius falls below
    ``xtol``. That is what happens when trial points keep failing (``fun`` returns
    ``inf`` where the forward or inner solve fails): the radius shrinks onto the edge
    of the solvable region while the gradient there is large. A step-length stop whose
    last trial failed and whose optimality misses ``gtol`` is reported as
    ``success=False`` (a step-length stop amid finite values is round-off in the
    objective near its minimum and stays a success).
    """
    finite = []

    def tracked(x):
        z, g = fun(x)
        finite.append(bool(np.isfinite(z)))
        return z, g

    z0, g0 = tracked(np.array(eps0, dtype=float))
    if not np.isfinite(z0):
        raise ConvergenceError(
            f"the objective cannot be evaluated at the start eps0={eps0} (the forward or "
            "inner solve fails there); choose a start where the model can be solved"
        )
    scale = max(1.0, float(np.abs(g0).max()))
    b = None
    if bounds is not None:
        lo = [-np.inf if lo is None else lo for lo, _ in bounds]
        hi = [np.inf if hi is None else hi for _, hi in bounds]
        b = sopt.Bounds(lo, hi)
    with warnings.catch_warnings():
        # trust-constr warns when it swaps its bound-handling method; not a failure
        warnings.simplefilter("ignore", UserWarning)
        res = sopt.minimize(
            tracked,
            eps0,
            jac=True,
            hess=sopt.BFGS(),
            method="trust-constr",
            bounds=b,
            options={
                "gtol": gtol * scale,
                "xtol": 1e-12,
                "maxiter": maxiter,
                "initial_tr_radius": trust_radius,
                # a small barrier: the default (0.1) biases interior optima by ~1e-5
                "initial_barrier_parameter": 1e-8,
                "initial_barrier_tolerance": 1e-8,
            },
        )
    if res.status == 2 and not finite[-1] and not res.optimality <= gtol * scale:
        res.success = False
        res.message = (
            f"{res.message} but the optimality {res.optimality:.3e} > gtol "
            f"{gtol * scale:.3e}: the trust region collapsed onto the edge of the region "
            "where the model can be solved (the last trial step failed)"
        )
    return res


def _fit_standard(like, eps0, bounds, gtol, maxiter, trust_radius=0.1, **_):
    sysm = like.system
    tr = _Tracker()

    def fun(eps):
        try:
            p = like.evaluate(eps, None, order=1)
        except _FAILURES as e:
            tr.failures.append(str(e))
            return np.inf, np.zeros(sysm.n_eps)
        tr.record(eps, eps, p.value, p)
        return p.value, p.grad_eps

    res = _trust_region(fun, eps0, bounds, gtol, maxiter, trust_radius)

    def evaluate(x):
        p = like.evaluate(x, None, order=1)
        return p.value, p

    x, loss, p, ok = tr.final(res.x, evaluate)
    return res, x, loss, p, ok, tr, {"lam": np.zeros(sysm.n_forces)}


def _fit_inner_outer(
    like, eps0, bounds, gtol, maxiter, lam0=None, trust_radius=0.1, inner_tol=1e-15, **_
):
    sysm = like.system
    tr = _Tracker()
    state = {"lam": like._lam(lam0), "inner_nit": 0}

    def inner(eps):
        # Lambda(eps, .) is not convex and has spurious local minima at large forces
        # (inflated variances absorbing the misfit); a warm start can land on one when
        # eps jumps. Take the lower Lambda of the zero-force and the warm start.
        found = [optimal_forces(like, eps, None, tol=inner_tol)]
        if np.any(state["lam"] != 0):
            found.append(optimal_forces(like, eps, state["lam"], tol=inner_tol))
        state["inner_nit"] += sum(fs.nit for fs in found)
        good = [fs for fs in found if fs.success]
        if not good:
            raise ConvergenceError(f"inner solve at eps={eps}: {found[0].message}")
        return min(good, key=lambda fs: fs.point.value)

    def fun(eps):
        try:
            fs = inner(eps)
        except _FAILURES as e:
            tr.failures.append(str(e))
            return np.inf, np.zeros(sysm.n_eps)
        state["lam"] = fs.lam
        z = 0.5 * float(fs.lam @ fs.lam)
        tr.record(eps, eps, z, fs)
        return z, fs.dlam_deps.T @ fs.lam

    res = _trust_region(fun, eps0, bounds, gtol, maxiter, trust_radius)

    def evaluate(x):
        fs = inner(x)
        return 0.5 * float(fs.lam @ fs.lam), fs

    x, loss, fs, ok = tr.final(res.x, evaluate)
    extra = {
        "lam": fs.lam,
        "inner_message": fs.message,
        "inner_nit": state["inner_nit"],
        "hess_lam_min_eig": fs.min_hess_eig,
        "hess_lam_cond": fs.hess_cond,
        "dlam_deps": fs.dlam_deps,
    }
    return res, x, loss, fs.point, ok, tr, extra


def _fit_penalty(like, eps0, bounds, gtol, maxiter, lam0=None, penalty=100.0, **_):
    sysm = like.system
    m, C = sysm.n_eps, sysm.n_forces
    alpha = check_positive("penalty", penalty)
    if lam0 is None:
        lam0 = np.full(C, 1e-3)
    lam0 = like._lam(lam0)
    if not np.any(lam0):
        raise ValueError(
            "`lam0` must be nonzero for the penalty form: log(0.5 ||lam||^2) is -inf at lam = 0"
        )
    tr = _Tracker()

    def objective(x):
        eps, lam = x[:m], x[m:]
        half = 0.5 * float(lam @ lam)
        if half <= 0.0:
            raise ConvergenceError("reached lam = 0 exactly, where log(0.5 ||lam||^2) = -inf")
        p = like.evaluate(eps, lam, order=1)
        z = np.log(half) + alpha * p.value
        g = np.concatenate([alpha * p.grad_eps, lam / half + alpha * p.grad_lam])
        return z, g, p

    def fun(x):
        try:
            z, g, p = objective(x)
        except _FAILURES as e:
            tr.failures.append(str(e))
            return np.inf, np.zeros_like(x)
        tr.record(x, x[:m], z, p)
        return z, g

    b = None if bounds is None else list(bounds) + [(None, None)] * C
    res = sopt.minimize(
        fun,
        np.concatenate([eps0, lam0]),
        jac=True,
        method="SLSQP",
        bounds=b,
        options={"ftol": gtol, "maxiter": maxiter},
    )
    x, loss, p, ok = tr.final(res.x, lambda x: objective(x)[::2])
    lam = x[m:]
    extra = {
        "lam": lam,
        "penalty": alpha,
        "log_force_term": float(np.log(0.5 * lam @ lam)),
        "grad_lam_norm": float(np.linalg.norm(p.grad_lam)),
        "slsqp_status": int(res.status),
    }
    return res, x, loss, p, ok, tr, extra


_FITTERS = {
    "inner-outer": _fit_inner_outer,
    "penalty": _fit_penalty,
    "standard": _fit_standard,
}


def fit_pseudo_likelihood(
    system,
    M_obs,
    v,
    eps0,
    formulation="inner-outer",
    *,
    lam0=None,
    penalty=100.0,
    bounds=None,
    trust_radius=0.1,
    gtol=1e-8,
    maxiter=200,
    likelihood_options=None,
    inner_tol=1e-15,
    uncertainty=True,
):
    """Estimate :math:`\\epsilon` of a stochastic model from replicated data.

    Parameters
    ----------
    system : GalerkinSystem
        Stochastic system; ``Gamma`` (N, C) is required except for ``"standard"``.
    M_obs : (C, N) array_like
    v : (C, D) array_like
        Replicated measurements, ``D >= 2``.
    eps0 : (n_eps,) array_like
        Start.
    formulation : {"inner-outer", "penalty", "standard"}
        ``"inner-outer"``: :math:`\\min_\\epsilon \\tfrac12\\|\\lambda^*(\\epsilon)\\|^2`
        with :math:`\\lambda^* = \\arg\\min_\\lambda\\Lambda` (the faithful reading of Eq.
        stochastic_model; a trust-region quasi-Newton method outside, globalized Newton
        inside, gradient by the implicit function theorem). ``"penalty"``: the paper's
        :math:`\\min_{\\epsilon,\\lambda}\\log(\\tfrac12\\|\\lambda\\|^2) + \\alpha\\Lambda`
        by SLSQP. ``"standard"``: :math:`\\min_\\epsilon\\Lambda(\\epsilon, 0)` by the same
        trust-region method.
    lam0 : (C,) array_like, optional
        Starting forces: zero for ``"inner-outer"``; for ``"penalty"`` it must be
        nonzero (default ``1e-3`` on every force).
    penalty : float
        :math:`\\alpha` of the penalty form (the paper uses 100).
    bounds : sequence of (lo, hi), optional
        Bounds on :math:`\\epsilon` (keep trial loads below buckling).
    trust_radius : float
        Initial trust radius in :math:`\\epsilon` units (``"inner-outer"``, ``"standard"``):
        the longest first step.
    gtol : float
        Outer gradient tolerance, relative to the gradient at ``eps0`` (``ftol`` of
        SLSQP for ``"penalty"``).
    maxiter : int
        Outer iterations.
    likelihood_options : dict, optional
        Passed to :class:`PseudoLikelihood` (``var_rtol``, ``hessian``, ``fd_step``,
        ``solve_options``).
    inner_tol : float
        Newton-decrement tolerance of the inner force solve (``"inner-outer"``).
    uncertainty : bool
        Attach the delta-method uncertainty from the replicates (about ``8 C`` extra
        gradient evaluations; ``False`` for loops that do not use it).

    Returns
    -------
    InverseResult
        With ``eps_cov``, ``eps_stderr``, ``eps_ci95`` (``noise_model="replicates"``):
        the implicit derivative of the estimate's optimality condition in the replicate
        statistics (:func:`replicate_statistics`) propagated through their sample
        covariance, Student-t intervals with D - 1 dof (not for ``"penalty"``, which no
        optimality condition defines); ``extra["verdict"]`` (:func:`moment_verdict`).
        ``method`` is ``"likelihood-<formulation>"``; ``loss`` is the objective
        minimized; ``extra`` holds ``lam``, ``force_norm`` :math:`\\|\\lambda\\|_2`,
        ``neg_log_likelihood`` :math:`\\Lambda`, ``mu``, ``var``, ``Theta``,
        ``n_solves`` and formulation diagnostics (inner Hessian eigenvalue, SLSQP status).

    Notes
    -----
    The penalty objective is unbounded below: as :math:`\\lambda\\to 0` the term
    :math:`\\log(\\tfrac12\\|\\lambda\\|^2)\\to-\\infty` while :math:`\\alpha\\Lambda` stays
    finite, so it has no minimizer. It can have local minima near the joint maximizer of
    the pseudo-likelihood over :math:`(\\epsilon, \\lambda)`, where the log term's pull
    toward zero forces balances :math:`\\alpha\\,\\partial\\Lambda/\\partial\\lambda`. What
    SLSQP returns depends on the start: either such a local minimum (for the beam, close
    to the inner-outer estimate) or a point on the way down the valley
    :math:`\\lambda\\to 0`, where the :math:`\\epsilon`-part reduces to the standard
    estimate :math:`\\arg\\min_\\epsilon\\Lambda(\\epsilon, 0)`. Its ``success`` flag is
    SLSQP's and certifies neither.
    """
    if formulation not in _FITTERS:
        raise ValueError(
            f"unknown `formulation` {formulation!r}; choose one of {list(FORMULATIONS)}"
        )
    if formulation != "standard" and system.Gamma is None:
        raise ValueError(
            f"formulation={formulation!r} needs a system with constraint forces (Gamma)"
        )
    if isinstance(penalty, bool) or not isinstance(penalty, numbers.Real):
        raise TypeError(f"`penalty` must be a positive number, got {penalty!r}")
    like = PseudoLikelihood(system, M_obs, v, **dict(likelihood_options or {}))
    eps0 = system.check_eps(eps0)
    bounds = _bounds(bounds, system.n_eps)
    gtol = check_positive("gtol", gtol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    trust_radius = check_positive("trust_radius", trust_radius)
    inner_tol = check_positive("inner_tol", inner_tol)
    res, x, loss, p, ok, tr, extra = _FITTERS[formulation](
        like,
        eps0,
        bounds,
        gtol,
        maxiter,
        lam0=lam0,
        penalty=penalty,
        trust_radius=trust_radius,
        inner_tol=inner_tol,
    )
    lam = extra.pop("lam")
    msg = str(res.message)
    ok = ok and bool(res.success)
    if not ok and tr.failures and tr.failures[-1].startswith("final point"):
        msg += f"; {tr.failures[-1]} -- returning the best point evaluated"
    if tr.failures:
        msg += f" ({len(tr.failures)} evaluations failed; first: {tr.failures[0]})"
    extra.update(
        lam=lam,
        force_norm=float(np.linalg.norm(lam)),
        neg_log_likelihood=p.value,
        grad_eps=p.grad_eps,
        mu=p.mu,
        var=p.var,
        Theta=p.Theta,
        n_solves=like.n_solves,
        n_failures=len(tr.failures),
    )
    eps_hat = np.asarray(x[: system.n_eps], dtype=float)
    extra["verdict"] = moment_verdict(p.mu, p.var, like.v)
    if not extra["verdict"]["consistent"]:
        msg += f" [{extra['verdict']['message']}]"
    return InverseResult(
        **(
            _likelihood_uncertainty(like, formulation, eps_hat, lam)
            if uncertainty
            else {"uncertainty_message": "not computed (uncertainty=False)"}
        ),
        eps=eps_hat,
        loss=float(loss),
        success=ok,
        message=msg,
        nit=int(res.nit),
        method=f"likelihood-{formulation}",
        eps_history=np.array(tr.eps).reshape(-1, system.n_eps),
        loss_history=np.array(tr.loss),
        extra=extra,
    )


# --------------------------------------------------------------------------------------
# uncertainty of the estimates (issue 13): delta method on the replicate statistics
# --------------------------------------------------------------------------------------
def replicate_statistics(v):
    """The statistics the pseudo-likelihood sees, and their sample covariance.

    :math:`\\Lambda` depends on the data only through the sensor means
    :math:`\\bar v_i` and the centred second moments :math:`m_i = \\frac1D\\sum_j
    (v_{ij} - \\bar v_i)^2`. Both are (asymptotically) means over the replicates of
    :math:`y_j = (v_{\\cdot j},\\ (v_{\\cdot j} - \\bar v)^2)`, whose covariance is
    estimated by the sample covariance of the :math:`y_j` divided by D (the sensors of one
    replicate may be correlated; replicates are independent).

    Parameters
    ----------
    v : (C, D) array_like
        Replicated data, ``D >= 2``.

    Returns
    -------
    w : (2C,) ndarray
        ``(vbar, m)``.
    Sigma_w : (2C, 2C) ndarray
        Sample covariance of ``w``.
    """
    v = as_finite_array("v", v, ndim=2)
    if v.shape[1] < 2:
        raise ValueError(
            f"`v` needs at least 2 replicates per sensor for a sample covariance, got "
            f"D={v.shape[1]}"
        )
    D = v.shape[1]
    vbar = v.mean(axis=1)
    dev = v - vbar[:, None]
    y = np.vstack([v, dev**2])  # (2C, D): one column per replicate
    return np.concatenate([vbar, (dev**2).mean(axis=1)]), np.atleast_2d(np.cov(y, ddof=1)) / D


def _at_statistics(like, w):
    """A copy of ``like`` whose data statistics are ``w = (vbar, m)`` (see
    :func:`replicate_statistics`); the estimate as a function of the data."""
    new = copy.copy(like)
    new.vbar = np.asarray(w[: like.C], dtype=float)
    new.ss = like.D * np.asarray(w[like.C :], dtype=float)
    return new


#: Newton-decrement tolerance of the inner solves inside the uncertainty's finite
#: differences: their step is 1e-6, so the forces must be exact to far below that (with the
#: fits' 1e-15 the covariance is off by ~1e-5 relative; quadratic convergence makes the
#: extra digits one more Newton step)
_UNCERTAINTY_INNER_TOL = 1e-24


def _likelihood_uncertainty(like, formulation, eps, lam):
    """``InverseResult`` uncertainty fields of a pseudo-likelihood estimate.

    The optimality condition is differentiated implicitly
    (:func:`~ecfm_uq.inverse.uncertainty.implicit_covariance`) in the replicate statistics
    ``w``, with their sample covariance (:func:`replicate_statistics`): a sandwich
    covariance, valid although the Gaussian pseudo-likelihood is not the data's
    distribution. Student-t intervals with D - 1 degrees of freedom (the covariance is
    estimated from D replicates).
    """
    from .uncertainty import estimate_uncertainty

    if formulation == "penalty":
        return {
            "uncertainty_message": "uncertainty not computed: the penalty objective has no "
            "minimizer (it is unbounded below as lam -> 0), so no optimality condition "
            "defines the estimate; use formulation='inner-outer' or 'standard'"
        }
    if formulation == "standard":

        def grad(e, w):
            return _at_statistics(like, w).evaluate(e, None, order=1).grad_eps

    else:

        def grad(e, w):
            fs = optimal_forces(_at_statistics(like, w), e, lam, tol=_UNCERTAINTY_INNER_TOL)
            if not fs.success:
                raise ConvergenceError(f"inner solve at eps={e}: {fs.message}")
            return fs.dlam_deps.T @ fs.lam

    w, Sigma_w = replicate_statistics(like.v)
    return estimate_uncertainty(
        grad, eps, w, Sigma_w, "replicates", dof=like.D - 1, rel_step=1e-4, stencil=4
    )


def moment_verdict(mu, var, v, alpha=0.01):
    """Whether the fitted model's sensor means agree with the replicated data.

    z-scores :math:`z_i = (\\bar v_i - \\mu_i)/\\sqrt{\\sigma_i^2/D}` of the sample means
    against the model's moments (Eq. stats), tested at family-wise level ``alpha`` with
    the Bonferroni quantile :math:`z_{1-\\alpha/(2C)}` (valid however the sensors of a
    replicate are correlated).

    Parameters
    ----------
    mu, var : (C,) array_like
        Model mean and variance at the sensors.
    v : (C, D) array_like
        Replicated data.
    alpha : float

    Returns
    -------
    dict
        ``z`` (C,), ``z_limit``, ``peak_sensor_index``, ``consistent``, ``message``.
    """
    from scipy import stats

    mu = as_finite_array("mu", mu, ndim=1)
    var = as_finite_array("var", var, shape=mu.shape)
    v = _check_data(v, mu.size)
    if not 0 < alpha < 1:
        raise ValueError(f"`alpha` must lie in (0, 1), got {alpha}")
    C, D = v.shape
    z = (v.mean(axis=1) - mu) / np.sqrt(var / D)
    limit = float(stats.norm.ppf(1 - alpha / (2 * C)))
    peak = int(np.argmax(np.abs(z)))
    ok = bool(np.abs(z[peak]) <= limit)
    verdict = "model and data are consistent" if ok else "NOT consistent"
    return {
        "z": z,
        "z_limit": limit,
        "peak_sensor_index": peak,
        "consistent": ok,
        "message": f"{verdict}: largest |z| of the sensor means {abs(z[peak]):.3g} at sensor "
        f"{peak} ({'<=' if ok else '>'} {limit:.3g}, family-wise level {alpha:g})",
    }


# --------------------------------------------------------------------------------------
# error measure of Section 3.3
# --------------------------------------------------------------------------------------
def expected_relative_error(spatial_basis, chaos_basis, Theta_ref, Theta, *, n_x=400, n_omega=400):
    """Expected relative L1 error of a PCE field against a reference PCE field.

    .. math::

        \\mathcal E = \\frac{\\int_0^1\\int_0^1 |u(x,\\omega) - \\hat w(x,\\omega)|\\,dx\\,d\\omega}
                          {\\int_0^1\\int_0^1 |u(x,\\omega)|\\,dx\\,d\\omega},
        \\quad u = f_i(x)\\Theta^{ref}_{ik}\\Psi_k(\\omega)

    (Section 3.3, after Eq. stochastic_model), by tensor composite Gauss quadrature
    (16 points on each of ``n/16`` panels per variable; the absolute value has kinks, so
    the rule is only algebraically accurate -- 400 x 400 points give ~1e-6 relative).

    Parameters
    ----------
    spatial_basis : SinusoidBasis
        With ``evaluate(x) -> (m, N)``.
    chaos_basis : ChaosBasis
        One germ variable.
    Theta_ref, Theta : (N, P) array_like
    n_x, n_omega : int
        Quadrature points per variable (rounded up to a multiple of 16).

    Returns
    -------
    float
    """
    from ..spectral import composite_gauss

    Theta_ref = as_finite_array("Theta_ref", Theta_ref, ndim=2)
    Theta = as_finite_array("Theta", Theta, shape=Theta_ref.shape)
    if chaos_basis.dim != 1:
        raise ValueError("expected_relative_error integrates over one germ variable (dim=1)")
    n_x = check_int("n_x", n_x, minimum=16)
    n_omega = check_int("n_omega", n_omega, minimum=16)

    def rule(n):
        panels = -(-n // 16)
        return composite_gauss(np.linspace(0, 1, panels + 1)[1:-1], 16)

    x, wx = rule(n_x)
    om, wo = rule(n_omega)
    F = spatial_basis.evaluate(x)
    Psi = chaos_basis.evaluate(om)
    u = F @ Theta_ref @ Psi.T
    w = F @ Theta @ Psi.T
    den = wx @ np.abs(u) @ wo
    if not den > 0:
        raise ValueError("`Theta_ref` describes a zero field; the relative error is undefined")
    return float(wx @ np.abs(u - w) @ wo / den)
