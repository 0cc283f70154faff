"""Benchmark: stochastic Galerkin PCE against Monte Carlo and Gauss collocation at equal
accuracy, for the beam of paper Section 3.3 (N = 6 modes, eps = 1).

Target: relative error 1e-4 in both the mean and the variance of the displacement at the
five sensors (``relative_error``: max abs error over max abs reference), against a
high-accuracy reference (Gauss-Legendre quadrature over omega of the same deterministic
solves, 64 nodes; its change with 96 nodes is printed).

- **Galerkin PCE**: the smallest chaos order reaching the target; timed is everything
  stochastic (chaos basis, expectation tensors, weighted Gram, GalerkinSystem, Newton
  solve, Eq. stats), median of repeats. The spatial operators are assembled once and
  shared by all three methods, so their cost is excluded from all three.
- **Monte Carlo**: the per-solve time is *measured* on a batch of serial deterministic
  solves through ``ecfm_uq.mc.monte_carlo``; the sample count needed for a standard error
  of 1e-4 relative is *estimated* from the batch's moments,
  ``n_mean = max_i (s_i / (1e-4 |mean|_max))^2`` and
  ``n_var = max_i (m4_i - s_i^4) / (1e-4 |var|_max)^2``; the MC time is *extrapolated*
  as n times the per-solve time, divided by 2 for ideal use of two workers (the
  conservative choice; the serial figure is printed too). One standard error is a
  68 % band; a 95 % guarantee would need about 4 times more samples.
- **Gauss collocation** (non-intrusive PCE): deterministic solves at p + 1 Gauss nodes
  projected on the chaos basis; the smallest node count reaching the target is timed.
  For an operator affine in one germ, Galerkin of order p equals collocation with p + 1
  nodes exactly (checked and printed), so the comparison is pure cost.

The last line is ``pce_vs_mc speedup: <float>x`` (Monte Carlo time over Galerkin time).
"""

from __future__ import annotations

import os

# every method here is single-core; a multi-threaded BLAS only adds wake-up noise to the
# tiny solves on a shared machine (set before numpy is imported)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ecfm_uq.chaos import ChaosBasis  # noqa: E402
from ecfm_uq.mc import (  # noqa: E402
    draw_germ,
    mc_moments,
    monte_carlo,
    pseudospectral_projection,
    quadrature_moments,
    relative_error,
)
from ecfm_uq.problems.beam import BeamModel  # noqa: E402

TARGET = 1e-4


def median_time(fn, repeats):
    """Median wall time of ``fn()`` over ``repeats`` calls (after one warm-up call)."""
    fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def galerkin_moments(order, delta, eps):
    model = BeamModel(order=order, delta=delta)
    sol = model.solve(eps, strict=True)
    return model.sensor_moments(sol.Theta)


def collocation_moments(n_nodes, fn):
    chaos = ChaosBasis(n_nodes - 1)
    Theta = pseudospectral_projection(fn, chaos, n_nodes)  # (C, P) at the sensors
    return Theta[:, 0], (Theta[:, 1:] ** 2).sum(axis=1)  # orthonormal: Eq. stats


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=5000, help="MC samples timed (default 5000)")
    ap.add_argument("--repeats", type=int, default=200, help="timing repeats (default 200)")
    ap.add_argument("--seed", type=int, default=2025)
    args = ap.parse_args(argv)
    if args.batch < 100 or args.repeats < 1:
        ap.error("--batch must be >= 100 and --repeats >= 1")

    eps = 1.0
    base = BeamModel()
    delta = base.delta
    fn = base.response_function(eps)  # sensors only
    ref_mean, ref_var = quadrature_moments(fn, 64)
    m96, v96 = quadrature_moments(fn, 96)
    print(
        f"# pce_vs_mc  python {platform.python_version()}  numpy {np.__version__}  {platform.machine()}"
    )
    print(f"beam: N = {base.N}, eps = {eps}, delta = {delta:.6f}, C = {base.sensors.size} sensors")
    print(
        f"reference: 64-node Gauss quadrature of deterministic solves; change with 96 nodes "
        f"{max(relative_error(ref_mean, m96), relative_error(ref_var, v96)):.1e}"
    )
    print(f"target: relative error {TARGET:g} in mean and variance at the sensors\n")

    # --- Galerkin PCE -----------------------------------------------------------------
    print("Galerkin PCE: order, error mean, error var")
    p_gal = None
    for p in range(0, 13):
        mu, var = galerkin_moments(p, delta, eps)
        em, ev = relative_error(mu, ref_mean), relative_error(var, ref_var)
        print(f"  {p:2d}  {em:.2e}  {ev:.2e}")
        if em < TARGET and ev < TARGET:
            p_gal = p
            break
    if p_gal is None:
        print("Galerkin PCE did not reach the target by order 12", file=sys.stderr)
        return 1
    t_gal = median_time(functools.partial(galerkin_moments, p_gal, delta, eps), args.repeats)
    model = BeamModel(order=p_gal, delta=delta)
    t_solve = median_time(lambda: model.solve(eps), args.repeats)
    sol = model.solve(eps)
    t_sens = median_time(lambda: (sol.eps_sensitivity(), sol.lam_sensitivity()), args.repeats)
    print(f"  -> order {p_gal} (P = {p_gal + 1}): {t_gal * 1e3:.3f} ms (build + solve + stats)")
    print(
        f"     of which solve_steady {t_solve * 1e3:.3f} ms; dTheta/d(eps, lam) +{t_sens * 1e3:.3f} ms"
    )

    # --- Gauss collocation ----------------------------------------------------------
    print("\nGauss collocation: nodes, error mean, error var")
    n_col = None
    for n in range(1, 14):
        mu, var = collocation_moments(n, fn)
        em, ev = relative_error(mu, ref_mean), relative_error(var, ref_var)
        print(f"  {n:2d}  {em:.2e}  {ev:.2e}")
        if em < TARGET and ev < TARGET:
            n_col = n
            break
    if n_col is None:
        print("collocation did not reach the target with 13 nodes", file=sys.stderr)
        return 1
    t_col = median_time(functools.partial(collocation_moments, n_col, fn), args.repeats)
    # Galerkin order p == collocation at p + 1 Gauss nodes (affine operator, one germ)
    theta_fn = functools.partial(base.solve_deterministic, eps=eps)
    same = np.abs(pseudospectral_projection(theta_fn, model.chaos) - sol.Theta).max()
    print(f"  -> {n_col} nodes: {t_col * 1e3:.3f} ms (solves + projection + stats)")
    print(f"     max |Theta_collocation - Theta_Galerkin| at order {p_gal}: {same:.1e}")

    # --- Monte Carlo ------------------------------------------------------------------
    w = draw_germ(args.batch, args.seed)
    monte_carlo(fn, w[:100], workers=1)  # warm-up
    t0 = time.perf_counter()
    y = monte_carlo(fn, w, workers=1)
    t_per = (time.perf_counter() - t0) / args.batch
    mom = mc_moments(y)
    m4 = ((y - mom.mean) ** 4).mean(axis=0)
    n_mean = float(np.max(mom.var / (TARGET * np.abs(mom.mean).max()) ** 2))
    n_var = float(np.max((m4 - mom.var**2) / (TARGET * np.abs(mom.var).max()) ** 2))
    n_mc = max(n_mean, n_var)
    t_mc_serial = n_mc * t_per
    t_mc = t_mc_serial / 2
    print(
        f"\nMonte Carlo: {t_per * 1e6:.1f} us per deterministic solve (measured, {args.batch} serial)"
    )
    print(
        f"  samples for 1e-4 (one standard error, estimated): mean {n_mean:.2e}, variance {n_var:.2e}"
    )
    print(
        f"  -> n = {n_mc:.2e}: {t_mc_serial:.1f} s serial, {t_mc:.1f} s on 2 ideal workers (extrapolated)"
    )

    print("\nsummary (time to 1e-4 in mean and variance):")
    print(f"  Galerkin PCE (order {p_gal})        {t_gal * 1e3:10.3f} ms")
    print(f"  Gauss collocation ({n_col} nodes)     {t_col * 1e3:10.3f} ms")
    print(f"  Monte Carlo (2 workers, extrap.)  {t_mc * 1e3:10.3e} ms")
    faster = "collocation" if t_col < t_gal else "Galerkin"
    print(f"  Galerkin / collocation time: {t_gal / t_col:.2f} ({faster} is faster at this size)")
    print(
        f"  Galerkin solve alone / collocation: {t_solve / t_col:.2f} (the affine block system "
        f"decouples at the Gauss nodes: {model.system.decoupling() is not None})"
    )
    print(f"  serial MC / Galerkin: {t_mc_serial / t_gal:.3e}x")
    print(f"pce_vs_mc speedup: {t_mc / t_gal:.6g}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
