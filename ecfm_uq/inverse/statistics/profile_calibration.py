"""A likelihood-ratio threshold calibrated by simulation at a profile's ends.

The chi-squared (Wilks) threshold of a profile interval assumes a regular model: the
estimate inside the parameter box and the likelihood close to quadratic in some
parametrization. Along a ridge to a bound, or near a singular operator, it is not: the
likelihood-ratio statistic at a value :math:`t` of :math:`\\epsilon_i` then has another
distribution, and the interval does not cover at its level. The parametric bootstrap
measures that distribution where it matters, at the interval's candidate ends (a
parametric bootstrap test, Davison & Hinkley 1997, Ch. 4, inverted into an interval): at
:math:`t`, with the other parameters re-optimized (:math:`\\hat\\nu(t)`), data are
simulated from :math:`(t, \\hat\\nu(t))` with the fit's noise, each simulated data set is
fitted with and without :math:`\\epsilon_i = t`, and the ``level`` quantile :math:`c(t)` of
the statistics :math:`\\ell^*_p(t) - \\hat\\ell^*` (the :math:`\\lceil
\\mathrm{level}\\,(n+1)\\rceil`-th smallest of the n, :func:`order_statistic`) is the
threshold there. The interval's end is where the profile meets it,
:math:`\\ell_p(t) - \\hat\\ell = c(t)`.

A Gaussian least-squares likelihood is simulated through its whitened residual
:math:`r(\\epsilon)`: data simulated from :math:`\\epsilon_t` have the residual
:math:`r(\\epsilon) - r(\\epsilon_t) + \\hat\\sigma z`, :math:`z \\sim N(0, I)`
(:math:`\\hat\\sigma = 1` with the noise known, else the fit's residual estimate), so a
simulation costs two small Levenberg-Marquardt fits warm-started at :math:`\\epsilon_t` and
no new problem. The same :math:`z` serve every :math:`t` of a profile (common random
numbers): :math:`c(t)` is then a smooth function of :math:`t` and the end is found by a few
fixed-point steps :math:`t_{k+1} = T(c(t_k))`, :math:`T(c)` the profile's crossing of the
constant level :math:`c` (:func:`~.profile_walk.walk`, no simulation), bisecting where the
steps overshoot. Typically 2-4 thresholds are simulated per end.

A likelihood that simulates its own data (``like.simulate``: the random-force ECFM's
marginal likelihood with :math:`\\tau` re-estimated at every :math:`\\epsilon`) is
simulated by its model instead: at :math:`(t, \\hat\\nu(t))` the forces are drawn with
the profiled :math:`\\hat\\tau(t)` where the data there reject :math:`\\tau = 0`, else
with :math:`\\tau = 0` (a nuisance at its bound: ``simulation_variances`` of
:mod:`ecfm_uq.inverse.formulations.random_force_simulation`), the noise with the known
:math:`\\sigma`, and each data set is refitted by L-BFGS-B on the random-force
likelihood's gradient (:func:`simulated_threshold_by_model`; the same seeds at every
:math:`t`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from ...errors import ConvergenceError
from .profile_walk import MODEL_FAILURES, WALL, _levenberg_marquardt, walk

__all__ = [
    "Calibration",
    "bootstrap_quantile",
    "calibrate_ends",
    "calibrated_end",
    "check_calibratable",
    "order_statistic",
    "simulated_threshold",
    "simulated_threshold_by_model",
]

#: fixed-point steps (thresholds simulated) per interval end
MAX_ITERATIONS = 6
#: an end has converged when its threshold changes by less than this fraction
THRESHOLD_RTOL = 0.02
#: the simulated fits' convergence (the Gauss-Newton decrease left, relative to the sum
#: of squares): 1e-9 of it is far below the simulated quantile's own Monte Carlo error
SIM_RTOL = 1e-9


@dataclass(frozen=True)
class Calibration:
    """How a calibrated interval's ends were found.

    Attributes
    ----------
    n_simulations : int
        Simulated data sets per threshold.
    seed : int
    points : tuple of (t, threshold, delta)
        Every simulated threshold (in units of :math:`\\ell_p - \\hat\\ell`, as
        :attr:`Profile.threshold`) with the profile's value at ``t``.
    thresholds : (2,) ndarray
        The threshold at the lower and upper end (NaN at an open end).
    chi2_interval : (2,) ndarray
        The chi-squared (or profile-t) interval it replaces.
    """

    n_simulations: int
    seed: int
    points: tuple
    thresholds: np.ndarray
    chi2_interval: np.ndarray


def check_calibratable(like):
    """Raise ValueError unless ``like`` is a Gaussian least-squares likelihood or one that
    simulates its own data (``like.simulate``: the random-force ECFM's)."""
    if like.simulate is not None:
        return
    if like.residual is None or like.noise not in ("known sigma", "profiled sigma"):
        raise ValueError(
            "threshold='calibrated' simulates data from a Gaussian least-squares likelihood "
            "or the random-force ECFM's marginal one; "
            f"this fit's is {like.description!r} ({like.noise}, "
            f"{'no' if like.residual is None else 'a'} residual): use threshold='chi2'"
        )


def noise_scale(like, ell_hat):
    """The simulated noise in the whitened residual's units: 1 with sigma known (or a
    likelihood that simulates its own data), else
    :math:`\\sqrt{S(\\hat\\epsilon)/(n - p)}`."""
    if like.noise != "profiled sigma":
        return 1.0
    rss = float(np.exp(2.0 * ell_hat / like.n_data))  # ell = n/2 log S
    return float(np.sqrt(rss / (like.n_data - like.n_eps)))


def _fit(like, shift, start, free, scale, bounds):
    """Minimum sum of squares of ``like.residual(eps) + shift`` over ``eps[free]``."""
    s = scale[free]
    lb = np.array([(bounds[j][0] - start[j]) / scale[j] for j in free])
    ub = np.array([(bounds[j][1] - start[j]) / scale[j] for j in free])

    def point(x):
        e = start.copy()
        e[free] = start[free] + s * x
        return e

    def fun(x):
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                r = like.residual(point(x)) + shift
        except MODEL_FAILURES:
            return np.full(shift.size, np.inf)
        return r

    def jac(x):
        return like.residual_jacobian(point(x), free) * s

    x, rss, _ = _levenberg_marquardt(fun, jac, np.zeros(free.size), lb, ub, rtol=SIM_RTOL)
    return rss, point(x)


def simulated_threshold(like, i, eps_t, Z, level, scale, bounds, memory=None):
    """The ``level`` quantile of :math:`\\ell^*_p(t) - \\hat\\ell^*` over data simulated
    from ``eps_t`` (:math:`t` = ``eps_t[i]``), one data set per row of ``Z`` (whitened
    noise, already scaled).

    ``memory`` (a dict, updated) holds each simulated data set's full optimum at the
    previous ``t``: with the same noise the optimum moves little between nearby ``t``, and
    a full fit along a ridge is the costly one, so it also starts there when better.
    """
    memory = {} if memory is None else memory
    n = like.n_eps
    r0 = like.residual(eps_t)
    others = np.setdiff1d(np.arange(n), [i])
    everything = np.arange(n)
    stat = np.empty(len(Z))
    for k, z in enumerate(Z):
        shift = z - r0
        if others.size:
            s_con, e_con = _fit(like, shift, eps_t, others, scale, bounds)
        else:
            r = r0 + shift
            s_con, e_con = float(r @ r), eps_t
        # the full fit starts at the constrained optimum (it can only decrease from
        # there) or at this data set's previous full optimum where that is lower
        start = e_con
        if k in memory:
            try:
                with np.errstate(over="ignore", invalid="ignore"):
                    r = like.residual(memory[k]) + shift
                if float(r @ r) < s_con:
                    start = memory[k]
            except MODEL_FAILURES:
                pass
        s_full, e_full = _fit(like, shift, start, everything, scale, bounds)
        memory[k] = e_full
        s_full = min(s_full, s_con)
        stat[k] = like.of_rss(s_con) - like.of_rss(s_full) if s_full > 0 else np.inf
    return bootstrap_quantile(stat, level)


def order_statistic(n, level):
    """The rank k of the bootstrap quantile: ceil(level (n + 1)).

    A new statistic falls at or below the k-th smallest of n exchangeable ones with
    probability k / (n + 1) >= ``level`` (Davison & Hinkley 1997, Sec. 4.2.2); the linear
    interpolation of ``np.quantile`` gives about ``level`` n / (n + 1), 0.941 at n = 100.
    """
    return int(np.ceil(level * (n + 1) - 1e-9))


def bootstrap_quantile(stat, level):
    """The :func:`order_statistic` of ``stat``."""
    return float(np.sort(stat)[order_statistic(len(stat), level) - 1])


def calibrated_end(prof, i, direction, chi2_end, step, bound, max_steps, simulate):
    """One end of a calibrated interval: (end, reason, thresholds simulated).

    ``simulate(t, eps_t)`` is the simulated threshold at ``t``; ``chi2_end`` the
    chi-squared end on this side (finite: a crossing or the bound).
    """
    t0 = prof.eps_hat[i]
    tried = []  # (t, delta - c, c, delta)
    t = chi2_end
    end = why = None
    for _ in range(MAX_ITERATIONS):
        d, eps_t = prof.at(i, t, _nearest(prof, i, t))
        c = simulate(t, eps_t)
        tried.append((t, d - c, c, d))
        if tried[-1][1] < 0 and t == bound:
            end = bound
            why = (
                f"the profile stays below the calibrated threshold up to the bound "
                f"eps[{i}]={bound:g} (2*delta = {2 * d:.3g} < {2 * c:.3g})"
            )
            break
        # the crossing of the constant level c: a fixed-point step
        pts, t_next, how = walk(prof, i, direction, c, step, bound, max_steps)
        if how != "crossed" and not np.isfinite(t_next):
            end, why = t_next, f"calibrated threshold {2 * c:.3g} (in 2*delta): {how}"
            break
        if len(tried) > 1 and abs(c - tried[-2][2]) <= THRESHOLD_RTOL * c:
            end, why = t_next, "crossed (calibrated)"
            break
        if abs(t_next - t) <= 1e-6 * max(abs(t - t0), 1e-300):
            end, why = t_next, "crossed (calibrated)"
            break
        below = [p[0] for p in tried if p[1] < 0]
        above = [p[0] for p in tried if p[1] >= 0]
        if below and above:
            a = max(below, key=lambda u: direction * (u - t0))
            b = min(above, key=lambda u: direction * (u - t0))
            if not min(a, b) <= t_next <= max(a, b):
                t_next = 0.5 * (a + b)  # the step overshot the bracket: bisect
        t = t_next
    if end is None:
        end, why = (
            t_next,
            (
                f"crossed (calibrated; the threshold still moved by more than {THRESHOLD_RTOL:g} "
                f"of itself after {MAX_ITERATIONS} simulated thresholds)"
            ),
        )
    return end, why, tried


def _nearest(prof, i, t):
    """A warm start for ``eps[i] = t``: the visited optimum nearest in ``eps[i]``."""
    if not prof.visited:
        return prof.eps_hat
    v = np.array([e[i] for e in prof.visited])
    return prof.visited[int(np.argmin(np.abs(v - t)))]


def _minimize(like, start, free, scale, bounds):
    """(value, eps): ``like`` minimized over ``eps[free]`` from ``start`` by L-BFGS-B on
    its gradient (the inner fits of a likelihood without a residual)."""
    s = scale[free]
    box = [((bounds[j][0] - start[j]) / scale[j], (bounds[j][1] - start[j]) / scale[j])
           for j in free]  # fmt: skip

    def point(x):
        e = np.array(start, dtype=float)
        e[free] = start[free] + s * x
        return e

    def fun(x):
        try:
            val, g = like(point(x))
        except MODEL_FAILURES:
            return WALL, np.zeros(free.size)
        if not np.isfinite(val):
            return WALL, np.zeros(free.size)
        return val, g[free] * s

    res = optimize.minimize(fun, np.zeros(free.size), jac=True, method="L-BFGS-B", bounds=box,
                            options={"ftol": 1e-12, "gtol": 1e-6, "maxiter": 500})  # fmt: skip
    return float(res.fun), point(res.x)


def simulated_threshold_by_model(like, i, eps_t, seeds, level, scale, bounds, memory=None):
    """:func:`simulated_threshold` of a likelihood that simulates its own data
    (``like.simulate(eps, rng)``, the random-force ECFM's: noise and forces drawn at
    ``eps_t`` with the nuisance re-estimated there), one data set per seed; each is
    fitted with and without ``eps[i] = eps_t[i]`` by L-BFGS-B (the full fit from the
    constrained optimum or this seed's previous full optimum, the lower)."""
    memory = {} if memory is None else memory
    n = like.n_eps
    others = np.setdiff1d(np.arange(n), [i])
    stat = np.empty(len(seeds))
    for k, sd in enumerate(seeds):
        sim = like.simulate(eps_t, np.random.default_rng(sd))
        if others.size:
            v_con, e_con = _minimize(sim, eps_t, others, scale, bounds)
        else:
            v_con, e_con = sim.value(eps_t), eps_t
        start, v_start = e_con, v_con
        if k in memory:
            try:
                v_mem = sim.value(memory[k])
                if v_mem < v_start:
                    start, v_start = memory[k], v_mem
            except MODEL_FAILURES:
                pass
        v_full, e_full = _minimize(sim, start, np.arange(n), scale, bounds)
        memory[k] = e_full
        stat[k] = v_con - min(v_full, v_start, v_con)
    return bootstrap_quantile(stat, level)


def simulator(like, i, level, scale, bounds, sigma, n_simulations, seed):
    """``simulate(t, eps_t)`` for parameter ``i`` with common random numbers."""
    memory = {}
    if like.simulate is not None:
        # the model draws its own noise and forces: the same seeds at every t
        seeds = [[seed, i, k] for k in range(n_simulations)]

        def threshold(eps_t):
            return simulated_threshold_by_model(like, i, eps_t, seeds, level, scale, bounds,
                                                memory)  # fmt: skip
    else:
        Z = sigma * np.random.default_rng([seed, i]).standard_normal((n_simulations, like.n_data))

        def threshold(eps_t):
            return simulated_threshold(like, i, eps_t, Z, level, scale, bounds, memory)

    def simulate(t, eps_t):
        c = threshold(np.asarray(eps_t, dtype=float))
        if not np.isfinite(c):
            raise ConvergenceError(
                f"the simulated likelihood-ratio statistics at eps[{i}]={t:.6g} are not finite"
            )
        return c

    simulate.n, simulate.seed = n_simulations, seed
    return simulate


def calibrate_ends(prof, i, ends, reasons, pts, step, bound, max_steps, simulate):
    """The ends of a calibrated interval from the chi-squared ones (finite ends only; an
    infinite one stays open). Returns (ends, reasons, (n, seed, points, thresholds))."""
    new_ends, new_reasons, tried, c_end = [], [], [], []
    for direction, end, why, b in zip((-1, 1), ends, reasons, bound, strict=True):
        if not np.isfinite(end):
            new_ends.append(end)
            new_reasons.append(why)
            c_end.append(np.nan)
            continue
        e, w, t = calibrated_end(prof, i, direction, end, step, b, max_steps, simulate)
        new_ends.append(e)
        new_reasons.append(w)
        tried += t
        c_end.append(t[-1][2] if np.isfinite(e) else np.nan)
        if np.isfinite(e) and w.startswith("crossed"):
            pts.append((e, *prof.at(i, e, prof.visited[-1] if prof.visited else prof.eps_hat)))
    points = tuple((t, c, d) for t, _, c, d in tried)
    return new_ends, new_reasons, (simulate.n, simulate.seed, points, np.array(c_end))
