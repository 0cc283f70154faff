"""The one result of every inverse fit, with its uncertainty and its verdict.

In the manner of :class:`scipy.optimize.OptimizeResult` (and of pyPESTO, where profiles
and samples are computed *from* a result), every formulation —
standard, ECFM, noisy, pseudo-likelihood, steady or dynamic — returns an
:class:`InverseResult` with the same fields:

* how the optimizer ended: ``success``, ``status`` (:class:`~ecfm_uq.inverse.core.status.FitStatus`, decided
  from the optimality conditions at the returned point), ``message``, ``nit``, ``nfev``,
  ``njev``, ``optimality``;
* the estimate: ``eps``, ``loss``, histories; the formulation's ``state``
  (:math:`\\Theta`) and constraint ``forces`` (:math:`\\lambda`) where it has them;
  further formulation-specific outputs in ``extra``, a typed record per formulation
  (:mod:`~ecfm_uq.inverse.core.details`, each key documented there and on
  :class:`InverseResult`);
* ``uncertainty``: an :class:`Uncertainty` (covariance, standard errors, intervals, how
  they were computed, or why not);
* ``verdict``: a :class:`Verdict`, the answer to "can this model explain these data?"
  as a test of stated size.

A result is frozen: :func:`~ecfm_uq.inverse.fit` builds it once, from the
:class:`~ecfm_uq.inverse.core.fitter.Outcome` its fitter returns.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special, stats

from ...chaos.inputs import Inputs
from ...chaos.student import StudentInputs
from .details import Details
from .status import FitStatus
from .summary_table import summary_table

__all__ = ["InverseResult", "Uncertainty", "Verdict"]

_FLOAT64 = np.dtype(np.float64)


def interval_quantile(level, dof=None):
    """The two-sided ``level`` quantile of every delta-method interval: normal, or
    Student-t with ``dof`` degrees of freedom when sigma was estimated (n - p).

    scipy.special's inverse CDFs: the quantiles of ``stats.norm.ppf``/``stats.t.ppf`` at a
    tenth of their per-call cost (a fit of a small model computes one).
    """
    q = 0.5 + level / 2
    return float(special.ndtri(q) if dof is None else special.stdtrit(dof, q))


@dataclass(frozen=True)
class Uncertainty:
    """How sure an estimate is: covariance, standard errors and intervals, or why not.

    Attributes
    ----------
    success : bool
        Whether the uncertainty could be computed (``False``: see ``message``).
    message : str
        Why not, or how (e.g. the non-identifiable parameter combination).
    cov : (n_eps, n_eps) ndarray or None
    stderr : (n_eps,) ndarray or None
    intervals : (n_eps, 2) ndarray or None
        Two-sided intervals at ``level`` (normal, or Student-t with ``dof``).
    level : float
        Coverage the intervals are built for (0.95).
    method : str
        ``"gauss-newton"`` (the default of the least-squares fits: the curvature of the
        sum of squares taken as :math:`J^TJ`, :math:`s^2(J^TJ)^{-1}` for the standard
        formulation, NIST's convention), ``"implicit"`` (delta method by implicit
        differentiation of the optimality condition with its full Hessian: the sandwich
        :math:`H^{-1}J^TJH^{-1}s^2` for least squares; ``options={"covariance":
        "sandwich"}``), ``"replicates"`` (sandwich from replicated data) or ``""`` when
        not computed.
    noise_model : str
        ``"known"`` (sigma given), ``"estimated"`` (from the residual), ``"replicates"``
        or ``"none"``.
    dof : int or None
        Degrees of freedom of Student-t intervals (sigma estimated), else ``None``.
    jacobian : (n_eps, n_data) ndarray or None
        :math:`d\\hat\\epsilon/dv`, the estimate's derivative in the data it was fitted to.
    sigma : float, (n_data,) ndarray or None
        The noise standard deviation the covariance is built on, per observation: the
        ``sigma`` given to :func:`~ecfm_uq.inverse.fit` (a number: that number), or the
        residual estimate :math:`s = \\sqrt{\\|r\\|^2/(n - p)}` (``noise_model ==
        "estimated"``, with :attr:`dof` :math:`= n - p`). One rule for an array ``sigma``:
        ``.sigma`` is each observation's own standard deviation, the ``(n,)`` array given,
        or the square roots of the diagonal of a covariance given (its correlations are in
        the fit, not here). ``None`` where the fit has no such noise level (replicated
        data, the random-force ECFM, a failed uncertainty).
    eps : (n_eps,) ndarray or None
        The estimate the covariance is centred on (the fit's ``eps``).
    names : list of str or None
        The parameter names (the problem's), for :meth:`to_inputs`.
    """

    success: bool
    message: str = ""
    cov: np.ndarray | None = None
    stderr: np.ndarray | None = None
    intervals: np.ndarray | None = None
    level: float = 0.95
    method: str = ""
    noise_model: str = "none"
    dof: int | None = None
    jacobian: np.ndarray | None = None
    sigma: float | np.ndarray | None = None
    eps: np.ndarray | None = None
    names: list | None = None

    @classmethod
    def failed(cls, message):
        """No uncertainty, and why."""
        return cls(False, str(message))

    def quantile(self, level):
        """The two-sided ``level`` quantile of these intervals (:func:`interval_quantile`
        with :attr:`dof`)."""
        return interval_quantile(level, self.dof)

    def to_inputs(self, kind="normal"):
        """The fit's uncertainty as the input distribution of a chaos or Monte Carlo study.

        Parameters
        ----------
        kind : {"normal", "t"}
            ``"normal"``: :math:`N(\\hat\\epsilon, \\mathrm{cov})`, an
            :class:`~ecfm_uq.chaos.Inputs` of normal marginals joined by a Gaussian copula
            (the map from its independent standard normal germ is the linear
            :math:`\\hat\\epsilon + \\mathrm{diag}(s) L\\xi`, :math:`LL^T` the
            correlation). ``"t"``: the multivariate Student t with :attr:`dof` :math:`= n -
            p` degrees of freedom, location :math:`\\hat\\epsilon` and scale matrix
            ``cov`` (:class:`~ecfm_uq.chaos.StudentInputs`; the marginal posterior of a
            linear model's parameters with sigma estimated under the Jeffreys prior); only
            when sigma was estimated.

        Returns
        -------
        Inputs or StudentInputs
            Named by :attr:`names` (``eps0, eps1, ...`` without names); accepted by
            :func:`~ecfm_uq.chaos.fit_pce`, :func:`~ecfm_uq.mc.sobol_indices` (``germ=True``
            for correlated parameters) and, through ``.sample(n, seed)``,
            :func:`~ecfm_uq.mc.monte_carlo`.

        Raises
        ------
        ValueError
            No covariance (the uncertainty failed or was not computed), an unknown
            ``kind``, ``kind="t"`` with sigma given.
        """
        if not isinstance(kind, str) or kind not in ("normal", "t"):
            raise ValueError(f"`kind` must be 'normal' or 't', got {kind!r}")
        if not self.success or self.cov is None or self.eps is None:
            raise ValueError(
                f"to_inputs needs the fit's covariance, and this fit has none ({self.message}); "
                "fit with uncertainty=True (the default) on data that determine every "
                "parameter (fix or reparametrize a non-identifiable one)"
            )
        eps = np.asarray(self.eps, dtype=float)
        cov = np.asarray(self.cov, dtype=float)
        names = list(self.names) if self.names else [f"eps{k}" for k in range(eps.size)]
        if kind == "t":
            if self.dof is None:
                raise ValueError(
                    f"to_inputs(kind='t') is for a sigma estimated from the residual (n - p "
                    f"degrees of freedom); this fit's noise is {self.noise_model!r}: use "
                    "kind='normal'"
                )
            return StudentInputs(eps, cov, self.dof, names=names)
        se = np.sqrt(np.diag(cov))
        if not np.all(se > 0):
            raise ValueError(
                "to_inputs: the covariance has a zero variance (a parameter the data fix "
                "exactly); drop it from the inputs"
            )
        corr = cov / np.outer(se, se)
        marginals = [stats.norm(m, s) for m, s in zip(eps, se, strict=True)]
        return Inputs(marginals, correlation=None if eps.size == 1 else corr, names=names)


@dataclass(frozen=True)
class Verdict:
    """Whether the fitted model explains the data: a test of stated size, one rule for all.

    ``consistent`` is ``p_value >= alpha`` (the data are compatible with the model plus
    its noise at level ``alpha``). For the exact-match ECFM on noise-free data there is no
    test of stated size: ``p_value`` and ``alpha`` are ``None`` and the rule is that the
    constraint forces change the observations by at most ``rtol`` of the data
    (``details["force_to_data"]``). A least-squares fit without a noise level or
    replicates has no test at all: ``consistent`` is ``None`` and ``message`` says what to
    give. See :mod:`ecfm_uq.inverse.statistics.verdict`.

    Attributes
    ----------
    consistent : bool or None
        ``None``: no test (no noise level, no replicates).
    p_value : float or None
    alpha : float or None
        The test's size (default 0.05).
    test : str
        Which test: e.g. ``"chi2"``, ``"likelihood-ratio tau=0"``, ``"moments z
        (Bonferroni)"``, ``"force-to-data"``.
    statistic : float or None
    message : str
        One sentence.
    details : dict
        Test-specific numbers (``chi2``, ``force_to_data``, ``peak_sensor_index``,
        ``peak_force_index``, ``at_bound``, ``extreme``, ...).
    identifiability : str
        Parameters at a bound (which side) or coefficients at an extreme value: a finding
        about what the data determine, reported beside the test, never folded into
        ``consistent``; empty when there is none.
    """

    consistent: bool | None
    p_value: float | None = None
    alpha: float | None = None
    test: str = ""
    statistic: float | None = None
    message: str = ""
    details: dict = field(default_factory=dict)
    identifiability: str = ""

    def __eq__(self, other):
        if isinstance(other, Verdict):
            return dataclasses.astuple(self) == dataclasses.astuple(other)
        return NotImplemented

    __hash__ = None


#: the computation behind :meth:`InverseResult.predict`, registered by
#: :mod:`ecfm_uq.inverse.statistics.prediction` on import (a layer below may not import
#: the one above it; the package's ``__init__`` imports that module, so it is always set)
_BAND_BUILDER = {}


def register_band_builder(build):
    """Make ``build(result, g, **options)`` the computation of :meth:`InverseResult.predict`."""
    _BAND_BUILDER["predict"] = build


def _empty_history():
    return np.zeros((0, 0))


@dataclass(frozen=True, repr=False, eq=False)
class InverseResult:
    """Outcome of an inverse fit (every formulation, every optimizer).

    Frozen: built once by :func:`~ecfm_uq.inverse.fit` from its fitter's
    :class:`~ecfm_uq.inverse.core.fitter.Outcome` (the status decided there).

    Attributes
    ----------
    eps : (n_eps,) ndarray
        The estimate (the optimizer's final point).
    loss : float
        Objective at ``eps``.
    status : FitStatus
        Decided from the optimality conditions at ``eps``; ``success`` is
        ``status == FitStatus.CONVERGED``.
    message : str
    nit : int
        Optimizer iterations (epochs for Adam).
    nfev, njev : int
        Objective and gradient (or Jacobian) evaluations. For a
        :class:`~ecfm_uq.inverse.problems.model.ModelProblem`, ``nfev`` is every model
        evaluation, those a Jacobian is differenced from (the status test's too) included
        (a given ``jac`` is not a model evaluation; the one-time check of complex steps
        aside), and ``njev`` the optimizer's Jacobians.
    optimality : float or None
        The measured first-order optimality at ``eps`` (unit-free; see
        :mod:`ecfm_uq.inverse.core.convergence`), when measured.
    formulation : str
        Label of the formulation that ran (``"standard"``, ``"ecfm"``, ``"noisy-ecfm"``,
        ``"likelihood-inner-outer"``, ...).
    method : str
        The optimizer that ran (what ``fit(method=)`` took, or the default chosen) (``"BFGS"``, ``"adam"``, ``"SLSQP"``, ...).
    eps_history : (nit + 1, n_eps) ndarray
    loss_history : (nit + 1,) ndarray
    state : ndarray or None
        The solution :math:`\\Theta` at the estimate (with the forces where the formulation
        has them): ``(N, P)`` for the steady least-squares and minimize fits and the
        replicated fits, the stacked unknowns ``theta`` of the all-at-once SLSQP fits;
        an :class:`~ecfm_uq.inverse.core.series.OdeTrajectory` (the fitted, forced
        solution with its dense output) for an
        :class:`~ecfm_uq.inverse.problems.ode.OdeProblem`;
        ``None`` for a :class:`~ecfm_uq.inverse.problems.model.ModelProblem`, the
        random-force ECFM and the dynamic fits (whose trajectory is
        ``problem.solve(result.eps, formulation)``; not kept, it is large).
    forces : ndarray or None
        The constraint forces :math:`\\lambda` at the estimate: ``(C,)`` for the steady
        and replicated ECFM fits (the posterior mean for the random-force ECFM; zeros for
        the replicated ``"standard"`` pseudo-likelihood, which holds them at zero),
        ``(n_steps + 1, C)`` for the dynamic ECFM, a
        :class:`~ecfm_uq.inverse.core.series.ForceSeries` (a labelled time series) for the
        ECFM of an :class:`~ecfm_uq.inverse.problems.ode.OdeProblem`; ``None`` where the formulation has no
        forces (``"standard"``, a :class:`~ecfm_uq.inverse.problems.model.ModelProblem`).
    uncertainty : Uncertainty
    verdict : Verdict or None
    likelihood : LogLikelihood, str or None
        The fit's negative log-likelihood in :math:`\\epsilon` (for
        :func:`~ecfm_uq.inverse.profile_intervals`), or why it has none.
    interval_likelihood : LogLikelihood, str or None
        Where it differs from ``likelihood``, the one the profile-likelihood intervals and
        likelihood-ratio tests use: for the random-force ECFM,
        :math:`\\ell(\\epsilon, \\hat\\tau(\\epsilon))` with the discrepancy's
        :math:`\\tau` re-estimated at every :math:`\\epsilon` (``likelihood`` holds the
        data covariance at :math:`\\hat\\tau`: a density of the data given
        :math:`\\epsilon`, what :func:`~ecfm_uq.inverse.sample_posterior` samples).
        A string where it cannot be built, saying why (:math:`\\tau` cannot be
        re-estimated at the estimate): the intervals then use ``likelihood``. ``None``
        where the intervals use ``likelihood`` by design (every other formulation, and
        the random-force ECFM with ``options={"tau_in_intervals": "held"}``).
    bounds : list of (lo, hi) or None
        The bounds the fit ran with.
    names : list of str or None
        Parameter names, where the problem has them.
    problem : ModelProblem or None
        The :class:`~ecfm_uq.inverse.problems.model.ModelProblem` that was fitted (its model
        gives :meth:`predict` its default quantity); ``None`` for the other problems.
    extra : Details
        Formulation-specific outputs: one frozen record per formulation family
        (:mod:`ecfm_uq.inverse.core.details`, each field documented there), read like a
        dict (``extra["tau"]``, ``extra.get("steps")``, ``"tau" in extra``) or by
        attribute (``extra.tau``); a field that is ``None`` (not computed by this fit) is
        not a key. Each key below (and no other):

        ============================  ========================  =========================
        key                           record (formulation)      meaning
        ============================  ========================  =========================
        ``prediction``                ModelDetails, OdeDetails  the model at ``eps``, in
                                      (ModelProblem,            the data's shape
                                      OdeProblem standard)
        ``n_missing``                 OdeDetails,               readings skipped (NaN)
                                      OdeEcfmDetails,
                                      OdeRandomDetails
        ``significant_forces``        OdeEcfmDetails (sigma)    ``(component, (t_start,
                                                                t_end), z)`` of each
                                                                force interval whose
                                                                z-score passes the
                                                                Bonferroni bound
        ``force_cov``                 OdeEcfmDetails (sigma)    covariance of the forces
                                                                (readings order)
        ``force_basis``,              OdeEcfmDetails            the forces' basis in time
        ``force_coefficients``        (``options["force_        and their coefficients
                                      basis"]``)                in it
        ``discrepancy``               AllAtOnceDetails          model minus data at the
                                      (all-at-once SLSQP)       optimum, ``(C,)``
        ``mean_discrepancy``,         AllAtOnceDetails          its sample mean and
        ``var_discrepancy``                                     variance
        ``residual_norm``             AllAtOnceDetails          norm of the model
                                                                equations' residual
        ``inequality``                AllAtOnceDetails          the scaled moment
                                                                inequalities (>= 0 when
                                                                met)
        ``moment_bounds``             AllAtOnceDetails          the z / chi-squared bounds
                                                                (dict)
        ``z``                         AllAtOnceDetails          the stacked unknowns
                                                                (theta, eps, lam)
        ``start``                     AllAtOnceDetails          how the start was built
        ``gradients``                 AllAtOnceDetails          ``"analytic"`` or ``"fd"``
        ``wall_time_s``               AllAtOnceDetails          SLSQP's wall time
        ``slsqp_status``              AllAtOnceDetails,         SLSQP's exit mode
                                      PenaltyDetails
        ``tau``                       RandomForceDetails,       rms of the forces'
                                      OdeRandomDetails          standard deviations
        ``force_tau``                 RandomForceDetails        each force's standard
                                                                deviation, ``(C,)``
        ``force_stderr``              RandomForceDetails        posterior standard
                                                                deviations of ``forces``
        ``force_prior``               RandomForceDetails        ``"shared"`` or
                                                                ``"sparse"``
        ``standard``                  RandomForceDetails,       the standard fit it
                                      OdeRandomDetails          started from: its
                                                                ``Outcome`` (what it
                                                                measured, no status:
                                                                ``holds(std.opt,
                                                                std.failure)`` whether
                                                                its conditions held)
        ``n_solves``                  RandomForceDetails,       forward solves
                                      ReplicatedDetails
        ``force_norm``                ReplicatedDetails         :math:`\\|\\lambda\\|`
        ``neg_log_likelihood``        ReplicatedDetails         the pseudo-likelihood
        ``grad_eps``                  ReplicatedDetails         its gradient in eps
        ``mu``, ``var``               ReplicatedDetails         the model's mean and
                                                                variance at the sensors
        ``n_failures``                ReplicatedDetails         failed evaluations
        ``optimality_solves``         ReplicatedDetails         solves of the status test
        ``inner_message``,            InnerOuterDetails         the last inner solve:
        ``inner_nit``,                (``inner-outer``)         message, iterations (all),
        ``hess_lam_min_eig``,                                   Hessian in lam (smallest
        ``hess_lam_cond``,                                      eigenvalue, condition),
        ``dlam_deps``                                           :math:`d\\lambda/d\\epsilon`
        ``penalty``,                  PenaltyDetails            the weight, the log force
        ``log_force_term``,           (``penalty``)             term, the norm of the
        ``grad_lam_norm``,                                      gradient in lam, the
        ``force_scaling_slope``                                 slope in log force scale
                                                                (0 at a minimum)
        ``grad``, ``grad_history``    DynamicDetails (Adam)     final gradient, all
                                                                gradients
        ``steps``                     DynamicDetails            the frozen time grid
                                      (``scheme=                (dict: ``n_steps``,
                                      "adaptive"``)             ``met``, ``max_error``,
                                                                ``times``, ...)
        ============================  ========================  =========================

        The steady ``"standard"`` and ``"ecfm"`` fits by least squares or ``minimize``
        have none (:class:`~ecfm_uq.inverse.core.details.Details`, empty).
    """

    eps: np.ndarray
    loss: float
    status: FitStatus = FitStatus.STALLED
    message: str = ""
    nit: int = 0
    nfev: int = 0
    njev: int = 0
    optimality: float | None = None
    formulation: str = ""
    method: str = ""
    eps_history: np.ndarray = field(default_factory=_empty_history)
    loss_history: np.ndarray = field(default_factory=lambda: np.zeros(0))
    state: np.ndarray | None = None
    forces: np.ndarray | None = None
    uncertainty: Uncertainty = field(default_factory=lambda: Uncertainty(False))
    verdict: Verdict | None = None
    likelihood: Any = None
    interval_likelihood: Any = None
    bounds: list | None = None
    names: list | None = None
    extra: Details = field(default_factory=Details)
    problem: Any = None

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        # each conversion only where the value is not already what it makes (a fitter's
        # result is built of float64 arrays, floats, ints and a FitStatus: the same
        # objects come out, without a call per field)
        if type(self.eps) is not np.ndarray or self.eps.dtype is not _FLOAT64:
            put("eps", np.asarray(self.eps, dtype=float))
        if type(self.loss) is not float:
            put("loss", float(self.loss))
        if type(self.status) is not FitStatus:
            put("status", FitStatus(self.status))
        if type(self.message) is not str:
            put("message", str(self.message))
        for name in ("nit", "nfev", "njev"):
            if type(getattr(self, name)) is not int:
                put(name, int(getattr(self, name)))
        if self.optimality is not None and type(self.optimality) is not float:
            put("optimality", float(self.optimality))
        if type(self.eps_history) is not np.ndarray:
            put("eps_history", np.asarray(self.eps_history))
        if type(self.loss_history) is not np.ndarray:
            put("loss_history", np.asarray(self.loss_history))
        if not isinstance(self.uncertainty, Uncertainty):
            raise TypeError(
                f"`uncertainty` must be an Uncertainty, got {type(self.uncertainty).__name__}"
            )
        if self.verdict is not None and not isinstance(self.verdict, Verdict):
            raise TypeError(f"`verdict` must be a Verdict, got {type(self.verdict).__name__}")
        if not isinstance(self.extra, Details):
            raise TypeError(
                f"`extra` must be a Details record (ecfm_uq.inverse.core.details), got "
                f"{type(self.extra).__name__}: each formulation reports its outputs in its "
                "own record, every field documented"
            )

    @property
    def success(self):
        """Whether the fit converged (``status == FitStatus.CONVERGED``)."""
        return self.status.success

    def __repr__(self):
        consistent = None if self.verdict is None else self.verdict.consistent
        return (
            f"<InverseResult {self.formulation} {self.status.name}: eps="
            f"{np.array2string(self.eps, precision=6)}, consistent={consistent}>"
        )

    def predict(self, g=None, *, level=0.95, kind="confidence", method="delta", **options):
        """A quantity of interest at the estimate with its ``level`` band.

        ``g(eps) -> array`` (default: the fitted :class:`~ecfm_uq.inverse.ModelProblem`'s
        predictions of its data) with a confidence band (the uncertainty of the estimate)
        or a prediction band (plus the noise of a new observation), by the delta method,
        a PCE of ``g`` or posterior samples. The computation is
        :func:`ecfm_uq.inverse.statistics.prediction.predict_band` (see it for every
        argument and what each method computes); it is handed to this layer when
        :mod:`ecfm_uq.inverse` is imported, so ``core`` imports nothing above it.

        Returns
        -------
        Band
        """
        return _BAND_BUILDER["predict"](self, g, level=level, kind=kind, method=method, **options)

    def summary(self, level=0.95, profile=None):
        """A table of the fit, as statsmodels and lmfit print one.

        One row per parameter: estimate, standard error, the ``level`` interval (the
        profile-likelihood interval of ``profile``, the summary
        :func:`~ecfm_uq.inverse.profile_likelihood` returned for this fit at that level,
        else the delta-method one, labelled), then the status, the measured optimality and
        the verdict with its test and p-value. A profile is passed in, never stored: the
        result does not change after the fit.

        Returns
        -------
        str
        """
        return summary_table(self, level, profile)
