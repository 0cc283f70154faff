"""More data is never worse: the default ``fit_pce`` on the borehole function, n = 10^3..10^5.

Issue 37 item 6: v0.4's adaptive default (``fit_pce(None, bounds, samples=X,
evaluations=Y)``, degree- and q-norm-adaptive sparse LAR) fitted *worse* expansions from
more data: the affordable candidate sets were sized by a fixed work limit
:math:`nP\\min(n, P) \\le 10^9`, so they shrank as n grew (at most 100 candidates at
n = 10^5). Since v0.5 the limit grows with n beyond 1 000 runs (``docs/pce.md``,
"The default sparse fit").

The model: the borehole function (Harper & Gupta 1983; Morris et al. 1993) with all eight
inputs uniform on their usual ranges,

.. math:: f = \\frac{2\\pi T_u (H_u - H_l)}{\\ln(r/r_w)\\bigl(1 + \\frac{2 L T_u}
          {\\ln(r/r_w) r_w^2 K_w} + T_u / T_l\\bigr)}.

Reference indices (computed here, cached nowhere): first-order and total Sobol indices by
tensor Gauss-Legendre quadrature of the conditional variances,
:math:`S_i = \\operatorname{Var}(E[f|x_i])/V` and
:math:`T_i = E[\\operatorname{Var}(f|x_{\\sim i})]/V`, on 10 x 100 x 5 x 2 x 8 x 2 x 8 x 8
nodes (100 in r, whose logarithm converges slowly; 2 in H_u and H_l, on which f is
linear, exact); one more node in every direction changes no index by more than 1e-14.

For each n in 10^3, 10^4, 10^5 (Latin hypercube, seed 0) the script prints the largest
absolute error of the eight first-order and eight total indices, the corrected LOO
error, the terms kept, and the fit's CPU and wall time (one thread), for the default and,
with ``--old``, beside it for v0.4's affordability rule (the work limit fixed at 10^9,
set through the module constant ``_ADAPTIVE_WORK_RUNS``; the refits are v0.5's).

``--part flood``: OpenTURNS' flood model (Q ~ Gumbel(558, 1013) truncated to Q > 0,
Ks ~ N(30, 7.5) truncated to Ks > 0, Zv ~ U(49, 51), Zm ~ U(54, 56);
S = (Q / (300 Ks sqrt((Zm - Zv) / 5000)))^0.6 + Zv - 58.5) at n = 1 000: the default fit's
time (median of 5), to check the rule leaves small designs as they were.

``--old`` also prints the default's CPU time over the v0.4 rule's (same process, warm);
``--fresh`` times both rules in fresh processes (imports, design and fit, as a user's
script sees them), interleaved; ``--v04 DIR`` also v0.4's own default from a checkout of
it (``git worktree add DIR 360e218``): the v0.4 rule above runs v0.5's faster refits.

Run: ``python benchmarks/pce_more_data.py [--n 1000 10000 100000] [--old] [--fresh]
[--v04 DIR] [--part borehole|flood|all]``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402
from scipy.stats import qmc  # noqa: E402

from ecfm_uq.chaos import fit_pce  # noqa: E402

try:
    from ecfm_uq.chaos.regression import adaptive  # noqa: E402
except ImportError:  # a v0.4 package (``--v04``'s child processes): its default only
    adaptive = None

# the borehole function and its quadrature indices are the tests' (tests/_models.py)
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _models import BOREHOLE_BOUNDS as BOREHOLE  # noqa: E402
from _models import borehole, borehole_indices  # noqa: E402

# Quadrature nodes per input of the reference (see the module docstring).
REFERENCE_NODES = (10, 100, 5, 2, 8, 2, 8, 8)
# Measured on main (v0.4, commit 360e218) with this design, before the change: n, largest
# index error, CPU seconds of the fit in a fresh process (one thread; 2.2-3.1 s over 6 runs).
V04 = ((1000, 2.60e-5, None), (10000, 7.97e-5, None), (100000, 1.04e-3, 2.45))


def design(n, seed=0):
    u = qmc.LatinHypercube(len(BOREHOLE), rng=np.random.default_rng(seed)).random(n)
    return BOREHOLE[:, 0] + (BOREHOLE[:, 1] - BOREHOLE[:, 0]) * u


def fit(X, Y, bounds):
    c0, w0 = time.process_time(), time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        pce = fit_pce(None, bounds, samples=X, evaluations=Y)
    return pce, time.process_time() - c0, time.perf_counter() - w0


def fit_rule(X, Y, runs):
    """The default fit with the work limit's run count ``runs`` (None: the package's)."""
    if runs is None:
        return fit(X, Y, BOREHOLE)
    keep = adaptive._ADAPTIVE_WORK_RUNS
    adaptive._ADAPTIVE_WORK_RUNS = runs
    try:
        return fit(X, Y, BOREHOLE)
    finally:
        adaptive._ADAPTIVE_WORK_RUNS = keep


def fresh_cpu(n, rule, package=None):
    """CPU seconds of a fresh process that imports, designs and fits (rule: default|v0.4).

    ``package``: the directory to import ``ecfm_uq`` from (default: this checkout's).
    """
    root = package or str(Path(__file__).resolve().parents[1])
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(n), rule],
        capture_output=True,
        text=True,
        check=True,
        env={**os.environ, "PYTHONPATH": str(root)},
    )
    return float(out.stdout.split()[-1])


def child(n, rule):
    """In a fresh process: the fit, then the process's CPU time so far (imports included)."""
    X = design(n)
    fit_rule(X, borehole(X), math.inf if rule == "v0.4" else None)
    print(f"{time.process_time():.3f}")


def run_borehole(ns, old, fresh, v04=None):
    S0, T0 = borehole_indices(REFERENCE_NODES)
    print("borehole, 8 uniform inputs, LHS seed 0; reference indices by quadrature")
    print(f"  S = {np.array2string(S0, precision=6)}")
    print(f"  T = {np.array2string(T0, precision=6)}")
    rules = [("default", None)] + ([("v0.4 rule", math.inf)] if old else [])
    print(
        f"{'rule':>10} {'n':>7} {'index error':>12} {'LOO':>9} {'terms':>6} {'cpu s':>7} "
        f"{'wall s':>7}" + (f" {'cpu / v0.4 rule':>15}" if old else "")
    )
    for n in ns:
        X = design(n)
        Y = borehole(X)
        cpus = {}
        for label, runs in rules:
            pce, cpu, wall = fit_rule(X, Y, runs)
            cpus[label] = cpu
            err = max(np.max(np.abs(pce.first_order() - S0)), np.max(np.abs(pce.total() - T0)))
            d = pce.diagnostics
            print(
                f"{label:>10} {n:>7} {err:12.2e} {float(d['corrected_loo_error']):9.1e} "
                f"{int(d['n_terms']):>6} {cpu:7.2f} {wall:7.2f}"
                + (f" {cpus['default'] / cpu:15.2f}" if label != "default" else ""),
                flush=True,
            )
    if fresh:
        # a user's script: a fresh process that imports, designs and fits, each rule
        # interleaved with the others (the ratios of one run, on a machine shared with others)
        print("fresh processes (imports, design, fit), CPU s; ratio = default / the other:")
        head = f"{'n':>7} {'default':>8} {'v0.4 rule':>10} {'ratio':>6}"
        print(head + (f" {'v0.4 default':>13} {'ratio':>6}" if v04 else ""))
        for n in ns:
            new, rule = fresh_cpu(n, "default"), fresh_cpu(n, "v0.4")
            line = f"{n:>7} {new:8.2f} {rule:10.2f} {new / rule:6.2f}"
            if v04:
                old = fresh_cpu(n, "default", v04)
                line += f" {old:13.2f} {new / old:6.2f}"
            print(line, flush=True)
    print("v0.4 (main, 360e218, before the change), same designs:")
    for n, err, cpu in V04:
        print(f"{'v0.4':>10} {n:>7} {err:12.2e}" + (f" {'':>9} {'':>6} {cpu:7.2f}" if cpu else ""))


class _TruncGumbel(stats.rv_continuous):
    """Gumbel (max) law, mode 1013, scale 558, truncated to x > 0 (OpenTURNS' flood Q)."""

    def _cdf0(self, x):
        return np.exp(-np.exp(-(x - 1013.0) / 558.0))

    def _pdf(self, x):
        z = (x - 1013.0) / 558.0
        return np.exp(-z - np.exp(-z)) / 558.0 / (1.0 - self._cdf0(0.0))

    def _cdf(self, x):
        return (self._cdf0(x) - self._cdf0(0.0)) / (1.0 - self._cdf0(0.0))

    def _ppf(self, u):
        c0 = self._cdf0(0.0)
        return 1013.0 - 558.0 * np.log(-np.log(c0 + u * (1.0 - c0)))


def flood_inputs():
    return [
        _TruncGumbel(a=0.0, name="truncgumbel")(),
        stats.truncnorm(-4.0, np.inf, loc=30.0, scale=7.5),
        stats.uniform(49.0, 2.0),
        stats.uniform(54.0, 2.0),
    ]


def flood(X):
    Q, Ks, Zv, Zm = np.asarray(X, dtype=float).T
    return (Q / (300.0 * Ks * np.sqrt((Zm - Zv) / 5000.0))) ** 0.6 + Zv - 58.5


def run_flood(n=1000, repeats=5):
    laws = flood_inputs()
    u = qmc.LatinHypercube(4, rng=np.random.default_rng(0)).random(n)
    X = np.column_stack([law.ppf(u[:, k]) for k, law in enumerate(laws)])
    Y = flood(X)
    cpus, walls = [], []
    for _ in range(repeats):
        pce, cpu, wall = fit(X, Y, laws)
        cpus.append(cpu)
        walls.append(wall)
    d = pce.diagnostics
    print(
        f"flood (OpenTURNS), n = {n}: median of {repeats} fits: cpu {np.median(cpus):.3f} s, "
        f"wall {np.median(walls):.3f} s; LOO {float(d['corrected_loo_error']):.1e}, "
        f"{int(d['n_terms'])} terms; S = {np.array2string(pce.first_order(), precision=4)}"
    )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--old", action="store_true", help="v0.4's rule beside the default")
    parser.add_argument(
        "--fresh", action="store_true", help="both rules also in fresh processes (imports included)"
    )
    parser.add_argument(
        "--v04",
        metavar="DIR",
        help="a v0.4 checkout (git worktree add DIR 360e218): its default in fresh processes too",
    )
    parser.add_argument("--part", choices=("borehole", "flood", "all"), default="all")
    parser.add_argument("--child", nargs=2, metavar=("N", "RULE"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(int(args.child[0]), args.child[1])
        return
    if args.part in ("borehole", "all"):
        run_borehole(args.n, args.old, args.fresh or bool(args.v04), args.v04)
    if args.part in ("flood", "all"):
        run_flood()


if __name__ == "__main__":
    main()
