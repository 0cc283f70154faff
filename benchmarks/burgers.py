"""Benchmark: cost of a Burgers gradient against a forward solve (SPEC "Performance").

One run times, at the paper's settings (N = 50, 100 backward-Euler steps, Newton
tolerance 1e-6):

* one forward solve (standard) and one constrained forward solve (ECFM),
* one gradient of each objective by the default method (``gradient="auto"``: the
  discrete adjoint for n_eps = 2 > 1 output) and by forward sensitivities (Eqs.
  discrete_sens and discrete_sens_ecfm), both reusing the factorized step Jacobian,
* a central finite-difference gradient (2 x n_eps forward solves),
* the whole 250-epoch Adam study for both methods without loss surfaces, at the study's
  Newton tolerance 1e-10, against a naive numpy implementation of the same maths (dense
  triple-product tensor contracted by ``einsum``, ``numpy.linalg.solve`` every Newton
  step, the same sensitivities and Adam), timed in the same run; the two estimates are
  compared.

Last lines: ``burgers gradient/forward: <ratio>``, the larger of the two formulations'
gradient-to-forward time ratios with the default gradient (aim <= 1.5), and ``burgers study
speedup: <x>x`` (naive time over ours for the study).

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

from ecfm_uq.inverse import fit  # noqa: E402
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem  # noqa: E402
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


# --------------------------------------------------------------------------------------
# a naive implementation of the same maths: dense tensors, numpy.linalg.solve, plain loops
# --------------------------------------------------------------------------------------
def naive_objective(model, V, eps, formulation, tol):
    """z and dz/deps by backward Euler + Newton + forward sensitivities, written plainly."""
    from ecfm_uq.problems.burgers import source_time

    M, K, A, F0 = model.M, model.K, model.A, model.F0
    Gam, Mo, dt = model.Gamma, model.M_obs, model.dt
    N, C = K.shape[0], Mo.shape[0]
    nu, dnu = 10.0 ** (-eps[0]), -np.log(10.0) * 10.0 ** (-eps[0])
    ecfm = formulation == "ecfm"
    theta, lam = model.theta0.copy(), np.zeros(C)
    dtheta = np.zeros((N, 2))
    z, grad = 0.0, np.zeros(2)
    for s in range(1, model.n_steps + 1):
        t = s * dt
        F = source_time(t) * F0
        x = np.concatenate([theta, lam]) if ecfm else theta.copy()
        for _ in range(50):
            th = x[:N]
            r = (
                M @ (th - theta) / dt
                + nu * K @ th
                + np.einsum("ijk,j,k->i", A, th, th)
                - eps[1] * F
            )
            J = M / dt + nu * K + np.einsum("ijk,k->ij", A, th) + np.einsum("ikj,k->ij", A, th)
            if ecfm:
                r = np.concatenate([r - Gam @ x[N:], Mo @ th - V[s]])
                J = np.block([[J, -Gam], [Mo, np.zeros((C, C))]])
            x = x - np.linalg.solve(J, r)
            if np.linalg.norm(r) < tol:
                break
        th = x[:N]
        D = np.column_stack([dnu * K @ th, -F])
        rhs = M @ dtheta / dt - D
        if ecfm:
            rhs = np.vstack([rhs, np.zeros((C, 2))])
        S = np.linalg.solve(J, rhs)
        theta, dtheta = th, S[:N]
        if ecfm:
            lam = x[N:]
            z += 0.5 * dt * lam @ lam
            grad += dt * S[N:].T @ lam
        else:
            e = Mo @ theta - V[s]
            z += 0.5 * dt * e @ e
            grad += dt * (Mo @ dtheta).T @ e
    return z, grad


def naive_study(model, V, formulation, epochs, tol, lr=1e-2, betas=(0.9, 0.999)):
    """250 Adam epochs from (1.5, 0.5) on the naive objective."""
    eps = np.array([1.5, 0.5])
    m = v = np.zeros(2)
    for k in range(1, epochs + 1):
        _, g = naive_objective(model, V, eps, formulation, tol)
        m = betas[0] * m + (1 - betas[0]) * g
        v = betas[1] * v + (1 - betas[1]) * g * g
        eps = eps - lr * (m / (1 - betas[0] ** k)) / (np.sqrt(v / (1 - betas[1] ** k)) + 1e-8)
    return eps


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
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V, solve_tol=1e-6
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

    fwd = DynamicInverseProblem(
        model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V, solve_tol=1e-6,
        gradient="forward",
    )  # fmt: skip
    fwd.standard_objective(eps)
    fwd.ecfm_objective(eps)
    rows = interleaved_best(
        {
            "standard forward": lambda: prob.loss(eps, "standard"),
            f"standard gradient ({prob.gradient}, the default)": lambda: prob.standard_objective(
                eps
            ),
            "standard gradient (forward sensitivities)": lambda: fwd.standard_objective(eps),
            "standard gradient (central FD, 4 solves)": lambda: fd_gradient("standard"),
            "ECFM forward": lambda: prob.loss(eps, "ecfm"),
            f"ECFM gradient ({prob.gradient}, the default)": lambda: prob.ecfm_objective(eps),
            "ECFM gradient (forward sensitivities)": lambda: fwd.ecfm_objective(eps),
            "ECFM gradient (central FD, 4 solves)": lambda: fd_gradient("ecfm"),
        },
        args.repeat,
    )
    speedup = None
    if not args.skip_study:
        # the study at its own tolerance (1e-10), ours against the naive implementation
        study_model = BurgersModel()
        Vs = study_model.true_data(PAPER_TRUE_EPS)
        args_ = (study_model.system, study_model.Theta0, study_model.dt, study_model.n_steps)
        ours = naive = 0.0
        for formulation in ("standard", "ecfm"):
            problem = DynamicInverseProblem(*args_, study_model.M_obs, Vs, solve_tol=1e-10)
            t0 = time.perf_counter()
            res = fit(
                problem,
                (1.5, 0.5),
                formulation=formulation,
                method="adam",
                maxiter=250,
                options={"lr": 1e-2},
            )
            ours += time.perf_counter() - t0
            t0 = time.perf_counter()
            eps_naive = naive_study(study_model, Vs, formulation, 250, 1e-10)
            naive += time.perf_counter() - t0
            diff = np.abs(res.eps - eps_naive).max()
            rows[
                f"  250 epochs, {formulation}: eps = {np.round(res.eps, 6)}, |ours - naive| = {diff:.1e}"
            ] = None
        rows["study: 250 Adam epochs x 2 methods, ours (tol 1e-10)"] = ours
        rows["study: the same, naive numpy implementation"] = naive
        speedup = naive / ours

    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}")
    print(f"{'what':<58} {'seconds':>10}")
    for name, t in rows.items():
        print(f"{name:<58} {'' if t is None else f'{t:10.4f}':>10}")
    default = f"({prob.gradient}, the default)"
    r_std = rows[f"standard gradient {default}"] / rows["standard forward"]
    r_ecfm = rows[f"ECFM gradient {default}"] / rows["ECFM forward"]
    f_std = rows["standard gradient (forward sensitivities)"] / rows["standard forward"]
    f_ecfm = rows["ECFM gradient (forward sensitivities)"] / rows["ECFM forward"]
    fd_std = rows["standard gradient (central FD, 4 solves)"] / rows["standard forward"]
    print(
        f"standard: gradient/forward {r_std:.3f} ({prob.gradient}), {f_std:.3f} (forward "
        f"sensitivities), central-FD gradient/forward {fd_std:.3f}"
    )
    print(f"ECFM:     gradient/forward {r_ecfm:.3f} ({prob.gradient}), {f_ecfm:.3f} (forward)")
    print(f"burgers gradient/forward: {max(r_std, r_ecfm):.3f}")
    if speedup is not None:
        print(f"burgers study speedup: {speedup:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
