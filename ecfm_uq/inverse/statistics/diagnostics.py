"""Diagnostics of a reduced objective :math:`z(\\epsilon)`: finite-difference Hessian,
condition number, Taylor test of a gradient, loss surfaces, and the expected relative
error of a PCE field (Section 3.3).

The paper characterizes the two Burgers objectives of Section 3.1 by "computing the
Hessian matrix of the objective with finite differences around the solution" and its
condition number (8.11 standard, 3.46 ECFM), and by plotting the loss surfaces. These
functions are generic: they take any objective as a callable.
"""

from __future__ import annotations

import numpy as np

from ..._validation import as_finite_array, check_choice, check_int, check_positive
from ...errors import ConvergenceError
from ...spectral import composite_gauss


def _as_point(x):
    return as_finite_array("x", np.atleast_1d(x), ndim=1).astype(float)


def _grad_of(out):
    """Accept ``g`` or ``(f, g)`` (or ``(f, g, ...)``) from a gradient callable."""
    if isinstance(out, tuple):
        if len(out) < 2:
            raise TypeError("a gradient callable must return g or a tuple (f, g, ...)")
        out = out[1]
    return np.asarray(out, dtype=float)


def fd_hessian(fun, x, h=1e-3, *, kind="gradient"):
    """Hessian of an objective by central finite differences, error :math:`O(h^2)`.

    Parameters
    ----------
    fun : callable
        ``kind="gradient"``: ``fun(x)`` returns the gradient ``(n,)`` or a tuple whose
        second item is the gradient (``(f, g)`` as for optimizers).
        ``kind="value"``: ``fun(x)`` returns the scalar objective (or a tuple whose first
        item is it).
    x : (n,) array_like
        Point of evaluation (e.g. the optimum).
    h : float
        Step in every coordinate.
    kind : {"gradient", "value"}
        ``"gradient"``: columns
        :math:`H_{:,j} = (g(x + h e_j) - g(x - h e_j)) / (2h)` (2n calls), then
        symmetrized :math:`(H + H^T)/2`.
        ``"value"``: second differences of values,
        :math:`H_{ii} = (f(x + he_i) - 2f(x) + f(x - he_i))/h^2` and
        :math:`H_{ij} = (f(x + he_i + he_j) - f(x + he_i - he_j) - f(x - he_i + he_j)
        + f(x - he_i - he_j))/(4h^2)` (:math:`1 + 2n^2` calls); cancellation makes it
        less accurate than ``"gradient"`` for small ``h``.

    Returns
    -------
    H : (n, n) ndarray
        Symmetric.

    Raises
    ------
    ValueError
        On a bad ``h``, ``kind`` or ``x``, or when ``fun`` returns a non-finite value.
    """
    x = _as_point(x)
    h = check_positive("h", h)
    kind = check_choice("kind", kind, ("gradient", "value"))
    n = x.size
    E = np.eye(n) * h

    if kind == "gradient":
        H = np.empty((n, n))
        for j in range(n):
            gp = _grad_of(fun(x + E[j]))
            gm = _grad_of(fun(x - E[j]))
            if gp.shape != (n,) or gm.shape != (n,):
                raise ValueError(f"`fun` must return a gradient of shape ({n},), got {gp.shape}")
            H[:, j] = (gp - gm) / (2.0 * h)
    else:

        def f(y):
            out = fun(y)
            return float(out[0] if isinstance(out, tuple) else out)

        f0 = f(x)
        H = np.empty((n, n))
        for i in range(n):
            H[i, i] = (f(x + E[i]) - 2.0 * f0 + f(x - E[i])) / h**2
            for j in range(i + 1, n):
                H[i, j] = (
                    f(x + E[i] + E[j])
                    - f(x + E[i] - E[j])
                    - f(x - E[i] + E[j])
                    + f(x - E[i] - E[j])
                ) / (4.0 * h**2)
                H[j, i] = H[i, j]
    if not np.all(np.isfinite(H)):
        raise ValueError("`fun` returned NaN or inf near `x`; cannot form a Hessian")
    return 0.5 * (H + H.T)


def condition_number(H):
    """Spectral condition number :math:`|\\mu|_{max}/|\\mu|_{min}` of a symmetric matrix.

    Parameters
    ----------
    H : (n, n) array_like
        Symmetric (e.g. from :func:`fd_hessian`).

    Returns
    -------
    float
        ``inf`` for a singular matrix.

    Raises
    ------
    ValueError
        If ``H`` is not square, not finite or not symmetric.
    """
    H = as_finite_array("H", H, ndim=2)
    if H.shape[0] != H.shape[1]:
        raise ValueError(f"`H` must be square, got shape {H.shape}")
    scale = max(np.abs(H).max(), 1e-300)
    if np.abs(H - H.T).max() > 1e-10 * scale:
        raise ValueError("`H` must be symmetric; symmetrize it with (H + H.T) / 2")
    mu = np.abs(np.linalg.eigvalsh(0.5 * (H + H.T)))
    if mu.min() == 0.0:
        return float("inf")
    return float(mu.max() / mu.min())


def taylor_remainders(fun_and_grad, x, direction, steps):
    """First-order Taylor remainders :math:`|z(x + h d) - z(x) - h\\,\\nabla z(x)\\cdot d|`.

    For a correct gradient they fall like :math:`h^2`; for a wrong one like :math:`h`
    (hIPPYlib's ``modelVerify``).

    Parameters
    ----------
    fun_and_grad : callable
        ``x -> (z, g)``.
    x, direction : (n,) array_like
    steps : (m,) array_like
        Positive step sizes h.

    Returns
    -------
    (m,) ndarray
    """
    x = _as_point(x)
    d = as_finite_array("direction", direction, shape=x.shape)
    hs = as_finite_array("steps", steps, ndim=1)
    if np.any(hs <= 0):
        raise ValueError("`steps` must be positive")
    z0, g0 = fun_and_grad(x)
    slope = float(np.dot(np.asarray(g0, dtype=float), d))
    return np.array([abs(fun_and_grad(x + h * d)[0] - z0 - h * slope) for h in hs])


def loss_surface(fun, grid1, grid2, *, callback=None):
    """Objective values on a tensor grid of two parameters.

    Parameters
    ----------
    fun : callable
        ``fun(eps) -> float`` for ``eps = (grid1[a], grid2[b])``.
    grid1, grid2 : (n1,), (n2,) array_like
    callback : callable, optional
        Called with no arguments after each point (progress bars).

    Returns
    -------
    Z : (n1, n2) numpy.ma.MaskedArray
        ``Z[a, b] = fun((grid1[a], grid2[b]))``; points where ``fun`` raised
        :class:`ConvergenceError` (a failed forward solve) or returned a non-finite value
        are masked (``numpy.ma.getmaskarray(Z)``), never left as NaN.
    """
    g1 = as_finite_array("grid1", grid1, ndim=1)
    g2 = as_finite_array("grid2", grid2, ndim=1)
    Z = np.zeros((g1.size, g2.size))
    mask = np.zeros(Z.shape, dtype=bool)
    for a, e1 in enumerate(g1):
        for b, e2 in enumerate(g2):
            try:
                Z[a, b] = float(fun(np.array([e1, e2])))
            except ConvergenceError:
                mask[a, b] = True
            if not mask[a, b] and not np.isfinite(Z[a, b]):
                mask[a, b] = True
            if callback is not None:
                callback()
    return np.ma.MaskedArray(Z, mask=mask)


def expected_relative_error(spatial_basis, chaos_basis, Theta_ref, Theta, *, n_x=400, n_omega=400):
    """Expected relative L1 error of a PCE field against a reference PCE field.

    .. math::

        \\mathcal E = \\frac{\\int_0^1\\int_0^1 |u(x,\\omega) - \\hat w(x,\\omega)|\\,dx\\,d\\omega}
                          {\\int_0^1\\int_0^1 |u(x,\\omega)|\\,dx\\,d\\omega},
        \\quad u = f_i(x)\\Theta^{ref}_{ik}\\Psi_k(\\omega)

    (Section 3.3, after Eq. stochastic_model), by tensor composite Gauss quadrature
    (16 points on each of ``n/16`` panels per variable; the absolute value has kinks, so
    the rule is only algebraically accurate -- 400 x 400 points give ~1e-6 relative).

    Parameters
    ----------
    spatial_basis : SinusoidBasis
        With ``evaluate(x) -> (m, N)``.
    chaos_basis : ChaosBasis
        One germ variable.
    Theta_ref, Theta : (N, P) array_like
    n_x, n_omega : int
        Quadrature points per variable (rounded up to a multiple of 16).

    Returns
    -------
    float
    """
    Theta_ref = as_finite_array("Theta_ref", Theta_ref, ndim=2)
    Theta = as_finite_array("Theta", Theta, shape=Theta_ref.shape)
    if chaos_basis.dim != 1:
        raise ValueError("expected_relative_error integrates over one germ variable (dim=1)")
    n_x = check_int("n_x", n_x, minimum=16)
    n_omega = check_int("n_omega", n_omega, minimum=16)

    def rule(n):
        panels = -(-n // 16)
        return composite_gauss(np.linspace(0, 1, panels + 1)[1:-1], 16)

    x, wx = rule(n_x)
    om, wo = rule(n_omega)
    F = spatial_basis.evaluate(x)
    Psi = chaos_basis.evaluate(om)
    u = F @ Theta_ref @ Psi.T
    w = F @ Theta @ Psi.T
    den = wx @ np.abs(u) @ wo
    if not den > 0:
        raise ValueError("`Theta_ref` describes a zero field; the relative error is undefined")
    return float(wx @ np.abs(u - w) @ wo / den)
