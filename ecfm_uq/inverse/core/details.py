"""The formulation-specific outputs of a fit (``InverseResult.extra``), one typed record each.

Every formulation reports, beside the fields every fit has (:class:`~ecfm_uq.inverse.
InverseResult`), a few outputs of its own: the all-at-once fits their discrepancy and
moment bounds, the random-force ECFM its :math:`\\tau`, the replicated fits the
pseudo-likelihood's moments, ... Each family has one frozen record here, every field
documented, kept on the result as ``result.extra``. A record reads like the dict it
replaces (``extra["tau"]``, ``extra.get("steps")``, ``"tau" in extra``, ``extra.keys()``:
:class:`Details` is a :class:`collections.abc.Mapping` over its fields) and also by
attribute (``extra.tau``). A fitter cannot report an undocumented key: a record takes its
fields only (an unknown name is a TypeError).

One rule for what is a key: a field that is ``None`` (not computed by this fit, or not
applicable: a dynamic fit's ``steps`` without ``scheme="adaptive"``, the ODE ECFM's force
covariance without ``sigma``) is not a key, as it was absent from the dict before; the
attribute is ``None``.

Kept on the result's own fields, not here: the histories (``eps_history``,
``loss_history``: every fit has them), the state, the forces, the likelihoods and the
counts.

=========================  ===============================================================
record                     formulation
=========================  ===============================================================
:class:`Details`           none of its own: the steady ``"standard"`` and ``"ecfm"`` fits
                           by least squares or ``minimize``
:class:`ModelDetails`      :class:`~ecfm_uq.inverse.ModelProblem`
:class:`OdeDetails`        :class:`~ecfm_uq.inverse.OdeProblem`, ``"standard"``
:class:`OdeEcfmDetails`    :class:`~ecfm_uq.inverse.OdeProblem`, ``"ecfm"``
:class:`OdeRandomDetails`  :class:`~ecfm_uq.inverse.OdeProblem`, ``"ecfm-random"``
:class:`RandomForceDetails`  steady ``"ecfm-random"``
:class:`AllAtOnceDetails`  steady ``"noisy-ecfm"``, ``method="all-at-once"``
:class:`DynamicDetails`    :class:`~ecfm_uq.inverse.DynamicInverseProblem`
:class:`ReplicatedDetails`  :class:`~ecfm_uq.inverse.ReplicatedProblem`, ``"standard"``
:class:`InnerOuterDetails`  :class:`~ecfm_uq.inverse.ReplicatedProblem`, ``"inner-outer"``
                           (``"ecfm"``)
:class:`PenaltyDetails`    :class:`~ecfm_uq.inverse.ReplicatedProblem`, ``"penalty"``
=========================  ===============================================================
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "AllAtOnceDetails",
    "Details",
    "DynamicDetails",
    "InnerOuterDetails",
    "ModelDetails",
    "OdeDetails",
    "OdeEcfmDetails",
    "OdeRandomDetails",
    "PenaltyDetails",
    "RandomForceDetails",
    "ReplicatedDetails",
]


@dataclass(frozen=True, eq=False)
class Details(Mapping):
    """A fit's formulation-specific outputs: none (the base of every record).

    A read-only mapping over the record's fields that are not ``None`` (the keys), in
    the order of their declaration; each field also an attribute. Equality is the
    mapping's (the same keys and values), as for the dict it replaces.
    """

    @classmethod
    def documented(cls):
        """The names of the fields this record can hold (its possible keys)."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def _keys(self):
        return [name for name in self.documented() if getattr(self, name) is not None]

    def __getitem__(self, key):
        if isinstance(key, str) and key in self.documented():
            value = getattr(self, key)
            if value is not None:
                return value
            raise KeyError(
                f"{key!r}: not computed by this fit ({type(self).__name__}.{key} is None); "
                f"its details are {self._keys()}"
            )
        raise KeyError(
            f"{key!r}: not a detail of this fit; {type(self).__name__} holds "
            f"{list(self.documented())} (see its docstring)"
        )

    def __iter__(self):
        return iter(self._keys())

    def __len__(self):
        return len(self._keys())

    def __contains__(self, key):
        return isinstance(key, str) and key in self.documented() and getattr(self, key) is not None

    def __repr__(self):
        inner = ", ".join(f"{k}={_short(v)}" for k, v in self.items())
        return f"{type(self).__name__}({inner})"


def _short(value):
    if isinstance(value, np.ndarray):
        return f"<array {value.shape}>"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


@dataclass(frozen=True, eq=False, repr=False)
class ModelDetails(Details):
    """The outputs of a fit of a :class:`~ecfm_uq.inverse.ModelProblem`.

    Attributes
    ----------
    prediction : ndarray or None
        The model at ``eps``, in the data's shape (``None``: the fit stopped where the
        model fails).
    """

    prediction: np.ndarray | None = None


@dataclass(frozen=True, eq=False, repr=False)
class OdeDetails(Details):
    """The outputs of the least-squares fit of an :class:`~ecfm_uq.inverse.OdeProblem`.

    Attributes
    ----------
    prediction : (n_times, n_components) ndarray
        The predicted readings at ``eps`` (NaN where the model cannot be solved there).
    n_missing : int
        The readings skipped (NaN in the data).
    """

    prediction: np.ndarray | None = None
    n_missing: int | None = None


@dataclass(frozen=True, eq=False, repr=False)
class OdeEcfmDetails(Details):
    """The outputs of the ECFM fit of an :class:`~ecfm_uq.inverse.OdeProblem`.

    Attributes
    ----------
    n_missing : int
        The readings skipped (NaN in the data).
    significant_forces : list of (str, (float, float), float) or None
        ``(component, (t_start, t_end), z)`` of each force window whose z-score passes
        the Bonferroni bound (with ``sigma``, forces piecewise constant).
    force_cov : ndarray or None
        The covariance of the forces, readings order (with ``sigma``, forces piecewise
        constant).
    force_basis : str or dict or None
        The forces' basis in time when it is not piecewise constant
        (``options["force_basis"]``).
    force_coefficients : ndarray or None
        The forces' coefficients in that basis.
    """

    n_missing: int | None = None
    significant_forces: list | None = None
    force_cov: np.ndarray | None = None
    force_basis: Any = None
    force_coefficients: np.ndarray | None = None


@dataclass(frozen=True, eq=False, repr=False)
class OdeRandomDetails(Details):
    """The outputs of the random-force ECFM of an :class:`~ecfm_uq.inverse.OdeProblem`.

    Attributes
    ----------
    tau : float
        The REML estimate of the forces' standard deviation.
    standard : Outcome
        The standard fit it started from (what it measured).
    n_missing : int
        The readings skipped (NaN in the data).
    """

    tau: float | None = None
    standard: Any = None
    n_missing: int | None = None


@dataclass(frozen=True, eq=False, repr=False)
class RandomForceDetails(Details):
    """The outputs of the random-force ECFM of a steady problem.

    Attributes
    ----------
    force_stderr : (C,) ndarray
        The posterior standard deviations of ``result.forces``.
    tau : float
        The root mean square of the forces' standard deviations.
    force_prior : str
        ``"shared"`` (one variance for every force) or ``"sparse"`` (one per force).
    force_tau : (C,) ndarray
        Each force's standard deviation.
    standard : InverseResult or Outcome
        The standard fit it started from.
    n_solves : int
        Forward solves.
    """

    force_stderr: np.ndarray | None = None
    tau: float | None = None
    force_prior: str | None = None
    force_tau: np.ndarray | None = None
    standard: Any = None
    n_solves: int | None = None


@dataclass(frozen=True, eq=False, repr=False)
class AllAtOnceDetails(Details):
    """The outputs of the all-at-once SLSQP fits of a steady problem (``"noisy-ecfm"``,
    ``method="all-at-once"``).

    Attributes
    ----------
    discrepancy : (C,) ndarray
        Model minus data at the optimum.
    mean_discrepancy, var_discrepancy : float
        Its sample mean and variance.
    residual_norm : float
        The norm of the model equations' residual.
    inequality : ndarray
        The scaled moment inequalities (``>= 0`` where met).
    moment_bounds : dict
        The z / chi-squared bounds.
    slsqp_status : int
        SLSQP's exit mode.
    start : str
        How the start was built.
    gradients : str
        ``"analytic"`` or ``"fd"``.
    wall_time_s : float
        SLSQP's wall time.
    z : ndarray
        The stacked unknowns ``(theta, eps, lam)`` (their number: ``z.size``).
    """

    discrepancy: np.ndarray | None = None
    mean_discrepancy: float | None = None
    var_discrepancy: float | None = None
    residual_norm: float | None = None
    inequality: np.ndarray | None = None
    moment_bounds: dict | None = None
    slsqp_status: int | None = None
    start: str | None = None
    gradients: str | None = None
    wall_time_s: float | None = None
    z: np.ndarray | None = None


@dataclass(frozen=True, eq=False, repr=False)
class DynamicDetails(Details):
    """The outputs of a fit of a :class:`~ecfm_uq.inverse.DynamicInverseProblem`.

    Attributes
    ----------
    steps : dict or None
        With ``scheme="adaptive"``: the frozen time grid (``n_steps``, ``n_data``,
        ``rtol``, ``atol``, ``max_error``, ``met``, ``refrozen``, ``times``, ``message``;
        ``n_steps=None``, ``met=False`` and the ``message`` when no grid could be chosen).
    grad : (n_eps,) ndarray or None
        With ``method="adam"``: the final gradient.
    grad_history : (nit + 1, n_eps) ndarray or None
        With ``method="adam"``: every gradient.
    """

    steps: dict | None = None
    grad: np.ndarray | None = None
    grad_history: np.ndarray | None = None


@dataclass(frozen=True, eq=False, repr=False)
class ReplicatedDetails(Details):
    """The outputs of a fit of a :class:`~ecfm_uq.inverse.ReplicatedProblem`
    (``"standard"``: the forces held at zero).

    Attributes
    ----------
    force_norm : float
        :math:`\\|\\lambda\\|` of ``result.forces``.
    neg_log_likelihood : float
        The pseudo-likelihood at the estimate.
    grad_eps : (n_eps,) ndarray
        Its gradient in eps.
    mu, var : (C,) ndarray
        The model's mean and variance at the sensors.
    n_solves : int
        Forward solves of the fit.
    optimality_solves : int
        Forward solves of the status test.
    n_failures : int
        Failed evaluations.
    """

    force_norm: float | None = None
    neg_log_likelihood: float | None = None
    grad_eps: np.ndarray | None = None
    mu: np.ndarray | None = None
    var: np.ndarray | None = None
    n_solves: int | None = None
    optimality_solves: int | None = None
    n_failures: int | None = None


@dataclass(frozen=True, eq=False, repr=False)
class InnerOuterDetails(ReplicatedDetails):
    """The outputs of the ``"inner-outer"`` (``"ecfm"``) fit of a
    :class:`~ecfm_uq.inverse.ReplicatedProblem`: :class:`ReplicatedDetails`' and the
    last inner solve's.

    Attributes
    ----------
    inner_message : str
        The last inner solve's message.
    inner_nit : int
        The inner solves' iterations, all of them.
    hess_lam_min_eig, hess_lam_cond : float
        The smallest eigenvalue and the condition number of the Hessian in lam.
    dlam_deps : ndarray
        :math:`d\\lambda/d\\epsilon`.
    """

    inner_message: str | None = None
    inner_nit: int | None = None
    hess_lam_min_eig: float | None = None
    hess_lam_cond: float | None = None
    dlam_deps: np.ndarray | None = None


@dataclass(frozen=True, eq=False, repr=False)
class PenaltyDetails(ReplicatedDetails):
    """The outputs of the ``"penalty"`` fit of a :class:`~ecfm_uq.inverse.ReplicatedProblem`:
    :class:`ReplicatedDetails`' and the penalty form's.

    Attributes
    ----------
    penalty : float
        The weight :math:`\\alpha`.
    log_force_term : float
        :math:`\\log(\\|\\lambda\\|^2/2)`.
    grad_lam_norm : float
        The norm of the gradient in lam.
    force_scaling_slope : float or None
        The objective's slope in the log of the force scale (0 at a minimum; ``None``
        where the returned point cannot be evaluated).
    slsqp_status : int
        SLSQP's exit mode.
    """

    penalty: float | None = None
    log_force_term: float | None = None
    grad_lam_norm: float | None = None
    force_scaling_slope: float | None = None
    slsqp_status: int | None = None
