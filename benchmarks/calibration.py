"""A model that is a Python function, calibrated by ecfm_uq and by scipy alone (issue 28).

The model: an exponential decay ``a exp(-b x)`` on 22 points (a black-box function, no
Jacobian given: issue 28's size, two parameters), fitted from the same start

* ``fit``: ``ecfm_uq.inverse.fit(ModelProblem(model, y), eps0)`` (trust-region least
  squares with one-sided differences, then the optimality test, Gauss-Newton standard
  errors and the verdict) against ``scipy.optimize.least_squares(model - y, eps0)`` (the
  same Jacobian mode, its default) followed by the same covariance by hand, and against
  ``scipy.optimize.curve_fit(f, x, y, p0)`` (MINPACK's Levenberg-Marquardt, its
  covariance included: the fastest fit scipy offers);
* ``profile``: ``profile_likelihood(result)`` (95 % profile-t intervals of both
  parameters) against a profile computed with scipy alone: each parameter fixed, the
  others refitted by warm-started ``least_squares``, the threshold crossing by Brent.

Each is timed as the best of ``--repeat`` runs in this one process, ours and scipy's taking
turns (the machine is shared: best-of is the least noisy statistic, and alternating keeps a
change of load from favouring either side); the estimates and intervals are compared too.

Then ``fit`` against ``curve_fit`` and ``least_squares`` on more small unbounded
problems (no Jacobian given, MINPACK's Levenberg-Marquardt on both sides): a Michaelis-Menten
curve, a saturating exponential (NIST Misra1a's model) and a Gaussian peak on a
background, one line per problem with both ratios, the estimates' largest relative
difference to ``curve_fit``'s and the status.

Last lines: ``calibration fit/scipy time ratio: <float>``, ``calibration
profile/scipy-profile time ratio: <float>``, ``calibration fit/curve_fit time ratio:
<float>`` (the decay) and ``calibration largest fit/curve_fit time ratio: <float>`` (over
every problem; all measured in this run).

Run: ``python benchmarks/calibration.py [--repeat 30]``.
"""

from __future__ import annotations

import argparse

import _scipy_peer as peer
import numpy as np
from scipy import optimize

from ecfm_uq.inverse import ModelProblem, fit, profile_likelihood

X = np.linspace(0.0, 5.0, 22)
TRUTH = np.array([2.0, 0.7])
START = np.array([1.0, 1.0])


def model(e):
    return e[0] * np.exp(-e[1] * X)


def scipy_fit(y):
    return peer.scipy_fit(lambda e: model(e) - y, START)


def curve_fit(y):
    return optimize.curve_fit(lambda x, a, b: a * np.exp(-b * x), X, y, p0=START)


def scipy_profile(y, ls, se, level=0.95):
    return peer.scipy_profile(lambda e: model(e) - y, ls, se, level)


def _gauss(x, a, m, w, c):
    return a * np.exp(-0.5 * ((x - m) / w) ** 2) + c


#: name, model f(x, *p), x, truth, start, noise: small unbounded problems
MORE = [
    ("Michaelis-Menten", lambda x, v, k: v * x / (k + x), np.linspace(0.2, 10.0, 15),
     [3.0, 1.5], [1.0, 1.0], 0.05),
    ("saturating exponential", lambda x, a, b: a * (1 - np.exp(-b * x)),
     np.linspace(10.0, 800.0, 14), [240.0, 5e-4], [500.0, 1e-4], 0.5),
    ("Gaussian peak", _gauss, np.linspace(-3.0, 3.0, 40), [2.0, 0.3, 0.8, 0.5],
     [1.5, 0.0, 1.0, 0.3], 0.05),
]  # fmt: skip


def one_more(name, f, x, truth, start, noise, repeat):
    """``fit``/``curve_fit`` and ``fit``/``least_squares`` on one problem, interleaved."""
    y = f(x, *truth) + noise * np.random.default_rng(1).standard_normal(x.size)
    start = np.array(start, dtype=float)
    problem = ModelProblem(lambda e: f(x, *e), y)
    fit(problem, start)
    (t_fit, t_cf, t_ls), (res, (popt, _), _) = peer.best_of(
        [lambda: fit(problem, start), lambda: optimize.curve_fit(f, x, y, p0=start),
         lambda: peer.scipy_fit(lambda e: f(x, *e) - y, start)], repeat,
    )  # fmt: skip
    tight, _ = optimize.curve_fit(f, x, y, p0=start, ftol=1e-15, xtol=1e-15, gtol=1e-15)
    rel, rel_tight = np.max(np.abs(res.eps / popt - 1)), np.max(np.abs(res.eps / tight - 1))
    print(f"  {name} ({x.size} points, {start.size} parameters): fit/curve_fit "
          f"{t_fit / t_cf:.2f}, fit/least_squares {t_fit / t_ls:.2f}; estimates "
          f"{rel:.1e} from curve_fit's ({rel_tight:.1e} from curve_fit's run to round-off, "
          f"ftol = xtol = gtol = 1e-15); {res.status.name}, {res.nfev} evaluations")  # fmt: skip
    return t_fit / t_cf


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=30)
    args = parser.parse_args(argv)
    y = model(TRUTH) + 0.05 * np.random.default_rng(0).standard_normal(X.size)
    problem = ModelProblem(model, y)
    fit(problem, START)  # first call: imports

    (t_fit, t_sp, t_cf), (res, (ls, se), (popt, pcov)) = peer.best_of(
        [lambda: fit(problem, START), lambda: scipy_fit(y), lambda: curve_fit(y)], args.repeat
    )
    print(f"estimates: ecfm_uq {res.eps.round(8)}, scipy {ls.x.round(8)}")
    print(f"  largest relative difference {np.max(np.abs(res.eps / ls.x - 1)):.1e}; "
          f"standard errors {np.max(np.abs(res.uncertainty.stderr / se - 1)):.1e}")  # fmt: skip
    print(f"  curve_fit: estimates {np.max(np.abs(res.eps / popt - 1)):.1e}, standard errors "
          f"{np.max(np.abs(res.uncertainty.stderr / np.sqrt(np.diag(pcov)) - 1)):.1e}")  # fmt: skip
    print(f"fit: ecfm_uq {1e3 * t_fit:.2f} ms, scipy least_squares {1e3 * t_sp:.2f} ms, "
          f"curve_fit {1e3 * t_cf:.2f} ms")  # fmt: skip

    rep = max(3, args.repeat // 5)
    (t_prof, t_sprof), (summary, ref) = peer.best_of(
        [lambda: profile_likelihood(res), lambda: scipy_profile(y, ls, se)], rep
    )
    width = ref[:, 1] - ref[:, 0]
    diff = np.max(np.abs(summary.intervals - ref), axis=1) / width
    print(f"profile intervals: ecfm_uq {summary.intervals.round(6).tolist()}")
    print(f"  scipy-only profile-t {ref.round(6).tolist()}; largest difference "
          f"{diff.max():.1e} of the width")  # fmt: skip
    print(f"profile: ecfm_uq {t_prof:.3f} s, scipy-only {t_sprof:.3f} s")
    print("more problems (fit, curve_fit and least_squares in turns):")
    ratios = [t_fit / t_cf, *(one_more(*m, args.repeat) for m in MORE)]
    print(f"calibration fit/scipy time ratio: {t_fit / t_sp:.2f}")
    print(f"calibration profile/scipy-profile time ratio: {t_prof / t_sprof:.2f}")
    print(f"calibration fit/curve_fit time ratio: {t_fit / t_cf:.2f}")
    print(f"calibration largest fit/curve_fit time ratio: {max(ratios):.2f}")


if __name__ == "__main__":
    main()
