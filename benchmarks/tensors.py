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

from ecfm_uq.chaos import ChaosBasis, expectation_tensor

HEADLINE_ORDER = 20


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


def time_ours(basis, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        T = expectation_tensor(basis, 3)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), T


def _chaospy_child(order, dim, rowwise, repeats, queue):
    """Child process: time chaospy cold and warm, send back times, tensor and term values."""
    try:
        import chaospy

        def make_dist():
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
        values = np.asarray(P(*omega.T), dtype=float).reshape(n, -1).T
        queue.put(("ok", cold, warm, np.asarray(T, dtype=float).reshape(n, n, n), omega, values))
    except Exception as e:  # reported in the table, never raised
        queue.put(("failed", f"{type(e).__name__}: {str(e)[:60]}"))


def run_chaospy(order, dim, rowwise, repeats, budget):
    """Run the chaospy route in a child process; give up after ``budget`` seconds."""
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    proc = ctx.Process(target=_chaospy_child, args=(order, dim, rowwise, repeats, queue))
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
    if headline is None:
        print("tensors speedup: nanx")
        return 1
    print(f"tensors speedup: {headline:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
