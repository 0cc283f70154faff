"""Derivatives by finite differences: the one helper every inverse module calls.

:func:`fd_jacobian` differences a vector function of the parameters column by column,

=============  =============================================  ==========  ================
``method``     column :math:`j`                               calls       error
=============  =============================================  ==========  ================
``"2-point"``  :math:`(f(x + h_je_j) - f(x)) / h_j`           :math:`p`   :math:`O(h)`
``"3-point"``  :math:`(f(x + h_je_j) - f(x - h_je_j)) / 2h_j`  :math:`2p`  :math:`O(h^2)`
``"5-point"``  the fourth-order central stencil               :math:`4p`  :math:`O(h^4)`
``"cs"``       :math:`\\mathrm{Im}\\,f(x + i h_j e_j) / h_j`     :math:`p`   :math:`O(h^2)`,
                                                                          no cancellation
=============  =============================================  ==========  ================

Steps are relative to each parameter's own size (``typical``: the larger of
:math:`|x_j|` and a typical magnitude the caller knows, e.g. the starting point), so a
parameter of size 1e-9 is not differenced with a step of 1e-8 (Dennis & Schnabel 1983,
Sec. 5.4): :math:`h_j = \\eta\\,\\max(|x_j|, \\mathrm{typ}_j)` with
:math:`\\eta = \\sqrt{\\varepsilon}` for one-sided, :math:`\\varepsilon^{1/3}` for central
and :math:`10^{-20}`-free complex steps. The points of one Jacobian may be evaluated
together (``map_points``, e.g. through an executor).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FD_METHODS", "fd_gradient", "fd_jacobian", "fd_steps"]

FD_METHODS = ("2-point", "3-point", "5-point", "cs")
_ETA = {
    "2-point": np.sqrt(np.finfo(float).eps),
    "3-point": np.finfo(float).eps ** (1 / 3),
    "5-point": np.finfo(float).eps ** (1 / 5),
    "cs": 1e-20,
}


def fd_steps(x, method="2-point", typical=None):
    """The step :math:`h_j` of each parameter (see the module's table)."""
    if type(x) is np.ndarray and x.ndim == 1 and x.size <= 16 and x.dtype == np.float64:
        # a few parameters: Python floats (IEEE doubles: max and product bit for bit as
        # numpy's), without five array operations
        eta = _ETA[method]
        if typical is None:
            return np.array([(abs(v) or 1.0) * eta for v in x.tolist()])
        t = np.asarray(typical, dtype=float).ravel().tolist()
        if len(t) == x.size:
            return np.array(
                [(max(abs(v), abs(w)) or 1.0) * eta for v, w in zip(x.tolist(), t, strict=True)]
            )
    size = np.abs(np.asarray(x, dtype=float))  # a fresh array; a scalar for a scalar x:
    if type(size) is not np.ndarray:
        size = np.array(size)
    if typical is not None:
        np.maximum(size, np.abs(np.asarray(typical, dtype=float)), out=size)
    if not size.all():
        size[size == 0] = 1.0
    size *= _ETA[method]
    return size


def _offsets(method):
    return {"2-point": (1.0,), "3-point": (1.0, -1.0), "5-point": (1.0, -1.0, 2.0, -2.0)}[method]


def fd_jacobian(fun, x, *, method="2-point", steps=None, typical=None, f0=None, columns=None,
                map_points=None):  # fmt: skip
    """:math:`\\partial f/\\partial x` of a vector function by finite differences.

    Parameters
    ----------
    fun : callable
        ``x (p,) -> (m,) array``; for ``"cs"`` it must accept complex ``x``.
    x : (p,) array_like
    method : {"2-point", "3-point", "5-point", "cs"}
    steps : float or (p,) array_like, optional
        Absolute steps (default :func:`fd_steps`).
    typical : (p,) array_like, optional
        Typical parameter magnitudes for the default steps.
    f0 : (m,) array_like, optional
        ``fun(x)`` when the caller has it (``"2-point"`` then costs ``p`` calls).
    columns : sequence of int, optional
        Only these columns (the others are not computed; the result has ``len(columns)``).
    map_points : callable, optional
        ``points (k, p) -> (k, m)``, evaluating many points at once (an executor);
        default: one call of ``fun`` after the other.

    Returns
    -------
    (m, len(columns)) ndarray
    """
    x = np.asarray(x, dtype=float)
    p = x.size
    cols = np.arange(p) if columns is None else np.asarray(columns, dtype=int)
    h = (
        fd_steps(x, method, typical)
        if steps is None
        else np.broadcast_to(np.asarray(steps, dtype=float), x.shape)
    )
    if method == "cs":
        outs = []
        for j in cols:
            z = x.astype(complex)
            z[j] += 1j * h[j]
            outs.append(np.imag(np.asarray(fun(z))).ravel() / h[j])
        return np.column_stack(outs) if outs else np.zeros((0, 0))
    if method not in FD_METHODS:
        raise ValueError(f"`method` must be one of {FD_METHODS}, got {method!r}")
    if method == "2-point" and f0 is not None and map_points is None:
        # the common case (an optimizer's Jacobian at a point it evaluated): no stencil
        base = np.asarray(f0, dtype=float).ravel()
        J = np.empty((base.size, cols.size))
        for c, j in enumerate(cols.tolist()):
            e = x.copy()
            xj = float(x[j])
            e[j] = xj + float(h[j])
            # the step actually taken (x + h rounded) divides, not h
            np.subtract(np.asarray(fun(e), dtype=float).reshape(-1), base, out=J[:, c])
            J[:, c] /= float(e[j]) - xj
        return J
    if method == "3-point" and map_points is None:
        # the status test's Jacobian: the stencil's points in the general path's order,
        # each difference computed as it does (the same bits), without the (2p, m) stack
        # (Python floats: IEEE doubles, the same sums and quotients as numpy's scalars)
        J = None
        xs, hs = x.tolist(), h.tolist()
        for c, j in enumerate(cols.tolist()):
            e = x.copy()
            e[j] = xs[j] + 1.0 * hs[j]
            # a copy: ``fun`` may hand back one array it rewrites at the next call
            up = np.array(fun(e), dtype=float).ravel()
            e = x.copy()
            e[j] = xs[j] + -1.0 * hs[j]
            down = np.asarray(fun(e), dtype=float).ravel()
            if J is None:
                J = np.empty((up.size, cols.size))
            J[:, c] = (up - down) / (2 * hs[j])
        return np.empty((0, 0)) if J is None else J
    offsets = _offsets(method)
    points = []
    for j in cols:
        for o in offsets:
            e = x.copy()
            e[j] = x[j] + o * h[j]
            points.append(e)
    if method == "2-point" and f0 is None:
        points.append(x.copy())
    if map_points is not None:
        values = np.asarray(map_points(np.array(points)), dtype=float).reshape(len(points), -1)
    else:
        values = np.array([np.asarray(fun(e), dtype=float).ravel() for e in points])
    k = len(offsets)
    J = np.empty((values.shape[1], cols.size))
    base = None
    if method == "2-point":
        base = np.asarray(f0, dtype=float).ravel() if f0 is not None else values[-1]
    for c, j in enumerate(cols):
        v = values[c * k : (c + 1) * k]
        if method == "2-point":
            # the step actually taken (x + h rounded) divides, not h
            J[:, c] = (v[0] - base) / ((x[j] + h[j]) - x[j])
        elif method == "3-point":
            J[:, c] = (v[0] - v[1]) / (2 * h[j])
        else:
            J[:, c] = (8 * (v[0] - v[1]) - (v[2] - v[3])) / (12 * h[j])
    return J


def fd_gradient(fun, x, h):
    """Gradient of a scalar ``fun`` by central differences,
    :math:`g_j = (f(x + h_j e_j) - f(x - h_j e_j)) / (2h_j)` (2n calls; a non-finite value
    passes through, for the caller to treat as a failure).

    ``h``: one step for every coordinate, or one per coordinate.
    """
    x = np.asarray(x, dtype=float)
    steps = np.broadcast_to(np.asarray(h, dtype=float), x.shape)
    return fd_jacobian(lambda e: np.atleast_1d(fun(e)), x, method="3-point", steps=steps)[0]
