"""Benchmark: a sparse PCE of a 10 000-value field output at 300 runs (PCA-PCE).

The model is a decaying, phase-shifted profile on 10 000 points with one normal, two
uniform and one beta input (not of finite rank in the inputs; four inputs since issue 30). ``fit_pce(method="lars")``
compresses the evaluations into their leading principal components by default and selects
on those; the route it replaces, one sparse selection per output component
(``compress=False``), is timed on 100 evenly spaced components and scaled to 10 000.
Reported: wall times, the number of components kept, the largest compression error and
corrected LOO error over the field, and the largest difference of the first-order and
total indices from the per-component fits on those 100 components.

Then the same fit under a memory budget of 64 MiB (``ECFM_UQ_MEMORY_BUDGET`` would do the
same), where the exact SVD of the 300 x 10 000 evaluations (161 MiB at its peak, as
printed) is refused and the randomized SVD in blocks runs instead: its time, the peak of the arrays
it allocates during the fit (``tracemalloc``, after a warm-up fit, the evaluations
included), the components kept, the
largest compression error and the largest index difference from the exact-path fit.
And under 32 MiB, where the evaluations cannot be stored beside any SVD: compressed as
they arrive (a one-pass sketch), the same numbers.

The last line printed is ``pce_field: <float>x``: the per-component time (scaled) over
the compressed time.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from ecfm_uq.chaos import fit_pce  # noqa: E402
from ecfm_uq.chaos.regression.compression import exact_pca_bytes  # noqa: E402
from ecfm_uq.memory import format_bytes, set_memory_budget  # noqa: E402

N_FIELD = 10_000
N_RUNS = 300
S_GRID = np.linspace(0.0, 1.0, N_FIELD)
INPUTS = [stats.norm(0, 1), stats.uniform(-1, 2), stats.beta(2, 3), stats.uniform(0, 1)]
SUBSET = np.linspace(0, N_FIELD - 1, 100).astype(int)


def field(x):
    return (
        np.exp(-(1 + 0.3 * x[0]) * S_GRID)
        * (1 + 0.2 * x[1] * np.sin(2 * np.pi * S_GRID + x[2]))
        * (1 + 0.1 * x[3] * S_GRID**2)
    )


def field_subset(x):
    return field(x)[SUBSET]


def _fit_under_budget(field, budget):
    """``fit_pce`` with the memory budget set to ``budget``: (fit, seconds, peak traced
    bytes), after one warm-up fit (numba, imports)."""
    previous = set_memory_budget(budget)
    try:
        fit_pce(field, INPUTS, "lars", n_samples=N_RUNS, seed=1)
        tracemalloc.start()
        t0 = time.perf_counter()
        res = fit_pce(field, INPUTS, "lars", n_samples=N_RUNS, seed=0)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    finally:
        set_memory_budget(previous)
    # timed, untraced, and outside the small budget: the indices of all 10 000 components
    # hold about four P x 10 000 arrays (60 MiB for the 197 terms of four inputs), which a
    # user under 32 MiB would take in slices of components
    res.first_order(zero_variance=0.0), res.total(zero_variance=0.0)
    elapsed = time.perf_counter() - t0
    return res, elapsed, peak


def main():
    fit_pce(field_subset, INPUTS, "lars", n_samples=40, seed=9)  # warm-up (numba, imports)
    t0 = time.perf_counter()
    pce = fit_pce(field, INPUTS, "lars", n_samples=N_RUNS, seed=0)
    S, T = pce.first_order(zero_variance=0.0), pce.total(zero_variance=0.0)
    t_pca = time.perf_counter() - t0
    d = pce.diagnostics
    t0 = time.perf_counter()
    ref = fit_pce(field_subset, INPUTS, "lars", n_samples=N_RUNS, seed=0, compress=False)
    S_ref, T_ref = ref.first_order(), ref.total()
    t_sub = time.perf_counter() - t0
    t_full = t_sub * N_FIELD / len(SUBSET)
    diff = max(np.abs(S[:, SUBSET] - S_ref).max(), np.abs(T[:, SUBSET] - T_ref).max())
    print(f"# {N_FIELD}-value field, {N_RUNS} runs, fit_pce(method='lars'), single thread")
    print(f"compressed (default): {t_pca:8.2f} s  components kept {d['n_components']}")
    print(f"  max compression error     {d['compression_error'].max():.1e}")
    print(f"  max corrected LOO error   {d['corrected_loo_error'].max():.1e}")
    print(
        f"per component: {t_sub:8.2f} s for {len(SUBSET)} components, "
        f"{t_full:.0f} s scaled to {N_FIELD}"
    )
    print(f"max |index difference| vs per-component fits on {len(SUBSET)} components: {diff:.1e}")
    budget = 64 * 2**20
    small, t_small, peak = _fit_under_budget(field, budget)
    ds = small.diagnostics
    S_s, T_s = small.first_order(zero_variance=0.0), small.total(zero_variance=0.0)
    diff_s = max(np.abs(S_s - S).max(), np.abs(T_s - T).max())
    print(
        f"budget {format_bytes(budget)} (exact SVD needs "
        f"{format_bytes(exact_pca_bytes(N_RUNS, N_FIELD))}): compression "
        f"{ds['compression']}, {t_small:.2f} s, peak traced {format_bytes(peak)} "
        f"(evaluations {format_bytes(8 * N_RUNS * N_FIELD)}), components kept "
        f"{ds['n_components']}, max compression error {ds['compression_error'].max():.1e}, "
        f"max |index difference| vs exact {diff_s:.1e}"
    )
    # evaluations that cannot be stored even once (22.9 MiB plus any SVD over 32 MiB)
    budget = 32 * 2**20
    streamed, t_stream, peak = _fit_under_budget(field, budget)
    S_t, T_t = streamed.first_order(zero_variance=0.0), streamed.total(zero_variance=0.0)
    dt = streamed.diagnostics
    diff_t = max(np.abs(S_t - S).max(), np.abs(T_t - T).max())
    print(
        f"budget {format_bytes(budget)}: compression {dt['compression']} "
        f"(sketch {dt['compression_info']['sketch_columns']} columns), {t_stream:.2f} s, peak "
        f"traced {format_bytes(peak)}, components kept {dt['n_components']}, estimated max "
        f"compression error {dt['compression_error'].max():.1e}, max |index difference| vs "
        f"exact {diff_t:.1e}"
    )
    print(f"pce_field: {t_full / t_pca:.1f}x")


if __name__ == "__main__":
    main()
