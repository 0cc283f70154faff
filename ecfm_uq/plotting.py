"""Figures shared by the library and the ``ecfm-uq`` studies (matplotlib, Agg backend)."""

from __future__ import annotations

import numpy as np

from ._files import atomic_path
from ._validation import as_finite_array

__all__ = ["pair_plot", "pyplot", "save_figure", "sobol_bars"]


def save_figure(fig, path, dpi=130):
    """Save a matplotlib figure atomically and close it."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)


def pyplot():
    """matplotlib.pyplot with a non-interactive backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def pair_plot(samples, names=None, truth=None, laplace=None, bins=40):
    """Pair plot of posterior samples: histograms on the diagonal, scatter below.

    Parameters
    ----------
    samples : (n_samples, n_eps) array_like
    names : list of str, optional
        Axis labels (default ``eps[k]``).
    truth : (n_eps,) array_like, optional
        Marked by lines.
    laplace : tuple ``(mean (n_eps,), cov (n_eps, n_eps))``, optional
        Gaussian approximation drawn over the histograms and as 2-sd ellipses.
    bins : int

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = pyplot()
    X = as_finite_array("samples", samples, ndim=2)
    n = X.shape[1]
    names = [f"eps[{k}]" for k in range(n)] if names is None else list(names)
    fig, axes = plt.subplots(n, n, figsize=(2.6 * n + 0.6, 2.6 * n + 0.6), squeeze=False)
    t = np.linspace(0, 2 * np.pi, 200)
    for i in range(n):
        for j in range(n):
            a = axes[i, j]
            if j > i:
                a.axis("off")
                continue
            if i == j:
                a.hist(X[:, i], bins=bins, density=True, color="C0", alpha=0.6)
                if laplace is not None:
                    m, C = laplace
                    s = np.sqrt(C[i, i])
                    x = np.linspace(X[:, i].min(), X[:, i].max(), 200)
                    a.plot(x, np.exp(-0.5 * ((x - m[i]) / s) ** 2) / (s * np.sqrt(2 * np.pi)), "k-")
                a.set_yticks([])
            else:
                a.plot(X[:, j], X[:, i], ".", ms=1, alpha=0.2, color="C0")
                if laplace is not None:
                    m, C = laplace
                    w, V = np.linalg.eigh(np.asarray(C)[np.ix_([j, i], [j, i])])
                    ell = V @ (2 * np.sqrt(np.maximum(w, 0))[:, None] * [np.cos(t), np.sin(t)])
                    a.plot(m[j] + ell[0], m[i] + ell[1], "k-", lw=1)
                if truth is not None:
                    a.axhline(truth[i], color="C3", lw=0.8)
            if truth is not None:
                a.axvline(truth[j], color="C3", lw=0.8)
            if i == n - 1:
                a.set_xlabel(names[j])
            if j == 0 and i > 0:
                a.set_ylabel(names[i])
    return fig


def _component(values, component, name):
    """``values[(k, *component)]`` for every input k: one output component's (d,) values."""
    arr = np.asarray(values, dtype=float)
    idx = (component,) if isinstance(component, (int, np.integer)) else tuple(component)
    if len(idx) != arr.ndim - 1:
        raise ValueError(
            f"`component` must index one output of shape {arr.shape[1:]} (e.g. "
            f"{(0,) * (arr.ndim - 1)}), got {component!r}"
        )
    try:
        return arr[(slice(None), *idx)]
    except IndexError as e:
        raise ValueError(
            f"`component` {component!r} is outside the output shape {arr.shape[1:]} of {name}"
        ) from e


def sobol_bars(first, total, names=None, ax=None, first_err=None, total_err=None, component=()):
    """Grouped bars of first-order and total Sobol indices, one pair per input.

    Parameters
    ----------
    first, total : (d, *output_shape) array_like
    names : sequence of str, optional
        Input names on the axis (default ``x0, x1, ...``).
    ax : matplotlib Axes, optional
    first_err, total_err : (2, d, *output_shape) array_like, optional
        Lower and upper interval bounds, drawn as error bars.
    component : int or tuple
        The output component drawn (``()`` for a scalar output).

    Returns
    -------
    matplotlib Axes
        Bars: ``2 d`` patches, the first ``d`` the first-order indices.
    """
    S = _component(first, component, "the indices")
    T = _component(total, component, "the indices")
    d = S.shape[0]
    names = [f"x{k}" for k in range(d)] if names is None else [str(n) for n in names]
    if len(names) != d:
        raise ValueError(f"`names` must hold {d} names (one per input), got {len(names)}")
    if ax is None:
        _, ax = pyplot().subplots(figsize=(max(3.5, 0.9 * d + 1.5), 3.4))
    pos = np.arange(d)
    w = 0.38

    def err(bounds, mid):
        if bounds is None:
            return None
        lo_hi = np.stack([_component(b, component, "the intervals") for b in bounds])
        return np.maximum(np.stack([mid - lo_hi[0], lo_hi[1] - mid]), 0.0)

    kw = {"capsize": 3, "error_kw": {"lw": 0.8}}
    ax.bar(pos - w / 2, S, w, yerr=err(first_err, S), label="first order", color="C0", **kw)
    ax.bar(pos + w / 2, T, w, yerr=err(total_err, T), label="total", color="C1", **kw)
    ax.set_xticks(pos)
    ax.set_xticklabels(names)
    ax.set_ylabel("Sobol index")
    ax.set_ylim(min(0.0, ax.get_ylim()[0]), max(1.0, ax.get_ylim()[1]))
    ax.legend(fontsize=7)
    return ax
