"""Sobol indices of a black-box model by sampling (Saltelli 2010 first order, Jansen 1999
total), with confidence intervals: the independent check of a polynomial chaos
surrogate's indices."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._validation import check_int, check_level, rng_from_seed
from ..executor import evaluate_samples
from ..memory import check_allocation
from ..plotting import sobol_bars

__all__ = ["SOBOL_MIN_N", "SobolResult", "sobol_indices"]

#: the smallest base sample of :func:`sobol_indices`: below it the ratio estimators and
#: their large-sample (delta-method, bootstrap) intervals mean nothing
SOBOL_MIN_N = 32


class SobolResult(NamedTuple):
    """Sampling estimates of Sobol indices with confidence intervals.

    Attributes
    ----------
    first_order, total : (d, *output_shape) ndarray
        Saltelli (2010) first-order and Jansen (1999) total indices.
    first_order_interval, total_interval : (2, d, *output_shape) ndarray
        Lower and upper bounds of the ``level`` confidence intervals (asymptotic normal by
        the delta method, or bootstrap percentiles).
    first_order_se, total_se : (d, *output_shape) ndarray
        Their standard errors.
    variance : (*output_shape) ndarray
        The output variance (pooled over the two base samples).
    n_evaluations : int
        Model runs: ``n (d + 2)``.
    level : float
    design : str
    """

    first_order: np.ndarray
    total: np.ndarray
    first_order_interval: np.ndarray
    total_interval: np.ndarray
    first_order_se: np.ndarray
    total_se: np.ndarray
    variance: np.ndarray
    n_evaluations: int
    level: float
    design: str

    def plot(self, ax=None, names=None, component=()):
        """Bars of the first-order and total indices with their intervals as error bars.

        Parameters
        ----------
        ax : matplotlib Axes, optional
        names : sequence of str, optional
            Input names on the axis (default ``x0, x1, ...``).
        component : int or tuple
            The output component drawn (``()`` for a scalar output).

        Returns
        -------
        matplotlib Axes
        """
        ax = sobol_bars(
            self.first_order,
            self.total,
            names,
            ax,
            self.first_order_interval,
            self.total_interval,
            component,
        )
        ax.set_title(f"Sobol indices by sampling ({100 * self.level:g} % intervals)")
        return ax


def _delta_se(num, s, r):
    """Standard error of mean(num) / (mean(r) - mean(s)^2) by the delta method.

    ``num``: (n, d, m) per-row numerators; ``s``, ``r``: (n, m) per-row first and second
    moments of the pooled base outputs. The estimate is a smooth function of four row
    means, so its asymptotic variance is :math:`\\nabla g^T \\Sigma \\nabla g / n` with
    :math:`\\Sigma` their sample covariance.
    """
    n = num.shape[0]
    N, S, R = num.mean(axis=0), s.mean(axis=0), r.mean(axis=0)
    V = R - S**2
    # gradient of N / (R - S^2) in (N, S, R)
    gN, gS, gR = 1.0 / V, 2.0 * S * N / V**2, -N / V**2
    dn = num - N
    ds, dr = (s - S)[:, None, :], (r - R)[:, None, :]
    lin = gN * dn + gS * ds + gR * dr  # the influence of each row
    return np.sqrt(np.sum(lin**2, axis=0) / (n * (n - 1)))


def _bootstrap(num_S, num_T, s, r, level, n_boot, rng):
    """Percentile intervals and standard deviations of the estimators over row resamples.

    A resample's row means are multinomial counts times the rows, (B, n) @ (n, k), in
    blocks of resamples so that no (B, n, d, m) array is formed.
    """
    n, d, m = num_S.shape
    rows = np.concatenate([num_S.reshape(n, -1), num_T.reshape(n, -1), s, r], axis=1)
    block = max(1, int(2**22 // max(n, 1)))
    stats_ = []
    for start in range(0, n_boot, block):
        b = min(block, n_boot - start)
        counts = rng.multinomial(n, np.full(n, 1.0 / n), size=b).astype(float)
        M = counts @ rows / n
        NS, NT = M[:, : d * m].reshape(b, d, m), M[:, d * m : 2 * d * m].reshape(b, d, m)
        Sm, Rm = M[:, 2 * d * m : 2 * d * m + m], M[:, 2 * d * m + m :]
        V = (Rm - Sm**2)[:, None, :]
        stats_.append(np.stack([NS / V, NT / V]))
    draws = np.concatenate(stats_, axis=1)  # (2, B, d, m)
    q = [0.5 - 0.5 * level, 0.5 + 0.5 * level]
    lo_hi = np.quantile(draws, q, axis=1)  # (2 quantiles, 2 estimators, d, m)
    sd = draws.std(axis=1, ddof=1)
    return (lo_hi[:, 0], sd[0]), (lo_hi[:, 1], sd[1])


def sobol_indices(
    model,
    inputs,
    n,
    *,
    seed,
    level=0.95,
    design="sobol",
    executor=None,
    workers=1,
    chunksize=None,
    vectorized=False,
    interval="asymptotic",
    n_bootstrap=1000,
    germ=False,
):
    """First-order and total Sobol indices of a model by sampling, with confidence intervals.

    Two independent base samples :math:`A, B` of n points each and, for each input i,
    the matrix :math:`A_B^{(i)}` (A with column i taken from B) give, with
    :math:`f_A = f(A)` etc. (Saltelli et al. 2010, Table 2, estimators (b) and (f)):

    .. math::
        S_i = \\frac{\\tfrac1n\\sum_j f_B(f_{A_B^{(i)}} - f_A)}{V}, \\qquad
        T_i = \\frac{\\tfrac1{2n}\\sum_j (f_A - f_{A_B^{(i)}})^2}{V},

    the total index being Jansen's (1999) estimator, and :math:`V` the variance of the
    pooled :math:`f_A, f_B`. The model runs :math:`n(d + 2)` times. The intervals are
    asymptotic normal ones (delta method on the row means); on a scrambled Sobol'
    design the errors are usually smaller than these iid-based intervals say.

    Parameters
    ----------
    model : callable
        ``model(x) -> array_like`` of a fixed shape, ``x`` a (d,) point on the inputs'
        own ranges (as :func:`ecfm_uq.chaos.fit_pce` calls it); picklable for worker
        processes.
    inputs : bounds, Inputs or distributions
        As in :func:`~ecfm_uq.chaos.fit_pce`; independent inputs, or dependent ones
        with ``germ=True``.
    n : int
        Base sample size (a power of 2 for ``design="sobol"``), at least ``SOBOL_MIN_N``
        (32).
    seed : int or numpy.random.Generator
        Required: the estimate is random (a scrambled sequence or random draws).
    level : float
        Confidence level of the intervals, in (0, 1).
    design : {"sobol", "random"}
        Scrambled Sobol' points of dimension 2d (``scipy.stats.qmc.Sobol``: the first d
        coordinates make A, the last d make B) or independent uniforms.
    executor : object with ``map``, optional
        As in :func:`monte_carlo` (a ``ThreadPoolExecutor``, ``ProcessPoolExecutor`` or
        ``dask.distributed.Client``); the model is called in batches of points, one
        batch per task.
    workers : int
        Processes of a pool created here when no ``executor`` is given (1: in-process).
    chunksize : int, optional
        Points per task.
    vectorized : bool
        ``model(X)`` takes a (k, d) array of points and returns (k, *output_shape): one
        call per task instead of one per point.
    interval : {"asymptotic", "bootstrap"}
        ``"asymptotic"``: normal intervals from the delta method; ``"bootstrap"``:
        percentile intervals of ``n_bootstrap`` resamples of the n rows (as SALib), the
        standard errors then the resamples' standard deviations. No model runs are added.
    n_bootstrap : int
        Resamples of the bootstrap.
    germ : bool
        ``True``: the indices of the independent germ components :math:`\\xi_k` the
        inputs are drawn from (``inputs.from_germ``), one per germ variable. For
        independent inputs these are the inputs' own indices. For dependent inputs they
        are not indices of the inputs (correlated inputs have no unique variance split):
        under a Gaussian copula :math:`z = L\\xi` with :math:`L` the Cholesky factor of the
        correlation in input order, so :math:`\\xi_1` carries all of the first input and
        :math:`\\xi_k` the part of input :math:`k` not explained by inputs :math:`1..k-1`
        (the order matters); for :class:`~ecfm_uq.chaos.StudentInputs` (e.g.
        ``result.uncertainty.to_inputs("t")``) there is one more component, the shared
        scale. ``False`` (default): dependent inputs are refused.

    Returns
    -------
    SobolResult

    Raises
    ------
    ValueError
        ``n`` not a power of 2 with ``design="sobol"`` or below ``SOBOL_MIN_N``, ``level``
        outside (0, 1), dependent inputs, an input without finite mean or variance, an
        output of zero variance, non-finite outputs.
    TypeError, IndexError, ...
        An exception of ``model``, as its own type, naming the point it was called at
        (the original chained).
    MemoryBudgetError
        The points and outputs held at once (A, B and one :math:`A_B^{(i)}`: 3n rows)
        exceed the memory budget (:mod:`ecfm_uq.memory`).

    Examples
    --------
    >>> import numpy as np
    >>> res = sobol_indices(lambda x: x[0] + 2 * x[1], [(0, 1), (0, 1)], 1024, seed=0)
    >>> np.round(res.first_order, 2).tolist()
    [0.2, 0.8]
    """
    from concurrent.futures import ProcessPoolExecutor

    from scipy import special
    from scipy.stats import qmc

    from ..chaos.inputs import as_inputs, check_moments

    if not callable(model):
        raise TypeError(f"`model` must be callable model(x), got {type(model).__name__}")
    inputs = as_inputs(inputs)
    if inputs is None:
        raise TypeError("`inputs` must be given: bounds (d, 2), Inputs or distributions")
    check_moments(inputs, "sobol_indices")
    if not isinstance(germ, bool):
        raise TypeError(f"`germ` must be True or False, got {germ!r}")
    if getattr(inputs, "dependent", False) and not germ:
        raise ValueError(
            "Sobol indices are not defined for dependent `inputs` (a Gaussian copula): the "
            "variance has no unique split among correlated inputs; pass independent inputs, "
            "or germ=True for the indices of the independent germ components (see the "
            "docstring for what they mean)"
        )
    n = check_int("n", n, minimum=1)
    if n < SOBOL_MIN_N:
        raise ValueError(
            f"`n` = {n} is too small for Sobol indices: the estimators are ratios of sample "
            f"means and their intervals are large-sample ones; pass n >= {SOBOL_MIN_N} (a "
            "power of 2, e.g. 1024; the model runs n (d + 2) times)"
        )
    if isinstance(design, str) and design == "sobol" and n & (n - 1):
        raise ValueError(
            f"`n` must be a power of 2 for design='sobol' (got {n}; the Sobol' points are "
            f"balanced only then): pass n={1 << (n - 1).bit_length()} or design='random'"
        )
    if design not in ("sobol", "random"):
        raise ValueError(f"`design` must be 'sobol' or 'random', got {design!r}")
    level = check_level("level", level)
    if interval not in ("asymptotic", "bootstrap"):
        raise ValueError(f"`interval` must be 'asymptotic' or 'bootstrap', got {interval!r}")
    n_bootstrap = check_int("n_bootstrap", n_bootstrap, minimum=10)
    workers = check_int("workers", workers, minimum=1)
    d = inputs.dim
    check_allocation(
        8.0 * 3 * n * d * 2,
        f"the points of a Sobol-index sample (3 x {n} points of {d} inputs)",
        "pass a smaller `n`",
    )
    rng = rng_from_seed("seed", seed)
    if design == "sobol":
        u = qmc.Sobol(2 * d, scramble=True, rng=rng).random(n)
    else:
        u = rng.random((n, 2 * d))
    # germ values of the uniforms, away from 0 and 1 for germs with unbounded support
    u = np.clip(u, np.finfo(float).tiny, 1.0 - np.finfo(float).epsneg)
    omega = np.empty_like(u)
    for k in range(2 * d):
        g = inputs.germs[k % d]
        omega[:, k] = u[:, k] if g.family == "legendre" else g.ppf(u[:, k])
    A, B = omega[:, :d], omega[:, d:]

    own_pool = executor is None and workers > 1
    pool = ProcessPoolExecutor(max_workers=workers) if own_pool else executor

    def run(points):
        x = inputs.from_germ(points)
        return evaluate_samples(
            model,
            x,
            pool,
            workers=workers,
            chunksize=chunksize,
            name="model",
            check=check,
            vectorized=vectorized,
        )

    def check(n_rows, shape):
        # held at once: f_A, f_B, one f_AB and the per-row numerators of the d inputs
        m = math.prod(shape)
        check_allocation(
            8.0 * n * m * (3 + 2 * d + 2),
            f"the outputs of a Sobol-index sample ({n} rows of a {m}-value output, {d} inputs)",
            "pass a smaller `n`, or let the model return fewer output values",
        )

    try:
        fA = run(A)
        shape = fA.shape[1:]
        fA = fA.reshape(n, -1)
        fB = run(B).reshape(n, -1)
        m = fA.shape[1]
        num_S = np.empty((n, d, m))
        num_T = np.empty((n, d, m))
        for i in range(d):
            ABi = A.copy()
            ABi[:, i] = B[:, i]
            fAB = run(ABi).reshape(n, m)
            num_S[:, i] = fB * (fAB - fA)
            num_T[:, i] = 0.5 * (fA - fAB) ** 2
    finally:
        if own_pool:
            pool.shutdown(wait=True, cancel_futures=True)
    s = 0.5 * (fA + fB)
    r = 0.5 * (fA**2 + fB**2)
    V = r.mean(axis=0) - s.mean(axis=0) ** 2
    if np.any(V <= 1e-28 * np.maximum(r.mean(axis=0), np.finfo(float).tiny)):
        j = int(np.argmax(V <= 1e-28 * np.maximum(r.mean(axis=0), np.finfo(float).tiny)))
        raise ValueError(
            f"output component {j} has zero variance over the sample: its Sobol indices "
            "are undefined"
        )
    S = num_S.mean(axis=0) / V
    T = num_T.mean(axis=0) / V
    if interval == "asymptotic":
        se_S, se_T = _delta_se(num_S, s, r), _delta_se(num_T, s, r)
        z = float(special.ndtri(0.5 + 0.5 * level))
        int_S = np.stack([S - z * se_S, S + z * se_S])
        int_T = np.stack([T - z * se_T, T + z * se_T])
    else:
        (int_S, se_S), (int_T, se_T) = _bootstrap(num_S, num_T, s, r, level, n_bootstrap, rng)

    def out(a):
        return a.reshape((*a.shape[:-1], *shape))

    return SobolResult(
        first_order=out(S),
        total=out(T),
        first_order_interval=out(int_S),
        total_interval=out(int_T),
        first_order_se=out(se_S),
        total_se=out(se_T),
        variance=V.reshape(shape),
        n_evaluations=n * (d + 2),
        level=float(level),
        design=design,
    )
