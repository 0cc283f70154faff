"""Observed order in time of ``march``'s schemes on a linear and a nonlinear model (issue 29).

* **linear**: the transient FE heat model of ``benchmarks/transient.py`` (``--cells``
  cells per side, 4 uniform germs, order 3, P = 35) from zero over [0, 0.1]; reference:
  ``integrate(rtol=1e-12)``.
* **nonlinear**: the random-stiffness pendulum (``ecfm_uq.problems.pendulum``, a
  ``NonlinearTerm``, chaos order 3) over [0, 2] at ``eps = 4``; reference: scipy's DOP853
  (the pendulum is not stiff) at ``rtol=1e-13`` on the same Galerkin right-hand side.

Error: max over chaos coefficients of :math:`|\\Theta_n - \\Theta_{ref}(T)|` at the final
time, relative to :math:`\\max|\\Theta_{ref}(T)|`; the order is
:math:`\\log_2(e_{\\Delta t} / e_{\\Delta t/2})`. Prints one markdown table per model
(the table of docs/time.md).

Run: ``nice python benchmarks/time_orders.py [--cells 15]``.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.integrate import solve_ivp

from ecfm_uq.problems.pendulum import build_pendulum
from ecfm_uq.system import integrate, march


def table(name, system, eps, Theta0, T, ns, ref):
    print(f"\n{name} (N = {system.N}, P = {system.P}, T = {T})\n")
    print("| steps | backward Euler error | order | BDF2 error | order |")
    print("|---|---|---|---|---|")
    prev = {}
    for n in ns:
        row = [f"| {n} "]
        for scheme in ("euler", "bdf2"):
            tr = march(system, eps, Theta0, T / n, n, scheme=scheme, tol=1e-12)
            err = np.abs(tr.Theta[-1] - ref).max() / np.abs(ref).max()
            order = f"{np.log2(prev[scheme] / err):.2f}" if scheme in prev else ""
            prev[scheme] = err
            row.append(f"| {err:.2e} | {order} ")
        print("".join(row) + "|")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=15)
    args = ap.parse_args()

    from transient import build  # benchmarks/transient.py (same folder)

    _fem, _M, system = build(args.cells)
    eps, Theta0 = np.zeros(system.n_eps), np.zeros(system.shape)
    ref = integrate(system, eps, Theta0, [0.1], t0=0.0, rtol=1e-12).Theta[-1]
    table("linear: transient FE heat model", system, eps, Theta0, 0.1, (25, 50, 100, 200, 400), ref)

    system, Theta0 = build_pendulum(order=3)
    eps = [4.0]

    def f(t, y):
        return -system.residual(y.reshape(system.shape), eps).ravel()

    sol = solve_ivp(f, (0, 2.0), Theta0.ravel(), method="DOP853", rtol=1e-13, atol=1e-15)
    ref = sol.y[:, -1].reshape(system.shape)
    table("nonlinear: random-stiffness pendulum", system, eps, Theta0, 2.0,
          (20, 40, 80, 160, 320), ref)  # fmt: skip


if __name__ == "__main__":
    main()
