"""Threads decided by the library (issue 21 item 4): a plain user script is as fast as the CLI.

A 2-D transient stochastic diffusion (scikit-fem P1 mesh, d = 4 germs, order 3, P = 35,
backward Euler) marched with ``solver="auto"``, timed in three fresh processes that differ
only in how BLAS threads are set, none of them through environment variables:

* ``plain``: the user's script imports ecfm_uq and calls ``march`` (the library decides);
* ``cli``: BLAS pinned to one thread for the whole process, as ``ecfm-uq`` does;
* ``threaded``: the library's decision overridden with every core (``set_blas_threads``),
  which is what a plain script got before the library decided.

Last line: ``threads: plain/cli time ratio: <float>`` (1.0 means the library's choice
costs nothing against pinning by hand); the threaded/plain ratio is printed above it.

Run: ``python benchmarks/threads.py [--cells 48] [--steps 20]`` (needs the ``fem`` extra).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys, time
import numpy as np
mode, cells, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
if mode == "cli":
    from threadpoolctl import threadpool_limits
    _pin = threadpool_limits(limits=1, user_api="blas")
import skfem
from skfem.helpers import dot
from ecfm_uq.problems.fem_diffusion import build_fem_diffusion
from ecfm_uq.system import GalerkinSystem, march
from ecfm_uq.threads import set_blas_threads
if mode == "threaded":
    set_blas_threads(os.cpu_count() or 2)
fem = build_fem_diffusion(cells, 3)

@skfem.BilinearForm
def mass(u, v, w):
    return u * v

Mfull = skfem.asm(mass, fem.fem_basis).tocsr()
M = Mfull[fem.interior][:, fem.interior]
sysT = GalerkinSystem(list(fem.system.terms), fem.system.n_eps, basis=fem.chaos, M=M)
Theta0 = np.zeros((sysT.N, sysT.P))
eps = np.zeros(sysT.n_eps)
march(sysT, eps, Theta0, 0.01, 2)  # warm-up: compile, factor caches
t = time.perf_counter()
tr = march(sysT, eps, Theta0, 0.01, steps)
elapsed = time.perf_counter() - t
print(json.dumps({"time": elapsed, "success": bool(tr.success), "N": sysT.N, "P": sysT.P,
                  "solver": str(tr.solver), "checksum": float(np.abs(tr.Theta[-1]).sum())}))
"""


def run(mode, cells, steps):
    env = {k: v for k, v in os.environ.items() if "NUM_THREADS" not in k}
    out = subprocess.run(
        [sys.executable, "-c", "import os\n" + CHILD, mode, str(cells), str(steps)],
        capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    if out.returncode:
        raise RuntimeError(f"{mode} run failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=48)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    best = {}
    for _ in range(args.repeats):
        for mode in ("plain", "cli", "threaded"):
            r = run(mode, args.cells, args.steps)
            if not r["success"]:
                raise RuntimeError(f"{mode}: the march did not converge")
            if mode not in best or r["time"] < best[mode]["time"]:
                best[mode] = r
    r = best["plain"]
    print(f"transient FEM march: N = {r['N']} nodes, P = {r['P']}, {args.steps} steps, "
          f"solver {r['solver']}, best of {args.repeats}")  # fmt: skip
    for mode in ("plain", "cli", "threaded"):
        print(f"  {mode:9s} {best[mode]['time']:8.3f} s  (checksum {best[mode]['checksum']:.12e})")
    print(f"threads: threaded/plain time ratio: {best['threaded']['time'] / r['time']:.2f}")
    print(f"threads: plain/cli time ratio: {r['time'] / best['cli']['time']:.2f}")


if __name__ == "__main__":
    main()
