"""Empirical coverage of the delta-method intervals over synthetic data sets.

An interval procedure is honest when, over many data sets drawn from the model at known
parameters, its 95 % intervals contain the truth 95 % of the time. These functions draw
the data sets (seeded), fit, and count; the uncertainty itself comes from the one code
path of :mod:`ecfm_uq.inverse.uncertainty`, attached to every fit result.
"""

from __future__ import annotations

import numpy as np

from .._validation import check_int
from ..system import solve_steady
from .likelihood import fit_pseudo_likelihood
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
    callback=None,
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
    callback : callable, optional
        Called after each data set (e.g. a progress bar's ``update``).

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
        failed += _count(res, true_eps, hits, widths)
        if callback is not None:
            callback(1)
    return _tally(hits, widths, failed)


def _count(res, true_eps, hits, widths):
    """Add one fit's interval hits and widths; 1 if it has no interval (failed), else 0."""
    if not res.success or res.eps_ci95 is None:
        return 1
    ci = res.eps_ci95
    hits.extend((ci[:, 0] <= true_eps) & (true_eps <= ci[:, 1]))
    widths.extend(ci[:, 1] - ci[:, 0])
    return 0


def _tally(hits, widths, failed):
    if not hits:
        raise ValueError(f"no data set gave an interval ({failed} fits failed)")
    return {
        "coverage": float(np.mean(hits)),
        "mean_width": float(np.mean(widths)),
        "n_failed": int(failed),
        "n_intervals": len(hits),
    }


def replicate_coverage(
    system,
    M_obs,
    sample_data,
    true_eps,
    eps0,
    n_datasets=200,
    seed=0,
    formulation="standard",
    fit_options=None,
    callback=None,
):
    """Coverage of :func:`fit_pseudo_likelihood`'s 95 % intervals on replicated data sets.

    Parameters
    ----------
    system : GalerkinSystem
        A stochastic system (``P >= 2``); ``Gamma`` for ``"inner-outer"``.
    M_obs : (C, N) array_like
    sample_data : callable
        ``sample_data(rng) -> (C, D)`` replicated measurements at ``true_eps`` (e.g.
        ``lambda rng: model.sample_data(1.0, 25, rng=rng)`` for the beam).
    true_eps : (n_eps,) array_like
    eps0 : (n_eps,) array_like
        Start of every fit.
    n_datasets, seed : int
        Data sets ``numpy.random.default_rng(seed)`` draws in turn.
    formulation : {"standard", "inner-outer"}
    fit_options : dict, optional
        More keyword arguments of :func:`fit_pseudo_likelihood` (``bounds``, ...).
    callback : callable, optional
        Called after each data set.

    Returns
    -------
    dict
        ``coverage`` (fraction, all parameters pooled), ``mean_width``, ``n_failed``,
        ``n_intervals``.
    """
    n_datasets = check_int("n_datasets", n_datasets, minimum=1)
    if formulation not in ("standard", "inner-outer"):
        raise ValueError(
            f"`formulation` must be 'standard' or 'inner-outer' (the penalty form has no "
            f"interval), got {formulation!r}"
        )
    true_eps = np.asarray(true_eps, dtype=float)
    rng = np.random.default_rng(seed)
    hits, widths, failed = [], [], 0
    for _ in range(n_datasets):
        v = sample_data(rng)
        res = fit_pseudo_likelihood(system, M_obs, v, eps0, formulation, **dict(fit_options or {}))
        failed += _count(res, true_eps, hits, widths)
        if callback is not None:
            callback(1)
    return _tally(hits, widths, failed)
