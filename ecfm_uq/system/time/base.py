"""The stepper interface of the time family and the grid vocabulary every method shares.

Every implicit method of the family advances :math:`M\\dot\\Theta + R(\\Theta; \\epsilon,
\\lambda, t) = 0` by one backward-Euler-like solve per step,

.. math::

    \\frac{M}{h_s}\\bigl(\\Theta_{s+1} - \\psi_s\\bigr)
        + R(\\Theta_{s+1}; \\epsilon, \\lambda_{s+1}, t_{s+1}) = 0,

from a combination :math:`\\psi_s = \\sum_j w_{s,j}\\Theta_{s-j}` of earlier states (the
*step rule* ``(h_s, w_s)``). Its Jacobian is :math:`M/h_s + \\partial R/\\partial\\Theta`
for every method, so the solve plan's linear solvers, preconditioners and warm starts
serve them all; :math:`\\partial\\psi_s/\\partial\\Theta_{s-j} = w_{s,j} I` is what the
forward sensitivities and the discrete adjoint carry from step to step.

A :class:`Stepper` is one method: its step rule on a fixed grid (``dt``, ``n_steps``) or
on a given one (``times``), and, for the error-controlled methods (``adaptive = True``),
the local error estimate and the choice of the next step size. The grid vocabulary:

* fixed: ``dt`` and ``n_steps`` (and ``t0``), the grid ``t0 + k dt``;
* given: ``times``, any strictly increasing grid (:func:`check_times`);
* chosen to a tolerance: ``choose_steps(..., rtol=)`` (:mod:`.grids`) returns a given
  grid that meets the tolerance, to be frozen for a calibration; ``integrate`` chooses
  its steps as it goes (:mod:`.bdf`).
"""

from __future__ import annotations

import numpy as np

from ..._validation import as_finite_array, check_int, check_positive

__all__ = ["Stepper", "check_times", "time_grid"]


class Stepper:
    """One time-integration method of the family (subclasses: one file per method).

    Attributes
    ----------
    name : str
        The ``method=`` name.
    order : int
        Order of accuracy (the highest order for a variable-order method).
    adaptive : bool
        ``True`` for a method that chooses its own steps to a tolerance (``integrate``),
        ``False`` for one that marches a fixed or given grid (``march``).
    """

    name = ""
    order = 1
    adaptive = False

    def __repr__(self):
        return f"{type(self).__name__}()"

    # -- fixed-grid methods --------------------------------------------------------------
    def rule(self, s, dt):
        """``(h_s, w_s)`` of step ``s`` on the uniform grid of step ``dt``.

        ``w_s`` is a tuple, ``w_s[j]`` multiplying :math:`\\Theta_{s-j}` in
        :math:`\\psi_s`.
        """
        raise NotImplementedError(f"{self.name!r} chooses its own steps (integrate)")

    def grid_rule(self, s, steps):
        """``(h_s, w_s)`` of step ``s`` on a given grid with step lengths ``steps``
        (``np.diff(times)``)."""
        raise NotImplementedError(f"{self.name!r} chooses its own steps (integrate)")

    def rules(self, dt=None, n_steps=None, times=None):
        """``[(h_s, w_s)]`` of every step: of the fixed grid (``dt``, ``n_steps``) or of
        the given grid ``times``."""
        if times is None:
            return [self.rule(s, dt) for s in range(n_steps)]
        steps = np.diff(np.asarray(times, dtype=float))
        return [self.grid_rule(s, steps) for s in range(steps.size)]

    @staticmethod
    def combine(w, states, s):
        """:math:`\\psi_s = \\sum_j w_j\\,X_{s-j}` for the step-indexed ``states`` (states
        or their sensitivities): ``states[s]`` itself when the rule has one weight."""
        if len(w) == 1:
            return states[s]
        return sum(wj * states[s - j] for j, wj in enumerate(w))

    @staticmethod
    def psi_derivative(w):
        """:math:`\\partial\\psi_s/\\partial\\Theta_{s-j} = w_j I`, as ``{j: w_j}`` (what the
        sensitivities carry forward and the adjoint carries back)."""
        return dict(enumerate(w))

    # -- error-controlled methods ----------------------------------------------------------
    def error_norm(self, order, d, scale):
        """The norm of the local error estimate of an accepted Newton solve (adaptive
        methods; at most 1 to accept the step)."""
        raise NotImplementedError(f"{self.name!r} marches a fixed or given grid (march)")

    def step_factor(self, order, error_norm, safety):
        """The factor of the step size after a rejected step (adaptive methods)."""
        raise NotImplementedError(f"{self.name!r} marches a fixed or given grid (march)")


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


def time_grid(times, dt, n_steps, t0):
    """``(times, dt, n_steps, t0)`` of a march: ``times`` ``None`` for a fixed grid, ``dt``
    ``None`` for a given one; a ``ValueError`` names what is missing or contradictory."""
    if times is None:
        if dt is None or n_steps is None:
            raise ValueError("pass `dt` and `n_steps` (fixed steps) or `times` (a time grid)")
        dt = check_positive("dt", dt)
        n_steps = check_int("n_steps", n_steps, minimum=1)
        t0 = 0.0 if t0 is None else float(as_finite_array("t0", t0, ndim=0))
        return None, dt, n_steps, t0
    if dt is not None or n_steps is not None or t0 is not None:
        raise ValueError(
            "pass either `times` (the grid; it starts at the time of Theta0) or `dt`, "
            "`n_steps` and `t0`, not both"
        )
    times = check_times(times)
    return times, None, times.size - 1, float(times[0])
