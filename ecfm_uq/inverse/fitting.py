"""One entry point for every inverse fit: :func:`fit`.

In the manner of :func:`scipy.optimize.minimize`: one call shape whatever the problem
(steady, dynamic, replicated), the formulation (standard, ECFM, noisy, pseudo-likelihood)
and the optimizer, running the :class:`~ecfm_uq.inverse.core.fitter.Fitter` of the pair
(problem kind, formulation) in the table :data:`FITTERS` (a new formulation is one Fitter
subclass and one row), which measures; ``fit`` decides the status from the measurement
and builds the result once (:func:`_result`); one tolerance
vocabulary (``tol``, ``maxiter``); method-specific settings in one ``options`` dict,
checked by name; one result class (:class:`~ecfm_uq.inverse.InverseResult`), whose
``status`` is decided from the optimality conditions at the returned point
(:mod:`ecfm_uq.inverse.core.convergence`), whatever the optimizer reported.

=====================  ===============================  ==============================
problem                formulation                      method (``"auto"`` first)
=====================  ===============================  ==============================
ModelProblem           ``"standard"``                   ``"least-squares"`` (trust-region
                                                        on the whitened residual,
                                                        derivatives differenced or given)
OdeProblem             ``"standard"``, ``"ecfm"``,      ``"least-squares"`` (trust-region;
                       ``"ecfm-random"`` (sigma)        Jacobian from forward
                                                        sensitivities, ECFM forces
                                                        piecewise constant between data
                                                        times)
SteadyProblem          ``"standard"``, ``"ecfm"``       ``"least-squares"`` (trust-region
                                                        on the residual and its exact
                                                        Jacobian), any gradient method
                                                        of ``scipy.optimize.minimize``
                                                        (``"BFGS"``, ...),
                                                        ``"all-at-once"`` (SLSQP on
                                                        (theta, eps), standard only)
SteadyProblem          ``"ecfm-random"`` (sigma)        trust-region on the marginal
                                                        likelihood (forces N(0, tau^2))
SteadyProblem          ``"noisy-ecfm"`` (scalar sigma)  ``"all-at-once"``
DynamicInverseProblem  ``"standard"``, ``"ecfm"``       ``"least-squares"`` (L-BFGS-B
                                                        beyond 16 parameters),
                                                        ``"adam"``, any gradient method
                                                        of ``minimize``
ReplicatedProblem      ``"standard"``,                  ``"trust-region"``;
                       ``"inner-outer"`` (``"ecfm"``),  ``"SLSQP"`` for the penalty
                       ``"penalty"``                    form
=====================  ===============================  ==============================

``sigma`` is checked once, by :func:`_check_sigma`, before any model solve: a number for
every formulation; an array (one value per observation or a covariance, per sensor for a
time series, or one per reading) for ModelProblem, and for the Galerkin formulations that
are functions of the sensors' residual, which then run once on the whitened problem
(:mod:`ecfm_uq.inverse.problems.whitening`); ``"noisy-ecfm"`` (the paper's bounds on i.i.d.
noise) and replicated data (noise from the replicates) refuse an array, naming what to do.
"""

from __future__ import annotations

import dataclasses
import numbers

import numpy as np

from .._validation import check_int, check_positive
from ..system.solve.plan import dense_unknowns
from ..threads import library_threads
from .core.convergence import decide_status
from .core.result import InverseResult
from .core.settings import FitSettings
from .formulations.dynamic_fit import DynamicFitter
from .formulations.fitters import (
    AllAtOnceFitter,
    ModelFitter,
    OdeEcfmFitter,
    OdeRandomFitter,
    OdeStandardFitter,
    RandomForceFitter,
    ReplicatedFitter,
    SteadyEcfmFitter,
    SteadyStandardFitter,
)
from .problems.dynamic import DynamicInverseProblem
from .problems.galerkin import ReplicatedProblem, SteadyProblem
from .problems.model import ModelProblem
from .problems.noise_model import NoiseModel, noise_model
from .problems.ode import OdeProblem
from .problems.whitening import dynamic_noise_model, jacobian_in_data_units, whitened_problem
from .statistics.verdict import DEFAULT_ALPHA, check_alpha, check_bounds

__all__ = ["FITTERS", "FORMULATIONS", "fit"]


def _problem_kind(problem):
    for cls, kind in (
        (ModelProblem, "model"),
        (OdeProblem, "ode"),
        (SteadyProblem, "steady"),
        (DynamicInverseProblem, "dynamic"),
        (ReplicatedProblem, "replicated"),
    ):
        if isinstance(problem, cls):
            return kind
    raise TypeError(
        "`problem` must be a ModelProblem, OdeProblem, SteadyProblem, "
        f"DynamicInverseProblem or ReplicatedProblem, got {type(problem).__name__}; e.g. "
        "fit(ModelProblem(model, data), eps0) for a model that is a Python function"
    )


#: formulations whose noise model is one standard deviation for every datum (paper's
#: bounds on i.i.d. noise; replicates carry their own noise), with what to do instead
_SCALAR_SIGMA_ONLY = {
    ("steady", "noisy-ecfm"): (
        "the paper's z and chi-squared bounds (Eq. ecfm_noise) are on the sample mean and "
        "variance of i.i.d. noise; use formulation='ecfm-random' or 'standard', which take "
        "it, or whiten the data and the sensor matrix by hand (W v, W M_obs) and pass "
        "sigma=1 for bounds on the whitened discrepancy"
    ),
}


def _check_sigma(sigma, kind, formulation, problem):
    """``sigma`` validated once, before any model solve: ``None``, a positive float, or a
    :class:`~ecfm_uq.inverse.problems.noise_model.NoiseModel` (one value per observation or
    a covariance: per sensor, a covariance over the sensors or per reading for a time
    series) for the formulations that whiten (:mod:`ecfm_uq.inverse.problems.whitening`)."""
    if sigma is None:
        return None
    if kind == "model":
        noise = noise_model(sigma, problem.n_data)  # raises naming `sigma` and its shapes
        return sigma if noise.kind == "scalar" else noise
    if kind == "ode":  # per reading present (NaN where missing), per component, covariance
        return problem.noise(sigma)
    if kind == "replicated":  # never silently ignored
        raise ValueError(
            f"`sigma` is not taken by a ReplicatedProblem (formulation={formulation!r}): the "
            "noise is estimated from the replicates; omit `sigma`"
        )
    if isinstance(sigma, numbers.Real) or np.ndim(sigma) == 0:
        try:
            return check_positive("sigma", sigma)
        except (TypeError, ValueError) as e:
            raise type(e)(f"{e}; `sigma` is the known sensor noise standard deviation") from e
    if (kind, formulation) in _SCALAR_SIGMA_ONLY:
        raise ValueError(
            f"formulation={formulation!r} takes `sigma` as one number (the same noise "
            f"standard deviation for every sensor), not an array of shape "
            f"{np.shape(sigma)}: {_SCALAR_SIGMA_ONLY[kind, formulation]}"
        )
    if kind == "dynamic":  # per sensor, a covariance over them, or per reading
        return dynamic_noise_model(sigma, problem.n_readings, problem.n_sensors)
    return noise_model(sigma, problem.n_sensors)


#: the fitter of each (problem kind, formulation): a new formulation is one Fitter
#: subclass (:class:`~ecfm_uq.inverse.core.fitter.Fitter`) and one row here
FITTERS = {
    ("model", "standard"): ModelFitter(),
    ("ode", "standard"): OdeStandardFitter(),
    ("ode", "ecfm"): OdeEcfmFitter(),
    ("ode", "ecfm-random"): OdeRandomFitter(),
    ("steady", "standard"): SteadyStandardFitter(),
    ("steady", "ecfm"): SteadyEcfmFitter(),
    ("steady", "ecfm-random"): RandomForceFitter(),
    ("steady", "noisy-ecfm"): AllAtOnceFitter(),
    ("dynamic", "standard"): DynamicFitter("standard"),
    ("dynamic", "ecfm"): DynamicFitter("ecfm"),
    ("replicated", "standard"): ReplicatedFitter("standard"),
    ("replicated", "inner-outer"): ReplicatedFitter("inner-outer"),
    ("replicated", "penalty"): ReplicatedFitter("penalty"),
    ("replicated", "ecfm"): ReplicatedFitter("ecfm"),
}


def _formulations():
    """The formulations of each problem kind, by name, in :data:`FITTERS`' order."""
    names = {}
    for kind, formulation in FITTERS:
        names.setdefault(kind, []).append(formulation)
    return {kind: tuple(forms) for kind, forms in names.items()}


#: the formulations of each problem kind, by name (what each one is: the table above)
FORMULATIONS = _formulations()

#: the problem kinds whose fitters see an array ``sigma`` as whitened sensors and data
#: (a ModelProblem and an OdeProblem take their noise model themselves)
_WHITENED_KINDS = ("steady", "dynamic", "replicated")


def _check_formulation(kind, settings):
    """Refuse a formulation the problem kind has not, and the v0.3 switches by name.

    The formulation is chosen by its name alone: ``"ecfm"`` is the paper's exact-match
    ECFM with or without ``sigma``; the random-force ECFM is ``"ecfm-random"`` (it needs
    ``sigma``).
    """
    if "forces" in settings.options:
        raise ValueError(
            "`options['forces']` is gone: the force model is the formulation's name, "
            "formulation='ecfm' (the paper's exact-match forces) or formulation="
            "'ecfm-random' (random forces, with sigma)"
        )
    if (kind, settings.formulation) not in FITTERS:
        names = tuple(f for k, f in FITTERS if k == kind)  # FITTERS may gain a row (tests)
        hint = ""
        if settings.formulation == "ecfm-random":
            hint = "; the random-force ECFM is defined for a SteadyProblem and an OdeProblem"
        raise ValueError(
            f"unknown `formulation` {settings.formulation!r} for a {kind} problem; choose "
            f"one of {list(names)}{hint}"
        )
    if settings.formulation == "ecfm-random" and settings.sigma is None:
        raise ValueError(
            "formulation='ecfm-random' needs `sigma`, the sensors' noise standard deviation "
            "(the forces' variance is estimated against it); without a noise level use "
            "formulation='ecfm' (exact-match forces) or 'standard'"
        )


def _size(problem, *args, **kwargs):
    own = getattr(problem, "dense_unknowns", None)  # a ModelProblem: none (NO_DENSE)
    if own is not None:
        return own
    system = getattr(problem, "system", None)
    return None if system is None else dense_unknowns(system)


@library_threads(size=_size)
def fit(
    problem,
    eps0,
    *,
    formulation="standard",
    method="auto",
    sigma=None,
    bounds=None,
    tol=None,
    maxiter=None,
    options=None,
    uncertainty=True,
    alpha=DEFAULT_ALPHA,
):
    """Estimate the parameters :math:`\\epsilon` of a model from data.

    Parameters
    ----------
    problem : ModelProblem, SteadyProblem, DynamicInverseProblem or ReplicatedProblem
        The model and the data: a Python function
        (:class:`~ecfm_uq.inverse.problems.model.ModelProblem`) or a Galerkin system with
        its sensors (:mod:`ecfm_uq.inverse.problems.galerkin`).
    eps0 : (n_eps,) array_like
        Starting point.
    formulation : str
        ``"standard"`` (least squares / maximum likelihood), ``"ecfm"`` (the paper's
        explicit constraint forces, matching the data exactly), ``"ecfm-random"`` (random
        constraint forces with a variance estimated against ``sigma``, steady),
        ``"noisy-ecfm"`` (the paper's z / chi-squared bounds, steady), ``"inner-outer"`` /
        ``"penalty"`` (pseudo-likelihood forces, replicated data); see the table in
        :mod:`ecfm_uq.inverse.fitting`.
    method : str
        The optimizer; ``"auto"`` picks the formulation's default.
    sigma : float or array_like, optional
        Known noise of the data (else estimated where needed): one standard deviation, one
        per observation ``(n,)`` or a covariance matrix ``(n, n)``
        (:mod:`ecfm_uq.inverse.problems.noise_model`). For a
        :class:`~ecfm_uq.inverse.problems.galerkin.SteadyProblem` ``n = C`` sensors; for a
        :class:`~ecfm_uq.inverse.problems.dynamic.DynamicInverseProblem` (readings at
        different times independent) ``sigma`` describes the ``C`` sensors, the same at
        every time (``(C,)`` or ``(C, C)``), or every reading: ``(n_steps, C)``, the shape
        of ``V[1:]`` (noise that changes with time). ``(C, C)`` is always a covariance, also
        when ``n_steps == C`` (a sigma per reading is then given flattened, ``(n_steps *
        C,)``); other shapes, ``V``'s ``(n_steps + 1, C)`` included, are refused. An array
        is whitened once and the fit runs on :math:`W\\mathcal M` and :math:`Wv` (per
        reading: :math:`v_{ic}/\\sigma_{ic}` and predicted readings divided alike) with
        ``sigma = 1`` (:mod:`ecfm_uq.inverse.problems.whitening`) for ``"standard"``,
        ``"ecfm"`` (whose estimate does not depend on it: it sets the uncertainty and the
        verdict) and ``"ecfm-random"`` (data covariance :math:`\\Sigma + \\tau^2AA^T`);
        ``"noisy-ecfm"`` and ``ReplicatedProblem`` refuse an array. Without ``sigma`` a
        least-squares fit has no consistency test (``verdict.consistent is None``).
    bounds : sequence of (lo, hi), optional
        Bounds on :math:`\\epsilon` (``None`` for an open side), ``lo < hi``, containing
        ``eps0``.
    tol : float, optional
        The tolerance of the test that decides the status
        (:mod:`ecfm_uq.inverse.core.convergence`), on every path: the relative offset of a
        sum of squares (least squares, the ``minimize`` methods and Adam on it;
        :data:`~ecfm_uq.inverse.core.convergence.OFFSET_TOL`), the KKT stationarity of the
        all-at-once fits (:data:`~ecfm_uq.inverse.core.convergence.KKT_TOL`), the gradient
        in standard-error units of the random-force ECFM
        (:data:`~ecfm_uq.inverse.core.convergence.SCALED_GRADIENT_TOL`), the relative Newton
        decrement of the replicated fits' objective in eps
        (:data:`~ecfm_uq.inverse.core.convergence.DECREMENT_TOL`). An optimizer's own
        stopping settings go in ``options`` (``ftol`` of SLSQP, ``gtol`` of BFGS and of the
        replicated fits' trust-constr, ...). A model solve's tolerance is the problem's
        ``solve_tol``.
    maxiter : int, optional
        Iterations (epochs for Adam, residual evaluations for ``"least-squares"``).
    options : dict, optional
        Method- and formulation-specific settings by name (e.g. ``{"lr": 1e-2}`` for Adam,
        ``{"penalty": 100}`` for the penalty form, ``{"covariance": "sandwich"}`` and
        ``{"polish": False}`` for the steady least-squares fits, ``{"force_prior":
        "sparse"}`` for the random-force ECFM with a variance per force (a localized
        discrepancy) and ``{"tau_in_intervals": "held"}`` for its intervals with tau held at
        its estimate); an unknown name is refused.
    uncertainty : bool
        Attach the estimate's uncertainty (costs extra gradient evaluations).
    alpha : float
        Size of the consistency test of the verdict (default 0.05).

    Returns
    -------
    InverseResult
        ``success``/``status``/``message``, ``eps``, ``uncertainty``, ``verdict``, ...

    Raises
    ------
    TypeError, ValueError
        For a malformed argument (named), before any model solve.
    ConvergenceError
        When the model cannot be solved at ``eps0``.
    """
    kind = _problem_kind(problem)
    if not isinstance(formulation, str):
        raise TypeError(f"`formulation` must be a string, got {formulation!r}")
    if not isinstance(method, str):
        raise TypeError(f"`method` must be a string, got {method!r}")
    if options is not None and not isinstance(options, dict):
        raise TypeError(f"`options` must be a dict of named settings, got {options!r}")
    if tol is not None:
        tol = check_positive("tol", tol)
    if maxiter is not None:
        maxiter = check_int("maxiter", maxiter, minimum=1)
    if not isinstance(uncertainty, bool | numbers.Integral):
        raise TypeError(f"`uncertainty` must be True or False, got {uncertainty!r}")
    if kind not in ("model", "ode"):
        n_eps = problem.system.n_eps
    else:  # a list's length without np.size's array conversion
        n_eps = len(eps0) if type(eps0) in (list, tuple) else np.size(eps0)
    settings = FitSettings(
        formulation=formulation,
        method=method,
        sigma=_check_sigma(sigma, kind, formulation, problem),
        bounds=check_bounds(bounds, n_eps, eps0),
        tol=tol,
        maxiter=maxiter,
        options=dict(options or {}),
        uncertainty=bool(uncertainty),
        alpha=check_alpha(alpha),
    )
    _check_formulation(kind, settings)
    fitter = FITTERS[kind, settings.formulation]
    fitter.check_options(problem, settings)  # by name, before any model call
    noise = settings.sigma if isinstance(settings.sigma, NoiseModel) else None
    if noise is None or kind not in _WHITENED_KINDS:
        return _result(fitter.run(problem, eps0, settings), problem, settings, None)
    # an array sigma: the same fit of whitened sensors and data, sigma = 1, its messages
    # naming the noise as given
    whitened = whitened_problem(problem, noise)
    label = f"sigma=1 (whitened: {noise.describe()})"
    outcome = fitter.run(
        whitened, eps0, dataclasses.replace(settings, sigma=1.0, sigma_label=label)
    )
    return _result(outcome, problem, settings, noise)


def _result(outcome, problem, settings, noise):
    """The one :class:`~ecfm_uq.inverse.InverseResult` of a fit, built once from the
    fitter's :class:`~ecfm_uq.inverse.core.fitter.Outcome`: the status decided from what
    was measured (:func:`~ecfm_uq.inverse.core.convergence.decide_status`), the
    estimate's derivative in the data given (``noise``: an array ``sigma`` whitened), the
    likelihood (or why there is none) and the bounds the profiles need,
    the uncertainty told the estimate and its parameter names."""
    unc = outcome.uncertainty
    if noise is not None:
        unc = _in_data_units(unc, noise)
    likelihood = outcome.likelihood
    if likelihood is None:
        likelihood = problem.log_likelihood(settings.formulation, settings.sigma)
    names = outcome.names
    unc = _with_estimate(unc, outcome.eps, names)
    histories = {
        name: value
        for name in ("eps_history", "loss_history")
        if (value := getattr(outcome, name)) is not None
    }
    return InverseResult(
        eps=outcome.eps, loss=outcome.loss,
        status=decide_status(outcome.opt, outcome.exhausted, outcome.failure),
        nit=outcome.nit, nfev=outcome.nfev, njev=outcome.njev,
        optimality=outcome.optimality, formulation=outcome.label, method=outcome.method,
        state=outcome.state, forces=outcome.forces, bounds=settings.bounds, names=names,
        extra=outcome.extra, problem=outcome.problem, message=outcome.message,
        uncertainty=unc, verdict=outcome.verdict, likelihood=likelihood,
        interval_likelihood=outcome.interval_likelihood, **histories,
    )  # fmt: skip


def _with_estimate(unc, eps, names):
    """The uncertainty told the estimate and the parameter names it belongs to (for
    :meth:`~ecfm_uq.inverse.Uncertainty.to_inputs`); as it is when its fitter told it
    already (no copy)."""
    if not unc.success:
        return unc
    names = None if names is None else list(names)
    told = unc.eps
    if told is not None and unc.names == names:
        eps = np.asarray(eps, dtype=float)
        if told.shape == eps.shape and told.tobytes() == eps.tobytes():
            return unc
    return dataclasses.replace(unc, eps=np.array(eps, dtype=float), names=names)


def _in_data_units(unc, noise):
    """The uncertainty of a fit of whitened data reported for the data given: the
    estimate's derivative in ``v`` (not ``W v``) and the noise standard deviations as
    given (the messages name the noise as given already: the fitter ran with
    ``FitSettings.sigma_label``)."""
    return dataclasses.replace(
        unc,
        jacobian=jacobian_in_data_units(unc.jacobian, noise),
        sigma=noise.std() if unc.success and unc.noise_model == "known" else unc.sigma,
    )
