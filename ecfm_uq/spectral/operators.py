"""Galerkin operators of the spatial bases: mass, stiffness, triple products, loads,
sensors and constraint-force shapes.

Every matrix is an integral of basis functions computed once by composite Gauss
quadrature (:mod:`.quadrature`), matching the paper's definitions:

* :math:`M_{ij} = \\int f_i f_j`, :math:`K_{ij} = \\int f_i' f_j'` (Sections 3.1-3.2),
* :math:`A_{ijk} = \\int f_i f_j f_k'` (Burgers, Section 3.1) or
  :math:`\\int f_i f_j f_k` (Fisher-KPP, Section 3.2),
* :math:`F_i = \\int s f_i`, :math:`\\mathcal M_{ij} = f_j(x_i)`,
* constraint forces :math:`\\Gamma_{ij} = \\int f_i \\Gamma(x - x_j)` (Eq. burgers_ecfm).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validation import as_finite_array, check_positive
from ..memory import check_allocation
from .basis import SinusoidBasis, TensorBasis2D
from .quadrature import composite_gauss, default_points


def _rule(bases, breakpoints, n_per_panel, extra=1):
    n = default_points(*bases, extra=extra) if n_per_panel is None else n_per_panel
    return composite_gauss(breakpoints, n)


def _weight_values(weight, x):
    if weight is None:
        return np.ones_like(x)
    if not callable(weight):
        raise TypeError(f"`weight` must be callable w(x) or None, got {type(weight).__name__}")
    w = np.broadcast_to(np.asarray(weight(x), dtype=float), x.shape)
    if not np.all(np.isfinite(w)):
        raise ValueError("`weight` returned NaN or inf on [0, 1]")
    return w


def gram(basis, other=None, derivatives=(0, 0), weight=None, breakpoints=(), n_per_panel=None):
    """Weighted Gram matrix :math:`G_{ij} = \\int_0^1 w(x) f_i^{(d_0)}(x) g_j^{(d_1)}(x)\\,dx`.

    Parameters
    ----------
    basis : SinusoidBasis
        Row basis :math:`f`.
    other : SinusoidBasis, optional
        Column basis :math:`g` (default: ``basis``).
    derivatives : (int, int)
        Derivative orders :math:`(d_0, d_1)`.
    weight : callable, optional
        :math:`w(x)`, vectorised.
    breakpoints : sequence of float
        Kinks or jumps of ``weight``.
    n_per_panel : int, optional
        Gauss points per panel (default resolves the bases' highest wavenumbers).

    Returns
    -------
    (N, N_other) ndarray
    """
    other = basis if other is None else other
    x, w = _rule((basis, other), breakpoints, n_per_panel)
    w = w * _weight_values(weight, x)
    fa = basis.evaluate(x, derivatives[0])
    fb = other.evaluate(x, derivatives[1])
    return (fa * w[:, None]).T @ fb


def mass(basis, **kw):
    """Mass matrix :math:`M_{ij} = \\int f_i f_j` (``I/2`` for the sine basis)."""
    return gram(basis, derivatives=(0, 0), **kw)


def stiffness(basis, **kw):
    """Stiffness matrix :math:`K_{ij} = \\int f_i' f_j'`."""
    return gram(basis, derivatives=(1, 1), **kw)


def triple(basis, derivatives=(0, 0, 0), breakpoints=(), n_per_panel=None):
    """Triple-product tensor :math:`A_{ijk} = \\int f_i^{(d_0)} f_j^{(d_1)} f_k^{(d_2)}`.

    Returns
    -------
    (N, N, N) ndarray
        Dense; for 2-D tensor bases use the 1-D factors instead.
    """
    x, w = _rule((basis, basis, basis), breakpoints, n_per_panel, extra=2)
    f = [basis.evaluate(x, d) for d in derivatives]
    return np.einsum("q,qi,qj,qk->ijk", w, f[0], f[1], f[2], optimize=True)


def load(basis, s, breakpoints=(), n_per_panel=None):
    """Load vector :math:`F_i = \\int_0^1 s(x) f_i(x)\\,dx`.

    Parameters
    ----------
    s : callable
        Vectorised source :math:`s(x)`.
    """
    if not callable(s):
        raise TypeError(f"`s` must be a callable s(x), got {type(s).__name__}")
    return gram_vector(basis, s, breakpoints=breakpoints, n_per_panel=n_per_panel)


def gram_vector(basis, s, derivative=0, breakpoints=(), n_per_panel=None):
    """:math:`\\int_0^1 s(x) f_i^{(d)}(x)\\,dx` for a vectorised callable ``s``."""
    x, w = _rule((basis,), breakpoints, n_per_panel, extra=2)
    sv = _weight_values(s, x)
    return basis.evaluate(x, derivative).T @ (w * sv)


def project(basis, u, **kw):
    """L2 projection coefficients :math:`M^{-1} \\int u f` of a function ``u``.

    For an orthogonal but not orthonormal basis (the sine basis has :math:`M = I/2`)
    this differs from :math:`\\int u f_i` by the factor :math:`M^{-1}`.
    """
    return np.linalg.solve(mass(basis), load(basis, u, **kw))


def _check_basis(basis, allow_2d=False):
    kinds = (SinusoidBasis, TensorBasis2D) if allow_2d else (SinusoidBasis,)
    if not isinstance(basis, kinds):
        want = "a SinusoidBasis or TensorBasis2D" if allow_2d else "a 1-D SinusoidBasis"
        raise TypeError(f"`basis` must be {want} (e.g. SineBasis(n)), got {type(basis).__name__}")


def _check_centers(c, dim=1):
    """Centres of constraint forces: at least one, inside the domain (like the sensors)."""
    if c.shape[0] == 0:
        raise ValueError("`centers` is empty; pass at least one force centre")
    outside = (c < 0) | (c > 1)
    if outside.ndim == 2:
        outside = outside.any(axis=1)
    if outside.any():
        j = int(np.flatnonzero(outside)[0])
        where = "the unit square [0, 1]^2" if dim == 2 else "[0, 1]"
        raise ValueError(
            f"`centers` must lie in {where} (the domain), got centre {j} at "
            f"{c[j].tolist()}; a force outside the domain has (almost) no effect"
        )


def sensor_matrix(basis, points):
    """Measurement operator :math:`\\mathcal M_{ij} = f_j(x_i)`.

    Parameters
    ----------
    basis : SinusoidBasis or TensorBasis2D
    points : (C,) or (C, 2) array_like
        Sensor positions inside the domain.

    Returns
    -------
    (C, N) ndarray
    """
    _check_basis(basis, allow_2d=True)
    if isinstance(basis, TensorBasis2D):
        p = as_finite_array("points", points, ndim=2)
        if p.shape[1] != 2:
            raise ValueError(f"`points` must have shape (C, 2), got {p.shape}")
        if p.shape[0] == 0:
            raise ValueError("`points` is empty; pass at least one sensor position")
        if np.any((p < 0) | (p > 1)):
            j = int(np.flatnonzero(np.any((p < 0) | (p > 1), axis=1))[0])
            raise ValueError(
                f"`points` must lie in the unit square [0, 1]^2, got sensor {j} at {p[j].tolist()}"
            )
        return basis.evaluate(p)
    p = as_finite_array("points", points, ndim=1)
    if p.size == 0:
        raise ValueError("`points` is empty; pass at least one sensor position")
    if np.any((p < 0) | (p > 1)):
        j = int(np.flatnonzero((p < 0) | (p > 1))[0])
        raise ValueError(f"`points` must lie in [0, 1], got sensor {j} at {p[j]}")
    return basis.evaluate(p)


def hat_forces(basis, centers, half_width):
    """Hat-function constraint forces :math:`\\Gamma_{ij} = \\int f_i\\,h_j`.

    :math:`h_j(x) = \\max(0, 1 - |x - x_j| / a)` with unit height and half-width
    :math:`a` (the paper's "finite element hat functions centred on the measurement
    positions", Section 3.1).

    Returns
    -------
    (N, C) ndarray
    """
    _check_basis(basis)
    c = as_finite_array("centers", centers, ndim=1)
    _check_centers(c)
    a = check_positive("half_width", half_width)
    cols = []
    for xc in c:
        hat = lambda x, xc=xc: np.maximum(0.0, 1.0 - np.abs(x - xc) / a)
        cols.append(gram_vector(basis, hat, breakpoints=(xc - a, xc, xc + a)))
    return np.column_stack(cols)


def gaussian_forces(basis, centers, omega):
    """1-D Gaussian constraint forces :math:`\\int f_i \\sqrt{\\omega/\\pi}\\,e^{-\\omega(x-x_j)^2}`.

    The 2-D RBF of Section 3.2, :math:`(\\omega/\\pi) e^{-\\omega\\|x - x_j\\|^2}`, is the
    product of two of these; see :func:`rbf_forces`.

    Returns
    -------
    (N, C) ndarray
    """
    _check_basis(basis)
    c = as_finite_array("centers", centers, ndim=1)
    _check_centers(c)
    om = check_positive("omega", omega)
    n = default_points(basis, extra=2) + int(4 * np.sqrt(om))
    C, panels = c.size, c.size + 1
    check_allocation(
        8.0 * max(float(n) ** 2, float(n) * panels * (basis.size + C + 2)),
        f"gaussian_forces quadrature with {n} points per panel (omega={om:g})",
        "pass a smaller `omega` (a wider force; width ~ 1/sqrt(omega))",
    )
    x, w = composite_gauss(tuple(c), n)
    g = np.sqrt(om / np.pi) * np.exp(-om * (x[:, None] - c[None, :]) ** 2)
    return basis.evaluate(x).T @ (w[:, None] * g)


def rbf_forces(basis, centers, omega):
    """2-D RBF constraint forces on a tensor basis (paper Section 3.2).

    :math:`\\Gamma_{(a,b),j} = \\int\\!\\!\\int g_a(x) h_b(y)\\,\\frac{\\omega}{\\pi}
    e^{-\\omega\\|(x,y) - c_j\\|^2}`, which factorizes into 1-D Gaussian integrals.

    Parameters
    ----------
    basis : TensorBasis2D
    centers : (C, 2) array_like
    omega : float
        Width parameter :math:`\\omega`.

    Returns
    -------
    (N, C) ndarray
    """
    if not isinstance(basis, TensorBasis2D):
        raise TypeError("`basis` must be a TensorBasis2D; use gaussian_forces for 1-D")
    c = as_finite_array("centers", centers, ndim=2)
    if c.shape[1] != 2:
        raise ValueError(f"`centers` must have shape (C, 2), got {c.shape}")
    _check_centers(c, dim=2)
    gx = gaussian_forces(basis.bx, c[:, 0], omega)
    gy = gaussian_forces(basis.by, c[:, 1], omega)
    return (gx[:, None, :] * gy[None, :, :]).reshape(basis.size, c.shape[0])


def kron2(ax, ay):
    """Kronecker product of 1-D factors (row-major tensor ordering).

    Dense for dense factors; CSR when either factor is ``scipy.sparse`` (no dense
    ``N x N`` array is formed then).
    """
    if sp.issparse(ax) or sp.issparse(ay):
        return sp.kron(ax, ay, format="csr")
    return np.kron(ax, ay)


__all__ = [
    "SinusoidBasis",
    "gram",
    "gram_vector",
    "mass",
    "stiffness",
    "triple",
    "load",
    "project",
    "sensor_matrix",
    "hat_forces",
    "gaussian_forces",
    "rbf_forces",
    "kron2",
]
