"""Dynamic calibration at equal accuracy: backward Euler, BDF2 and the frozen adaptive grid.

The model: logistic growth :math:`\\dot u = a\\,u(1 - u/K)`, :math:`u(0) = 0.1`, through the
user-callback ``NonlinearTerm`` (every march on the generic path, so the three schemes
run the same solver code), calibrated for :math:`(a, K)` from exact data (the closed
form at :math:`a = 1.5`, :math:`K = 2`) at ``--n-data`` times on [0, 6], from
:math:`(1.2, 2.5)`, by ``fit(..., uncertainty=False)`` (trust-region least squares with
forward sensitivities).

* ``scheme="adaptive"`` at several ``rtol``: data at the ``--n-data`` times only, the
  steps chosen at the start and frozen (re-checked at the estimate).
* ``"euler"`` and ``"bdf2"``: a fixed-step problem takes its data at every step, so each
  step count gets the exact data on its own grid (noise-free: the only error of the
  estimate is the time discretization's).

Printed per run: calibration time (grid choice included), steps, the largest relative
error of the estimate, and the model error: the largest relative error of the calibrated
model's exact solution against the truth at the data times. Last lines: for the tightest
adaptive run's model error, the time BDF2 and backward Euler need to reach it (BDF2: the
cheapest measured count that does; backward Euler: extrapolated with its observed order
from the measured time per step) and the time ratios to the adaptive run.

Run: ``nice python benchmarks/dynamic_calibration.py [--n-data 8]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ecfm_uq.inverse import fit
from ecfm_uq.inverse.problems.dynamic import DynamicInverseProblem
from ecfm_uq.system import GalerkinSystem, NonlinearTerm

TRUE = np.array([1.5, 2.0])
U0, T, EPS0 = 0.1, 6.0, [1.2, 2.5]


def logistic():
    def residual(u, w, eps):
        return -eps[0] * u * (1 - u / eps[1])

    def jacobian(u, w, eps):
        return np.array([[-eps[0] * (1 - 2 * u[0] / eps[1])]])

    def eps_jacobian(u, w, eps):
        return np.array([[-u[0] * (1 - u[0] / eps[1]), -eps[0] * u[0] ** 2 / eps[1] ** 2]])

    term = NonlinearTerm(residual, jacobian, eps_jacobian=eps_jacobian, degree=3, size=1)
    return GalerkinSystem([term], 2, M=np.eye(1), name="logistic")


def exact(t, a, K):
    return K / (1 + (K / U0 - 1) * np.exp(-a * t))


def calibrate(system, n, t_data, **kw):
    V = exact(np.linspace(0.0, T, n + 1), *TRUE)[:, None]
    problem = DynamicInverseProblem(system, [U0], T / n, n, np.eye(1), V, **kw)
    t0 = time.perf_counter()
    res = fit(problem, EPS0, uncertainty=False)
    sec = time.perf_counter() - t0
    if not res.success:
        raise RuntimeError(res.message)
    err = float(np.abs(res.eps / TRUE - 1).max())
    u_true = exact(t_data, *TRUE)
    model = float(np.abs(exact(t_data, *res.eps) - u_true).max() / np.abs(u_true).max())
    steps = res.extra["steps"]["n_steps"] if "steps" in res.extra else n
    return sec, steps, err, model


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-data", type=int, default=8)
    ap.add_argument("--rtols", type=float, nargs="*", default=[1e-4, 1e-5, 1e-6])
    ap.add_argument("--bdf2", type=int, nargs="*", default=[128, 512, 1536])
    ap.add_argument("--euler", type=int, nargs="*", default=[128, 512])
    args = ap.parse_args()
    system = logistic()
    t_data = np.linspace(0.0, T, args.n_data + 1)
    rows = {}
    print(f"logistic calibration, (a, K) = {TRUE.tolist()} from {EPS0}, exact data")
    print(f"  {'scheme':28s} {'steps':>6s} {'eps err':>9s} {'model err':>9s} {'time [s]':>9s}")
    for rtol in args.rtols:
        r = calibrate(system, args.n_data, t_data, scheme="adaptive", rtol=rtol)
        rows[("adaptive", rtol)] = r
        print(f"  {f'adaptive rtol={rtol:g}':28s} {r[1]:6d} {r[2]:9.1e} {r[3]:9.1e} {r[0]:9.2f}")
    for scheme, counts in (("bdf2", args.bdf2), ("euler", args.euler)):
        for n in counts:
            r = calibrate(system, n, t_data, scheme=scheme)
            rows[(scheme, n)] = r
            label = f"{scheme}, data at every step"
            print(f"  {label:28s} {r[1]:6d} {r[2]:9.1e} {r[3]:9.1e} {r[0]:9.2f}")
    sec_a, _, _, target = rows[("adaptive", args.rtols[-1])]
    print(f"target: the model error of adaptive rtol={args.rtols[-1]:g}, {target:.1e}")
    ok = [rows[("bdf2", n)] for n in args.bdf2 if rows[("bdf2", n)][3] <= target]
    if ok:
        best = min(ok, key=lambda r: r[0])
        print(f"  bdf2 reaches it with {best[1]} steps in {best[0]:.2f} s: "
              f"time ratio bdf2/adaptive {best[0] / sec_a:.2f}")  # fmt: skip
    else:
        n1, n2 = args.bdf2[-2:]
        (_, _, _, e1), (s2, _, _, e2) = rows[("bdf2", n1)], rows[("bdf2", n2)]
        order = np.log(e1 / e2) / np.log(n2 / n1)
        need = n2 * (e2 / target) ** (1 / order)
        print(f"  bdf2 (observed order {order:.2f}) needs ~{need:.3g} steps, ~{s2 / n2 * need:.3g} s "
              f"(extrapolated): time ratio bdf2/adaptive ~{s2 / n2 * need / sec_a:.3g}")  # fmt: skip
    n1, n2 = args.euler[-2:]
    (_, _, _, e1), (s2, _, _, e2) = rows[("euler", n1)], rows[("euler", n2)]
    order = np.log(e1 / e2) / np.log(n2 / n1)
    need = n2 * (e2 / target) ** (1 / order)
    be = s2 / n2 * need
    print(f"  backward Euler (observed order {order:.2f}) needs ~{need:.3g} steps, ~{be:.3g} s "
          f"(extrapolated from the measured time per step)")  # fmt: skip
    print(f"dynamic calibration: backward-Euler/adaptive time ratio at equal model error: "
          f"{be / sec_a:.3g}")  # fmt: skip


if __name__ == "__main__":
    main()
