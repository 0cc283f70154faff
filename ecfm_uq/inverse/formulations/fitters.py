"""The :class:`~ecfm_uq.inverse.core.fitter.Fitter` of each formulation whose fit is a
function of its own module (``fit_model_problem``, ``fit_steady_problem``, ...).

Each class runs that function and reads its measurement back as an
:class:`~ecfm_uq.inverse.core.fitter.Outcome`
(:meth:`~ecfm_uq.inverse.core.fitter.Outcome.from_result`); the entry point decides the
status and builds the result. The function checks its ``method`` and ``options`` by name
before any model call, with its own messages. A formulation written as a Fitter from the
start (:class:`~ecfm_uq.inverse.formulations.dynamic_fit.DynamicFitter`) needs no class
here.
"""

from __future__ import annotations

from ..core.fitter import Fitter, Outcome
from ..problems.model import fit_model_problem
from ..problems.ode import fit_ode_standard
from .all_at_once import fit_all_at_once
from .ode_forces import fit_ode_ecfm
from .ode_random import fit_ode_random
from .random_forces import fit_random_force
from .replicated import fit_replicated_problem
from .steady import fit_steady_problem

__all__ = [
    "AllAtOnceFitter",
    "FunctionFitter",
    "ModelFitter",
    "OdeEcfmFitter",
    "OdeRandomFitter",
    "OdeStandardFitter",
    "RandomForceFitter",
    "ReplicatedFitter",
    "SteadyEcfmFitter",
    "SteadyFitter",
    "SteadyStandardFitter",
]


class FunctionFitter(Fitter):
    """A fitter that runs a fit function ``fit_function(problem, eps0, settings)``."""

    #: whether ``fit`` whitens for it an array ``sigma`` and completes its likelihood
    #: and bounds (the Galerkin formulations); a ModelProblem and an OdeProblem take
    #: their noise model themselves
    whitens = True

    @staticmethod
    def fit_function(problem, eps0, settings):
        raise NotImplementedError

    def run(self, problem, eps0, settings):
        return Outcome.from_result(type(self).fit_function(problem, eps0, settings))


class ModelFitter(FunctionFitter):
    """``ModelProblem``, ``"standard"``: least squares of the model function."""

    kind, formulation, default_method, whitens = "model", "standard", "least-squares", False
    fit_function = staticmethod(fit_model_problem)


class OdeStandardFitter(FunctionFitter):
    """``OdeProblem``, ``"standard"``: least squares of the readings present."""

    kind, formulation, default_method, whitens = "ode", "standard", "least-squares", False
    fit_function = staticmethod(fit_ode_standard)


class OdeEcfmFitter(FunctionFitter):
    """``OdeProblem``, ``"ecfm"``: forces piecewise constant between data times."""

    kind, formulation, default_method, whitens = "ode", "ecfm", "least-squares", False
    fit_function = staticmethod(fit_ode_ecfm)


class OdeRandomFitter(FunctionFitter):
    """``OdeProblem``, ``"ecfm-random"``: random forces, their variance against sigma."""

    kind, formulation, default_method, whitens = "ode", "ecfm-random", "least-squares", False
    fit_function = staticmethod(fit_ode_random)


class SteadyFitter(FunctionFitter):
    """``SteadyProblem``, ``"standard"`` / ``"ecfm"``: reduced (least squares or a
    ``minimize`` method). For every steady formulation ``method="all-at-once"`` is the
    stacked SLSQP fit (:func:`~.all_at_once.fit_all_at_once`, which names the
    formulations it solves)."""

    kind, default_method = "steady", "least-squares"
    fit_function = staticmethod(fit_steady_problem)

    def run(self, problem, eps0, settings):
        if settings.method == "all-at-once":  # written as an Outcome already
            return fit_all_at_once(problem, eps0, settings)
        return Outcome.from_result(type(self).fit_function(problem, eps0, settings))


class SteadyStandardFitter(SteadyFitter):
    """``SteadyProblem``, ``"standard"``."""

    formulation = "standard"


class SteadyEcfmFitter(SteadyFitter):
    """``SteadyProblem``, ``"ecfm"`` (the paper's exact-match forces)."""

    formulation = "ecfm"


class RandomForceFitter(SteadyFitter):
    """``SteadyProblem``, ``"ecfm-random"``: trust region on the marginal likelihood."""

    kind, formulation, default_method = "steady", "ecfm-random", "least-squares"
    fit_function = staticmethod(fit_random_force)


class AllAtOnceFitter(Fitter):
    """``SteadyProblem``, ``"noisy-ecfm"``: SLSQP on (theta, eps, lam), the paper's bounds
    (:func:`~.all_at_once.fit_all_at_once` returns its :class:`Outcome`)."""

    kind, formulation, default_method = "steady", "noisy-ecfm", "all-at-once"

    def run(self, problem, eps0, settings):
        return fit_all_at_once(problem, eps0, settings)


class ReplicatedFitter(Fitter):
    """``ReplicatedProblem``: the pseudo-likelihood fits (one class for every
    formulation: :func:`~.replicated.fit_replicated_problem` reads its name and returns
    its :class:`Outcome`)."""

    kind, default_method = "replicated", "trust-region"

    def __init__(self, formulation):
        self.formulation = formulation

    def run(self, problem, eps0, settings):
        return fit_replicated_problem(problem, eps0, settings)
