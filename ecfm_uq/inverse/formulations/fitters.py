"""The :class:`~ecfm_uq.inverse.core.fitter.Fitter` of each formulation whose fit is a
function of its own module (``fit_ode_ecfm``, ``fit_steady_problem``, ...).

Each class runs that function, which returns an
:class:`~ecfm_uq.inverse.core.fitter.Outcome`: what was measured at the returned point
(no status); the entry point decides the status and builds the result. The ModelProblem
and OdeProblem ``"standard"`` rows are in their problems' modules
(:class:`~ecfm_uq.inverse.problems.model.ModelFitter`,
:class:`~ecfm_uq.inverse.problems.ode.OdeStandardFitter`). The function checks its
``method`` and ``options`` by name before any model call, with its own messages. A
formulation written as a Fitter from the start
(:class:`~ecfm_uq.inverse.formulations.dynamic_fit.DynamicFitter`) needs no class here.
"""

from __future__ import annotations

from ..core.fitter import Fitter
from ..problems.model import ModelFitter
from ..problems.ode import OdeStandardFitter
from .all_at_once import fit_all_at_once
from .ode_forces import fit_ode_ecfm
from .ode_random import fit_ode_random
from .random_forces import fit_random_force
from .replicated import fit_replicated_problem
from .steady import fit_steady_problem

__all__ = [
    "AllAtOnceFitter",
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


class OdeEcfmFitter(Fitter):
    """``OdeProblem``, ``"ecfm"``: forces piecewise constant between data times (or
    on a basis, ``options["force_basis"]``); :func:`~.ode_forces.fit_ode_ecfm` returns
    its :class:`Outcome`."""

    kind, formulation, default_method = "ode", "ecfm", "least-squares"

    def run(self, problem, eps0, settings):
        return fit_ode_ecfm(problem, eps0, settings)


class OdeRandomFitter(Fitter):
    """``OdeProblem``, ``"ecfm-random"``: random forces, their variance against sigma
    (:func:`~.ode_random.fit_ode_random` returns its :class:`Outcome`)."""

    kind, formulation, default_method = "ode", "ecfm-random", "least-squares"

    def run(self, problem, eps0, settings):
        return fit_ode_random(problem, eps0, settings)


class SteadyFitter(Fitter):
    """``SteadyProblem``, ``"standard"`` / ``"ecfm"``: reduced (least squares or a
    ``minimize`` method; :func:`~.steady.fit_steady_problem` returns its
    :class:`Outcome`). For every steady formulation ``method="all-at-once"`` is the
    stacked SLSQP fit (:func:`~.all_at_once.fit_all_at_once`, which names the
    formulations it solves)."""

    kind, default_method = "steady", "least-squares"

    def run(self, problem, eps0, settings):
        if settings.method == "all-at-once":
            return fit_all_at_once(problem, eps0, settings)
        return fit_steady_problem(problem, eps0, settings)


class SteadyStandardFitter(SteadyFitter):
    """``SteadyProblem``, ``"standard"``."""

    formulation = "standard"


class SteadyEcfmFitter(SteadyFitter):
    """``SteadyProblem``, ``"ecfm"`` (the paper's exact-match forces)."""

    formulation = "ecfm"


class RandomForceFitter(SteadyFitter):
    """``SteadyProblem``, ``"ecfm-random"``: trust region on the marginal likelihood
    (:func:`~.random_forces.fit_random_force` returns its :class:`Outcome`)."""

    kind, formulation, default_method = "steady", "ecfm-random", "least-squares"

    def run(self, problem, eps0, settings):
        if settings.method == "all-at-once":
            return fit_all_at_once(problem, eps0, settings)
        return fit_random_force(problem, eps0, settings)


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
