"""Benchmark: exact E[Psi_i Psi_j Psi_k] from ecfm_uq.chaos against chaospy's E(outer(...)) route.

Both sides run in this process tree in one invocation, after a warm-up (numba compile for
ours). For each case we report

- our time (median of many repeats of ``expectation_tensor(basis, 3)``, basis prebuilt);
- chaospy's time with a cold moment cache (a fresh distribution, as a user computing the
  tensor once pays it) and with a warm cache (the same distribution again, a lower bound);
- the max abs error of each side against the exact tensor (Adams-Neumann in rational
  arithmetic; the multivariate tensor is the product of exact 1-D entries).

chaospy runs in a child process with a time budget, so a case that is too slow or that
chaospy cannot represent is reported as skipped/failed rather than hanging the run.

chaospy route: ``P = chaospy.generate_expansion(order, dist, normed=True)`` and
``chaospy.E(chaospy.outer(P, chaospy.outer(P, P)), dist)``. (``chaospy.outer(P, P, P)``
does not work in chaospy 4.3: numpoly's ``outer`` takes two operands and treats the third
as ``out``.) For the 3-variable case the single call would hold P^3 polynomials of degree
3 p at once (several GB at P = 84), so the same product is formed and averaged one row
``P[i] * outer(P, P)`` at a time; that is also faster than the single call.

A second table does the same for the other Askey germs at 1-D orders 5 and 10:
Hermite (normal; ours: closed form), Laguerre (gamma, shape 2.5) and Jacobi (beta(2, 3));
ours from the Jacobi matrix), against chaospy's route on ``chaospy.Normal(0, 1)``,
``chaospy.Gamma(2.5)`` and ``chaospy.Beta(2, 3)``; exact values from Gram-Schmidt on the
germ's moments in rational arithmetic. Its summary line gives the smallest warm-cache
ratio over the three germs at order 10.

The last line printed is ``tensors speedup: <float>x``: chaospy's warm-cache time over
ours at 1-D order 20 (the conservative ratio; the cold-cache ratio is in the table).
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import math
import multiprocessing as mp
import os
import platform
import statistics
import sys
import time
from fractions import Fraction

import numpy as np

from ecfm_uq.chaos import ChaosBasis, Germ, expectation_tensor

HEADLINE_ORDER = 20
ASKEY = {
    "hermite": Germ("hermite"),
    "laguerre": Germ("laguerre", shape=2.5),
    "jacobi": Germ("jacobi", a=2.0, b=3.0),
}
ASKEY_ORDER = 10


def exact_table_1d(p):
    """Orthonormal E[L_i L_j L_k], i, j, k <= p, from Adams-Neumann in exact arithmetic."""
    f = math.factorial
    t = np.zeros((p + 1,) * 3)
    for i, j, k in itertools.combinations_with_replacement(range(p + 1), 3):
        if (i + j + k) % 2 or k > i + j:
            continue
        s = (i + j + k) // 2
        v = Fraction(f(2 * s - 2 * i) * f(2 * s - 2 * j) * f(2 * s - 2 * k), f(2 * s + 1))
        v *= Fraction(f(s), f(s - i) * f(s - j) * f(s - k)) ** 2
        val = float(v) * math.sqrt((2 * i + 1) * (2 * j + 1) * (2 * k + 1))
        for perm in set(itertools.permutations((i, j, k))):
            t[perm] = val
    return t


def exact_tensor(basis):
    t = exact_table_1d(basis.order)
    a = basis.indices
    T = np.ones((basis.size,) * 3)
    for d in range(basis.dim):
        T *= t[np.ix_(a[:, d], a[:, d], a[:, d])]
    return T


def exact_askey_table(germ, p):
    """Orthonormal E[psi_i psi_j psi_k] by Gram-Schmidt on the germ's exact moments."""
    n_mom = 3 * p + 1
    if germ.family == "hermite":
        mom = [Fraction(0) if m % 2 else Fraction(math.prod(range(1, m, 2))) for m in range(n_mom)]
    elif germ.family == "laguerre":
        k = Fraction(germ.params[0])
        mom = [math.prod((k + r for r in range(m)), start=Fraction(1)) for m in range(n_mom)]
    else:
        a, b = (Fraction(v) for v in germ.params)
        mom = [
            math.prod(((a + r) / (a + b + r) for r in range(m)), start=Fraction(1))
            for m in range(n_mom)
        ]

    def mul(f, g):
        out = [Fraction(0)] * (len(f) + len(g) - 1)
        for i, fi in enumerate(f):
            for j, gj in enumerate(g):
                out[i + j] += fi * gj
        return out

    def expect(f):
        return sum(c * mom[m] for m, c in enumerate(f))

    polys, norms = [], []
    for n in range(p + 1):
        f = [Fraction(0)] * n + [Fraction(1)]
        for q, h in zip(polys, norms, strict=True):
            c = expect(mul(f, q)) / h
            f = [fi - c * (q[i] if i < len(q) else 0) for i, fi in enumerate(f)]
        polys.append(f)
        norms.append(expect(mul(f, f)))
    t = np.zeros((p + 1,) * 3)
    for i, j, k in itertools.combinations_with_replacement(range(p + 1), 3):
        e = expect(mul(mul(polys[i], polys[j]), polys[k]))
        val = float(e) / math.sqrt(float(norms[i] * norms[j] * norms[k]))
        for perm in set(itertools.permutations((i, j, k))):
            t[perm] = val
    return t


def time_ours(basis, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        T = expectation_tensor(basis, 3)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), T


def _chaospy_child(order, dim, rowwise, repeats, queue, family="legendre"):
    """Child process: time chaospy cold and warm, send back times, tensor and term values."""
    try:
        import chaospy

        def make_dist():
            if family == "hermite":
                return chaospy.Normal(0, 1)
            if family == "laguerre":
                return chaospy.Gamma(ASKEY["laguerre"].params[0])
            if family == "jacobi":
                return chaospy.Beta(*ASKEY["jacobi"].params)
            if dim == 1:
                return chaospy.Uniform(0, 1)
            return chaospy.J(*[chaospy.Uniform(0, 1) for _ in range(dim)])

        def tensor(P, dist):
            if rowwise:
                PP = chaospy.outer(P, P)
                return np.stack([chaospy.E(P[i] * PP, dist) for i in range(len(P))])
            return chaospy.E(chaospy.outer(P, chaospy.outer(P, P)), dist)

        # Warm up chaospy's own code paths on a tiny case.
        small = make_dist()
        tensor(chaospy.generate_expansion(1, small, normed=True), small)

        cold, warm = [], []
        for _ in range(repeats):
            dist = make_dist()
            P = chaospy.generate_expansion(order, dist, normed=True)
            t0 = time.perf_counter()
            T = tensor(P, dist)
            cold.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            tensor(P, dist)
            warm.append(time.perf_counter() - t0)
        n = len(P)
        omega = np.random.default_rng(0).random((4 * n, dim))
        if family != "legendre":
            omega = ASKEY[family].ppf(omega)
        values = np.asarray(P(*omega.T), dtype=float).reshape(n, -1).T
        queue.put(("ok", cold, warm, np.asarray(T, dtype=float).reshape(n, n, n), omega, values))
    except Exception as e:  # reported in the table, never raised
        queue.put(("failed", f"{type(e).__name__}: {str(e)[:60]}"))


def run_chaospy(order, dim, rowwise, repeats, budget, family="legendre"):
    """Run the chaospy route in a child process; give up after ``budget`` seconds."""
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    proc = ctx.Process(target=_chaospy_child, args=(order, dim, rowwise, repeats, queue, family))
    proc.start()
    try:
        msg = queue.get(timeout=budget)
    except Exception:
        msg = ("skipped", f"> {budget:.0f} s time budget")
    finally:
        if proc.is_alive():
            proc.terminate()
        proc.join()
    return msg


def match_terms(basis, omega, values):
    """Permutation perm with chaospy term k == our term perm[k] (order/sign are conventions)."""
    ours = basis.evaluate(omega)
    perm = []
    for k in range(basis.size):
        err = np.abs(ours - values[:, [k]]).max(axis=0)
        perm.append(int(err.argmin()))
    if sorted(perm) != list(range(basis.size)):
        raise RuntimeError("could not match chaospy's terms to ours")
    return np.array(perm)


def run_askey(ours_repeats, cp_repeats, budget, header):
    """The table for Hermite, Laguerre and Jacobi germs; returns the smallest order-10 ratio."""
    for germ in ASKEY.values():
        expectation_tensor(ChaosBasis(2, germ=germ), 3)  # compile / load the kernels
    print()
    print(header.replace("case          ", "germ, order   "))
    print("-" * len(header))
    ratios = []
    for family, germ in ASKEY.items():
        for order in (5, ASKEY_ORDER):
            basis = ChaosBasis(order, germ=germ)
            t_ours, T = time_ours(basis, ours_repeats)
            exact = exact_askey_table(germ, order)
            ours_err = np.abs(T - exact).max()
            msg = run_chaospy(order, 1, False, cp_repeats, budget, family)
            row = f"{family[:8] + ' p=' + str(order):<14}{basis.size:>5}{1e3 * t_ours:>11.3f}"
            if msg[0] == "ok":
                _, cold, warm, T_cp, _, _ = msg
                cp_err = np.abs(T_cp - exact).max()
                c, w = statistics.median(cold), statistics.median(warm)
                row += f"{c:>18.4f}{w:>18.4f}{c / t_ours:>10.0f}x{w / t_ours:>10.0f}x"
                row += f"{cp_err:>13.1e}{ours_err:>10.1e}"
                if order == ASKEY_ORDER:
                    ratios.append(w / t_ours)
            else:
                row += f"{'--':>18}{'--':>18}{'--':>11}{'--':>11}{'--':>13}{ours_err:>10.1e}"
            print(row, flush=True)
    return min(ratios) if len(ratios) == len(ASKEY) else None


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick",
        action="store_true",
        help="orders 5, 10, 20 and a 3-variable order-4 basis, one chaospy repeat",
    )
    parser.add_argument(
        "--budget",
        type=float,
        default=None,
        help="seconds allowed for chaospy per 1-D case (default 60; the 3-variable case "
        "gets 10x that)",
    )
    args = parser.parse_args(argv)

    if args.quick:
        cases = [(5, 1), (10, 1), (20, 1), (4, 3)]
        ours_repeats, cp_repeats = 15, 1
    else:
        cases = [(5, 1), (10, 1), (20, 1), (40, 1), (6, 3)]
        ours_repeats, cp_repeats = 51, 3
    budget = 60.0 if args.budget is None else args.budget

    import chaospy
    import numba

    print(f"# E[Psi_i Psi_j Psi_k]: ecfm_uq.chaos vs chaospy {chaospy.__version__}")
    print(
        f"# {datetime.date.today().isoformat()}  {platform.machine()} {os.cpu_count()} cores  "
        f"python {platform.python_version()}  numpy {np.__version__}  numba {numba.__version__}"
    )
    t0 = time.perf_counter()
    expectation_tensor(ChaosBasis(2), 3)
    expectation_tensor(ChaosBasis(2, dim=3), 3)
    print(f"# warm-up (numba compile or cache load): {time.perf_counter() - t0:.2f} s")

    header = (
        f"{'case':<14}{'P':>5}{'ours [ms]':>11}{'chaospy cold [s]':>18}{'chaospy warm [s]':>18}"
        f"{'cold/ours':>11}{'warm/ours':>11}{'chaospy err':>13}{'ours err':>10}"
    )
    print(header)
    print("-" * len(header))
    headline = None
    notes = []
    for order, dim in cases:
        basis = ChaosBasis(order, dim=dim)
        t_ours, T = time_ours(basis, ours_repeats)
        exact = exact_tensor(basis)
        ours_err = np.abs(T - exact).max()
        rowwise = dim > 1
        repeats = 1 if dim > 1 else cp_repeats
        msg = run_chaospy(order, dim, rowwise, repeats, budget * (10 if dim > 1 else 1))
        name = f"1-D p={order}" if dim == 1 else f"{dim}-var p={order}"
        row = f"{name:<14}{basis.size:>5}{1e3 * t_ours:>11.3f}"
        if msg[0] == "ok":
            _, cold, warm, T_cp, omega, values = msg
            perm = np.arange(basis.size) if dim == 1 else match_terms(basis, omega, values)
            cp_err = np.abs(T_cp - exact[np.ix_(perm, perm, perm)]).max()
            c, w = statistics.median(cold), statistics.median(warm)
            row += f"{c:>18.4f}{w:>18.4f}{c / t_ours:>10.0f}x{w / t_ours:>10.0f}x"
            row += f"{cp_err:>13.1e}{ours_err:>10.1e}"
            if dim == 1 and order == HEADLINE_ORDER:
                headline = w / t_ours
        else:
            row += f"{'--':>18}{'--':>18}{'--':>11}{'--':>11}{'--':>13}{ours_err:>10.1e}"
            notes.append(f"# {name}: chaospy {msg[0]} ({msg[1]})")
        print(row, flush=True)
    for note in notes:
        print(note)
    print(
        "# err = max |T - T_exact| over all entries; chaospy's E() works from raw moments. "
        "Speedup below = warm-cache chaospy / ours at 1-D order 20."
    )
    askey = run_askey(ours_repeats, cp_repeats, budget, header)
    if askey is not None:
        print(
            f"# Askey germs at 1-D order {ASKEY_ORDER}: smallest warm-cache speedup over "
            f"Hermite, Laguerre, Jacobi {askey:.1f}x"
        )
    if headline is None:
        print("tensors speedup: nanx")
        return 1
    print(f"tensors speedup: {headline:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
