"""Benchmark: SLSQP with our analytic gradients against SLSQP with its own finite
differences on the Fisher-KPP inverse problems of paper Section 3.2, plus the memory of the
Kronecker-factored model at N = 40 x 40.

Part 1 (memory): build the 40 x 40 model and solve the true problem by Newton, measuring
the peak of Python/numpy allocations (``tracemalloc``) and the process peak RSS
(``resource.getrusage``) before anything else runs. The dense triple-product tensor would
need N^3 * 8 B = 32.8 GB; the Kronecker factors need 2 * 40^3 * 8 B = 1 MB.

Part 2 (gradients): the standard problem (Eq. kpp_inv, variables theta, eps) and the
noise-aware ECFM problem (Eq. ecfm_noise, variables theta, eps, lam) at the paper's size
(N = 100, M = 16, C = 225, seed 0) are solved twice each by ``scipy.optimize.minimize
(method="SLSQP")``: with analytic Jacobians of the objective and every constraint, and
with every ``jac`` omitted (SLSQP then differences objective and constraints itself, one
evaluation per variable and iteration). Same start, ``maxiter``, ``ftol``. We report wall
time, iterations, function evaluations, success and the difference of the estimates.

The last line printed is ``kpp analytic-gradient speedup: <float>x``: the total wall time
of the two finite-difference runs over that of the two analytic runs.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import resource
import sys
import time
import tracemalloc

import numpy as np


def memory_part(n):
    from ecfm_uq.problems.fisher_kpp import build_kpp, solve_true_state

    tracemalloc.start()
    t0 = time.perf_counter()
    problem = build_kpp(n_state=n, n_source=4)
    t_build = time.perf_counter() - t0
    _, peak_build = tracemalloc.get_traced_memory()
    tracemalloc.reset_peak()
    t0 = time.perf_counter()
    theta, steps, nit = solve_true_state(problem)
    t_solve = time.perf_counter() - t0
    _, peak_solve = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux
    N = problem.system.N
    return {
        "N": N,
        "build_s": t_build,
        "solve_s": t_solve,
        "newton_iterations": nit,
        "load_steps": steps,
        "peak_build_mb": peak_build / 2**20,
        "peak_solve_mb": peak_solve / 2**20,
        "rss_mb": rss,
        "dense_A_gb": N**3 * 8 / 1e9,
        "factors_mb": 2 * n**3 * 8 / 2**20,
        "max_u": float(theta.max()),
    }


def gradient_part(n_state, n_source, seed, maxiter, ftol):
    from ecfm_uq.inverse import SteadyProblem, fit
    from ecfm_uq.problems.fisher_kpp import build_kpp, make_data

    problem = build_kpp(n_state=n_state, n_source=n_source)
    data = make_data(problem, 0.05, seed)
    eps0 = np.zeros(problem.system.n_eps)
    rows = {}
    for name, kw in (
        ("standard", {"method": "all-at-once"}),
        ("noisy-ecfm", {"formulation": "noisy-ecfm", "sigma": 0.05}),
    ):
        for grads in ("analytic", "fd"):
            t0 = time.perf_counter()
            res = fit(
                SteadyProblem(problem.system, problem.M_obs, data.v),
                eps0,
                **kw,
                maxiter=maxiter,
                options={"jac": grads, "ftol": ftol},
            )
            rows[name, grads] = (time.perf_counter() - t0, res)
        print(f"  ({name} done)", file=sys.stderr, flush=True)
    return problem, rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-memory", type=int, default=40, help="per-direction N of part 1")
    ap.add_argument("--n-state", type=int, default=10, help="per-direction N of part 2")
    ap.add_argument("--n-source", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--maxiter", type=int, default=500)
    ap.add_argument("--ftol", type=float, default=1e-12)
    a = ap.parse_args(argv)

    print(f"# benchmarks/kpp.py  {datetime.datetime.now():%Y-%m-%d %H:%M}")
    print(
        f"# python {platform.python_version()}, numpy {np.__version__}, "
        f"{os.cpu_count()} cpus, {platform.machine()}"
    )
    m = memory_part(a.n_memory)
    print(f"\n## memory: N = {a.n_memory} x {a.n_memory} = {m['N']}")
    print(
        f"build                  {m['build_s']:8.2f} s   peak traced {m['peak_build_mb']:8.1f} MB"
    )
    print(
        f"Newton true solve      {m['solve_s']:8.2f} s   peak traced {m['peak_solve_mb']:8.1f} MB"
        f"   ({m['newton_iterations']} iterations, {m['load_steps']} load step(s))"
    )
    print(f"process peak RSS       {m['rss_mb']:8.1f} MB")
    print(
        f"dense A would need     {m['dense_A_gb']:8.1f} GB; Kronecker factors "
        f"{m['factors_mb']:.2f} MB"
    )

    problem, rows = gradient_part(a.n_state, a.n_source, a.seed, a.maxiter, a.ftol)
    print(
        f"\n## SLSQP gradients: N = {problem.system.N}, M = {problem.n_eps}, "
        f"C = {problem.M_obs.shape[0]}, seed {a.seed}, maxiter {a.maxiter}, ftol {a.ftol:g}"
    )
    print(
        f"{'problem':<11} {'gradients':<9} {'vars':>5} {'time s':>8} {'nit':>5} {'nfev':>7} "
        f"{'success':>8} {'objective':>11}  message"
    )
    for (name, grads), (t, res) in rows.items():
        print(
            f"{name:<11} {grads:<9} {res.extra['z'].size:>5} {t:8.2f} {res.nit:>5} "
            f"{res.nfev:>7} {str(res.success):>8} {res.loss:11.4e}  {res.message}"
        )
    for name in ("standard", "noisy-ecfm"):
        ea, ef = rows[name, "analytic"][1].eps, rows[name, "fd"][1].eps
        ratio = rows[name, "fd"][0] / rows[name, "analytic"][0]
        print(
            f"{name}: ||eps_fd - eps_analytic|| / ||eps_analytic|| = "
            f"{np.linalg.norm(ef - ea) / np.linalg.norm(ea):.2e}; time ratio fd/analytic "
            f"{ratio:.1f}x"
        )
    t_an = sum(rows[k, "analytic"][0] for k in ("standard", "noisy-ecfm"))
    t_fd = sum(rows[k, "fd"][0] for k in ("standard", "noisy-ecfm"))
    print(f"kpp analytic-gradient speedup: {t_fd / t_an:.2f}x")


if __name__ == "__main__":
    main()
