"""Standard and ECFM inverse problems for steady systems (paper Eqs. traditional, ecfm;
Section 4).

Both are reduced to unconstrained problems in :math:`\\epsilon` by treating the state
(and, for ECFM, the forces) as functions of :math:`\\epsilon` through the system and its
sensitivities:

* standard: :math:`z^{INV}(\\epsilon) = \\tfrac12\\|\\mathcal M\\,\\mathbb E[\\theta(\\epsilon)] - v\\|^2`,
  :math:`\\nabla z = e^T \\mathcal M\\,\\partial\\mathbb E[\\theta]/\\partial\\epsilon`;
* ECFM (inner-outer): :math:`(\\theta, \\lambda)(\\epsilon)` solve
  :math:`R(\\theta;\\epsilon) - \\Gamma\\lambda = 0,\\ \\mathcal M\\theta = v`, and
  :math:`z^{ECFM}(\\epsilon) = \\tfrac12\\|\\lambda(\\epsilon)\\|^2`,
  :math:`\\nabla z = \\lambda^T\\partial\\lambda/\\partial\\epsilon`.
"""

from __future__ import annotations

import numpy as np

from ..._validation import as_finite_array, as_operator
from ...errors import ConvergenceError, NonIdentifiableError
from ...system import solve_steady
from ..core.convergence import OFFSET_TOL
from ..core.drivers import (
    LEAST_SQUARES_KEYWORDS,
    check_minimize_method,
    least_squares_scaled,
    minimize_scaled,
    verify_least_squares,
)
from ..core.fitter import Outcome, measured
from ..core.gradients import choose_gradient
from ..core.result import Uncertainty, Verdict
from ..problems.galerkin import lazy_standard_residual
from ..statistics.uncertainty import estimate_uncertainty, least_squares_jacobian, residual_variance
from ..statistics.verdict import consistency_verdict


def _data(system, M_obs, v):
    M_obs = as_operator("M_obs", M_obs)
    if M_obs.shape[1] != system.N:
        raise ValueError(f"`M_obs` must have {system.N} columns (N), got {M_obs.shape}")
    v = as_finite_array("v", v, shape=(M_obs.shape[0],))
    return M_obs, v


def standard_objective(system, M_obs, v, eps, gradient="auto", **solve_kw):
    """:math:`z^{INV}` and its gradient at ``eps``.

    ``gradient`` chooses forward sensitivities or one adjoint solve
    (:func:`~ecfm_uq.inverse.core.gradients.choose_gradient`); both give the same gradient.

    Returns
    -------
    z : float
    grad : (n_eps,) ndarray
    sol : SteadySolution

    Raises
    ------
    ValueError
        If ``M_obs`` is not (C, N) or ``v`` not (C,), or either is not finite.
    """
    M_obs, v = _data(system, M_obs, v)
    sol = solve_steady(system, eps, strict=True, **solve_kw)
    e = M_obs @ system.mean(sol.Theta) - v
    if choose_gradient(gradient, system.n_eps) == "adjoint":
        g_theta = np.outer(M_obs.T @ e, system.E1)  # dz/dTheta
        return 0.5 * float(e @ e), sol.adjoint_gradient(g_theta), sol
    dTheta, _ = sol.eps_sensitivity()
    dmean = np.einsum("ikm,k->im", dTheta, system.E1)
    return 0.5 * float(e @ e), (M_obs @ dmean).T @ e, sol


def ecfm_objective(system, M_obs, v, eps, gradient="auto", **solve_kw):
    """:math:`z^{ECFM}` and its gradient at ``eps`` (equality-constrained forces).

    Returns
    -------
    z : float
    grad : (n_eps,) ndarray
    sol : SteadySolution
        With ``sol.lam`` the constraint forces :math:`\\lambda(\\epsilon)`.
    """
    sol = solve_steady(system, eps, constraint=(M_obs, v), strict=True, **solve_kw)
    z = 0.5 * float(sol.lam @ sol.lam)
    if choose_gradient(gradient, system.n_eps) == "adjoint":
        return z, sol.adjoint_gradient(system.zeros(), sol.lam), sol
    _, dlam = sol.eps_sensitivity()
    return z, dlam.T @ sol.lam, sol


def standard_residual(system, M_obs, v, eps, **solve_kw):
    """The residual :math:`r = \\mathcal M\\,\\mathbb E[\\theta(\\epsilon)] - v` of
    :math:`z^{INV} = \\tfrac12\\|r\\|^2` and its sensitivity Jacobian.

    Returns
    -------
    r : (C,) ndarray
    J : (C, n_eps) ndarray
        :math:`\\mathcal M\\,\\partial\\mathbb E[\\theta]/\\partial\\epsilon` (forward
        sensitivities with the factored Jacobian).
    sol : SteadySolution
    """
    M_obs, v = _data(system, M_obs, v)
    solve_kw.pop("gradient", None)
    r, J, sol = lazy_standard_residual(system, M_obs, v, eps, **solve_kw)
    return r, J(), sol


def ecfm_residual(system, M_obs, v, eps, **solve_kw):
    """The constraint forces :math:`\\lambda(\\epsilon)`, residual of
    :math:`z^{ECFM} = \\tfrac12\\|\\lambda\\|^2`, and their Jacobian
    :math:`\\partial\\lambda/\\partial\\epsilon`.

    Returns
    -------
    lam : (C,) ndarray
    dlam : (C, n_eps) ndarray
    sol : SteadySolution
    """
    solve_kw.pop("gradient", None)
    sol = solve_steady(system, eps, constraint=(M_obs, v), strict=True, **solve_kw)
    _, dlam = sol.eps_sensitivity()
    return np.asarray(sol.lam), np.asarray(dlam), sol


_OBJECTIVES = {"standard": standard_objective, "ecfm": ecfm_objective}
#: options of the steady least-squares fits: ours, then the least-squares driver's
LEAST_SQUARES_OPTIONS = ("covariance", "polish", *LEAST_SQUARES_KEYWORDS)
_RESIDUALS = {"standard": standard_residual, "ecfm": ecfm_residual}
#: the least-squares driver's options (the rest go to scipy.optimize.least_squares) and
#: the covariance conventions
_COVARIANCES = ("gauss-newton", "sandwich")
#: the minimize methods' gradient tolerance (relative: the optimizer sees the objective
#: divided by its value at eps0, so it has no data units); options={"gtol": ...} overrides
_DEFAULT_TOL = 1e-10
_DEFAULT_MAXITER = 500
#: residual evaluations allowed to the least-squares method (its `maxiter`): hard
#: problems (NIST Bennett5 from its first start) need over 1000
_DEFAULT_MAX_NFEV = 2000


def fit_steady_problem(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` for a :class:`~ecfm_uq.inverse.problems.galerkin.SteadyProblem` (validated
    settings ``s``, a :class:`~ecfm_uq.inverse.core.settings.FitSettings`), reduced
    formulations ``"standard"`` and ``"ecfm"``.

    Returns
    -------
    Outcome
        What was measured at the returned point (the driver's ``opt``, ``exhausted`` and
        model failure, :func:`~ecfm_uq.inverse.core.fitter.measured`) with the
        uncertainty and the verdict; no status (:func:`~ecfm_uq.inverse.fit` decides it).
    """
    system = problem.system
    if s.formulation not in _OBJECTIVES:
        raise ValueError(
            f"unknown `formulation` {s.formulation!r}; choose 'standard', 'ecfm' or 'noisy-ecfm'"
        )
    if s.formulation == "ecfm" and system.Gamma is None:
        raise ValueError("formulation='ecfm' needs a system with constraint forces (Gamma)")
    M_obs, v = problem.M_obs, problem.v
    eps0 = system.check_eps(eps0)
    lsq = s.method in ("auto", "least-squares", "trf")
    method = "least-squares" if lsq else s.method
    if not lsq:
        check_minimize_method(method)
    if lsq:  # by name, before any model solve (scipy would refuse after the first)
        s.take(dict.fromkeys(LEAST_SQUARES_OPTIONS))
    options = dict(s.options)
    covariance = options.pop("covariance", "gauss-newton")
    if covariance not in _COVARIANCES:
        raise ValueError(f"options['covariance'] must be one of {_COVARIANCES}, got {covariance!r}")
    polish = options.pop("polish", lsq)
    if not isinstance(polish, bool):
        raise TypeError(f"options['polish'] must be True or False, got {polish!r}")
    if s.maxiter is not None:
        maxiter = s.maxiter
    else:
        maxiter = _DEFAULT_MAX_NFEV if lsq else _DEFAULT_MAXITER
    bounds, sigma = s.bounds, s.sigma
    if v.size < system.n_eps:
        raise ValueError(
            f"`v` has {v.size} measurements for {system.n_eps} parameters: fewer sensors "
            "than parameters cannot determine eps; add sensors (rows of `M_obs`) or fix "
            "parameters"
        )
    objective = _OBJECTIVES[s.formulation]
    solve_kw = {**problem.solve_options, "gradient": problem.gradient}

    def evaluate(eps):
        return objective(system, M_obs, v, eps, **solve_kw)

    def residual(eps):
        return _RESIDUALS[s.formulation](system, M_obs, v, eps, **problem.solve_options)

    try:
        if lsq:
            out = least_squares_scaled(residual, eps0, bounds, s.tol, maxiter, options)
        else:
            # tol is the status test's (the relative offset); the optimizer's own gtol is
            # its default unless options give one
            out = minimize_scaled(evaluate, eps0, method, bounds, _DEFAULT_TOL, maxiter, options)
            out = verify_least_squares(
                out, residual, bounds, out.exhausted, polish=polish,
                tol=OFFSET_TOL if s.tol is None else s.tol,
            )  # fmt: skip
    except ConvergenceError as e:
        raise ConvergenceError(f"fit: {e}") from e
    if out.payload is None:  # the optimizer stopped where the model fails
        return Outcome(
            eps=out.x, loss=np.inf, message=out.message, nit=out.nit, nfev=out.nfev,
            label=s.formulation, method=method, eps_history=out.eps_history,
            loss_history=out.loss_history,
            verdict=Verdict(False, test="none", message=f"NOT consistent: {out.final_error}"),
            **measured(out),
        )  # fmt: skip
    res, z, sol, msg = out, out.loss, out.payload, out.message
    # the unforced solve at the estimate, shared by the verdict and the residual sigma
    free = (
        sol if s.formulation == "standard" else solve_steady(system, res.x, **problem.solve_options)
    )
    if s.uncertainty:
        unc = _uncertainty(
            system, M_obs, v, np.asarray(res.x), s.formulation, solve_kw, sigma, free, covariance
        )
    else:
        unc = Uncertainty.failed("not computed (uncertainty=False)")
    lam = sol.lam if s.formulation == "ecfm" else np.zeros(0)
    verdict = consistency_verdict(
        system, M_obs, v, res.x, lam, bounds, sigma=sigma, alpha=s.alpha,
        n_fitted=system.n_eps, solution=free,
    )  # fmt: skip
    if verdict.consistent is False or verdict.identifiability:
        msg += f" [{verdict.message}]"
    return Outcome(
        uncertainty=unc,
        eps=np.asarray(res.x),
        loss=z,
        message=msg,
        nit=out.nit,
        nfev=out.nfev,
        njev=out.nfev,
        label=s.formulation,
        method=method,
        eps_history=out.eps_history,
        loss_history=out.loss_history,
        state=sol.Theta,
        solution=sol if s.formulation == "standard" else None,
        forces=lam if s.formulation == "ecfm" else None,
        verdict=verdict,
        **measured(out),
    )


def _uncertainty(
    system, M_obs, v, eps, formulation, solve_kw, sigma, free=None, covariance="gauss-newton"
):
    """Delta-method covariance of the fitted eps; ``free`` is the unforced solve at
    ``eps`` if the caller has it (its residual estimates sigma).

    ``covariance="gauss-newton"`` (default): the curvature of the sum of squares is
    :math:`J^TJ` (:math:`J` the residual's Jacobian), so the standard formulation gives
    :math:`s^2(J^TJ)^{-1}`, the convention of NIST's certified values and of every
    regression package. ``"sandwich"``: the full Hessian by finite differences of the
    gradient, :math:`H^{-1}J^TJH^{-1}s^2` (the v0.2 convention).
    """
    objective = _OBJECTIVES[formulation]
    try:
        if sigma is not None:
            s2, model, dof = float(sigma) ** 2, "known", None
        else:
            if free is None:
                opts = {k: w for k, w in solve_kw.items() if k != "gradient"}
                free = solve_steady(system, eps, **opts)
            if not free.success:
                raise ConvergenceError(f"the unforced model fails at the estimate: {free.message}")
            sol = free
            r = M_obs @ system.mean(sol.Theta) - v
            # project out the model's tangent space: the least-squares residual of the
            # linearized model, so the ECFM estimate's own misfit does not inflate s^2
            dTheta, _ = sol.eps_sensitivity()
            J = M_obs @ np.einsum("ikm,k->im", dTheta, system.E1)
            r = r - J @ np.linalg.lstsq(J, r, rcond=None)[0]
            s2, model, dof = residual_variance(r, eps.size), "estimated", r.size - eps.size
        hessian = None
        if covariance == "gauss-newton":
            opts = {k: w for k, w in solve_kw.items() if k != "gradient"}
            _, Jr, _ = _RESIDUALS[formulation](system, M_obs, v, eps, **opts)
            hessian = Jr.T @ Jr
    except (ConvergenceError, ValueError) as e:
        return Uncertainty.failed(f"uncertainty not computed: {e}")
    if covariance == "gauss-newton" and formulation == "standard":
        # d eps_hat / dv = J^+ exactly (g = J^T (M theta - v)), by the SVD of J
        try:
            D = least_squares_jacobian(Jr)
        except NonIdentifiableError as e:
            return Uncertainty.failed(f"uncertainty not computed: {e}")
        return estimate_uncertainty(None, eps, v, s2, model, dof=dof, deps_dv=D)
    return estimate_uncertainty(
        lambda e, w: objective(system, M_obs, w, e, **solve_kw)[1], eps, v, s2, model,
        dof=dof, hessian=hessian,
    )  # fmt: skip
