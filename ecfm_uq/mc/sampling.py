"""Monte Carlo over deterministic solves: sampling, moments, quadrature references and
Monte Carlo error against sample size (the package docstring of :mod:`ecfm_uq.mc` has the
whole list)."""

from __future__ import annotations

import math
import numbers
from typing import NamedTuple

import numpy as np

from .._validation import as_finite_array, check_int, rng_from_seed
from ..executor import NonFiniteOutputError, evaluate_samples
from ..memory import check_allocation

__all__ = [
    "Moments",
    "batch_errors",
    "draw_germ",
    "loglog_slope",
    "mc_moments",
    "monte_carlo",
    "pseudospectral_projection",
    "quadrature_moments",
    "relative_error",
]


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
    from ..chaos import gauss_legendre
    from ..chaos.quadrature import tensor_gauss_legendre

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
    from ..chaos import ChaosBasis, project

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
