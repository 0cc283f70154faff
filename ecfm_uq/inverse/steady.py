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
import scipy.optimize as sopt

from .._validation import as_finite_array, as_operator, check_int, check_positive
from ..errors import ConvergenceError
from ..system import solve_steady
from .gradients import choose_gradient
from .result import InverseResult
from .verdict import check_bounds, consistency_verdict


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
    """Fit :math:`\\epsilon` of a steady system to data by the standard or ECFM formulation.

    Parameters
    ----------
    system : GalerkinSystem
        With ``Gamma`` for ``formulation="ecfm"``.
    M_obs : (C, N) array_like or scipy.sparse matrix
    v : (C,) array_like
    eps0 : (n_eps,) array_like
        Starting point.
    formulation : {"standard", "ecfm"}
    method : str
        A gradient-based ``scipy.optimize.minimize`` method (BFGS, L-BFGS-B, ...).
    gtol : float
        Gradient tolerance, relative: the optimizer sees the objective divided by its
        value at ``eps0`` (so the tolerance does not depend on the data's units).
    maxiter : int
    bounds : sequence of (lo, hi), optional
        For bounded methods; keeps trial parameters physical (e.g. a positive length).
    solve_options : dict, optional
        Passed to :func:`solve_steady` (``tol``, ``maxiter``, ``solver``).
    options : dict, optional
        Extra ``scipy.optimize.minimize`` options (override the defaults above).
    gradient : {"auto", "forward", "adjoint"}
        Forward sensitivities or one adjoint solve per evaluation
        (:func:`~ecfm_uq.inverse.gradients.choose_gradient`).
    sigma : float, optional
        Known sensor noise standard deviation. Without it the noise variance is
        estimated from the standard residual at the estimate,
        s^2 = ||r||^2 / (C - n_eps) (``noise_model="estimated"``).

    Returns
    -------
    InverseResult
        ``extra`` holds ``Theta`` and ``lam`` at the optimum (``lam`` is the ECFM
        constraint force, zero-length for the standard formulation) and ``verdict``, the
        :func:`~ecfm_uq.inverse.verdict.consistency_verdict` of the fit (whether model
        and data agree, where the forces peak, parameters at a bound or extreme); its
        message is appended to ``message`` when the fit is not consistent. Inner solves
        that fail (including a coefficient that overflows at a trial ``eps``) count as
        ``z = inf`` and are reported in ``message``; no numpy/Python arithmetic error
        escapes.

    Raises
    ------
    ValueError, TypeError
        For malformed data, ``eps0``, ``method``, ``gtol``, ``maxiter``, ``bounds`` or
        ``sigma`` (<= 0), or fewer measurements than parameters; all before any solve.
        A singular information matrix (a parameter combination the data do not
        determine) is not raised: ``eps_cov`` is None and ``uncertainty_message`` names
        the combination.
    ConvergenceError
        When the model cannot be solved at ``eps0``.
    """
    if not isinstance(formulation, str) or formulation not in _OBJECTIVES:
        raise ValueError(f"unknown `formulation` {formulation!r}; choose 'standard' or 'ecfm'")
    if formulation == "ecfm" and system.Gamma is None:
        raise ValueError("formulation='ecfm' needs a system with constraint forces (Gamma)")
    M_obs, v = _data(system, M_obs, v)
    eps0 = system.check_eps(eps0)
    method, gtol, maxiter, bounds = _check_fit_options(system, method, gtol, maxiter, bounds)
    sigma = _check_sigma(sigma)
    if v.size < system.n_eps:
        raise ValueError(
            f"`v` has {v.size} measurements for {system.n_eps} parameters: fewer sensors "
            "than parameters cannot determine eps; add sensors (rows of `M_obs`) or fix "
            "parameters"
        )
    objective = _OBJECTIVES[formulation]
    solve_kw = dict(solve_options or {})
    solve_kw["gradient"] = choose_gradient(gradient, system.n_eps)
    hist_eps, hist_loss = [], []
    failures = []

    last = {}

    def fun(eps):
        try:
            z, g, _ = objective(system, M_obs, v, eps, **solve_kw)
        except ConvergenceError as e:
            failures.append(str(e))
            z, g = np.inf, np.zeros_like(eps)
        last["eps"], last["z"] = np.array(eps), z
        return z / scale, g / scale

    def callback(xk, *args):
        # the optimizer evaluated fun at xk last (no second solve); fall back otherwise
        z = last["z"] if "eps" in last and np.array_equal(last["eps"], xk) else fun(xk)[0] * scale
        hist_eps.append(np.array(xk))
        hist_loss.append(z)

    scale = 1.0
    z0 = fun(eps0)[0]
    if not np.isfinite(z0):
        raise ConvergenceError(
            f"fit_steady: the model cannot be solved at eps0={eps0}: {failures[0]}"
        )
    scale = z0 if z0 > 0 else 1.0
    last["z"] = z0  # z0 was computed with scale 1
    callback(eps0)
    opts = {"maxiter": maxiter}
    if method.upper() in {"BFGS", "CG", "L-BFGS-B", "TNC"}:
        opts["gtol"] = gtol
    if method.upper() == "L-BFGS-B":
        opts["ftol"] = 1e-15  # stop on the (relative) gradient, not on a stalled decrease
    opts.update(options or {})
    res = sopt.minimize(
        fun, eps0, jac=True, method=method, bounds=bounds, options=opts, callback=callback
    )
    try:
        z, g, sol = objective(system, M_obs, v, res.x, **solve_kw)
    except ConvergenceError as e:  # the optimizer stopped where the model fails
        return _failed_fit(res, formulation, hist_eps, hist_loss, e)
    msg = str(res.message)
    success = bool(res.success)
    if not success and res.get("status") == 2 and not failures:
        # the line search could not decrease z at machine precision. That is convergence
        # when z is at round-off zero (both objectives are >= 0: a global minimum) or
        # when first-order optimality holds relative to z itself: a relative change of
        # eps would change z by less than 1e-6 relative (misspecified data: z* > 0)
        rel_opt = float(np.linalg.norm(g) * max(np.linalg.norm(res.x), 1.0) / max(z, 1e-300))
        if z <= 1e-20 * scale:
            success = True
            msg += " (objective at round-off zero: global minimum)"
        elif rel_opt <= 1e-6:
            success = True
            msg += f" (stopped at the round-off limit; relative optimality {rel_opt:.1e})"
    if failures:
        msg += f" ({len(failures)} inner solves failed; first: {failures[0]})"
    # the unforced solve at the estimate, shared by the verdict and the residual sigma
    free = (
        sol if formulation == "standard" else solve_steady(system, res.x, **(solve_options or {}))
    )
    unc = _uncertainty(system, M_obs, v, np.asarray(res.x), objective, solve_kw, sigma, free)
    lam = sol.lam if formulation == "ecfm" else np.zeros(0)
    verdict = consistency_verdict(system, M_obs, v, res.x, lam, bounds, sigma=sigma, solution=free)
    if not verdict["consistent"]:
        msg += f" [{verdict['message']}]"
    return InverseResult(
        **unc,
        eps=np.asarray(res.x),
        loss=z,
        success=success,
        message=msg,
        nit=int(res.get("nit", 0)),
        method=formulation,
        eps_history=np.array(hist_eps),
        loss_history=np.array(hist_loss),
        extra={"Theta": sol.Theta, "lam": lam, "verdict": verdict},
    )


_METHODS = ("BFGS", "CG", "L-BFGS-B", "TNC", "SLSQP", "Newton-CG", "trust-constr")


def _check_fit_options(system, method, gtol, maxiter, bounds):
    """Validate the optimizer arguments of :func:`fit_steady` (before any solve)."""
    if not isinstance(method, str) or method.upper() not in {m.upper() for m in _METHODS}:
        raise ValueError(f"unknown `method` {method!r}; choose a gradient method of {_METHODS}")
    gtol = check_positive("gtol", gtol)
    maxiter = check_int("maxiter", maxiter, minimum=1)
    bounds = check_bounds(bounds, system.n_eps)
    return method, gtol, maxiter, bounds


def _check_sigma(sigma):
    """``sigma`` is None or a positive finite noise standard deviation (checked up front)."""
    if sigma is None:
        return None
    try:
        return check_positive("sigma", sigma)
    except (TypeError, ValueError) as e:
        raise type(e)(f"{e}; `sigma` is the known sensor noise standard deviation") from e


def _failed_fit(res, formulation, hist_eps, hist_loss, error):
    """A reported failure: the model cannot be solved at the optimizer's last point."""
    return InverseResult(
        eps=np.asarray(res.x),
        loss=np.inf,
        success=False,
        message=f"{res.message} (the model cannot be solved at the final eps: {error})",
        nit=int(res.get("nit", 0)),
        method=formulation,
        eps_history=np.array(hist_eps),
        loss_history=np.array(hist_loss),
        extra={"verdict": {"consistent": False, "message": str(error)}},
    )


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
