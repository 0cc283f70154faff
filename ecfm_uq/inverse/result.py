"""The one result of every inverse fit, with its uncertainty and its verdict.

In the manner of :class:`scipy.optimize.OptimizeResult` (and of pyPESTO, where profiles
and samples are computed *from* a result and stored beside it), every formulation —
standard, ECFM, noisy, pseudo-likelihood, steady or dynamic — returns an
:class:`InverseResult` with the same fields:

* how the optimizer ended: ``success``, ``status`` (:class:`~.status.FitStatus`, decided
  from the optimality conditions at the returned point), ``message``, ``nit``, ``nfev``,
  ``njev``, ``optimality``;
* the estimate: ``eps``, ``loss``, histories, formulation-specific arrays in ``extra``;
* ``uncertainty``: an :class:`Uncertainty` (covariance, standard errors, intervals, how
  they were computed, or why not);
* ``verdict``: a :class:`Verdict`, the answer to "can this model explain these data?"
  as a test of stated size.

The v0.2 spellings (``eps_cov``, ``eps_stderr``, ``eps_ci95``, ``noise_model``,
``uncertainty_message``, ``eps_jacobian``, ``extra["verdict"][...]``) still read (and
write) the same information.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .status import FitStatus

__all__ = ["InverseResult", "Uncertainty", "Verdict"]


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

    @classmethod
    def failed(cls, message):
        """No uncertainty, and why."""
        return cls(False, str(message))


_UNCERTAINTY_ALIASES = {
    "eps_cov": "cov",
    "eps_stderr": "stderr",
    "eps_ci95": "intervals",
    "noise_model": "noise_model",
    "eps_jacobian": "jacobian",
    "covariance_method": "method",
}


@dataclass(frozen=True)
class Verdict(Mapping):
    """Whether the fitted model explains the data: a test of stated size, one rule for all.

    ``consistent`` is ``p_value >= alpha`` (the data are compatible with the model plus
    its noise at level ``alpha``). For the exact-match ECFM on noise-free data there is no
    test of stated size: ``p_value`` and ``alpha`` are ``None`` and the rule is that the
    constraint forces change the observations by at most ``rtol`` of the data
    (``details["force_to_data"]``). A least-squares fit without a noise level or
    replicates has no test at all: ``consistent`` is ``None`` and ``message`` says what to
    give. See :mod:`ecfm_uq.inverse.verdict`.

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

    Notes
    -----
    Reads as a mapping too (``verdict["consistent"]``, ``verdict["force_to_data"]``), the
    v0.2 dict form.
    """

    consistent: bool | None
    p_value: float | None = None
    alpha: float | None = None
    test: str = ""
    statistic: float | None = None
    message: str = ""
    details: dict = field(default_factory=dict)
    identifiability: str = ""

    def _view(self):
        out = {
            "consistent": self.consistent,
            "message": self.message,
            "p_value": self.p_value,
            "alpha": self.alpha,
            "test": self.test,
            "statistic": self.statistic,
        }
        out.update(self.details)
        return out

    def __getitem__(self, key):
        return self._view()[key]

    def __iter__(self):
        return iter(self._view())

    def __len__(self):
        return len(self._view())

    def __eq__(self, other):
        if isinstance(other, Verdict):
            return dataclasses.astuple(self) == dataclasses.astuple(other)
        return NotImplemented

    __hash__ = None


class InverseResult:
    """Outcome of an inverse fit (every formulation, every optimizer).

    Attributes
    ----------
    eps : (n_eps,) ndarray
        The estimate (the optimizer's final point).
    loss : float
        Objective at ``eps``.
    success : bool
        ``status == FitStatus.CONVERGED``: the optimality conditions hold at ``eps``.
    status : FitStatus
    message : str
    nit : int
        Optimizer iterations (epochs for Adam).
    nfev, njev : int
        Objective and gradient (or Jacobian) evaluations.
    optimality : float or None
        The measured first-order optimality at ``eps`` (unit-free; see
        :mod:`ecfm_uq.inverse.convergence`), when measured.
    method : str
        Label of the formulation that ran (``"standard"``, ``"ecfm"``, ``"noisy-ecfm"``,
        ``"likelihood-inner-outer"``, ...).
    optimizer : str
        The optimizer that ran (``"BFGS"``, ``"adam"``, ``"SLSQP"``, ...).
    eps_history : (nit + 1, n_eps) ndarray
    loss_history : (nit + 1,) ndarray
    extra : dict
        Formulation-specific outputs (state, forces, diagnostics); ``extra["verdict"]``
        is :attr:`verdict`.
    uncertainty : Uncertainty
    verdict : Verdict or None
    likelihood : LogLikelihood, str or None
        The fit's negative log-likelihood in :math:`\\epsilon` (for
        :func:`~ecfm_uq.inverse.profile_intervals`), or why it has none.
    interval_likelihood : LogLikelihood or None
        Where it differs from ``likelihood``, the one the profile-likelihood intervals and
        likelihood-ratio tests use: for the random-force ECFM,
        :math:`\\ell(\\epsilon, \\hat\\tau(\\epsilon))` with the discrepancy's
        :math:`\\tau` re-estimated at every :math:`\\epsilon` (``likelihood`` holds the
        data covariance at :math:`\\hat\\tau`: a density of the data given
        :math:`\\epsilon`, what :func:`~ecfm_uq.inverse.sample_posterior` samples).
    bounds : list of (lo, hi) or None
        The bounds the fit ran with.

    Notes
    -----
    The v0.2 names ``eps_cov``, ``eps_stderr``, ``eps_ci95``, ``noise_model``,
    ``eps_jacobian`` and ``uncertainty_message`` (and ``covariance_method``, the
    uncertainty's ``method``) read and write :attr:`uncertainty`.
    """

    def __init__(
        self,
        eps,
        loss,
        success=None,
        message="",
        nit=0,
        method="",
        eps_history=None,
        loss_history=None,
        extra=None,
        *,
        status=None,
        nfev=0,
        njev=0,
        optimality=None,
        optimizer="",
        uncertainty=None,
        verdict=None,
        eps_cov=None,
        eps_stderr=None,
        eps_ci95=None,
        noise_model="none",
        uncertainty_message="",
        eps_jacobian=None,
        covariance_method=None,
        dof=None,
    ):
        self.eps = np.asarray(eps, dtype=float)
        self.loss = float(loss)
        if status is None:
            status = FitStatus.CONVERGED if success else FitStatus.STALLED
        self.status = FitStatus(status)
        if success is not None and bool(success) != self.status.success:
            raise ValueError(f"`success`={success} contradicts `status`={self.status.name}")
        self.message = str(message)
        self.nit = int(nit)
        self.nfev, self.njev = int(nfev), int(njev)
        self.optimality = None if optimality is None else float(optimality)
        self.method = method
        self.optimizer = optimizer
        self.eps_history = np.zeros((0, 0)) if eps_history is None else np.asarray(eps_history)
        self.loss_history = np.zeros(0) if loss_history is None else np.asarray(loss_history)
        self.extra = {} if extra is None else dict(extra)
        if uncertainty is None:
            computed = eps_cov is not None
            uncertainty = Uncertainty(
                computed,
                uncertainty_message,
                eps_cov,
                eps_stderr,
                eps_ci95,
                noise_model=noise_model,
                dof=dof,
                jacobian=eps_jacobian,
                method=(covariance_method or "implicit") if computed else "",
            )
        self.uncertainty = uncertainty
        if verdict is None and "verdict" in self.extra:
            verdict = self.extra["verdict"]
        self.verdict = verdict
        self.likelihood = None  # set by fit: a LogLikelihood, or why there is none
        self.interval_likelihood = None  # set by fit where the intervals use another one
        self.bounds = None  # the bounds the fit ran with
        self.names = None  # parameter names, where the problem has them

    # -- status ---------------------------------------------------------------------------
    @property
    def success(self):
        """Whether the fit converged (``status == FitStatus.CONVERGED``)."""
        return self.status.success

    @success.setter
    def success(self, value):
        if bool(value):
            self.status = FitStatus.CONVERGED
        elif self.status.success:
            self.status = FitStatus.STALLED

    # -- verdict (also extra["verdict"]) --------------------------------------------------
    @property
    def verdict(self):
        """The :class:`Verdict` (``None`` when the formulation has no noise model yet)."""
        return self._verdict

    @verdict.setter
    def verdict(self, value):
        if isinstance(value, Mapping) and not isinstance(value, Verdict):
            value = _verdict_from_dict(value)
        self._verdict = value
        if value is None:
            self.extra.pop("verdict", None)
        else:
            self.extra["verdict"] = value

    # -- v0.2 names of the uncertainty ----------------------------------------------------
    @property
    def uncertainty_message(self):
        """Why the uncertainty is missing (empty when it was computed)."""
        return self.uncertainty.message

    @uncertainty_message.setter
    def uncertainty_message(self, value):
        self.uncertainty = dataclasses.replace(self.uncertainty, message=str(value))

    def __repr__(self):
        consistent = None if self.verdict is None else self.verdict.consistent
        return (
            f"<InverseResult {self.method} {self.status.name}: eps="
            f"{np.array2string(self.eps, precision=6)}, consistent={consistent}>"
        )

    def summary(self, level=0.95):
        """A table of the fit, as statsmodels and lmfit print one.

        One row per parameter: estimate, standard error, the ``level`` interval (the
        profile-likelihood interval where :func:`~ecfm_uq.inverse.profile_likelihood` has
        run at that level, else the delta-method one, labelled), then the status, the
        measured optimality and the verdict with its test and p-value.

        Returns
        -------
        str
        """
        from .summary_table import summary_table

        return summary_table(self, level)


def _alias_property(old, new):
    def get(self):
        return getattr(self.uncertainty, new)

    def set_(self, value):
        changes = {new: value}
        if new == "cov":
            changes["success"] = value is not None
        self.uncertainty = dataclasses.replace(self.uncertainty, **changes)

    return property(get, set_, doc=f"v0.2 name of ``uncertainty.{new}``.")


for _old, _new in _UNCERTAINTY_ALIASES.items():
    setattr(InverseResult, _old, _alias_property(_old, _new))


def _verdict_from_dict(d):
    """A :class:`Verdict` from the v0.2 dict form (``consistent``, ``message``, details)."""
    d = dict(d)
    keys = ("consistent", "p_value", "alpha", "test", "statistic", "message")
    fields = {k: d.pop(k) for k in keys if k in d}
    fields.setdefault("consistent", False)
    return Verdict(**fields, details=d)
