"""Empirical coverage of the delta-method intervals over synthetic data sets."""

from __future__ import annotations

import numpy as np

from ..system import solve_steady
from .steady import fit_steady


def steady_coverage(
    system,
    M_obs,
    true_eps,
    sigma,
    n_datasets=200,
    seed=0,
    formulation="standard",
    known_sigma=False,
):
    """Coverage of the 95% intervals of :func:`fit_steady` on ``n_datasets`` noisy data sets.

    Parameters
    ----------
    system : GalerkinSystem
    M_obs : (C, N) ndarray
    true_eps : (n_eps,) array_like
    sigma : float
        Gaussian sensor noise standard deviation.
    n_datasets : int
    seed : int
    formulation : {"standard", "ecfm"}
    known_sigma : bool
        Pass ``sigma`` to the fit (otherwise it is estimated from the residual).

    Returns
    -------
    dict
        ``coverage`` (fraction, all parameters pooled), ``mean_width``, ``n_failed``.
    """
    if int(n_datasets) < 1:
        raise ValueError(f"`n_datasets` must be a positive integer, got {n_datasets}")
    if not sigma > 0:
        raise ValueError(f"`sigma` must be positive, got {sigma}")
    true_eps = np.asarray(true_eps, dtype=float)
    v0 = M_obs @ system.mean(solve_steady(system, true_eps).Theta)
    rng = np.random.default_rng(seed)
    hits, widths, failed = [], [], 0
    for _ in range(int(n_datasets)):
        v = v0 + sigma * rng.normal(size=v0.size)
        res = fit_steady(
            system, M_obs, v, true_eps, formulation, sigma=sigma if known_sigma else None
        )
        if not res.success or res.eps_ci95 is None:
            failed += 1
            continue
        ci = res.eps_ci95
        hits.extend((ci[:, 0] <= true_eps) & (true_eps <= ci[:, 1]))
        widths.extend(ci[:, 1] - ci[:, 0])
    return {
        "coverage": float(np.mean(hits)) if hits else float("nan"),
        "mean_width": float(np.mean(widths)) if widths else float("nan"),
        "n_failed": failed,
    }
