"""Fixed-step implicit schemes of :func:`.stepping.march`, each step a backward-Euler-like solve.

Every scheme here advances :math:`M\\dot\\Theta + R(\\Theta; \\epsilon, \\lambda, t) = 0`
from the grid time :math:`t_s` to :math:`t_{s+1} = t_s + \\Delta t` by one nonlinear solve

.. math::

    \\frac{M}{h_s}\\Bigl(\\Theta_{s+1} - \\sum_j w_{s,j}\\,\\Theta_{s-j}\\Bigr)
        + R(\\Theta_{s+1}; \\epsilon, \\lambda_{s+1}, t_{s+1}) = 0,

i.e. a backward-Euler step of effective length :math:`h_s` from the combination
:math:`\\psi_s = \\sum_j w_{s,j}\\Theta_{s-j}` of earlier states. Its Jacobian is the
backward-Euler one, :math:`M/h_s + \\partial R/\\partial\\Theta`, so every solver, warm
start and preconditioner of the march serves every scheme, and so do the forward
sensitivities (the same solve with :math:`\\partial\\psi_s/\\partial\\epsilon` on the
right) and the discrete adjoint (:func:`.trajectory._generic_adjoint`, which carries
:math:`w_{s,j}(M/h_s)^T\\mu_{s+1}` back to the state :math:`s - j`).

``"euler"``
    Backward Euler (paper Eq. backward_euler): :math:`h_s = \\Delta t`, :math:`\\psi_s =
    \\Theta_s`. First order, L-stable. The default (the paper's numbers).
``"bdf2"``
    The two-step backward differentiation formula (Hairer & Wanner II, Sec. III.1 and
    V.1),

    .. math::

        \\frac{M}{\\Delta t}\\Bigl(\\tfrac32\\Theta_{s+1} - 2\\Theta_s
            + \\tfrac12\\Theta_{s-1}\\Bigr) + R(\\Theta_{s+1}) = 0,

    i.e. :math:`h_s = \\tfrac23\\Delta t`, :math:`\\psi_s = \\tfrac43\\Theta_s -
    \\tfrac13\\Theta_{s-1}`. Second order, A- and L-stable (stiffly accurate: the data
    constraint of the ECFM holds exactly at every grid time, as for backward Euler). It
    starts with one backward-Euler step, whose local error :math:`O(\\Delta t^2)` keeps the
    global error second order.

On a given, non-uniform grid :math:`t_0 < t_1 < \\dots` (``march(..., times=...)``)
the same two schemes take their variable-step forms (:func:`grid_rules`): backward Euler
with :math:`h_s = t_{s+1} - t_s`, and the variable-step BDF2 (Hairer & Wanner II, Sec.
III.5; :math:`p'(t_{s+1}) = f` for the quadratic :math:`p` through the last three states),
with :math:`\\omega_s = h_s/h_{s-1}`,

.. math::

    \\frac{1 + 2\\omega_s}{1 + \\omega_s}\\Theta_{s+1} - (1 + \\omega_s)\\Theta_s
        + \\frac{\\omega_s^2}{1 + \\omega_s}\\Theta_{s-1}
        = -h_s M^{-1}R(\\Theta_{s+1}),

i.e. an effective length :math:`h_s(1 + \\omega_s)/(1 + 2\\omega_s)` and
:math:`\\psi_s = ((1 + \\omega_s)^2\\Theta_s - \\omega_s^2\\Theta_{s-1})/(1 + 2\\omega_s)`
(:math:`\\omega_s = 1`: the fixed-step BDF2). It is zero-stable for step ratios
:math:`\\omega_s < 1 + \\sqrt 2` (Grigorieff 1983); the grids of :mod:`.step_control`
keep :math:`\\omega_s \\le 2`. The adjoint is the same generic one: only the rules differ.

Crank-Nicolson is not offered: it is A- but not L-stable (stiff modes of the heat and
finite-element models would ring from step to step instead of decaying), and under the
ECFM constraint its forces would act at two times per step.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array

SCHEMES = ("euler", "bdf2")

__all__ = ["SCHEMES", "check_scheme", "check_times", "grid_rules", "scheme_order", "step_rule"]

_ORDER = {"euler": 1, "bdf2": 2}


def check_scheme(scheme):
    """``scheme`` if it names a fixed-step scheme, else ``ValueError`` listing them."""
    if not isinstance(scheme, str) or scheme not in SCHEMES:
        raise ValueError(
            f"`scheme` must be one of {SCHEMES}, got {scheme!r}; for error-controlled "
            "steps use ecfm_uq.system.integrate(..., rtol=...)"
        )
    return scheme


def scheme_order(scheme):
    """The order of accuracy in :math:`\\Delta t` of ``scheme``."""
    return _ORDER[check_scheme(scheme)]


def step_rule(scheme, s, dt):
    """``(h_s, w_s)`` of step ``s`` (from :math:`t_s` to :math:`t_{s+1}`) of ``scheme``.

    ``w_s`` is a tuple: ``w_s[j]`` multiplies :math:`\\Theta_{s-j}`.
    """
    if scheme == "euler" or s == 0:
        return dt, (1.0,)
    return 2.0 * dt / 3.0, (4.0 / 3.0, -1.0 / 3.0)


def check_times(times):
    """``times`` as a strictly increasing float array of at least two points, else a
    ``ValueError`` naming ``times`` and the first offending entry."""
    times = as_finite_array("times", times, ndim=1)
    if times.size < 2:
        raise ValueError(f"`times` must hold at least two times (start and end), got {times.size}")
    bad = np.nonzero(np.diff(times) <= 0)[0]
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"`times` must be strictly increasing, but times[{k + 1}] = {times[k + 1]:g} <= "
            f"times[{k}] = {times[k]:g}; sort it (np.unique) before marching"
        )
    return times


def grid_rules(scheme, times):
    """``[(h_s, w_s)]`` of every step of ``scheme`` on the grid ``times`` (variable steps).

    Step ``s`` goes from ``times[s]`` to ``times[s + 1]``; ``w_s[j]`` multiplies
    :math:`\\Theta_{s-j}` (module notes). The first BDF2 step is backward Euler, as on
    a uniform grid.
    """
    h = np.diff(np.asarray(times, dtype=float))
    rules = []
    for s, hs in enumerate(h):
        if scheme == "euler" or s == 0:
            rules.append((float(hs), (1.0,)))
            continue
        om = hs / h[s - 1]
        rules.append(
            (
                float(hs * (1.0 + om) / (1.0 + 2.0 * om)),
                ((1.0 + om) ** 2 / (1.0 + 2.0 * om), -(om**2) / (1.0 + 2.0 * om)),
            )
        )
    return rules
