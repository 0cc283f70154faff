"""What a scipy user writes without ecfm_uq, shared by the calibration benchmarks: a fit by
``least_squares`` with its Gauss-Newton standard errors, profile-t intervals by refitting
at fixed values, and the alternating best-of timer. Not a benchmark itself."""

from __future__ import annotations

import time

import numpy as np
from scipy import optimize, stats


def scipy_fit(residual, start):
    """``least_squares(residual, start)`` and its standard errors, sigma from the residual."""
    ls = optimize.least_squares(residual, start)
    n, p = ls.fun.size, np.size(start)
    cov = 2 * ls.cost / (n - p) * np.linalg.inv(ls.jac.T @ ls.jac)
    return ls, np.sqrt(np.diag(cov))


def scipy_profile(residual, ls, se, level=0.95):
    """Profile-t intervals with scipy alone (Bates & Watts 1988, Sec. 6.1): each parameter
    fixed, the others refitted by warm-started ``least_squares``, the crossing by Brent."""
    n, p = ls.fun.size, ls.x.size
    limit = 2 * ls.cost * (1 + stats.f.ppf(level, 1, n - p) / (n - p))
    out = np.empty((p, 2))
    for j in range(p):
        free = [k for k in range(p) if k != j]
        warm = {"x": ls.x[free]}

        def rss(val, j=j, free=free, warm=warm):
            def r(z):
                e = np.empty(p)
                e[j], e[free] = val, z
                return residual(e)

            o = optimize.least_squares(r, warm["x"])
            warm["x"] = o.x
            return 2 * o.cost - limit

        for k, d in enumerate((-1.0, 1.0)):
            warm["x"] = ls.x[free]
            b = ls.x[j] + d * 2 * se[j]
            while rss(b) < 0:
                b = ls.x[j] + 2 * (b - ls.x[j])
            out[j, k] = optimize.brentq(rss, *sorted([ls.x[j], b]), xtol=1e-10)
    return out


def best_of(fns, repeat):
    """Best time of each function over ``repeat`` rounds, the functions taking turns
    within each round (a change of the machine's load hits every side alike); returns
    the best times and the last values."""
    times = [[] for _ in fns]
    values = [None] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            values[k] = fn()
            times[k].append(time.perf_counter() - t0)
    return [min(t) for t in times], values
