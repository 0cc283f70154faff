"""The time-series outputs of an ODE fit: :class:`ForceSeries` (the ECFM force as a
function of time) and :class:`OdeTrajectory` (the fitted, forced solution).

Both are frozen: a fitter builds them once
(:mod:`ecfm_uq.inverse.problems.ode`, :mod:`ecfm_uq.inverse.formulations.ode_forces`).
Their attributes are an interface other tools read (e.g. a search for the missing terms
of a model from its forces): ``forces.times``/``intervals``/``values``/``stderr``/
``names`` and ``state(times)``/``state.names``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ForceSeries", "OdeTrajectory"]


@dataclass(frozen=True, eq=False)
class ForceSeries:
    """A piecewise-constant force :math:`f(t)` on some state components, labelled.

    Attributes
    ----------
    times : (n_knots,) ndarray
        Left end of each interval (where each constant value starts).
    intervals : (n_knots, 2) ndarray
        ``[start, end)`` of each interval; consecutive data times.
    values : (n_knots, n_forced) ndarray
        The force on each forced component in each interval (state units per time unit).
        ``0`` where the component was unconstrained (its datum at the interval's end was
        missing).
    stderr : (n_knots, n_forced) ndarray or None
        Standard errors of ``values`` from the data noise (first order), when ``sigma``
        was given.
    names : list of str
        The forced components' state names.
    jump : (n_forced,) ndarray or None
        The initial jump of the state at ``t0`` that meets a datum at ``t0`` (state units),
        when there is one.
    jump_stderr : (n_forced,) ndarray or None
    """

    times: np.ndarray
    intervals: np.ndarray
    values: np.ndarray
    stderr: np.ndarray | None = None
    names: list = field(default_factory=list)
    jump: np.ndarray | None = None
    jump_stderr: np.ndarray | None = None

    @property
    def zscores(self):
        """``values / stderr`` (``None`` without standard errors; 0 where the standard
        error is 0, i.e. an unconstrained component)."""
        if self.stderr is None:
            return None
        se = np.where(self.stderr > 0, self.stderr, np.inf)
        return self.values / se

    def integral_of_square(self):
        """:math:`\\int |f(t)|^2\\,dt = \\sum_k \\Delta t_k |f_k|^2` (per component)."""
        dt = np.diff(self.intervals, axis=1)
        return np.sum(dt * self.values**2, axis=0)

    def plot(self, ax=None):
        """Step plot of each forced component with a band of +-2 standard errors.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Drawn on a new figure's axes when omitted.

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt  # heavy and optional: only when a plot is asked

        if ax is None:
            _, ax = plt.subplots(figsize=(7, 3.5))
        edges = np.append(self.intervals[:, 0], self.intervals[-1, 1])
        for j, name in enumerate(self.names):
            vals = np.append(self.values[:, j], self.values[-1, j])
            (line,) = ax.step(edges, vals, where="post", label=f"force on {name}")
            if self.stderr is not None:
                se = np.append(self.stderr[:, j], self.stderr[-1, j])
                ax.fill_between(edges, vals - 2 * se, vals + 2 * se, step="post",
                                color=line.get_color(), alpha=0.2, linewidth=0)  # fmt: skip
        ax.axhline(0.0, color="k", linewidth=0.6)
        ax.set_xlabel("t")
        ax.set_ylabel("force f(t)")
        ax.legend(loc="best", fontsize="small")
        return ax


@dataclass(frozen=True, eq=False)
class OdeTrajectory:
    """The fitted (forced) solution of an ODE: its steps and its dense output.

    Attributes
    ----------
    t : (n_t,) ndarray
        The integrator's time points.
    y : (n_t, n_state) ndarray
        The state there.
    names : list of str
        The state components' names.

    Calling the trajectory, ``state(times)``, returns the dense output at ``times``,
    ``(len(times), n_state)``, inside ``[t[0], t[-1]]``.
    """

    t: np.ndarray
    y: np.ndarray
    names: list = field(default_factory=list)
    segments: tuple = field(default=(), repr=False)

    def __call__(self, times):
        times = np.atleast_1d(np.asarray(times, dtype=float))
        if times.ndim != 1 or not np.all(np.isfinite(times)):
            raise ValueError("`times` must be a 1-D array of finite times")
        lo, hi = self.t[0], self.t[-1]
        span = max(abs(hi - lo), 1.0)
        if np.any(times < lo - 1e-12 * span) or np.any(times > hi + 1e-12 * span):
            raise ValueError(
                f"`times` must lie in the fitted span [{lo:g}, {hi:g}]; the trajectory "
                "is not extrapolated"
            )
        starts = np.array([s[0] for s in self.segments])
        which = np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(starts) - 1)
        out = np.empty((times.size, self.y.shape[1]))
        for k in np.unique(which):
            sel = which == k
            out[sel] = np.asarray(self.segments[k][1](times[sel])).T
        return out
