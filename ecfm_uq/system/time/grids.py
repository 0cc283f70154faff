"""The grid vocabulary of the time family, and grids chosen to a tolerance.

A march runs on a grid that is *fixed* (``dt``, ``n_steps``: ``t0 + k dt``), *given*
(``times``, any strictly increasing grid, :func:`check_times`) or *chosen to a tolerance*
(:func:`choose_steps` below: a given grid that meets ``rtol``/``atol``, then frozen);
``integrate`` chooses its steps as it goes (:mod:`.bdf`).

A calibration needs gradients that are the exact derivatives of the objective it
minimizes, so it marches a *frozen* step sequence (``march(..., times=...)``, whose
discrete adjoint is exact, :mod:`.base`), and that sequence should meet an accuracy
asked for. This module estimates the local error of every step of a march that ran and
chooses a grid that meets ``rtol``/``atol`` and holds every data time as a step point.

Local error estimates (a posteriori, from the states the march computed): with the
divided differences :math:`\\Theta[t_i, \\dots, t_{i+k}]` of the trajectory,

* backward Euler, step :math:`t_s \\to t_{s+1}` of length :math:`h_s`:
  :math:`\\delta_s = h_s^2\\,\\Theta[t_{s-1}, t_s, t_{s+1}]` (:math:`-\\tfrac12 h^2\\ddot\\Theta`;
  the first step uses :math:`t_0, t_1, t_2`);
* variable-step BDF2 (:math:`\\omega_s = h_s/h_{s-1}`), the interpolation error of its
  quadratic differentiated at :math:`t_{s+1}` over the leading coefficient,

  .. math::

      \\delta_s = \\Theta[t_{s-2}, \\dots, t_{s+1}]\\;
          \\frac{h_s^2\\,(h_s + h_{s-1})\\,(1 + \\omega_s)}{1 + 2\\omega_s}

  (:math:`\\tfrac29 h^3\\dddot\\Theta` on uniform steps, Hairer & Wanner II, Sec. III.2;
  the second step uses :math:`t_0..t_3`); its backward-Euler first step is estimated as
  backward Euler.

A step meets the tolerance when the norm of :func:`scipy.integrate.solve_ivp` and of
:func:`.integration.integrate`,

.. math::

    \\|\\delta_s\\| = \\Bigl(\\frac{1}{NP}\\sum_{i,\\ell}\\Bigl(\\frac{\\delta_{s,i\\ell}}
        {\\mathrm{atol} + \\mathrm{rtol}\\,|\\Theta_{s+1,i\\ell}|}\\Bigr)^2\\Bigr)^{1/2},

is at most 1 (over all chaos coefficients; ``atol`` defaults to ``rtol * max|Theta0|``,
``rtol`` when ``Theta0 = 0``, as for ``integrate``).

Choosing the grid (:func:`choose_steps`): start from the data times, march, estimate,
split every step that misses the tolerance into :math:`\\lceil\\|\\delta_s\\|^{1/(q+1)}/0.9
\\rceil` equal steps (:math:`q` the step's order, at most 8 pieces per round), split
the steps after it until no step is more than twice its predecessor (the variable-step
BDF2 is zero-stable for ratios below :math:`1 + \\sqrt 2`), and march again, until every
step meets the tolerance. Steps are only split, never merged: data times closer than the
tolerance needs are kept as step points (the data must land on them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import as_finite_array, check_int, check_positive
from ...errors import ConvergenceError
from .base import check_times, time_grid
from .marching import march
from .methods import check_method

__all__ = [
    "StepSequence",
    "check_steps",
    "check_times",
    "check_tolerances",
    "choose_steps",
    "default_atol",
    "step_errors",
    "time_grid",
]

#: largest ratio of consecutive steps in a chosen grid (BDF2: zero-stable below 1 + sqrt 2)
MAX_RATIO = 2.0
#: safety factor of the split counts, and the most pieces one step is split into per round
SAFETY, MAX_SPLIT = 0.9, 8
#: the fewest steps of a grid (BDF2's estimate needs four states)
MIN_STEPS = 3
#: failed marches in a row whose gains in time shrink geometrically (each at most
#: STALL_RATIO of the one before: the march creeps towards a time it cannot pass however
#: the steps are split) mean that the solution left the region, e.g. a blow-up
MAX_STALLED, STALL_RATIO = 5, 0.8


@dataclass(frozen=True)
class StepSequence:
    """A time grid chosen for (or checked against) a tolerance.

    Attributes
    ----------
    times : (n_steps + 1,) ndarray
        The step points; ``times[data_index]`` are the data times.
    data_index : (n_data,) ndarray of int
    errors : (n_steps,) ndarray
        The norm of every step's local error estimate (:func:`step_errors`); a step meets
        the tolerance when it is at most 1.
    rtol, atol : float
    scheme : str
    met : bool
        ``errors.max() <= 1``.
    rounds : int
        Marches run to choose it (1 for a check).
    message : str
    """

    times: np.ndarray
    data_index: np.ndarray
    errors: np.ndarray
    rtol: float
    atol: float
    scheme: str
    met: bool
    rounds: int
    message: str

    @property
    def n_steps(self):
        """Number of steps."""
        return self.times.size - 1

    @property
    def max_error(self):
        """The largest step error norm (``<= 1``: the tolerance is met)."""
        return float(self.errors.max())


def default_atol(rtol, Theta0):
    """``rtol * max|Theta0|`` (``rtol`` when ``Theta0 = 0``): the rule of ``integrate``."""
    big = float(np.abs(Theta0).max())
    return rtol * (big if big > 0 else 1.0)


def check_tolerances(rtol, atol):
    """``(rtol, atol)`` checked: ``rtol > 0`` and above round-off, ``atol`` ``None`` or
    ``>= 0``; a ``ValueError`` names the argument."""
    rtol = check_positive("rtol", rtol)
    if rtol < 100 * np.finfo(float).eps:
        raise ValueError(f"`rtol`={rtol:g} is below what double precision can meet; use >= 1e-14")
    if atol is not None:
        atol = float(as_finite_array("atol", atol, ndim=0))
        if atol < 0:
            raise ValueError(f"`atol` must be >= 0 (or None for rtol * max|Theta0|), got {atol}")
    return rtol, atol


def _divided(Theta, times, k):
    """The k-th divided differences of the states, (n_t - k, N, P)."""
    D = Theta
    for j in range(1, k + 1):
        D = (D[1:] - D[:-1]) / (times[j:] - times[:-j])[:, None, None]
    return D


def step_errors(trajectory, rtol, atol):
    """The norm of the local error estimate of every step of a march (module notes).

    Parameters
    ----------
    trajectory : Trajectory
        A successful march (``scheme`` ``"euler"`` or ``"bdf2"``) of at least
        ``MIN_STEPS`` steps; the grid ``trajectory.times`` may be non-uniform.
    rtol, atol : float

    Returns
    -------
    (n_steps,) ndarray
        At most 1 where the step meets the tolerance.
    """
    t, Th = np.asarray(trajectory.times, dtype=float), trajectory.Theta
    n = t.size - 1
    if n < MIN_STEPS:
        raise ValueError(f"a local error estimate needs at least {MIN_STEPS} steps, got {n}")
    scheme = check_method(trajectory.scheme)
    h = np.diff(t)
    D2 = _divided(Th, t, 2)
    delta = np.empty_like(Th[1:])
    if scheme == "euler":
        win = np.maximum(np.arange(n) - 1, 0)
        delta[:] = (h**2)[:, None, None] * D2[win]
    else:
        delta[0] = h[0] ** 2 * D2[0]
        D3 = _divided(Th, t, 3)
        s = np.arange(1, n)
        om = h[1:] / h[:-1]
        c = h[1:] ** 2 * (h[1:] + h[:-1]) * (1 + om) / (1 + 2 * om)
        delta[1:] = c[:, None, None] * D3[np.maximum(s - 2, 0)]
    w = atol + rtol * np.abs(Th[1:])
    return np.sqrt(np.mean((delta / w) ** 2, axis=(1, 2)))


def _refine(times, errors, scheme):
    """Split every step that misses the tolerance, then the steps after a jump, so that no
    step exceeds ``MAX_RATIO`` times its predecessor; every old point stays a step point."""
    order = np.full(errors.size, 1 if scheme == "euler" else 2)
    order[0] = 1
    pieces = np.ones(errors.size, dtype=int)
    miss = errors > 1.0
    pieces[miss] = np.minimum(
        MAX_SPLIT, np.ceil(errors[miss] ** (1.0 / (order[miss] + 1)) / SAFETY)
    ).astype(int)
    pieces[miss] = np.maximum(pieces[miss], 2)
    new = [times[0]]
    for s, k in enumerate(pieces):
        new.extend(np.linspace(times[s], times[s + 1], k + 1)[1:])
    new = np.asarray(new)
    # grade the grid: a step longer than MAX_RATIO times the one before is split evenly
    out, prev = [new[0]], None
    for a, b in zip(new[:-1], new[1:], strict=True):
        h = b - a
        k = 1 if prev is None else max(1, int(np.ceil(h / (MAX_RATIO * prev) - 1e-12)))
        out.extend(np.linspace(a, b, k + 1)[1:])
        prev = h / k
    # linspace ends exactly at its stop: every old point, data times included, stays
    return np.asarray(out)


def _stalled(reached):
    """Whether the times reached by consecutive failed marches converge to a limit short of
    the end: ``MAX_STALLED`` gains, none negative, each at most ``STALL_RATIO`` times the
    one before (none: the first step fails however it is split)."""
    if len(reached) <= MAX_STALLED:
        return False
    d = np.diff(reached[-(MAX_STALLED + 1) :])
    return bool(np.all(d >= 0) and np.all(d[1:] <= STALL_RATIO * d[:-1]))


def choose_steps(
    system,
    eps,
    Theta0,
    t_data=None,
    *,
    rtol=1e-6,
    atol=None,
    scheme=None,
    start=None,
    max_rounds=20,
    max_steps=100_000,
    tol=1e-10,
    maxiter=30,
    solver="auto",
    times=None,
    method=None,
):
    """A time grid through the data times on which ``method`` meets ``rtol``/``atol``.

    The grid is chosen at ``eps`` by marching, estimating every step's local error
    (:func:`step_errors`) and splitting the steps that miss (module notes); it is meant
    to be *frozen* afterwards (``march(..., times=seq.times)``), so that the gradients of
    a calibration are the exact derivatives of its discrete objective.

    Parameters
    ----------
    system : GalerkinSystem
        With a mass matrix.
    eps : (n_eps,) array_like
    Theta0 : (N, P) or (N,) array_like
        State at ``t_data[0]``.
    t_data : (n_data,) array_like
        Strictly increasing times that must be step points (``t_data[0]``: the start).
    rtol : float
        Relative tolerance of every step's local error, ``> 0``.
    atol : float, optional
        Absolute tolerance; default ``rtol * max|Theta0|`` (``rtol`` when ``Theta0 = 0``).
    scheme : {"bdf2", "euler"}, optional
        The older name of ``method`` (same values, same behaviour).
    start : (n,) array_like, optional
        The grid to refine (e.g. one frozen at other parameters); it must hold every
        data time. Default: the data times.
    max_rounds : int
        Marches allowed before giving up.
    max_steps : int
        Largest grid allowed.
    tol, maxiter, solver
        The march's Newton and linear-solver settings (:func:`.marching.march`).
    times : None
        Not an argument of this function (``march``'s grid): given, it is refused with
        a TypeError that points to ``t_data`` (the data times) and ``start`` (a grid).
    method : {"bdf2", "euler"}, optional
        The method the grid is for (variable-step forms, :mod:`.bdf2`, :mod:`.euler`);
        default ``"bdf2"``.

    Returns
    -------
    StepSequence
        ``met`` is ``False`` (with a message) when ``max_rounds`` or ``max_steps`` ran out
        before every step met the tolerance: the last grid is returned.

    Raises
    ------
    ValueError
        ``rtol <= 0``, ``atol < 0``, ``t_data`` not increasing, an unknown ``method``.
    ConvergenceError
        A march failed even on steps split ``max_rounds`` times (when a step's Newton
        solve fails, the steps before it are halved, it is split in four, and the march
        runs again), or consecutive failed marches creep towards a time they cannot pass
        (``MAX_STALLED`` gains shrinking geometrically: the solution left the region where
        the model can be marched, a blow-up), or splitting would exceed ``max_steps``; the
        message names the time the march reached.
    """
    if times is not None:
        raise TypeError(
            "choose_steps takes the data times as `t_data` (the times that must be step "
            "points), not `times` (march's grid); pass t_data=..., and a grid to refine as "
            "start=..."
        )
    if t_data is None:
        raise TypeError("choose_steps needs `t_data`, the data times the grid must hold")
    rtol, atol = check_tolerances(rtol, atol)
    scheme = check_method(method, scheme, default="bdf2")
    t_data = check_times(t_data)
    max_rounds = check_int("max_rounds", max_rounds, minimum=1)
    max_steps = check_int("max_steps", max_steps, minimum=MIN_STEPS)
    eps = system.check_eps(eps)
    N, P = system.shape
    Theta0 = system.check_initial_state(Theta0)
    atol = default_atol(rtol, Theta0) if atol is None else atol
    times = t_data.copy()
    if start is not None:
        times = check_times(start)
        missing = ~np.isin(t_data, times)
        if missing.any():
            raise ValueError(
                f"`start` must hold every data time; t_data[{int(np.argmax(missing))}] = "
                f"{t_data[np.argmax(missing)]:g} is not in it"
            )
    while times.size - 1 < MIN_STEPS:  # too few points for an estimate: halve every step
        times = np.sort(np.concatenate([times, 0.5 * (times[1:] + times[:-1])]))
    message = ""
    reached = []  # the times consecutive failed marches reached
    for rounds in range(1, max_rounds + 1):
        traj = march(system, eps, Theta0, times=times, scheme=scheme, tol=tol, maxiter=maxiter,
                     solver=solver)  # fmt: skip
        if not traj.success:
            # Newton failed, likely after steps too long for the model took it off the
            # solution: halve every step before, split the failed one in four
            if rounds == max_rounds:
                raise ConvergenceError(f"{traj.message} (after {rounds} marches)")
            k = traj.failed_step
            reached.append(float(times[k - 1]))
            if _stalled(reached):
                raise ConvergenceError(
                    f"the solution left the region where the model can be marched near "
                    f"t={reached[-1]:.6g}: {len(reached)} marches in a row failed there, each "
                    f"gaining less time than the one before, with steps split down to "
                    f"{times[k] - times[k - 1]:.3g} (a blow-up, or a state where the model "
                    f"is undefined); the data run to t={t_data[-1]:g}. Last: {traj.message}"
                )
            errors = np.zeros(times.size - 1)
            errors[:k] = (2 * SAFETY) ** 2
            errors[k - 1] = (4 * SAFETY) ** 2
            refined = _refine(times, errors, "euler")
            if refined.size - 1 > max_steps:
                raise ConvergenceError(
                    f"{traj.message}: splitting the steps to get past t={reached[-1]:.6g} would "
                    f"exceed max_steps={max_steps} (after {rounds} marches); the solution may "
                    "leave the region where the model can be marched there"
                )
            times = refined
            continue
        reached = []
        errors = step_errors(traj, rtol, atol)
        if errors.max() <= 1.0:
            message = f"every step meets rtol={rtol:g}, atol={atol:g} ({times.size - 1} steps)"
            break
        worst = int(np.argmax(errors))
        refined = _refine(times, errors, scheme)
        if refined.size - 1 > max_steps:
            message = (
                f"the grid would exceed max_steps={max_steps} (worst step at t={times[worst]:g},"
                f" error norm {errors[worst]:.3g}); raise max_steps or loosen rtol"
            )
            break
        if rounds == max_rounds:
            message = (
                f"max_rounds={max_rounds} marches did not meet rtol={rtol:g} (worst step at "
                f"t={times[worst]:g}, error norm {errors[worst]:.3g}); raise max_rounds"
            )
            break
        times = refined
    index = np.searchsorted(times, t_data)
    met = bool(errors.max() <= 1.0)
    return StepSequence(times, index, errors, rtol, atol, scheme, met, rounds, message)


def check_steps(trajectory, data_index, rtol, atol):
    """The :class:`StepSequence` of a march on a frozen grid: its step errors at the
    parameters it ran at, and whether they meet the tolerance (one march, no refinement)."""
    errors = step_errors(trajectory, rtol, atol)
    met = bool(errors.max() <= 1.0)
    worst = int(np.argmax(errors))
    msg = f"every step meets rtol={rtol:g}, atol={atol:g}"
    if not met:
        msg = f"step error norm up to {errors[worst]:.3g} > 1 (step from t={trajectory.times[worst]:g})"
    return StepSequence(
        np.asarray(trajectory.times), np.asarray(data_index), errors, rtol, atol,
        trajectory.scheme, met, 1, msg,
    )  # fmt: skip
