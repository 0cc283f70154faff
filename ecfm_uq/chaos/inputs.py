"""Independent uniform inputs on their own ranges, mapped affinely to the germ.

The chaos basis lives on the germ :math:`\\omega \\sim \\mathcal U(0, 1)^d`. A user's model
takes its inputs on their own ranges, :math:`x_k \\sim \\mathcal U(a_k, b_k)` independent,
and the affine map

.. math:: x_k = a_k + (b_k - a_k)\\,\\omega_k, \\qquad \\omega_k = (x_k - a_k)/(b_k - a_k)

carries one to the other. Because the map is affine, Legendre polynomials in
:math:`\\omega` are Legendre polynomials in :math:`x` and every statistic (moments, Sobol
indices, quantiles) is the same in either variable. Only uniform inputs are supported:
the basis is Legendre, orthogonal for the uniform density.
"""

from __future__ import annotations

import numpy as np

from .._validation import as_finite_array

__all__ = ["UniformInputs"]


class UniformInputs:
    """Independent uniform inputs :math:`x_k \\sim \\mathcal U(a_k, b_k)`, ``k < dim``.

    Parameters
    ----------
    bounds : (dim, 2) array_like
        Rows ``(a_k, b_k)`` with ``a_k < b_k``, finite. A single pair ``(a, b)`` is one
        input.
    names : sequence of str, optional
        Input names (default ``x0, x1, ...``), used in reports and in the chaospy export.

    Attributes
    ----------
    bounds : (dim, 2) ndarray
    lower, upper, width : (dim,) ndarray
    dim : int
    names : tuple of str

    Raises
    ------
    ValueError
        If ``bounds`` is misshaped, non-finite, or some ``a_k >= b_k``.

    Examples
    --------
    >>> inputs = UniformInputs([(-np.pi, np.pi)] * 3)
    >>> inputs.from_germ([[0.5, 0.0, 1.0]]).round(6).tolist()
    [[0.0, -3.141593, 3.141593]]
    """

    def __init__(self, bounds, names=None):
        arr = as_finite_array("bounds", bounds)
        if arr.ndim == 1 and arr.shape == (2,):
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
            raise ValueError(f"`bounds` must have shape (dim, 2), rows (a_k, b_k), got {arr.shape}")
        bad = np.flatnonzero(arr[:, 0] >= arr[:, 1])
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"`bounds` row {k} is ({arr[k, 0]:g}, {arr[k, 1]:g}): each input needs a < b; "
                "pass (lower, upper)"
            )
        self.bounds = arr.copy()
        self.bounds.setflags(write=False)
        if names is None:
            names = [f"x{k}" for k in range(arr.shape[0])]
        names = tuple(str(n) for n in names)
        if len(names) != arr.shape[0]:
            raise ValueError(f"`names` must hold {arr.shape[0]} names, got {len(names)}")
        self.names = names

    @property
    def dim(self):
        """Number of inputs."""
        return self.bounds.shape[0]

    @property
    def lower(self):
        return self.bounds[:, 0]

    @property
    def upper(self):
        return self.bounds[:, 1]

    @property
    def width(self):
        return self.bounds[:, 1] - self.bounds[:, 0]

    def __repr__(self):
        rows = ", ".join(
            f"{n}~U({a:g}, {b:g})" for n, (a, b) in zip(self.names, self.bounds, strict=True)
        )
        return f"UniformInputs({rows})"

    def __eq__(self, other):
        if not isinstance(other, UniformInputs):
            return NotImplemented
        return np.array_equal(self.bounds, other.bounds)

    __hash__ = None

    def _points(self, name, value):
        arr = as_finite_array(name, value)
        if arr.ndim == 1 and self.dim == 1:
            arr = arr[:, None]
        elif arr.ndim == 1 and arr.shape[0] == self.dim:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.dim:
            raise ValueError(f"`{name}` must have shape (n, {self.dim}), got {arr.shape}")
        return arr

    def to_germ(self, x):
        """Germ points :math:`\\omega = (x - a)/(b - a)`.

        Parameters
        ----------
        x : (n, dim) array_like
            Points in the inputs' box (a single point of shape (dim,) is accepted).

        Returns
        -------
        omega : (n, dim) ndarray

        Raises
        ------
        ValueError
            If a point lies outside the box (beyond round-off).
        """
        x = self._points("x", x)
        omega = (x - self.lower) / self.width
        if omega.size and (omega.min() < -1e-12 or omega.max() > 1 + 1e-12):
            q, k = np.unravel_index(np.argmax(np.maximum(-omega, omega - 1)), omega.shape)
            raise ValueError(
                f"`x` point {q} has {self.names[k]} = {x[q, k]:g} outside its range "
                f"[{self.lower[k]:g}, {self.upper[k]:g}]"
            )
        return np.clip(omega, 0.0, 1.0)

    def from_germ(self, omega):
        """Input points :math:`x = a + (b - a)\\,\\omega`.

        Parameters
        ----------
        omega : (n, dim) array_like
            Germ points in [0, 1]^dim.

        Returns
        -------
        x : (n, dim) ndarray
        """
        omega = self._points("omega", omega)
        return self.lower + self.width * omega

    @classmethod
    def from_chaospy(cls, dist):
        """Inputs from a chaospy distribution of independent uniforms.

        Parameters
        ----------
        dist : chaospy.Distribution
            A ``chaospy.Uniform`` or a joint ``chaospy.J`` / ``chaospy.Iid`` of
            ``chaospy.Uniform`` s.

        Raises
        ------
        TypeError
            If ``dist`` is not a chaospy distribution, or has a non-uniform component
            (the basis is Legendre, orthogonal for uniform inputs only).
        """
        import chaospy

        if not isinstance(dist, chaospy.Distribution):
            raise TypeError(f"`dist` must be a chaospy distribution, got {type(dist).__name__}")
        parts = [dist] if isinstance(dist, chaospy.Uniform) else list(dist)
        for k, d in enumerate(parts):
            if not isinstance(d, chaospy.Uniform):
                raise TypeError(
                    f"`dist` component {k} is {type(d).__name__}: the basis is "
                    "Legendre, orthogonal for uniform inputs only; pass a chaospy.J of "
                    "chaospy.Uniform(a, b) (or transform the input to a uniform yourself)"
                )
        bounds = [(float(d.lower[0]), float(d.upper[0])) for d in parts]
        return cls(bounds)

    def to_chaospy(self):
        """The same inputs as a chaospy joint distribution of ``chaospy.Uniform``."""
        import chaospy

        return chaospy.J(*[chaospy.Uniform(float(a), float(b)) for a, b in self.bounds])
