"""Monte Carlo and quadrature over deterministic solves, to verify the stochastic Galerkin
PCE (paper Section 3.3, Eqs. pce and stats; SPEC "Monte Carlo vs PCE verification").

The PCE gives the mean and variance of a model output in closed form (Eq. stats). Here
the same statistics are estimated non-intrusively from deterministic solves
:math:`y(\\omega)` at germ samples:

* :func:`monte_carlo` evaluates a picklable ``fn(omega)`` on caller-drawn samples through an
  executor (a local process pool by default; any object with ``map`` works, including a
  ``dask.distributed.Client``), so the numbers do not depend on where they ran;
* :func:`mc_moments` gives :math:`\\bar y`, :math:`s^2` and their standard errors
  :math:`s/\\sqrt n` and :math:`\\sqrt{(m_4 - \\tfrac{n-3}{n-1}s^4)/n}`;
* :func:`quadrature_moments` and :func:`pseudospectral_projection` are the
  high-accuracy Gauss-Legendre references (and the non-intrusive collocation PCE);
* :func:`batch_errors` and :func:`loglog_slope` measure the :math:`n^{-1/2}` decay of
  Monte Carlo errors;
* :func:`sobol_indices` estimates first-order and total Sobol indices of a black-box
  model by sampling (Saltelli 2010, Jansen 1999), with confidence intervals: the
  independent check of a polynomial chaos surrogate's indices.
"""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np

from ._validation import as_finite_array, check_int, check_level, rng_from_seed
from .executor import NonFiniteOutputError, evaluate_samples
from .memory import check_allocation

__all__ = [
    "Moments",
    "SobolResult",
    "sobol_indices",
    "batch_errors",
    "draw_germ",
    "loglog_slope",
    "mc_moments",
    "monte_carlo",
    "pseudospectral_projection",
    "quadrature_moments",
    "relative_error",
]


#: the smallest base sample of :func:`sobol_indices`: below it the ratio estimators and
#: their large-sample (delta-method, bootstrap) intervals mean nothing
SOBOL_MIN_N = 32


class Moments(NamedTuple):
    """Sample statistics of Monte Carlo outputs (each of the output's shape)."""

    mean: np.ndarray
    var: np.ndarray
    se_mean: np.ndarray
    se_var: np.ndarray


def draw_germ(n, seed=None, dim=1):
    """``n`` draws of the germ :math:`\\omega \\sim U(0,1)^{dim}` from a seeded generator.

    Parameters
    ----------
    n : int
    seed : None, int or numpy.random.Generator
    dim : int

    Returns
    -------
    (n,) ndarray for ``dim == 1``, else (n, dim)
    """
    n = check_int("n", n, minimum=1)
    dim = check_int("dim", dim, minimum=1)
    gen = rng_from_seed("seed", seed)
    return gen.random(n) if dim == 1 else gen.random((n, dim))


def monte_carlo(fn, samples, executor=None, *, workers=2, chunksize=None, callback=None):
    """Evaluate ``fn`` at each sample, in parallel, and stack the outputs.

    The executor path shared with :func:`ecfm_uq.chaos.fit_pce`
    (:func:`ecfm_uq.executor.evaluate_samples`).

    Parameters
    ----------
    fn : callable
        ``fn(sample) -> array_like`` of a fixed shape. For a process pool it must be
        picklable: a module-level function or a ``functools.partial`` of one (e.g.
        :meth:`ecfm_uq.problems.beam.BeamModel.response_function`).
    samples : (n, ...) array_like
        Germ samples, drawn by the caller from a seeded generator (:func:`draw_germ`) so
        the result does not depend on the executor.
    executor : object with ``map``, optional
        ``None``: a local ``concurrent.futures.ProcessPoolExecutor(max_workers=workers)``
        (run in-process when ``workers == 1``), created and shut down here. Otherwise any
        executor whose ``map(f, chunks)`` returns results or futures, e.g. a
        ``ThreadPoolExecutor`` or a ``dask.distributed.Client`` (whose futures are
        gathered with ``client.gather``).
    workers : int
        Worker count for the default pool and for the default chunk size.
    chunksize : int, optional
        Samples per task (default ``ceil(n / (4 workers))``).
    callback : callable, optional
        Called with the number of samples in each finished chunk (e.g. a progress bar's
        ``update``).

    Returns
    -------
    (n, ...) ndarray
        Outputs in the order of ``samples``.

    Raises
    ------
    TypeError
        ``fn`` not callable or not picklable for a process pool; ``executor`` without ``map``.
    ValueError
        Empty or non-finite samples, outputs of different shapes, or a non-finite output
        (the message gives the first offending sample).
    """
    return evaluate_samples(
        fn, samples, executor, workers=workers, chunksize=chunksize, callback=callback
    )


def mc_moments(outputs):
    """Sample mean and variance with their standard errors.

    Parameters
    ----------
    outputs : (n, ...) array_like
        ``n >= 2`` finite samples.

    Returns
    -------
    Moments
        ``mean``, ``var`` (unbiased, ddof = 1), ``se_mean`` :math:`= s/\\sqrt n` and
        ``se_var`` :math:`= \\sqrt{(m_4 - \\frac{n-3}{n-1}s^4)/n}` (the standard error of
        :math:`s^2`, with :math:`m_4` the sample fourth central moment).
    """
    y = as_finite_array("outputs", outputs)
    if y.ndim == 0 or y.shape[0] < 2:
        raise ValueError("`outputs` must hold at least 2 samples along axis 0")
    n = y.shape[0]
    check_allocation(
        8.0 * 3 * y.size,
        f"the moments of {n} samples of {y.size // n} outputs (deviations, their squares "
        "and fourth powers)",
        "pass the outputs in slices of components (mc_moments(outputs[:, idx]))",
    )
    mean = y.mean(axis=0)
    d = y - mean
    var = (d**2).sum(axis=0) / (n - 1)
    m4 = (d**4).mean(axis=0)
    se_var = np.sqrt(np.maximum(m4 - (n - 3) / (n - 1) * var**2, 0.0) / n)
    return Moments(mean, var, np.sqrt(var / n), se_var)


def _node_outputs(fn, nodes):
    """``fn`` at each Gauss node, stacked (:func:`~ecfm_uq.executor.evaluate_samples`, in
    process); a non-finite output raises (never a NaN moment).

    The first node's output sizes the (n, m) array, checked against the memory budget
    (with the two temporaries of the moments) before the other nodes run.
    """

    def check(n, shape):
        check_allocation(
            8.0 * 3 * n * math.prod(shape),
            f"the outputs of `fn` at {n} Gauss nodes ({math.prod(shape)} values each)",
            "let `fn` return only the values you need (e.g. the sensors), or fewer `n_points`",
        )  # None: the executor fills its own (n, m) array

    try:
        return evaluate_samples(fn, nodes, workers=1, name="fn", check=check)
    except NonFiniteOutputError as e:
        omega = np.array2string(np.asarray(nodes[e.index]), precision=6)
        raise ValueError(
            f"`fn` returned NaN or inf at Gauss node {e.index} (omega={omega}); "
            "check the model at that germ value"
        ) from e


def quadrature_moments(fn, n_points, dim=1):
    """Mean and variance of ``fn(omega)``, :math:`\\omega \\sim U(0,1)^d`, by Gauss-Legendre.

    Tensor-product Gauss collocation: converges exponentially for outputs analytic in
    :math:`\\omega` (the beam below buckling, diffusion with a positive random
    conductivity), so it is the high-accuracy reference for both PCE and Monte Carlo.

    Parameters
    ----------
    fn : callable
        ``fn(omega) -> (m,)``, ``omega`` a float for ``dim = 1`` and a (dim,) array else.
    n_points : int
        Nodes per variable (``n_points**dim`` model runs).
    dim : int
        Number of germ variables.

    Returns
    -------
    mean, var : (m,) ndarray

    Raises
    ------
    ValueError
        If ``fn`` returns NaN or inf at a node (the message names the node).
    """
    from .chaos import gauss_legendre
    from .chaos.quadrature import tensor_gauss_legendre

    n_points = check_int("n_points", n_points, minimum=1)
    if check_int("dim", dim, minimum=1) == 1:
        nodes, w = gauss_legendre(n_points)
    else:
        nodes, w = tensor_gauss_legendre(n_points, dim)
    y = _node_outputs(fn, nodes)
    mean = w @ y
    return mean, w @ (y - mean) ** 2


def pseudospectral_projection(fn, chaos, n_points=None):
    """Non-intrusive PCE coefficients by Gauss-Legendre projection (collocation).

    .. math:: \\Theta_{ik} = \\sum_q w_q\\, y_i(\\omega_q)\\, \\Psi_k(\\omega_q)

    With ``n_points = order + 1`` this is interpolation at the Gauss nodes, which for an
    operator affine in a single germ equals the stochastic Galerkin solution of Eq. pce.
    The projection itself is the chaos layer's one (:func:`ecfm_uq.chaos.project`, also
    behind ``fit_pce(method="quadrature")``); this function only takes a model of the
    germ in the Galerkin layout.

    Parameters
    ----------
    fn : callable
        ``fn(omega) -> (m,)`` deterministic solve.
    chaos : ChaosBasis
        One-dimensional basis.
    n_points : int, optional
        Gauss nodes (default ``chaos.order + 1``).

    Returns
    -------
    (m, P) ndarray

    Raises
    ------
    ValueError
        If ``fn`` returns NaN or inf at a node (the message names the node).
    """
    from .chaos import ChaosBasis, project

    if not isinstance(chaos, ChaosBasis) or chaos.dim != 1:
        raise TypeError("`chaos` must be a one-dimensional ChaosBasis")
    n_points = chaos.order + 1 if n_points is None else n_points
    nodes, w = chaos.quadrature(check_int("n_points", n_points, minimum=1))
    y = _node_outputs(fn, nodes[:, 0])
    return project(chaos, nodes, w, y).T  # the PCE layer's projection, as (m, P)


def relative_error(estimate, reference):
    """:math:`\\max_i |e_i - r_i| / \\max_i |r_i|` (the reference's scale, never 0/0)."""
    e = as_finite_array("estimate", estimate)
    r = as_finite_array("reference", reference)
    if e.shape != r.shape:
        raise ValueError(f"`estimate` {e.shape} and `reference` {r.shape} must have equal shapes")
    scale = np.abs(r).max()
    if scale == 0:
        raise ValueError("`reference` is identically zero; a relative error is undefined")
    return float(np.abs(e - r).max() / scale)


def batch_errors(outputs, ref_mean, ref_var, sizes):
    """Monte Carlo error of mean and variance against sample size, from one ensemble.

    For each size ``n`` the first ``B n`` outputs are split into ``B = len // n``
    disjoint batches; the error of a batch is :func:`relative_error` of its mean (and
    variance) against the reference, and the root mean square over batches is returned.

    Parameters
    ----------
    outputs : (n_total, m) array_like
    ref_mean, ref_var : (m,) array_like
    sizes : sequence of int
        Batch sizes, each in ``[2, n_total]``.

    Returns
    -------
    err_mean, err_var, n_batches : (len(sizes),) ndarray
    """
    y = as_finite_array("outputs", outputs, ndim=2)
    ref_mean = as_finite_array("ref_mean", ref_mean, shape=(y.shape[1],))
    ref_var = as_finite_array("ref_var", ref_var, shape=(y.shape[1],))
    check_allocation(
        8.0 * 2 * y.size,
        f"the batch variances of {y.shape[0]} samples of {y.shape[1]} outputs",
        "pass the outputs of a few components (outputs[:, idx] with ref_mean[idx], ref_var[idx])",
    )
    em, ev, nb = [], [], []
    for n in sizes:
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or not 2 <= n <= y.shape[0]:
            raise ValueError(f"`sizes` must be integers in [2, {y.shape[0]}], got {n!r}")
        B = y.shape[0] // n
        batches = y[: B * n].reshape(B, n, -1)
        mu = batches.mean(axis=1)
        var = batches.var(axis=1, ddof=1)
        em.append(np.sqrt(np.mean([relative_error(m, ref_mean) ** 2 for m in mu])))
        ev.append(np.sqrt(np.mean([relative_error(v, ref_var) ** 2 for v in var])))
        nb.append(B)
    return np.array(em), np.array(ev), np.array(nb)


def loglog_slope(x, y):
    """Least-squares slope of ``log y`` against ``log x`` (e.g. -1/2 for Monte Carlo)."""
    x = as_finite_array("x", x, ndim=1)
    y = as_finite_array("y", y, shape=(x.size,))
    if x.size < 2 or np.any(x <= 0) or np.any(y <= 0):
        raise ValueError("`x` and `y` must hold at least 2 positive values")
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


# --------------------------------------------------------------------------------------
# Sobol indices by sampling (Saltelli 2010 first order, Jansen 1999 total)
# --------------------------------------------------------------------------------------
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
        As in :func:`~ecfm_uq.chaos.fit_pce`; independent inputs only.
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

    from .chaos.inputs import as_inputs, check_moments

    if not callable(model):
        raise TypeError(f"`model` must be callable model(x), got {type(model).__name__}")
    inputs = as_inputs(inputs)
    if inputs is None:
        raise TypeError("`inputs` must be given: bounds (d, 2), Inputs or distributions")
    check_moments(inputs, "sobol_indices")
    if getattr(inputs, "dependent", False):
        raise ValueError(
            "Sobol indices are not defined for dependent `inputs` (a Gaussian copula): the "
            "variance has no unique split among correlated inputs; pass independent inputs"
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
