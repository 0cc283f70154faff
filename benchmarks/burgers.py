"""Benchmark: cost of a Burgers gradient against a forward solve (SPEC "Performance").

One run times, at the paper's settings (N = 50, 100 backward-Euler steps, Newton
tolerance 1e-6):

* one forward solve (standard) and one constrained forward solve (ECFM),
* one gradient of each objective (forward + forward sensitivities, Eqs. discrete_sens and
  discrete_sens_ecfm, reusing the factorized step Jacobian),
* a central finite-difference gradient (2 x n_eps forward solves),
* the whole 250-epoch Adam study for both methods without loss surfaces.

The last line is ``burgers gradient/forward: <ratio>``, the larger of the two methods'
gradient-to-forward time ratios (aim <= 1.5).

BLAS threads: the step systems are 50 x 50 (54 x 54 for ECFM). With a multi-threaded
OpenBLAS, ``lu_solve`` with exactly two right-hand sides (the two sensitivity columns)
was measured at about 40 times the single-threaded cost on a loaded 2-core machine, so
this script pins BLAS to one thread unless ``OPENBLAS_NUM_THREADS`` is already set (run
``OPENBLAS_NUM_THREADS=2 python benchmarks/burgers.py`` to see the threaded numbers).

Usage: ``python benchmarks/burgers.py [--repeat R] [--skip-study]``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ecfm_uq.inverse.dynamic import DynamicInverseProblem  # noqa: E402
from ecfm_uq.problems.burgers import PAPER_TRUE_EPS, BurgersModel  # noqa: E402


def interleaved_best(fns, repeat):
    """Minimum wall time of each callable over ``repeat`` rounds, calling them in turn.

    Interleaving keeps slow drifts of the machine's load (other users) from favouring one
    row; the minimum is the run least disturbed by them.
    """
    best = {name: np.inf for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t0)
    return best


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--repeat", type=int, default=20, help="timing rounds (the best of each row is kept)"
    )
    p.add_argument("--skip-study", action="store_true", help="skip the 250-epoch study row")
    args = p.parse_args(argv)
    if args.repeat < 1:
        p.error("--repeat must be >= 1")

    model = BurgersModel(newton_tol=1e-6)
    V = model.true_data(PAPER_TRUE_EPS)
    prob = DynamicInverseProblem(
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V, tol=1e-6
    )
    eps = np.array([1.6, 0.8])  # away from the optimum, as during the optimization
    prob.standard_objective(eps)  # warm-up (imports, caches)
    prob.ecfm_objective(eps)
    h = 1e-6
    E = np.eye(2) * h

    def fd_gradient(formulation):
        return [
            (prob.loss(eps + e, formulation) - prob.loss(eps - e, formulation)) / (2 * h) for e in E
        ]

    rows = interleaved_best(
        {
            "standard forward": lambda: prob.loss(eps, "standard"),
            "standard gradient (sensitivities)": lambda: prob.standard_objective(eps),
            "standard gradient (central FD, 4 solves)": lambda: fd_gradient("standard"),
            "ECFM forward": lambda: prob.loss(eps, "ecfm"),
            "ECFM gradient (sensitivities)": lambda: prob.ecfm_objective(eps),
            "ECFM gradient (central FD, 4 solves)": lambda: fd_gradient("ecfm"),
        },
        args.repeat,
    )
    if not args.skip_study:
        t0 = time.perf_counter()
        for formulation in ("standard", "ecfm"):
            res = prob.fit((1.5, 0.5), formulation, lr=1e-2, epochs=250)
            rows[f"  250 epochs, {formulation}: eps = {np.round(res.eps, 4)}"] = None
        rows["study: 250 Adam epochs x 2 methods (no surfaces)"] = time.perf_counter() - t0

    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"{'what':<58} {'seconds':>10}")
    for name, t in rows.items():
        print(f"{name:<58} {'' if t is None else f'{t:10.4f}':>10}")
    r_std = rows["standard gradient (sensitivities)"] / rows["standard forward"]
    r_ecfm = rows["ECFM gradient (sensitivities)"] / rows["ECFM forward"]
    fd_std = rows["standard gradient (central FD, 4 solves)"] / rows["standard forward"]
    print(f"standard: gradient/forward {r_std:.3f}, central-FD gradient/forward {fd_std:.3f}")
    print(f"ECFM:     gradient/forward {r_ecfm:.3f}")
    print(f"burgers gradient/forward: {max(r_std, r_ecfm):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
