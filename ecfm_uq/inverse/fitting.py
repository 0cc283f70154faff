"""One entry point for every inverse fit: :func:`fit`.

In the manner of :func:`scipy.optimize.minimize`: one call shape whatever the problem
(steady, dynamic, replicated), the formulation (standard, ECFM, noisy, pseudo-likelihood)
and the optimizer, dispatching to the module that owns each problem kind; one tolerance
vocabulary (``tol``, ``maxiter``); method-specific settings in one ``options`` dict,
checked by name; one result class (:class:`~ecfm_uq.inverse.InverseResult`), whose
``status`` is decided from the optimality conditions at the returned point
(:mod:`.convergence`), whatever the optimizer reported.

=====================  ===============================  ==============================
problem                formulation                      method (``"auto"`` first)
=====================  ===============================  ==============================
ModelProblem           ``"standard"``                   ``"least-squares"`` (trust-region
                                                        on the whitened residual,
                                                        derivatives differenced or given)
SteadyProblem          ``"standard"``, ``"ecfm"``       ``"least-squares"`` (trust-region
                                                        on the residual and its exact
                                                        Jacobian), any gradient method
                                                        of ``scipy.optimize.minimize``
                                                        (``"BFGS"``, ...),
                                                        ``"all-at-once"`` (SLSQP on
                                                        (theta, eps), standard only)
SteadyProblem          ``"noisy-ecfm"`` (sigma)         ``"all-at-once"``
DynamicInverseProblem  ``"standard"``, ``"ecfm"``       ``"least-squares"`` (L-BFGS-B
                                                        beyond 16 parameters),
                                                        ``"adam"``, any gradient method
                                                        of ``minimize``
ReplicatedProblem      ``"standard"``,                  ``"trust-region"``;
                       ``"inner-outer"`` (``"ecfm"``),  ``"SLSQP"`` for the penalty
                       ``"penalty"``                    form
=====================  ===============================  ==============================
"""

from __future__ import annotations

import numbers
from dataclasses import replace

import numpy as np

from .._validation import check_int, check_positive
from ..system.plan import dense_unknowns
from ..threads import library_threads
from .settings import FitSettings
from .verdict import DEFAULT_ALPHA, check_alpha, check_bounds

__all__ = ["fit"]


def _problem_kind(problem):
    from .dynamic import DynamicInverseProblem
    from .model_problem import ModelProblem
    from .problems import ReplicatedProblem, SteadyProblem

    for cls, kind in (
        (ModelProblem, "model"),
        (SteadyProblem, "steady"),
        (DynamicInverseProblem, "dynamic"),
        (ReplicatedProblem, "replicated"),
    ):
        if isinstance(problem, cls):
            return kind
    raise TypeError(
        "`problem` must be a ModelProblem, SteadyProblem, DynamicInverseProblem or "
        f"ReplicatedProblem, got {type(problem).__name__}; e.g. "
        "fit(ModelProblem(model, data), eps0) for a model that is a Python function"
    )


def _check_sigma(sigma, kind, n_data):
    if sigma is None:
        return None
    if kind == "model":
        from .noise_model import noise_model

        noise_model(sigma, n_data)  # raises naming `sigma` and the shapes it may take
        return sigma
    if not isinstance(sigma, numbers.Real) and np.ndim(sigma) > 0:
        raise TypeError(
            f"`sigma` for a {kind} problem is one noise standard deviation for every "
            "observation in this version; a per-observation sigma or a covariance is taken "
            "by ModelProblem (or whiten the data and the model's predictions by hand)"
        )
    try:
        return check_positive("sigma", sigma)
    except (TypeError, ValueError) as e:
        raise type(e)(f"{e}; `sigma` is the known sensor noise standard deviation") from e


def _size(problem, *args, **kwargs):
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
        The model and the data: a Python function (:class:`~.model_problem.ModelProblem`)
        or a Galerkin system with its sensors (:mod:`ecfm_uq.inverse.problems`).
    eps0 : (n_eps,) array_like
        Starting point.
    formulation : str
        ``"standard"`` (least squares / maximum likelihood), ``"ecfm"`` (the paper's
        explicit constraint forces), ``"noisy-ecfm"`` (the paper's z / chi-squared
        bounds, steady), ``"inner-outer"`` / ``"penalty"`` (pseudo-likelihood forces,
        replicated data); see the table in :mod:`ecfm_uq.inverse.fitting`.
    method : str
        The optimizer; ``"auto"`` picks the formulation's default.
    sigma : float or array_like, optional
        Known noise of the data (else estimated where needed): one standard deviation;
        for a :class:`~.model_problem.ModelProblem` also one per observation or a
        covariance matrix (:mod:`.noise_model`). Without it a least-squares fit has no
        consistency test (``verdict.consistent is None``).
    bounds : sequence of (lo, hi), optional
        Bounds on :math:`\\epsilon` (``None`` for an open side).
    tol : float, optional
        Optimality tolerance: the relative offset of the least-squares methods
        (:data:`~ecfm_uq.inverse.convergence.OFFSET_TOL` when omitted), the relative
        gradient tolerance of the ``minimize`` methods.
    maxiter : int, optional
        Iterations (epochs for Adam, residual evaluations for ``"least-squares"``).
    options : dict, optional
        Method- and formulation-specific settings by name (e.g. ``{"lr": 1e-2}`` for
        Adam, ``{"penalty": 100}`` for the penalty form, ``{"covariance": "sandwich"}``
        and ``{"polish": False}`` for the steady least-squares fits,
        ``{"forces": "exact"}`` for the paper's ECFM, ``{"force_prior": "sparse"}`` for
        random-force ECFM with a variance per force (a localized discrepancy) and
        ``{"tau_in_intervals": "held"}`` for its intervals with tau held at its
        estimate); an unknown name is refused.
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
    n_eps = problem.system.n_eps if kind != "model" else np.size(eps0)
    settings = FitSettings(
        formulation=formulation,
        method=method,
        sigma=_check_sigma(sigma, kind, getattr(problem, "n_data", None)),
        bounds=check_bounds(bounds, n_eps),
        tol=tol,
        maxiter=maxiter,
        options=dict(options or {}),
        uncertainty=bool(uncertainty),
        alpha=check_alpha(alpha),
    )
    forces = settings.options.get("forces", "random") if formulation == "ecfm" else None
    if forces not in (None, "random", "exact"):
        raise ValueError(f"`options['forces']` must be 'random' or 'exact', got {forces!r}")
    if forces is not None and "forces" in settings.options:
        settings = replace(
            settings, options={k: v for k, v in settings.options.items() if k != "forces"}
        )
    if kind == "model":
        from .model_problem import fit_model_problem

        return fit_model_problem(problem, eps0, settings)
    if kind == "steady" and (formulation == "noisy-ecfm" or method == "all-at-once"):
        from .noisy import fit_all_at_once as fitter
    elif kind == "steady" and forces == "random" and settings.sigma is not None:
        from .discrepancy import fit_random_force as fitter
    elif kind == "steady":
        from .steady import fit_steady_problem as fitter
    elif kind == "dynamic":
        from .dynamic import fit_dynamic_problem as fitter
    else:
        from .replicated import fit_replicated_problem as fitter
    result = fitter(problem, eps0, settings)
    # what the profile likelihood needs: the likelihood (or why there is none), the bounds
    likelihood = result.likelihood
    if likelihood is None:
        likelihood = problem.log_likelihood(settings.formulation, settings.sigma)
    return replace(result, likelihood=likelihood, bounds=settings.bounds)
