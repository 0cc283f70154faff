"""A user's ODE calibrated by ecfm_uq and by scipy alone (issue 36, goal 1).

The model: Lotka-Volterra, du/dt = a u - b u v, dv/dt = c u v - d v, fitted to the Hudson
Bay lynx-hare pelts (21 annual counts 1900-1920, ``ecfm_uq/data/lynx_hare.csv``, raw) with
six unknowns (a, b, c, d and the initial hare and lynx), rtol = 1e-10, from the same start:

* ``fit``: ``fit(OdeProblem(rhs, y0(eps), t, data, t0=1900, jac=(jac_y, jac_eps)), eps0)``
  (trust-region least squares on the readings, the Jacobian from forward sensitivities of
  one augmented DOP853 solve, then the optimality test, Gauss-Newton standard errors and
  the verdict) against ``scipy.optimize.least_squares`` on ``solve_ivp(DOP853, rtol=1e-10)``
  with its default two-point Jacobian (seven solves per Jacobian), and the same covariance
  by hand. The differenced-sensitivity variant (no ``jac``; ``rhs`` takes columns) is timed
  too.
* ``profile``: ``profile_likelihood(result)`` (95 % profile-t intervals of all six)
  against a profile with scipy alone: each parameter fixed, the others refitted by
  warm-started ``least_squares``, the threshold crossing by Brent.

Best of ``--repeat`` runs in one process, ours and scipy's taking turns (see
``benchmarks/calibration.py``). Both integrate with the same ``atol`` (1e-8: the counts are
in thousands, 4 to 80).

Last lines: ``ode fit/scipy time ratio: <float>`` and ``ode profile/scipy-profile time
ratio: <float>``.

Run: ``python benchmarks/ode_calibration.py [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import optimize, stats
from scipy.integrate import solve_ivp

from ecfm_uq.datasets import lynx_hare
from ecfm_uq.inverse import OdeProblem, fit, profile_likelihood
from ecfm_uq.problems.lotka_volterra import initial_state as y0
from ecfm_uq.problems.lotka_volterra import jac_eps, jac_y, rhs

RTOL, ATOL = 1e-10, 1e-8
START = np.array([0.55, 0.028, 0.024, 0.8, 30.0, 4.0])
NAMES = ["a", "b", "c", "d", "hare0", "lynx0"]


def scipy_residual(t, data):
    def r(e):
        s = solve_ivp(lambda x, y: rhs(x, y, e), (t[0], t[-1]), e[4:6], method="DOP853",
                      t_eval=t, rtol=RTOL, atol=ATOL)  # fmt: skip
        return (s.y.T - data).ravel()

    return r


def scipy_fit(t, data):
    ls = optimize.least_squares(scipy_residual(t, data), START)
    n, p = data.size, START.size
    cov = 2 * ls.cost / (n - p) * np.linalg.inv(ls.jac.T @ ls.jac)
    return ls, np.sqrt(np.diag(cov))


def scipy_profile(t, data, ls, se, level=0.95):
    """Profile-t intervals with scipy alone (Bates & Watts 1988, Sec. 6.1)."""
    n, p = data.size, START.size
    limit = 2 * ls.cost * (1 + stats.f.ppf(level, 1, n - p) / (n - p))
    res = scipy_residual(t, data)
    out = np.empty((p, 2))
    for j in range(p):
        free = [k for k in range(p) if k != j]
        warm = {"x": ls.x[free]}

        def rss(val, j=j, free=free, warm=warm):
            def r(z):
                e = np.empty(p)
                e[j], e[free] = val, z
                return res(e)

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
    """Best time of each function over ``repeat`` rounds, taking turns; the last values."""
    times = [[] for _ in fns]
    values = [None] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            values[k] = fn()
            times[k].append(time.perf_counter() - t0)
    return [min(t) for t in times], values


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-profile", action="store_true")
    args = parser.parse_args(argv)
    t, data = lynx_hare()
    problem = OdeProblem(rhs, y0, t, data, t0=t[0], rtol=RTOL, atol=ATOL,
                         jac=(jac_y, jac_eps), names=NAMES, state_names=["hare", "lynx"])  # fmt: skip
    differenced = OdeProblem(rhs, y0, t, data, t0=t[0], rtol=RTOL, atol=ATOL,
                             names=NAMES)  # fmt: skip
    fit(problem, START)  # first call: imports

    (t_fit, t_sp, t_fd), (res, (ls, se), res_fd) = best_of(
        [lambda: fit(problem, START), lambda: scipy_fit(t, data),
         lambda: fit(differenced, START)], args.repeat,
    )  # fmt: skip
    print(res.summary())
    print(f"estimates: ecfm_uq {res.eps.round(8)}, scipy {ls.x.round(8)}")
    diff = np.max(np.abs(res.eps / ls.x - 1))
    print(f"  largest relative difference {diff:.1e}; standard errors "
          f"{np.max(np.abs(res.uncertainty.stderr / se - 1)):.1e}; differenced "
          f"sensitivities vs exact {np.max(np.abs(res_fd.eps / res.eps - 1)):.1e}")  # fmt: skip
    r = scipy_residual(t, data)  # both estimates through one integrator
    print(f"  half sum of squares (scipy's solve_ivp at each estimate): ecfm_uq "
          f"{0.5 * np.sum(r(res.eps) ** 2):.12g}, scipy {0.5 * np.sum(r(ls.x) ** 2):.12g}")  # fmt: skip
    print(f"fit: ecfm_uq {t_fit:.3f} s (differenced sensitivities {t_fd:.3f} s), scipy "
          f"least_squares {t_sp:.3f} s ({ls.nfev} residuals, status {ls.status})")  # fmt: skip
    print(f"ode fit/scipy time ratio: {t_fit / t_sp:.2f}")
    print(f"ode fit/scipy max relative estimate difference: {diff:.2e}")
    print(f"ode differenced-fit/scipy time ratio: {t_fd / t_sp:.2f}")
    if args.no_profile:
        return
    (t_prof, t_sprof), (summary, ref) = best_of(
        [lambda: profile_likelihood(res), lambda: scipy_profile(t, data, ls, se)], 1
    )
    width = ref[:, 1] - ref[:, 0]
    pdiff = np.max(np.abs(summary.intervals - ref), axis=1) / width
    print(f"profile intervals: ecfm_uq {summary.intervals.round(6).tolist()}")
    print(f"  scipy-only profile-t {ref.round(6).tolist()}; largest difference "
          f"{pdiff.max():.1e} of the width")  # fmt: skip
    print(f"profile: ecfm_uq {t_prof:.3f} s, scipy-only {t_sprof:.3f} s")
    print(f"ode profile/scipy-profile time ratio: {t_prof / t_sprof:.2f}")


if __name__ == "__main__":
    main()
