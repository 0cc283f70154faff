"""The pseudo-spectral projection of node values onto a chaos basis (paper Eq. ``pce``).

One implementation, used by ``fit_pce(method="quadrature")``,
:meth:`~ecfm_uq.chaos.PolynomialChaosExpansion.from_chaospy` and
:func:`ecfm_uq.mc.pseudospectral_projection`.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array
from .basis import ChaosBasis

__all__ = ["project"]


def project(basis, nodes, weights, values):
    """Pseudo-spectral projection :math:`c_k = \\sum_q w_q y_q \\Psi_k(\\omega_q) / n_k`.

    The one discrete projection of the package: ``fit_pce(method="quadrature")``,
    :meth:`PolynomialChaosExpansion.from_chaospy` and
    :func:`ecfm_uq.mc.pseudospectral_projection` all call it.

    Parameters
    ----------
    basis : ChaosBasis
        With P terms and :math:`n_k = \\mathbb E[\\Psi_k^2]` (``basis.norms2``).
    nodes : (n, dim) array_like
        Germ points of a quadrature rule.
    weights : (n,) array_like
        Its probability weights.
    values : (n, *output_shape) array_like
        Model outputs at the nodes.

    Returns
    -------
    (P, *output_shape) ndarray
        Exact coefficients when the rule integrates :math:`y\\,\\Psi_k` exactly.

    Examples
    --------
    >>> basis = ChaosBasis(2)
    >>> nodes, w = basis.quadrature(3)
    >>> project(basis, nodes, w, nodes[:, 0] ** 2).round(6).tolist()  # w^2 = 1/3 + ...
    [0.333333, 0.288675, 0.074536]
    """
    if not isinstance(basis, ChaosBasis):
        raise TypeError(f"`basis` must be a ChaosBasis, got {type(basis).__name__}")
    weights = as_finite_array("weights", weights, ndim=1)
    y = as_finite_array("values", values)
    if y.ndim == 0 or y.shape[0] != len(weights):
        raise ValueError(
            f"`values` must have shape (n, *output_shape) with n = {len(weights)} rows, one "
            f"per node, got {y.shape}"
        )
    Psi = basis.evaluate(nodes)
    yf = y.reshape(len(weights), -1)
    c = (Psi * weights[:, None]).T @ yf / np.asarray(basis.norms2)[:, None]
    return c.reshape((basis.size, *y.shape[1:]))
