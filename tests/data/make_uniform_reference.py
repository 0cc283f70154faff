"""Write tests/data/uniform_reference.npz: today's results on uniform inputs.

Run from the main checkout *before* a change to the chaos layer, e.g.

    PYTHONPATH=/work/main python tests/data/make_uniform_reference.py

``tests/chaos/test_uniform_reference.py`` then checks that the changed code reproduces
every array to round-off (see that test for the tolerances and why).
"""

from __future__ import annotations

import pathlib

import numpy as np


def ishigami(x):
    return np.sin(x[0]) + 7.0 * np.sin(x[1]) ** 2 + 0.1 * x[2] ** 4 * np.sin(x[0])


def vector_model(x):
    return np.array([x[0] + x[1] ** 2, np.exp(0.3 * x[0]) * x[1]])


FITS = {
    "quadrature": dict(method="quadrature", order=4),
    "smolyak_gauss": dict(method="smolyak", order=4, options={"rule": "gauss"}),
    "smolyak_cc": dict(method="smolyak", order=3, options={"rule": "clenshaw-curtis"}),
    "lstsq": dict(method="lstsq", order=3, n_samples=60, seed=3),
    "lstsq_sobol": dict(method="lstsq", order=3, n_samples=64, options={"design": "sobol"}, seed=4),
    # q_norm=1.0: the fixed total-degree candidates that were the sparse default up to
    # v0.3 (the default is now the q-adaptive truncation, which selects other terms)
    "lars": dict(method="lars", n_samples=120, seed=5, options={"q_norm": 1.0}),
    "omp": dict(method="omp", n_samples=120, seed=6, options={"q_norm": 1.0}),
}


def reference():
    from ecfm_uq.chaos import ChaosBasis, expectation_tensor, fit_pce, weighted_gram
    from ecfm_uq.mc import pseudospectral_projection, quadrature_moments

    out = {}
    bounds = [(-np.pi, np.pi)] * 3
    for name, kw in FITS.items():
        pce = fit_pce(ishigami, bounds, **kw)
        out[f"{name}/coefficients"] = pce.coefficients
        out[f"{name}/indices"] = np.asarray(pce.basis.indices)
        out[f"{name}/mean"] = np.asarray(pce.mean)
        out[f"{name}/variance"] = np.asarray(pce.variance)
        out[f"{name}/first_order"] = pce.first_order()
        out[f"{name}/total"] = pce.total()
        out[f"{name}/sample"] = pce.sample(50, seed=1)
        out[f"{name}/call"] = pce(np.array([[0.1, -1.0, 2.0], [3.0, 0.5, -2.5]]))
    vec = fit_pce(
        vector_model,
        [(0.0, 1.0), (-1.0, 2.0)],
        method="lars",
        n_samples=80,
        seed=7,
        options={"q_norm": 1.0},
    )
    out["vector_lars/coefficients"] = vec.coefficients
    out["vector_lars/first_order"] = vec.first_order()
    out["vector_lars/covariance"] = vec.covariance
    out["vector_lars/quantile"] = vec.quantile([0.1, 0.9], n_samples=2000, seed=2)
    for normalized in (True, False):
        b = ChaosBasis(3, dim=2, normalized=normalized)
        tag = "norm" if normalized else "unnorm"
        out[f"tensor_{tag}/E1"] = expectation_tensor(b, 1)
        out[f"tensor_{tag}/E2"] = expectation_tensor(b, 2)
        out[f"tensor_{tag}/E3"] = expectation_tensor(b, 3)
        out[f"tensor_{tag}/E3_sparse"] = expectation_tensor(b, 3, sparse=True).todense()
        out[f"tensor_{tag}/gram_2d"] = weighted_gram(b, lambda w: np.exp(w[:, 0] * w[:, 1]))
        b1 = ChaosBasis(4, normalized=normalized)
        out[f"tensor_{tag}/gram_1d"] = weighted_gram(b1, np.exp, n_points=9)
        out[f"tensor_{tag}/evaluate"] = b.evaluate(np.array([[0.1, 0.7], [0.95, 0.2]]))
    b = ChaosBasis(5)
    out["mc/pseudospectral"] = pseudospectral_projection(
        lambda w: np.array([np.exp(w), np.sin(3 * w)]), b
    )
    out["mc/quadrature_mean"], out["mc/quadrature_var"] = quadrature_moments(
        lambda w: np.array([np.exp(w[0] * w[1])]), 6, dim=2
    )
    return out


if __name__ == "__main__":
    path = pathlib.Path(__file__).with_name("uniform_reference.npz")
    np.savez(path, **reference())
    print(f"wrote {path}")
