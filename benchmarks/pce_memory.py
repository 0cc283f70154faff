"""Benchmark: ``fit_pce`` with its defaults on 2 000, 20 000 and 100 000 runs of an 8-input model.

The model is a smooth product of eight exponentials (a Sobol'-g-like function with
closed-form moments), on independent U(0, 1) inputs:

.. math:: f(x) = \\prod_{k=1}^{8} \\bigl(1 + a_k \\varphi(x_k)\\bigr), \\qquad
          \\varphi(x) = \\frac{e^x - (e - 1)}{\\sigma}, \\quad
          \\sigma^2 = \\frac{e^2 - 1}{2} - (e - 1)^2,

so :math:`\\mathbb E f = 1`, :math:`\\operatorname{Var} f = \\prod_k (1 + a_k^2) - 1` and the
first-order Sobol' indices are :math:`S_k = a_k^2 / \\operatorname{Var} f`.

Each size runs in its own process (``fit_pce(model, bounds, "lars", n_samples=n, seed=0)``,
one BLAS thread): wall time, peak resident memory (``VmHWM`` of that process), the chosen
candidate degree and the rule that limited it, the selection form (design or Gram), and
the errors of the mean and variance (relative) and of the first-order indices (largest
absolute) against the closed forms. Before this change the defaults at 20 000 runs sized
the candidates at degree 12 (125 970 terms, an 18.8 GiB design matrix: killed by the
operating system) and at 100 000 runs at degree 16 (735 471 terms, 548 GiB).

The last line printed is ``pce_memory: 1e5 runs <float> s, peak <float> GiB``.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

SIZES = (2_000, 20_000, 100_000)
DIM = 8
A = np.array([0.8, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.05])
SIGMA = math.sqrt((math.e**2 - 1) / 2 - (math.e - 1) ** 2)
MEAN = 1.0
VARIANCE = float(np.prod(1 + A**2) - 1)
FIRST_ORDER = A**2 / VARIANCE


def model(x):
    return float(np.prod(1.0 + A * (np.exp(x) - (math.e - 1)) / SIGMA))


def _peak_bytes():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return float("nan")


def run_one(n):
    from ecfm_uq.chaos import fit_pce

    t0 = time.perf_counter()
    pce = fit_pce(model, [(0.0, 1.0)] * DIM, "lars", n_samples=n, seed=0)
    wall = time.perf_counter() - t0
    d = pce.diagnostics
    return dict(
        n=n,
        time=wall,
        peak=_peak_bytes(),
        candidate_degree=int(d["candidate_degree"]),
        candidate_limit=d["candidate_limit"],
        selection=d["selection"],
        degree=int(d["degree"]),
        n_terms=int(d["n_terms"]),
        loo=float(d["corrected_loo_error"]),
        err_mean=abs(float(pce.mean) - MEAN) / MEAN,
        err_var=abs(float(pce.variance) - VARIANCE) / VARIANCE,
        err_S=float(np.abs(pce.first_order() - FIRST_ORDER).max()),
    )


def main(sizes=SIZES):
    rows = []
    for n in sizes:
        out = subprocess.run(
            [sys.executable, __file__, "--one", str(n)],
            check=True,
            capture_output=True,
            text=True,
        )
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    print(f"# fit_pce(method='lars') defaults, {DIM} inputs, smooth product model, one thread")
    print(
        f"{'n':>7} {'time s':>8} {'peak GiB':>9} {'cand.deg':>8} {'limit':>8} {'form':>6} "
        f"{'deg':>4} {'terms':>6} {'LOO':>8} {'err mean':>9} {'err var':>9} {'err S1':>9}"
    )
    for r in rows:
        print(
            f"{r['n']:>7} {r['time']:>8.1f} {r['peak'] / 2**30:>9.2f} "
            f"{r['candidate_degree']:>8} {r['candidate_limit']:>8} {r['selection']:>6} "
            f"{r['degree']:>4} {r['n_terms']:>6} {r['loo']:>8.1e} {r['err_mean']:>9.1e} "
            f"{r['err_var']:>9.1e} {r['err_S']:>9.1e}"
        )
    last = rows[-1]
    print(f"pce_memory: 1e5 runs {last['time']:.1f} s, peak {last['peak'] / 2**30:.2f} GiB")


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--one":
        print(json.dumps(run_one(int(sys.argv[2]))))
    elif len(sys.argv) > 1:
        main(tuple(int(a) for a in sys.argv[1:]))
    else:
        main()
