"""Time integration at equal accuracy: backward Euler, BDF2 and adaptive ``integrate`` (issue 29).

Three models, each timed in this one run:

* **Decay tutorial** (chaospy's intrusive Galerkin tutorial): :math:`\\dot u = -\\beta u`,
  :math:`u(0) = \\alpha`, :math:`\\alpha \\sim N(1.5, 0.2^2)`, :math:`\\beta \\sim U(0.1, 0.2)`,
  chaos order 5, chaospy's 1000-point grid on [0, 10]. Ours: the recipe of docs/time.md
  (inputs, basis, Gram matrix, initial coefficients, system, ``integrate(rtol=1e-10)``,
  moments); chaospy's: its tutorial (``stieltjes`` expansion, ``E`` of the products,
  ``scipy.integrate.odeint``, ``E``/``Var``), once with odeint's defaults and once at
  ``rtol=atol=1e-10``. Errors are against the closed-form mean and variance.
* **Transient FE model** of ``benchmarks/transient.py`` (scikit-fem P1 heat, 4 uniform
  germs, order 3, P = 35; ``--cells`` cells per side) from zero over [0, ``--T``].
  Errors: max over ``--n-out`` output times and nodes of :math:`|x - x_{ref}| /
  \\max|x_{ref}|` for the mean and the variance; the reference is ``integrate`` at
  ``rtol=1e-12`` (its distance to ``rtol=1e-11`` is printed as a check). Each
  method's cheapest setting that reaches ``--target`` (1e-6) on both moments is timed.
  Backward Euler's error is first order: it is measured at four step counts and the count
  reaching the target is extrapolated from the finest two (``err * n`` constant); its time
  is that count times the measured time per step (printed as an extrapolation).
* **Burgers with a random viscosity** (``BurgersModel``, order 3 in one germ), the same
  comparison on its mean and variance over the march's grid.

Last line: ``time integration: best/backward-Euler time ratio on the FE model: <float>``
(aim <= 0.5).

Run: ``nice python benchmarks/time_integration.py [--cells 15] [--T 0.1]`` (needs the
``fem`` extra and chaospy).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats

from ecfm_uq.chaos import ChaosBasis, Inputs, input_basis, input_coefficients, input_gram
from ecfm_uq.problems.burgers import BurgersModel
from ecfm_uq.system import GalerkinSystem, LinearTerm, integrate, march


def rel_err(x, ref):
    return float(np.abs(x - ref).max() / np.abs(ref).max())


def moments(system, Theta):
    mean = Theta @ system.E1
    var = np.einsum("tik,kl,til->ti", Theta, system.E2, Theta) - mean**2
    return mean, var


# -- the decay tutorial ------------------------------------------------------------------
def decay_exact(t):
    safe = np.where(t > 0, t, 1.0)

    def mgf(k):
        e = (np.exp(-0.1 * k * safe) - np.exp(-0.2 * k * safe)) / (0.1 * k * safe)
        return np.where(t > 0, e, 1.0)

    mean = 1.5 * mgf(1)
    return mean, (1.5**2 + 0.2**2) * mgf(2) - mean**2


def decay_ours(t, rtol=1e-10):
    inputs = Inputs([stats.norm(1.5, 0.2), stats.uniform(0.1, 0.1)], names=["alpha", "beta"])
    basis = input_basis(inputs, 5)
    G = input_gram(basis, inputs, lambda x: x[:, 1])
    u0 = input_coefficients(basis, inputs, lambda x: x[:, 0])
    system = GalerkinSystem([LinearTerm(np.eye(1), G=G)], 0, basis=basis, M=np.eye(1))
    tr = integrate(system, [], u0[None, :], t, rtol=rtol)
    mean, var = moments(system, tr.Theta)
    return mean[:, 0], var[:, 0], tr


def decay_chaospy(t, **odeint_kw):
    import chaospy
    from scipy.integrate import odeint

    alpha, beta = chaospy.Normal(1.5, 0.2), chaospy.Uniform(0.1, 0.2)
    joint = chaospy.J(alpha, beta)
    phi = chaospy.expansion.stieltjes(5, joint, normed=True)
    a, b = chaospy.variable(2)
    e_alpha_phi = chaospy.E(a * phi, joint)
    e_beta_phi_phi = chaospy.E(b * phi * phi[:, None], joint)

    def rhs(c, _t):
        return -np.sum(c * e_beta_phi_phi, -1)

    coefs = odeint(rhs, e_alpha_phi, t, **odeint_kw)
    u = chaospy.sum(phi * coefs, -1)
    return chaospy.E(u, joint), chaospy.Var(u, joint)


def timed(fn, *args, repeats=3, **kw):
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn(*args, **kw)
        best = min(best, time.perf_counter() - t0)
    return best, out


def tutorial():
    t = np.linspace(0.0, 10.0, 1000)
    m_ex, v_ex = decay_exact(t)
    decay_ours(t)  # warm-up (imports, caches)
    rows = [
        ("ecfm_uq integrate(rtol=1e-10)", timed(decay_ours, t)),
        ("chaospy recipe, odeint defaults", timed(decay_chaospy, t)),
        ("chaospy recipe, odeint rtol=atol=1e-10", timed(decay_chaospy, t, rtol=1e-10, atol=1e-10)),
    ]  # fmt: skip
    print("decay tutorial, chaos order 5 (P = 21), 1000 times on [0, 10]")
    print(f"  {'method':42s} {'mean err':>9s} {'var err':>9s} {'time [s]':>9s}")
    for name, (sec, out) in rows:
        e_m, e_v = np.abs(out[0] - m_ex).max(), np.abs(out[1] - v_ex).max()
        print(f"  {name:42s} {e_m:9.1e} {e_v:9.1e} {sec:9.3f}")
    ratio = rows[0][1][0] / rows[2][1][0]
    print(f"  integrate recipe / chaospy recipe at rtol 1e-10: {ratio:.2f}")
    print(f"  integrate recipe / chaospy recipe with defaults: {rows[0][1][0] / rows[1][1][0]:.2f}")
    return ratio


# -- fixed steps against adaptive on one model -------------------------------------------
def compare(name, system, eps, Theta0, T, n_out, target, be_steps, bdf2_steps, rtols, ref_rtol):
    """The table of one model; returns (best new time, backward Euler's time)."""
    t_out = np.linspace(0.0, T, n_out + 1)[1:]
    t0 = time.perf_counter()
    ref = integrate(system, eps, Theta0, t_out, t0=0.0, rtol=ref_rtol)
    t_ref = time.perf_counter() - t0
    check = integrate(system, eps, Theta0, t_out, t0=0.0, rtol=10 * ref_rtol)
    if not (ref.success and check.success):
        raise RuntimeError(ref.message + check.message)
    m_ref, v_ref = moments(system, ref.Theta)
    m_c, v_c = moments(system, check.Theta)
    print(f"{name}: N = {system.N}, P = {system.P}, T = {T}, {n_out} output times; reference "
          f"integrate(rtol={ref_rtol:g}) in {t_ref:.1f} s, its distance to rtol="
          f"{10 * ref_rtol:g}: mean {rel_err(m_c, m_ref):.1e}, variance "
          f"{rel_err(v_c, v_ref):.1e}")  # fmt: skip

    def fixed(scheme, n):
        t0 = time.perf_counter()
        tr = march(system, eps, Theta0, T / n, n, scheme=scheme, tol=1e-12)
        sec = time.perf_counter() - t0
        if not tr.success:
            raise RuntimeError(tr.message)
        idx = np.rint(t_out / (T / n)).astype(int)
        m, v = moments(system, tr.Theta[idx])
        return sec, rel_err(m, m_ref), rel_err(v, v_ref)

    print(f"  {'method':34s} {'mean err':>9s} {'var err':>9s} {'time [s]':>9s}")
    results = {}
    for scheme, counts in (("euler", be_steps), ("bdf2", bdf2_steps)):
        for n in counts:
            sec, em, ev = fixed(scheme, n)
            results[(scheme, n)] = (sec, em, ev)
            print(f"  {scheme + f', {n} steps':34s} {em:9.1e} {ev:9.1e} {sec:9.2f}")
    for rtol in rtols:
        t0 = time.perf_counter()
        tr = integrate(system, eps, Theta0, t_out, t0=0.0, rtol=rtol)
        sec = time.perf_counter() - t0
        m, v = moments(system, tr.Theta)
        em, ev = rel_err(m, m_ref), rel_err(v, v_ref)
        results[("integrate", rtol)] = (sec, em, ev)
        label = f"integrate rtol={rtol:g} ({tr.stats['n_steps']} steps)"
        print(f"  {label:34s} {em:9.1e} {ev:9.1e} {sec:9.2f}")
    # backward Euler: extrapolate the step count reaching the target (first order)
    n1, n2 = be_steps[-2], be_steps[-1]
    e1 = max(results[("euler", n1)][1:])
    e2 = max(results[("euler", n2)][1:])
    order = np.log(e1 / e2) / np.log(n2 / n1)
    n_need = n2 * (e2 / target) ** (1.0 / order)
    be_time = results[("euler", n2)][0] / n2 * n_need
    print(f"  backward Euler: observed order {order:.2f}; {target:g} needs ~{n_need:.3g} steps, "
          f"~{be_time:.3g} s (extrapolated from the measured time per step)")  # fmt: skip
    ok = [(k, r[0]) for k, r in results.items() if k[0] != "euler" and max(r[1:]) <= target]
    if not ok:
        print(f"  no new setting reached {target:g}: refine the lists")
        return np.nan, be_time
    best = min(ok, key=lambda kr: kr[1])
    print(f"  cheapest at {target:g}: {best[0][0]} {best[0][1]:g} in {best[1]:.2f} s; "
          f"time ratio to backward Euler {best[1] / be_time:.2e}")  # fmt: skip
    b2 = [k for k in results if k[0] == "bdf2"]
    if len(b2) >= 2:
        (_, na), (_, nb) = b2[-2], b2[-1]
        ea, eb = max(results[b2[-2]][1:]), max(results[b2[-1]][1:])
        print(f"  BDF2 observed order {np.log(ea / eb) / np.log(nb / na):.2f}")
    return best[1], be_time


def fe_model(args):
    from transient import build  # benchmarks/transient.py (same folder)

    _fem, _M, system = build(args.cells)
    eps, Theta0 = np.zeros(system.n_eps), np.zeros(system.shape)
    return compare("transient FE model", system, eps, Theta0, args.T, args.n_out, args.target,
                   (50, 100, 200), (100, 400, 1600), (1e-8, 1e-9, 1e-10), 1e-12)  # fmt: skip


def burgers(args):
    model = BurgersModel(n_modes=32, n_steps=10, T=1.0, viscosity_chaos=ChaosBasis(3),
                         viscosity_spread=0.4)  # fmt: skip
    eps = np.array([1.6, 1.0])
    return compare("Burgers, random viscosity", model.system, eps, model.Theta0, 1.0, 10,
                   args.target, (100, 200, 400), (100, 400), (1e-8, 1e-9, 1e-10),
                   1e-12)  # fmt: skip


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=15)
    ap.add_argument("--T", type=float, default=0.1)
    ap.add_argument("--n-out", type=int, default=10)
    ap.add_argument("--target", type=float, default=1e-6)
    ap.add_argument("--skip", nargs="*", default=[], choices=["tutorial", "fe", "burgers"])
    args = ap.parse_args()
    if "tutorial" not in args.skip:
        tutorial()
        print()
    if "burgers" not in args.skip:
        burgers(args)
        print()
    if "fe" not in args.skip:
        new, be = fe_model(args)
        print(f"time integration: best/backward-Euler time ratio on the FE model: {new / be:.3g}")


if __name__ == "__main__":
    main()
