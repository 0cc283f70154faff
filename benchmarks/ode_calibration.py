"""A user's ODE calibrated by ecfm_uq and by scipy alone (issue 36, goal 1).

The model: Lotka-Volterra, du/dt = a u - b u v, dv/dt = c u v - d v, fitted to the Hudson
Bay lynx-hare pelts (21 annual counts 1900-1920, ``ecfm_uq/data/lynx_hare.csv``, raw) with
six unknowns (a, b, c, d and the initial hare and lynx), rtol = 1e-10, from the same start:

* ``fit``: ``fit(OdeProblem(rhs, y0(eps), t, data, t0=1900, jac=(jac_y, jac_eps)), eps0)``
  (trust-region least squares on the readings, the Jacobian from forward sensitivities of
  one augmented DOP853 solve, then the optimality test, Gauss-Newton standard errors and
  the verdict) against ``scipy.optimize.least_squares`` on ``solve_ivp(DOP853, rtol=1e-10)``
  with its default two-point Jacobian (seven solves per Jacobian), and the same covariance
  by hand. The fit without ``jac`` is timed too, in the same rounds: its default
  sensitivities, complex steps of ``rhs`` (one call with a column per parameter; ``rhs``
  takes columns and is analytic), and one-sided differences
  (``sensitivities="differences"``).
* ``profile``: ``profile_likelihood(result)`` (95 % profile-t intervals of all six), of
  the fit with ``jac`` and of the one without, against a profile with scipy alone: each
  parameter fixed, the others refitted by warm-started ``least_squares``, the threshold
  crossing by Brent.

Best of ``--repeat`` runs in one process, ours and scipy's taking turns (see
``benchmarks/calibration.py``). Both integrate with the same ``atol`` (1e-8: the counts are
in thousands, 4 to 80).

Last lines: ``ode fit/scipy time ratio: <float>``, ``ode no-jac fit/scipy time ratio:
<float>`` (and the estimates' largest relative difference to scipy's), ``ode
profile/scipy-profile time ratio: <float>`` and ``ode no-jac profile/scipy-profile time
ratio: <float>``.

Run: ``python benchmarks/ode_calibration.py [--repeat 3] [--no-profile]``; ``--options``
prints only the table of docs/ode.md (the sensitivity routes without ``jac``, among them
scipy's own: differences of the whole solution).
"""

from __future__ import annotations

import argparse

import _scipy_peer as peer
import numpy as np
from scipy import optimize
from scipy.integrate import solve_ivp

from ecfm_uq.datasets import lynx_hare
from ecfm_uq.inverse import ModelProblem, OdeProblem, fit, profile_likelihood
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
    return peer.scipy_fit(scipy_residual(t, data), START)


def scipy_profile(t, data, ls, se, level=0.95):
    return peer.scipy_profile(scipy_residual(t, data), ls, se, level)


def options_table(t, data, repeat=2):
    """``--options``: the ways to get the sensitivities without ``jac`` (docs/ode.md),
    each fit timed in turns with scipy's, best of ``repeat``."""
    kw = {"t0": t[0], "rtol": RTOL, "atol": ATOL}
    problems = {
        "with jac (reference)": OdeProblem(rhs, y0, t, data, jac=(jac_y, jac_eps), **kw),
        "(b) complex steps, columns": OdeProblem(rhs, y0, t, data, **kw),
        "(b) complex steps, per parameter": OdeProblem(rhs, y0, t, data, vectorized=False,
                                                       **kw),
        "(a) differences, columns": OdeProblem(rhs, y0, t, data,
                                               sensitivities="differences", **kw),
        "(a) differences, per parameter": OdeProblem(rhs, y0, t, data, vectorized=False,
                                                     sensitivities="differences", **kw),
    }  # fmt: skip

    def solution(e):
        s = solve_ivp(lambda x, y: rhs(x, y, e), (t[0], t[-1]), e[4:6], method="DOP853",
                      t_eval=t, rtol=RTOL, atol=ATOL)  # fmt: skip
        return s.y.T

    # (c): MINPACK differences the whole solution, as scipy's least_squares does
    problems["(c) differences of the whole solution"] = ModelProblem(solution, data)
    fns = [lambda p=p: fit(p, START) for p in problems.values()]
    times, values = peer.best_of([*fns, lambda: scipy_fit(t, data)], repeat)
    ref = values[0].eps
    for name, tt, res in zip(problems, times, values, strict=False):
        print(f"  {name}: fit/scipy {tt / times[-1]:.2f}, {res.nfev} evaluations, "
              f"{res.status.name}, estimates {np.max(np.abs(res.eps / ref - 1)):.1e} from "
              "the fit with jac")  # fmt: skip


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-profile", action="store_true")
    parser.add_argument("--options", action="store_true",
                        help="only the table of sensitivity routes without jac")  # fmt: skip
    args = parser.parse_args(argv)
    t, data = lynx_hare()
    if args.options:
        options_table(t, data)
        return
    problem = OdeProblem(rhs, y0, t, data, t0=t[0], rtol=RTOL, atol=ATOL,
                         jac=(jac_y, jac_eps), names=NAMES, state_names=["hare", "lynx"])  # fmt: skip
    no_jac = OdeProblem(rhs, y0, t, data, t0=t[0], rtol=RTOL, atol=ATOL, names=NAMES)
    differenced = OdeProblem(rhs, y0, t, data, t0=t[0], rtol=RTOL, atol=ATOL,
                             names=NAMES, sensitivities="differences")  # fmt: skip
    fit(problem, START)  # first call: imports

    (t_fit, t_sp, t_nj, t_fd), (res, (ls, se), res_nj, res_fd) = peer.best_of(
        [lambda: fit(problem, START), lambda: scipy_fit(t, data),
         lambda: fit(no_jac, START), lambda: fit(differenced, START)], args.repeat,
    )  # fmt: skip
    print(res.summary())
    print(f"estimates: ecfm_uq {res.eps.round(8)}, scipy {ls.x.round(8)}")
    diff = np.max(np.abs(res.eps / ls.x - 1))
    diff_nj = np.max(np.abs(res_nj.eps / ls.x - 1))
    print(f"  largest relative difference {diff:.1e}; standard errors "
          f"{np.max(np.abs(res.uncertainty.stderr / se - 1)):.1e}; without jac "
          f"({no_jac.sensitivity_method}) vs with {np.max(np.abs(res_nj.eps / res.eps - 1)):.1e},"
          f" differenced vs with {np.max(np.abs(res_fd.eps / res.eps - 1)):.1e}")  # fmt: skip
    r = scipy_residual(t, data)  # both estimates through one integrator
    tight = optimize.least_squares(r, ls.x, ftol=1e-15, xtol=1e-15, gtol=1e-15).x
    print(f"  scipy's least_squares continued to round-off (ftol = xtol = gtol = 1e-15): "
          f"with jac {np.max(np.abs(res.eps / tight - 1)):.1e}, without "
          f"{np.max(np.abs(res_nj.eps / tight - 1)):.1e} from its estimate")  # fmt: skip
    print(f"  half sum of squares (scipy's solve_ivp at each estimate): ecfm_uq "
          f"{0.5 * np.sum(r(res.eps) ** 2):.12g}, scipy {0.5 * np.sum(r(ls.x) ** 2):.12g}")  # fmt: skip
    print(f"fit: ecfm_uq {t_fit:.3f} s ({res.nfev} evaluations; without jac {t_nj:.3f} s, "
          f"{res_nj.nfev}; differenced sensitivities {t_fd:.3f} s, {res_fd.nfev}), scipy "
          f"least_squares {t_sp:.3f} s ({ls.nfev} residuals, status {ls.status})")  # fmt: skip
    print(f"ode fit/scipy time ratio: {t_fit / t_sp:.2f}")
    print(f"ode fit/scipy max relative estimate difference: {diff:.2e}")
    print(f"ode differenced-fit/scipy time ratio: {t_fd / t_sp:.2f}")
    print(f"ode no-jac fit/scipy time ratio: {t_nj / t_sp:.2f}")
    print(f"ode no-jac fit/scipy max relative estimate difference: {diff_nj:.2e}")
    if args.no_profile:
        return
    (t_prof, t_prof_nj, t_sprof), (summary, summary_nj, ref) = peer.best_of(
        [lambda: profile_likelihood(res), lambda: profile_likelihood(res_nj),
         lambda: scipy_profile(t, data, ls, se)], 1,
    )  # fmt: skip
    width = ref[:, 1] - ref[:, 0]
    pdiff = np.max(np.abs(summary.intervals - ref), axis=1) / width
    pdiff_nj = np.max(np.abs(summary_nj.intervals - ref), axis=1) / width
    print(f"profile intervals: ecfm_uq {summary.intervals.round(6).tolist()}")
    print(f"  scipy-only profile-t {ref.round(6).tolist()}; largest difference "
          f"{pdiff.max():.1e} of the width ({pdiff_nj.max():.1e} without jac)")  # fmt: skip
    print(f"profile: ecfm_uq {t_prof:.3f} s (without jac {t_prof_nj:.3f} s), scipy-only "
          f"{t_sprof:.3f} s")  # fmt: skip
    print(f"ode profile/scipy-profile time ratio: {t_prof / t_sprof:.2f}")
    print(f"ode no-jac profile/scipy-profile time ratio: {t_prof_nj / t_sprof:.2f}")


if __name__ == "__main__":
    main()
