"""The fits of a :class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem` (:func:`fit_dynamic_problem`,
called by :func:`~ecfm_uq.inverse.fit`): the optimizers on its trajectory residual or
objective, the status from the least-squares optimality conditions, the uncertainty, the
verdict, and for ``scheme="adaptive"`` the frozen time grid checked at the estimate."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..._validation import check_choice
from ...errors import ConvergenceError
from ..core.convergence import OFFSET_TOL, decide_status, least_squares_optimality
from ..core.drivers import (
    LEAST_SQUARES_KEYWORDS,
    check_minimize_method,
    least_squares_scaled,
    minimize_scaled,
    verify_least_squares,
)
from ..core.optimizers import adam
from ..core.result import InverseResult, Uncertainty, Verdict
from ..core.status import FitStatus
from ..problems.dynamic import FORMULATIONS, DynamicInverseProblem
from ..problems.force_bases import check_force_basis

__all__ = ["fit_dynamic_problem"]


#: defaults of the dynamic fits: Adam's epochs (the paper's 250), the relative gradient
#: tolerance and iterations of the quasi-Newton methods, the residual evaluations of the
#: least-squares method, and the largest n_eps for which the least-squares method's
#: forward sensitivities count as cheap (beyond: L-BFGS-B with the adjoint gradient)
_ADAM_EPOCHS = 250
_DEFAULT_TOL = 1e-10
_DEFAULT_MAXITER = 500
_DEFAULT_MAX_NFEV = 500
_LSQ_MAX_EPS = 16


def fit_dynamic_problem(problem, eps0, s):
    """:func:`~ecfm_uq.inverse.fit` for a :class:`DynamicInverseProblem`.

    With ``scheme="adaptive"`` the step sequence is chosen at ``eps0`` (unless one is
    frozen already) and frozen for the optimization; at the estimate it is checked
    against ``rtol``/``atol``, and if a step misses them the grid is refined there and
    the fit polished from the estimate on the refined grid (once). ``extra["steps"]``
    reports the grid: ``n_steps``, ``n_data``, ``rtol``, ``atol``, ``max_error`` (the
    largest step error norm at the estimate, ``<= 1`` when met), ``met``, ``refrozen``
    and ``times``. The fit itself is :func:`_fit_dynamic`.

    ``options["force_basis"]`` (``formulation="ecfm"``): the basis in time of the forces,
    ``"constant"``, ``"linear"`` or ``{"rbf": width}`` (the problem's ``force_basis``,
    :mod:`~ecfm_uq.inverse.problems.force_bases`), for this fit: a copy of the problem
    with that basis is fitted.
    """
    if "force_basis" in s.options:
        problem = _with_force_basis(problem, s.formulation, s.options["force_basis"])
        s = dataclasses.replace(
            s, options={k: w for k, w in s.options.items() if k != "force_basis"}
        )
    if not problem.adaptive:
        return _fit_dynamic(problem, eps0, s)
    if problem.steps is None:
        try:
            problem.freeze_steps(eps0)
        except ConvergenceError as e:  # no grid at eps0 (a blow-up): a reported failure
            return _failed_at_start(problem, eps0, s, e)
    res = _fit_dynamic(problem, eps0, s)
    refrozen = False
    try:
        check = problem.check_steps(res.eps)
        if not check.met:
            problem.freeze_steps(res.eps, refine=True)
            res, refrozen = _fit_dynamic(problem, res.eps, s), True
            check = problem.check_steps(res.eps)
    except ConvergenceError as e:  # the estimate cannot be marched or no grid meets rtol
        steps = dict(n_steps=problem.steps.n_steps, met=False, message=str(e))
        return dataclasses.replace(res, extra={**res.extra, "steps": steps})
    steps = dict(
        n_steps=check.n_steps, n_data=problem.n_readings, rtol=check.rtol, atol=check.atol,
        max_error=check.max_error, met=check.met, refrozen=refrozen, times=check.times,
        message=check.message,
    )  # fmt: skip
    return dataclasses.replace(res, extra={**res.extra, "steps": steps})


def _with_force_basis(problem, formulation, force_basis):
    """The problem with the ECFM forces in ``force_basis`` (a copy when it differs)."""
    if formulation != "ecfm":
        raise ValueError(
            f"options['force_basis'] is the basis in time of the ECFM forces; "
            f"formulation={formulation!r} has no forces (drop the option, or use 'ecfm')"
        )
    check_force_basis(force_basis)
    if force_basis == problem.force_basis:
        return problem
    other = copy.copy(problem)
    other.force_basis, other._forces = force_basis, None
    other._last = {k: w for k, w in problem._last.items() if not k.startswith("ecfm")}
    return other


def _failed_at_start(problem, eps0, s, error):
    """The result of an adaptive fit whose step sequence cannot be chosen at ``eps0``:
    ``success=False`` (``MODEL_FAILURE``), the message naming where the march stopped."""
    eps0 = np.array(problem.system.check_eps(eps0), dtype=float)
    message = f"fit not started: {error}; start from parameters where the model can be marched"
    return InverseResult(
        eps=eps0, loss=np.inf, status=decide_status(None, False, failure=error), message=message,
        formulation=s.formulation, method=s.method,
        uncertainty=Uncertainty.failed("not computed: the fit did not start"),
        verdict=Verdict(None, message=message),
        extra={"steps": dict(n_steps=None, met=False, message=str(error))},
    )  # fmt: skip


def _fit_dynamic(problem, eps0, s):
    """The fit of :func:`fit_dynamic_problem` on the problem's current time grid.

    ``method``: ``"auto"`` (trust-region least squares on the stacked trajectory
    residual with its forward-sensitivity Jacobian, :meth:`DynamicInverseProblem.residual`;
    L-BFGS-B with the adjoint gradient when ``n_eps > 16``), ``"adam"`` (the paper's
    optimizer; ``maxiter`` epochs, ``options`` ``lr``, ``betas``, ``eps_hat``,
    ``callback``) or a gradient method of ``scipy.optimize.minimize`` on the objective
    scaled by its value at ``eps0``. Whatever ran, the status is decided from the
    least-squares optimality conditions at the returned point
    (:mod:`~ecfm_uq.inverse.core.convergence`): Adam's fixed epochs are ``MAX_ITERATIONS``
    unless the conditions hold there. The verdict tests the unforced model's trajectory
    residual (chi2 with ``sigma``, the noise-free rule without).
    """
    formulation = check_choice("formulation", s.formulation, FORMULATIONS)
    eps0 = problem.system.check_eps(eps0)
    n_eps = problem.system.n_eps
    method = s.method
    covariance = s.options.get("covariance", "gauss-newton")
    if covariance not in ("gauss-newton", "sandwich"):
        raise ValueError(
            f"options['covariance'] must be 'gauss-newton' or 'sandwich', got {covariance!r}"
        )
    s = dataclasses.replace(s, options={k: w for k, w in s.options.items() if k != "covariance"})
    if method == "auto":
        method = "least-squares" if n_eps <= _LSQ_MAX_EPS else "L-BFGS-B"

    def residual(eps):
        return problem.residual(eps, formulation)

    if method == "adam":
        opts = s.take({"lr": 1e-2, "betas": (0.9, 0.999), "eps_hat": 1e-8, "callback": None})
        res = adam(
            problem.objective(formulation),
            eps0,
            lr=opts["lr"],
            epochs=_ADAM_EPOCHS if s.maxiter is None else s.maxiter,
            betas=opts["betas"],
            eps_hat=opts["eps_hat"],
            formulation=formulation,
            callback=opts["callback"],
        )
        traj = None
        res = _check_adam(problem, res, residual, s.bounds)
    elif method in ("least-squares", "trf"):
        s.take(dict.fromkeys(LEAST_SQUARES_KEYWORDS))  # by name, before any march
        out = least_squares_scaled(
            residual, eps0, s.bounds, s.tol,
            _DEFAULT_MAX_NFEV if s.maxiter is None else s.maxiter, s.options,
        )  # fmt: skip
        res = _result(out, formulation, "least-squares")
        traj = out.payload
    else:
        check_minimize_method(method)
        options = dict(s.options)
        polish = options.pop("polish", False)

        def evaluate(eps):
            z, g, traj = _OBJECTIVE[formulation](problem, eps, gradient=True)
            return z, g, traj

        out = minimize_scaled(
            evaluate, eps0, method, s.bounds, _DEFAULT_TOL,
            _DEFAULT_MAXITER if s.maxiter is None else s.maxiter, options,
        )  # fmt: skip
        if n_eps <= _LSQ_MAX_EPS:
            out = verify_least_squares(
                out, residual, s.bounds, out.exhausted, polish=polish,
                tol=OFFSET_TOL if s.tol is None else s.tol,
            )  # fmt: skip
        res = _result(out, formulation, method)
        traj = out.payload
    if traj is None and method != "adam":  # stopped where the model cannot be marched
        verdict = Verdict(False, test="none", message=f"NOT consistent: {res.message}")
        return dataclasses.replace(res, verdict=verdict)
    if formulation == "ecfm":
        traj = traj if traj is not None else problem.solve(res.eps, "ecfm")
        res = dataclasses.replace(res, forces=traj.lam)
    if s.uncertainty and res.success:
        conv = "implicit" if covariance == "sandwich" else covariance
        unc = problem.uncertainty(res.eps, formulation, s.sigma, conv)
    elif s.uncertainty:
        unc = Uncertainty.failed("uncertainty not computed: the fit did not succeed")
    else:
        unc = Uncertainty.failed("not computed (uncertainty=False)")
    res = dataclasses.replace(res, uncertainty=unc)
    verdict = _verdict(problem, res, s, traj if formulation == "standard" else None)
    return dataclasses.replace(res, verdict=verdict)


def _result(out, formulation, method):
    return InverseResult(
        eps=out.x, loss=out.loss, status=out.status, message=out.message, nit=out.nit,
        nfev=out.nfev, njev=out.nfev, formulation=formulation, method=method,
        eps_history=out.eps_history, loss_history=out.loss_history,
        optimality=out.optimality,
    )  # fmt: skip


def _check_adam(problem, res, residual, bounds):
    """The one status decision of an Adam fit: Adam's epochs are a budget (``exhausted``),
    not a test; the least-squares optimality conditions at its last iterate decide
    (:func:`~ecfm_uq.inverse.core.convergence.decide_status`), a failed evaluation (Adam's
    or the check's march) being a measured model failure. Adam's own status is not asked.
    Returns the result with that status and the measured optimality."""
    if res.status is FitStatus.MODEL_FAILURE:  # an evaluation failed: nothing to measure
        return dataclasses.replace(
            res, status=decide_status(None, True, failure=res.message), optimality=None
        )
    saved = dict(problem._last)  # the check must not move the warm starts
    try:
        r, J, _ = residual(res.eps)
    except ConvergenceError as e:
        return dataclasses.replace(
            res, status=decide_status(None, True, failure=e), optimality=None,
            message=f"{res.message} [the model cannot be marched at the last iterate: {e}]",
        )  # fmt: skip
    finally:
        problem._last = saved
    opt = least_squares_optimality(r, J, res.eps, bounds=bounds)
    message = res.message if opt.converged else f"{res.message} [NOT converged: {opt.message}]"
    return dataclasses.replace(
        res, status=decide_status(opt, exhausted=True), nfev=res.nfev + 1,
        optimality=opt.value, message=message,
    )  # fmt: skip


_OBJECTIVE = {
    "standard": DynamicInverseProblem.standard_objective,
    "ecfm": DynamicInverseProblem.ecfm_objective,
}


def _verdict(problem, res, s, traj=None):
    """Whether the unforced model's trajectory at the estimate explains the data
    (``traj``: that trajectory if the caller has it)."""
    from ..core.convergence import at_bound
    from ..statistics.verdict import (
        EXTREME_DECADES,
        FORCE_RULE,
        decide,
        extreme_coefficients,
        residual_verdict,
    )

    hits = at_bound(res.eps, s.bounds)
    extreme = extreme_coefficients(problem.system, res.eps, EXTREME_DECADES)
    saved = dict(problem._last)  # the check must not move the optimizer's warm starts
    try:
        traj = problem.solve(res.eps, "standard") if traj is None else traj
    except ConvergenceError as e:
        return decide(
            "chi2" if s.sigma is not None else FORCE_RULE,
            None if s.sigma is None else 0.0, s.alpha,
            [f"the unforced model cannot be marched at the estimate: {e}"],
            explained=False, at_bound=hits, extreme=extreme,
        )  # fmt: skip
    finally:
        problem._last = saved
    e = problem.predictions(traj)[1:] - problem.V[1:]
    details = {}
    if res.forces is not None:
        lam = res.forces[1:]
        details["peak_force_index"] = int(np.argmax(np.abs(lam).max(axis=0)))
    return residual_verdict(
        e, problem.V[1:], s.sigma, s.alpha, problem.system.n_eps, at_bound=hits,
        extreme=extreme, details=details, forces=res.forces is not None,
    )  # fmt: skip
