"""Models that are Python functions, for the calibration checks of ``reproduce coverage``.

Two small regressions of the kind a user brings to
:class:`~ecfm_uq.inverse.ModelProblem` (neither is a Galerkin system):

* :func:`decay_with_offset`: :math:`a e^{-b x} + c`, three parameters acting
  nonlinearly, for small-sample intervals (few data, sigma estimated) and for a bound on
  the offset that estimates reach;
* :func:`mirror_decay`: :math:`a e^{-b^2 x}`, whose likelihood has two basins (:math:`b`
  and :math:`-b` predict the same data), for profile regions.
"""

from __future__ import annotations

import numpy as np

__all__ = ["decay", "decay_with_offset", "mirror_decay"]


def decay(x):
    """``model(eps) = eps[0] exp(-eps[1] x)``: :func:`decay_with_offset` missing its offset."""
    x = np.asarray(x, dtype=float)

    def model(eps):
        return eps[0] * np.exp(-eps[1] * x)

    return model


def decay_with_offset(x):
    """``model(eps) = eps[0] exp(-eps[1] x) + eps[2]`` at the points ``x``."""
    x = np.asarray(x, dtype=float)

    def model(eps):
        return eps[0] * np.exp(-eps[1] * x) + eps[2]

    return model


def mirror_decay(x):
    """``model(eps) = eps[0] exp(-eps[1]**2 x)`` at the points ``x`` (even in ``eps[1]``)."""
    x = np.asarray(x, dtype=float)

    def model(eps):
        return eps[0] * np.exp(-(eps[1] ** 2) * x)

    return model
