"""The fits of a :class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem`
(:class:`DynamicFitter`, a row of :data:`ecfm_uq.inverse.fitting.FITTERS`): the
optimizers on its trajectory residual or objective, the least-squares optimality
conditions measured at the returned point, the uncertainty, the verdict, and for
``scheme="adaptive"`` the frozen time grid checked at the estimate."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..._validation import check_choice
from ...errors import ConvergenceError
from ..core.convergence import OFFSET_TOL, at_bound, least_squares_optimality
from ..core.details import DynamicDetails
from ..core.drivers import (
    LEAST_SQUARES_KEYWORDS,
    check_minimize_method,
    least_squares_scaled,
    minimize_scaled,
    verify_least_squares,
)
from ..core.fitter import Fitter, Outcome, holds, measured
from ..core.optimizers import run_adam
from ..core.result import Uncertainty, Verdict
from ..problems.dynamic import FORMULATIONS, DynamicInverseProblem
from ..statistics.verdict import (
    EXTREME_DECADES,
    FORCE_RULE,
    decide,
    extreme_coefficients,
    residual_verdict,
)

__all__ = ["DynamicFitter"]


#: defaults of the dynamic fits: Adam's epochs (the paper's 250), the relative gradient
#: tolerance and iterations of the quasi-Newton methods, the residual evaluations of the
#: least-squares method, and the largest n_eps for which the least-squares method's
#: forward sensitivities count as cheap (beyond: L-BFGS-B with the adjoint gradient)
_ADAM_EPOCHS = 250
_DEFAULT_TOL = 1e-10
_DEFAULT_MAXITER = 500
_DEFAULT_MAX_NFEV = 500
_LSQ_MAX_EPS = 16

#: Adam's options with their defaults
_ADAM_OPTIONS = {"lr": 1e-2, "betas": (0.9, 0.999), "eps_hat": 1e-8, "callback": None}


class DynamicFitter(Fitter):
    """:func:`~ecfm_uq.inverse.fit` for a :class:`DynamicInverseProblem`, one formulation
    (``"standard"`` or ``"ecfm"``).

    ``method``: ``"auto"`` (trust-region least squares on the stacked trajectory
    residual with its forward-sensitivity Jacobian, :meth:`DynamicInverseProblem.residual`;
    L-BFGS-B with the adjoint gradient when ``n_eps > 16``), ``"adam"`` (the paper's
    optimizer; ``maxiter`` epochs, ``options`` ``lr``, ``betas``, ``eps_hat``,
    ``callback``) or a gradient method of ``scipy.optimize.minimize`` on the objective
    scaled by its value at ``eps0``. Whatever ran, what is measured at the returned point
    is the least-squares optimality conditions
    (:mod:`~ecfm_uq.inverse.core.convergence`): Adam's fixed epochs are a budget
    (``exhausted``). The verdict tests the unforced model's trajectory residual (chi2 with
    ``sigma``, the noise-free rule without).

    With ``scheme="adaptive"`` the step sequence is chosen at ``eps0`` (unless one is
    frozen already) and frozen for the optimization; at the estimate it is checked
    against ``rtol``/``atol``, and if a step misses them the grid is refined there and
    the fit polished from the estimate on the refined grid (once). ``extra["steps"]``
    reports the grid: ``n_steps``, ``n_data``, ``rtol``, ``atol``, ``max_error`` (the
    largest step error norm at the estimate, ``<= 1`` when met), ``met``, ``refrozen``
    and ``times``.

    ``options["force_basis"]`` (``formulation="ecfm"``): the basis in time of the forces,
    ``"constant"``, ``"linear"`` or ``{"rbf": width}`` (the problem's ``force_basis``,
    :mod:`~ecfm_uq.inverse.problems.force_bases`), for this fit: a copy of the problem
    with that basis is fitted.
    """

    kind = "dynamic"

    def __init__(self, formulation):
        self.formulation = formulation

    def check_options(self, problem, settings):
        """``options`` by name (and ``covariance`` by value), before any march."""
        covariance = settings.options.get("covariance", "gauss-newton")
        if covariance not in ("gauss-newton", "sandwich"):
            raise ValueError(
                f"options['covariance'] must be 'gauss-newton' or 'sandwich', got {covariance!r}"
            )
        if "force_basis" in settings.options:
            _with_force_basis(problem, settings.formulation, settings.options["force_basis"])
        s = _without_force_basis(_without_covariance(settings))
        method = _method(problem, s)
        if method == "adam":
            return s.take(_ADAM_OPTIONS)
        if method in ("least-squares", "trf"):
            return s.take(dict.fromkeys(LEAST_SQUARES_KEYWORDS))
        check_minimize_method(method)  # its options: scipy's, checked by the driver
        return dict(s.options)

    def run(self, problem, eps0, s):
        if "force_basis" in s.options:
            problem = _with_force_basis(problem, s.formulation, s.options["force_basis"])
            s = _without_force_basis(s)
        if not problem.adaptive:
            return Outcome(**_fit(problem, eps0, s))
        if problem.steps is None:
            try:
                problem.freeze_steps(eps0)
            except ConvergenceError as e:  # no grid at eps0 (a blow-up): a reported failure
                return _failed_at_start(problem, eps0, s, e)
        fields = _fit(problem, eps0, s)
        refrozen = False
        try:
            check = problem.check_steps(fields["eps"])
            if not check.met:
                problem.freeze_steps(fields["eps"], refine=True)
                fields, refrozen = _fit(problem, fields["eps"], s), True
                check = problem.check_steps(fields["eps"])
        except ConvergenceError as e:  # the estimate cannot be marched or no grid meets rtol
            steps = dict(n_steps=problem.steps.n_steps, met=False, message=str(e))
        else:
            steps = dict(
                n_steps=check.n_steps, n_data=problem.n_readings, rtol=check.rtol,
                atol=check.atol, max_error=check.max_error, met=check.met,
                refrozen=refrozen, times=check.times, message=check.message,
            )  # fmt: skip
        return Outcome(**{**fields, "extra": dataclasses.replace(fields["extra"], steps=steps)})


def _without_covariance(s):
    """The settings without ``options["covariance"]`` (the uncertainty's, not the
    optimizer's)."""
    return dataclasses.replace(s, options={k: w for k, w in s.options.items() if k != "covariance"})


def _without_force_basis(s):
    """The settings without ``options["force_basis"]`` (the problem's, not the
    optimizer's)."""
    return dataclasses.replace(
        s, options={k: w for k, w in s.options.items() if k != "force_basis"}
    )


def _method(problem, s):
    """The optimizer: ``"auto"`` is least squares up to 16 parameters, else L-BFGS-B."""
    if s.method == "auto":
        return "least-squares" if problem.system.n_eps <= _LSQ_MAX_EPS else "L-BFGS-B"
    return s.method


def _with_force_basis(problem, formulation, force_basis):
    """The problem with the ECFM forces in ``force_basis`` (a copy when it differs)."""
    if formulation != "ecfm":
        raise ValueError(
            f"options['force_basis'] is the basis in time of the ECFM forces; "
            f"formulation={formulation!r} has no forces (drop the option, or use 'ecfm')"
        )
    return problem.with_force_basis(force_basis)


def _failed_at_start(problem, eps0, s, error):
    """The outcome of an adaptive fit whose step sequence cannot be chosen at ``eps0``:
    a model failure, the message naming where the march stopped."""
    eps0 = np.array(problem.system.check_eps(eps0), dtype=float)
    message = f"fit not started: {error}; start from parameters where the model can be marched"
    return Outcome(
        eps=eps0, loss=np.inf, opt=None, exhausted=False, failure=error, message=message,
        label=s.formulation, method=s.method,
        uncertainty=Uncertainty.failed("not computed: the fit did not start"),
        verdict=Verdict(None, message=message),
        extra=DynamicDetails(steps=dict(n_steps=None, met=False, message=str(error))),
    )  # fmt: skip


def _fit(problem, eps0, s):
    """The fit on the problem's current time grid: the :class:`Outcome`'s fields."""
    formulation = check_choice("formulation", s.formulation, FORMULATIONS)
    eps0 = problem.system.check_eps(eps0)
    covariance = s.options.get("covariance", "gauss-newton")
    s = _without_covariance(s)
    method = _method(problem, s)

    def residual(eps):
        return problem.residual(eps, formulation)

    if method == "adam":
        opts = s.take(_ADAM_OPTIONS)
        out = run_adam(
            problem.objective(formulation),
            eps0,
            lr=opts["lr"],
            epochs=_ADAM_EPOCHS if s.maxiter is None else s.maxiter,
            betas=opts["betas"],
            eps_hat=opts["eps_hat"],
            label=formulation,
            callback=opts["callback"],
        )
        traj = None
        fields = _adam_measured(problem, out, formulation, residual, s.bounds)
    elif method in ("least-squares", "trf"):
        out = least_squares_scaled(
            residual, eps0, s.bounds, s.tol,
            _DEFAULT_MAX_NFEV if s.maxiter is None else s.maxiter, s.options,
        )  # fmt: skip
        fields = _driver_fields(out, formulation, "least-squares")
        traj = out.payload
    else:
        options = dict(s.options)
        polish = options.pop("polish", False)

        def evaluate(eps):
            z, g, traj = _OBJECTIVE[formulation](problem, eps, gradient=True)
            return z, g, traj

        out = minimize_scaled(
            evaluate, eps0, method, s.bounds, _DEFAULT_TOL,
            _DEFAULT_MAXITER if s.maxiter is None else s.maxiter, options,
        )  # fmt: skip
        if problem.system.n_eps <= _LSQ_MAX_EPS:
            out = verify_least_squares(
                out, residual, s.bounds, out.exhausted, polish=polish,
                tol=OFFSET_TOL if s.tol is None else s.tol,
            )  # fmt: skip
        fields = _driver_fields(out, formulation, method)
        traj = out.payload
    if traj is None and method != "adam":  # stopped where the model cannot be marched
        message = fields["message"]
        return {
            **fields,
            "verdict": Verdict(False, test="none", message=f"NOT consistent: {message}"),
        }
    eps = fields["eps"]
    forces = None
    if formulation == "ecfm":
        traj = traj if traj is not None else problem.solve(eps, "ecfm")
        forces = traj.lam
    if s.uncertainty and holds(fields["opt"], fields["failure"]):
        conv = "implicit" if covariance == "sandwich" else covariance
        unc = problem.uncertainty(eps, formulation, s.sigma, conv)
    elif s.uncertainty:
        unc = Uncertainty.failed("uncertainty not computed: the fit did not succeed")
    else:
        unc = Uncertainty.failed("not computed (uncertainty=False)")
    verdict = _verdict(problem, eps, forces, s, traj if formulation == "standard" else None)
    return {**fields, "forces": forces, "uncertainty": unc, "verdict": verdict}


def _driver_fields(out, formulation, method):
    """A driver's :class:`~ecfm_uq.inverse.core.drivers.Outcome` as the fit's fields."""
    return dict(
        eps=out.x, loss=out.loss, message=out.message, nit=out.nit, nfev=out.nfev,
        njev=out.nfev, label=formulation, method=method, eps_history=out.eps_history,
        loss_history=out.loss_history, extra=DynamicDetails(), **measured(out),
    )  # fmt: skip


def _adam_measured(problem, out, formulation, residual, bounds):
    """What is measured at Adam's last iterate (``out``, what
    :func:`~ecfm_uq.inverse.core.optimizers.run_adam` reports): Adam's epochs are a budget
    (``exhausted``), not a test; the least-squares optimality conditions there are the
    measurement, a failed evaluation (Adam's or the check's march) a model failure.
    Adam's own optimality test is not asked. The fit's fields."""
    fields = dict(
        eps=out.x, loss=out.loss, message=out.message, nit=out.nit, nfev=out.nfev,
        njev=out.nfev, label=formulation, method="adam", eps_history=out.eps_history,
        loss_history=out.loss_history, extra=out.payload, exhausted=True,
    )  # fmt: skip
    if out.final_error is not None:  # an evaluation failed: nothing to measure
        return {**fields, "opt": None, "failure": out.final_error}
    try:
        with problem.warm_starts_kept():  # the check must not move the warm starts
            r, J, _ = residual(out.x)
    except ConvergenceError as e:
        message = f"{out.message} [the model cannot be marched at the last iterate: {e}]"
        return {**fields, "opt": None, "failure": e, "message": message}
    opt = least_squares_optimality(r, J, out.x, bounds=bounds)
    message = out.message if opt.converged else f"{out.message} [NOT converged: {opt.message}]"
    return {**fields, "opt": opt, "failure": None, "nfev": out.nfev + 1, "message": message}


_OBJECTIVE = {
    "standard": DynamicInverseProblem.standard_objective,
    "ecfm": DynamicInverseProblem.ecfm_objective,
}


def _verdict(problem, eps, forces, s, traj=None):
    """Whether the unforced model's trajectory at the estimate explains the data
    (``traj``: that trajectory if the caller has it)."""
    hits = at_bound(eps, s.bounds)
    extreme = extreme_coefficients(problem.system, eps, EXTREME_DECADES)
    try:
        with problem.warm_starts_kept():  # the check must not move the warm starts
            traj = problem.solve(eps, "standard") if traj is None else traj
    except ConvergenceError as e:
        return decide(
            "chi2" if s.sigma is not None else FORCE_RULE,
            None if s.sigma is None else 0.0, s.alpha,
            [f"the unforced model cannot be marched at the estimate: {e}"],
            explained=False, at_bound=hits, extreme=extreme,
        )  # fmt: skip
    e = problem.predictions(traj)[1:] - problem.V[1:]
    details = {}
    if forces is not None:
        lam = forces[1:]
        details["peak_force_index"] = int(np.argmax(np.abs(lam).max(axis=0)))
    return residual_verdict(
        e, problem.V[1:], s.sigma, s.alpha, problem.system.n_eps, at_bound=hits,
        extreme=extreme, details=details, forces=forces is not None,
    )  # fmt: skip
