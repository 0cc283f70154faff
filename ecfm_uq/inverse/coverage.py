"""Empirical coverage of the delta-method intervals over synthetic data sets (issue 13).

A 95 % interval is honest when, over many data sets drawn from the model at known
parameters, it contains the true value in 95 % of them. :func:`steady_coverage` checks
the intervals of :func:`~ecfm_uq.inverse.fit` (steady) (Gaussian sensor noise of known
standard deviation, sigma known or estimated from the residual);
:func:`likelihood_coverage` those of the pseudo-likelihood fits
(replicated data, covariance from the replicates). With R data sets and all parameters
pooled, the empirical coverage of honest intervals lies in
:func:`binomial_band` (R n_eps, 0.95) with probability about 95 % (pooled parameters of
one data set are not independent, so the band is indicative).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from .._validation import check_int, check_positive, rng_from_seed
from ..errors import ConvergenceError
from ..system import solve_steady
from .fitting import fit
from .problems.galerkin import ReplicatedProblem, SteadyProblem
from .statistics.profile import profile_likelihood

__all__ = [
    "binomial_band",
    "discrepancy_power",
    "interval_coverage",
    "likelihood_coverage",
    "model_coverage",
    "steady_coverage",
]


def binomial_band(n, p=0.95, level=0.95):
    """Central ``level`` range of the fraction of hits among ``n`` Bernoulli(p) trials.

    Parameters
    ----------
    n : int
        Number of intervals.
    p : float
        Nominal coverage.
    level : float

    Returns
    -------
    lo, hi : float
        Fractions in [0, 1].
    """
    n = check_int("n", n, minimum=1)
    if not 0 < p < 1 or not 0 < level < 1:
        raise ValueError(f"`p` and `level` must lie in (0, 1), got p={p}, level={level}")
    a = (1 - level) / 2
    return float(stats.binom.ppf(a, n, p) / n), float(stats.binom.ppf(1 - a, n, p) / n)


def _summary(true_eps, estimates, intervals, failed):
    """Pooled coverage and width, plus the per-data-set records (for figures)."""
    if not estimates:  # a coverage of nothing is not a number to report
        raise ConvergenceError(
            f"no data set gave an interval: all {failed} fits failed or had no uncertainty"
        )
    out = {"n_failed": int(failed)}
    ci = np.array(intervals)  # (R, n_eps, 2)
    hits = (ci[..., 0] <= true_eps) & (true_eps <= ci[..., 1])
    out.update(
        coverage=float(hits.mean()),
        mean_width=float((ci[..., 1] - ci[..., 0]).mean()),
        n_intervals=int(hits.size),
        coverage_per_parameter=hits.mean(axis=0),
        eps=np.array(estimates),
        intervals=ci,
    )
    return out


def _check_common(n_datasets, seed):
    n = check_int("n_datasets", n_datasets, minimum=1)
    seed = check_int("seed", seed, minimum=0)
    return n, seed


def steady_coverage(
    system,
    M_obs,
    true_eps,
    sigma,
    n_datasets=200,
    seed=0,
    formulation="standard",
    known_sigma=False,
    eps0=None,
):
    """Coverage of the 95% intervals of the steady fits on ``n_datasets`` noisy data sets.

    Data set r is :math:`v = \\mathcal M\\,\\mathbb E[\\theta(\\epsilon_{true})] + \\sigma
    \\xi_r`, :math:`\\xi_r \\sim N(0, I)` from ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    system : GalerkinSystem
    M_obs : (C, N) ndarray
    true_eps : (n_eps,) array_like
    sigma : float
        Gaussian sensor noise standard deviation.
    n_datasets : int
        R.
    seed : int
    formulation : {"standard", "ecfm"}
    known_sigma : bool
        Pass ``sigma`` to the fit (otherwise it is estimated from the residual).
    eps0 : (n_eps,) array_like, optional
        Start of every fit (default ``true_eps``: coverage is about the intervals, not
        about the optimizer's basin).

    Returns
    -------
    dict
        ``coverage`` (fraction of intervals holding the truth, all parameters pooled),
        ``mean_width``, ``n_failed`` (fits without intervals), ``n_intervals``,
        ``coverage_per_parameter`` (n_eps,), ``eps`` (R', n_eps) and ``intervals``
        (R', n_eps, 2) of the R' successful fits.
    """
    n, seed = _check_common(n_datasets, seed)
    sigma = check_positive("sigma", sigma)
    true_eps = system.check_eps(true_eps)
    eps0 = true_eps if eps0 is None else system.check_eps(eps0)
    v0 = M_obs @ system.mean(solve_steady(system, true_eps, strict=True).Theta)
    rng = rng_from_seed("seed", seed)
    est, ints, failed = [], [], 0
    for _ in range(n):
        v = v0 + sigma * rng.normal(size=v0.size)
        problem = SteadyProblem(system, M_obs, v)
        res = fit(problem, eps0, formulation=formulation, sigma=sigma if known_sigma else None)
        if not res.success or res.uncertainty.intervals is None:
            failed += 1
            continue
        est.append(res.eps)
        ints.append(res.uncertainty.intervals)
    return _summary(true_eps, est, ints, failed)


def likelihood_coverage(
    system,
    M_obs,
    sample,
    true_eps,
    eps0,
    n_datasets=200,
    seed=0,
    formulation="standard",
    *,
    problem_options=None,
    **fit_options,
):
    """Coverage of the 95% intervals of the pseudo-likelihood fits on replicated data.

    Parameters
    ----------
    system : GalerkinSystem
        Stochastic system (with ``Gamma`` for ``"inner-outer"``).
    M_obs : (C, N) ndarray
    sample : callable ``(numpy.random.Generator) -> (C, D) ndarray``
        Draws one replicated data set at the true parameters (e.g.
        ``lambda g: model.sample_data(1.0, 25, rng=g)`` for the beam).
    true_eps : (n_eps,) array_like
    eps0 : (n_eps,) array_like
        Start of every fit.
    n_datasets : int
        R; data set r uses the generator of ``numpy.random.SeedSequence(seed).spawn(R)[r]``.
    seed : int
    formulation : {"standard", "inner-outer"}
        The penalty form has no uncertainty (no optimality condition defines it).
    problem_options : dict, optional
        Passed to :class:`~ecfm_uq.inverse.ReplicatedProblem` (e.g. ``solve_tol`` of the solves).
    **fit_options
        Passed to :func:`~ecfm_uq.inverse.fit` (``bounds``, ``options``, ...).

    Returns
    -------
    dict
        As :func:`steady_coverage`, plus ``stderr`` (R', n_eps).
    """
    n, seed = _check_common(n_datasets, seed)
    if formulation not in ("standard", "inner-outer"):
        raise ValueError(
            f"unknown `formulation` {formulation!r}; choose 'standard' or 'inner-outer' "
            "(the penalty form has no uncertainty)"
        )
    if not callable(sample):
        raise TypeError(f"`sample` must be callable sample(rng) -> (C, D) data, got {sample!r}")
    true_eps = system.check_eps(true_eps)
    est, ints, se, failed = [], [], [], 0
    for child in np.random.SeedSequence(seed).spawn(n):
        v = sample(np.random.default_rng(child))
        problem = ReplicatedProblem(system, M_obs, v, **dict(problem_options or {}))
        res = fit(problem, eps0, formulation=formulation, **fit_options)
        if not res.success or res.uncertainty.intervals is None:
            failed += 1
            continue
        est.append(res.eps)
        ints.append(res.uncertainty.intervals)
        se.append(res.uncertainty.stderr)
    out = _summary(true_eps, est, ints, failed)
    if se:
        out["stderr"] = np.array(se)
    return out


def _hits(true_eps, intervals):
    ci = np.array(intervals)  # (R, n_eps, 2)
    hits = (ci[..., 0] <= true_eps) & (true_eps <= ci[..., 1])
    width = ci[..., 1] - ci[..., 0]
    return {
        "coverage_per_parameter": hits.mean(axis=0),
        "median_width_per_parameter": np.median(width, axis=0),
        "open_per_parameter": (~np.isfinite(width)).mean(axis=0),
    }


def interval_coverage(
    problem, clean, true_eps, sigma, n_datasets=200, seed=0, formulation="standard", eps0=None,
    options=None,
):  # fmt: skip
    """Delta-method and profile-likelihood coverage of fits with ``sigma`` known.

    Data set r is ``clean + sigma * xi_r`` (``numpy.random.default_rng(seed)``); each is
    fitted by :func:`~ecfm_uq.inverse.fit` (``formulation`` ``"standard"`` or ``"ecfm-random"``,
    the random-force ECFM, with ``options``) and both intervals are computed
    (:func:`~ecfm_uq.inverse.profile_likelihood`).

    Returns
    -------
    dict
        ``delta`` (over the converged fits) and ``profile`` (over every data set: a fit
        that did not converge, e.g. an estimate running to infinity, still has a profile):
        per-parameter coverage, median width and fraction of open (infinite or bound)
        ends; ``n_failed`` fits that did not converge;
        ``n_at_bound``; ``n_not_consistent`` (the verdict at 0.05); ``eps`` (R', n_eps).
    """
    n, seed = _check_common(n_datasets, seed)
    sigma = check_positive("sigma", sigma)
    system = problem.system
    true_eps = system.check_eps(true_eps)
    eps0 = true_eps if eps0 is None else system.check_eps(eps0)
    rng = rng_from_seed("seed", seed)
    est, delta, prof, failed, rejected = [], [], [], 0, 0
    for _ in range(n):
        v = clean + sigma * rng.normal(size=clean.size)
        res = fit(problem.with_data(v), eps0, formulation=formulation, sigma=sigma,
                  options=options)  # fmt: skip
        # the profile starts from wherever the fit stopped (it re-centres on a better
        # point, and an estimate at infinity gives an open end): every data set has one
        prof.append(profile_likelihood(res).intervals)
        if not res.success or res.uncertainty.intervals is None:
            failed += 1
            continue
        est.append(res.eps)
        delta.append(res.uncertainty.intervals)
        rejected += res.verdict.consistent is False
    if not est:
        raise ConvergenceError(f"no data set gave an interval: all {failed} fits failed")
    return {
        "delta": _hits(true_eps, delta),
        "profile": _hits(true_eps, prof),
        "n_failed": failed,
        "n_not_consistent": rejected,
        "eps": np.array(est),
    }


def model_coverage(problem, clean, true_eps, sigma, n_datasets=200, seed=0, *, eps0=None,
                   bounds=None, known_sigma=True, profile=True):  # fmt: skip
    """Coverage of the intervals and size of the verdict for a :class:`ModelProblem`.

    Data set r is ``clean + sigma * xi_r`` (``numpy.random.default_rng(seed)``), fitted by
    :func:`~ecfm_uq.inverse.fit` from ``eps0`` (default the truth) within ``bounds``, with
    ``sigma`` given (``known_sigma``) or estimated; with ``profile`` its profile regions
    are computed (:func:`~ecfm_uq.inverse.profile_likelihood`: every piece of a
    parameter's range below the threshold, scanned to finite bounds).

    Returns
    -------
    dict
        ``delta`` (over the fits with standard errors) and ``regions`` (the truth inside
        any profile region) per-parameter coverage; ``n_failed`` fits not converged;
        ``n_at_bound`` estimates at a bound; ``n_not_consistent`` and ``n_no_test`` of
        the verdicts at 0.05 (``consistent`` False / None).
    """
    n, seed = _check_common(n_datasets, seed)
    sigma = check_positive("sigma", sigma)
    true_eps = np.asarray(true_eps, dtype=float)
    eps0 = true_eps if eps0 is None else np.asarray(eps0, dtype=float)
    rng = rng_from_seed("seed", seed)
    delta, inside, failed, rejected, no_test, at_bound = [], [], 0, 0, 0, 0
    for _ in range(n):
        v = clean + sigma * rng.normal(size=clean.size)
        res = fit(problem.with_data(v), eps0, sigma=sigma if known_sigma else None,
                  bounds=bounds, uncertainty=True)  # fmt: skip
        rejected += res.verdict.consistent is False
        no_test += res.verdict.consistent is None
        at_bound += bool(res.verdict.identifiability)
        if not res.success:
            failed += 1
        if res.uncertainty.intervals is not None:
            delta.append(res.uncertainty.intervals)
        if profile:
            regions = profile_likelihood(res).regions
            inside.append(
                [any(lo <= t <= hi for lo, hi in regions[j]) for j, t in enumerate(true_eps)]
            )
    out = {
        "n_failed": failed,
        "n_not_consistent": rejected,
        "n_no_test": no_test,
        "n_at_bound": at_bound,
        "n_datasets": n,
    }
    if delta:
        out["delta"] = _hits(true_eps, delta)
    if inside:
        out["regions"] = {"coverage_per_parameter": np.mean(inside, axis=0)}
    return out


def discrepancy_power(
    problem, clean_by_amplitude, sigma, eps0, n_datasets=200, seed=0, alpha=0.05, options=None
):
    """Size and power of the test "can this model explain these data?".

    For each amplitude of a physics missing from the model (``clean_by_amplitude``:
    amplitude -> noise-free readings), R noisy data sets are fitted by the random-force
    ECFM (its restricted likelihood-ratio test of tau = 0; ``options`` of the fit, e.g.
    ``{"force_prior": "sparse"}``) and the standard fit (its chi2 test); amplitude 0 gives
    the size.

    Returns
    -------
    list of dict
        Per amplitude: ``amplitude``, ``tau_test_rejects``, ``chi2_rejects`` (fractions at
        ``alpha``), ``residual_rms_over_sigma`` (median over data sets of the standard
        fit's residual root mean square in units of sigma).
    """
    n, seed = _check_common(n_datasets, seed)
    sigma = check_positive("sigma", sigma)
    rows = []
    for amplitude, clean in clean_by_amplitude.items():
        rng = rng_from_seed("seed", seed)
        tau_rej, chi_rej, rms = [], [], []
        for _ in range(n):
            v = clean + sigma * rng.normal(size=clean.size)
            res = fit(problem.with_data(v), eps0, formulation="ecfm-random", sigma=sigma, alpha=alpha,
                      options=options)  # fmt: skip
            std = res.extra["standard"]
            tau_rej.append(not res.verdict.consistent)
            chi_rej.append(not std.verdict.consistent)
            rms.append(np.sqrt(2.0 * std.loss / v.size) / sigma)
        rows.append(
            {
                "amplitude": float(amplitude),
                "tau_test_rejects": float(np.mean(tau_rej)),
                "chi2_rejects": float(np.mean(chi_rej)),
                "residual_rms_over_sigma": float(np.median(rms)),
            }
        )
    return rows
