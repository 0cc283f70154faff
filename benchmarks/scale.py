"""Benchmark: matrix-free stochastic Galerkin at scale against Gauss collocation.

Problem: :func:`ecfm_uq.problems.fem_diffusion.build_fem_diffusion`, the 2-D diffusion
-div(a grad u) = 1 on the unit square, P1 triangles from scikit-fem, with the affine
random field a = 1 + sum_k sigma_k phi_k(x)(omega_k - 1/2), d = 4, sigma = (0.16, 0.12,
0.08, 0.04), at eps = (0.1, 0.5); chaos order 3 (P = 35). Meshes from ~10^3 to ~10^5
nodes.

In one run:

1. **Accuracy** (smallest mesh). Reference: tensor Gauss collocation with 7^4 = 2401
   nodes. Errors (largest absolute error over the largest reference value) of the
   order-3 Galerkin mean and variance, and of the collocation rules tensor Gauss n^4
   (n = 2..5) and Smolyak sparse Gauss-Legendre (chaospy, levels 1..4, non-nested). The
   cheapest rule at least as accurate as Galerkin in both mean and variance is
   "collocation at equal accuracy". The stochastic error does not depend on the mesh,
   so that rule is used on every mesh.
2. **Scale** (each mesh, each method in a fresh process so peak RSS is its own):
   Galerkin = ``solve_steady(..., solver="auto")`` (CG with the mean-based
   preconditioner, the mean block factorized once by ``splu``); collocation = one
   ``P = 1`` engine solve per node with the *same* sparse solver (``splu``), then the
   weighted moments. Timed: the solve (assembly excluded and printed). Both on one core.
   Printed: wall time, peak RSS, Krylov iterations per solve, and how far the Galerkin
   mean/variance are from the collocation ones.

Last two lines:
``scale: NP = <int> solved in <s> s, peak <GB> GB`` (the largest mesh) and
``galerkin/collocation time ratio: <float>`` (largest mesh; < 1 means Galerkin wins).

Usage: ``python benchmarks/scale.py [--cells 31 100 316] [--quick]``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import multiprocessing as mp  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402

import numpy as np  # noqa: E402

EPS = np.array([0.1, 0.5])
ORDER = 3


def _peak_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB -> GiB


def collocation_rule(kind, level, dim=4):
    """Nodes (n, dim) in [0, 1]^dim and weights of a tensor or Smolyak Gauss rule."""
    if kind == "tensor":
        from ecfm_uq.chaos.quadrature import tensor_gauss_legendre

        return tensor_gauss_legendre(level, dim)
    import chaospy

    joint = chaospy.J(*[chaospy.Uniform(0, 1) for _ in range(dim)])
    x, w = chaospy.generate_quadrature(level, joint, rule="gaussian", sparse=True)
    return np.clip(x.T, 0.0, 1.0), w


def collocation_moments(problem, nodes, weights):
    from ecfm_uq.system import solve_steady

    U = np.empty((len(nodes), problem.system.N))
    for q, omega in enumerate(nodes):
        sol = solve_steady(problem.deterministic_system(omega), EPS, solver="sparse-direct")
        if not sol.success:
            raise RuntimeError(f"collocation solve failed at node {q}: {sol.message}")
        U[q] = sol.Theta[:, 0]
    mean = weights @ U
    return mean, weights @ (U - mean) ** 2


def run_galerkin(n_cells):
    from ecfm_uq.problems.fem_diffusion import build_fem_diffusion
    from ecfm_uq.system import solve_steady

    t0 = time.perf_counter()
    problem = build_fem_diffusion(n_cells, ORDER)
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = solve_steady(problem.system, EPS)
    t_solve = time.perf_counter() - t0
    if not sol.success:
        raise RuntimeError(f"Galerkin solve failed: {sol.message}")
    s = problem.system
    return {
        "N": s.N,
        "NP": s.N * s.P,
        "nodes": problem.n_nodes,
        "build": t_build,
        "time": t_solve,
        "peak": _peak_gb(),
        "solver": sol.solver,
        "iterations": sol.linear_iterations,
        "mean": s.mean(sol.Theta),
        "var": s.variance(sol.Theta),
    }


def run_collocation(n_cells, kind, level):
    from ecfm_uq.problems.fem_diffusion import build_fem_diffusion

    problem = build_fem_diffusion(n_cells, 0)  # chaos not needed for sampling
    nodes, weights = collocation_rule(kind, level)
    t0 = time.perf_counter()
    mean, var = collocation_moments(problem, nodes, weights)
    return {
        "time": time.perf_counter() - t0,
        "peak": _peak_gb(),
        "runs": len(nodes),
        "mean": mean,
        "var": var,
    }


def rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def in_fresh_process(fn, *args):
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        return pool.submit(fn, *args).result()


def accuracy(n_cells):
    from ecfm_uq.problems.fem_diffusion import build_fem_diffusion

    problem = build_fem_diffusion(n_cells, 0)
    ref = collocation_moments(problem, *collocation_rule("tensor", 7))
    gal = run_galerkin(n_cells)
    errors = {"galerkin": (rel(gal["mean"], ref[0]), rel(gal["var"], ref[1]), 1)}
    rules = [("tensor", n) for n in (2, 3, 4, 5)] + [("smolyak", k) for k in (1, 2, 3, 4)]
    for kind, level in rules:
        nodes, w = collocation_rule(kind, level)
        m, v = collocation_moments(problem, nodes, w)
        errors[(kind, level)] = (rel(m, ref[0]), rel(v, ref[1]), len(nodes))
    return errors


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, nargs="+", default=[31, 100, 316])
    ap.add_argument("--quick", action="store_true", help="meshes 15 and 31 cells only")
    args = ap.parse_args(argv)
    cells = [15, 31] if args.quick else sorted(args.cells)

    print(f"accuracy on the {cells[0]}x{cells[0]} mesh (reference: 7^4 tensor Gauss)")
    errors = accuracy(cells[0])
    g_mean, g_var, _ = errors["galerkin"]
    print(f"{'method':>24} {'runs':>6} {'mean err':>10} {'var err':>10}")
    print(f"{'Galerkin order 3 (P=35)':>24} {1:>6} {g_mean:10.2e} {g_var:10.2e}")
    matching = []
    for key, (em, ev, n) in errors.items():
        if key == "galerkin":
            continue
        label = f"{key[0]} level {key[1]}" if key[0] == "smolyak" else f"tensor {key[1]}^4"
        ok = em <= g_mean and ev <= g_var
        print(f"{label:>24} {n:>6} {em:10.2e} {ev:10.2e}{'  <- as accurate' if ok else ''}")
        if ok:
            matching.append((n, key))
    n_runs, (kind, level) = min(matching)
    print(f"collocation at equal accuracy: {kind} level {level} ({n_runs} runs)\n")

    header = (
        f"{'nodes':>8} {'NP':>9} {'Gal s':>7} {'Gal GB':>7} {'its':>8} "
        f"{'coll s':>8} {'coll GB':>8} {'ratio':>6} {'mean diff':>10} {'var diff':>9}"
    )
    print(header)
    rows = []
    for n in cells:
        g = in_fresh_process(run_galerkin, n)
        c = in_fresh_process(run_collocation, n, kind, level)
        ratio = g["time"] / c["time"]
        its = g["iterations"]
        print(
            f"{g['nodes']:>8} {g['NP']:>9} {g['time']:7.2f} {g['peak']:7.2f} "
            f"{str(its):>8} {c['time']:8.2f} {c['peak']:8.2f} {ratio:6.2f} "
            f"{rel(g['mean'], c['mean']):10.1e} {rel(g['var'], c['var']):9.1e}",
            flush=True,
        )
        rows.append((g, c, ratio))
    first, last = rows[0][0]["iterations"][0], rows[-1][0]["iterations"][0]
    print(
        f"\nKrylov iterations of the first Newton solve: {first} -> {last} "
        f"(growth {last - first}); solver {rows[-1][0]['solver']}; assembly "
        f"{rows[-1][0]['build']:.1f} s at the largest mesh (not timed)"
    )
    g, c, ratio = rows[-1]
    print(f"scale: NP = {g['NP']} solved in {g['time']:.2f} s, peak {g['peak']:.2f} GB")
    print(f"galerkin/collocation time ratio: {ratio:.2f}")


if __name__ == "__main__":
    main()
