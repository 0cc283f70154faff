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

from .._validation import as_finite_array, as_operator
from ..errors import ConvergenceError
from ..system import solve_steady
from .drivers import check_minimize_method, minimize_scaled
from .gradients import choose_gradient
from .result import InverseResult, Verdict
from .verdict import consistency_verdict


def _data(system, M_obs, v):
    M_obs = as_operator("M_obs", M_obs)
    if M_obs.shape[1] != system.N:
        raise ValueError(f"`M_obs` must have {system.N} columns (N), got {M_obs.shape}")
    v = as_finite_array("v", v, shape=(M_obs.shape[0],))
    return M_obs, v


def standard_objective(system, M_obs, v, eps, gradient="auto", **solve_kw):
    """:math:`z^{INV}` and its gradient at ``eps``.

    ``gradient`` chooses forward sensitivities or one adjoint solve
    (:func:`~ecfm_uq.inverse.gradients.choose_gradient`); both give the same gradient.

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


_OBJECTIVES = {"standard": standard_objective, "ecfm": ecfm_objective}
#: the reduced formulations' defaults (tol is the relative gradient tolerance: the
#: optimizer sees the objective divided by its value at eps0, so it has no data units)
_DEFAULT_TOL = 1e-10
_DEFAULT_MAXITER = 500


def fit_steady_problem(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` for a :class:`~.problems.SteadyProblem` (validated
    settings ``s``, a :class:`~.fitting.FitSettings`)."""
    system = problem.system
    if s.formulation == "noisy-ecfm" or s.method == "all-at-once":
        from .noisy import fit_all_at_once

        return fit_all_at_once(problem, eps0, s)
    if s.formulation not in _OBJECTIVES:
        raise ValueError(
            f"unknown `formulation` {s.formulation!r}; choose 'standard', 'ecfm' or 'noisy-ecfm'"
        )
    if s.formulation == "ecfm" and system.Gamma is None:
        raise ValueError("formulation='ecfm' needs a system with constraint forces (Gamma)")
    M_obs, v = problem.M_obs, problem.v
    eps0 = system.check_eps(eps0)
    method = "BFGS" if s.method == "auto" else s.method
    check_minimize_method(method)
    gtol = _DEFAULT_TOL if s.tol is None else s.tol
    maxiter = _DEFAULT_MAXITER if s.maxiter is None else s.maxiter
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

    try:
        out = minimize_scaled(evaluate, eps0, method, bounds, gtol, maxiter, s.options)
    except ConvergenceError as e:
        raise ConvergenceError(f"fit_steady: {e}") from e
    if out.payload is None:  # the optimizer stopped where the model fails
        return InverseResult(
            eps=out.x, loss=np.inf, message=out.message, nit=out.nit, nfev=out.nfev,
            status=out.status, method=s.formulation, optimizer=method,
            eps_history=out.eps_history, loss_history=out.loss_history,
            verdict=Verdict(False, test="none", message=f"NOT consistent: {out.final_error}"),
        )  # fmt: skip
    res, z, sol, msg = out, out.loss, out.payload, out.message
    # the unforced solve at the estimate, shared by the verdict and the residual sigma
    free = (
        sol if s.formulation == "standard" else solve_steady(system, res.x, **problem.solve_options)
    )
    if s.uncertainty:
        unc = _uncertainty(system, M_obs, v, np.asarray(res.x), objective, solve_kw, sigma, free)
    else:
        unc = {"uncertainty_message": "not computed (uncertainty=False)"}
    lam = sol.lam if s.formulation == "ecfm" else np.zeros(0)
    verdict = consistency_verdict(
        system, M_obs, v, res.x, lam, bounds, sigma=sigma, alpha=s.alpha,
        n_fitted=system.n_eps, solution=free,
    )  # fmt: skip
    if not verdict.consistent:
        msg += f" [{verdict.message}]"
    return InverseResult(
        **unc,
        eps=np.asarray(res.x),
        loss=z,
        status=out.status,
        message=msg,
        nit=out.nit,
        nfev=out.nfev,
        njev=out.nfev,
        method=s.formulation,
        optimizer=method,
        eps_history=out.eps_history,
        loss_history=out.loss_history,
        extra={"Theta": sol.Theta, "lam": lam},
        verdict=verdict,
    )


def fit_steady(
    system,
    M_obs,
    v,
    eps0,
    formulation="ecfm",
    *,
    method="BFGS",
    gtol=1e-10,
    maxiter=500,
    bounds=None,
    solve_options=None,
    options=None,
    gradient="auto",
    sigma=None,
):
    """Deprecated: ``fit(SteadyProblem(system, M_obs, v, ...), eps0, formulation=...)``.

    The v0.2 call shape, kept as a thin alias of :func:`~ecfm_uq.inverse.fit`:
    ``gtol`` is ``tol``, ``solve_options`` (``tol``, ``maxiter``, ``solver``) and
    ``gradient`` go to :class:`~ecfm_uq.inverse.SteadyProblem`; the default
    ``formulation`` is ``"ecfm"`` here (``"standard"`` in ``fit``).
    """
    from .fitting import fit, warn_deprecated
    from .problems import SteadyProblem

    warn_deprecated("fit_steady", "fit(SteadyProblem(system, M_obs, v), eps0, formulation=...)")
    if not isinstance(solve_options, dict | type(None)):
        raise TypeError(f"`solve_options` must be a dict, got {solve_options!r}")
    problem = SteadyProblem(system, M_obs, v, gradient=gradient, **dict(solve_options or {}))
    if formulation == "ecfm":  # v0.2's ECFM with sigma: exact-match forces, delta method
        options = {"forces": "exact", **dict(options or {})}
    return fit(
        problem, eps0, formulation=formulation, method=method, sigma=sigma, bounds=bounds,
        tol=gtol, maxiter=maxiter, options=options,
    )  # fmt: skip


def _uncertainty(system, M_obs, v, eps, objective, solve_kw, sigma, free=None):
    """Delta-method covariance of the fitted eps (implicit differentiation of grad z = 0);
    ``free`` is the unforced solve at ``eps`` if the caller has it (its residual
    estimates sigma)."""
    from .uncertainty import estimate_uncertainty, residual_variance

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
    except (ConvergenceError, ValueError) as e:
        return {"uncertainty_message": f"uncertainty not computed: {e}"}
    return estimate_uncertainty(
        lambda e, w: objective(system, M_obs, w, e, **solve_kw)[1], eps, v, s2, model, dof=dof
    )
