"""How an inverse fit ended: one status vocabulary for every formulation and optimizer.

In the manner of :class:`scipy.optimize.OptimizeResult`, every
:class:`~ecfm_uq.inverse.InverseResult` carries ``success``, ``status`` and ``message``.
Unlike scipy's per-method codes, ``status`` means the same thing whatever formulation
(standard, ECFM, noisy, pseudo-likelihood, dynamic) and optimizer ran the fit, and it is
decided from the optimality conditions at the returned point, not from the message of
the library underneath: an optimizer that stopped on "precision loss" at a point where
the (projected) gradient or the KKT conditions hold to tolerance is ``CONVERGED``; one
that reported success away from such a point is not.

``success`` is ``status == FitStatus.CONVERGED``.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["FitStatus"]


class FitStatus(IntEnum):
    """Why a fit stopped.

    Attributes
    ----------
    CONVERGED : 0
        First-order optimality (gradient, projected gradient on bounds, or KKT
        conditions) holds to tolerance at the returned point.
    MAX_ITERATIONS : 1
        The iteration, epoch or evaluation budget ran out before optimality was reached.
    STALLED : 2
        The optimizer stopped short of optimality (line search or trust region unable to
        make progress) and restarts did not help.
    MODEL_FAILURE : 3
        The model cannot be solved at the returned point (or the optimizer kept stepping
        into parameters where it cannot be solved).
    INFEASIBLE : 4
        The constraints of the formulation cannot be satisfied.
    NOT_UNIQUE : 5
        The optimality conditions hold on a whole set of parameters, not at a point
        (e.g. the noisy ECFM's feasible set with zero forces): the returned point is one
        member, not an estimate.
    """

    CONVERGED = 0
    MAX_ITERATIONS = 1
    STALLED = 2
    MODEL_FAILURE = 3
    INFEASIBLE = 4
    NOT_UNIQUE = 5

    @property
    def success(self):
        """Whether this status counts as a successful fit."""
        return self is FitStatus.CONVERGED

    def __str__(self):
        """The name, not the code: ``print(res.status)`` prints ``CONVERGED``."""
        return self.name

    def __format__(self, spec):
        return format(self.name, spec)
