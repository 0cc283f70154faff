"""Benchmark: stochastic Galerkin PCE against non-intrusive Gauss collocation on a
nonlinear problem, Burgers' equation with a random viscosity (paper Section 3.1 model,
random coefficient as in Eq. pce; SPEC "Performance").

Problem: the Burgers model of :mod:`ecfm_uq.problems.burgers` at the paper's
discretization (N = 50 sine modes, 100 backward-Euler steps, T = 2, Newton tolerance
1e-10) with eps = (1.75, 1.0) and a random log-viscosity

    eps1(omega) = 1.75 + spread * (omega - 1/2),   omega ~ U(0, 1),   spread = 0.5

(the viscosity 10^-eps1 varies by a factor 10^0.5 = 3.2). Quantity of interest: mean
and variance of the four sensor readings at every time step (100 x 4 values);
``relative_error`` is the largest absolute error over the largest absolute reference value.

Reference: Gauss-Legendre quadrature over omega of deterministic solves (24 nodes; the
change with 32 nodes is printed), with forward sensitivities in (eps1, eps2).

For chaos orders p = 1..6, in one run:

- **Galerkin** (intrusive): ``model.solve`` on the P = p + 1 stochastic Galerkin system
  of ``BurgersModel(viscosity_chaos=ChaosBasis(p), viscosity_spread=spread)``, the
  convection coupled through E[Psi_b Psi_c Psi_l], with the engine's default solver for
  this march: iterations preconditioned by the P node-wise deterministic Jacobians at
  the germ's Gauss nodes, compiled (``solver`` column; ``ecfm_uq.system.solve.linear.
  NodalPreconditioner``). Timed: the march only (building the order-p model, about
  0.05 s, is excluded and printed). Also timed, for reference: the same march with
  ``solver="dense"`` (an (NP x NP) Newton Jacobian factorized per iteration, the v0.1
  path; ``dense s`` column).
- **Collocation** (non-intrusive): p + 1 deterministic solves at the Gauss nodes,
  projected on the order-p chaos basis (``pseudospectral_projection``). Timed: solves
  plus projection.
- The same two with forward sensitivities (``sensitivities=True``): the error of
  d(mean)/d eps and d(variance)/d eps against the reference is printed beside the time.

For the quadratic convection term, Galerkin order p is *not* collocation with p + 1
nodes (the projection of w w_x differs from interpolating the solves), so the two
accuracies differ and both are reported.

Timing: BLAS pinned to one thread; per order, one untimed warm-up call of each of the
four variants (its output gives the errors), then ``--repeats`` rounds calling the four
in turn; the median of each is reported.

The last line is ``galerkin_vs_collocation time ratio: <float>``: Galerkin time over
collocation time, each at its smallest order reaching relative error 1e-4 in both the
mean and the variance (> 1 means collocation is faster).

Usage: ``python benchmarks/galerkin_vs_collocation.py [--repeats R] [--spread S]``.
"""

from __future__ import annotations

import os

# every method here is single-core; a multi-threaded BLAS only adds wake-up noise to the
# small dense solves on a shared machine (set before numpy is imported)
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ecfm_uq.chaos import ChaosBasis  # noqa: E402
from ecfm_uq.mc import pseudospectral_projection, relative_error  # noqa: E402
from ecfm_uq.problems.burgers import PAPER_TRUE_EPS, BurgersModel  # noqa: E402
from ecfm_uq.system import march  # noqa: E402

TARGET = 1e-4


class Stats:
    """Mean and variance of the sensor series and their eps-derivatives (None if absent)."""

    def __init__(self, coeffs, norms2, dcoeffs=None):
        # coeffs (m, P) chaos coefficients of the m = n_steps * C sensor values;
        # dcoeffs (m, P, n_eps) their eps-derivatives (Eq. stats for an orthogonal basis)
        w = np.asarray(norms2)[1:]
        self.mean = coeffs[:, 0]
        self.var = (coeffs[:, 1:] ** 2) @ w
        self.dmean = self.dvar = None
        if dcoeffs is not None:
            self.dmean = dcoeffs[:, 0, :]
            self.dvar = 2.0 * np.einsum("mk,k,mke->me", coeffs[:, 1:], w, dcoeffs[:, 1:, :])

    def errors(self, ref):
        """Relative errors (mean, variance, sensitivities) against ``ref``."""
        em = relative_error(self.mean, ref.mean)
        ev = relative_error(self.var, ref.var)
        es = None
        if self.dmean is not None:
            es = max(
                relative_error(a[:, e], b[:, e])
                for a, b in ((self.dmean, ref.dmean), (self.dvar, ref.dvar))
                for e in range(a.shape[1])
            )
        return em, ev, es


class Collocation:
    """Deterministic solves at Gauss nodes of the germ, projected on a chaos basis."""

    def __init__(self, det_model, eps, spread):
        self.model = det_model
        self.eps = np.asarray(eps, dtype=float)
        self.spread = float(spread)
        self.C = det_model.sensors.size

    def _fn(self, sensitivities):
        model, eps, spread = self.model, self.eps, self.spread

        def fn(omega):
            e = eps.copy()
            e[0] += spread * (float(omega) - 0.5)
            tr = model.solve(e, sensitivities=sensitivities, strict=True)
            y = model.measure(tr)[1:].ravel()  # (n_steps * C,)
            if not sensitivities:
                return y
            # d eps1(omega) / d eps1 = 1: the node's sensitivity is that of the mean eps1
            dy = np.einsum("cn,tne->tce", model.M_obs, tr.dTheta[1:, :, 0, :]).reshape(y.size, -1)
            return np.concatenate([y, dy.ravel()])

        return fn

    def stats(self, order, n_nodes=None, sensitivities=False):
        chaos = ChaosBasis(order)
        coef = pseudospectral_projection(self._fn(sensitivities), chaos, n_nodes)
        m = self.model.n_steps * self.C
        if not sensitivities:
            return Stats(coef, chaos.norms2)
        dcoef = coef[m:].reshape(m, -1, chaos.size).transpose(0, 2, 1)  # (m, P, n_eps)
        return Stats(coef[:m], chaos.norms2, dcoef)


def galerkin_stats(model, eps, sensitivities=False, solver=None):
    """March the stochastic Galerkin system and return the sensor statistics.

    ``solver=None``: the model's own solve (the engine's default choice).
    """
    if solver is None:
        tr = model.solve(eps, sensitivities=sensitivities, strict=True)
    else:
        tr = march(
            model.system, eps, model.Theta0, model.dt, model.n_steps, sensitivities=sensitivities,
            tol=model.newton_tol, maxiter=model.newton_maxiter, strict=True, solver=solver,
        )  # fmt: skip
    S = np.einsum("cn,tnp->tcp", model.M_obs, tr.Theta[1:])
    coef = S.reshape(-1, S.shape[-1])
    dcoef = None
    if sensitivities:
        dS = np.einsum("cn,tnpe->tcpe", model.M_obs, tr.dTheta[1:])
        dcoef = dS.reshape(coef.shape[0], coef.shape[1], -1)
    return Stats(coef, model.chaos.norms2, dcoef), tr


def timed_rounds(fns, repeats):
    """One warm-up call of each ``fns[name]()`` (its value is returned), then ``repeats``
    rounds calling them in turn; returns ``(values, median wall times)``."""
    values = {name: fn() for name, fn in fns.items()}
    ts = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            ts[name].append(time.perf_counter() - t0)
    return values, {name: statistics.median(v) for name, v in ts.items()}


def first_reaching(rows, key):
    """Smallest order whose mean and variance errors are both below TARGET."""
    for r in rows:
        if r[key][0] < TARGET and r[key][1] < TARGET:
            return r
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spread", type=float, default=0.5, help="width of eps1(omega) (0.5)")
    ap.add_argument("--max-order", type=int, default=6, help="largest chaos order (6)")
    ap.add_argument("--repeats", type=int, default=5, help="timed rounds per order (5)")
    ap.add_argument("--ref-nodes", type=int, default=24, help="reference Gauss nodes (24)")
    ap.add_argument("--check-nodes", type=int, default=32, help="reference check nodes (32)")
    ap.add_argument("--n-modes", type=int, default=50, help="sine modes N (paper: 50)")
    ap.add_argument("--n-steps", type=int, default=100, help="backward-Euler steps (100)")
    args = ap.parse_args(argv)
    if not (args.spread > 0 and args.max_order >= 1 and args.repeats >= 1):
        ap.error("--spread must be > 0, --max-order >= 1, --repeats >= 1")
    if not (args.check_nodes > args.ref_nodes > args.max_order + 1):
        ap.error("need --check-nodes > --ref-nodes > --max-order + 1")

    eps = np.array(PAPER_TRUE_EPS, dtype=float)
    det = BurgersModel(n_modes=args.n_modes, n_steps=args.n_steps)
    col = Collocation(det, eps, args.spread)
    print(
        f"# galerkin_vs_collocation  python {platform.python_version()}  numpy {np.__version__}"
        f"  {platform.machine()}  OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}"
    )
    print(
        f"burgers: N = {det.n_modes}, {det.n_steps} steps, T = {det.T:g}, eps = {eps.tolist()}, "
        f"eps1(omega) = {eps[0]:g} + {args.spread:g} (omega - 1/2), Newton tol {det.newton_tol:g}"
    )
    t0 = time.perf_counter()
    ref = col.stats(args.ref_nodes - 1, args.ref_nodes, sensitivities=True)
    t_ref = time.perf_counter() - t0
    chk = col.stats(args.check_nodes - 1, args.check_nodes, sensitivities=True)
    dm, dv, ds = chk.errors(ref)
    print(
        f"reference: {args.ref_nodes}-node Gauss collocation ({t_ref:.1f} s); change with "
        f"{args.check_nodes} nodes: mean {dm:.1e}, var {dv:.1e}, sensitivities {ds:.1e}"
    )
    print(
        f"QoI: mean and variance of {det.sensors.size} sensors x {det.n_steps} steps; "
        f"target relative error {TARGET:g}; median of {args.repeats} rounds after warm-up\n"
    )

    rows = []
    hdr = (
        f"{'p':>2} {'P':>2} | {'Galerkin err mean':>17} {'var':>8} {'sens':>8} "
        f"{'march s':>8} {'+sens s':>8} {'nit':>4} {'dense s':>8} | {'colloc err mean':>15} "
        f"{'var':>8} {'sens':>8} {'solves s':>8} {'+sens s':>8}"
    )
    print(hdr)
    print("-" * len(hdr))
    for p in range(1, args.max_order + 1):
        t0 = time.perf_counter()
        gmodel = BurgersModel(
            n_modes=args.n_modes,
            n_steps=args.n_steps,
            viscosity_chaos=ChaosBasis(p),
            viscosity_spread=args.spread,
        )
        t_build = time.perf_counter() - t0
        fns = {
            "gal": lambda m=gmodel: galerkin_stats(m, eps),
            "gal_s": lambda m=gmodel: galerkin_stats(m, eps, sensitivities=True),
            "gal_dense": lambda m=gmodel: galerkin_stats(m, eps, solver="dense"),
            "col": lambda p=p: col.stats(p),
            "col_s": lambda p=p: col.stats(p, sensitivities=True),
        }
        vals, t = timed_rounds(fns, args.repeats)
        g_err = vals["gal_s"][0].errors(ref)
        c_err = vals["col_s"].errors(ref)
        if not np.array_equal(vals["gal"][0].mean, vals["gal_s"][0].mean):
            print("march with sensitivities changed the states", file=sys.stderr)
            return 1
        d_err = vals["gal_dense"][0].errors(ref)
        if max(abs(a - b) for a, b in zip(d_err[:2], g_err[:2], strict=True)) > 1e-3 * TARGET:
            print("the dense and the default Galerkin march disagree", file=sys.stderr)
            return 1
        nit = int(vals["gal"][1].nit.sum())
        solver = vals["gal"][1].solver
        row = {"p": p, "gal": g_err, "col": c_err, "t": t, "build": t_build, "nit": nit}
        rows.append(row)
        print(
            f"{p:2d} {p + 1:2d} | {g_err[0]:17.2e} {g_err[1]:8.2e} {g_err[2]:8.2e} "
            f"{t['gal']:8.3f} {t['gal_s']:8.3f} {nit:4d} {t['gal_dense']:8.3f} | "
            f"{c_err[0]:15.2e} {c_err[1]:8.2e} {c_err[2]:8.2e} {t['col']:8.3f} {t['col_s']:8.3f}"
        )
    t_det = rows[-1]["t"]["col"] / (args.max_order + 1)
    print(f"\nGalerkin solver (the engine's default for this march): {solver}")
    print(
        "default / dense-LU Galerkin march: "
        + ", ".join(f"{r['t']['gal'] / r['t']['gal_dense']:.2f}" for r in rows)
        + " (p=1..)"
    )
    print(
        f"Galerkin model build (chaos tensors, weighted Gram; excluded above): "
        f"{min(r['build'] for r in rows):.3f}-{max(r['build'] for r in rows):.3f} s"
    )
    print(
        f"one deterministic solve ~{t_det * 1e3:.0f} ms; Galerkin march / (P deterministic "
        f"solves): " + ", ".join(f"{r['t']['gal'] / r['t']['col']:.1f}" for r in rows) + " (p=1..)"
    )

    g, c = first_reaching(rows, "gal"), first_reaching(rows, "col")
    print(f"\nto reach {TARGET:g} in mean and variance:")
    for name, r, key in (("Galerkin", g, "gal"), ("collocation", c, "col")):
        if r is None:
            print(f"  {name}: not reached by order {args.max_order}")
            continue
        tk, tks = ("gal", "gal_s") if key == "gal" else ("col", "col_s")
        print(
            f"  {name:11s} order {r['p']} (P = {r['p'] + 1}): {r['t'][tk]:.3f} s, "
            f"with sensitivities {r['t'][tks]:.3f} s (sensitivity error {r[key][2]:.1e})"
        )
    if g is None or c is None:
        print("a method did not reach the target; raise --max-order", file=sys.stderr)
        return 1
    ratio = g["t"]["gal"] / c["t"]["col"]
    ratio_s = g["t"]["gal_s"] / c["t"]["col_s"]
    faster = "collocation" if ratio > 1 else "Galerkin"
    print(f"  with sensitivities: Galerkin / collocation {ratio_s:.2f}")
    print(f"  without: {ratio:.2f} ({faster} is faster at equal accuracy)")
    print(f"galerkin_vs_collocation time ratio: {ratio:.6g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
