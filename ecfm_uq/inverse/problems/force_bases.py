"""Bases in time for the ECFM forces of a problem with data at their own times.

The force is a function of time on the data's time scale, :math:`F(t) = \\sum_j
\\phi_j(t)\\lambda_j`, with knots at the data times :math:`t_0 < t_1 < \\dots < t_J`
(:math:`t_0` the initial time):

* ``"constant"`` (the default): :math:`J` functions, :math:`\\phi_j = 1` on the data
  interval :math:`(t_{j-1}, t_j]`, zero elsewhere: one force per data interval;
* ``"linear"``: the :math:`J + 1` hat functions of the knots (continuous piecewise linear
  forces, :math:`F(t_j) = \\lambda_j`), zero outside :math:`[t_0, t_J]`;
* ``{"rbf": w}``: :math:`J + 1` Gaussians :math:`\\phi_j(t) = \\exp(-\\tfrac12
  ((t - t_j)/w)^2)` centred at the knots, ``w`` (> 0) their width in time units.

The ECFM objective is the force function's :math:`L^2` over the data span,
:math:`\\tfrac12\\int_{t_0}^{t_J}|F|^2dt = \\tfrac12\\lambda^T(G\\otimes I)\\lambda` with
:math:`G_{ij} = \\int\\phi_i\\phi_j\\,dt` the basis' Gram matrix (:func:`gram`: exact for
all three, the Gaussians' by the error function). With more basis functions than data
intervals the exact match does not fix the forces: they are the *minimum-norm* forces
(in that :math:`L^2`) that match, :func:`right_inverse` the map of a linearized match.
"""

from __future__ import annotations

import numbers

import numpy as np
import scipy.linalg as sla
from scipy.special import erf

__all__ = [
    "FORCE_BASES",
    "basis_matrix",
    "check_force_basis",
    "checked_gram",
    "gram",
    "interval_means",
    "n_basis",
    "right_inverse",
]

#: the force bases by name (and ``{"rbf": width}``)
FORCE_BASES = ("constant", "linear")


def check_force_basis(force_basis):
    """``(kind, width)`` of a force basis: ``"constant"``, ``"linear"`` or ``{"rbf": w}``.

    Raises
    ------
    ValueError
        Naming ``force_basis``: an unknown name, or an RBF width not a positive number.
    """
    if isinstance(force_basis, str) and force_basis in FORCE_BASES:
        return force_basis, None
    if isinstance(force_basis, dict) and set(force_basis) == {"rbf"}:
        w = force_basis["rbf"]
        ok = isinstance(w, numbers.Real) and not isinstance(w, bool)
        if ok and np.isfinite(w) and w > 0:
            return "rbf", float(w)
        raise ValueError(
            f"`force_basis` {{'rbf': width}} needs a positive width in time units, got {w!r}"
        )
    raise ValueError(
        f"`force_basis` must be 'constant' (one force per data interval, the default), "
        f"'linear' (hat functions at the data times) or {{'rbf': width}} (Gaussians at the "
        f"data times, width in time units), got {force_basis!r}"
    )


def n_basis(kind, n_knots):
    """Number of basis functions for ``n_knots`` data times (the initial one included)."""
    return n_knots - 1 if kind == "constant" else n_knots


def basis_matrix(kind, width, knots, times):
    """:math:`\\phi_j(t_s)`, ``(len(times), n_basis)``: the forces at ``times`` are
    ``basis_matrix(...) @ lam``. A time equal to a knot :math:`t_j` belongs to the
    interval :math:`(t_{j-1}, t_j]` (``"constant"``); ``times`` at or before :math:`t_0`
    get no ``"constant"`` force."""
    knots = np.asarray(knots, dtype=float)
    times = np.asarray(times, dtype=float)
    J = knots.size - 1
    out = np.zeros((times.size, n_basis(kind, knots.size)))
    rows = np.arange(times.size)
    if kind == "constant":
        i = np.searchsorted(knots, times, side="left")
        held = (i >= 1) & (i <= J)
        out[rows[held], i[held] - 1] = 1.0
    elif kind == "linear":
        inside = (times >= knots[0]) & (times <= knots[-1])
        i = np.clip(np.searchsorted(knots, times, side="right") - 1, 0, J - 1)
        s = (times - knots[i]) / (knots[i + 1] - knots[i])
        out[rows[inside], i[inside]] = 1.0 - s[inside]
        out[rows[inside], i[inside] + 1] += s[inside]
    else:
        out[:] = np.exp(-0.5 * ((times[:, None] - knots[None, :]) / width) ** 2)
    return out


def gram(kind, width, knots):
    """The Gram matrix :math:`\\int_{t_0}^{t_J}\\phi_i\\phi_j\\,dt`, exact."""
    knots = np.asarray(knots, dtype=float)
    h = np.diff(knots)
    if kind == "constant":
        return np.diag(h)
    if kind == "linear":  # the P1 mass matrix
        G = np.zeros((knots.size, knots.size))
        idx = np.arange(h.size)
        G[idx, idx] += h / 3
        G[idx + 1, idx + 1] += h / 3
        G[idx, idx + 1] = G[idx + 1, idx] = h / 6
        return G
    c = knots
    m = 0.5 * (c[:, None] + c[None, :])
    a, b = knots[0], knots[-1]
    part = erf((b - m) / width) - erf((a - m) / width)
    return np.exp(-((c[:, None] - c[None, :]) ** 2) / (4 * width**2)) * (
        0.5 * width * np.sqrt(np.pi) * part
    )


def interval_means(kind, width, knots):
    """``(J, n_basis)``: the mean of each basis function over each data interval
    :math:`(t_{k-1}, t_k]`, so that ``interval_means(...) @ lam`` are the forces'
    interval means (their integrals over :math:`\\Delta t_k`), exact."""
    knots = np.asarray(knots, dtype=float)
    J = knots.size - 1
    if kind == "constant":
        return np.eye(J)
    if kind == "linear":
        M = np.zeros((J, J + 1))
        M[np.arange(J), np.arange(J)] = M[np.arange(J), np.arange(J) + 1] = 0.5
        return M
    a, b, c = knots[:-1, None], knots[1:, None], knots[None, :]
    r = np.sqrt(2.0) * width
    integral = 0.5 * np.sqrt(np.pi) * r * (erf((b - c) / r) - erf((a - c) / r))
    return integral / (b - a)


#: largest condition number of a Gram matrix accepted (wider Gaussians are refused)
MAX_GRAM_CONDITION = 1e10


def checked_gram(kind, width, knots):
    """:func:`gram`, refused when its functions are numerically dependent.

    Raises
    ------
    ValueError
        Naming ``force_basis``: Gaussians too wide for the data spacing (the condition
        number of the Gram matrix above :data:`MAX_GRAM_CONDITION`).
    """
    G = gram(kind, width, knots)
    cond = np.linalg.cond(G)
    if not np.isfinite(cond) or cond > MAX_GRAM_CONDITION:
        raise ValueError(
            f"`force_basis` {{'rbf': {width:g}}}: Gaussians this wide on data times "
            f"{float(np.min(np.diff(knots))):g} apart are numerically dependent (Gram "
            f"matrix condition number {cond:.2g}); choose a width of the order of the data "
            "spacing"
        )
    return G


def right_inverse(A, W):
    """``P`` with ``A P = I`` mapping a change of the match to the minimum-``W``-norm change
    of the forces: ``inv(A)`` when square, else :math:`W^{-1}A^T(AW^{-1}A^T)^{-1}`.

    Raises
    ------
    numpy.linalg.LinAlgError
        ``A`` (or :math:`AW^{-1}A^T`) singular: a force reaching no sensor.
    """
    if A.shape[0] == A.shape[1]:
        return np.linalg.inv(A)
    WiAt = sla.cho_solve(sla.cho_factor(W), A.T)
    return WiAt @ np.linalg.inv(A @ WiAt)
