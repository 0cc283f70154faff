"""Benchmark: a user's cubic reaction (NonlinearTerm) on scikit-fem, Galerkin vs collocation.

The model of ``docs/nonlinear.md``: -div(a(w0) grad u) + eps0 c(w1) u^3 = 100 on the unit
square, u = 0 on the boundary, a = 1 + w0/2, c = 1 + w1 (w ~ U(0, 1)^2), P1 triangles with
lumped mass, eps0 = 50. The reaction enters as ``NonlinearTerm(residual, jacobian)`` with
the user's deterministic callbacks (a sparse diagonal Jacobian). For each mesh and chaos
order the Galerkin system is solved by ``solve_steady`` (solver="auto": Newton-GMRES) and
compared with tensor Gauss collocation (``--coll`` nodes per germ, Newton with scipy's
``splu`` on the deterministic model at each node, independent of the engine); the table
gives the Newton steps, GMRES iterations, times and the relative max-norm errors of
mean and variance, and the same for collocation with ``p + 1`` nodes per germ (the
rule that interpolates the same polynomial degree per germ: the cheap competitor).

The last line printed is ``nonlinear_fem: galerkin/collocation time ratio: <float>``:
Galerkin's time over that of the ``(p + 1)``-node collocation, at the largest mesh and
order.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

from ecfm_uq.chaos import ChaosBasis, weighted_gram  # noqa: E402
from ecfm_uq.system import (  # noqa: E402
    GalerkinSystem,
    LinearTerm,
    LoadTerm,
    NonlinearTerm,
    solve_steady,
)

EPS0 = 50.0


def model(refine):
    import skfem
    from skfem.helpers import dot, grad

    mesh = skfem.MeshTri().refined(refine)
    fem = skfem.Basis(mesh, skfem.ElementTriP1())
    interior = fem.complement_dofs(fem.get_dofs())
    K = skfem.asm(skfem.BilinearForm(lambda u, v, w: dot(grad(u), grad(v))), fem)
    M = skfem.asm(skfem.BilinearForm(lambda u, v, w: u * v), fem)
    K = K[interior][:, interior].tocsr()
    m = np.asarray(M.sum(axis=1)).ravel()[interior]
    return K, m, 100.0 * m


def a(w):
    return 1.0 + 0.5 * w[..., 0]


def c(w):
    return 1.0 + w[..., 1]


def galerkin(K, m, F, order):
    def residual(u, w, eps):
        return eps[0] * c(w) * m * u**3

    def jacobian(u, w, eps):
        return sp.diags(3.0 * eps[0] * c(w) * m * u**2)

    chaos = ChaosBasis(order, dim=2)
    terms = [
        LinearTerm(K, G=weighted_gram(chaos, a)),
        NonlinearTerm(residual, jacobian, degree=4),
        LoadTerm.constant(F),
    ]
    system = GalerkinSystem(terms, n_eps=1, basis=chaos)
    t0 = time.perf_counter()
    sol = solve_steady(system, [EPS0])
    t = time.perf_counter() - t0
    return system, sol, t


def collocation(K, m, F, n):
    nodes, weights = ChaosBasis(1, dim=2).quadrature(n)
    t0 = time.perf_counter()
    U = []
    for w in nodes:
        u = np.zeros(len(F))
        for _ in range(50):
            r = a(w) * (K @ u) + EPS0 * c(w) * m * u**3 - F
            if np.linalg.norm(r) < 1e-10 * np.linalg.norm(F):
                break
            J = (a(w) * K + sp.diags(3.0 * EPS0 * c(w) * m * u**2)).tocsc()
            u = u - spla.splu(J).solve(r)
        else:
            raise RuntimeError(f"collocation Newton did not converge at {w}")
        U.append(u)
    U = np.array(U)
    mean = weights @ U
    return mean, weights @ U**2 - mean**2, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--refine", type=int, nargs="+", default=[5, 7])
    ap.add_argument("--orders", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--coll", type=int, default=10, help="collocation nodes per germ")
    args = ap.parse_args()
    print("| N | p | P | rule nodes | solver | Newton | GMRES its | Galerkin s | mean err "
          "| var err | (p+1)^2 collocation s | its mean err | its var err |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    ratio = None
    for refine in args.refine:
        K, m, F = model(refine)
        mean_c, var_c, t_c = collocation(K, m, F, args.coll)
        for p in args.orders:
            system, sol, t_g = galerkin(K, m, F, p)
            if not sol.success:
                print(f"| {len(F)} | {p} | solve failed: {sol.message} |")
                continue
            em = np.abs(system.mean(sol.Theta) - mean_c).max() / np.abs(mean_c).max()
            ev = np.abs(system.variance(sol.Theta) - var_c).max() / np.abs(var_c).max()
            its = ",".join(str(i) for i in sol.linear_iterations)
            mean_p, var_p, t_p = collocation(K, m, F, p + 1)
            cm = np.abs(mean_p - mean_c).max() / np.abs(mean_c).max()
            cv = np.abs(var_p - var_c).max() / np.abs(var_c).max()
            print(
                f"| {len(F)} | {p} | {system.P} | {system.terms[1].n_nodes} | {sol.solver} "
                f"| {sol.nit} | {its} | {t_g:.2f} | {em:.1e} | {ev:.1e} | {t_p:.2f} "
                f"| {cm:.1e} | {cv:.1e} |"
            )
            ratio = t_g / t_p
        print(f"(reference: {args.coll}^2-node collocation, {t_c:.1f} s at N = {len(F)})")
    print(f"nonlinear_fem: galerkin/collocation time ratio: {ratio:.3g}")


if __name__ == "__main__":
    main()
