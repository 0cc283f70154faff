"""Spatial bases on the unit interval and their tensor products.

The paper discretizes every state with global trigonometric bases that satisfy the
homogeneous boundary conditions by construction:

* sine basis :math:`f_i(x) = \\sin(i\\pi x)` (Burgers, Fisher-KPP, heat; Section 3.1, 3.2),
* beam modes :math:`f_i(x) = \\sin((2i-1)\\pi x/2)` (Section 3.3), which satisfy
  :math:`f(0) = f''(0) = f'(1) = f'''(1) = 0`.

Both are members of one family :math:`f_i(x) = \\sin(k_i x)` with wavenumbers
:math:`k_i`, whose derivatives are closed-form:
:math:`f_i^{(d)}(x) = k_i^d \\sin(k_i x + d\\pi/2)`.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array, check_int


class SinusoidBasis:
    """Basis :math:`f_i(x) = \\sin(k_i x)` on :math:`[0, 1]`.

    Parameters
    ----------
    wavenumbers : (N,) array_like
        Positive wavenumbers :math:`k_i`.
    name : str
        Label used in reprs and figures.
    """

    def __init__(self, wavenumbers, name="sinusoid"):
        k = as_finite_array("wavenumbers", wavenumbers, ndim=1)
        if k.size == 0 or np.any(k <= 0):
            raise ValueError("`wavenumbers` must be a non-empty array of positive numbers")
        self.wavenumbers = k
        self.name = name

    @property
    def size(self):
        """Number of basis functions N."""
        return self.wavenumbers.size

    def __len__(self):
        return self.size

    def __repr__(self):
        return f"{type(self).__name__}(N={self.size})"

    def evaluate(self, x, derivative=0):
        """Values of :math:`f_i^{(d)}` at points ``x``.

        Parameters
        ----------
        x : (m,) array_like
            Evaluation points (any real values; the basis is analytic).
        derivative : int
            Derivative order :math:`d \\ge 0`.

        Returns
        -------
        (m, N) ndarray
        """
        d = check_int("derivative", derivative, minimum=0)
        x = as_finite_array("x", x)
        scalar = x.ndim == 0
        x = np.atleast_1d(x)
        if x.ndim != 1:
            raise ValueError(f"`x` must be 1-D, got shape {x.shape}")
        k = self.wavenumbers
        out = (k**d) * np.sin(np.outer(x, k) + d * np.pi / 2)
        return out[0] if scalar else out

    def max_wavenumber(self):
        """Largest wavenumber, used to choose quadrature sizes."""
        return float(self.wavenumbers.max())


class SineBasis(SinusoidBasis):
    """Dirichlet sine basis :math:`f_i = \\sin(i\\pi x)`, :math:`i = 1..N`."""

    def __init__(self, n):
        n = check_int("n", n, minimum=1)
        super().__init__(np.pi * np.arange(1, n + 1), name="sine")


class BeamBasis(SinusoidBasis):
    """Beam modes :math:`f_i = \\sin((2i-1)\\pi x/2)`, :math:`i = 1..N` (paper Section 3.3).

    They satisfy :math:`f(0) = f''(0) = 0` (simple support at the left) and
    :math:`f'(1) = f'''(1) = 0` (zero rotation and shear at the right).
    """

    def __init__(self, n):
        n = check_int("n", n, minimum=1)
        super().__init__(np.pi * (2 * np.arange(1, n + 1) - 1) / 2, name="beam")


class TensorBasis2D:
    """Tensor-product basis :math:`f_{(a,b)}(x, y) = g_a(x) h_b(y)` on the unit square.

    Index ordering is row-major: the flat index of :math:`(a, b)` is ``a * Ny + b``, so a
    coefficient vector reshapes to an ``(Nx, Ny)`` matrix :math:`\\Theta` with
    :math:`w(x, y) = g(x)^T \\Theta h(y)`. Operators are kept as their 1-D factors
    (Kronecker form) so that large bases never need dense 4-index arrays.

    Parameters
    ----------
    bx, by : SinusoidBasis
        1-D bases in x and y.
    """

    def __init__(self, bx, by=None):
        for name, b in (("bx", bx), ("by", by)):
            if not (b is None and name == "by") and not isinstance(b, SinusoidBasis):
                raise TypeError(
                    f"`{name}` must be a 1-D SinusoidBasis (e.g. SineBasis(n)), "
                    f"got {type(b).__name__}"
                )
        self.bx = bx
        self.by = bx if by is None else by

    @property
    def shape(self):
        """(Nx, Ny)."""
        return (self.bx.size, self.by.size)

    @property
    def size(self):
        """N = Nx * Ny."""
        return self.bx.size * self.by.size

    def __len__(self):
        return self.size

    def __repr__(self):
        return f"TensorBasis2D({self.bx!r} x {self.by!r})"

    def evaluate(self, points, derivative=(0, 0)):
        """Values at scattered points.

        Parameters
        ----------
        points : (m, 2) array_like
        derivative : (int, int)
            Derivative orders in x and y.

        Returns
        -------
        (m, N) ndarray
            Row-wise Kronecker (Khatri-Rao) product of the 1-D values.
        """
        p = as_finite_array("points", points, ndim=2)
        if p.shape[1] != 2:
            raise ValueError(f"`points` must have shape (m, 2), got {p.shape}")
        gx = self.bx.evaluate(p[:, 0], derivative[0])
        gy = self.by.evaluate(p[:, 1], derivative[1])
        return (gx[:, :, None] * gy[:, None, :]).reshape(p.shape[0], -1)

    def evaluate_grid(self, theta, x, y):
        """Field :math:`w(x_a, y_b)` on the grid ``x`` by ``y`` for coefficients ``theta``.

        Parameters
        ----------
        theta : (N,) array_like
        x : (mx,) array_like
        y : (my,) array_like

        Returns
        -------
        (mx, my) ndarray
        """
        t = np.asarray(theta, dtype=float).reshape(self.shape)
        return self.bx.evaluate(x) @ t @ self.by.evaluate(y).T
