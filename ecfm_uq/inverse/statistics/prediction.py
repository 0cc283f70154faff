"""Predictions of a fit with confidence and prediction bands (issue 38).

For a quantity of interest :math:`y = g(\\epsilon)` (default: the fitted
:class:`~ecfm_uq.inverse.ModelProblem`'s predictions of its data) at the estimate
:math:`\\hat\\epsilon` with covariance :math:`C` (``result.uncertainty.cov``):

============  ==============================================================================
method        band
============  ==============================================================================
``"delta"``   :math:`g(\\hat\\epsilon) \\pm q\\,s`, :math:`s^2 = \\mathrm{diag}(J_g C J_g^T)`
              (confidence) :math:`+\\,\\sigma_i^2` (prediction); :math:`J_g` the model's own
              Jacobian for the default ``g`` (the user's ``jac`` or its finite differences),
              else ``g_jac`` or central differences of ``g``; :math:`q` the two-sided
              Student-t quantile with :math:`n - p` degrees of freedom when sigma was
              estimated, the normal one when it was given (statsmodels' OLS
              ``get_prediction`` for a linear model).
``"pce"``     a PCE of ``g`` over the inputs :math:`N(\\hat\\epsilon, C)`
              (:meth:`~ecfm_uq.inverse.Uncertainty.to_inputs`, :func:`~ecfm_uq.chaos.fit_pce`):
              ``value`` the PCE mean, ``std`` its standard deviation (with
              :math:`\\sigma_i^2` added for a prediction band) and the band ``value ± q std``
              with the same :math:`q` as the delta method (so a ``g`` linear in
              :math:`\\epsilon` gives the delta band); it carries the curvature of ``g`` the
              delta method drops.
``"posterior"``  ``g`` of posterior samples (:func:`~ecfm_uq.inverse.statistics.posterior.\
sample_posterior`, sigma sampled too when it was estimated), plus a draw of the noise for a
              prediction band: ``value`` and ``std`` their mean and standard deviation, the
              band their empirical :math:`(1 \\mp \\text{level})/2` quantiles.
============  ==============================================================================

:math:`\\sigma_i` is ``result.uncertainty.sigma``, each observation's noise standard deviation
(given or estimated). A user's ``g`` gets that noise in a prediction band when it is one
number; with a per-observation ``sigma`` pass ``noise_std`` (the new observation's).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from ..._validation import all_finite, as_finite_array, check_int
from ...chaos.nonintrusive import fit_pce
from ..core.finite_differences import fd_jacobian
from ..core.result import InverseResult, register_band_builder
from .posterior import sample_posterior

__all__ = ["Band", "predict_band"]

KINDS = ("confidence", "prediction")
METHODS = ("delta", "pce", "posterior")


@dataclass(frozen=True, eq=False)
class Band:
    """A quantity of interest with a two-sided band.

    Attributes
    ----------
    value : ndarray
        ``g`` at the estimate (``"delta"``), the PCE mean (``"pce"``) or the posterior
        mean (``"posterior"``); the shape of ``g``'s output.
    lower, upper : ndarray
        The band's edges.
    std : ndarray
        The standard deviation the band is built on (delta method, PCE, or the samples').
    level : float
    kind : str
        ``"confidence"`` (the uncertainty of :math:`g(\\epsilon)`) or ``"prediction"``
        (of a new observation: plus the noise).
    method : str
        ``"delta"``, ``"pce"`` or ``"posterior"``.
    quantile : float or None
        The factor :math:`q` of ``value ± q std`` (``None`` for ``"posterior"``, whose band
        is the samples' quantiles).
    dof : int or None
        Student-t degrees of freedom of :math:`q` (sigma estimated), else ``None``.
    """

    value: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    std: np.ndarray
    level: float
    kind: str
    method: str
    quantile: float | None = None
    dof: int | None = None

    def plot(self, x=None, data=None, ax=None, *, label=None):
        """Draw the value and the band (a 1-D quantity) against ``x``.

        Parameters
        ----------
        x : (m,) array_like, optional
            Abscissae (default ``0, 1, ...``).
        data : (m,) array_like, optional
            Observations to draw as points.
        ax : matplotlib Axes, optional
            Default: a new figure's.
        label : str, optional
            The value's legend label.

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt  # the plotting stack only when a plot is asked for

        v, lo, hi = (np.ravel(a) for a in (self.value, self.lower, self.upper))
        x = np.arange(v.size) if x is None else as_finite_array("x", x, shape=(v.size,))
        if ax is None:
            _, ax = plt.subplots()
        order = np.argsort(x, kind="stable")
        ax.fill_between(
            x[order], lo[order], hi[order], alpha=0.3,
            label=f"{self.level:.0%} {self.kind} band ({self.method})",
        )  # fmt: skip
        ax.plot(x[order], v[order], label=label or "prediction")
        if data is not None:
            d = as_finite_array("data", data).ravel()
            if d.size != v.size:
                raise ValueError(f"`data` must hold {v.size} values, got {d.size}")
            ax.plot(x, d, "k.", label="data")
        ax.legend()
        return ax


def predict_band(
    result,
    g=None,
    *,
    level=0.95,
    kind="confidence",
    method="delta",
    g_jac=None,
    noise_std=None,
    order=3,
    posterior=None,
    n_draws=2000,
    seed=0,
    **sampler,
):
    """``g`` at a fit's estimate with a ``level`` confidence or prediction band.

    Parameters
    ----------
    result : InverseResult
    g : callable ``eps -> array_like``, optional
        The quantity of interest (any fixed shape). Default: the predictions of the data
        of the fitted :class:`~ecfm_uq.inverse.ModelProblem` (in the data's shape); other
        problems need a ``g`` (e.g. ``lambda e: M @ problem.system.mean(solve(e))``).
    level : float
        In (0, 1).
    kind : {"confidence", "prediction"}
    method : {"delta", "pce", "posterior"}
        See the module docstring.
    g_jac : callable ``eps -> (m, p)``, optional
        ``g``'s Jacobian for the delta method (default: central differences).
    noise_std : float or array_like, optional
        The noise standard deviation of a new observation of ``g`` (prediction band of a
        user ``g`` when ``sigma`` is not one number). Default: ``result.uncertainty.sigma``.
    order : int
        ``"pce"``: the degree per variable of the tensor Gauss quadrature
        (:func:`~ecfm_uq.chaos.fit_pce` with ``method="quadrature"``).
    posterior : PosteriorResult, optional
        ``"posterior"``: samples already drawn (else drawn here with ``**sampler``).
    n_draws : int
        ``"posterior"``: samples pushed through ``g`` (evenly thinned).
    seed : int
        ``"posterior"``: seed of the sampler and of the noise draws.
    **sampler
        ``"posterior"``: ``prior``/``bounds`` (one required), ``n_steps``, ``n_walkers``
        of :func:`~ecfm_uq.inverse.statistics.posterior.sample_posterior`.

    Returns
    -------
    Band

    Raises
    ------
    TypeError
        ``g`` or ``g_jac`` not callable, ``result`` not an InverseResult.
    ValueError
        ``level`` outside (0, 1), an unknown ``kind``/``method``, ``g`` returning
        non-finite values or changing shape, no covariance (``"delta"``, ``"pce"``), no
        noise level for a prediction band, ``g=None`` for a fit that is not a
        ModelProblem's.
    """
    if not isinstance(result, InverseResult):
        raise TypeError(f"`result` must be an InverseResult, got {type(result).__name__}")
    if isinstance(level, bool) or not isinstance(level, numbers.Real) or not 0 < level < 1:
        raise ValueError(f"`level` must be a number in (0, 1), e.g. 0.95; got {level!r}")
    level = float(level)
    if not isinstance(kind, str) or kind not in KINDS:
        raise ValueError(f"`kind` must be one of {list(KINDS)}, got {kind!r}")
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"`method` must be one of {list(METHODS)}, got {method!r}")
    if g_jac is not None and not callable(g_jac):
        raise TypeError(f"`g_jac` must be a callable eps -> (m, p) Jacobian, got {g_jac!r}")
    if sampler and method != "posterior":
        raise TypeError(
            f"unknown argument(s) {sorted(sampler)} for method={method!r} (sampler settings "
            "are for method='posterior')"
        )
    unc = result.uncertainty
    eps = np.asarray(result.eps, dtype=float)
    fun, shape, default = _quantity(result, g)
    y0 = fun(eps)
    noise2 = _noise_variance(unc, y0.size, default, noise_std) if kind == "prediction" else 0.0
    if method == "posterior":
        return _posterior_band(
            result, fun, shape, level, kind, noise2, posterior, n_draws, seed, sampler
        )
    if not unc.success or unc.cov is None:
        raise ValueError(
            f"predict(method={method!r}) needs the fit's covariance, and this fit has none "
            f"({unc.message}); fit with uncertainty=True (the default), or use "
            "method='posterior'"
        )
    q = unc.quantile(level)
    if method == "delta":
        J = _jacobian(result, fun, eps, y0, default, g_jac)
        var = np.einsum("ij,jk,ik->i", J, unc.cov, J) + noise2
        value = y0
    else:
        order = check_int("order", order, minimum=1)
        pce = fit_pce(fun, unc.to_inputs("normal"), method="quadrature", order=order)
        value = np.asarray(pce.mean, dtype=float).ravel()
        var = np.asarray(pce.variance, dtype=float).ravel() + noise2
    std = np.sqrt(np.clip(var, 0.0, None))
    return Band(
        value=value.reshape(shape), lower=(value - q * std).reshape(shape),
        upper=(value + q * std).reshape(shape), std=std.reshape(shape), level=level,
        kind=kind, method=method, quantile=q, dof=unc.dof,
    )  # fmt: skip


def _quantity(result, g):
    """``eps -> (m,)`` checked, the output shape, and whether it is the model's own."""
    if g is None:
        problem = result.problem
        if problem is None or not hasattr(problem, "predict"):
            raise ValueError(
                "predict(g=None) predicts the data of a fitted ModelProblem, and this "
                f"result ({result.formulation}) is not one's; pass `g`, a callable eps -> the "
                "quantity of interest (e.g. the sensors' mean of a solve at eps)"
            )
        return (lambda e: problem.predict(e, first=True)), problem.shape, True
    if not callable(g):
        raise TypeError(f"`g` must be a callable eps -> array (the quantity), got {g!r}")
    box = {}

    def fun(e):
        try:
            y = np.asarray(g(e), dtype=float)
        except (TypeError, ValueError) as err:
            raise type(err)(f"`g` at eps={np.asarray(e).tolist()} failed: {err}") from err
        if "shape" not in box:
            if y.size == 0:
                raise ValueError("`g` returned an empty array; it must return the quantity")
            box["shape"] = y.shape
        elif y.shape != box["shape"]:
            raise ValueError(
                f"`g` returned shape {y.shape} at eps={np.asarray(e).tolist()}, but "
                f"{box['shape']} at the estimate: it must return one fixed shape"
            )
        y = y.ravel()
        if not all_finite(y):
            k = int(np.flatnonzero(~np.isfinite(y))[0])
            raise ValueError(
                f"`g` returned a non-finite value (entry {k}: {y[k]}) at eps="
                f"{np.asarray(e).tolist()}; it must be finite where the parameters are "
                "plausible"
            )
        return y

    fun(np.asarray(result.eps, dtype=float))
    return fun, box["shape"], False


def _noise_variance(unc, m, default, noise_std):
    """The variance a new observation adds, per output value (m,)."""
    if noise_std is not None:
        s = as_finite_array("noise_std", noise_std)
        if s.size not in (1, m) or np.any(s < 0):
            raise ValueError(
                f"`noise_std` must be one non-negative number or {m} (one per output value)"
            )
        return np.broadcast_to(s.ravel() ** 2, (m,)).copy()
    sigma = unc.sigma
    if sigma is None:
        raise ValueError(
            f"a prediction band needs the noise level, and this fit has none "
            f"(noise {unc.noise_model!r}: {unc.message or 'no sigma'}); pass `noise_std`"
        )
    if np.ndim(sigma) == 0:
        return np.full(m, float(sigma) ** 2)
    if not default or np.size(sigma) != m:
        raise ValueError(
            "`sigma` was given per observation, so the noise of a new observation of a "
            "user `g` is unknown; pass `noise_std` (one number or one per output value)"
        )
    return np.asarray(sigma, dtype=float).ravel() ** 2


def _jacobian(result, fun, eps, y0, default, g_jac):
    """:math:`\\partial g/\\partial\\epsilon` at the estimate, (m, p)."""
    if default and g_jac is None:
        return result.problem.jacobian(eps, y0, typical=eps)
    if g_jac is not None:
        J = as_finite_array("g_jac", np.asarray(g_jac(eps), dtype=float))
        if J.shape not in ((y0.size, eps.size), (*np.shape(y0), eps.size)):
            raise ValueError(
                f"`g_jac` returned shape {J.shape}; expected ({y0.size}, {eps.size}): one row "
                "per output value, one column per parameter"
            )
        return J.reshape(y0.size, eps.size)
    return fd_jacobian(fun, eps, method="3-point", f0=y0)


def _posterior_band(result, fun, shape, level, kind, noise2, post, n_draws, seed, sampler):
    """The band of ``g`` over posterior samples (and noise draws)."""
    n_draws = check_int("n_draws", n_draws, minimum=10)
    if post is None:
        post = sample_posterior(result, seed=seed, **sampler)
    elif not hasattr(post, "samples"):
        raise TypeError(f"`posterior` must be a PosteriorResult, got {type(post).__name__}")
    pick = np.unique(np.linspace(0, len(post.samples) - 1, n_draws).round().astype(int))
    Y = np.array([fun(e) for e in post.samples[pick]])
    if kind == "prediction":
        rng = np.random.default_rng(seed)
        z = rng.standard_normal(Y.shape)
        if post.sigma is not None:  # sigma sampled with eps: its draws, not the estimate
            Y = Y + z * post.sigma[pick, None]
        else:
            Y = Y + z * np.sqrt(noise2)
    a = (1.0 - level) / 2
    lo, hi = np.quantile(Y, [a, 1.0 - a], axis=0)
    return Band(
        value=Y.mean(axis=0).reshape(shape), lower=lo.reshape(shape), upper=hi.reshape(shape),
        std=Y.std(axis=0, ddof=1).reshape(shape), level=level, kind=kind, method="posterior",
        dof=result.uncertainty.dof,
    )  # fmt: skip


register_band_builder(predict_band)
