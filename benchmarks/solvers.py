"""Benchmark: the solver and preconditioner choices of ``solver="auto"``, side by side.

The claims behind the ``"auto"`` rules of :mod:`ecfm_uq.system.solve.plan`, each measured in
this one run (BLAS on one thread, best of ``--repeats``):

1. **Sparse LU of the chaos-coupled block matrix vs mean-preconditioned CG** on the
   scikit-fem diffusion model (``ecfm_uq.problems.fem_diffusion``, d = 4, order 3,
   P = 35) at ``--small-cells`` (14: N = 225 nodes): why ``"auto"`` never takes
   ``"sparse-direct"`` for P > 1.
2. **splu vs one AMG V-cycle for the mean block** on the same model at ``--cells``
   (100: N = 10 201 nodes): iterations and time of ``preconditioner="mean"`` and
   ``"mean-amg"``; why ``"auto"`` keeps splu up to N = 4e5.
3. **Mean vs decoupled vs nodal preconditioner** for the Newton-Krylov march of
   Burgers with a random viscosity (paper discretization, order 4, P = 5): GMRES
   iterations per Newton step and march time of the generic (Python) Newton-Krylov
   march, beside the dense LU march and ``"auto"`` (for this march: the nodal
   preconditioner in the compiled kernel, chord iterations first); and each
   preconditioner's distance from the step Jacobian, ``||I - B^-1 J||_2``.

Last lines: ``sparse-direct/cg time ratio: <x>``, ``mean-amg/mean time ratio: <x>``,
``gmres iterations per Newton step, mean/decoupled/nodal: <a>/<b>/<c>``,
``dense/auto march time ratio: <x>``.

Usage: ``python benchmarks/solvers.py [--small-cells 14] [--cells 100] [--repeats 3]``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ecfm_uq.chaos import ChaosBasis  # noqa: E402
from ecfm_uq.problems.burgers import BurgersModel  # noqa: E402
from ecfm_uq.problems.fem_diffusion import build_fem_diffusion  # noqa: E402
from ecfm_uq.system import SolverOptions, march, solve_steady  # noqa: E402
from ecfm_uq.system.solve.preconditioners import make_preconditioner  # noqa: E402

EPS = np.array([0.1, 0.5])


def best(fn, repeats):
    """Best wall time of ``repeats`` calls and the last result."""
    t, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        t = min(t, time.perf_counter() - t0)
    return t, out


def steady_row(system, options, repeats):
    t, sol = best(lambda: solve_steady(system, EPS, solver=options), repeats)
    if not sol.success:
        raise RuntimeError(f"{options}: {sol.message}")
    its = sol.linear_iterations
    return t, sol, (max(its) if its else 0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small-cells", type=int, default=14)
    ap.add_argument("--cells", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    # 1. sparse LU of the block matrix vs CG + mean block
    small = build_fem_diffusion(args.small_cells, 3).system
    t_lu, lu, _ = steady_row(small, "sparse-direct", args.repeats)
    t_cg, cg, it_cg = steady_row(small, SolverOptions("cg", preconditioner="mean"), args.repeats)
    agree = np.abs(lu.Theta - cg.Theta).max() / np.abs(lu.Theta).max()
    print(f"1. FEM diffusion N = {small.N}, P = {small.P} (NP = {small.N * small.P}):")
    print(f"   sparse-direct {t_lu:8.3f} s | cg+mean {t_cg:8.3f} s ({it_cg} iterations)")
    print(f"   solutions agree to {agree:.1e}")

    # 2. splu vs AMG for the mean block
    big = build_fem_diffusion(args.cells, 3).system
    t_m, _, it_m = steady_row(big, SolverOptions("cg", preconditioner="mean"), args.repeats)
    t_a, _, it_a = steady_row(big, SolverOptions("cg", preconditioner="mean-amg"), args.repeats)
    print(f"2. FEM diffusion N = {big.N}, P = {big.P}:")
    print(f"   cg+mean {t_m:8.3f} s ({it_m} iterations) | cg+mean-amg {t_a:8.3f} s ({it_a})")

    # 3. Newton-Krylov march with a random viscosity: mean vs decoupled preconditioner
    m = BurgersModel(viscosity_chaos=ChaosBasis(4), viscosity_spread=0.5)
    args3 = (m.system, np.array([1.75, 1.0]), m.Theta0, m.dt, m.n_steps)
    rows = {}
    # keep_factors=True keeps the generic Newton-Krylov march (the compiled one keeps none)
    for label, opts, generic in (
        ("dense LU", "dense", False),
        ("gmres+mean", SolverOptions("gmres", preconditioner="mean"), True),
        ("gmres+decoupled", SolverOptions("gmres", preconditioner="decoupled"), True),
        ("gmres+nodal", SolverOptions("gmres", preconditioner="nodal"), True),
        ("auto", "auto", False),
    ):
        t, tr = best(
            lambda opts=opts, generic=generic: march(
                *args3, tol=1e-10, solver=opts, keep_factors=generic
            ),
            args.repeats,
        )
        if not tr.success:
            raise RuntimeError(f"{label}: {tr.message}")
        its = np.mean(tr.linear_iterations) if tr.linear_iterations else 0.0
        rows[label] = (t, its, tr)
        print(f"3. Burgers, random viscosity, P = {m.system.P}: {label:<16} {t:7.3f} s, "
              f"{its:5.2f} Krylov iterations per step, {tr.nit.sum()} iterations ({tr.solver})")  # fmt: skip
    ref = rows["dense LU"][2].Theta
    for label in ("gmres+mean", "gmres+decoupled", "gmres+nodal", "auto"):
        diff = np.abs(rows[label][2].Theta - ref).max() / np.abs(ref).max()
        print(f"   {label} vs dense LU: {diff:.1e}")
    # how far each preconditioner B is from the step Jacobian J: ||I - B^-1 J||_2
    gaps = {}
    for t in (1, m.n_steps // 3, 2 * m.n_steps // 3, m.n_steps):
        op = m.system.jacobian_operator(ref[t], args3[1], dt=m.dt)
        J = op.to_dense()
        N, P = m.system.shape
        for kind in ("mean", "decoupled", "nodal"):
            B = make_preconditioner(op, kind)
            BJ = np.column_stack([B.apply(J[:, j].reshape(N, P)).ravel() for j in range(N * P)])
            gap = np.linalg.norm(np.eye(N * P) - BJ, 2)
            gaps[kind] = max(gaps.get(kind, 0.0), gap)
    print(
        "   ||I - B^-1 J||_2, largest over 4 states of the march: "
        + ", ".join(f"{k} {v:.3f}" for k, v in gaps.items())
    )

    print(f"sparse-direct/cg time ratio: {t_lu / t_cg:.1f}")
    print(f"mean-amg/mean time ratio: {t_a / t_m:.2f} (iterations {it_a} vs {it_m})")
    print(
        "gmres iterations per Newton step, mean/decoupled/nodal: "
        f"{rows['gmres+mean'][1]:.1f}/{rows['gmres+decoupled'][1]:.1f}"
        f"/{rows['gmres+nodal'][1]:.1f}"
    )
    print(f"dense/auto march time ratio: {rows['dense LU'][0] / rows['auto'][0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
