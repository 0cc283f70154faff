"""Monte Carlo verification of a polynomial chaos surrogate against its model.

:func:`verify` draws ``n`` fresh samples of the surrogate's inputs, runs the model on them
(:func:`~ecfm_uq.mc.monte_carlo`, through any executor) and compares, per output:

* the surrogate's own mean and variance (closed form, Eq. stats) with the Monte Carlo
  ones, as z-scores :math:`z = (\\mu_{\\mathrm{PCE}} - \\bar y)/\\mathrm{se}(\\bar y)` and
  :math:`(\\sigma^2_{\\mathrm{PCE}} - s^2)/\\mathrm{se}(s^2)` (:func:`~ecfm_uq.mc.mc_moments`,
  the variance's standard error from the fourth central moment);
* quantiles of the surrogate and of the model on the same samples;
* the hold-out error, the root mean square of :math:`\\mathrm{pce}(x) - \\mathrm{model}(x)`
  over the samples relative to the model outputs' standard deviation;
* the Monte Carlo error of mean and variance against the sample size, relative to the
  surrogate's moments (:func:`~ecfm_uq.mc.batch_errors`): it falls as :math:`n^{-1/2}` for
  a correct surrogate and levels off at the bias for a wrong one.

The result is a :class:`VerificationReport` with a text :meth:`~VerificationReport.summary`
and plots (parity and convergence).
"""

from __future__ import annotations

import math
import pickle
from dataclasses import dataclass

import numpy as np

from .._validation import as_finite_array, check_int
from ..chaos.inputs import as_inputs, draw_germs
from ..chaos.pce import PolynomialChaosExpansion
from ..executor import CallerWrapped, NonFiniteOutputError
from ..plotting import pyplot
from .sampling import batch_errors, loglog_slope, mc_moments, monte_carlo, relative_error

__all__ = ["VerificationReport", "verify"]

# Points drawn at most in a parity plot (a deterministic thinning of the n x m values).
_PARITY_POINTS = 20_000
# Rows of the summary table for outputs with many components (the worst ones are shown).
_SUMMARY_ROWS = 12


class _SampleFailure(CallerWrapped):
    """The model raised at one sample (carried out of a worker process with its index)."""

    def __init__(self, index, original):
        super().__init__(index, original)
        self.index = index
        self.original = original


class _IndexedModel:
    """``model(x)`` on rows ``(index, *x)``: a failure names its sample (picklable)."""

    def __init__(self, model):
        self.model = model

    def __call__(self, row):
        try:
            return self.model(row[1:])
        except Exception as e:
            raise _SampleFailure(int(row[0]), e) from e


def _ratio(num, den):
    """``num / den`` elementwise, 0 where both are 0 and inf where only ``den`` is."""
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = num / den
    zero = den == 0
    return np.where(zero, np.where(num == 0, 0.0, np.copysign(np.inf, num)), out)


def _default_sizes(n):
    """About six sample sizes from 10 to n / 10 (at least 10 disjoint batches each)."""
    lo = min(10, n)
    hi = max(n // 10, lo)
    return sorted({max(2, int(round(v))) for v in np.geomspace(lo, hi, 6)})


@dataclass(frozen=True, eq=False)
class VerificationReport:
    """A polynomial chaos surrogate against Monte Carlo runs of its model (:func:`verify`).

    Per-output arrays have the surrogate's ``output_shape``.

    Attributes
    ----------
    n : int
        Monte Carlo samples (model runs).
    pce_mean, pce_variance : ndarray
        The surrogate's own mean and variance (closed form).
    mc_mean, mc_variance : ndarray
        Sample mean and unbiased variance of the model outputs.
    se_mean, se_variance : ndarray
        Their standard errors, :math:`s/\\sqrt n` and
        :math:`\\sqrt{(m_4 - \\tfrac{n-3}{n-1}s^4)/n}`.
    mean_z, variance_z : ndarray
        ``(pce_mean - mc_mean) / se_mean`` and ``(pce_variance - mc_variance) /
        se_variance`` (0 where both difference and error are 0, inf where only the error
        is). Within about ±3 for a correct surrogate.
    quantile_levels : (q,) ndarray
    pce_quantiles, model_quantiles : (q, *output_shape) ndarray
        Quantiles of the surrogate and of the model on the same samples.
    holdout_error : ndarray
        Root mean square of ``pce(x) - model(x)`` over the samples divided by the model
        outputs' standard deviation (0 is a perfect surrogate, 1 is no better than the mean).
    sizes : (k,) ndarray
        Sample sizes of the convergence data.
    convergence_mean_error, convergence_variance_error : (k,) ndarray
        Root mean square over disjoint batches of each size of the relative error
        (:func:`~ecfm_uq.mc.relative_error`, over all components) of the batch mean and
        variance against the surrogate's (:func:`~ecfm_uq.mc.batch_errors`); NaN when the
        surrogate's mean or variance is identically zero.
    n_batches : (k,) ndarray
    running_mean_error : (k,) ndarray
        Relative error of the mean of the first ``sizes[j]`` samples against the surrogate's.
    samples : (n, dim) ndarray
        The input points the model ran at.
    pce_values, model_values : (n, *output_shape) ndarray
        Surrogate and model at ``samples``.
    names : tuple of str
        Input names.
    """

    n: int
    pce_mean: np.ndarray
    pce_variance: np.ndarray
    mc_mean: np.ndarray
    mc_variance: np.ndarray
    se_mean: np.ndarray
    se_variance: np.ndarray
    mean_z: np.ndarray
    variance_z: np.ndarray
    quantile_levels: np.ndarray
    pce_quantiles: np.ndarray
    model_quantiles: np.ndarray
    holdout_error: np.ndarray
    sizes: np.ndarray
    convergence_mean_error: np.ndarray
    convergence_variance_error: np.ndarray
    n_batches: np.ndarray
    running_mean_error: np.ndarray
    samples: np.ndarray
    pce_values: np.ndarray
    model_values: np.ndarray
    names: tuple = ()

    @property
    def output_shape(self):
        """Shape of one output value."""
        return np.shape(self.pce_mean)

    @property
    def max_abs_z(self):
        """Largest |z| of mean and variance over all output components."""
        return float(max(np.max(np.abs(self.mean_z)), np.max(np.abs(self.variance_z))))

    @property
    def convergence_slope(self):
        """Least-squares log-log slope of ``convergence_mean_error`` against ``sizes``
        (about -1/2 for a correct surrogate, flatter for a biased one); NaN when fewer
        than two sizes or a zero error."""
        e = np.asarray(self.convergence_mean_error)
        if e.size < 2 or not np.all(np.isfinite(e)) or np.any(e <= 0):
            return float("nan")
        return loglog_slope(self.sizes, e)

    # -- text ------------------------------------------------------------------------
    def summary(self, max_rows=_SUMMARY_ROWS):
        """A text table: per output component the moments, z-scores, hold-out error and
        quantiles (for many components, the ``max_rows`` worst by |z| and hold-out error).

        Parameters
        ----------
        max_rows : int

        Returns
        -------
        str
        """
        max_rows = check_int("max_rows", max_rows, minimum=1)
        flat = {
            k: np.asarray(getattr(self, k)).reshape(-1)
            for k in (
                "pce_mean",
                "mc_mean",
                "se_mean",
                "mean_z",
                "pce_variance",
                "mc_variance",
                "se_variance",
                "variance_z",
                "holdout_error",
            )
        }
        m = flat["pce_mean"].size
        badness = np.maximum(
            np.maximum(np.abs(flat["mean_z"]), np.abs(flat["variance_z"])) / 4.0,
            flat["holdout_error"] / 0.1,
        )
        rows = np.arange(m) if m <= max_rows else np.sort(np.argsort(-badness)[:max_rows])
        shape = self.output_shape

        def label(j):
            return "y" if shape == () else "y" + str([int(i) for i in np.unravel_index(j, shape)])

        lines = [
            f"Monte Carlo verification of a PCE surrogate: n = {self.n} model runs, "
            f"{m} output component(s)",
            f"max |z| = {self.max_abs_z:.2f} (mean and variance); max hold-out error = "
            f"{float(np.max(flat['holdout_error'])):.3g}; MC error slope in n = "
            f"{self.convergence_slope:.2f}",
        ]
        if m > max_rows:
            lines.append(f"(the {max_rows} components with the largest |z| / hold-out error)")
        head = (
            f"{'output':>10} {'PCE mean':>12} {'MC mean':>12} {'se':>9} {'z':>7} "
            f"{'PCE var':>12} {'MC var':>12} {'se':>9} {'z':>7} {'holdout':>8}"
        )
        lines += [head, "-" * len(head)]
        for j in rows:
            f = {k: v[j] for k, v in flat.items()}
            lines.append(
                f"{label(j):>10} {f['pce_mean']:12.5g} {f['mc_mean']:12.5g} "
                f"{f['se_mean']:9.2g} {f['mean_z']:7.2f} {f['pce_variance']:12.5g} "
                f"{f['mc_variance']:12.5g} {f['se_variance']:9.2g} {f['variance_z']:7.2f} "
                f"{f['holdout_error']:8.3g}"
            )
        qp = np.asarray(self.pce_quantiles).reshape(len(self.quantile_levels), -1)
        qm = np.asarray(self.model_quantiles).reshape(len(self.quantile_levels), -1)
        qhead = f"{'output':>10} " + " ".join(
            f"{f'q{100 * q:g}% PCE':>12} {f'q{100 * q:g}% model':>12}" for q in self.quantile_levels
        )
        lines += ["", qhead, "-" * len(qhead)]
        for j in rows:
            cells = " ".join(
                f"{qp[i, j]:12.5g} {qm[i, j]:12.5g}" for i in range(len(self.quantile_levels))
            )
            lines.append(f"{label(j):>10} {cells}")
        return "\n".join(lines)

    def __str__(self):
        return self.summary()

    # -- plots -----------------------------------------------------------------------
    def plot_parity(self, ax=None):
        """Surrogate against model on the Monte Carlo samples (all components), with the
        line y = x.

        Parameters
        ----------
        ax : matplotlib Axes, optional

        Returns
        -------
        matplotlib Axes
        """
        if ax is None:
            _, ax = pyplot().subplots(figsize=(4.5, 4.2))
        y_m = np.asarray(self.model_values).reshape(-1)
        y_p = np.asarray(self.pce_values).reshape(-1)
        step = max(1, math.ceil(y_m.size / _PARITY_POINTS))
        ax.plot(y_m[::step], y_p[::step], ".", ms=2, alpha=0.5, color="C0", label="samples")
        lo, hi = float(min(y_m.min(), y_p.min())), float(max(y_m.max(), y_p.max()))
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8, label="y = x")
        ax.set_xlabel("model(x)")
        ax.set_ylabel("PCE(x)")
        ax.set_title(f"hold-out error {float(np.max(self.holdout_error)):.2g} (n = {self.n})")
        ax.legend(fontsize=7)
        return ax

    def plot_convergence(self, ax=None):
        """Monte Carlo error of mean and variance against the sample size, relative to
        the surrogate's moments, with a slope -1/2 reference line.

        Parameters
        ----------
        ax : matplotlib Axes, optional

        Returns
        -------
        matplotlib Axes
        """
        if ax is None:
            _, ax = pyplot().subplots(figsize=(4.5, 4.2))
        n = np.asarray(self.sizes, dtype=float)
        em = np.asarray(self.convergence_mean_error)
        ev = np.asarray(self.convergence_variance_error)
        ax.loglog(n, em, "o-", label="mean")
        ax.loglog(n, ev, "s-", label="variance")
        if np.isfinite(em[0]) and em[0] > 0:
            ax.loglog(n, em[0] * np.sqrt(n[0] / n), "k--", lw=0.8, label=r"slope $-1/2$")
        ax.set_xlabel("samples n")
        ax.set_ylabel("relative error vs PCE (RMS over batches)")
        ax.set_title(f"Monte Carlo against the PCE (slope {self.convergence_slope:.2f})")
        ax.legend(fontsize=7)
        return ax

    def plot(self, ax=None):
        """Parity and convergence side by side.

        Parameters
        ----------
        ax : sequence of two matplotlib Axes, optional
            Default: a new 1 x 2 figure.

        Returns
        -------
        (2,) ndarray of matplotlib Axes
        """
        if ax is None:
            _, ax = pyplot().subplots(1, 2, figsize=(9.5, 4.2))
        axes = np.asarray(ax, dtype=object).reshape(-1)
        if axes.size != 2:
            raise ValueError(f"`ax` must be two Axes (parity, convergence), got {axes.size}")
        self.plot_parity(axes[0])
        self.plot_convergence(axes[1])
        axes[0].figure.tight_layout()
        return axes


def _check_inputs(pce, inputs):
    """The inputs to sample: the surrogate's, or ``inputs`` when they match it."""
    if inputs is None:
        return pce.inputs
    given = as_inputs(inputs)
    if given.dim != pce.dim:
        raise ValueError(
            f"`inputs` has {given.dim} inputs but the surrogate `pce` has {pce.dim}: they "
            "are not the surrogate's inputs; pass inputs=None to sample the surrogate's own"
        )
    if pce.inputs is not None and not given == pce.inputs:
        raise ValueError(
            f"`inputs` ({given!r}) differ from the surrogate's own inputs ({pce.inputs!r}): "
            "the surrogate's mean and variance are over its own inputs; pass inputs=None, "
            "or fit the surrogate on these inputs"
        )
    if tuple(given.germs) != tuple(pce.basis.germs):
        raise ValueError(
            f"`inputs` are expanded on the germs {list(given.germs)} but the surrogate `pce` "
            f"on {list(pce.basis.germs)}: they are not the surrogate's inputs"
        )
    return given


def _run_model(model, x, executor, workers, chunksize, callback, pce):
    """The model at each row of ``x``; a failure names the sample and chains the original."""
    n = x.shape[0]
    if executor is None and workers > 1:
        try:
            pickle.dumps(model)
        except Exception as e:
            raise TypeError(
                "`model` must be picklable to run in worker processes: use a module-level "
                "function or functools.partial of one (not a lambda or closure), or pass "
                "workers=1"
            ) from e
    rows = np.column_stack([np.arange(n, dtype=float), x])
    dims = f"{pce.dim} input(s)"
    try:
        y = monte_carlo(
            _IndexedModel(model),
            rows,
            executor,
            workers=workers,
            chunksize=chunksize,
            callback=callback,
        )
    except _SampleFailure as e:
        at = np.array2string(x[e.index], precision=6)
        orig = e.original
        what = f"`model` raised {type(orig).__name__} at sample {e.index} (x={at}): {orig}"
        if isinstance(orig, (IndexError, TypeError, ValueError)):
            raise ValueError(
                f"{what}. The surrogate `pce` has {dims} and the model is called as "
                f"model(x) with x of shape ({pce.dim},) (as fit_pce calls it): a model of a "
                "different number of inputs is not the model of this surrogate"
            ) from orig
        raise RuntimeError(what) from orig
    except NonFiniteOutputError as e:
        at = np.array2string(x[e.index], precision=6)
        raise ValueError(
            f"`model` returned NaN or inf at sample {e.index} (x={at}); check the model there"
        ) from e
    if y.shape[1:] != pce.output_shape:
        if math.prod(y.shape[1:]) != math.prod(pce.output_shape):
            raise ValueError(
                f"`model` returns outputs of shape {y.shape[1:]} but the surrogate `pce` has "
                f"output shape {pce.output_shape}: pass the surrogate of this model's outputs"
            )
        y = y.reshape((n, *pce.output_shape))
    return y


def verify(
    pce,
    model,
    n,
    *,
    seed=None,
    executor=None,
    inputs=None,
    sizes=None,
    quantiles=(0.05, 0.5, 0.95),
    workers=1,
    chunksize=None,
    callback=None,
):
    """Verify a polynomial chaos surrogate against its model by Monte Carlo.

    The model runs on ``n`` fresh random samples of the surrogate's inputs; the
    surrogate's closed-form mean and variance are compared with the sample ones through
    z-scores, the surrogate's values with the model's (hold-out error, quantiles), and
    the Monte Carlo error against the sample size is recorded.

    Parameters
    ----------
    pce : PolynomialChaosExpansion
        The surrogate (e.g. from :func:`ecfm_uq.chaos.fit_pce` or
        :meth:`~ecfm_uq.chaos.PolynomialChaosExpansion.from_galerkin`).
    model : callable
        ``model(x) -> array_like`` of the surrogate's output shape, ``x`` a (dim,) point
        on the inputs' own ranges (the germ when the surrogate has no inputs): the
        calling convention of :func:`~ecfm_uq.chaos.fit_pce`. Picklable for worker
        processes.
    n : int
        Monte Carlo samples, at least 2.
    seed : None, int or numpy.random.Generator
        Seeds the samples (drawn by :func:`ecfm_uq.chaos.inputs.draw_germs`, so the
        numbers do not depend on the executor).
    executor : object with ``map``, optional
        As in :func:`~ecfm_uq.mc.monte_carlo` (``ThreadPoolExecutor``,
        ``ProcessPoolExecutor``, ``dask.distributed.Client``).
    inputs : Inputs, bounds or distributions, optional
        The inputs to sample, when the surrogate has none (a Galerkin PCE in the germ) or
        to check they are its own; they must match the surrogate's (dimension, germs, and
        its ``inputs`` when it has them).
    sizes : sequence of int, optional
        Sample sizes of the convergence data, each in [2, n] (default about six from 10
        to n / 10).
    quantiles : sequence of float
        Probabilities of the compared quantiles.
    workers : int
        Processes of a pool created here when no ``executor`` is given (1: in-process).
    chunksize : int, optional
        Samples per task.
    callback : callable, optional
        Called with the number of samples in each finished chunk (a progress bar).

    Returns
    -------
    VerificationReport

    Raises
    ------
    TypeError
        ``pce`` not a PolynomialChaosExpansion; ``model`` not callable, or not picklable
        for the worker processes of ``workers > 1``.
    ValueError
        ``n < 2``; ``inputs`` that are not the surrogate's; a model output of another
        size than the surrogate's; a model raising IndexError, TypeError or ValueError
        (typically called with the wrong number of inputs) or returning NaN or inf (the
        message names the sample; the model's exception is chained).
    RuntimeError
        The model raised another exception (the message names the sample; chained).

    Examples
    --------
    >>> from ecfm_uq.chaos import fit_pce
    >>> def f(x):
    ...     return x[0] ** 2 + 2.0 * x[1]
    >>> pce = fit_pce(f, [(0, 1), (0, 1)], method="quadrature", order=2)
    >>> rep = verify(pce, f, 1000, seed=0)
    >>> bool(rep.max_abs_z < 4 and rep.holdout_error < 1e-10)
    True
    """
    if not isinstance(pce, PolynomialChaosExpansion):
        raise TypeError(
            f"`pce` must be a PolynomialChaosExpansion (e.g. from fit_pce), got "
            f"{type(pce).__name__}"
        )
    if not callable(model):
        raise TypeError(f"`model` must be callable model(x) -> array, got {type(model).__name__}")
    n = check_int("n", n, minimum=2)
    workers = check_int("workers", workers, minimum=1)
    q = as_finite_array("quantiles", quantiles, ndim=1)
    if q.size == 0 or np.any((q < 0) | (q > 1)):
        raise ValueError(f"`quantiles` must be probabilities in [0, 1], got {q.tolist()}")
    inp = _check_inputs(pce, inputs)
    sizes = _default_sizes(n) if sizes is None else list(sizes)

    omega = draw_germs(pce.basis.germs, n, seed)
    x = omega if inp is None else inp.from_germ(omega)
    y_model = _run_model(model, x, executor, workers, chunksize, callback, pce)
    y_pce = pce.evaluate(omega)

    mom = mc_moments(y_model)
    mu, var = pce.mean, pce.variance
    flat = y_model.reshape(n, -1)
    if np.any(mu != 0) and np.any(var != 0):
        err_m, err_v, n_b = batch_errors(flat, mu.reshape(-1), var.reshape(-1), sizes)
    else:  # a relative error against an identically zero reference is undefined
        batch_errors(flat, np.ones(flat.shape[1]), np.ones(flat.shape[1]), sizes)  # checks
        err_m = err_v = np.full(len(sizes), np.nan)
        n_b = np.array([n // k for k in sizes])
    running = np.array(
        [
            relative_error(flat[:k].mean(axis=0), mu.reshape(-1)) if np.any(mu != 0) else np.nan
            for k in sizes
        ]
    )
    rms = np.sqrt(np.mean((y_pce - y_model) ** 2, axis=0))
    names = tuple(inp.names) if inp is not None else tuple(f"w{k}" for k in range(pce.dim))
    return VerificationReport(
        n=n,
        pce_mean=mu,
        pce_variance=var,
        mc_mean=mom.mean,
        mc_variance=mom.var,
        se_mean=mom.se_mean,
        se_variance=mom.se_var,
        mean_z=_ratio(mu - mom.mean, mom.se_mean),
        variance_z=_ratio(var - mom.var, mom.se_var),
        quantile_levels=q,
        pce_quantiles=np.quantile(y_pce, q, axis=0),
        model_quantiles=np.quantile(y_model, q, axis=0),
        holdout_error=_ratio(rms, np.sqrt(mom.var)),
        sizes=np.asarray(sizes, dtype=int),
        convergence_mean_error=np.asarray(err_m),
        convergence_variance_error=np.asarray(err_v),
        n_batches=np.asarray(n_b),
        running_mean_error=running,
        samples=x,
        pce_values=y_pce,
        model_values=y_model,
        names=names,
    )
