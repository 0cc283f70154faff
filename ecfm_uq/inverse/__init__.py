"""Inverse formulations: standard least squares, ECFM (equality constraint forces),
noisy ECFM (z-score and chi-squared bounds), pseudo-likelihood constraint forces.

One entry point, :func:`fit`, takes a problem (the model and the data) and returns an
:class:`InverseResult` (``success``/``status``, the estimate, its :class:`Uncertainty` and
the :class:`Verdict` on whether the model explains the data):

==========================  =====================================================  ================
problem                     formulations (``fit(problem, eps0, formulation=...)``)  paper
==========================  =====================================================  ================
:class:`ModelProblem`       ``"standard"`` (a model that is a Python function)     --
:class:`OdeProblem`         ``"standard"``, ``"ecfm"`` (a user's ODE, readings     --
                            at any times; forces piecewise constant in time)
:class:`SteadyProblem`      ``"standard"``, ``"ecfm"``, ``"noisy-ecfm"``            Eqs. traditional,
                                                                                   ecfm,
                                                                                   kpp_inv,
                                                                                   ecfm_noise;
                                                                                   Sec. 4
:class:`DynamicInverse\\    ``"standard"``, ``"ecfm"``                              Eqs. inv_obj,
Problem`                                                                           ecfm_obj
:class:`ReplicatedProblem`  ``"standard"``, ``"inner-outer"``, ``"penalty"``        Eq. stochastic_model
==========================  =====================================================  ================

``SteadyProblem`` also takes ``"ecfm-random"`` (the random-force ECFM, with ``sigma``).
From a result: :func:`profile_likelihood` / :func:`profile_intervals` (profile-likelihood
intervals and regions), :func:`likelihood_ratio_test`, ``result.summary()``; from an ECFM
fit of an ODE, :func:`discover_terms` (which library terms its forces are).

The package, read from the top: each layer imports only from itself and the layers below
it (:file:`tests/inverse/test_layout.py` checks this), and nothing but :mod:`.coverage`
imports :mod:`.fitting`:

==================  ======================================================================
``fitting``,        ``fit`` (validate, whiten, dispatch: the only entry);
``coverage``        fits over synthetic data sets
``formulations/``   how each formulation turns a problem into an estimate: ``steady``
                    (standard and exact ECFM, reduced), ``all_at_once`` and
                    ``noise_bounds`` (all at once, the paper's noise bounds),
                    ``random_forces``, ``random_force_gradient``,
                    ``random_force_search``, ``random_force_scoring``,
                    ``random_force_simulation`` and ``sparse_forces`` (random-force ECFM),
                    ``dynamic_fit``, ``replicated``, ``replicated_status`` and
                    ``forces`` (pseudo-likelihood), ``ode_forces``, ``ode_basis`` and
                    ``ode_random`` (exact-match and random-force ECFM of an ODE);
                    ``fitters`` (the Fitter of each formulation whose fit is a function)
``problems/``       a model and its data behind one interface (``interface``): ``model``
                    (a Python function), ``ode`` (a user's ODE, forward sensitivities),
                    ``galerkin`` (steady, replicated), ``dynamic`` (``dynamic_sparse``:
                    data at some times, forces in a basis in time, ``force_bases``);
                    ``noise_model`` and ``whitening`` (``sigma`` as given);
                    ``pseudo_likelihood`` and ``moments`` (the replicated data's
                    likelihood)
``statistics/``     what a fit says: ``uncertainty``, ``verdict``, ``loglik``, ``profile``
                    with ``profile_walk`` and ``profile_calibration``, ``posterior``,
                    ``diagnostics``, ``prediction``
                    (bands; ``InverseResult.predict`` in ``core`` reaches it through a
                    function this package's import registers, not an upward import),
                    ``terms`` (the missing term named from an ODE fit's forces)
``core/``           shared machinery: ``fitter`` (the shape of every fit: a
                    ``Fitter``'s steps and the ``Outcome`` it measures),
                    ``convergence`` (the one status decision),
                    ``drivers`` and ``optimizers`` (the optimizer calls), ``minpack``
                    (MINPACK's Levenberg-Marquardt called directly) and
                    ``levenberg_marquardt`` (the driver around it), ``gradients``,
                    ``finite_differences``; the types handed around: ``settings`` (the
                    validated arguments), ``result`` (the one frozen result),
                    ``details`` (each formulation's typed ``result.extra``), ``series``
                    (an ODE's forces and trajectory), ``status``,
                    ``summary_table``
==================  ======================================================================
"""

from .core.optimizers import adam
from .core.result import InverseResult, Uncertainty, Verdict
from .core.series import ForceSeries, OdeTrajectory
from .core.status import FitStatus
from .coverage import likelihood_coverage, steady_coverage
from .fitting import fit
from .formulations.all_at_once import ConstrainedInverse
from .formulations.forces import optimal_forces
from .formulations.noise_bounds import (
    ConsistencyTest,
    consistency_test,
    noise_bounds,
    sample_moments,
)
from .formulations.steady import ecfm_objective, standard_objective
from .problems.dynamic import DynamicInverseProblem
from .problems.galerkin import ReplicatedProblem, SteadyProblem
from .problems.model import ModelProblem
from .problems.moments import (
    DegenerateVarianceError,
    negative_log_pseudo_likelihood,
    sensor_moments,
)
from .problems.ode import OdeProblem
from .problems.pseudo_likelihood import PseudoLikelihood
from .statistics.diagnostics import (
    condition_number,
    expected_relative_error,
    fd_hessian,
    loss_surface,
    taylor_remainders,
)
from .statistics.loglik import LogLikelihood
from .statistics.prediction import Band, predict_band
from .statistics.profile import likelihood_ratio_test, profile_intervals, profile_likelihood
from .statistics.terms import TermsResult, discover_terms

__all__ = [
    "Band",
    "FitStatus",
    "ModelProblem",
    "OdeProblem",
    "ForceSeries",
    "OdeTrajectory",
    "ReplicatedProblem",
    "SteadyProblem",
    "Uncertainty",
    "Verdict",
    "fit",
    "LogLikelihood",
    "likelihood_ratio_test",
    "profile_intervals",
    "profile_likelihood",
    "ConsistencyTest",
    "ConstrainedInverse",
    "DegenerateVarianceError",
    "DynamicInverseProblem",
    "InverseResult",
    "PseudoLikelihood",
    "adam",
    "condition_number",
    "consistency_test",
    "ecfm_objective",
    "expected_relative_error",
    "fd_hessian",
    "loss_surface",
    "negative_log_pseudo_likelihood",
    "noise_bounds",
    "optimal_forces",
    "predict_band",
    "likelihood_coverage",
    "sample_moments",
    "sensor_moments",
    "standard_objective",
    "steady_coverage",
    "taylor_remainders",
    "TermsResult",
    "discover_terms",
]
