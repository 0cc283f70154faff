"""The common result of every inverse formulation."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class InverseResult:
    """Outcome of an inverse solve.

    Attributes
    ----------
    eps : (n_eps,) ndarray
        Final model parameters.
    loss : float
        Objective at ``eps``.
    success : bool
        Whether the optimizer (and every inner solve) reported success.
    message : str
    nit : int
        Optimizer iterations (epochs for Adam).
    method : str
        ``"standard"``, ``"ecfm"``, ``"noisy-ecfm"``, ...
    eps_history : (nit + 1, n_eps) ndarray
    loss_history : (nit + 1,) ndarray
    extra : dict
        Formulation-specific outputs (state, forces, diagnostics).
    eps_cov : (n_eps, n_eps) ndarray or None
        Delta-method covariance of ``eps`` (:mod:`ecfm_uq.inverse.uncertainty`);
        None where not computed (see ``uncertainty_message``).
    eps_stderr : (n_eps,) ndarray or None
    eps_ci95 : (n_eps, 2) ndarray or None
    noise_model : str
        ``"known"`` (sigma given), ``"estimated"`` (s^2 = ||r||^2/(C - n_eps)),
        ``"replicates"`` (sample covariance of replicated data) or ``"none"``.
    uncertainty_message : str
        Why the uncertainty fields are None, if they are.
    eps_jacobian : (n_eps, n_data) ndarray or None
        :math:`d\\hat\\epsilon/dv`, the implicit derivative of the estimate in the data it
        was computed from (for :func:`~ecfm_uq.inverse.fit_pseudo_likelihood` the replicate
        statistics of :func:`~ecfm_uq.inverse.likelihood.replicate_statistics`).
    """

    eps: np.ndarray
    loss: float
    success: bool
    message: str
    nit: int
    method: str
    eps_history: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    loss_history: np.ndarray = field(default_factory=lambda: np.zeros(0))
    extra: dict = field(default_factory=dict)
    eps_cov: np.ndarray | None = None
    eps_stderr: np.ndarray | None = None
    eps_ci95: np.ndarray | None = None
    noise_model: str = "none"
    uncertainty_message: str = ""
    eps_jacobian: np.ndarray | None = None

    def __repr__(self):
        return (
            f"InverseResult(method={self.method!r}, eps={np.array2string(self.eps, precision=6)}, "
            f"loss={self.loss:.3e}, success={self.success}, nit={self.nit}, message={self.message!r})"
        )
