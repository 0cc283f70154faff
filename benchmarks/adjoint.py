"""Benchmark: adjoint against forward-sensitivity gradients with many parameters.

Two cases, timed interleaved in one run (median of ``--repeats``):

- **Fisher-KPP, source in 8 x 8 = 64 modes** (paper Section 3.2 model, state 10 x 10
  sines, 25 sensors, the paper's data): the steady standard objective
  z = |M E[theta] - v|^2 / 2. Forward solve = Newton on the nonlinear system (no
  gradient); forward gradient = the same solve plus d(theta)/d(eps) for 64 right-hand
  sides; adjoint gradient = the same solve plus one transposed solve.
- **Burgers, viscosity in 20 cells** (paper Section 3.1 model, 50 modes, 100 steps, 21
  parameters): the dynamic standard and ECFM objectives. Forward = the march alone;
  gradient = march + forward sensitivities (21 right-hand sides a step) or march +
  backward adjoint pass (one transposed solve a step with the kept factors).

- **2-D stochastic diffusion, conductivity in 8 x 8 = 64 patches** (the scikit-fem model
  of ``ecfm_uq.problems.fem_diffusion``, 48 x 48 cells, N = 2209, d = 4, order 3, P = 35,
  NP = 77 315, solved matrix-free by CG with the mean-based preconditioner): the steady
  standard objective. Here every sensitivity right-hand side is a full Krylov solve.

Printed: seconds per call and gradient/forward cost ratios. Last line (the diffusion
case, where the choice matters):
``gradient/forward at n_eps=64: <adjoint ratio> (adjoint), <forward ratio> (forward)``.

Usage: ``python benchmarks/adjoint.py [--repeats R]``.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ecfm_uq.inverse import DynamicInverseProblem  # noqa: E402
from ecfm_uq.inverse.formulations.steady import standard_objective  # noqa: E402
from ecfm_uq.problems.burgers import BurgersModel  # noqa: E402
from ecfm_uq.problems.fisher_kpp import build_kpp, make_data, sensor_grid  # noqa: E402
from ecfm_uq.system import solve_steady  # noqa: E402


def interleaved(fns, repeats):
    """Median seconds of each callable, calling them in turn ``repeats`` times."""
    times = {k: [] for k in fns}
    for fn in fns.values():
        fn()  # warm-up
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def steady_timings(system, M_obs, v, eps, repeats):
    """Forward solve, forward-sensitivity and adjoint gradients of the standard objective."""

    def gradient(kind):
        return standard_objective(system, M_obs, v, eps, gradient=kind)[1]

    g_f, g_a = gradient("forward"), gradient("adjoint")
    agree = float(np.abs(g_a - g_f).max() / np.abs(g_f).max())
    t = interleaved(
        {
            "forward solve": lambda: solve_steady(system, eps, strict=True),
            "gradient (forward sens.)": lambda: gradient("forward"),
            "gradient (adjoint)": lambda: gradient("adjoint"),
        },
        repeats,
    )
    return system.n_eps, t, agree


def kpp_case(repeats):
    problem = build_kpp(n_state=10, n_source=8, sensors=sensor_grid(5))
    data = make_data(problem, sigma=0.05, seed=0)
    system, M_obs, v = problem.system, problem.M_obs, data.v
    eps = np.random.default_rng(0).uniform(0.0, 3.0, system.n_eps)
    return steady_timings(system, M_obs, v, eps, repeats)


def fem_case(repeats):
    from ecfm_uq.problems.fem_diffusion import build_fem_diffusion

    problem = build_fem_diffusion(48, 3, patches=8, inclusion=None)
    system, M_obs = problem.system, problem.M_obs
    rng = np.random.default_rng(2)
    v = M_obs @ system.mean(solve_steady(system, 0.1 * rng.standard_normal(64)).Theta)
    return steady_timings(system, M_obs, v, 0.1 * rng.standard_normal(64), repeats)


def burgers_case(repeats):
    model = BurgersModel(viscosity_cells=20)
    eps_true = np.concatenate([np.full(20, 1.75), [1.0]])
    V = model.solve(eps_true).Theta @ model.system.E1 @ model.M_obs.T
    args = (model.system, model.Theta0, model.dt, model.n_steps, model.M_obs, V)
    fwd = DynamicInverseProblem(*args, gradient="forward")
    adj = DynamicInverseProblem(*args, gradient="adjoint")
    eps = eps_true + 0.1 * np.random.default_rng(1).standard_normal(21)
    out = {}
    for form in ("standard", "ecfm"):
        g_f, g_a = fwd.objective(form)(eps)[1], adj.objective(form)(eps)[1]
        agree = float(np.abs(g_a - g_f).max() / np.abs(g_f).max())
        t = interleaved(
            {
                "forward solve": lambda form=form: fwd.loss(eps, form),
                "gradient (forward sens.)": lambda form=form: fwd.objective(form)(eps),
                "gradient (adjoint)": lambda form=form: adj.objective(form)(eps),
            },
            repeats,
        )
        out[form] = (t, agree)
    return model.system.n_eps, out


def report(title, n_eps, t, agree):
    base = t["forward solve"]
    print(f"\n{title} (n_eps = {n_eps}); adjoint vs forward gradient: {agree:.1e} relative")
    for k, s in t.items():
        print(f"  {k:>26}: {s * 1e3:9.2f} ms   x{s / base:6.2f} of the forward solve")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    n_b, burgers = burgers_case(max(3, args.repeats // 2))
    for form, (t, agree) in burgers.items():
        report(f"Burgers, viscosity in 20 cells, {form}", n_b, t, agree)
    n_k, t, agree = kpp_case(args.repeats)
    report("Fisher-KPP, source in 8 x 8 modes, standard (dense LU)", n_k, t, agree)
    n_f, t, agree = fem_case(max(3, args.repeats // 2))
    report("2-D diffusion, conductivity in 8 x 8 patches, standard (CG)", n_f, t, agree)
    base = t["forward solve"]
    ra, rf = t["gradient (adjoint)"] / base, t["gradient (forward sens.)"] / base
    print(f"gradient/forward at n_eps={n_f}: {ra:.2f} (adjoint), {rf:.2f} (forward)")


if __name__ == "__main__":
    main()
